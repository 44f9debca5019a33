"""The readout time estimated by a rolling-shutter bundle adjustment, against plates synthesised with a known one."""

from __future__ import annotations

import numpy as np
import pytest
from tests.geometry.rolling_shutter_plates import plate

from camcal.base.errors import CamcalError
from camcal.geometry.rolling_shutter_ba import estimate_readout

TRUE_READOUT = 0.025  # s


def _z_scores(motion: str, n_frames: int, seeds: range) -> np.ndarray:
    """``(estimate - truth) / sigma`` of plates read out in 25 ms, one per seed, each checked for what it says."""
    estimates = [estimate_readout(*plate(TRUE_READOUT, motion, seed, n_frames=n_frames).estimate_arguments())
                 for seed in seeds]
    assert all(e.determined for e in estimates)
    assert all(0.05e-3 < e.sigma_s < 2e-3 for e in estimates)  # a useful precision, well under the frame interval
    assert all(e.sigma_s == max(e.noise_sigma_s, e.jackknife_sigma_s) for e in estimates)
    assert all(0.5 < e.rms_px < 0.9 for e in estimates)  # the noise (0.5 px a coordinate), nothing left over
    return np.array([(e.readout_s - TRUE_READOUT) / e.sigma_s for e in estimates])


@pytest.mark.parametrize(("motion", "n_frames"), [("turning", 12), ("shaking", 24)])
def test_the_readouts_sigma_covers_its_error_over_seeds(motion, n_frames):
    """Four noisy handheld plates read out in 25 ms, one walking and panning, one with a 3 Hz tremor besides (the
    central differences' velocities then 6.6 % slow, the readout as much high: 2.5 noise sigmas on 24 frames unless
    corrected): each estimate within 3 sigma of the truth, and the sigmas describe the errors (their normalised
    squares average near 1: a chi-square of 4 degrees of freedom over 4 lies in [0.05, 3.3] 99 % of the time)."""
    z = _z_scores(motion, n_frames, range(4))
    assert np.all(np.abs(z) < 3.0), z
    assert 0.05 < np.mean(z ** 2) < 3.3, z


@pytest.mark.slow
@pytest.mark.parametrize(("motion", "n_frames"), [("turning", 12), ("shaking", 24), ("turning", 48)])
def test_the_readouts_sigma_covers_its_error_over_many_seeds(motion, n_frames):
    """The fast test over 20 seeds: the RMS of the normalised errors within the 99 % band of a chi-square of 20
    degrees of freedom ([0.61, 1.37]) and their mean within 3 standard errors of 0."""
    z = _z_scores(motion, n_frames, range(100, 120))
    assert 0.61 < np.sqrt(np.mean(z ** 2)) < 1.37, z
    assert abs(np.mean(z)) < 3.0 / np.sqrt(len(z)), z


def test_a_global_shutter_plate_gives_zero_within_its_sigma():
    for seed in (10, 11):
        estimate = estimate_readout(*plate(0.0, "turning", seed).estimate_arguments())
        assert estimate.determined
        assert abs(estimate.readout_s) < 3.0 * estimate.sigma_s < 3e-3


@pytest.mark.parametrize("motion", ["sideways", "forward"])
def test_straight_constant_motion_does_not_determine_the_readout(motion):
    """A dolly or a drive at a constant speed without a turn: the shutter is a deformation of the scene the points
    absorb, the readout's sigma far beyond the bound (a tenth of the frame interval)."""
    estimate = estimate_readout(*plate(TRUE_READOUT, motion, 3).estimate_arguments())
    assert not estimate.determined
    assert estimate.sigma_s > 3.0 * estimate.limit_s
    assert estimate.limit_s == pytest.approx(0.1 / 30.0)


def test_the_estimate_keeps_the_longest_tracks_when_capped():
    """Capped at 400 observations, the adjustment keeps the points seen in the most frames up to that many
    observations and still finds the readout."""
    synthetic = plate(TRUE_READOUT, "turning", 4)
    estimate = estimate_readout(*synthetic.estimate_arguments(), max_observations=400)
    counts = np.sort(np.bincount(synthetic.point_of))[::-1]
    longest = counts[np.cumsum(counts) <= 400]
    assert (estimate.n_points, estimate.n_observations) == (len(longest), longest.sum())
    assert 350 < estimate.n_observations <= 400
    assert abs(estimate.readout_s - TRUE_READOUT) < 3.0 * estimate.sigma_s


def test_too_few_frames_or_mismatched_observations_are_refused():
    arguments = list(plate(TRUE_READOUT, "turning", 0, n_frames=3).estimate_arguments())
    short = [a[:2] if k in (2, 3, 4) else a for k, a in enumerate(arguments)]
    with pytest.raises(CamcalError, match="at least 3 solved frames, got 2"):
        estimate_readout(*short)
    arguments[9] = arguments[9][:-1]
    with pytest.raises(CamcalError, match="differ in length"):
        estimate_readout(*arguments)
