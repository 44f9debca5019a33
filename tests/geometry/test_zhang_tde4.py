"""Board calibration with 3DE's lens models: a 2x anamorphic lens recovered from synthetic board views."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.tde4_fit import FITTED_PARAMS, MAX_ROTATION_SIGMA_DEG
from camcal.geometry.zhang import calibrate_board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

BOARD = Board("chessboard", 12, 9, 0.04)
SIGMA_PX = 0.1
W, H = 1920, 1080
#: A 2x anamorphic: fy = 2 fx (pixel aspect 2), its LDPK lens with every degree-2 and degree-4 term.
TRUTH = Camera("anamorphic", (W, H), [[700.0, 0.0, 972.0], [0.0, 1400.0, 530.0], [0.0, 0.0, 1.0]],
               Distortion("3de4-anamorphic-deg4", {
                   "filmback_width_px": W, "filmback_height_px": H, "cx02": -0.06, "cy02": -0.03, "cx22": 0.012,
                   "cy22": 0.018, "cx04": 0.01, "cy04": 0.004, "cx24": 0.003, "cy24": -0.002, "cx44": -0.001,
                   "cy44": 0.0008}), np.eye(3), np.zeros(3))


def board_views(camera: Camera, n_views: int, rng: np.random.Generator) -> dict[str, list[Detection]]:
    """Board poses seen whole; corners projected through the camera's lens (Camera.project) plus noise."""
    centred = BOARD.object_points - BOARD.object_points.mean(axis=0)
    detections = []
    while len(detections) < n_views:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        X = centred @ R.T + rng.uniform([-0.6, -0.12, 0.45], [0.6, 0.12, 0.8])
        pixels = camera.project(X)
        if not np.all((pixels > 5) & (pixels < np.array(camera.image_size) - 5)):
            continue
        noisy = pixels + rng.normal(0.0, SIGMA_PX, pixels.shape)
        detections.append(Detection(f"view_{len(detections):03d}.png", camera.image_size,
                                    np.arange(BOARD.n_corners), noisy, "synthetic"))
    return {camera.name: detections}


def rays(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Unit rays (camera frame) of distorted pixels."""
    ideal = np.column_stack([camera.distortion.undistort(pixels, camera.K), np.ones(len(pixels))])
    directions = np.linalg.solve(camera.K, ideal.T).T
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


def ray_error_px(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Where ``camera`` images the truth's rays of ``pixels``, minus ``pixels``, after the rotation that best
    aligns the two cameras' rays (a camera frame turned by a fraction of a pixel is the same calibration: its
    principal point and every pose take it up)."""
    truth, fitted = rays(TRUTH, pixels), rays(camera, pixels)
    u, _, vt = np.linalg.svd(fitted.T @ truth)
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt  # Kabsch: truth -> fitted
    aligned = truth @ rotation.T
    ideal = (camera.K @ (aligned / aligned[:, 2:3]).T).T[:, :2]
    return np.linalg.norm(camera.distortion.distort(ideal, camera.K) - pixels, axis=1)


def test_anamorphic_squeeze_recovered_directly():
    detections = board_views(TRUTH, 15, np.random.default_rng(11))
    result = calibrate_board(BOARD, detections, model="3de4-anamorphic-deg4", holdout={12, 13, 14})
    camera = result.rig.cameras[0]
    assert result.model == "3de4-anamorphic-deg4" and camera.distortion.model == "3de4-anamorphic-deg4"
    squeeze = camera.K[1, 1] / camera.K[0, 0]
    assert abs(squeeze / 2.0 - 1.0) < 5e-4, squeeze
    assert np.allclose(camera.K, TRUTH.K, rtol=2e-3, atol=1.0)
    corners = np.concatenate([detection.corners_px for detection in detections["anamorphic"]])
    assert np.ptp(corners, axis=0).min() > 0.7 * H and np.ptp(corners[:, 0]) > 0.7 * W
    # the lens where the views saw it (held-out views included), against the truth: within the sampling noise of
    # 12 views at 0.1 px (0.06 px RMS here), far below a lens in the wrong direction or normalisation (pixels)
    errors = ray_error_px(camera, corners)
    assert np.sqrt(np.mean(errors**2)) < 0.1 and errors.max() < 0.3, (np.sqrt(np.mean(errors**2)), errors.max())
    # training and held-out errors at the corners' noise (2D RMS of N(0, 0.1) per axis: 0.14 px)
    assert result.rms_px < 1.2 * SIGMA_PX * np.sqrt(2)
    assert result.heldout_rms_px is not None and result.heldout_rms_px < 1.3 * SIGMA_PX * np.sqrt(2)
    assert set(camera.quality.sigma) == {"fx", "fy", "cx", "cy", *FITTED_PARAMS["3de4-anamorphic-deg4"]}
    assert camera.quality.sigma["fy"] > 0.0
    assert any("started from the opencv fit" in note for note in result.notes)


def test_a_3de_model_calibrates_one_camera():
    detections = board_views(TRUTH, 4, np.random.default_rng(2))
    twice = {"a": detections["anamorphic"], "b": detections["anamorphic"]}
    with pytest.raises(CamcalError, match="calibrates one camera on a flat board"):
        calibrate_board(BOARD, twice, model="3de4-radial-deg4")


@pytest.mark.slow
@pytest.mark.parametrize("model, K, coefficients", [
    ("3de-classic", [[1400.0, 0, 965.0], [0, 1403.0, 536.0], [0, 0, 1]],
     {"distortion": -0.05, "curvature_x": 0.01, "curvature_y": -0.01, "quartic_distortion": 0.01}),
    ("3de4-radial-deg4", [[1400.0, 0, 965.0], [0, 1403.0, 536.0], [0, 0, 1]],
     {"c2": -0.05, "u2": 0.003, "v2": -0.002, "c4": 0.01, "u4": 0.001, "v4": 0.0}),
    ("3de4-fisheye-deg8", [[700.0, 0, 965.0], [0, 700.0, 536.0], [0, 0, 1]], {"c2": 0.02, "c4": 0.005}),
])
def test_every_3de_model_calibrates_to_the_noise(model, K, coefficients):
    """The other three models (the anamorphic one above is their fast sibling): K and the lens's coefficients of
    degree 2 recovered, training and held-out errors at the corners' noise."""
    truth = Camera("cam", (W, H), K, Distortion(model, {"filmback_width_px": W, "filmback_height_px": H,
                                                        **coefficients}), np.eye(3), np.zeros(3))
    result = calibrate_board(BOARD, board_views(truth, 12, np.random.default_rng(5)), model=model, holdout={10, 11})
    camera = result.rig.cameras[0]
    assert np.allclose(camera.K, truth.K, rtol=1e-3, atol=1.0)
    degree_2 = "distortion" if model == "3de-classic" else "c2"
    assert camera.distortion.params[degree_2] == pytest.approx(coefficients[degree_2], abs=2e-3)
    assert result.rms_px < 1.2 * SIGMA_PX * np.sqrt(2)
    assert result.heldout_rms_px < 1.3 * SIGMA_PX * np.sqrt(2)


def test_a_fit_whose_covariance_has_no_positive_variance_is_one_error(monkeypatch):
    """Near-singular normal equations invert with negative variances by rounding: one line naming the parameters,
    not a NaN sigma that the quality record refuses later (seen on a 3DE4 fisheye fit of a wide action camera)."""
    import camcal.geometry.tde4_fit as tde4_fit

    real_inv = np.linalg.inv

    def rounding_inverse(matrix):
        inverse = real_inv(matrix)
        if inverse.ndim == 2 and inverse.shape[0] > 30:  # the lens + poses normal equations, not a 3x3
            inverse[0, 0] = -abs(inverse[0, 0])  # fx's variance as rounding leaves it on a singular system
        return inverse

    monkeypatch.setattr(tde4_fit.np.linalg, "inv", rounding_inverse)
    detections = board_views(TRUTH, 6, np.random.default_rng(5))
    with pytest.raises(CamcalError, match=r"degenerate .*not determined: fx$"):
        calibrate_board(BOARD, detections, model="3de4-anamorphic-deg4")


def test_anamorphic_model_holds_the_rotation_a_square_pixel_lens_does_not_determine():
    """A round lens on square pixels (no anisotropic term): turning it changes nothing the corners see, so the lens
    rotation is held at 0 and said so (its standard error there, above the bound); the rest of the fit is sound."""
    truth = Camera("round", (W, H), [[1400.0, 0, 965.0], [0, 1400.0, 536.0], [0, 0, 1]],
                   Distortion("3de4-anamorphic-deg4", {"filmback_width_px": W, "filmback_height_px": H, "cx02": -0.05,
                                                        "cy02": -0.05, "cx04": 0.01, "cy04": 0.01}),
                   np.eye(3), np.zeros(3))
    result = calibrate_board(BOARD, board_views(truth, 6, np.random.default_rng(5)), model="3de4-anamorphic-deg4")
    camera = result.rig.cameras[0]
    assert camera.distortion.params["lens_rotation_deg"] == 0.0 and "lens_rotation_deg" not in camera.quality.sigma
    [note] = [note for note in result.notes if "lens rotation held at 0 deg" in note]
    sigma = float(re.search(r"standard error there ([\d.e+]+) deg", note).group(1))
    assert sigma > MAX_ROTATION_SIGMA_DEG, note
    assert any("lens_rotation_deg 0" in note for note in result.notes)
    assert np.allclose(camera.K, truth.K, rtol=2e-3, atol=1.0)
    assert result.rms_px < 1.2 * SIGMA_PX * np.sqrt(2)
