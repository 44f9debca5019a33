"""Registration, the File > Import operator, the panel's operators (bpy module)."""

import numpy as np
import pytest

from addon_helpers import camera_dict, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)

K = [[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]]


@pytest.fixture
def registered(bpy, addon):
    addon.register()
    yield bpy
    addon.unregister()


def test_register_unregister_is_clean(bpy, addon):
    for _ in range(2):  # twice: unregister must leave nothing behind
        addon.register()
        assert hasattr(bpy.types, "VIEW3D_PT_camcal")
        assert hasattr(bpy.ops.import_scene, "camcal_rig")
        assert bpy.types.VIEW3D_PT_camcal.bl_category == "camcal"
        assert "menu_import" in {f.__name__ for f in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()}
        addon.unregister()
        assert not hasattr(bpy.types, "VIEW3D_PT_camcal")
        assert "menu_import" not in {f.__name__ for f in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()}


def test_import_operator(registered, tmp_path):
    bpy = registered
    cams = [camera_dict("a", (640, 480), K), camera_dict("b", (800, 600), K, c=(1, 0, 0))]
    path = write_rig(tmp_path / "op.rig.json", cams)
    assert bpy.ops.import_scene.camcal_rig(filepath=str(path), sensor_fit="VERTICAL") == {"FINISHED"}
    a, b = bpy.data.objects["op_a"], bpy.data.objects["op_b"]
    assert a.data.sensor_fit == "VERTICAL" and bpy.context.scene.camera == a
    # Set active camera: switches the scene camera and its resolution.
    assert bpy.ops.camcal.set_active_camera(camera=b.name) == {"FINISHED"}
    scene = bpy.context.scene
    assert scene.camera == b and (scene.render.resolution_x, scene.render.resolution_y) == (800, 600)
    scene.render.resolution_x = 10
    assert bpy.ops.camcal.apply_resolution() == {"FINISHED"}
    assert scene.render.resolution_x == 800
    multiview = scene.render.use_multiview
    assert bpy.ops.camcal.toggle_stereo() == {"FINISHED"}
    assert scene.render.use_multiview is not multiview


def test_import_operator_reports_errors(registered, tmp_path):
    bpy = registered
    bad = tmp_path / "bad.rig.json"
    bad.write_text('{"format": "camcal.rig", "version": 2}')
    with pytest.raises(RuntimeError, match="version: unsupported 2"):
        bpy.ops.import_scene.camcal_rig(filepath=str(bad))
    with pytest.raises(RuntimeError, match="not a camera imported by camcal"):
        bpy.ops.camcal.set_active_camera(camera="nothing")


def test_panel_draws(registered, tmp_path, addon):
    bpy = registered
    quality = {"rms_px": 0.21, "n_views": 18, "sigma": {"fx": 0.3, "cx": 0.12}}
    path = write_rig(tmp_path / "p.rig.json", [camera_dict("a", (640, 480), K, quality=quality)])
    addon.import_rig(bpy.context.scene, str(path))
    text = addon.panel._quality_text(bpy.data.objects["p_a"].data)
    assert text == "RMS 0.21 px, sigma.fx ±0.3, sigma.cx ±0.12"
    assert np.isclose(bpy.data.objects["p_a"].data["camcal_rms_px"], 0.21)
