"""A camera's sigma map as its background overlay: the pure size checks and the bpy operator."""

import importlib

import numpy as np
import pytest

from addon_helpers import camera_dict, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.io.stmap import write_sigma_map
from camcal.report.sigma import heatmap_image, write_heatmap_png

K = [[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]]


def _ramp(width=320, height=240):
    y, x = np.mgrid[0:height, 0:width]
    return (0.05 + 0.001 * x + 0.0005 * y).astype(np.float32)


def test_overlay_reads_the_size_of_camcal_maps(addon, tmp_path):
    overlay = importlib.import_module(f"{addon.__name__}.overlay")
    sigma = _ramp()
    png = write_heatmap_png(sigma, tmp_path / "s.png")
    exr = write_sigma_map(tmp_path / "s.exr", sigma)
    assert overlay.image_size(png) == (320, 240) and overlay.image_size(exr) == (320, 240)
    assert overlay.sigma_max(png) == pytest.approx(float(sigma.max()), rel=1e-5)
    assert overlay.sigma_max(exr) is None
    assert overlay.check_overlay(str(png), (320, 240)) == (320, 240)
    with pytest.raises(overlay.OverlayError, match="lines up only with its own camera"):
        overlay.check_overlay(str(exr), (640, 480))
    (tmp_path / "x.txt").write_text("not an image")
    with pytest.raises(overlay.OverlayError, match="not a PNG or OpenEXR"):
        overlay.image_size(tmp_path / "x.txt")


@pytest.fixture
def registered(bpy, addon):
    addon.register()
    yield bpy
    addon.unregister()


def test_sigma_overlay_operator_shows_the_map_pixel_for_pixel(registered, addon, tmp_path):
    bpy = registered
    path = write_rig(tmp_path / "o.rig.json", [camera_dict("a", (320, 240), K)])
    addon.import_rig(bpy.context.scene, str(path))
    camera = bpy.data.objects["o_a"]
    sigma = _ramp()
    png = write_heatmap_png(sigma, tmp_path / "a_sigma.png")
    for _ in range(2):  # shown twice: one sigma overlay, replaced
        assert bpy.ops.camcal.sigma_overlay(filepath=str(png), camera=camera.name, alpha=0.5) == {"FINISHED"}
    overlays = [bg for bg in camera.data.background_images if bg.image is not None
                and bg.image.get("camcal_overlay") == "camcal sigma"]
    assert len(overlays) == 1 and camera.data.show_background_images
    bg = overlays[0]
    assert bg.alpha == pytest.approx(0.5) and bg.display_depth == "FRONT" and bg.frame_method == "STRETCH"
    image = bg.image
    assert tuple(image.size) == (320, 240)
    assert image["camcal_sigma_max_px"] == pytest.approx(float(sigma.max()), rel=1e-5)
    # Blender's pixels run bottom-up, RGBA floats: the top-left plate pixel is the last row's first
    pixels = np.array(image.pixels[:]).reshape(240, 320, 4)[::-1]
    expected = heatmap_image(sigma)
    for y, x in ((0, 0), (120, 200), (239, 319)):
        assert np.allclose(pixels[y, x, :3] * 255, expected[y, x], atol=1.0)
    # a map of another camera's size is refused
    other = write_heatmap_png(_ramp(160, 120), tmp_path / "small.png")
    with pytest.raises(RuntimeError, match="lines up only with its own camera"):
        bpy.ops.camcal.sigma_overlay(filepath=str(other), camera=camera.name)


def test_sigma_overlay_operator_shows_an_exr_with_its_sigma_values(registered, addon, tmp_path):
    """The EXR (``camcal sigma --out``, ``stmap --sigma``) as the overlay: Non-Color, its floats kept pixel for
    pixel (Blender's rows bottom-up), no colour-scale top (that is the PNG's)."""
    bpy = registered
    path = write_rig(tmp_path / "e.rig.json", [camera_dict("a", (320, 240), K)])
    addon.import_rig(bpy.context.scene, str(path))
    camera = bpy.data.objects["e_a"]
    sigma = _ramp()
    sigma[10:20, 30:40] = np.nan  # no source pixel
    exr = write_sigma_map(tmp_path / "a_sigma.exr", sigma)
    assert bpy.ops.camcal.sigma_overlay(filepath=str(exr), camera=camera.name, alpha=0.4) == {"FINISHED"}
    (bg,) = [bg for bg in camera.data.background_images if bg.image is not None]
    image = bg.image
    assert image.colorspace_settings.name == "Non-Color" and "camcal_sigma_max_px" not in image
    assert tuple(image.size) == (320, 240) and bg.alpha == pytest.approx(0.4)
    pixels = np.array(image.pixels[:]).reshape(240, 320, 4)[::-1, :, 0]
    finite = np.isfinite(sigma)
    assert np.allclose(pixels[finite], sigma[finite], rtol=1e-6)
