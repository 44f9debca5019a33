"""A real zoom lens rendered in Blender through camcal's exact mapping: its lens profile checked at 3 held-out states.

The truth is the Nikon AF-S DX Zoom-Nikkor 17-55mm f/2.8G IF-ED as Lensfun's
database (the copy bundled with lensfunpy) publishes it: ``poly3``
distortion measured at 7 focal lengths, from barrel (``k1 = -0.0104`` at
17 mm) to pincushion (``+0.0073`` at 38 mm), and between them Lensfun's own
interpolation (``lfLens::InterpolateDistortion`` through lensfunpy), each
turned into camcal's exact ``polynomial`` lens by
:func:`camcal.io.lensfun.camera_of` on a 640 x 426 image of the lens' APS-C
format (crop factor 1.528, 3:2). Lensfun has no focus distance and one
principal point for every focal length; constructed here: focus breathing
(the focal length 3 % longer per dioptre of focus, 6 % at 0.5 m) and a
principal point drifting with zoom (+4 / -3 px over the range) and with
focus (-2 / +2 px per dioptre).

Ten states are calibrated into a profile (the 7 published focal lengths,
focused at 0.5 m, 1.5 m or infinity) through :func:`camcal.calibrate_profile`,
the function ``camcal calibrate profile`` calls; 3 states the profile never
saw are held out. At each held-out state:

- coverage: the profile's camera there projects the truth's ray of each
  pixel of an 8-pixel grid over the image; the share of pixels where that
  is within 2 of the profile's own projection sigma there
  (:func:`camcal.geometry.lens_profile.projection_sigma_px`: the state
  covariances propagated through the surfaces, each surface's sigma scaled
  by its leave-one-state-out misses) must be >= 95 %;
- reprojection: boards of that state used nowhere else, detected, each posed
  with the camera held (:func:`camcal.geometry.zhang_fit.posed_residuals`):
  the profile's camera RMS <= 1.1x that of a calibration made at that state
  directly from as many views as a profile state (the same model).

The images (slow test): Cycles renders each view as an undistorted pinhole
on an overscan canvas and camcal's exact redistort map applies the truth's
lens (the demo's renderer, :mod:`camcal.demo.render`); the board is
emissive, there is no depth of field. The fast sibling runs the same states,
poses, profile and figures on the truth's projected corners plus Gaussian
noise, no rendering.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import camcal
from camcal.api.board import BoardCalibration
from camcal.demo.render import render_board_views
from camcal.demo.truth import board_outline
from camcal.geometry.board import Detection, detect_board, parse_board
from camcal.geometry.lens_profile import camera_at, projection_sigma_px
from camcal.geometry.zhang import calibrate_board as fit_board
from camcal.geometry.zhang_fit import posed_residuals
from camcal.io.lensfun import LensfunLens, camera_of
from camcal.model.distortion import frame_grid
from camcal.model.lens_profile import LensProfile, format_state
from camcal.model.rig import Camera

lensfunpy = pytest.importorskip("lensfunpy")

LENS = "Nikon AF-S DX Zoom-Nikkor 17-55mm f/2.8G IF-ED"
BOARD = parse_board("chessboard:9x6:0.03")
SIZE = (640, 426)
MODEL = "polynomial"
#: (focal mm, focus m): the 7 focal lengths Lensfun publishes, near and far at both ends and in between.
TRAINING = ((17, 0.5), (17, math.inf), (19, 1.5), (22, 0.5), (26, math.inf), (30, 1.5), (38, 0.5), (38, math.inf),
            (55, 0.5), (55, math.inf))
HELD_OUT = ((18, 0.7), (28, 3.0), (45, 1.0))
VIEWS = 8
CHECK_VIEWS = 4
#: The fast sibling's views a state: below 5 (:data:`camcal.geometry.jackknife.MIN_FRAMES`) a board fit runs no
#: delete-one-view jackknife, so each state's covariance is the Jacobian's and its fit takes about 0.1 s.
FAST_VIEWS = 4
#: Blender's samples a pixel (Cycles, emission only: no noise but the edges' anti-aliasing).
SAMPLES = 8


def lensfun_lens():
    """The lens' entry in lensfunpy's bundled database."""
    [lens] = [lens for lens in lensfunpy.Database().lenses if lens.model == LENS]
    return lens


def truth_camera(focal_mm: float, focus_m: float, lens) -> Camera:
    """The truth at a lens state (``R = I``, ``c = 0``): Lensfun's distortion at that focal length (its own
    interpolation between the focal lengths it holds), breathing with focus, its centre drifting."""
    k1 = lens.interpolate_distortion(float(focal_mm)).terms[0]
    aspect = (max(SIZE) - 1) / (min(SIZE) - 1)
    exact = camera_of(LensfunLens("poly3", {"k1": k1}, focal_mm, lens.crop_factor, aspect, (0.0, 0.0)), SIZE, "truth")
    vergence = 1.0 / focus_m
    zoom = (focal_mm - 17.0) / (55.0 - 17.0)
    K = exact.K.copy()
    K[:2, :2] *= 1.0 + 0.03 * vergence
    K[0, 2] += 4.0 * zoom - 2.0 * vergence
    K[1, 2] += -3.0 * zoom + 2.0 * vergence
    return Camera("camera", SIZE, K, exact.distortion, np.eye(3), np.zeros(3))


def _outline_points(n: int = 16) -> np.ndarray:
    """Points along the printed board's border (its squares and a white square of margin), board coordinates."""
    corners = board_outline(BOARD)
    return np.concatenate([a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a)
                           for a, b in zip(corners, np.roll(corners, -1, axis=0))])


def board_poses(camera: Camera, n_views: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n_views`` poses (``cam_from_board``) of the printed board filling 45-70 % of the width, tilted up to 30
    degrees, anywhere in the frame, its whole border at least 4 px inside (through ``camera``'s lens)."""
    border = _outline_points()
    centre = board_outline(BOARD).mean(axis=0)
    width = np.ptp(border[:, 0])
    poses = []
    while len(poses) < n_views:
        fill = rng.uniform(0.45, 0.7)
        distance = camera.K[0, 0] * width / (fill * SIZE[0])
        R = Rotation.from_euler("xyz", rng.uniform(-30, 30, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        room_px = 0.5 * np.array(SIZE) * [1.0 - fill, 1.0 - fill * 1.1]
        shift = rng.uniform(-1.0, 1.0, 2) * room_px * distance / camera.K[0, 0]
        t = np.array([*shift, distance]) - R @ centre
        pixels = camera.project(border @ R.T + t)
        if np.all(np.isfinite(pixels)) and np.all((pixels > 4) & (pixels < np.array(SIZE) - 5)):
            poses.append((R, t))
    return poses


def state_poses(focal_mm: float, focus_m: float, lens, n_views: int, seed: int) -> list:
    return board_poses(truth_camera(focal_mm, focus_m, lens), n_views, np.random.default_rng(seed))


def projected_views(camera: Camera, poses, noise_px: float, seed: int, tag: str) -> list[Detection]:
    """The board's corners where ``camera`` puts them at ``poses``, plus Gaussian noise (seeded)."""
    rng = np.random.default_rng(seed)
    ids = np.arange(len(BOARD.object_points))
    return [Detection(f"{tag}_{k:02d}.png", SIZE, ids,
                      camera.project(BOARD.object_points @ R.T + t) + rng.normal(0.0, noise_px, (len(ids), 2)), "sb")
            for k, (R, t) in enumerate(poses)]


def reprojection_rms(camera: Camera, views: list[Detection]) -> float:
    """RMS (px) of ``views``, each posed with the camera held."""
    residuals = np.concatenate([posed_residuals(BOARD, camera, view) for view in views])
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))


def held_out_figures(profile: LensProfile, focal_mm: float, focus_m: float, truth: Camera, direct: Camera,
                     check: list[Detection]) -> dict[str, float]:
    """The profile at a state it never saw, against the truth and a direct calibration there (module docstring).

    Returns ``within`` (share of an 8-pixel grid within 2 sigma), ``worst_error_px``, ``worst_sigma_px``,
    ``profile_rms_px``, ``direct_rms_px`` (on ``check``, views used by neither) and ``ratio``.
    """
    grid = frame_grid(SIZE, 8.0)
    predicted = camera_at(profile, focal_mm, focus_m)
    pixels = predicted.distortion.project_rays(truth.distortion.rays_from_pixels(grid, truth.K), predicted.K)
    error = np.linalg.norm(pixels - grid, axis=1)
    sigma = projection_sigma_px(profile, focal_mm, focus_m, pixels)
    profile_rms, direct_rms = reprojection_rms(predicted, check), reprojection_rms(direct, check)
    return {"within": float(np.mean(error <= 2.0 * sigma)), "worst_error_px": float(error.max()),
            "worst_sigma_px": float(sigma.max()), "profile_rms_px": profile_rms, "direct_rms_px": direct_rms,
            "ratio": profile_rms / direct_rms}


def report(figures: dict[str, dict[str, float]]) -> None:
    print("held-out state: within 2 sigma, worst error / worst sigma px, held-out RMS profile / direct px, ratio")
    for label, f in figures.items():
        print(f"  {label}: {100 * f['within']:.1f} %, {f['worst_error_px']:.3f} / {f['worst_sigma_px']:.3f} px, "
              f"{f['profile_rms_px']:.4f} / {f['direct_rms_px']:.4f} px, {f['ratio']:.3f}")


def state_chi_square(profile: LensProfile, lens) -> dict[str, float]:
    """Each calibrated state's parameters against the truth's, ``r^T C^-1 r`` with the state's own covariance
    (chi-square of as many degrees of freedom as parameters when that covariance is right)."""
    figures = {}
    for state in profile.states:
        truth = truth_camera(state.focal_mm, state.focus_m, lens)
        expected = {"fx": truth.K[0, 0], "fy": truth.K[1, 1], "cx": truth.K[0, 2], "cy": truth.K[1, 2],
                    **truth.distortion.params}
        r = np.array([state.params[name] - expected[name] for name in profile.parameters])
        figures[state.label] = float(r @ np.linalg.solve(state.covariance, r))
    return figures


def assert_targets(figures: dict[str, dict[str, float]]) -> None:
    for label, f in figures.items():
        assert f["within"] >= 0.95, (label, f)
        assert f["ratio"] <= 1.1, (label, f)


# -- fast: the truth's corners plus noise ------------------------------------------------------------------------


def _calibrated(views: list[Detection]) -> BoardCalibration:
    result = fit_board(BOARD, {"camera": views}, model=MODEL, board_shape="flat")
    return BoardCalibration(result, BOARD, {}, {"camera": tuple(views)})


#: The spread (px a axis) of the renders' detections about the true corners, measured on the slow test's check views.
DETECTION_NOISE_PX = 0.035


def synthetic_figures(noise_px: float, n_views: int, seed: int = 0) -> dict[str, dict[str, float]]:
    """The slow test's states, profile and figures on the truth's projected corners plus Gaussian noise; ``seed``
    shifts every pose and noise draw (``0``: the slow test's poses)."""
    lens = lensfun_lens()
    states = {format_state(f, d): _calibrated(projected_views(truth_camera(f, d, lens),
                                                             state_poses(f, d, lens, n_views, seed + k), noise_px,
                                                             seed + k, "t"))
              for k, (f, d) in enumerate(TRAINING)}
    profile = camcal.calibrate_profile(states, BOARD, model=MODEL).profile
    figures = {}
    for k, (focal, focus) in enumerate(HELD_OUT, start=seed + 100):
        truth = truth_camera(focal, focus, lens)
        direct = _calibrated(projected_views(truth, state_poses(focal, focus, lens, n_views, k), noise_px, k, "d"))
        check = projected_views(truth, state_poses(focal, focus, lens, CHECK_VIEWS, k + 50), noise_px, k, "c")
        figures[format_state(focal, focus)] = held_out_figures(profile, focal, focus, truth, direct.rig.cameras[0],
                                                               check)
    return figures


def test_held_out_states_of_the_real_zoom_from_projected_corners():
    """The slow test's computation on the truth's corners plus the renders' detection noise, 4 views a state."""
    figures = synthetic_figures(DETECTION_NOISE_PX, FAST_VIEWS)
    report(figures)
    assert_targets(figures)


# -- slow: Blender renders -----------------------------------------------------------------------------------------


def render_states(folder: Path, states: dict[str, tuple[Camera, list]]) -> dict[str, str]:
    """Render each state's board views (Cycles, then the truth's lens by camcal's redistort map) into
    ``folder/LABEL/vNN.png``; returns the label -> glob of its images."""
    return render_board_views(BOARD, states, folder, SAMPLES)


def detected(pattern: str) -> list[Detection]:
    files = sorted(Path(pattern).parent.glob(Path(pattern).name))
    views = [detect_board(BOARD, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), path.name) for path in files]
    assert all(view is not None for view in views), [path.name for path, view in zip(files, views) if view is None]
    return views


@pytest.mark.slow
def test_held_out_states_of_the_real_zoom_rendered_in_blender(tmp_path):
    """Ten states of 8 rendered views calibrated into a profile; 3 held-out states, each with 8 views for a direct
    calibration and 4 to check both on (116 Cycles renders, 640 x 426; 5 to 11 minutes on 2 shared cores)."""
    lens = lensfun_lens()
    states = {}
    for seed, (focal, focus) in enumerate(TRAINING):
        states[format_state(focal, focus)] = (truth_camera(focal, focus, lens),
                                              state_poses(focal, focus, lens, VIEWS, seed))
    for seed, (focal, focus) in enumerate(HELD_OUT, start=100):
        label = format_state(focal, focus)
        truth = truth_camera(focal, focus, lens)
        states[f"direct_{label}"] = (truth, state_poses(focal, focus, lens, VIEWS, seed))
        states[f"check_{label}"] = (truth, state_poses(focal, focus, lens, CHECK_VIEWS, seed + 50))
    globs = render_states(tmp_path, states)
    training = {format_state(f, d): globs[format_state(f, d)] for f, d in TRAINING}
    result = camcal.calibrate_profile(training, BOARD.spec(), model=MODEL, cache=False, progress=False)
    profile = result.profile
    print("\n".join(result.lines()))
    chi_square = state_chi_square(profile, lens)
    print(f"states against the truth, chi-square of {len(profile.parameters)} parameters with their own covariance: "
          + ", ".join(f"{label} {value:.1f}" for label, value in chi_square.items())
          + f" (median {np.median(list(chi_square.values())):.1f})")
    figures = {}
    for focal, focus in HELD_OUT:
        label = format_state(focal, focus)
        direct = camcal.calibrate_board(globs[f"direct_{label}"], BOARD.spec(), model=MODEL, cache=False,
                                        progress=False)
        figures[label] = held_out_figures(profile, focal, focus, states[f"direct_{label}"][0],
                                          direct.rig.cameras[0], detected(globs[f"check_{label}"]))
    report(figures)
    assert_targets(figures)
