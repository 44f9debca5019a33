import numpy as np
import pytest

from camcal.colour.difference import DELTA_E_METHODS, DeltaEStats, XYZ_to_Lab, delta_E
from camcal.colour.fit.evaluate import evaluate_model, leave_one_out_predictions, patch_table
from camcal.report.colour_plots import plot_report
from camcal.io.patches import write_patch_table
from camcal.colour.fit.fitting import fit_model
from camcal.base.errors import CamcalError


def test_stats_of_known_values():
    s = DeltaEStats.from_values([1.0, 2.0, 3.0, 4.0, 10.0])
    assert (s.n, s.mean, s.median, s.max) == (5, 4.0, 3.0, 10.0)
    assert s.p95 == pytest.approx(np.percentile([1, 2, 3, 4, 10], 95))
    with pytest.raises(CamcalError):
        DeltaEStats.from_values([])


def test_white_is_L100(sim):
    np.testing.assert_allclose(XYZ_to_Lab(sim.white, sim.white), [100, 0, 0], atol=1e-9)


def test_delta_E_methods_zero_on_identity_and_positive_otherwise(sim):
    for method in DELTA_E_METHODS:
        assert np.all(delta_E(sim.XYZ_train, sim.XYZ_train, sim.white, method) == 0)
        assert np.all(delta_E(sim.XYZ_train * 1.05, sim.XYZ_train, sim.white, method) > 0)
    with pytest.raises(CamcalError, match="unknown Delta E method"):
        delta_E(sim.XYZ_train, sim.XYZ_train, sim.white, "CIE 2001")


def test_leave_one_out_is_refit_without_the_patch(sim):
    def fit(R, X):
        return fit_model("matrix3x3", R, X)

    pred = leave_one_out_predictions(fit, sim.RGB_train, sim.XYZ_train)
    keep = np.arange(24) != 5
    expected = fit(sim.RGB_train[keep], sim.XYZ_train[keep]).apply(sim.RGB_train[5:6])[0]
    np.testing.assert_allclose(pred[5], expected, rtol=1e-12)


def test_loo_is_worse_than_training_and_test_is_reported(sim):
    r = evaluate_model(lambda R, X: fit_model("polynomial:10", R, X), sim.RGB_train, sim.XYZ_train,
                       sim.white, test=(sim.RGB_test, sim.XYZ_test))
    assert r.stats_loo.mean > r.stats_train.mean
    assert r.stats_test.n == 190
    block = r.evaluation_dict()
    assert set(block) == {"metric", "train", "loo", "test"}


def test_patch_table_and_plots(tmp_path, sim):
    model = fit_model("matrix3x3", sim.RGB_train, sim.XYZ_train)
    pred = model.apply(sim.RGB_train)
    rows = patch_table(sim.names_train, sim.XYZ_train, pred, sim.white)
    assert len(rows) == 24 and {"dE2000", "dE1976", "dE1994", "dECMC"} <= set(rows[0])
    write_patch_table(tmp_path / "t.csv", rows)
    assert (tmp_path / "t.csv").read_text().count("\n") == 25
    files = plot_report(tmp_path / "plots", sim.names_train, sim.XYZ_train, pred, sim.white, title="t")
    assert [f.name for f in files] == ["swatches.png", "delta_E_histogram.png", "ab_errors.png"]
    for f in files:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
