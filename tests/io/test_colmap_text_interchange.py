"""COLMAP text model export / import, read back by pycolmap."""

import dataclasses

import numpy as np
import pycolmap
import pytest

from camcal.base.errors import CamcalError
from camcal.model.camera import pixels_from_colmap
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.io.ply import read_points_ply
from camcal.model.rig import Rig

from interchange_rigs import division_rig, fisheye_rig, moving_rig, stereo_rig, world_points


def pycolmap_pixels(image, X):
    """Project world points with pycolmap's own camera and pose, in camcal's pixel convention."""
    cam_from_world = image.cam_from_world().matrix()
    in_camera = X @ cam_from_world[:, :3].T + cam_from_world[:, 3]
    return pixels_from_colmap(np.array([image.camera.img_from_cam(p) for p in in_camera]))


def test_moving_rig_read_by_pycolmap_projects_like_camcal(tmp_path):
    rig, rig_path = moving_rig(tmp_path)
    result = export_rig(rig, "colmap", tmp_path / "model", rig_path=rig_path)
    assert all(c.exact for c in result.conversions)
    reconstruction = pycolmap.Reconstruction(str(tmp_path / "model"))
    assert (len(reconstruction.cameras), len(reconstruction.images)) == (2, 2 * len(rig.frames))
    assert len(reconstruction.points3D) == 200
    points = read_points_ply(rig_path.parent / rig.points)
    stored = np.array(sorted((tuple(p.xyz) for p in reconstruction.points3D.values())))
    assert np.array_equal(stored, np.array(sorted(zip(points["x"], points["y"], points["z"]))))
    worst = 0.0
    for image in reconstruction.images.values():
        camera_name, frame = image.name.split("/")
        posed = rig.camera_at_frame(camera_name, int(frame))
        X, pixels = world_points(rig, posed)
        worst = max(worst, np.abs(pycolmap_pixels(image, X) - pixels).max())
    print(f"pycolmap vs camcal projection over {len(reconstruction.images)} images: {worst:.2e} px")
    assert worst < 1e-9


def test_round_trip_is_exact(tmp_path):
    rig = stereo_rig(rectified=False)
    export_rig(rig, "colmap", tmp_path / "model")
    back = import_rig(tmp_path / "model", "colmap").rig
    assert [c.name for c in back.cameras] == ["left", "right"]
    for a, b in zip(rig.cameras, back.cameras):
        X, _ = world_points(rig, a)
        assert np.abs(a.project(X) - b.project(X)).max() < 1e-9
        assert np.abs(a.K - b.K).max() < 1e-12


def test_skew_and_off_centre_division_are_fitted_within_the_printed_residual(tmp_path):
    rig = division_rig()
    (conversion,) = export_rig(rig, "colmap", tmp_path / "model").conversions
    assert not conversion.exact and conversion.target.startswith("COLMAP ")
    image = next(iter(pycolmap.Reconstruction(str(tmp_path / "model")).images.values()))
    X, pixels = world_points(rig, rig.cameras[0], n=3000)
    observed = np.abs(pycolmap_pixels(image, X) - pixels).max()
    print(f"division + skew -> {conversion.target}: printed {conversion.max_px:.3g} px, pycolmap observed {observed:.3g} px")
    assert observed <= conversion.max_px * 1.05
    back = import_rig(tmp_path / "model", "colmap").rig
    assert max_pixel_residual(rig.cameras[0], back.cameras[0]) == pytest.approx(conversion.max_px, rel=1e-6)


def test_fisheye_is_opencv_fisheye_exactly_and_pycolmap_projects_it_like_camcal(tmp_path):
    rig = fisheye_rig(rectified=False)
    result = export_rig(rig, "colmap", tmp_path / "model")
    assert all(c.exact and c.target == "COLMAP OPENCV_FISHEYE" for c in result.conversions)
    reconstruction = pycolmap.Reconstruction(str(tmp_path / "model"))
    worst = 0.0
    for image in reconstruction.images.values():
        camera = rig.camera(image.name)
        assert image.camera.model.name == "OPENCV_FISHEYE"
        X, pixels = world_points(rig, camera, n=500)
        worst = max(worst, np.abs(pycolmap_pixels(image, X) - pixels).max())
    print(f"pycolmap OPENCV_FISHEYE vs camcal kannala-brandt: {worst:.1e} px")
    assert worst < 1e-9
    back = import_rig(tmp_path / "model", "colmap").rig
    assert [c.distortion for c in back.cameras] == [c.distortion for c in rig.cameras]
    for a, b in zip(rig.cameras, back.cameras):
        X, _ = world_points(rig, a)
        assert np.abs(a.project(X) - b.project(X)).max() < 1e-9
    # skew: dropped, the fisheye stays a fisheye (not fitted with a pinhole lens), the residual printed
    K = rig.cameras[0].K.copy()
    K[0, 1] = 0.6
    skewed = Rig((dataclasses.replace(rig.cameras[0], K=K),))
    (conversion,) = export_rig(skewed, "colmap", tmp_path / "skewed").conversions
    assert conversion.target == "COLMAP OPENCV_FISHEYE" and not conversion.exact and 0 < conversion.max_px < 1.0


@pytest.mark.parametrize("cameras, images, message", [
    ("1 PINHOLE 640 480 500 500 320\n", "1 1 0 0 0 0 0 0 1 a.png\n\n", "PINHOLE takes 4 parameters"),
    ("1 PINHOLE 640 480 500 nan 320 240\n", "1 1 0 0 0 0 0 0 1 a.png\n\n", "NaN"),
    ("1 PINHOLE 640 480 500 500 320 240\n", "1 1 0 0 0 0 0 0 2 a.png\n\n", "camera 2 is not in cameras.txt"),
    ("1 FOV 640 480 500 500 320 240 0.1\n", "1 1 0 0 0 0 0 0 1 a.png\n\n", "no camcal counterpart"),
    ("1 PINHOLE 640 480 500 500 320 240\n", "", "holds no image"),
])
def test_bad_input_is_one_line(tmp_path, cameras, images, message):
    (tmp_path / "cameras.txt").write_text(cameras)
    (tmp_path / "images.txt").write_text(images)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(tmp_path, "colmap")
    assert "\n" not in str(info.value)


def test_a_binary_model_is_named(tmp_path):
    (tmp_path / "cameras.bin").write_bytes(b"\0")
    with pytest.raises(CamcalError, match="model_converter"):
        import_rig(tmp_path, "colmap")
