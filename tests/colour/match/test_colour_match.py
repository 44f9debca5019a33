"""Colour match: model fitting, robustness on samples, the 3D LUT against OCIO, the match file."""

import json

import numpy as np
import pytest

from camcal.colour.match.record import ColourMatch, match_provenance
from camcal.io.colourfile import load_colour_file, load_match
from camcal.io.colourfile import FILE_KINDS, reader_of
from camcal.colour.match.models import Lut3DModel, parse_match_model
from camcal.colour.match.robust import fit_match_model
from camcal.base.errors import CamcalError
from camcal.io.colourfile import save_colour_file

M_TRUE = np.array([[1.10, -0.08, 0.03], [0.05, 0.93, 0.04], [-0.02, 0.09, 0.88]])


def _samples(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.03, 0.9, (n, 3))


def test_exact_data_recovers_matrix_and_root_polynomial():
    B = _samples()
    fit = fit_match_model(B, B @ M_TRUE.T, "matrix3x3", robust="none")
    np.testing.assert_allclose(fit.model.M, M_TRUE, atol=1e-12)
    root = np.sqrt(B[:, [0]] * B[:, [1]])
    A = B @ M_TRUE.T + 0.05 * root * np.array([1.0, -0.5, 0.2])
    fit = fit_match_model(B, A, "root-polynomial:2", robust="lmeds-irls")
    np.testing.assert_allclose(fit.model.apply(B), A, atol=1e-10)
    assert fit.inliers.all()


def test_lut_reproduces_a_smooth_nonlinear_map():
    B = _samples(6000)

    def G(b):
        x = b @ M_TRUE.T
        return x * (1 + 0.25 * (x - 0.45))

    fit = fit_match_model(B, G(B), "lut3d:9", robust="none")
    test = _samples(2000, seed=5)
    # Trilinear interpolation error bound: sum_i h_i^2 / 8 |d2 G_c / db_i^2| with
    # d2 G_c / db_i^2 = 0.5 M_ci^2; twice that leaves room for the smoothing bias.
    h = (fit.model.domain_max - fit.model.domain_min) / 8
    bound = max(np.sum(0.5 * M_TRUE[c] ** 2 * h**2 / 8) for c in range(3))
    assert np.max(np.abs(fit.model.apply(test) - G(test))) < 2 * bound
    matrix = fit_match_model(B, G(B), "matrix3x3", robust="none")
    assert np.mean(np.abs(fit.model.apply(test) - G(test))) < 0.1 * np.mean(np.abs(matrix.model.apply(test) - G(test)))


@pytest.mark.parametrize("model", ["matrix3x3", "root-polynomial:2"])
def test_robust_fit_ignores_gross_outliers_least_squares_does_not(model):
    rng = np.random.default_rng(3)
    B = _samples(4000, seed=3)
    sigma = 0.004
    A = (B @ M_TRUE.T) * (1 + sigma * rng.standard_normal(B.shape))
    bad = rng.random(len(B)) < 0.15
    A[bad] += rng.uniform(0.1, 0.4, (bad.sum(), 1))  # speculars: white added in A only
    test = _samples(1000, seed=9)
    truth = test @ M_TRUE.T
    robust = fit_match_model(B, A, model)
    plain = fit_match_model(B, A, model, robust="none")
    err_robust = np.abs(robust.model.apply(test) - truth).max()
    err_plain = np.abs(plain.model.apply(test) - truth).max()
    # the robust error is of the order of sigma / sqrt(inliers) (x 10 for the worst of 1000
    # test colours); least squares is pulled by the outliers
    assert err_robust < 10 * sigma / np.sqrt(len(B) * 0.85)
    assert err_plain > 20 * err_robust
    # relative residual scale: multiplicative noise sigma per channel, relative to mean(A)
    assert 0.5 * sigma < robust.sigma < 2 * sigma
    recall = np.mean(~robust.inliers[bad])
    false_alarm = np.mean(~robust.inliers[~bad])
    assert recall > 0.95 and false_alarm < 0.01


def test_lut_matches_opencolorio_lut3d():
    ocio = pytest.importorskip("PyOpenColorIO")
    rng = np.random.default_rng(1)
    size = 5
    table = rng.uniform(0, 1, (size, size, size, 3))
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0])
    lut = Lut3DModel(table, lo, hi, 1e-3)
    transform = ocio.Lut3DTransform(gridSize=size)
    transform.setInterpolation(ocio.INTERP_LINEAR)
    flat = lut.to_dict()["table"]
    for i in range(size):
        for j in range(size):
            for k in range(size):
                transform.setValue(i, j, k, *flat[(i * size + j) * size + k])
    cpu = ocio.Config.CreateRaw().getProcessor(transform).getDefaultCPUProcessor()
    x = rng.uniform(0, 1, (500, 3)).astype(np.float32)
    out = x.copy()
    cpu.applyRGB(out)
    np.testing.assert_allclose(lut.apply(x.astype(np.float64)), out, atol=2e-6)


def test_parse_match_model():
    assert parse_match_model("matrix3x3") == ("matrix3x3", None)
    assert parse_match_model("lut3d:33") == ("lut3d", 33)
    for bad in ("rbf", "lut3d:1", "lut3d:x", "matrix3x3:white-preserving", "root-polynomial:9"):
        with pytest.raises(CamcalError):
            parse_match_model(bad)


def test_bad_fit_inputs():
    B = _samples(100)
    with pytest.raises(CamcalError, match=r"\(N, 3\)"):
        fit_match_model(B, B[:, :2])
    C = B.copy()
    C[3, 1] = np.nan
    with pytest.raises(CamcalError, match="non-finite"):
        fit_match_model(B, C)
    with pytest.raises(CamcalError, match="needs at least"):
        fit_match_model(B[:5], B[:5])
    with pytest.raises(CamcalError, match="robust method"):
        fit_match_model(B, B, robust="ransac")


def _match(model):
    B = _samples(500)
    fit = fit_match_model(B, B @ M_TRUE.T, model, robust="none")
    stats = {"n": 10, "mean": 0.1, "median": 0.1, "p90": 0.2, "p95": 0.2, "max": 0.3}
    return ColourMatch(model=fit.model, evaluation={"metric": "CIE 2000", "space": "x", "train": stats,
                                                    "test": None, "before": None, "n_test_outliers": None,
                                                    "chart": None},
                       fit={"route": "image", "robust": "none", "n_fit": 500, "n_inliers": 500,
                            "inlier_threshold": None},
                       source="right", target="left", provenance=match_provenance(None))


@pytest.mark.parametrize("model", ["matrix3x3", "root-polynomial:2", "lut3d:5"])
def test_match_file_round_trip(tmp_path, model):
    match = _match(model)
    path = save_colour_file(match, tmp_path / "m.colour.json")
    back = load_match(path)
    assert back == match
    assert isinstance(load_colour_file(path), ColourMatch)
    assert FILE_KINDS["match"] is ColourMatch
    assert reader_of("match") == ColourMatch.from_dict
    x = _samples(50, seed=2)
    np.testing.assert_array_equal(back.apply(x), match.apply(x))
    if model == "matrix3x3":
        np.testing.assert_allclose(back.matrix, M_TRUE, atol=1e-12)
        np.testing.assert_array_equal(back.apply(x), x @ back.matrix.T)
    else:
        assert back.matrix is None


def test_match_file_errors_name_the_field(tmp_path):
    data = _match("matrix3x3").to_dict()
    cases = [
        (lambda d: d["model"].update(coefficients=[[1, 0, 0], [0, 1, 0]]), "model.coefficients"),
        (lambda d: d["model"].update(kind="rbf"), "model.kind"),
        (lambda d: d["fit"].update(route="magic"), "fit.route"),
        (lambda d: d.update(extra=1), "unknown key 'extra'"),
        (lambda d: d["evaluation"].pop("train"), "evaluation: missing key 'train'"),
        (lambda d: d["model"].update(terms=["R", "G", "X"]), "model.terms"),
    ]
    for change, message in cases:
        bad = json.loads(json.dumps(data))
        change(bad)
        path = tmp_path / "bad.colour.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(CamcalError, match=message.replace("(", r"\(").replace(")", r"\)")):
            load_match(path)
    lut = _match("lut3d:3").to_dict()
    lut["model"]["table"] = lut["model"]["table"][:-1]
    path = tmp_path / "lut.colour.json"
    path.write_text(json.dumps(lut))
    with pytest.raises(CamcalError, match="model.table"):
        load_colour_file(path)
