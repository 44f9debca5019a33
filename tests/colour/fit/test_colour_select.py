"""``auto``: the one-standard-error parsimony rule on leave-one-out, the spectral route, the ranking."""

import numpy as np
import pytest

from camcal.colour.chart.patches import PatchSet
from camcal.colour.fit.characterise import characterise
from camcal.colour.fit.select import select_model
from camcal.colour.fit.synthetic import synthesise_from_chart

SIMPLE = ("matrix3x3", "polynomial:7", "root-polynomial:2")


def _simpler(a, b):
    return a.n_params < b.n_params


def test_pick_is_the_simplest_within_one_standard_error(sim):
    selection = select_model(sim.RGB_train, sim.XYZ_train, sim.white, objectives=("xyz",), candidates=SIMPLE)
    best = selection.best
    p = selection.picked
    assert p.score <= best.score + p.score_se + 1e-12
    for c in selection.candidates:  # nothing simpler than the pick was within its margin of the best
        if _simpler(c, p):
            assert c.score > best.score + c.score_se
    lines = selection.ranking()
    assert len(lines) == len(selection.candidates) and sum("<- picked" in line for line in lines) == 1
    assert [float(line.split("score ")[1].split()[0]) for line in lines] == sorted(
        round(c.score, 3) for c in selection.candidates)
    assert all(c.score == c.loo_mean for c in selection.candidates)


def test_objective_is_no_simplicity_the_lower_score_of_a_model_wins(sim):
    """The objectives fit the same terms: within the margin, the pick has the lowest score of its size."""
    selection = select_model(sim.RGB_train, sim.XYZ_train, sim.white, candidates=SIMPLE)
    p, best = selection.picked, selection.best
    assert {c.objective for c in selection.candidates} == {"xyz", "de2000", "xyz+de2000"}
    for c in selection.candidates:
        if c.n_params == p.n_params and c.score <= best.score + c.score_se:
            assert p.score <= c.score


def test_averaged_candidate_is_the_mean_of_its_two_fits(sim):
    """xyz+de2000: one model of the same terms whose coefficients, and so predictions, are the mean of the xyz
    and de2000 fits; its leave-one-out score is that of the mean prediction, without a refit."""
    from camcal.colour.difference import delta_E
    from camcal.colour.fit.evaluate import leave_one_out_predictions
    from camcal.colour.fit.select import fitter

    selection = select_model(sim.RGB_train, sim.XYZ_train, sim.white, candidates=("root-polynomial:2",))
    mean = next(c for c in selection.candidates if c.objective == "xyz+de2000")
    fits = {o: fitter(mean.spec, o, mean.regularisation, sim.white) for o in ("xyz", "de2000", "xyz+de2000")}
    models = {o: f(sim.RGB_train, sim.XYZ_train) for o, f in fits.items()}
    assert models["xyz+de2000"].M == pytest.approx((models["xyz"].M + models["de2000"].M) / 2, rel=1e-9)
    loo = leave_one_out_predictions(fits["xyz+de2000"], sim.RGB_train, sim.XYZ_train)
    assert mean.loo_mean == pytest.approx(float(np.mean(delta_E(loo, sim.XYZ_train, sim.white))), rel=1e-6)
    # averaging two fits of one model lowers the variance: its leave-one-out beats the worse of the two
    pair = [c for c in selection.candidates if c.regularisation == mean.regularisation and c.objective != mean.objective]
    assert mean.loo_mean < max(c.loo_mean for c in pair)


def test_weights_change_nothing_when_equal(sim):
    plain = select_model(sim.RGB_train, sim.XYZ_train, sim.white, objectives=("xyz",), candidates=SIMPLE)
    equal = select_model(sim.RGB_train, sim.XYZ_train, sim.white, objectives=("xyz",), candidates=SIMPLE,
                         weights=np.full(len(sim.RGB_train), 3.0))
    assert [c.score for c in plain.candidates] == pytest.approx([c.score for c in equal.candidates], rel=1e-9)


def test_spectral_route_scored_on_held_out_colours_and_says_why(sim):
    """Sensitivities estimated from the 24 patches alone; the spectral candidates trained on the 99 CIE 2017
    samples and 300 Munsell colours through them beside the chart; everything scored on 300 other Munsell
    colours; chart-only against spectral decided on the chart's own patches held out."""
    train = PatchSet(sim.names_train, sim.RGB_train * 0.37, sim.XYZ_train)  # any exposure
    synthetic = synthesise_from_chart(train, "BabelColor Average", "D65")
    assert synthetic.chart_rms < 0.02 and len(synthetic.training) == 399 and len(synthetic.held_out) == 300
    assert not set(synthetic.training.names) & set(synthetic.held_out.names)
    white = sim.white
    xy = f"{white[0] / white.sum():.10f},{white[1] / white.sum():.10f}"
    test = PatchSet(sim.names_test, sim.RGB_test * 0.37, sim.XYZ_test)
    out = characterise(train, white=xy, model="auto", objective="xyz", candidates=SIMPLE, test=test,
                       spectra="BabelColor Average", illuminant="D65")
    selection = out.selection
    assert {c.training for c in selection.candidates} == {"chart", "spectral"}
    for c in selection.candidates:  # chart candidates scored by leave-one-out, spectral ones on held-out colours
        assert c.score == (c.validation_mean if c.training == "spectral" else c.loo_mean)
    chart, spectral = selection.rivals
    assert chart.training == "chart" and spectral.training == "spectral"
    winner = spectral if spectral.loo_mean < chart.loo_mean else chart
    assert selection.picked is winner
    assert ("spectral route written" if winner is spectral else "chart-only fit written") in selection.reason
    assert "spectral route: sensitivities estimated from the chart's 24 patches" in out.summary()
    assert out.fit.selection["picked"]["training"] == winner.training
    # the written fit is the one judged: the independent figure is of the picked route's model
    assert out.result.stats_test.mean < 1.2


def test_spectral_candidates_take_the_ridge_their_held_out_colours_prefer(sim):
    """A spectral model gets the grid's lambda with the lowest xyz error on the synthesised held-out colours,
    refitted here through the public fitter, and the chart's leave-one-out lambda as a smoother fallback."""
    from camcal.colour.difference import delta_E
    from camcal.colour.fit.select import RIDGE_GRID, fitter

    train = PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train)
    synthetic = synthesise_from_chart(train, "BabelColor Average", "D65")
    extra = (synthetic.training.RGB, synthetic.training.XYZ)
    held = synthetic.held_out
    selection = select_model(train.RGB, train.XYZ, sim.white, objectives=("xyz",), candidates=("root-polynomial:2",),
                             validation=(held.RGB, held.XYZ), spectral=extra)
    spectral = sorted((c for c in selection.candidates if c.training == "spectral"), key=lambda c: c.score)
    chart = min((c for c in selection.candidates if c.training == "chart" and not c.shrinkage), key=lambda c: c.score)
    errors = {lam: float(np.mean(delta_E(fitter(spectral[0].spec, "xyz", lam, sim.white, extra)(
        train.RGB, train.XYZ).apply(held.RGB), held.XYZ, sim.white))) for lam in RIDGE_GRID}
    assert {c.regularisation for c in spectral} == {min(errors, key=errors.get), chart.regularisation}
    assert len(spectral) == len({c.regularisation for c in spectral})
    assert spectral[0].regularisation == min(errors, key=errors.get)
    assert spectral[0].validation_mean == pytest.approx(min(errors.values()), rel=1e-9)


def test_shrunk_candidate_scores_as_its_refit_and_beats_its_base(sim):
    """Stage 4: a candidate blended with the matrix3x3 fit at the grid weight with the lowest leave-one-out. Its
    score, computed from the two fits' held-out predictions without a refit, is the leave-one-out of the shrunk
    model refitted on every 23 patches, and it is lower than the unshrunk candidate's."""
    from camcal.colour.difference import delta_E
    from camcal.colour.fit.evaluate import leave_one_out_predictions
    from camcal.colour.fit.select import SHRINKAGE_GRID, fitter

    selection = select_model(sim.RGB_train, sim.XYZ_train, sim.white, objectives=("xyz",),
                             candidates=("matrix3x3", "root-polynomial:3"))
    shrunk = [c for c in selection.candidates if c.shrinkage]
    assert shrunk and all(c.shrinkage in SHRINKAGE_GRID and "shrunk" in c.label for c in shrunk)
    c = min(shrunk, key=lambda c: c.loo_mean)
    base = next(b for b in selection.candidates if b.spec == c.spec and b.regularisation == c.regularisation
                and b.objective == c.objective and not b.shrinkage)
    assert c.loo_mean < base.loo_mean
    loo = leave_one_out_predictions(fitter(c.spec, c.objective, c.regularisation, sim.white, shrinkage=c.shrinkage),
                                    sim.RGB_train, sim.XYZ_train)
    assert c.loo_mean == pytest.approx(float(np.mean(delta_E(loo, sim.XYZ_train, sim.white))), rel=1e-9)
    assert c.to_dict()["shrinkage"] == c.shrinkage
