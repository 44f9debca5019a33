"""Blender (bpy, OCIO 2.5) reads the exported config: the camera space is listed and converts like OCIO."""

import numpy as np
import pytest

from camcal.io.ocio import export_ocio
from colour_export_helpers import blender_reads, make_fit


def test_blender_lists_and_converts_the_camera_space(tmp_path, sim):
    pytest.importorskip("bpy")  # only checks it is installed: bpy runs in a subprocess (OCIO set first)
    ocio = pytest.importorskip("PyOpenColorIO")
    fit = make_fit(sim, "root-polynomial:2")
    result = export_ocio([("nikon", fit)], tmp_path / "cfg", base="camcal")
    codes = np.random.default_rng(2).uniform(0.02, 0.98, (6, 8, 3))
    listed, blender = blender_reads(result.config_path, "camcal nikon", codes, tmp_path)
    assert "camcal nikon" in listed
    config = ocio.Config.CreateFromFile(str(result.config_path))
    cpu = config.getProcessor("camcal nikon", "scene_linear").getDefaultCPUProcessor()
    expected = np.ascontiguousarray(codes.reshape(-1, 3), dtype=np.float32)
    cpu.applyRGB(expected)
    # Blender links OCIO 2.5.0, this venv 2.6.0: same ops, float32 and fast-pow differences only
    np.testing.assert_allclose(blender, expected, atol=1e-4)
    assert np.abs(blender - codes.reshape(-1, 3)).max() > 0.05  # it did convert
