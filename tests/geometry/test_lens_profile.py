"""A lens profile of a real zoom lens's published distortion, checked at lens states it never saw.

The truth: the Canon EF 70-200mm f/4L USM as Lensfun's database (bundled with
lensfunpy) holds it, ``poly3`` distortion measured at 13 focal lengths,
turned into camcal's exact ``polynomial`` lens (:func:`camcal.io.lensfun.camera_of`),
with focus breathing (the focal length 3 % longer per dioptre of focus) and a
principal point drifting with zoom and focus. Board corners are projected
through camcal's mapping of that truth, with noise; each state is calibrated
by the board calibration, and the profile fitted without three states is
checked at those three: its projection within 2 sigma of the truth over
95 % of the image, and its reprojection of the state's own views no worse
than 1.1x a calibration made at that state.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import scipy.optimize
from scipy.spatial.transform import Rotation

from camcal.api.board import BoardCalibration
from camcal.api.profile import calibrate_profile
from camcal.geometry.board import Detection, parse_board
from camcal.geometry.lens_profile import camera_at, projection_sigma_px, suggest_state
from camcal.geometry.zhang import calibrate_board
from camcal.io.lensfun import LensfunLens, camera_of
from camcal.model.distortion import frame_grid
from camcal.model.lens_profile import format_state
from camcal.model.rig import Camera

lensfunpy = pytest.importorskip("lensfunpy")

BOARD = parse_board("chessboard:8x6:0.03")
SIZE = (1200, 800)
NOISE_PX = 0.25
LENS = "Canon EF 70-200mm f/4L USM"
TRAINING = ((70, 1.5), (70, math.inf), (94, 3.0), (109, 1.5), (135, math.inf), (145, 3.0), (159, 1.5),
            (168, math.inf), (200, 1.5), (200, math.inf))
HELD_OUT = ((81, 2.0), (122, math.inf), (184, 2.5))


def _lensfun_k1() -> dict[float, float]:
    """The lens's ``poly3`` k1 at each focal length Lensfun's database holds."""
    database = lensfunpy.Database()
    [lens] = [lens for lens in database.lenses if lens.model == LENS]
    return {entry.focal: entry.terms[0] for entry in lens.calib_distortion}


def truth_camera(focal_mm: float, focus_m: float, k1: dict[float, float]) -> Camera:
    """The truth at a lens state: Lensfun's lens, breathing with focus, its centre drifting."""
    aspect = (max(SIZE) - 1) / (min(SIZE) - 1)
    lens = camera_of(LensfunLens("poly3", {"k1": k1[focal_mm]}, focal_mm, 1.0, aspect, (0.0, 0.0)), SIZE, "truth")
    vergence = 1.0 / focus_m
    K = lens.K.copy()
    K[:2, :2] *= 1.0 + 0.03 * vergence
    K[0, 2] += 4.0 * (focal_mm - 135.0) / 65.0
    K[1, 2] += -3.0 * (focal_mm - 135.0) / 65.0 + 2.0 * vergence
    return Camera("camera", SIZE, K, lens.distortion, np.eye(3), np.zeros(3))


def board_views(camera: Camera, n_views: int, seed: int, tag: str) -> list[Detection]:
    """``n_views`` views of the board filling about half the image, corners with Gaussian noise (seeded)."""
    rng = np.random.default_rng(seed)
    X = BOARD.object_points
    centre = X.mean(axis=0)
    width = np.ptp(X[:, 0])
    distance = camera.K[0, 0] * width / (0.6 * SIZE[0])
    views = []
    while len(views) < n_views:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        t = np.array([*rng.uniform(-0.25, 0.25, 2) * distance * 0.4, distance]) - R @ centre
        pixels = camera.project(X @ R.T + t)
        if not np.all((pixels > 2) & (pixels < np.array(SIZE) - 3)):
            continue
        pixels = pixels + rng.normal(0.0, NOISE_PX, pixels.shape)
        views.append(Detection(f"{tag}_{len(views):02d}.png", SIZE, np.arange(len(X)), pixels, "sb"))
    return views


def calibrated(views: list[Detection]) -> BoardCalibration:
    result = calibrate_board(BOARD, {"camera": views}, model="polynomial", board_shape="flat")
    return BoardCalibration(result, BOARD, {}, {"camera": tuple(views)})


def posed_rms(camera: Camera, views: list[Detection]) -> float:
    """RMS reprojection of ``views``, each posed (OpenCV's PnP, then least squares in pixels) with the camera held."""
    squared = []
    for view in views:
        ideal = camera.distortion.undistort(view.corners_px, camera.K)
        _, rvec, tvec = cv2.solvePnP(BOARD.object_points, ideal, camera.K, None)

        def residual(pose: np.ndarray) -> np.ndarray:
            R = Rotation.from_rotvec(pose[:3]).as_matrix()
            return (camera.project(BOARD.object_points @ R.T + pose[3:]) - view.corners_px).ravel()

        fit = scipy.optimize.least_squares(residual, np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm")
        squared.append(fit.fun.reshape(-1, 2))
    return float(np.sqrt(np.mean(np.sum(np.concatenate(squared) ** 2, axis=1))))


def check_profile(training, held_out, n_views: int, seed: int = 0) -> dict:
    k1 = _lensfun_k1()
    states = {format_state(f, d): calibrated(board_views(truth_camera(f, d, k1), n_views, seed, "t"))
              for seed, (f, d) in enumerate(training, start=seed)}
    profile = calibrate_profile(states, BOARD, model="polynomial").profile
    figures = {}
    for seed, (focal, focus) in enumerate(held_out, start=seed + 100):
        truth = truth_camera(focal, focus, k1)
        grid = frame_grid(SIZE, 25.0)
        rays = truth.distortion.rays_from_pixels(grid, truth.K)
        predicted = camera_at(profile, focal, focus)
        pixels = predicted.distortion.project_rays(rays, predicted.K)
        sigma = projection_sigma_px(profile, focal, focus, pixels)
        within = float(np.mean(np.linalg.norm(pixels - grid, axis=1) <= 2.0 * sigma))
        direct = calibrated(board_views(truth, n_views, seed, "d")).rig.cameras[0]
        check = board_views(truth, 4, seed + 50, "c")
        figures[format_state(focal, focus)] = (within, posed_rms(predicted, check), posed_rms(direct, check))
    return figures


def _assert_held_out_states_predicted(figures: dict) -> None:
    for label, (within, profile_rms, direct_rms) in figures.items():
        assert within >= 0.95, (label, within)
        assert profile_rms <= 1.1 * direct_rms, (label, profile_rms, direct_rms)


def test_the_profile_predicts_held_out_zoom_states_of_a_real_lens():
    _assert_held_out_states_predicted(check_profile(TRAINING, HELD_OUT, n_views=4))


@pytest.mark.slow
def test_the_profile_predicts_held_out_states_over_other_noise_draws():
    """Six noise draws (18 held-out states): every state within 2 sigma over 90 % of the image and reprojecting
    within 1.25x the direct calibration, and at least 80 % of them within the fast test's 2 sigma over 95 % and
    1.1x (with four views a state, the direct calibration's own error is as large as the profile's: the ratio
    scatters about 1)."""
    figures = [value for seed in range(0, 6000, 1000)
               for value in check_profile(TRAINING, HELD_OUT, n_views=4, seed=seed).values()]
    assert all(within >= 0.9 and profile_rms <= 1.25 * direct_rms for within, profile_rms, direct_rms in figures)
    strict = [within >= 0.95 and profile_rms <= 1.1 * direct_rms for within, profile_rms, direct_rms in figures]
    assert np.mean(strict) >= 0.8, figures


PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _synthetic_states(focals_focuses, shift: dict[int, float] | None = None, seed: int = 3) -> list:
    """States of a smooth lens (fx linear in focal, breathing 3 % per dioptre; k1 quadratic in focal), each with
    its sigma and Gaussian noise of that sigma; ``shift``: state index -> k1 moved by that many sigmas."""
    from camcal.model.lens_profile import LensState

    rng = np.random.default_rng(seed)
    sigma = np.array([2.0, 2.0, 0.5, 0.5, 0.002, 0.01])
    states = []
    for index, (focal, focus) in enumerate(focals_focuses):
        truth = np.array([40.0 * focal * (1 + 0.03 / focus), 40.0 * focal * (1 + 0.03 / focus), 600.0, 400.0,
                          -0.1 + 1e-5 * (focal - 100.0) ** 2, 0.0])
        values = truth + rng.normal(0.0, sigma)
        values[4] += (shift or {}).get(index, 0.0) * sigma[4]
        states.append(LensState(format_state(focal, focus), focal, focus,
                                dict(zip(PARAMETERS, values)), np.diag(sigma**2), 6, 0.2))
    return states


def test_a_state_that_no_smooth_profile_predicts_is_named():
    from camcal.geometry.lens_profile import fit_profile

    grid = [(f, d) for f in (50, 80, 110, 140, 170) for d in (1.0, math.inf)]
    parameters = PARAMETERS
    assert fit_profile(_synthetic_states(grid), parameters).disagreeing == {}
    fitted = fit_profile(_synthetic_states(grid, {4: 40.0}), parameters)
    assert list(fitted.disagreeing) == ["110mm@1m"]
    assert fitted.disagreeing["110mm@1m"].startswith("k1 ")


def test_the_next_state_suggested_is_where_the_profile_knows_least():
    from camcal.geometry.lens_profile import fit_profile
    from camcal.model.lens_profile import LensProfile

    # focused at 2 m, shot densely from 50 to 110 mm and at 170 mm: the gap is where to shoot next
    grid = [(f, 2.0) for f in (50, 60, 70, 80, 90, 100, 110, 170)]
    states = _synthetic_states(grid)
    parameters = PARAMETERS
    fitted = fit_profile(states, parameters)
    profile = LensProfile("polynomial", (1200, 800), BOARD.spec(), parameters, tuple(states), fitted.surfaces)
    suggestion = suggest_state(profile)
    assert 110 < suggestion.focal_mm < 170
