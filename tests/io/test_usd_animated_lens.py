"""A zoom in USD: focal length, apertures and their offsets sampled per frame, checked with pxr's Gf.Camera, read back."""

import numpy as np
from pxr import Usd, UsdGeom

from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

from interchange_rigs import BROWN, SIZE, K, world_points, zoom_rig
from test_usd_interchange import gf_pixels, ideal_pixels


def brown_per_zoom(distortion, zoom):
    return Distortion("opencv", {**distortion.params, "k1": distortion.params["k1"] / zoom})


def test_zoom_is_sampled_per_frame_and_reads_back(tmp_path):
    camera = Camera("cam", SIZE, K(1010.0, 1008.0, 652.3, 351.7), BROWN, np.eye(3), np.zeros(3), sensor_width_mm=24.0)
    rig = zoom_rig(camera, zooms=(1.0, 1.2, 1.5, 1.8), scale_lens=brown_per_zoom)
    out = tmp_path / "zoom.usda"
    [conversion] = export_rig(rig, "usd", out).conversions
    stage = Usd.Stage.Open(str(out))
    focal = UsdGeom.Camera(stage.GetPrimAtPath("/rig/cam")).GetFocalLengthAttr()
    assert focal.GetTimeSamples() == [1001.0, 1002.0, 1003.0, 1004.0]
    worst = 0.0
    for frame in rig.frames:
        posed = rig.camera_at_frame("cam", frame.index)
        X, _ = world_points(rig, rig.camera("cam"), n=100)
        X = X @ frame.R + frame.c  # rig -> world
        worst = max(worst, np.abs(gf_pixels(stage, "cam", Usd.TimeCode(frame.index), X, SIZE)
                                  - ideal_pixels(posed, X)).max())
    print(f"Gf.Camera per frame vs camcal: {worst:.2e} px (printed {conversion.max_px:.2e} px, 32-bit floats)")
    assert worst < 1e-3 and conversion.max_px < 1e-3
    back = import_rig(out, "usd").rig
    assert [f.index for f in back.frames] == [1001, 1002, 1003, 1004]
    for frame in rig.frames:
        original, read = rig.camera_at_frame("cam", frame.index), back.camera_at_frame("cam", frame.index)
        assert max_pixel_residual(original, read) < 1e-6
        assert np.abs(original.c - read.c).max() < 1e-9
    assert [(f.lenses["cam"].focal_mm, f.lenses["cam"].focus_m) for f in back.frames[1:]] == [
        (24.0 * z, 2.0 + i) for i, z in enumerate((1.2, 1.5, 1.8), start=1)]


def test_a_static_camera_with_a_sampled_lens_reads_as_frames_at_the_origin(tmp_path):
    """Another tool's zoom: a camera that does not move, focal length sampled; no camcal customData."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "zoom.usda"))
    camera = UsdGeom.Camera.Define(stage, "/cam")
    camera.CreateHorizontalApertureAttr(36.0)
    camera.CreateVerticalApertureAttr(24.0)
    for time, focal in ((10, 35.0), (11, 50.0)):
        camera.CreateFocalLengthAttr().Set(focal, Usd.TimeCode(time))
    stage.Save()
    back = import_rig(tmp_path / "zoom.usda", "usd", image_size=(600, 400)).rig
    assert [f.index for f in back.frames] == [10, 11]
    for index, focal in ((10, 35.0), (11, 50.0)):
        assert back.camera_at_frame("cam", index).K[0, 0] == focal * 600 / 36.0


def test_formats_with_one_lens_per_camera_say_the_zoom_is_not_written(tmp_path):
    camera = Camera("cam", SIZE, K(1010.0, 1008.0, 652.3, 351.7), BROWN, np.eye(3), np.zeros(3))
    rig = zoom_rig(camera, scale_lens=brown_per_zoom)
    notes = export_rig(rig, "opencv", tmp_path / "cam.yaml").notes
    assert any("per-frame lenses of cam are not written" in note for note in notes)
    assert not any("per-frame" in note for note in export_rig(rig, "usd", tmp_path / "cam.usda").notes)


def test_a_zooms_st_maps_are_referenced_as_a_sequence(tmp_path):
    camera = Camera("cam", (96, 64), K(90.0, 90.0, 47.5, 31.5), BROWN, np.eye(3), np.zeros(3))
    rig = zoom_rig(camera, scale_lens=brown_per_zoom)
    result = export_rig(rig, "usd", tmp_path / "zoom.usda", stmaps=True)
    assert sorted(p.name for p in result.paths if p.suffix == ".exr") == sorted(
        f"cam_{kind}.{index:04d}.exr" for kind in ("undistort", "redistort") for index in (1001, 1002, 1003))
    stage = Usd.Stage.Open(str(tmp_path / "zoom.usda"))
    prim = stage.GetPrimAtPath("/rig/cam")
    assert prim.GetCustomDataByKey("camcal:stmap_undistort").path == "zoom_stmaps/cam_undistort.%04d.exr"
