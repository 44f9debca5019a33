"""Gaussian priors on intrinsics in the bundle adjustment: the posterior is the prior where the images say
nothing, the images where they are strong, and their information-weighted mean in between."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, PriorSpec, bundle_adjust, parse_prior
from camcal.geometry.bundle.prior import UNDETERMINED_RATIO
from tests.geometry.test_selfcal import intrinsics, stereo_rig, tracks_state

FREE_PP = BundleOptions(refine_principal_point=True)


@pytest.fixture(scope="module")
def orbit():
    """Synthetic tracks of a rig orbiting the set (strong geometry), its truth and the fit without priors."""
    cameras = stereo_rig()
    state = tracks_state(cameras, np.random.default_rng(11), n_frames=6, n_points=900)
    return cameras, state, bundle_adjust(state, FREE_PP)


@pytest.fixture(scope="module")
def lateral():
    """A long lens slid sideways without turning: the principal point is a rotation of every view."""
    cameras = stereo_rig(f=4000.0, lam=(0.0, 0.0))
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    poses = [(R, np.array([-26.7, 3.0 + 0.3 * i, 1.5])) for i in range(4)]
    return cameras, tracks_state(cameras, np.random.default_rng(7), poses=poses, n_points=800)


def test_the_posterior_is_the_prior_where_the_images_say_nothing(lateral):
    cameras, state = lateral
    spec = PriorSpec("left", "cx", 470.0, 12.0)
    result = bundle_adjust(state, BundleOptions(refine_principal_point=True, priors=(spec,), default_priors=True))
    solved = intrinsics(result.state, 0)
    print(result.summary())
    # the images barely move it from the prior and leave the prior's sigma (the given prior replaced the default)
    assert abs(solved.K[0, 2] - 470.0) < 0.3 * 12.0
    assert UNDETERMINED_RATIO * 12.0 < result.sigmas["left.cx"] <= 12.0
    assert "left.cx: the images barely determine it: posterior sigma" in result.summary()
    assert sum(p.spec.label == "left.cx" for p in result.priors) == 1
    # and it still covers the truth, 6.5 px from the centre
    assert abs(solved.K[0, 2] - cameras[0].K[0, 2]) < 2 * result.sigmas["left.cx"]


def test_the_images_win_where_they_are_strong(orbit):
    cameras, state, free = orbit
    f_data, sigma_data = free.state.params[0][0], free.sigmas["left.f"]
    # a prior 5 % off with a sigma of 100 data sigmas: the posterior barely notices it
    wide = PriorSpec("left", "f", 1.05 * f_data, 100 * sigma_data)
    result = bundle_adjust(state, BundleOptions(refine_principal_point=True, priors=(wide,)))
    assert abs(result.state.params[0][0] - f_data) < 0.05 * sigma_data
    assert result.sigmas["left.f"] == pytest.approx(sigma_data, rel=1e-3)
    assert abs(result.state.params[0][0] - cameras[0].K[0, 0]) < 4 * result.sigmas["left.f"]
    assert "barely determine" not in result.summary()


def test_posterior_of_equal_informations_is_the_mean_with_sigma_over_root_two(orbit):
    # a prior as informative as the images, 3 sigma away: mean half-way, sigma / sqrt(2) (linear Gaussian update)
    _, state, free = orbit
    f_data, sigma_data = free.state.params[0][0], free.sigmas["left.f"]
    spec = PriorSpec("left", "f", f_data + 3 * sigma_data, sigma_data)
    result = bundle_adjust(state, BundleOptions(refine_principal_point=True, priors=(spec,),
                                                prior_noise_px=float(np.sqrt(2 * free.final_cost / (free.n_residuals - free.n_parameters)))))
    assert result.state.params[0][0] == pytest.approx(f_data + 1.5 * sigma_data, abs=0.1 * sigma_data)
    assert result.sigmas["left.f"] == pytest.approx(sigma_data / np.sqrt(2), rel=0.05)
    assert result.prior_posterior_sigmas[0] == pytest.approx(result.sigmas["left.f"])


def test_priors_on_the_lens_and_in_camcal_conventions(orbit):
    cameras, state, free = orbit
    # lambda in camcal's pixel units becomes COLMAP's k = lambda f^2; cx and cy carry the half pixel
    truth = cameras[0]
    tight = (PriorSpec("left", "lambda", truth.distortion.params["lambda"], 1e-12),
             PriorSpec("left", "cy", truth.K[1, 2], 1e-3))
    result = bundle_adjust(state, BundleOptions(refine_principal_point=True, priors=tight))
    solved = intrinsics(result.state, 0)
    # COLMAP's k = lambda f^2 at the start's focal length f0 (documented linearisation): lambda f^2 = lambda_0 f0^2
    f0, f = state.params[0][0], result.state.params[0][0]
    assert solved.distortion.params["lambda"] == pytest.approx(truth.distortion.params["lambda"] * (f0 / f) ** 2, rel=1e-4)
    assert solved.K[1, 2] == pytest.approx(truth.K[1, 2], abs=0.01)
    # the division model has no k1: said, not applied
    unused = bundle_adjust(state, BundleOptions(refine_principal_point=True, compute_sigmas=False,
                                                priors=(PriorSpec("left", "k1", 0.0, 0.1),)))
    assert [spec.label for spec in unused.unused_priors] == ["left.k1"]
    assert "prior on left.k1 not used" in unused.summary()


def test_parse_prior():
    assert parse_prior("left.f=1200+-30") == PriorSpec("left", "f", 1200.0, 30.0)
    assert parse_prior(" cam 2.lambda = -1.5e-7 +- 1e-8") == PriorSpec("cam 2", "lambda", -1.5e-7, 1e-8)
    for bad, message in (("left.f=1200", "expected CAMERA.NAME=MEAN"), ("left.f=a+-3", "must be numbers"),
                         ("left.zoom=1+-1", "unknown intrinsic"), ("left.f=1200+-0", "sigma positive")):
        with pytest.raises(CamcalError, match=message):
            parse_prior(bad)


def test_prior_on_an_unknown_camera_is_an_error(orbit):
    _, state, _ = orbit
    with pytest.raises(CamcalError, match="no camera named 'middle'"):
        bundle_adjust(state, BundleOptions(priors=(PriorSpec("middle", "f", 600.0, 10.0),)))
