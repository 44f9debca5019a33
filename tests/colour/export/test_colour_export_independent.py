"""Baked exports on independent colours: OCIO's processor and LittleCMS against the fit (slow).

For each colour-science camera, ``--model auto``'s pick (and the baked models
that export) is exported; colours no step of the fit or of the bake used
(the 190 rawtoaces reflectances, PMC, NIST CQS 9.0 VS, CIE 2024 TCS, rendered
through the camera's true sensitivities) go through the exported transforms.
"""

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")
import colour  # noqa: E402
from colour.quality.datasets import SDS_TCS, SDS_VS  # noqa: E402
from scipy.spatial import Delaunay  # noqa: E402

from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.icc import D50_XYZ, _bradford_to_D50, icc_profile_from_fit  # noqa: E402
from camcal.colour.export.ocio_fit import chart_gamut_samples  # noqa: E402
from camcal.colour.export.lcms import lcms_to_XYZ, load_lcms  # noqa: E402
from camcal.colour.spectral.data import reflectance_set  # noqa: E402
from camcal.colour.export.ocio_fit import fit_processor  # noqa: E402
from colour_export_helpers import codes_of, make_fit  # noqa: E402


def independent_sets(sim):
    wl = sim.camera.wavelengths
    shape = colour.SpectralShape(wl[0], wl[-1], wl[1] - wl[0])
    sets = {"rawtoaces 190": sim.RGB_test, "PMC": sim.camera.RGB(reflectance_set("PMC", wl)[1], 0.0)}
    for name, sds in (("CQS VS", SDS_VS["NIST CQS 9.0"]), ("TCS 2024", SDS_TCS["CIE 2024"])):
        R = np.array([sd.copy().extrapolate(shape).align(shape).values for sd in sds.values()])
        sets[name] = sim.camera.RGB(R, 0.0)
    return sets


@pytest.mark.slow
@pytest.mark.parametrize("camera", ["Nikon 5100 (NPL)", "Sigma SDMerill (NPL)"])
@pytest.mark.parametrize("model", ["auto", "root-polynomial:2", "polynomial:7"])
def test_baked_exports_hold_on_independent_colours(sim_factory, camera, model):
    sim = sim_factory(camera)
    fit = make_fit(sim, model)
    try:
        processor = fit_processor(fit, "CIE XYZ")
    except Exception as error:  # a model the exporter refuses: auto must never be one
        assert model != "auto", error
        pytest.skip(f"{camera} {model}: refused by the exporter ({error})")
    profile = icc_profile_from_fit(fit, "cam")
    lcms = load_lcms()
    hull = Delaunay(np.vstack([chart_gamut_samples(fit), np.zeros((1, 3))]))
    chad = _bradford_to_D50(fit.target_white_XYZ)
    for name, RGB in independent_sets(sim).items():
        codes = codes_of(RGB)
        truth = fit.apply_codes(codes)
        inside = hull.find_simplex(fit.linearise(codes)) >= 0
        dE = delta_E(processor.apply(codes).astype(np.float64), truth, fit.target_white_XYZ)
        print(f"{camera} {fit.model.label} {name}: OCIO in gamut max {dE[inside].max(initial=0):.3f}, "
              f"outside max {dE[~inside].max(initial=0):.3f} ({(~inside).sum()} of {len(dE)})")
        assert dE.max() < 0.2, name
        if lcms is not None:
            dE_icc = delta_E(lcms_to_XYZ(lcms, profile.data, codes), truth @ chad.T, D50_XYZ)
            print(f"  LittleCMS (ICC v4 D2B1): in max {dE_icc[inside].max(initial=0):.3f}, "
                  f"outside max {dE_icc[~inside].max(initial=0):.3f}")
            assert dE_icc.max() < 0.2, name
