"""Correspondence CSV: exact round trip."""

import numpy as np

from camcal.io.points_csv import read_correspondences, write_correspondences


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    X, x = rng.normal(size=(7, 3)), rng.normal(size=(7, 2)) * 1000
    X2, x2 = read_correspondences(write_correspondences(tmp_path / "p.csv", X, x))
    assert np.array_equal(X, X2) and np.array_equal(x, x2)
