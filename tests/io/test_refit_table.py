"""The refit table's function (bench/bench_refit_table.py) on a small synthetic calibration: exact pairs are exact,
every refit's figures are the refit core's own for that pair."""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.geometry.board import Board, Detection
from camcal.io.conversion import EXACT_FAMILIES, refit_camera
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from bench_refit_table import EXACT_PX, TARGETS, calibrate_models, format_table, refit_table  # noqa: E402

BOARD = Board("chessboard", 6, 5, 0.03)
TRUTH = Camera("small", (320, 240), np.array([[300.0, 0, 161.0], [0, 300.0, 118.5], [0, 0, 1]]),
               Distortion("polynomial", {"k1": -0.12, "k2": 0.03}), np.eye(3), np.zeros(3))


def synthetic_views(n: int, rng: np.random.Generator) -> list[Detection]:
    """``n`` whole views of the board projected by TRUTH with 0.05 px noise."""
    views, centred = [], BOARD.object_points - BOARD.object_points.mean(axis=0)
    while len(views) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-30, 30, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        points = TRUTH.project(centred @ R.T + rng.uniform([-0.03, -0.03, 0.25], [0.03, 0.03, 0.35]))
        if np.all((points > 3) & (points < np.array(TRUTH.image_size) - 3)):
            noisy = points + rng.normal(0.0, 0.05, points.shape)
            views.append(Detection(f"view_{len(views):03d}.png", TRUTH.image_size, np.arange(len(points)),
                                   noisy, "synthetic"))
    return views


@pytest.fixture(scope="module")
def table():
    cameras = calibrate_models(BOARD, synthetic_views(8, np.random.default_rng(3)), ("polynomial", "division"),
                               "small", log=lambda line: None)
    targets = tuple(t for t in TARGETS if t.name in ("opencv", "division"))
    return cameras, refit_table(cameras, targets)


def test_every_model_meets_every_target(table):
    cameras, rows = table
    assert set(cameras) == {"polynomial", "division"}
    assert {(r.model, r.target) for r in rows} == {(m, t) for m in cameras for t in ("opencv", "division")}
    assert all(r.refit is not None and not r.error for r in rows)


def test_exact_pairs_are_exact_and_refits_are_the_cores(table):
    cameras, rows = table
    for row in rows:
        holds = cameras[row.model].distortion.model in EXACT_FAMILIES[row.target]
        assert row.exact == holds, (row.model, row.target)
        expected = refit_camera(cameras[row.model], row.target)[1]
        assert (row.refit.family, row.refit.exact) == (expected.family, expected.exact)
        figures = [dataclasses.astuple(refit)[2:] for refit in (row.refit, expected)]
        np.testing.assert_allclose(*figures, rtol=1e-12, atol=1e-12)
        if holds:
            assert row.refit.max_px < EXACT_PX and row.refit.border_max_px < EXACT_PX
        else:  # a refit across families on a real lens costs something, and the table prints it
            assert row.refit.rms_px > EXACT_PX
    text = format_table(rows, "small")
    assert text.count("exact") == sum(r.exact for r in rows) == 2
