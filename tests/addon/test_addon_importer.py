"""The importer in Blender (bpy module): exact cameras, rigs, frames, plates, points."""

import json
import struct

import numpy as np
import pytest

from addon_helpers import blender_project, camera_dict, frame, points_in_view, project_ref, rotation, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.model.rig import Rig

# (image size, fx, fy, principal point offset from the centre in px)
CASES = [
    ((1920, 1080), 1500.0, 1500.0, (37.3, -21.9)),   # landscape
    ((1920, 1080), 1400.0, 1530.0, (-80.2, 44.1)),  # landscape, fy > fx
    ((1080, 1920), 1600.0, 1490.0, (12.5, 63.0)),   # portrait, fx > fy
    ((1000, 1000), 900.0, 960.0, (-30.0, -10.0)),   # square, fy > fx
    ((1000, 1000), 990.0, 900.0, (25.0, 5.0)),      # square, fx > fy
    ((640, 480), 500.0, 520.0, (0.0, 0.0)),
]


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
def test_projection_matches_camcal_to_1e3_px(bpy, addon, tmp_path, fit):
    rng = np.random.default_rng(7)
    worst = 0.0
    for i, (size, fx, fy, (ox, oy)) in enumerate(CASES):
        W, H = size
        K = [[fx, 0.0, (W - 1) / 2 + ox], [0.0, fy, (H - 1) / 2 + oy], [0.0, 0.0, 1.0]]
        R = rotation(*rng.uniform(-np.pi, np.pi, 3))
        c = rng.uniform(-5, 5, 3)
        path = write_rig(tmp_path / f"case{i}.rig.json", [camera_dict("cam", size, K, R, c)])
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        result = addon.import_rig(scene, str(path), sensor_fit=fit)
        obj = result.cameras["cam"]
        assert obj.data.sensor_fit == fit
        X = points_in_view(K, R, c, size, 200, rng)
        err = np.abs(blender_project(bpy, obj, scene, X) - project_ref(K, R, c, X)).max()
        worst = max(worst, err)
    print(f"max projection error over {len(CASES)} cameras, fit {fit}: {worst:.2e} px")
    assert worst < 1e-3


def test_scene_structure_and_exact_custom_properties(bpy, addon, tmp_path):
    fx = 1234.5678901234567
    K = [[fx, 0.0, 640.123456789], [0.0, fx * 1.01, 360.987654321], [0.0, 0.0, 1.0]]
    R = rotation(0.1, 0.2, 0.3)
    path = write_rig(tmp_path / "one.rig.json", [camera_dict("main", (1280, 720), K, R, (1, 2, 3))])
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path))
    assert result.collection.name == "one" and result.collection.name in scene.collection.children
    assert result.root.type == "EMPTY" and result.root["camcal_rig_path"] == str(path)
    obj = result.cameras["main"]
    assert obj.parent == result.root and obj.name == "one_main"
    assert scene.camera == obj
    assert (scene.render.resolution_x, scene.render.resolution_y) == (1280, 720)
    assert scene.render.pixel_aspect_x == pytest.approx(1.01) and scene.render.pixel_aspect_y == 1.0
    data = obj.data
    assert list(data["camcal_K"]) == [v for row in K for v in row]  # doubles, bit-exact
    assert np.array_equal(np.reshape(list(data["camcal_R"]), (3, 3)), R)
    assert data["camcal_rms_px"] == 0.21
    assert json.loads(data["camcal_camera"])["K"] == K
    assert result.stereo_mode == "NONE" and not result.clips and result.warnings == []


def test_up_axis_is_applied_on_the_root(bpy, addon, tmp_path):
    K = [[800.0, 0, 399.5], [0, 800.0, 299.5], [0, 0, 1]]
    R = rotation(0.4, -0.1, 0.2)
    c = np.array([0.3, -1.0, 2.0])
    path = write_rig(tmp_path / "up.rig.json", [camera_dict("cam", (800, 600), K, R, c)])
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path), up_axis="-Y")
    M = np.array(addon.mapping.up_axis_matrix("-Y"))[:3, :3]
    X = points_in_view(K, R, c, (800, 600), 50, np.random.default_rng(1))
    got = blender_project(bpy, result.cameras["cam"], scene, (M @ X.T).T)  # Blender world = M camcal world
    assert np.abs(got - project_ref(K, R, c, X)).max() < 1e-3


def test_rectified_stereo_pair_is_parallel_stereo_3d(bpy, addon, tmp_path):
    K = [[900.0, 0, 650.0], [0, 900.0, 355.0], [0, 0, 1]]
    R = rotation(0.05, 0.3, -0.02)
    c_left = np.array([0.0, 0.0, 0.0])
    c_right = c_left + R.T @ [0.065, 0, 0]
    path = write_rig(tmp_path / "stereo.rig.json",
                     [camera_dict("left", (1280, 720), K, R, c_left), camera_dict("right", (1280, 720), K, R, c_right)])
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path))
    assert result.stereo_mode == "STEREO_3D"
    assert scene.render.use_multiview and scene.render.views_format == "STEREO_3D"
    left = result.cameras["left"]
    assert scene.camera == left
    stereo = left.data.stereo
    assert stereo.convergence_mode == "PARALLEL" and stereo.pivot == "LEFT"
    assert stereo.interocular_distance == pytest.approx(0.065, rel=1e-6)
    # Both cameras exact on their own.
    X = points_in_view(K, R, c_left, (1280, 720), 50, np.random.default_rng(2))
    for name, c in (("left", c_left), ("right", c_right)):
        err = np.abs(blender_project(bpy, result.cameras[name], scene, X) - project_ref(K, R, c, X)).max()
        assert err < 1e-3


def test_three_cameras_are_multiview(bpy, addon, tmp_path):
    K = [[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]]
    cams = [camera_dict(n, (640, 480), K, rotation(0, 0.2 * i, 0), (i * 0.5, 0, 0))
            for i, n in enumerate(["a", "b", "c"])]
    path = write_rig(tmp_path / "tri.rig.json", cams)
    scene = bpy.context.scene
    # A second import of the same rig keeps multi-view naming consistent.
    addon.import_rig(scene, str(path))
    result = addon.import_rig(scene, str(path))
    assert result.stereo_mode == "MULTIVIEW" and scene.render.views_format == "MULTIVIEW"
    views = {v.name: v for v in scene.render.views if v.use}
    assert set(views) == {"a", "b", "c"}
    base = scene.camera.name[: -len(views["a"].camera_suffix)]
    for name, view in views.items():
        assert result.cameras[name].name == base + view.camera_suffix


def test_frames_animate_the_rig_root(bpy, addon, tmp_path):
    K = [[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]]
    rng = np.random.default_rng(3)
    cams = [camera_dict("a", (640, 480), K, rotation(0.0, -0.1, 0.0), (-0.05, 0, 0)),
            camera_dict("b", (640, 480), K, rotation(0.0, 0.1, 0.0), (0.05, 0, 0))]
    frames = [frame(i, rotation(*rng.uniform(-3, 3, 3)), rng.uniform(-2, 2, 3)) for i in range(4)]
    path = write_rig(tmp_path / "seq.rig.json", cams, frames=frames)
    rig = Rig.load(path)
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path), frame_start=10, up_axis="-Y")
    assert (scene.frame_start, scene.frame_end) == (10, 13)
    M = np.array(addon.mapping.up_axis_matrix("-Y"))[:3, :3]
    for i in range(4):
        scene.frame_set(10 + i)
        for name in ("a", "b"):
            cam = rig.camera_at_frame(name, i)  # camcal's world pose of the camera at this frame
            X = points_in_view(cam.K, cam.R, cam.c, (640, 480), 30, rng)
            got = blender_project(bpy, result.cameras[name], scene, (M @ X.T).T)
            assert np.abs(got - cam.project(X)).max() < 1e-3


def _write_png(bpy, path, w, h):
    image = bpy.data.images.new("plate", w, h)
    image.filepath_raw = str(path)
    image.file_format = "PNG"
    image.save()
    bpy.data.images.remove(image)


def test_plates_points_and_lens_clip(bpy, addon, tmp_path):
    (tmp_path / "plates").mkdir()
    _write_png(bpy, tmp_path / "plates" / "left.png", 320, 240)
    _write_png(bpy, tmp_path / "plates" / "right.png", 320, 240)
    K = [[300.0, 0, 161.0], [0, 300.0, 118.0], [0, 0, 1]]
    division = {"model": "division", "params": {"lambda": -2e-6}, "center": [158.0, 121.0]}
    cams = [camera_dict("left", (320, 240), K, distortion=division),
            camera_dict("right", (320, 240), K, c=(0.2, 0, 0.01))]
    frames = [frame(0, images={"left": "plates/left.png", "right": "plates/right.png"})]
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    body = b"".join(struct.pack("<fffBBB", *p) for p in [(0, 0, 5, 255, 0, 0), (1, 0, 5, 0, 255, 0), (0, 1, 6, 0, 0, 255)])
    (tmp_path / "pts.ply").write_bytes(header + body)
    path = write_rig(tmp_path / "plates.rig.json", cams, frames=frames, points="pts.ply")
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path), aux_directory=str(tmp_path / "aux"))
    # Plates: the distorted camera shows its plate through the lens clip, undistorted.
    left, right = result.cameras["left"].data, result.cameras["right"].data
    assert left.show_background_images and left.background_images[0].source == "MOVIE_CLIP"
    assert left.background_images[0].clip_user.use_render_undistorted
    assert right.background_images[0].source == "IMAGE"
    assert right.background_images[0].image.filepath == str(tmp_path / "plates" / "right.png")
    assert right.background_images[0].image.colorspace_settings.name == "sRGB"  # no camcal OCIO config
    # The lens: NUKE model centred on the distortion centre.
    tc = result.clips["left"].tracking.camera
    assert tc.distortion_model == "NUKE"
    assert tc.nuke_k1 == pytest.approx(-2e-6 * 160 ** 2, rel=1e-6)
    assert tuple(tc.principal_point_pixels) == pytest.approx((158.5, 118.5), abs=1e-4)
    assert "right" not in result.clips
    # The distortion compositor scene, with the measured Movie Distortion offset.
    dist = result.distorted_scenes["left"]
    assert (dist.render.resolution_x, dist.render.resolution_y) == (320, 240)
    shift = list(dist["camcal_distortion_shift_px"])
    assert all(float(v).is_integer() and abs(v) <= 4 for v in shift)
    assert not [o.name for o in bpy.data.objects if "shift probe" in o.name]  # the measuring camera is removed
    # Points: a mesh of vertices with colours, under the rig root.
    mesh = result.points.data
    assert len(mesh.vertices) == 3 and result.points.parent == result.root
    assert tuple(mesh.vertices[2].co) == (0.0, 1.0, 6.0)
    assert tuple(mesh.color_attributes["Col"].data[1].color)[:3] == (0.0, 1.0, 0.0)


def test_rectified_import_uses_rectified_cameras(bpy, addon, tmp_path):
    K = np.array([[900.0, 0, 640.0], [0, 900.0, 360.0], [0, 0, 1]])
    R = rotation(0.0, 0.1, 0.0)
    Q = rotation(0.01, -0.02, 0.005)
    K_rect = np.array([[880.0, 0, 650.0], [0, 880.0, 370.0], [0, 0, 1]])
    rect = {"H": (K_rect @ Q @ np.linalg.inv(K)).tolist(), "K_rect": K_rect.tolist(), "image_size": [1300, 740]}
    cam = camera_dict("cam", (1280, 720), K, R, (0, 0, 0), rectification=rect,
                      distortion={"model": "division", "params": {"lambda": -1e-7}})
    path = write_rig(tmp_path / "rect.rig.json", [cam])
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path), use_rectified=True)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (1300, 740)
    assert not result.clips  # rectified cameras carry no distortion
    X = points_in_view(K_rect, Q @ R, [0, 0, 0], (1300, 740), 50, np.random.default_rng(4))
    err = np.abs(blender_project(bpy, result.cameras["cam"], scene, X) - project_ref(K_rect, Q @ R, [0, 0, 0], X))
    assert err.max() < 1e-3
    bpy.ops.wm.read_factory_settings(use_empty=True)
    path = write_rig(tmp_path / "norect.rig.json", [camera_dict("cam", (1280, 720), K)])
    with pytest.raises(addon.rigfile.RigFileError, match="no rectification"):
        addon.import_rig(bpy.context.scene, str(path), use_rectified=True)


def test_bad_inputs_raise_rig_file_errors(bpy, addon, tmp_path):
    with pytest.raises(addon.rigfile.RigFileError, match="cannot read rig file"):
        addon.import_rig(bpy.context.scene, str(tmp_path / "missing.rig.json"))
    K = [[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]]
    (tmp_path / "bad.ply").write_text("nope")
    path = write_rig(tmp_path / "p.rig.json", [camera_dict("a", (100, 80), K)], points="bad.ply")
    with pytest.raises(addon.rigfile.RigFileError, match="points: .*not a PLY file"):
        addon.import_rig(bpy.context.scene, str(path))
    assert len(bpy.data.objects) == 0 and len(bpy.data.cameras) == 0  # nothing half-built
