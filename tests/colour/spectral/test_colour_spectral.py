import numpy as np
import pytest

from camcal.colour.spectral.data import CAMERAS, adapt_XYZ, illuminant_white_XYZ, reflectance_set
from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.colour.spectral.estimate import estimate_sensitivities, mu_factor
from camcal.base.errors import CamcalError


def test_mu_factor_is_one_for_a_colorimetric_camera():
    cam = SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65")
    luther = cam.cmfs @ np.array([[1.0, 0.2, 0.0], [0.3, 1.0, 0.1], [0.0, 0.4, 1.0]])
    assert mu_factor(luther, cam.cmfs) == pytest.approx(1.0, abs=1e-12)
    assert mu_factor(luther, cam.cmfs, cam.illuminant) == pytest.approx(1.0, abs=1e-12)


def test_mu_factor_of_the_two_measured_cameras():
    """Documented figures (equal energy / D65-weighted), see the README table."""
    values = {}
    for name in CAMERAS:
        cam = SimulatedCamera.from_colour(name, "D65")
        values[name] = (mu_factor(cam.sensitivities, cam.cmfs), mu_factor(cam.sensitivities, cam.cmfs, cam.illuminant))
        print(f"mu-factor {name}: {values[name][0]:.4f} (equal energy), {values[name][1]:.4f} (D65)")
    assert values["Nikon 5100 (NPL)"][0] == pytest.approx(0.9298, abs=1e-3)
    assert values["Sigma SDMerill (NPL)"][0] == pytest.approx(0.8082, abs=1e-3)
    for eq, d65 in values.values():
        assert 0 < eq < 1 and 0 < d65 < 1


def test_ssf_recovery_from_190_reflectances():
    """A known camera's sensitivities are recovered to < 10 % relative RMS."""
    for name in CAMERAS:
        cam = SimulatedCamera.from_colour(name, "D65")
        _, R = reflectance_set("rawtoaces 190", cam.wavelengths)
        RGB = cam.RGB(R, noise=0.002, seed=7)
        est = estimate_sensitivities(cam.stimulus(R), RGB, cam.wavelengths)
        truth = cam.effective_sensitivities
        per_channel = est.relative_rms_error(truth)
        overall = np.linalg.norm(est.sensitivities - truth) / np.linalg.norm(truth)
        print(f"SSF recovery {name}: R {per_channel[0]:.3f} G {per_channel[1]:.3f} B {per_channel[2]:.3f}, overall {overall:.3f}")
        assert overall < 0.10
        assert np.all(per_channel < 0.12)
        assert np.all(est.sensitivities >= 0)


def test_ssf_estimation_errors():
    with pytest.raises(CamcalError, match="at least 10 patches"):
        estimate_sensitivities(np.ones((5, 20)), np.ones((5, 3)), np.arange(20.0))
    with pytest.raises(CamcalError, match="do not agree"):
        estimate_sensitivities(np.ones((15, 20)), np.ones((15, 2)), np.arange(20.0))


def test_chromatic_adaptation_round_trip_and_white():
    D50, D65 = illuminant_white_XYZ("D50"), illuminant_white_XYZ("D65")
    XYZ = np.random.default_rng(0).uniform(0.05, 0.9, (10, 3))
    for transform in ("CAT02", "Bradford"):
        np.testing.assert_allclose(adapt_XYZ(D65, D65, D50, transform), D50, atol=1e-12)
        back = adapt_XYZ(adapt_XYZ(XYZ, D65, D50, transform), D50, D65, transform)
        np.testing.assert_allclose(back, XYZ, atol=1e-12)
    with pytest.raises(CamcalError, match="unknown adaptation"):
        adapt_XYZ(XYZ, D65, D50, "XYZ Scaling")


def test_simulated_camera_white():
    cam = SimulatedCamera.from_colour("Sigma SDMerill (NPL)", "A")
    assert cam.RGB_white[1] == pytest.approx(1.0)
    assert cam.white_XYZ[1] == pytest.approx(1.0)


def test_cie_2017_samples_are_colour_sciences_measured_spectra():
    """The 99 CIE 224:2017 samples on another grid equal colour-science's own 5 nm table at its wavelengths."""
    import colour
    from colour.quality.cfi2017 import load_TCS_CIE2017

    names, R = reflectance_set("CIE 2017 TCS", np.arange(360.0, 781.0, 10.0))
    table = load_TCS_CIE2017(colour.SpectralShape(380, 780, 5))
    assert len(names) == len(set(names)) == 99 and R.shape == (99, 43)
    np.testing.assert_allclose(R[:, 2:], table.values[::2].T, atol=1e-12)
    assert np.all(R[:, 0] == R[:, 2])  # extended with the end value below 380 nm
