"""``--model auto`` picks fits that export: it hands its ranking to the exporters' own bake check."""

import pytest

ocio = pytest.importorskip("PyOpenColorIO")

from camcal.colour.characterise import characterise  # noqa: E402
from camcal.colour.export_icc import icc_profile_from_fit  # noqa: E402
from camcal.colour.export_ocio import export_ocio  # noqa: E402
from camcal.colour.fitfile import load_fit  # noqa: E402
from camcal.colour.patches import PatchSet  # noqa: E402
from camcal.colour.select import select_model  # noqa: E402
from camcal.errors import CamcalError  # noqa: E402
from colour_export_helpers import codes_of, make_fit  # noqa: E402


def test_auto_walks_down_its_ranking_past_refused_models(sim):
    """With an exporter that refuses every non-matrix model, auto picks the matrix and records the refusals."""
    RGB, XYZ = sim.RGB_train, sim.XYZ_train
    asked = []

    def refuse_nonlinear(model):
        asked.append(model.label)
        if model.kind != "matrix3x3":
            raise CamcalError("a 65^3 Lut3D still leaves CIEDE2000 up to 1.234 over the samples")
        return None

    plain = select_model(RGB, XYZ, sim.white, objectives=("xyz",))
    checked = select_model(RGB, XYZ, sim.white, objectives=("xyz",), exportable=refuse_nonlinear)
    assert plain.picked.spec.kind != "matrix3x3"  # unchecked, auto prefers a non-linear model here
    assert checked.picked.spec.kind == "matrix3x3" and checked.picked.exportable is True
    refused = [c for c in checked.candidates if c.exportable is False]
    # every candidate ranked above the matrix was asked, in order, and refused
    better = [c for c in plain.candidates if c.loo_mean < checked.picked.loo_mean - 0.005]
    assert len(refused) == len(better) == len(asked) - 1 and asked[-1] == "matrix3x3"
    assert all(c.bake_error_max == pytest.approx(1.234) for c in refused)
    assert "failed the export bake check" in checked.reason
    data = checked.to_dict()
    assert data["picked"]["exportable"] is True and "bake_error_max" not in data["picked"]  # exact


def test_auto_pick_exports_and_what_it_refused_the_exporter_refuses(tmp_path, sim_factory):
    """Sigma SDMerill: auto's best leave-one-out model does not bake within 0.2; auto says so, picks the
    next, and both exporters take the pick while the OCIO exporter refuses the one auto passed over."""
    sim = sim_factory("Sigma SDMerill (NPL)")
    fit = make_fit(sim, "auto")
    fit = load_fit(fit.save(tmp_path / "sigma.colour.json"))  # the new candidate keys round-trip
    picked = fit.selection["picked"]
    assert picked["exportable"] is True
    refused = [c for c in fit.selection["candidates"] if c.get("exportable") is False]
    assert refused and all(c["loo_mean"] < picked["loo_mean"] for c in refused)
    assert all(c["bake_error_max"] > 0.2 for c in refused)
    result = export_ocio([("sigma", fit)], tmp_path / "ocio", base="camcal")
    assert result.spaces[0].kind == "matrix" or result.spaces[0].bake_error.max <= 0.2
    icc_profile_from_fit(fit, "sigma")
    best = refused[0]
    train = PatchSet(sim.names_train, codes_of(sim.RGB_train), sim.XYZ_train)
    other = characterise(train, white="D65", model=best["model"], objective=best["objective"],
                         regularisation=best["regularisation"], linearise="gamma-offset", loo=False).fit
    with pytest.raises(CamcalError, match="still leaves"):
        export_ocio([("sigma", other)], tmp_path / "refused", base="camcal")
    assert not (tmp_path / "refused").exists()
