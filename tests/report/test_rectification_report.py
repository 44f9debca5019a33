"""``camcal rectify --sigma --report``: the page's sigma figures are the EXRs' own, read back; bad input: nothing."""

import json
import warnings
from html.parser import HTMLParser

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.zhang import calibrate_board
from camcal.io.stmap import read_sigma_map
from tests.geometry.test_rectify import line_rig
from tests.geometry.test_rectify_sigma import SIZE, board_poses, detections, true_rig
from tests.geometry.test_uncertainty import BOARD


class _Page(HTMLParser):
    """The page's sigma rows (id -> unrounded figures and the EXR link), its images and its sigma note."""

    def __init__(self, text: str):
        super().__init__()
        self.rows, self.images, self.row, self.note = {}, {}, None, None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "tr" and attrs.get("id", "").startswith("sigma-"):
            self.row = self.rows.setdefault(attrs["id"], {"values": [], "href": None})
        elif tag == "td" and self.row is not None and "data-value" in attrs:
            self.row["values"].append(float(attrs["data-value"]) if attrs["data-value"] else float("nan"))
        elif tag == "a" and self.row is not None:
            self.row["href"] = attrs["href"]
        elif tag == "img":
            self.images[attrs["id"]] = attrs["src"]
        elif tag == "p" and attrs.get("id") == "sigma":
            self.note = ""

    def handle_endtag(self, tag):
        if tag == "tr":
            self.row = None

    def handle_data(self, data):
        if self.note is not None:
            self.note += data


@pytest.fixture(scope="module")
def pair_rig(tmp_path_factory):
    """A stereo pair calibrated from 8 board views (independent 0.1 px corner noise), with its joint covariance."""
    truth = true_rig()
    rng = np.random.default_rng(5)
    path = tmp_path_factory.mktemp("pair") / "pair.rig.json"
    calibrate_board(BOARD, detections(truth, board_poses(truth, 8, rng), rng), model="division").rig.save(path)
    return path


def _check_row(row: dict, exr) -> None:
    """The row's worst, median and four corners are those of the EXR read back (NaN pixels: no source pixel)."""
    values = read_sigma_map(exr).astype(np.float64)
    finite = values[np.isfinite(values)]
    worst, median, *corners = row["values"]
    assert finite.size > 0.9 * values.size
    assert worst == float(finite.max()) and median == pytest.approx(float(np.median(finite)), rel=1e-12)
    expected = [values[0, 0], values[0, -1], values[-1, 0], values[-1, -1]]
    assert np.allclose(corners, expected, rtol=1e-12, equal_nan=True)
    assert worst > 1.5 * median > 0  # a map that varies over the frame, not a constant


def test_page_draws_the_pair_sigma_maps_with_the_exr_figures(pair_rig, tmp_path, capsys):
    report, out = tmp_path / "report", tmp_path / "rect.rig.json"
    assert main(["rectify", str(pair_rig), "--out", str(out), "--report", str(report), "--sigma", "--distance", "2",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    page = _Page((report / "index.html").read_text())
    assert set(page.rows) == {"sigma-left-right-vertical", "sigma-left-right-depth"}
    figures = summary["figures"]["sigma"][0]
    for kind, unit, key in (("vertical", "px", "vertical_disparity"), ("depth", "m", "depth")):
        row = page.rows[f"sigma-left-right-{kind}"]
        assert row["href"] == f"left-right_{kind}_sigma.exr"
        _check_row(row, report / row["href"])
        assert row["values"][:2] == [figures[key][f"worst_{unit}"], figures[key][f"median_{unit}"]]
        heatmap = cv2.imread(str(report / page.images[f"map-left-right-{kind}"]))
        assert heatmap is not None and heatmap.shape[0] > 300
    files = {(item["path"], item["kind"]) for item in summary["files"]}
    assert (str(report / "index.html"), "report") in files
    assert {(str(report / f"sigma_{kind}_left-right.png"), "report") for kind in ("vertical", "depth")} <= files
    assert not list(tmp_path.glob(".*"))  # no staging folder left


def test_page_links_the_exrs_of_the_write_folder_and_has_no_depth_at_infinity(pair_rig, tmp_path):
    for name in ("left", "right"):
        (tmp_path / name).mkdir()
        cv2.imwrite(str(tmp_path / name / "f0.png"), np.full(SIZE[::-1], 128, np.uint8))
    report, written = tmp_path / "report", tmp_path / "written"
    with warnings.catch_warnings(record=True) as caught:  # camcal prints its own lines only
        warnings.simplefilter("always")
        assert main(["rectify", str(pair_rig), "--out", str(tmp_path / "rect.rig.json"), "--images",
                     f"left={tmp_path}/left/*.png", f"right={tmp_path}/right/*.png", "--write", str(written),
                     "--report", str(report), "--sigma"]) == 0
    assert [str(w.message) for w in caught] == []
    page = _Page((report / "index.html").read_text())
    assert list(page.rows) == ["sigma-left-right-vertical"] and list(page.images) == ["map-left-right-vertical"]
    row = page.rows["sigma-left-right-vertical"]
    assert (report / row["href"]).resolve() == (written / "left-right_vertical_sigma.exr").resolve()
    _check_row(row, report / row["href"])
    assert not list(report.glob("*.exr")) and not (written / "left-right_depth_sigma.exr").exists()


def test_bad_input_one_line_exit_2_nothing_written(pair_rig, tmp_path, capsys):
    plain = tmp_path / "plain.rig.json"
    line_rig(2, np.random.default_rng(1)).save(plain)  # no covariance in its quality
    out, report = tmp_path / "rect.rig.json", tmp_path / "report"
    assert main(["rectify", str(plain), "--out", str(out), "--report", str(report), "--sigma"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("camcal: error:") and "has no covariance" in err[0]
    taken = tmp_path / "taken"
    taken.write_text("a file, not a folder")
    assert main(["rectify", str(pair_rig), "--out", str(out), "--report", str(taken), "--sigma"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists and is not a folder" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.rig.json", "taken"]
    assert taken.read_text() == "a file, not a folder"
    # without --sigma the page says how to get the maps
    assert main(["rectify", str(plain), "--out", str(out), "--report", str(report)]) == 0
    page = _Page((report / "index.html").read_text())
    assert not page.rows and not page.images and "--sigma" in page.note
