"""DLT calibration against synthetic cameras with known noise."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.dlt import calibrate_dlt, dlt_P
from camcal.model.camera import decompose_P
from camcal.synthetic import example_camera, points_in_view


@pytest.fixture(scope="module")
def truth():
    return example_camera(skew=1.7)


def test_exact_without_noise(truth):
    X = points_in_view(truth, 40, np.random.default_rng(0))
    x = truth.project(X)
    linear_K, _, _ = decompose_P(dlt_P(X, x))
    assert np.allclose(linear_K, truth.K, rtol=1e-6)
    result = calibrate_dlt(X, x)
    assert np.allclose(result.K, truth.K, rtol=1e-6)
    assert np.allclose(result.R, truth.R, atol=1e-6)
    assert np.allclose(result.c, truth.c, rtol=1e-6)
    assert result.rms_px < 1e-6


@pytest.mark.parametrize("seed", range(20))
def test_noisy_60_points_within_half_percent(truth, seed):
    """sigma = 0.5 px: fx, fy within 0.5 %, centre within 0.5 % of the scene depth."""
    rng = np.random.default_rng(seed)
    X = points_in_view(truth, 60, rng)
    sigma = 0.5
    x = truth.project(X) + rng.normal(0.0, sigma, (60, 2))
    result = calibrate_dlt(X, x)
    assert abs(result.K[0, 0] / truth.K[0, 0] - 1) < 0.005
    assert abs(result.K[1, 1] / truth.K[1, 1] - 1) < 0.005
    depth = np.mean(np.linalg.norm(X - truth.c, axis=1))
    assert np.linalg.norm(result.c - truth.c) < 0.005 * depth
    # the residual RMS estimates the noise: E[rms^2] = 2 sigma^2 (1 - 11 / 2N)
    expected_rms = sigma * np.sqrt(2 * (1 - 11 / 120))
    assert result.rms_px == pytest.approx(expected_rms, rel=0.3)


@pytest.mark.slow
def test_reported_sigmas_cover_the_error(truth):
    """Over 200 noisy trials, |fx error| < 2 sigma about 95 % of the time."""
    inside = []
    for seed in range(200):
        rng = np.random.default_rng(1000 + seed)
        X = points_in_view(truth, 60, rng)
        result = calibrate_dlt(X, truth.project(X) + rng.normal(0.0, 0.5, (60, 2)))
        inside.append(abs(result.K[0, 0] - truth.K[0, 0]) < 2 * result.sigmas["fx"])
    assert 0.9 < np.mean(inside) <= 1.0


def test_bad_inputs_each_named(truth):
    rng = np.random.default_rng(0)
    X = points_in_view(truth, 20, rng)
    x = truth.project(X)
    with pytest.raises(CamcalError, match="at least 6 correspondences, got 5"):
        calibrate_dlt(X[:5], x[:5])
    X_nan = X.copy()
    X_nan[3, 1] = np.nan
    with pytest.raises(CamcalError, match="NaN"):
        calibrate_dlt(X_nan, x)
    planar = X.copy()
    planar[:, 2] = 0.5
    with pytest.raises(CamcalError, match="coplanar"):
        calibrate_dlt(planar, truth.project(planar))
    line = np.outer(np.linspace(0, 1, 20), [1.0, 2.0, 0.5]) + [0.0, 0.0, 0.5]
    with pytest.raises(CamcalError, match="collinear"):
        calibrate_dlt(line, truth.project(line))
    with pytest.raises(CamcalError, match="got 20 3D points but 19"):
        calibrate_dlt(X, x[:19])
    with pytest.raises(CamcalError, match="from behind"):
        # a mirrored image (u -> -u) has no camera in front of the points
        calibrate_dlt(X, x * [-1.0, 1.0])
