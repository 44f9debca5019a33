"""Every kind of *.colour.json is listed explicitly; none registers itself by being imported."""

import subprocess
import sys

import numpy as np
import pytest

from camcal.colour.fit.record import KINDS
from camcal.colour.match.record import ColourMatch
from camcal.colour.match.robust import fit_match_model
from camcal.io.colourfile import FILE_KINDS, reader_of, save_colour_file


def test_every_listed_kind_has_a_reader():
    with pytest.raises(TypeError):
        FILE_KINDS["other"] = ("x", "Y")  # the table is read-only: nothing registers at import time
    assert tuple(FILE_KINDS) == KINDS  # every kind the record checks accept has a reader
    for kind, cls in FILE_KINDS.items():
        reader = reader_of(kind)
        assert reader.__qualname__ == f"{cls.__name__}.from_dict" and reader.__module__ == cls.__module__


def test_a_match_file_loads_in_a_process_that_imported_only_colourfile(tmp_path):
    """The match kind is found through FILE_KINDS; the match pipelines are never imported to read it."""
    B = np.random.default_rng(0).uniform(0.05, 0.9, (200, 3))
    fit = fit_match_model(B, B @ np.diag([1.1, 1.0, 0.9]).T, "matrix3x3", robust="none")
    stats = {"n": 10, "mean": 0.1, "median": 0.1, "p90": 0.2, "p95": 0.2, "max": 0.3}
    path = save_colour_file(ColourMatch(model=fit.model, source="right", target="left",
                       evaluation={"metric": "CIE 2000", "space": "x", "train": stats, "test": None,
                                   "before": None, "n_test_outliers": None, "chart": None},
                       fit={"route": "image", "robust": "none", "n_fit": 200, "n_inliers": 200,
                            "inlier_threshold": None}), tmp_path / "m.colour.json")
    code = (
        "import sys\n"
        "from camcal.io.colourfile import load_colour_file\n"
        f"match = load_colour_file({str(path)!r})\n"
        "assert type(match).__name__ == 'ColourMatch' and match.source == 'right'\n"
        "assert 'camcal.pipelines.colour' not in sys.modules  # the pipelines are not needed to read the file\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
