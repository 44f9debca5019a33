"""Distortion models: round trips, peers (OpenCV), closed forms, bad input."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion

W, H = 1920, 1080
K = np.array([[1400.0, 0.0, 965.2], [0.0, 1395.0, 538.9], [0.0, 0.0, 1.0]])


def frame_grid(step: int = 40, overscan: float = 0.0) -> np.ndarray:
    """Pixel grid over the whole frame (optionally beyond it)."""
    u = np.arange(-overscan * W, (1 + overscan) * W, step)
    v = np.arange(-overscan * H, (1 + overscan) * H, step)
    return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2).astype(np.float64)


MODELS = [
    Distortion("polynomial", {"k1": -0.12, "k2": 0.03}),
    Distortion("polynomial", {"k1": 0.08, "k2": -0.01, "k3": 0.002}),
    Distortion("opencv", {"k1": -0.2, "k2": 0.05, "p1": 0.001, "p2": -0.0007, "k3": -0.004}),
    Distortion("division", {"lambda": -1.5e-7}, center=(950.0, 545.0)),
    Distortion("division", {"lambda": 8e-8}),
    Distortion.none(),
]


@pytest.mark.parametrize("model", MODELS, ids=lambda d: f"{d.model}:{dict(d.params)}")
def test_round_trip_over_the_frame(model):
    undistorted = frame_grid()
    distorted = model.distort(undistorted, K)
    assert np.all(np.isfinite(distorted))
    assert np.abs(model.undistort(distorted, K) - undistorted).max() < 1e-8
    # and the other way: distorted pixels of the frame back and forth
    grid = frame_grid()
    assert np.abs(model.distort(model.undistort(grid, K), K) - grid).max() < 1e-8


def test_opencv_model_matches_cv2_projection_and_undistortion():
    model = MODELS[2]
    p = model.params
    coeffs = np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"]])
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.6, 0.6, (200, 2)), np.ones(200)]) * rng.uniform(1, 5, (200, 1))
    cv_pixels, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, coeffs)
    ideal = (X / X[:, 2:]) @ K.T
    assert np.abs(model.distort(ideal[:, :2], K) - cv_pixels.reshape(-1, 2)).max() < 1e-9
    # OpenCV's undistortPoints iterates a fixed number of times; ask for tight criteria
    # (OpenCV 5 folded undistortPointsIter into undistortPoints' criteria argument).
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    undistort_iter = getattr(cv2, "undistortPointsIter", None)
    if undistort_iter is not None:
        cv_undistorted = undistort_iter(cv_pixels, K, coeffs, None, K, criteria)
    else:
        cv_undistorted = cv2.undistortPoints(cv_pixels, K, coeffs, R=None, P=K, criteria=criteria)
    cv_undistorted = cv_undistorted.reshape(-1, 2)
    assert np.abs(model.undistort(cv_pixels.reshape(-1, 2), K) - cv_undistorted).max() < 1e-6


def test_polynomial_is_opencv_without_tangential_terms():
    poly = Distortion("polynomial", {"k1": -0.1, "k2": 0.02, "k3": 0.001})
    brown = Distortion("opencv", {"k1": -0.1, "k2": 0.02, "p1": 0.0, "p2": 0.0, "k3": 0.001})
    grid = frame_grid()
    assert np.array_equal(poly.distort(grid, K), brown.distort(grid, K))


def test_division_model_definition_and_closed_form():
    """x_u = c + (x_d - c) / (1 + lambda r_d^2), with r_d measured in pixels."""
    lam, centre = -2e-7, np.array([940.0, 520.0])
    model = Distortion("division", {"lambda": lam}, center=tuple(centre))
    distorted = np.array([[1800.0, 1000.0], [100.0, 50.0], [940.0, 520.0]])
    r2 = np.sum((distorted - centre) ** 2, axis=1, keepdims=True)
    expected = centre + (distorted - centre) / (1 + lam * r2)
    assert np.allclose(model.undistort(distorted, K), expected, rtol=0, atol=1e-12)
    assert np.allclose(model.distort(expected, K), distorted, rtol=0, atol=1e-9)
    # barrel: undistorted points lie further out than distorted ones
    assert np.linalg.norm(expected[0] - centre) > np.linalg.norm(distorted[0] - centre)


def test_division_default_centre_is_principal_point():
    model = Distortion("division", {"lambda": 1e-7})
    assert np.allclose(model.distort(K[:2, 2][None], K), K[:2, 2][None])


def test_division_out_of_range_is_nan():
    model = Distortion("division", {"lambda": 1e-6})
    # 1 - 4 lambda r^2 < 0 beyond r = 500 px: no distorted point maps there
    far = K[:2, 2] + np.array([[600.0, 0.0]])
    assert np.all(np.isnan(model.distort(far, K)))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(model="poly", params={}), "unknown distortion model 'poly'"),
        (dict(model="polynomial", params={"k1": 0.1}), "needs parameter"),
        (dict(model="division", params={"lambda": 1e-7, "k1": 0.1}), "no parameter"),
        (dict(model="division", params={"lambda": float("nan")}), "not finite"),
        (dict(model="division", params={"lambda": "x"}), "must be a number"),
        (dict(model="polynomial", params={"k1": 0.1, "k2": 0.0}, center=(1.0, 2.0)), "only to the division"),
        (dict(model="division", params={"lambda": 1e-7}, center=(1.0, float("inf"))), "finite"),
    ],
)
def test_bad_parameters_are_named(kwargs, message):
    with pytest.raises(CamcalError, match=message):
        Distortion(**kwargs)


def test_dict_round_trip_and_unknown_keys():
    for model in MODELS:
        assert Distortion.from_dict(model.to_dict()) == model
    with pytest.raises(CamcalError, match="unknown key"):
        Distortion.from_dict({"model": "none", "params": {}, "centre": [0, 0]})
    with pytest.raises(CamcalError, match="shape"):
        MODELS[0].distort(np.zeros((3, 3)), K)


# -- fits between models ------------------------------------------------------------

from camcal.model.distortion import fit_distortion  # noqa: E402


def test_fit_recovers_a_model_of_the_same_kind():
    for truth, kwargs in [
        (Distortion("division", {"lambda": -1.2e-7}, center=(940.0, 551.0)), dict(fit_center=True)),
        (Distortion("polynomial", {"k1": -0.11, "k2": 0.025}), {}),
        (MODELS[2], {}),
    ]:
        fit = fit_distortion(truth, K, (W, H), truth.model, **kwargs)
        assert fit.max_px < 1e-6
        for name, value in truth.params.items():
            assert abs(fit.distortion.params[name] - value) <= 1e-6 * max(abs(value), 1e-3)
        if truth.center is not None:
            assert np.allclose(fit.distortion.center, truth.center, atol=1e-4)


def test_fit_reports_its_true_residual_over_the_frame():
    """The reported max / RMS equal an independent evaluation on a finer grid (to grid sampling)."""
    source = Distortion("polynomial", {"k1": -0.12, "k2": 0.03})
    fit = fit_distortion(source, K, (W, H), "division", fit_center=True)
    distorted = frame_grid(step=5)
    distorted = distorted[(distorted[:, 0] <= W - 1) & (distorted[:, 1] <= H - 1)]
    ideal = source.undistort(distorted, K)
    distance = np.linalg.norm(fit.distortion.distort(ideal, K) - distorted, axis=1)
    assert fit.max_px == pytest.approx(distance.max(), rel=0.05)
    # the RMS depends on the grid (the fit's always includes the last row and column)
    assert fit.rms_px == pytest.approx(np.sqrt(np.mean(distance**2)), rel=0.1)
    # one parameter cannot follow k1 and k2 exactly; it gets most of the way
    assert 0.05 < fit.max_px < 5.0
    none_max = np.linalg.norm(ideal - distorted, axis=1).max()
    assert fit.max_px < 0.1 * none_max


def test_richer_targets_fit_better():
    source = Distortion("division", {"lambda": -1.5e-7})
    two = fit_distortion(source, K, (W, H), "polynomial")
    three = fit_distortion(source, K, (W, H), "polynomial", with_k3=True)
    brown = fit_distortion(source, K, (W, H), "opencv")
    assert three.max_px < two.max_px and brown.rms_px <= three.rms_px * 1.001
    # the opencv fit of a radial lens has (nearly) no tangential part
    assert abs(brown.distortion.params["p1"]) < 1e-4 and abs(brown.distortion.params["p2"]) < 1e-4


def test_fit_bad_arguments():
    with pytest.raises(CamcalError, match="cannot fit model 'none'"):
        fit_distortion(MODELS[0], K, (W, H), "none")
    with pytest.raises(CamcalError, match="fit_center applies only"):
        fit_distortion(MODELS[0], K, (W, H), "polynomial", fit_center=True)


@pytest.mark.parametrize("model", ["polynomial", "opencv"])
def test_a_pixel_on_the_lens_fold_has_no_inverse(model):
    """k1 = -1/3 folds at r = 1 (d r_d / d r = 1 + 3 k1 r^2 = 0): the Newton inverse of a pixel there is NaN, not a
    point billions of pixels away (it was 7e9 px) nor an error; a pixel inside the fold still round-trips."""
    params = {"k1": -1 / 3, "k2": 0.0} | ({"p1": 0.0, "p2": 0.0, "k3": 0.0} if model == "opencv" else {})
    lens = Distortion(model, params)
    camera_K = np.array([[1000.0, 0.0, 500.0], [0.0, 1000.0, 400.0], [0.0, 0.0, 1.0]])
    inside, on_fold_x, on_fold_y = lens.undistort(np.array([[600.0, 400.0], [1500.0, 400.0], [500.0, 1400.0]]), camera_K)
    assert np.abs(lens.distort(inside[None], camera_K)[0] - [600.0, 400.0]).max() < 1e-8
    assert np.isnan(on_fold_x).all() and np.isnan(on_fold_y).all()
