import numpy as np
import pytest
from colour.characterisation import matrix_augmented_Cheung2004, polynomial_expansion_Finlayson2015

from camcal.colour.difference import delta_E
from camcal.colour.fit.terms import CHEUNG_TERMS, expand, parse_model_spec, terms_Cheung2004, terms_Finlayson2015
from camcal.colour.fit.models import LinearTermsModel, RBFModel, model_from_dict
from camcal.colour.fit.fitting import delta_E2000_components, fit_model
from camcal.base.errors import CamcalError

RNG = np.random.default_rng(3)
RGB = RNG.uniform(0.02, 1.0, (40, 3))


@pytest.mark.parametrize("n", CHEUNG_TERMS)
def test_cheung_terms_match_colour_science(n):
    ours = expand(RGB, terms_Cheung2004(n))
    theirs = matrix_augmented_Cheung2004(RGB, terms=n)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12)


def test_seed_3x10_terms():
    assert terms_Cheung2004(10) == ("R", "G", "B", "R*G", "R*B", "G*B", "R^2", "G^2", "B^2", "1")


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_root_polynomial_terms_match_colour_science(degree):
    ours = expand(RGB, terms_Finlayson2015(degree))
    theirs = polynomial_expansion_Finlayson2015(RGB, degree=degree, root_polynomial_expansion=True)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12)


def test_root_polynomial_is_exposure_invariant():
    XYZ = RGB @ np.array([[0.4, 0.3, 0.2], [0.2, 0.7, 0.1], [0.0, 0.1, 0.9]]).T + 0.05 * np.sqrt(RGB[:, :1] * RGB[:, 1:2])
    model = fit_model("root-polynomial:3", RGB, XYZ, regularisation=1e-6)
    np.testing.assert_allclose(model.apply(3.7 * RGB[:5]), 3.7 * model.apply(RGB[:5]), rtol=1e-12)


def test_matrix_recovered_exactly_without_noise():
    M = np.array([[0.41, 0.36, 0.18], [0.21, 0.72, 0.07], [0.02, 0.12, 0.95]])
    model = fit_model("matrix3x3", RGB, RGB @ M.T)
    np.testing.assert_allclose(model.M, M, atol=1e-12)


def test_polynomial_recovered_exactly_without_noise():
    terms = terms_Cheung2004(10)
    M = RNG.normal(0, 0.3, (3, 10))
    model = fit_model("polynomial:10", RGB, expand(RGB, terms) @ M.T)
    np.testing.assert_allclose(model.M, M, atol=1e-9)


def test_white_preserving_maps_white_exactly(sim):
    white_rgb = sim.camera.RGB_white
    for spec in ("matrix3x3:white-preserving", "root-polynomial:2:white-preserving"):
        for objective in ("xyz", "de2000"):
            model = fit_model(spec, sim.RGB_train, sim.XYZ_train, objective=objective,
                              white_XYZ=sim.white, RGB_white=white_rgb)
            np.testing.assert_allclose(model.apply(white_rgb[None])[0], sim.white, atol=1e-12)
            assert model.white_preserving


def test_white_preserving_needs_white():
    with pytest.raises(CamcalError, match="white"):
        fit_model("matrix3x3:white-preserving", RGB, RGB)


def test_de2000_objective_lowers_training_delta_E(sim):
    for spec in ("matrix3x3", "root-polynomial:2"):
        xyz = fit_model(spec, sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white)
        de = fit_model(spec, sim.RGB_train, sim.XYZ_train, objective="de2000", white_XYZ=sim.white)
        d_xyz = delta_E(xyz.apply(sim.RGB_train), sim.XYZ_train, sim.white)
        d_de = delta_E(de.apply(sim.RGB_train), sim.XYZ_train, sim.white)
        assert np.sum(d_de**2) < np.sum(d_xyz**2)
        assert de.objective == "de2000"


def test_de2000_components_norm_is_colour_science_delta_E():
    import colour

    rng = np.random.default_rng(0)
    Lab1 = np.column_stack([rng.uniform(0, 100, 5000), rng.uniform(-90, 90, 5000), rng.uniform(-90, 90, 5000)])
    Lab2 = Lab1 + rng.normal(0, 4, Lab1.shape)
    Lab2[:100, 1:] = 0  # neutrals: undefined hue
    ours = np.linalg.norm(delta_E2000_components(Lab1, Lab2), axis=-1)
    np.testing.assert_allclose(ours, colour.delta_E(Lab1, Lab2, method="CIE 2000"), atol=1e-10)


# Sharma, Wu, Dalal (2005), Table 1: pairs 1, 7, 17, 25 and their CIEDE2000.
SHARMA = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
]


@pytest.mark.parametrize("a,b,expected", SHARMA)
def test_de2000_components_sharma_2005(a, b, expected):
    value = np.linalg.norm(delta_E2000_components(np.array(a), np.array(b)))
    assert value == pytest.approx(expected, abs=1e-4)


def test_rbf_interpolates_with_tiny_smoothing():
    XYZ = np.column_stack([np.sin(3 * RGB[:, 0]), RGB[:, 1] ** 2, RGB[:, 2] * RGB[:, 0]])
    for kernel in ("polyharmonic-1", "polyharmonic-3", "thin-plate"):
        model = fit_model(f"rbf:{kernel}", RGB, XYZ, smoothing=1e-12)
        np.testing.assert_allclose(model.apply(RGB), XYZ, atol=1e-6)


def test_rbf_smoothing_chosen_by_cross_validation(sim):
    model = fit_model("rbf:polyharmonic-3", sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white)
    assert model.smoothing > 0
    assert isinstance(model, RBFModel)


def test_rbf_rejects_de2000():
    with pytest.raises(CamcalError, match="not available for rbf"):
        fit_model("rbf", RGB, RGB, objective="de2000")


@pytest.mark.parametrize("spec", ["matrix3x3", "polynomial:7", "root-polynomial:2", "rbf:thin-plate"])
def test_model_dict_round_trip(spec, sim):
    model = fit_model(spec, sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white)
    again = model_from_dict(model.to_dict())
    assert again == model
    np.testing.assert_array_equal(again.apply(sim.RGB_test), model.apply(sim.RGB_test))


def test_parse_model_spec_errors():
    assert parse_model_spec("root-polynomial:3").terms() == terms_Finlayson2015(3)
    assert parse_model_spec("matrix3x3:white-preserving").white_preserving
    with pytest.raises(CamcalError, match="unknown model 'poly'"):
        parse_model_spec("poly")
    with pytest.raises(CamcalError, match="Cheung 2004 polynomial with 9 terms"):
        parse_model_spec("polynomial:9")
    with pytest.raises(CamcalError, match="RBF kernel"):
        parse_model_spec("rbf:gauss")


def test_fit_rejects_nan_and_too_few_patches():
    bad = RGB.copy()
    bad[0, 0] = np.nan
    with pytest.raises(CamcalError, match="NaN"):
        fit_model("matrix3x3", bad, RGB)
    with pytest.raises(CamcalError, match="at least 10 patches, got 5"):
        fit_model("polynomial:10", RGB[:5], RGB[:5])


def test_malformed_term_rejected():
    with pytest.raises(CamcalError, match="canonical"):
        LinearTermsModel("polynomial", ("G*R",), np.zeros((3, 1))).apply(RGB)


@pytest.mark.parametrize("spec,objective", [("root-polynomial:2", "xyz"), ("polynomial:7", "de2000")])
def test_shrinkage_blends_the_fit_with_the_matrix_fit(sim, spec, objective):
    """Shrinkage alpha: the predictions are (1 - alpha) times the unshrunk fit's plus alpha times the matrix3x3
    fit's (same patches, objective), anywhere in the RGB cube; it is recorded and read back."""
    a = 0.3
    full, matrix, shrunk = (fit_model(s, sim.RGB_train, sim.XYZ_train, objective=objective, white_XYZ=sim.white,
                                      regularisation=1e-5 if s != "matrix3x3" else 0.0, shrinkage=k)
                            for s, k in ((spec, 0.0), ("matrix3x3", 0.0), (spec, a)))
    np.testing.assert_allclose(shrunk.apply(RGB), (1 - a) * full.apply(RGB) + a * matrix.apply(RGB), atol=1e-12)
    assert shrunk.to_dict()["shrinkage"] == a and "shrinkage" not in full.to_dict()
    assert model_from_dict(shrunk.to_dict()) == shrunk


def test_shrinkage_keeps_the_white_and_refuses_what_it_cannot_do(sim):
    white_rgb = sim.camera.RGB_white
    model = fit_model("root-polynomial:3:white-preserving", sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white,
                      RGB_white=white_rgb, regularisation=1e-6, shrinkage=0.4)
    np.testing.assert_allclose(model.apply(white_rgb[None])[0], sim.white, atol=1e-12)
    for spec, alpha, message in (("matrix3x3", 0.2, "polynomial and root-polynomial"),
                                 ("rbf:thin-plate", 0.2, "polynomial and root-polynomial"),
                                 ("root-polynomial:2", 1.0, r"\[0, 1\)"), ("root-polynomial:2", -0.1, r"\[0, 1\)")):
        with pytest.raises(CamcalError, match=message):
            fit_model(spec, sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white, shrinkage=alpha)
