"""The thin-prism fisheye (kannala-brandt-thin-prism) in every interchange format: exact or a nearest fit with its
residual reported, and that residual the true one."""

import dataclasses

import numpy as np
import pytest

from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import FORMATS, export_rig, import_rig
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig

from interchange_rigs import fisheye_rig

THIN_PRISM = Distortion("kannala-brandt-thin-prism", {
    "k1": 0.021, "k2": -0.006, "k3": 0.0012, "k4": -0.0002, "k5": 2e-5, "k6": -1e-6,
    "p1": 4e-4, "p2": -3e-4, "s1": 5e-4, "s2": -1e-4, "s3": -4e-4, "s4": 1e-4})
#: where the format holds the lens exactly (Nuke holds it through its ST-maps, its Camera3 has one focal and the Root
#: format's pixel aspect: the first camera's fy / fx, exact for that camera alone)
EXACT = {"colmap"}
#: where the lens read back is the nearest Kannala-Brandt lens the file holds
NEAREST_FISHEYE = {"opencv", "kalibr"}
OUT = {"opencv": "cam.yaml", "kalibr": "camchain.yaml", "colmap": "sparse", "usd": "rig.usda", "nuke": "rig.nk",
       "3de": "lens.txt", "lensfun": "lens.xml"}


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_is_exact_or_a_reported_nearest_fit(fmt, tmp_path):
    rig = fisheye_rig(rectified=False)
    rig = Rig(tuple(dataclasses.replace(c, distortion=THIN_PRISM) for c in rig.cameras), units=rig.units,
              provenance=rig.provenance)
    if fmt in ("opencv", "3de"):  # one camera (or a stereo pair) per file, one lens per 3DE file
        rig = Rig(rig.cameras[:1], units=rig.units, provenance=rig.provenance)
    result = export_rig(rig, fmt, tmp_path / OUT[fmt])
    for conversion in result.conversions:
        print(conversion.describe())
        first = fmt == "nuke" and conversion.camera == rig.cameras[0].name and rig.cameras[0].K[0, 1] == 0.0
        assert conversion.exact == (fmt in EXACT or first)
        assert conversion.max_px == 0.0 if conversion.exact else conversion.max_px > 0.0
        if fmt in ("nuke", "3de"):  # the 3DE lens: a refit to 3DE's fisheye, its residual printed
            assert conversion.refit.family == "3de4-fisheye-deg8" and not conversion.refit.exact
        assert conversion.camera in conversion.describe()
    if fmt not in EXACT | NEAREST_FISHEYE:
        return  # usd, nuke, 3de and lensfun: their own tests read them back
    back = import_rig(tmp_path / OUT[fmt], fmt)
    for camera, conversion in zip(rig.cameras, result.conversions):
        read = back.rig.cameras[rig.cameras.index(camera)]
        if conversion.exact:
            assert read.distortion.model == "kannala-brandt-thin-prism"
            assert max_pixel_residual(camera, read) < 1e-6
        else:
            assert read.distortion.model == "kannala-brandt"
            # the residual reported is the one the file's lens has
            assert max_pixel_residual(camera, read) == pytest.approx(conversion.max_px, rel=1e-3, abs=1e-6)
