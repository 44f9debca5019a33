import numpy as np
import pytest

from camcal.colour.chart.linearise import ChannelCurve, Linearisation, fit_linearisation, named_function
from camcal.base.errors import CamcalError

Y = np.array([0.031, 0.090, 0.19, 0.36, 0.59, 0.90])


def encode(Y, gamma, offset, gain):
    return (Y / gain) ** (1 / gamma) + offset


def test_gamma_offset_recovers_known_curve():
    params = [(2.2, 0.02, 1.1), (1.8, -0.01, 0.9), (2.5, 0.0, 1.0)]
    codes = np.column_stack([encode(Y, *p) for p in params])
    lin = fit_linearisation(codes, Y, "gamma-offset")
    for curve, (gamma, offset, gain) in zip(lin.channels, params):
        assert curve.params["gamma"] == pytest.approx(gamma, rel=1e-5)
        assert curve.params["offset"] == pytest.approx(offset, abs=1e-6)
        assert curve.params["gain"] == pytest.approx(gain, rel=1e-5)
    assert lin.residual < 1e-6


def test_lut1d_passes_through_neutrals_and_is_monotone():
    import colour

    codes = np.repeat(colour.cctf_encoding(Y, "sRGB")[:, None], 3, axis=1) ** 1.1  # not a pure gamma
    lin = fit_linearisation(codes, Y, "lut1d")
    np.testing.assert_allclose(lin.apply(codes), np.repeat(Y[:, None], 3, axis=1), rtol=2e-3)
    x = np.linspace(-0.1, 1.1, 500)
    for curve in lin.channels:
        assert np.all(np.diff(curve.apply(x)) >= 0)


def test_named_srgb_is_colour_science_decoding_with_white_balance():
    import colour

    codes = np.column_stack([colour.cctf_encoding(Y * k, "sRGB") for k in (0.8, 1.0, 1.3)])
    lin = fit_linearisation(codes, Y, "named:srgb")
    assert [c.params["function"] for c in lin.channels] == ["sRGB"] * 3
    np.testing.assert_allclose(lin.apply(codes), np.repeat(Y[:, None], 3, axis=1), rtol=1e-9)


def test_identity_and_round_trip():
    lin = Linearisation.identity()
    assert lin.is_identity
    x = np.random.default_rng(0).random((5, 3))
    np.testing.assert_array_equal(lin.apply(x), x)
    for kind in ("gamma-offset", "lut1d", "named:ITU-R BT.709"):
        fitted = fit_linearisation(np.column_stack([Y ** 0.45] * 3), Y, kind)
        assert Linearisation.from_dict(fitted.to_dict()) == fitted


def test_errors():
    with pytest.raises(CamcalError, match="unknown transfer function"):
        named_function("sRBG")
    with pytest.raises(CamcalError, match="unknown linearisation"):
        fit_linearisation(np.ones((3, 3)) * 0.5, np.ones(3) * 0.2, "spline")
    with pytest.raises(CamcalError, match="at least 3 unclipped"):
        fit_linearisation(np.ones((3, 3)), Y[:3], "gamma-offset")
    with pytest.raises(CamcalError, match="non-decreasing"):
        ChannelCurve("lut1d", {"samples": (0.0, 0.5, 0.4)})
