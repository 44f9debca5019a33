"""Plates get camcal's camera colour space when an exported OCIO config is active."""

import os
import subprocess
import sys
import textwrap

import pytest

from addon_helpers import camera_dict, frame, write_rig

K = [[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1]]


def _config_with_camera_space(path, camera):
    """A config like camcal's export: Blender's roles plus ``camcal <camera>`` in Input/camcal."""
    ocio = pytest.importorskip("PyOpenColorIO")
    config = ocio.Config.CreateFromBuiltinConfig("cg-config-v2.1.0_aces-v1.3_ocio-v2.3")
    space = ocio.ColorSpace(name=f"camcal {camera}", family="Input/camcal",
                            encoding="scene-linear")
    space.setTransform(ocio.MatrixTransform([0.9, 0.1, 0, 0, 0.05, 0.9, 0.05, 0, 0, 0.1, 0.9, 0, 0, 0, 0, 1]),
                       ocio.COLORSPACE_DIR_TO_REFERENCE)
    config.addColorSpace(space)
    config.validate()
    path.write_text(config.serialize())


@pytest.mark.parametrize("with_config", [True, False])
def test_plate_colour_space(tmp_path, with_config):
    pytest.importorskip("bpy")
    cfg = tmp_path / "camcal.ocio"
    if with_config:
        _config_with_camera_space(cfg, "left")
    rig = write_rig(tmp_path / "c.rig.json", [camera_dict("left", (320, 240), K), camera_dict("right", (320, 240), K, c=(1, 0, 0))],
                    frames=[frame(0, images={"left": "left.png", "right": "right.png"})])
    script = textwrap.dedent(
        f"""
        import bpy
        from camcal.blender_bridge import load_addon
        bpy.ops.wm.read_factory_settings(use_empty=True)
        for name in ("left", "right"):
            im = bpy.data.images.new(name, 320, 240)
            im.filepath_raw = {str(tmp_path)!r} + "/" + name + ".png"
            im.file_format = "PNG"
            im.save()
        addon = load_addon()
        result = addon.import_rig(bpy.context.scene, {str(rig)!r})
        for name in ("left", "right"):
            print(name, result.cameras[name].data.background_images[0].image.colorspace_settings.name)
        """
    )
    env = dict(os.environ)
    env.pop("OCIO", None)
    if with_config:
        env["OCIO"] = str(cfg)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if line.startswith(("left ", "right ")))
    if with_config:
        assert lines["left"] == "camcal left"
        assert lines["right"] != "camcal right"  # not in the config: left at the default
    else:
        assert lines == {"left": "sRGB", "right": "sRGB"}
