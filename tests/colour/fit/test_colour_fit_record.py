import json

import numpy as np
import pytest

from camcal.io.colourfile import load_colour_file, load_fit
from camcal.colour.fit.characterise import characterise
from camcal.colour.fit.record import ColourFit
from camcal.colour.chart.patches import PatchSet
from camcal.base.errors import CamcalError
from camcal.io.colourfile import save_colour_file


@pytest.fixture(scope="module")
def fits(sim):
    train = PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train)
    test = PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test)
    out = {}
    for model in ("matrix3x3", "polynomial:10", "root-polynomial:2", "rbf:polyharmonic-3"):
        out[model] = characterise(train, white="D65", model=model, test=test, camera="nikon").fit
    # A chart-like fit with a fitted lut1d curve and adaptation to D50.
    codes = np.clip(sim.RGB_train, 0, None) ** (1 / 2.2)
    out["lut"] = characterise(PatchSet(sim.names_train, codes, sim.XYZ_train), white="D65",
                              target_white="D50", model="matrix3x3", linearise="lut1d").fit
    return out


@pytest.mark.parametrize("name", ["matrix3x3", "polynomial:10", "root-polynomial:2", "rbf:polyharmonic-3", "lut"])
def test_exact_round_trip(tmp_path, fits, name):
    fit = fits[name]
    path = save_colour_file(fit, tmp_path / "cam.colour.json")
    again = load_fit(path)
    assert again == fit
    save_colour_file(again, tmp_path / "again.colour.json")
    assert (tmp_path / "again.colour.json").read_bytes() == path.read_bytes()
    rgb = np.random.default_rng(1).random((50, 3))
    np.testing.assert_array_equal(again.apply(rgb), fit.apply(rgb))
    np.testing.assert_array_equal(again.apply_codes(rgb), fit.apply(fit.linearise(rgb)))
    assert isinstance(load_colour_file(path), ColourFit)


def test_apply_maps_white_near_one(fits, sim):
    XYZ = fits["matrix3x3"].apply(sim.camera.RGB_white[None])[0]
    assert XYZ[1] == pytest.approx(1.0, abs=0.01)


def test_adapted_fit_records_target(fits):
    d = fits["lut"].to_dict()
    assert d["target"]["white"] == "D50" and d["target"]["adaptation"] == "Bradford"
    assert d["training"]["illuminant"] == "D65"
    assert d["linearisation"]["channels"][0]["kind"] == "lut1d"


def _mutate(tmp_path, fit, change):
    data = fit.to_dict()
    change(data)
    path = tmp_path / "bad.colour.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d.update(extra=1), "unknown key 'extra'"),
        (lambda d: d["model"].update(gain=2), "model: unknown key 'gain'"),
        (lambda d: d.update(version=2), "version: this camcal reads version 1, got 2"),
        (lambda d: d.update(format="camcal.rig"), "format: expected 'camcal.colour'"),
        (lambda d: d.update(kind="lut"), "kind: expected one of"),
        (lambda d: d["model"]["coefficients"][1].__setitem__(2, "x"), r"model.coefficients\[1\]\[2\]: expected a finite number"),
        (lambda d: d["model"]["coefficients"].pop(), "model.coefficients: expected 3 rows"),
        (lambda d: d["model"].update(kind="spline"), "model.kind: expected a string"),
        (lambda d: d["model"]["terms"].__setitem__(3, "G*R"), r"model.terms\[3\]"),
        (lambda d: d["evaluation"]["train"].pop("p95"), "evaluation.train: missing key 'p95'"),
        (lambda d: d["target"].update(white_XYZ=[0.9, 0.5, 1.0]), "target.white_XYZ: Y of the white must be 1"),
        (lambda d: d["linearisation"]["channels"].pop(), "linearisation.channels: expected 3 curves"),
        (lambda d: d["linearisation"]["channels"][0].update(kind="gamma-offset"), r"linearisation.channels\[0\]: missing key 'gamma'"),
        (lambda d: d["training"].update(n_patches=True), "training.n_patches: expected an integer"),
        (lambda d: d["model"].update(shrinkage=1.0), "model.shrinkage: must be < 1"),
        (lambda d: d["model"].update(shrinkage=-0.2), "model.shrinkage: must be >= 0"),
    ],
)
def test_bad_field_named_in_one_error(tmp_path, fits, change, message):
    path = _mutate(tmp_path, fits["polynomial:10"], change)
    with pytest.raises(CamcalError, match=message) as info:
        load_fit(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(CamcalError, match="not found"):
        load_fit(tmp_path / "none.colour.json")
    (tmp_path / "x.colour.json").write_text("{not json")
    with pytest.raises(CamcalError, match="not valid JSON"):
        load_fit(tmp_path / "x.colour.json")


def test_atomic_write_leaves_no_temporary(tmp_path, fits):
    save_colour_file(fits["matrix3x3"], tmp_path / "a.colour.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.colour.json"]


def test_shrunk_model_round_trips(tmp_path, fits, sim):
    """A fit whose model was shrunk toward the 3x3 matrix (auto's stage 4) is written and read back exactly."""
    from dataclasses import replace

    from camcal.colour.fit.fitting import fit_model

    model = fit_model("root-polynomial:2", sim.RGB_train, sim.XYZ_train, white_XYZ=sim.white, shrinkage=0.2)
    fit = replace(fits["root-polynomial:2"], model=model)
    path = save_colour_file(fit, tmp_path / "shrunk.colour.json")
    assert json.loads(path.read_text())["model"]["shrinkage"] == 0.2
    again = load_fit(path)
    assert again == fit and again.model.shrinkage == 0.2
