"""OpenCV files with 4, 5, 8, 12 and 14 distortion coefficients: read, projected and written as OpenCV does."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.interchange import export_rig, import_rig
from camcal.model.rig import Rig

K = np.array([[812.5, 0.0, 643.25], [0.0, 797.75, 471.5], [0.0, 0.0, 1.0]])
#: a wide lens in OpenCV's order k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tauX tauY (tilt zero)
COEFFICIENTS = np.array([-0.31, 0.115, 8e-4, -1.2e-3, -0.021, 0.19, 0.043, 0.008, 1.1e-3, -4e-4, 1.6e-3, 2e-4, 0.0, 0.0])


def write_camera(path, D):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 1280)
    storage.write("image_height", 960)
    storage.write("camera_matrix", K)
    storage.write("distortion_coefficients", D.reshape(1, -1))
    storage.release()


def read_coefficients(path):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        return storage.getNode("distortion_coefficients").mat()
    finally:
        storage.release()


def points_in_view(n=3000, seed=0):
    """Points whose pinhole image covers the frame and some margin beyond."""
    rng = np.random.default_rng(seed)
    u = rng.uniform([-80, -60], [1360, 1020], (n, 2))
    depth = rng.uniform(0.5, 20.0, (n, 1))
    xy = (u - K[:2, 2]) / np.diag(K)[:2]
    return np.column_stack([xy, np.ones(n)]) * depth


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_projection_equals_cv2_project_points(tmp_path, n):
    D = COEFFICIENTS[:n].copy()
    write_camera(tmp_path / "lens.yaml", D)
    camera = import_rig(tmp_path / "lens.yaml", "opencv").rig.cameras[0]
    X = points_in_view()
    expected = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    assert np.abs(camera.project(X) - expected).max() < 1e-9
    # and back out: the shortest OpenCV vector that holds the lens, equal to the file's
    result = export_rig(Rig((camera,)), "opencv", tmp_path / "out.yaml")
    assert result.conversions[0].exact
    written = read_coefficients(tmp_path / "out.yaml")
    length = {4: 5, 5: 5, 8: 8, 12: 12, 14: 12}[n]
    assert written.shape == (1, length)
    assert np.array_equal(written.ravel()[:min(n, length)], D[:min(n, length)])
    again = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, written)[0].reshape(-1, 2)
    assert np.abs(again - expected).max() < 1e-9


def test_undistort_inverts_the_rational_thin_prism_lens(tmp_path):
    write_camera(tmp_path / "lens.yaml", COEFFICIENTS[:12])
    camera = import_rig(tmp_path / "lens.yaml", "opencv").rig.cameras[0]
    # the lens is one-to-one up to the radius where r_d(r) stops growing; sample within 0.9 of it
    radius = np.linspace(0.0, 3.0, 3001)
    r_d = np.linalg.norm(camera.distortion.distort_normalised(np.column_stack([radius, radius]) / np.sqrt(2)), axis=1)
    reach = radius[np.argmax(np.diff(r_d) <= 0)]
    rng = np.random.default_rng(1)
    angle, r = rng.uniform(0, 2 * np.pi, 4000), 0.9 * reach * np.sqrt(rng.uniform(0, 1, 4000))
    ideal = np.column_stack([r * np.cos(angle), r * np.sin(angle)]) * np.diag(K)[:2] + K[:2, 2]
    distorted = camera.distortion.distort(ideal, K)
    assert np.abs(camera.distortion.undistort(distorted, K) - ideal).max() < 1e-9


def test_cli_round_trip_through_opencv(tmp_path, capsys):
    write_camera(tmp_path / "lens.yml", COEFFICIENTS[:12])
    assert main(["rig", "import", str(tmp_path / "lens.yml"), "--from", "opencv", "--out", str(tmp_path / "l.rig.json")]) == 0
    rig = Rig.load(tmp_path / "l.rig.json")
    assert rig.cameras[0].distortion.opencv_terms == 12
    assert main(["rig", "export", str(tmp_path / "l.rig.json"), "--to", "opencv", str(tmp_path / "back.yml")]) == 0
    assert "opencv (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4)" in capsys.readouterr().out
    written = read_coefficients(tmp_path / "back.yml")
    assert np.array_equal(written.ravel(), COEFFICIENTS[:12])


def test_tilt_is_refused_in_one_line(tmp_path):
    D = COEFFICIENTS.copy()
    D[12:] = [0.01, -0.02]
    write_camera(tmp_path / "tilted.yaml", D)
    with pytest.raises(CamcalError, match="tilt terms tauX = 0.01, tauY = -0.02") as info:
        import_rig(tmp_path / "tilted.yaml", "opencv")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("n", [3, 6, 13])
def test_other_lengths_are_refused(tmp_path, n):
    write_camera(tmp_path / "odd.yaml", np.zeros(n))
    with pytest.raises(CamcalError, match=f"4, 5, 8, 12 or 14 coefficients, got {n}"):
        import_rig(tmp_path / "odd.yaml", "opencv")
