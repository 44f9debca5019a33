"""``--model auto`` picks fits that export: it hands its ranking to the exporters' own bake check."""

import pytest

ocio = pytest.importorskip("PyOpenColorIO")

from camcal.colour.fit.characterise import characterise  # noqa: E402
from camcal.colour.export.icc import icc_profile_from_fit  # noqa: E402
from camcal.io.ocio import export_ocio  # noqa: E402
from camcal.io.colourfile import load_fit  # noqa: E402
from camcal.colour.chart.patches import PatchSet  # noqa: E402
from camcal.colour.fit.select import select_model  # noqa: E402
from camcal.base.errors import CamcalError  # noqa: E402
from camcal.io.colourfile import save_colour_file
from colour_export_helpers import make_fit  # noqa: E402


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
    # asked in order, the unchecked pick first, the matrix last, every other one refused
    assert len(refused) == len(asked) - 1 and asked[-1] == "matrix3x3" and asked[0] == plain.picked.spec.label
    assert plain.picked.label in {c.label for c in refused}
    assert all(c.bake_error_max == pytest.approx(1.234) for c in refused)
    assert "failed the export bake check" in checked.reason
    data = checked.to_dict()
    assert data["picked"]["exportable"] is True and "bake_error_max" not in data["picked"]  # exact


def test_auto_refuses_what_the_exporter_refuses(tmp_path, sim):
    """The real check (the exporters' bake_model, as ``colour fit`` passes it, here limited to a 17^3 grid
    so that it refuses): root-polynomial:3 fits rank above the matrix by leave-one-out on the Nikon but do
    not bake in 17^3; auto passes over them, and the OCIO exporter with the same grid refuses those fits."""
    from camcal.colour.bake.samples import bake_model

    def exportable(model):
        baked = bake_model(model, sim.white, illuminant="D65", lut_sizes=(17,))
        return None if baked.bake_error is None else baked.bake_error.max

    selection = select_model(sim.RGB_train, sim.XYZ_train, sim.white, objectives=("xyz",),
                             candidates=("root-polynomial:3", "matrix3x3"), exportable=exportable)
    refused = [c for c in selection.candidates if c.exportable is False]
    assert refused and selection.picked.exportable is True
    assert all(c.score < selection.picked.score and c.bake_error_max > 0.2 for c in refused)
    first = refused[0]
    train = PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train)
    fit = characterise(train, white="D65", model=first.spec.label, regularisation=first.regularisation,
                       linearise="none", loo=False).fit
    with pytest.raises(CamcalError, match="still leaves"):
        export_ocio([("nikon", fit)], tmp_path / "refused", base="camcal", lut_sizes=(17,))


# the Sigma (a minute of auto ranking) runs with the slow tests; the Nikon is its fast sibling
@pytest.mark.parametrize("camera", ["Nikon 5100 (NPL)", pytest.param("Sigma SDMerill (NPL)", marks=pytest.mark.slow)])
def test_auto_pick_exports_through_both_exporters(tmp_path, sim_factory, camera):
    sim = sim_factory(camera)
    fit = load_fit(save_colour_file(make_fit(sim, "auto"), tmp_path / "cam.colour.json"))  # the new keys round-trip
    picked = fit.selection["picked"]
    assert picked["exportable"] is True
    result = export_ocio([("cam", fit)], tmp_path / "ocio", base="camcal")
    assert result.spaces[0].kind == "matrix" or result.spaces[0].bake_error.max <= 0.2
    profile = icc_profile_from_fit(fit, "cam")
    assert profile.kind == "matrix-trc" or profile.float_bake_error.max <= 0.2
