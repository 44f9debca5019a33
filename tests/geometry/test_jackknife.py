"""Delete-one-frame jackknife of the bundle adjustment, against errors the test constructs."""

import dataclasses

import numpy as np
import pytest
from test_selfcal import stereo_rig, tracks_state

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, bundle_adjust
from camcal.geometry.jackknife import FrameJackknife, frame_jackknife, interval_factor, without_frames

OPTIONS = BundleOptions(refine_principal_point=True)


def test_jackknife_agrees_with_the_covariance_on_independent_noise():
    # Gaussian noise, independent per observation: both estimate the same spread; the jackknife over
    # n = 10 frames is itself uncertain by about 1 / sqrt(2 (n - 1)) = 24 %
    state = tracks_state(stereo_rig(), np.random.default_rng(3), n_points=1200)
    full = bundle_adjust(state, OPTIONS)
    spread = frame_jackknife(full, OPTIONS)
    assert spread.n_frames == spread.n_groups == 10
    assert set(spread.sigmas) == set(full.sigmas)
    ratios = np.array([spread.sigmas[key] / full.sigmas[key] for key in full.sigmas if not key.endswith("baseline_rel")])
    print({key: round(spread.sigmas[key] / full.sigmas[key], 2) for key in full.sigmas})
    assert 0.75 < np.exp(np.mean(np.log(ratios))) < 1.4  # the jackknife errs high (Efron & Stein 1981)
    assert np.all((ratios > 0.4) & (ratios < 2.0))


def test_jackknife_sees_errors_shared_by_an_image_that_the_covariance_misses():
    # each image's features scaled about the principal point by (1 + e_i), e_i ~ N(0, 1e-3): what a focus
    # breathing or a per-image feature bias does. Each image then says f (1 + e_i): over 10 frames the
    # focal length is uncertain by about f 1e-3 / sqrt(10), while the residuals stay small and the
    # covariance sigma says far less
    rng = np.random.default_rng(11)
    cameras = stereo_rig()
    state = tracks_state(cameras, rng, n_points=1200, noise_px=0.1)
    xy = state.obs_xy.copy()
    for camera, truth in enumerate(cameras):
        for frame in range(10):
            mine = (state.obs_camera == camera) & (state.obs_frame == frame)
            xy[mine] = truth.K[:2, 2] + (xy[mine] - truth.K[:2, 2]) * (1 + 1e-3 * rng.standard_normal())
    state = dataclasses.replace(state, obs_xy=xy)
    full = bundle_adjust(state, OPTIONS)
    spread = frame_jackknife(full, OPTIONS)
    for truth in cameras:
        expected = truth.K[0, 0] * 1e-3 / np.sqrt(10)
        covariance, jackknife = full.sigmas[f"{truth.name}.f"], spread.sigmas[f"{truth.name}.f"]
        print(f"{truth.name}: sigma(f) covariance {covariance:.3f} px, jackknife {jackknife:.3f} px, "
              f"expected about {expected:.3f} px")
        assert covariance < 0.5 * expected
        assert 0.4 * expected < jackknife < 2.0 * expected


def test_one_gauss_newton_step_per_frame_matches_full_refits():
    # the default replicates (one Gauss-Newton step from the full solution) against full refits: the frame's
    # influence is small, so the step lands within a few percent of the refit's move, and the sigmas agree
    state = tracks_state(stereo_rig(), np.random.default_rng(5), n_frames=6, n_points=500)
    full = bundle_adjust(state, OPTIONS)
    step, refit = frame_jackknife(full, OPTIONS), frame_jackknife(full, OPTIONS, method="refit")
    assert (step.method, refit.method) == ("step", "refit") and set(step.sigmas) == set(refit.sigmas)
    for key, value in refit.sigmas.items():
        assert step.sigmas[key] == pytest.approx(value, rel=0.05), key
    for key, moved in refit.replicates.items():
        spread = np.max(np.abs(moved - moved.mean(axis=0)))
        assert np.max(np.abs(step.replicates[key] - moved)) < 0.05 * spread, key
    with pytest.raises(CamcalError, match="unknown jackknife method"):
        frame_jackknife(full, OPTIONS, method="magic")


@pytest.mark.parametrize("n", [5, 10, 20])
def test_widened_sigmas_cover_as_tukeys_t_interval(n):
    # the jackknife of a mean over n groups is s / sqrt(n), exactly Student-t with n - 1 degrees of freedom:
    # 1.96 plain sigmas cover 88 % at n = 5, 92 % at 10, 93 % at 20; 1.96 widened ones 95 %
    rng = np.random.default_rng(n)
    samples = rng.normal(0.0, 1.0, (20000, n))
    replicates = (samples.sum(axis=1, keepdims=True) - samples) / (n - 1)  # each group left out in turn
    plain = np.sqrt((n - 1) / n * np.sum((replicates - replicates.mean(axis=1, keepdims=True)) ** 2, axis=1))
    error = np.abs(samples.mean(axis=1))
    widened = plain * interval_factor(n)
    assert FrameJackknife({"x": 2.0}, {}, n, n).widened_sigmas == {"x": 2.0 * interval_factor(n)}
    assert np.mean(error < 1.96 * widened) == pytest.approx(0.95, abs=0.006)
    assert np.mean(error < 1.96 * plain) < 0.95 - 0.25 / n  # the plain sigmas fall short by about 0.35 / n
    assert np.mean(error < 2 * plain) < 0.95


def test_without_frames_drops_observations_and_the_points_they_leave_alone():
    state = tracks_state(stereo_rig(), np.random.default_rng(0), n_frames=5, n_points=300)
    reduced = without_frames(state, np.array([1, 3]))
    assert not np.isin(reduced.obs_frame, [1, 3]).any()
    assert np.bincount(reduced.obs_point).min() >= 2 and reduced.obs_point.max() == len(reduced.points) - 1
    kept = ~np.isin(state.obs_frame, [1, 3])
    assert len(reduced.obs_xy) <= kept.sum() and len(reduced.point_ids) == len(reduced.points)


def test_jackknife_needs_five_frames():
    state = tracks_state(stereo_rig(), np.random.default_rng(0), n_frames=4, n_points=300)
    full = bundle_adjust(state, dataclasses.replace(OPTIONS, compute_sigmas=False))
    with pytest.raises(CamcalError, match="the frame jackknife needs at least 5 frames with observations, got 4"):
        frame_jackknife(full, OPTIONS)
