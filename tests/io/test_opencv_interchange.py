"""OpenCV FileStorage export / import, checked with OpenCV's own reader and stereoRectify."""

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.rig import Rig

from interchange_rigs import division_rig, fisheye_rig, relative_projection_error, stereo_rig, world_points


def undistort_points(x, K, D, R, P):
    """cv2.undistortPoints iterated to convergence (OpenCV 4: undistortPointsIter; 5: a criteria argument)."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(x.reshape(-1, 1, 2), K, D, R, P, criteria).reshape(-1, 2)
    return cv2.undistortPoints(x.reshape(-1, 1, 2), K, D, R=R, P=P, criteria=criteria).reshape(-1, 2)


@pytest.mark.parametrize("suffix", [".yaml", ".yml", ".xml"])
def test_stereo_round_trip_is_exact_and_opencv_reads_it(tmp_path, suffix):
    rig = stereo_rig()
    out = tmp_path / f"stereo{suffix}"
    result = export_rig(rig, "opencv", out)
    assert all(c.exact for c in result.conversions) and result.paths == (out,)
    back = import_rig(out, "opencv").rig
    assert relative_projection_error(rig, back) < 1e-9
    for a, b in zip(rig.cameras, back.cameras):
        H_a, H_b = a.rectification.H, b.rectification.H
        corners = np.array([[0, 0, 1], [1279, 0, 1], [0, 719, 1], [1279, 719, 1]], float)
        pa, pb = corners @ H_a.T, corners @ H_b.T
        assert np.abs(pa[:, :2] / pa[:, 2:] - pb[:, :2] / pb[:, 2:]).max() < 1e-9
        assert np.array_equal(a.rectification.K_rect, b.rectification.K_rect)
        assert a.rectification.image_size == b.rectification.image_size
    # OpenCV's own reader: the names and shapes stereo_calib.cpp writes
    storage = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    shapes = {key: storage.getNode(key).mat().shape for key in ("K1", "D1", "K2", "D2", "R", "T", "E", "F",
                                                                  "R1", "R2", "P1", "P2", "Q")}
    assert shapes == {"K1": (3, 3), "D1": (1, 5), "K2": (3, 3), "D2": (1, 5), "R": (3, 3), "T": (3, 1), "E": (3, 3),
                      "F": (3, 3), "R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}
    # E and F hold the epipolar constraint of points both cameras see
    left, right = rig.cameras
    X, _ = world_points(rig, left)
    x1 = left.distortion.undistort(left.project(X), left.K)
    x2 = right.distortion.undistort(right.project(X), right.K)
    F = storage.getNode("F").mat()
    lines = np.column_stack([x1, np.ones(len(x1))]) @ F.T
    distance = np.abs(np.sum(lines * np.column_stack([x2, np.ones(len(x2))]), axis=1)) / np.hypot(lines[:, 0], lines[:, 1])
    assert distance.max() < 1e-6


def test_opencv_rectifies_the_imported_pair_like_camcal(tmp_path):
    rig = stereo_rig()
    out = tmp_path / "stereo.yaml"
    export_rig(rig, "opencv", out)
    storage = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    K1, D1, K2, D2, R, T, R1, R2, P1, P2 = (storage.getNode(k).mat() for k in
                                             ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2"))
    size = (int(storage.getNode("image_width").real()), int(storage.getNode("image_height").real()))
    left, right = rig.cameras
    X, _ = world_points(rig, left, n=300)
    inside = [np.all((p > 0) & (p < np.array(size) - 1), axis=1) for p in (left.project(X), right.project(X))]
    X = X[inside[0] & inside[1]]
    x1, x2 = left.project(X), right.project(X)
    # 1. the file's own R1 P1 R2 P2 through OpenCV's undistortPoints give camcal's rectified pixels
    ours = [c.rectification.H for c in rig.cameras]
    for x, Kc, D, Rr, P, H, camera in ((x1, K1, D1, R1, P1, ours[0], left), (x2, K2, D2, R2, P2, ours[1], right)):
        cv_rect = undistort_points(x, Kc, D, Rr, P)
        ideal = camera.distortion.undistort(x, camera.K)
        mapped = np.column_stack([ideal, np.ones(len(ideal))]) @ H.T
        assert np.abs(cv_rect - mapped[:, :2] / mapped[:, 2:]).max() < 0.01
    # 2. cv2.stereoRectify on the imported K, D, R, T chooses camcal's rectifying rotations (the
    #    rotation nearest the cameras' mean one), so with the file's P1 P2 it gives camcal's rectified
    #    pixels; with its own P1 P2 (its zoom and frame) the same up to that affine change of frame
    R1_cv, R2_cv, P1_cv, P2_cv, *_ = cv2.stereoRectify(K1, D1, K2, D2, size, R, T, alpha=0.0)
    angles = [np.degrees(Rotation.from_matrix(a @ b.T).magnitude()) for a, b in ((R1_cv, R1), (R2_cv, R2))]
    worst = {"file P": 0.0, "OpenCV P": 0.0}
    for x, Kc, D, Rr, P, P_cv, H, camera in ((x1, K1, D1, R1_cv, P1, P1_cv, ours[0], left),
                                              (x2, K2, D2, R2_cv, P2, P2_cv, ours[1], right)):
        mapped = np.column_stack([camera.distortion.undistort(x, camera.K), np.ones(len(x))]) @ H.T
        camcal_rect = mapped[:, :2] / mapped[:, 2:]
        worst["file P"] = max(worst["file P"], np.abs(undistort_points(x, Kc, D, Rr, P) - camcal_rect).max())
        cv_rect = undistort_points(x, Kc, D, Rr, P_cv)
        to_ours = P[:, :3] @ np.linalg.inv(P_cv[:, :3])  # OpenCV's rectified frame -> camcal's (affine)
        moved = np.column_stack([cv_rect, np.ones(len(cv_rect))]) @ to_ours.T
        worst["OpenCV P"] = max(worst["OpenCV P"], np.abs(moved[:, :2] / moved[:, 2:] - camcal_rect).max())
    print(f"cv2.stereoRectify vs camcal: rotations {angles[0]:.1e}, {angles[1]:.1e} deg apart; rectified pixels "
          f"{worst['file P']:.1e} px (file's P), {worst['OpenCV P']:.1e} px (OpenCV's P, moved to camcal's frame)")
    assert max(angles) < 1e-9
    assert worst["file P"] < 0.01 and worst["OpenCV P"] < 0.01


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_fisheye_pair_is_exact_and_cv2_fisheye_reads_it(tmp_path, suffix):
    rig = fisheye_rig()
    out = tmp_path / f"fisheye{suffix}"
    result = export_rig(rig, "opencv", out)
    assert all(c.exact and c.target == "opencv fisheye (k1 k2 k3 k4)" for c in result.conversions)
    back = import_rig(out, "opencv").rig
    assert [c.distortion for c in back.cameras] == [c.distortion for c in rig.cameras]
    assert relative_projection_error(rig, back) < 1e-9
    storage = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    assert storage.getNode("fisheye_model").real() == 1
    K1, D1, K2, D2, R, T, R1, R2, P1, P2 = (storage.getNode(k).mat() for k in
                                             ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2"))
    assert D1.shape == D2.shape == (1, 4)
    size = (int(storage.getNode("image_width").real()), int(storage.getNode("image_height").real()))
    # cv2.fisheye projects with the file's K and D like camcal, over a ~150 deg field
    worst_projection = worst_rectified = 0.0
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    for camera, Kc, D, Rr, P in zip(rig.cameras, (K1, K2), (D1, D2), (R1, R2), (P1, P2)):
        X, pixels = world_points(rig, camera, n=500)
        in_camera = (X - camera.c) @ camera.R.T
        projected, _ = cv2.fisheye.projectPoints(in_camera.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), Kc, D)
        worst_projection = max(worst_projection, np.abs(projected.reshape(-1, 2) - pixels).max())
        # and its undistortPoints with the file's R_i, P_i gives camcal's rectified pixels
        rectified = cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2), Kc, D, R=Rr, P=P, criteria=criteria)
        mapped = np.column_stack([camera.distortion.undistort(pixels, camera.K), np.ones(len(pixels))]) @ \
            camera.rectification.H.T
        worst_rectified = max(worst_rectified, np.abs(rectified.reshape(-1, 2) - mapped[:, :2] / mapped[:, 2:]).max())
    # cv2.fisheye.stereoRectify on the imported pair chooses the same rectifying rotations
    R1_cv, R2_cv, *_ = cv2.fisheye.stereoRectify(K1, D1, K2, D2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY)
    angles = [np.degrees(Rotation.from_matrix(a @ b.T).magnitude()) for a, b in ((R1_cv, R1), (R2_cv, R2))]
    print(f"cv2.fisheye vs camcal: projection {worst_projection:.1e} px, rectified pixels {worst_rectified:.1e} px, "
          f"stereoRectify rotations {max(angles):.1e} deg apart")
    assert worst_projection < 1e-9 and worst_rectified < 1e-6 and max(angles) < 1e-9


def test_fisheye_with_skew_and_mixed_pairs(tmp_path):
    left, right = fisheye_rig(rectified=False).cameras
    K = left.K.copy()
    K[0, 1] = 0.6
    skewed = Rig((dataclasses.replace(left, K=K),))
    (conversion,) = export_rig(skewed, "opencv", tmp_path / "skew.yaml").conversions
    assert not conversion.exact and conversion.loss == "nearest fit"
    storage = cv2.FileStorage(str(tmp_path / "skew.yaml"), cv2.FILE_STORAGE_READ)
    K_file, D_file = storage.getNode("camera_matrix").mat(), storage.getNode("distortion_coefficients").mat()
    X, pixels = world_points(skewed, skewed.cameras[0], n=2000)
    in_camera = (X - left.c) @ left.R.T
    projected, _ = cv2.fisheye.projectPoints(in_camera.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_file, D_file)
    observed = np.abs(projected.reshape(-1, 2) - pixels).max()
    print(f"fisheye with skew 0.6 -> cv2.fisheye without: printed {conversion.max_px:.3g} px, observed {observed:.3g} px")
    assert K_file[0, 1] == 0.0 and 0.0 < observed <= conversion.max_px * 1.05
    mixed = Rig((left, dataclasses.replace(right, distortion=stereo_rig().cameras[1].distortion)))
    with pytest.raises(CamcalError, match="two cv2.fisheye lenses or two pinhole lenses"):
        export_rig(mixed, "opencv", tmp_path / "mixed.yaml")
    assert not (tmp_path / "mixed.yaml").exists()


def test_single_camera_and_lossy_division_lens_with_skew(tmp_path, capsys):
    rig = division_rig()
    out = tmp_path / "wide.yml"
    result = export_rig(rig, "opencv", out)
    (conversion,) = result.conversions
    assert not conversion.exact and 0 < conversion.max_px < 2.0
    storage = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    K = storage.getNode("camera_matrix").mat()
    D = storage.getNode("distortion_coefficients").mat()
    assert K[0, 1] == 0.0 and D.shape == (1, 5)
    assert (storage.getNode("image_width").real(), storage.getNode("image_height").real()) == (1280, 720)
    # the printed residual is OpenCV's projection against camcal's, over the frame
    camera = rig.cameras[0]
    X, pixels = world_points(rig, camera, n=2000)
    cv_pixels, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)
    observed = np.abs(cv_pixels.reshape(-1, 2) - pixels).max()
    assert observed <= conversion.max_px * 1.05 + 1e-6
    back = import_rig(out, "opencv").rig
    assert max_pixel_residual(camera, back.cameras[0]) == pytest.approx(conversion.max_px, rel=1e-6)


@pytest.mark.parametrize("text, message", [
    ("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n", "no camera_matrix"),
    ("%YAML:1.0\n---\nK1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 1., 0., 1., 1., 0., 0., 1. ]\n"
     "D1: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\nimage_width: 640\nimage_height: 480\n",
     "missing K2, D2, R, T"),
    ("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     "   data: [ .Nan, 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n"
     "   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n", "camera_matrix contains NaN"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n"
     "   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n", "no image size"),
    ("this is not yaml: [", "not an OpenCV FileStorage file"),
    ("%YAML:1.0\n---\nfisheye_model: 1\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n"
     "   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n"
     "   rows: 1\n   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n", "a cv2.fisheye lens .fisheye_model: 1. has 4"),
    ("%YAML:1.0\n---\nfisheye_model: 2\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n"
     "   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n"
     "   rows: 1\n   cols: 4\n   dt: d\n   data: [ 0., 0., 0., 0. ]\n", "fisheye_model must be 0 or 1"),
])
def test_bad_input_is_one_line(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "opencv")
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_export_refuses_what_it_cannot_hold_and_writes_nothing(tmp_path):
    rig = stereo_rig()
    with pytest.raises(CamcalError, match="must end in"):
        export_rig(rig, "opencv", tmp_path / "stereo.json")
    three = Rig(rig.cameras + (rig.cameras[0].__class__("third", *[getattr(rig.cameras[0], f) for f in
                                                                   ("image_size", "K", "distortion", "R")],
                                                                   c=[0.5, 0.0, 0.0]),))
    with pytest.raises(CamcalError, match="one camera or a stereo pair; the rig has 3"):
        export_rig(three, "opencv", tmp_path / "three.yaml")
    assert list(tmp_path.iterdir()) == []
    single = export_rig(three, "opencv", tmp_path / "third.yaml", cameras=["third"])
    assert single.paths == (tmp_path / "third.yaml",)
