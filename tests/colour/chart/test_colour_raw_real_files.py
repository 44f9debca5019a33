"""Real raw captures of a ColorChecker, when present: ``colour fit --chart RAW`` end to end without ``--corners``.

The files live outside the repository (``../data/raw_charts`` from the
project root, or ``CAMCAL_RAW_CHARTS``; its README says where each comes
from). A sidecar ``FILE.json`` may give ``reference`` and ``illuminant``.
Every patch is used unless saturated; the leave-one-out figures are printed
beside cv2.ccm and colour-science on the same patches.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest
from raw_chart_peers import colour_science_raw, cv2_ccm_raw

from camcal.cli import main
from camcal.io.raw import RAW_SUFFIXES, read_raw
from camcal.pipelines.colour import patches_from_chart

FOLDER = Path(os.environ.get("CAMCAL_RAW_CHARTS", Path(__file__).resolve().parents[3].parent / "data" / "raw_charts"))
FILES = sorted(p for p in FOLDER.glob("*") if p.suffix.lower() in RAW_SUFFIXES) if FOLDER.is_dir() else []


@pytest.mark.slow
@pytest.mark.parametrize("path", FILES or [None], ids=[p.name for p in FILES] or ["none"])
def test_real_raw_chart_end_to_end(path, tmp_path, capsys):
    if path is None:
        pytest.skip(f"no real raw ColorChecker captures in {FOLDER} (see its README; CAMCAL_RAW_CHARTS=DIR)")
    sidecar = path.with_name(path.name + ".json")
    meta = json.loads(sidecar.read_text()) if sidecar.is_file() else {}
    reference, illuminant = meta.get("reference", "cc24"), meta.get("illuminant", "D50")
    out = tmp_path / "real.colour.json"
    assert main(["colour", "fit", "--chart", str(path), "--reference", reference, "--illuminant", illuminant,
                 "--out", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)["figures"]
    found = patches_from_chart(path, reference, illuminant=illuminant)
    raw = read_raw(path)
    # every patch used unless saturated: a dropped patch holds saturated pixels
    assert figures["n_train"] + figures["n_dropped"] == 24 and figures["n_train"] == len(found.patches)
    for name in found.excluded:
        k = found.reference.patch_names.index(name)
        centre = np.round(found.detection.patch_centres()[k]).astype(int)
        assert raw.saturated[centre[1] - 2: centre[1] + 3, centre[0] - 2: centre[0] + 3].any(), name
    P, white = found.patches, found.reference.white_XYZ
    print(f"\n{path.name} ({found.detection.method}): camcal {figures['model']} leave-one-out "
          f"{figures['delta_E2000']['loo']['mean']:.2f}")
    for label, (train, loo) in {**cv2_ccm_raw(P.RGB, P.XYZ, white), **colour_science_raw(P.RGB, P.XYZ, white)}.items():
        print(f"  {label}: train {train:.2f} leave-one-out {loo:.2f}")
