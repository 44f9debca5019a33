"""Colour match, chart route: two simulated cameras with different measured sensitivities."""

from dataclasses import dataclass

import numpy as np
import pytest

from camcal.colour.fit.characterise import characterise
from camcal.colour.difference import delta_E
from camcal.colour.match.routes import match_charts
from camcal.report.colour_match import write_report
from camcal.colour.chart.patches import PatchSet
from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.colour.spectral.data import camera_sensitivities, reflectance_set
from camcal.base.errors import CamcalError


NOISE = 0.002


@dataclass
class Shot:
    RGB_train: np.ndarray
    RGB_test: np.ndarray
    XYZ_train: np.ndarray
    XYZ_test: np.ndarray
    names_train: list


@pytest.fixture(scope="module")
def cameras():
    """Nikon 5100 and Sigma SDMerill (NPL measured sensitivities) under D65 on ONE wavelength grid
    (the Sigma's, 400-680 nm), so both see the same reference XYZ: a ColorChecker (BabelColor
    average) for training and the 190 RAW-to-ACES reflectances as independent surfaces."""
    sigma = SimulatedCamera.from_colour("Sigma SDMerill (NPL)", "D65")
    grid = sigma.wavelengths
    _, nikon_sens = camera_sensitivities("Nikon 5100 (NPL)", grid)
    nikon = SimulatedCamera(grid, nikon_sens, sigma.illuminant, sigma.cmfs, "Nikon 5100 (NPL)", "D65")
    names, chart = reflectance_set("BabelColor Average", grid)
    _, others = reflectance_set("rawtoaces 190", grid)
    return tuple(Shot(cam.RGB(chart, NOISE, seed), cam.RGB(others, NOISE, seed + 100), cam.XYZ(chart),
                      cam.XYZ(others), names) for cam, seed in ((nikon, 0), (sigma, 1)))


def _fit(sim, model, name):
    return characterise(PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train), white="D65", model=model,
                        camera=name, loo=False).fit


@pytest.mark.parametrize("fit_model", ["matrix3x3", "root-polynomial:2"])
def test_camera_to_camera_residual_below_the_sum_of_own_errors(cameras, fit_model):
    nikon, sigma = cameras
    fit_A, fit_B = _fit(nikon, fit_model, "nikon"), _fit(sigma, fit_model, "sigma")
    result = match_charts(fit_B, fit_A, sigma.RGB_train, nikon.RGB_train, XYZ_reference=nikon.XYZ_train,
                          test=(sigma.RGB_test, nikon.RGB_test), model="root-polynomial:2")
    chart = result.match.evaluation["chart"]
    common = chart["common_reference"]["mean"]
    own_A, own_B = chart["target_vs_reference"]["mean"], chart["source_vs_reference"]["mean"]
    print(f"{fit_model}: camera-to-camera {common:.3f}, nikon {own_A:.3f}, sigma {own_B:.3f}")
    # both cameras saw the same reference; each one's own error is what its fit file reports
    np.testing.assert_array_equal(nikon.XYZ_train, sigma.XYZ_train)
    assert own_A == pytest.approx(fit_A.evaluation["train"]["mean"], rel=1e-9)
    assert own_B == pytest.approx(fit_B.evaluation["train"]["mean"], rel=1e-9)
    assert 0 < common < own_A + own_B
    # the residual is a real camera-to-camera difference: recompute it per patch
    dE = delta_E(fit_A.apply(nikon.RGB_train), fit_B.apply(sigma.RGB_train), fit_A.target_white_XYZ)
    assert common == pytest.approx(float(dE.mean()), rel=1e-12)
    # matching brings B close to A through A's characterisation, on the chart and on 190 other surfaces
    ev = result.match.evaluation
    assert ev["before"]["mean"] > 5 * ev["test"]["mean"]
    assert ev["train"]["mean"] < 1.2 * common


def test_matrix_fits_compose_exactly(cameras):
    nikon, sigma = cameras
    fit_A, fit_B = _fit(nikon, "matrix3x3", "nikon"), _fit(sigma, "matrix3x3", "sigma")
    result = match_charts(fit_B, fit_A, sigma.RGB_train, nikon.RGB_train)
    np.testing.assert_allclose(result.match.matrix, np.linalg.inv(fit_A.model.M) @ fit_B.model.M, atol=1e-10)
    assert result.match.source == "sigma" and result.match.target == "nikon"
    # with an exact composition, the match reproduces the common-reference residual
    ev = result.match.evaluation
    assert ev["train"]["mean"] == pytest.approx(ev["chart"]["common_reference"]["mean"], rel=1e-6)


def test_chart_report_and_bad_input(tmp_path, cameras):
    nikon, sigma = cameras
    fit_A, fit_B = _fit(nikon, "matrix3x3", "nikon"), _fit(sigma, "matrix3x3", "sigma")
    result = match_charts(fit_B, fit_A, sigma.RGB_train, nikon.RGB_train)
    names = {p.name for p in write_report(result, tmp_path)}
    assert {"swatches.png", "delta_E_histogram.png", "ab_errors.png", "summary.txt"} <= names
    with pytest.raises(CamcalError, match=r"\(N, 3\)"):
        match_charts(fit_B, fit_A, sigma.RGB_train, nikon.RGB_train[:-1])
    with pytest.raises(CamcalError, match="reference XYZ"):
        match_charts(fit_B, fit_A, sigma.RGB_train, nikon.RGB_train, XYZ_reference=nikon.XYZ_train[:3])
