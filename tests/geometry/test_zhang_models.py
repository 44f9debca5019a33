"""Board calibration with every lens model and ``model="auto"`` on few views and partly seen boards."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.geometry.board import Board, Detection
from camcal.geometry.zhang import AUTO_MODELS, calibrate_board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

SIGMA_PX = 0.1
#: a portrait phone camera and a small board, as in the recording the issue names (4x7 inner corners)
PHONE_BOARD = Board("chessboard", 4, 7, 0.03)
PHONE = Camera("phone", (1088, 1920), np.array([[1675.0, 0, 543.5], [0, 1675.0, 959.5], [0, 0, 1]]),
               Distortion("polynomial", {"k1": 0.08, "k2": -0.15}), np.eye(3), np.zeros(3))


def views(camera, board, n, rng, partial=False, distance=(0.3, 0.45), tilt=30.0):
    """Board views projected by ``camera`` with noise; ``partial``: about half cut by a vertical line."""
    out, centred = [], board.object_points - board.object_points.mean(axis=0)
    while len(out) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-tilt, tilt, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        X = centred @ R.T + rng.uniform([-0.05, -0.1, distance[0]], [0.05, 0.1, distance[1]])
        p = camera.project(X)
        inside = np.all((p > 5) & (p < np.array(camera.image_size) - 5), axis=1)
        if partial and rng.uniform() < 0.5:
            inside &= p[:, 0] < rng.uniform(0.3, 0.8) * camera.image_size[0]
        if inside.sum() < 8:
            continue
        ids = np.flatnonzero(inside)
        noisy = p[ids] + rng.normal(0.0, SIGMA_PX, (len(ids), 2))
        out.append(Detection(f"view_{len(out):03d}.png", camera.image_size, ids, noisy, "synthetic"))
    return {camera.name: out}


@pytest.mark.parametrize("n_views", [4, 5, 6, 7])
@pytest.mark.parametrize("partial", [False, True])
def test_auto_on_few_views_gives_a_rig(n_views, partial):
    """4-7 views of a 4x7 board, whole or cut: the default (auto) gives a sound rig, never an internal error."""
    detections = views(PHONE, PHONE_BOARD, n_views, np.random.default_rng(n_views), partial)
    result = calibrate_board(PHONE_BOARD, detections)
    assert result.model in AUTO_MODELS
    assert {score.model for score in result.model_ranking} == set(AUTO_MODELS)
    assert all(score.reason or score.rms_px > 0 for score in result.model_ranking)
    camera = result.rig.cameras[0]
    assert abs(camera.K[0, 0] / 1675.0 - 1.0) < 0.01 and result.rms_px < 3 * SIGMA_PX


def test_auto_with_three_views_fits_without_a_choice():
    detections = views(PHONE, PHONE_BOARD, 3, np.random.default_rng(0))
    result = calibrate_board(PHONE_BOARD, detections)
    assert result.model == "polynomial" and any("too few views" in note for note in result.notes)
    assert all(score.rms_px is None for score in result.model_ranking)


WIDE = Camera("wide", (1280, 960), np.array([[620.0, 0, 641.5], [0, 618.0, 478.0], [0, 0, 1]]),
              Distortion.from_opencv_coefficients([-0.21, 0.04, 8e-4, -1.2e-3, -0.004, 0.05, 0.012, 0.002,
                                                   1.1e-3, -4e-4, 1.6e-3, 2e-4]), np.eye(3), np.zeros(3))
WIDE_BOARD = Board("chessboard", 9, 6, 0.04)


@pytest.mark.parametrize("model, terms", [("opencv-rational", 8), ("opencv-thin-prism", 12)])
def test_rational_and_thin_prism_recover_the_lens(model, terms):
    """OpenCV's 8- and 12-coefficient lenses: fitted, the projection over the frame matches the truth's."""
    lens = WIDE if terms == 12 else Camera(WIDE.name, WIDE.image_size, WIDE.K, Distortion.from_opencv_coefficients(
        WIDE.distortion.opencv_coefficients()[:8]), WIDE.R, WIDE.c)
    detections = views(lens, WIDE_BOARD, 30, np.random.default_rng(3), distance=(0.35, 0.7), tilt=40.0)
    result = calibrate_board(WIDE_BOARD, detections, model=model, holdout=set(range(0, 30, 6)))
    camera = result.rig.cameras[0]
    assert camera.distortion.model == "opencv" and camera.distortion.opencv_terms == terms
    # per-corner norm of 2D noise of sigma 0.1 px: sqrt(2) sigma, on views the fit never saw (the thin-prism
    # terms trade off against the principal point and the poses: parameters and single rays are not compared)
    assert result.rms_px < 1.2 * math.sqrt(2) * SIGMA_PX
    assert result.heldout_rms_px < 1.25 * math.sqrt(2) * SIGMA_PX
    assert abs(camera.K[0, 0] - lens.K[0, 0]) < 5 * camera.quality["sigma"]["fx"]


def test_opencvs_thin_prism_fit_does_not_depend_on_the_callers_opencv_threads():
    """Same input, same output: OpenCV's parallel sums differ in the last digits with its thread count, and an
    ill-conditioned fit (thin prism) can then land in another minimum; calibrate_board runs OpenCV on one thread
    and gives the caller's thread count back."""
    import cv2  # noqa: PLC0415

    detections = views(WIDE, WIDE_BOARD, 12, np.random.default_rng(5), distance=(0.35, 0.7), tilt=40.0)
    before = cv2.getNumThreads()
    try:
        figures = []
        for threads in (1, 2, 4):
            cv2.setNumThreads(threads)
            result = calibrate_board(WIDE_BOARD, detections, model="opencv-thin-prism")
            assert cv2.getNumThreads() == threads
            figures.append((result.rms_px, tuple(result.rig.cameras[0].K.ravel())))
    finally:
        cv2.setNumThreads(before)
    assert figures[0] == figures[1] == figures[2], figures
