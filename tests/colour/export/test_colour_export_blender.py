"""Blender (bpy, OCIO 2.4) reads the exported config: the camera space is listed and converts like OCIO."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from camcal.io.ocio import export_ocio
from colour_export_helpers import make_fit

SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import bpy
    args = json.loads(sys.argv[1])
    items = bpy.types.ColorManagedInputColorspaceSettings.bl_rna.properties["name"].enum_items
    print("CAMCAL_LISTED " + json.dumps([i.identifier for i in items]))
    codes = np.asarray(args["codes"], dtype=np.float32)
    H, W = codes.shape[:2]
    image = bpy.data.images.new("codes", W, H, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Raw"
    pixels = np.ones((H, W, 4), np.float32)
    pixels[..., :3] = codes
    image.pixels.foreach_set(pixels.ravel())
    image.filepath_raw = args["exr"]
    image.file_format = "OPEN_EXR"
    image.save()
    plate = bpy.data.images.load(args["exr"])
    plate.colorspace_settings.name = args["space"]
    plate.reload()
    out = np.empty(H * W * 4, np.float32)
    plate.pixels.foreach_get(out)
    print("CAMCAL_PIXELS " + json.dumps(out.reshape(H, W, 4)[..., :3].tolist()))
    """
)


def test_blender_lists_and_converts_the_camera_space(tmp_path, sim):
    pytest.importorskip("bpy")  # only checks it is installed: bpy runs in a subprocess (OCIO set first)
    ocio = pytest.importorskip("PyOpenColorIO")
    fit = make_fit(sim, "root-polynomial:2")
    result = export_ocio([("nikon", fit)], tmp_path / "cfg", base="camcal")
    codes = np.random.default_rng(2).uniform(0.02, 0.98, (6, 8, 3))
    args = {"codes": codes.tolist(), "exr": str(tmp_path / "codes.exr"), "space": "camcal nikon"}
    env = dict(os.environ, OCIO=str(result.config_path))
    proc = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(args)], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = {line.split(" ", 1)[0]: json.loads(line.split(" ", 1)[1]) for line in proc.stdout.splitlines()
             if line.startswith("CAMCAL_")}
    assert "camcal nikon" in lines["CAMCAL_LISTED"]
    blender = np.asarray(lines["CAMCAL_PIXELS"]).reshape(-1, 3)
    config = ocio.Config.CreateFromFile(str(result.config_path))
    cpu = config.getProcessor("camcal nikon", "scene_linear").getDefaultCPUProcessor()
    expected = np.ascontiguousarray(codes.reshape(-1, 3), dtype=np.float32)
    cpu.applyRGB(expected)
    # Blender links OCIO 2.4.2, this venv 2.6.0: same ops, float32 and fast-pow differences only
    np.testing.assert_allclose(blender, expected, atol=1e-4)
    assert np.abs(blender - codes.reshape(-1, 3)).max() > 0.05  # it did convert
