"""A lens that folds inside the image (its rays stop turning outward) is found, and ``model="auto"`` moves past it."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.geometry import zhang
from camcal.geometry.board import Board, Detection
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

BOARD = Board("chessboard", 9, 6, 0.04)
SIZE = (1280, 960)
K = np.array([[500.0, 0, 639.5], [0, 500.0, 479.5], [0, 0, 1]])


def barrel(k1: float) -> Camera:
    return Camera("c", SIZE, K, Distortion("opencv", {"k1": k1, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}),
                  np.eye(3), np.zeros(3))


@pytest.mark.parametrize("k1", [-0.5, -0.3])
def test_fold_radius_of_a_barrel_polynomial(k1):
    """``r_d = r (1 + k1 r^2)`` peaks at ``r = 1 / sqrt(-3 k1)``, ``r_d = (2/3) r``: the fold is f r_d from the
    principal point, found to the step (1 px)."""
    expected = K[0, 0] * (2.0 / 3.0) / np.sqrt(-3.0 * k1)
    assert abs(zhang.fold_radius_px(barrel(k1)) - expected) <= 1.0


def test_a_lens_that_maps_the_image_one_to_one_does_not_fold():
    assert zhang.fold_radius_px(barrel(-0.05)) is None  # its peak is 861 px out, beyond the image's 479 px
    fisheye = dataclasses.replace(barrel(0.0), distortion=Distortion(
        "kannala-brandt", {"k1": 0.02, "k2": -0.01, "k3": 0.002, "k4": -0.0005}))
    assert zhang.fold_radius_px(fisheye) is None


def central_views_of_a_fisheye(n: int, seed: int) -> list[Detection]:
    """Boards within 300 px of the centre of a 1280x960 fisheye (f 380 px): its rim never seen."""
    truth = Camera("fish", SIZE, np.array([[380.0, 0, 639.5], [0, 380.0, 479.5], [0, 0, 1]]),
                   Distortion("kannala-brandt", {"k1": 0.02, "k2": -0.01, "k3": 0.002, "k4": -0.0005}), np.eye(3),
                   np.zeros(3))
    rng = np.random.default_rng(seed)
    out, centred = [], BOARD.object_points - BOARD.object_points.mean(axis=0)
    while len(out) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        p = truth.project(centred @ R.T + rng.uniform([-0.12, -0.1, 0.35], [0.12, 0.1, 0.5]))
        if np.all(np.isfinite(p)) and np.linalg.norm(p - [639.5, 479.5], axis=1).max() <= 300:
            out.append(Detection(f"view_{len(out):03d}.png", SIZE, np.arange(BOARD.n_corners),
                                 p + rng.normal(0.0, 0.1, p.shape), "synthetic"))
    return out


@pytest.mark.slow
def test_auto_moves_past_a_pick_that_folds_inside_the_image(monkeypatch):
    """The cross-validation sees only the centre; where its pick (here forced to be opencv, whose fit on these views
    turns over 334 px out) folds inside the image, auto takes the next model and says why."""
    views = central_views_of_a_fisheye(16, 5)
    assert zhang.fold_radius_px(zhang.calibrate_board(BOARD, {"fish": views}, model="opencv").rig.cameras[0]) < 479
    rank = zhang.rank_models

    def opencv_first(*args, **kwargs):
        ranking, squared, corners = rank(*args, **kwargs)
        best = min(s.rms_px for s in ranking if s.rms_px is not None)
        forced = [dataclasses.replace(s, rms_px=0.9 * best) if s.model == "opencv" else s for s in ranking]
        return tuple(sorted(forced, key=lambda s: (s.rms_px is None, s.rms_px or 0.0))), squared, corners

    monkeypatch.setattr(zhang, "rank_models", opencv_first)
    result = zhang.calibrate_board(BOARD, {"fish": views})
    assert result.model != "opencv"
    assert zhang.fold_radius_px(result.rig.cameras[0]) is None
    assert any(note.startswith("model auto: opencv: fish: the lens folds") for note in result.notes), result.notes
