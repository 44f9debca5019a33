"""`camcal demo`: a real (small) run renders, calibrates and reports; the report opens in Chromium.

The fast tests run :data:`camcal.demo.QUICK` once (Blender renders, real
calibrations, no structure from motion) and check its rows against the
files the verbs wrote and against the truth; the HTML report is opened in
headless Chromium (screenshot + DOM). The full ``make demo`` run is the
``slow`` test: every row within its tolerance.
"""

from __future__ import annotations

import html.parser
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.demo import COLOUR_EXPORTS_SECTION, QUICK, STAGES, make_truth, reference_XYZ, run_demo
from camcal.model.rig import Rig
from user_text import internal_references

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# .ci/run installs Chromium and sets this: there the browser tests must run, not skip
if os.environ.get("CAMCAL_REQUIRE_CHROMIUM") and CHROMIUM is None:
    raise RuntimeError("CAMCAL_REQUIRE_CHROMIUM is set but chromium is not installed")
pytest.importorskip("bpy", reason="the demo renders with the bpy module (camcal[blender])")


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    return out, run_demo(out, QUICK)


def test_quick_run_rows_match_outputs_and_truth(quick):
    out, report = quick
    stages = {row.stage for row in report.rows}
    assert stages == set(QUICK.stages) - {"render"}
    truth = make_truth(QUICK)
    rig = Rig.load(out / "calibrate" / "board.rig.json")
    for camera in rig.cameras:
        row = next(r for r in report.rows if r.quantity == f"{camera.name} fx error")
        assert row.recovered == camera.K[0, 0] and row.true == truth.rig.camera(camera.name).K[0, 0]
        assert row.error == pytest.approx(100 * (camera.K[0, 0] / row.true - 1))
    # stages that hold with margin even on the small run
    for row in report.rows:
        if row.stage in ("rectify", "rig export", "blender import", "colour fit", "colour match", "colour export"):
            assert row.ok, report.table()
        assert np.isfinite(row.recovered), row
    assert report.report == out / "report.html"
    for _, path in report.outputs:
        assert Path(path).exists(), path


def test_quick_run_colour_exports(quick):
    """The OCIO config holds both cameras and the match Look, each camera's ICC profile is version 4."""
    import PyOpenColorIO as ocio

    from camcal.colour.export.icc import check_icc

    out, report = quick
    config = ocio.Config.CreateFromFile(str(out / "ocio" / "config.ocio"))
    config.validate()
    assert {"camcal left", "camcal right"} <= {space.getName() for space in config.getColorSpaces()}
    assert config.getLook("camcal match right to left") is not None
    for name in ("left", "right"):  # each space against its fit: the colour export rows of the run
        assert check_icc((out / "icc" / f"{name}.icc").read_bytes()).version_major == 4
    assert sum(row.stage == "colour export" for row in report.rows) == 5


def test_quick_run_plates_carry_the_true_lens(quick):
    """The rendered plates are the truth: true corners found where the true camera puts them."""
    from camcal.demo.truth import board_corners
    from camcal.geometry.board import detect_board, parse_board

    out, _ = quick
    truth = make_truth(QUICK)
    board = parse_board(truth.board_spec)
    errors = []
    for k, (R, t) in enumerate(truth.board_poses):
        image = cv2.imread(str(out / "images" / "board" / "left" / f"left_{k + 1:02d}.png"), cv2.IMREAD_GRAYSCALE)
        found = detect_board(board, image)
        errors.append(found.corners_px - truth.rig.camera("left").project(board_corners(board, R, t))[found.ids])
    errors = np.vstack(errors)
    # lens shifts the corners by up to 25 px; rendering + detection noise is ~0.1 px
    assert np.sqrt(np.mean(np.sum(errors**2, axis=1))) < 0.2


@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_independent_truth_integrates_like_the_chart_reference(illuminant):
    """The independent set's true XYZ and the chart's reference XYZ come from one integration."""
    from camcal.colour.chart.reference import reference_chart

    chart = reference_chart("ISO 17321-1", illuminant)
    assert np.abs(reference_XYZ("ISO 17321-1", illuminant) - chart.XYZ).max() < 1e-12
    assert reference_XYZ("rawtoaces 190", illuminant).shape == (190, 3)


class _Page(html.parser.HTMLParser):
    """Elements of the report: ids, table row classes, image sources, link targets."""

    def __init__(self):
        super().__init__()
        self.ids, self.rows, self.images, self.links = set(), [], [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.add(attrs["id"])
        if tag == "tr" and attrs.get("class") in ("pass", "fail"):
            self.rows.append(attrs["class"])
        if tag == "img":
            self.images.append(attrs["src"])
        if tag == "a" and "href" in attrs:
            self.links.append(attrs["href"])


def open_in_chromium(page: Path, workdir: Path) -> tuple[_Page, list[str], np.ndarray]:
    """Screenshot and DOM of ``page`` in headless Chromium; the console errors it logged."""
    common = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
              "--disable-background-networking", "--disable-component-update", "--disable-sync",
              "--enable-logging=stderr", "--v=0", f"--user-data-dir={workdir / 'profile'}"]
    shot = workdir / "shot.png"
    subprocess.run([*common, "--window-size=1200,2400", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, text=True, timeout=120, check=True)
    dom = subprocess.run([*common, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120, check=True)
    parsed = _Page()
    parsed.feed(dom.stdout)
    errors = [line for line in dom.stderr.splitlines() if ":CONSOLE" in line]
    errors += [f"missing {src}" for src in parsed.images + parsed.links
               if not src.startswith(("http", "#")) and not (page.parent / src).exists()]
    errors += [f"not an image {src}" for src in parsed.images
               if (page.parent / src).exists() and cv2.imread(str(page.parent / src)) is None]
    return parsed, errors, cv2.imread(str(shot))


def test_quick_run_report_shows_the_rectified_pairs_sigma_maps(quick):
    """The rectify stage runs with --sigma --distance: its heat maps are written and the demo page shows them."""
    out, _ = quick
    page = (out / "report.html").read_text()
    for kind in ("vertical", "depth"):
        assert (out / "rectify" / f"sigma_{kind}_left-right.png").stat().st_size > 0
        assert f'src="rectify/sigma_{kind}_left-right.png"' in page
    assert (out / "rectify" / "images" / "left-right_depth_sigma.exr").exists()


def test_quick_run_names_its_tolerance_sources_without_internal_references(quick):
    """The terminal table and report.html name each tolerance's source (a test, a peer, a probability)."""
    out, report = quick
    assert all(row.source.strip() for row in report.rows)
    for text in (report.table(), (out / "report.html").read_text()):
        assert internal_references(text, allowed_prefixes=(str(out.resolve()), str(out))) == []


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (.ci/run installs it)")
def test_report_opens_in_chromium(quick, tmp_path):
    out, report = quick
    page, errors, shot = open_in_chromium(out / "report.html", tmp_path)
    assert not errors, errors
    assert page.rows == ["pass" if row.ok else "fail" for row in report.rows]
    anchors = {"verdict", "truth", "renders", "calibrate-board", "distortion", "rectify", "colour-fit",
               "colour-match", "blender",
               COLOUR_EXPORTS_SECTION, "outputs", "timing"}
    assert anchors <= page.ids, anchors - page.ids
    assert len(page.images) >= 8
    # the screenshot shows a page, not a blank window: dark text on white, and the plots
    assert shot is not None and shot.shape[:2] == (2400, 1200) and shot.std() > 20


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (.ci/run installs it)")
def test_chromium_check_catches_a_broken_page(tmp_path):
    bad = tmp_path / "bad.html"
    bad.write_text('<html><body><img src="missing.png"><script>nosuch()</script></body></html>')
    _, errors, _ = open_in_chromium(bad, tmp_path)
    assert any("missing missing.png" in e for e in errors)
    assert any("Uncaught" in e for e in errors)


def test_demo_help_and_bad_stage(tmp_path, capsys):
    run = subprocess.run([sys.executable, "-m", "camcal", "demo", "--help"], capture_output=True, text=True)
    text = " ".join(run.stdout.split())
    assert run.returncode == 0 and "--stages" in text
    assert all(stage.name in text for stage in STAGES)
    assert main(["demo", "--out", str(tmp_path / "d"), "--stages", "render,nonsense"]) == 2
    assert "unknown stage(s) 'nonsense'" in capsys.readouterr().err
    assert not (tmp_path / "d" / "report.html").exists()


def test_stage_needing_a_skipped_one_says_so(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "d"), "--stages", "rectify"]) == 2
    assert "needs 'board_rig'" in capsys.readouterr().err


@pytest.mark.slow
def test_full_demo_every_row_within_tolerance(tmp_path, capsys):
    """What ``make demo`` runs (about 5-8 minutes on 2 loaded cores)."""
    assert main(["demo", "--out", str(tmp_path / "demo_out")]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "all " in out and "within tolerance" in out
    run_dir = tmp_path / "demo_out"
    page = (run_dir / "report.html").read_text()
    assert internal_references(out + page, allowed_prefixes=(str(run_dir.resolve()), str(run_dir))) == []
    stages = {line.split()[0] for line in out.splitlines() if line.startswith(("calibrate", "solve", "rectify"))}
    assert {"calibrate", "solve", "rectify"} <= stages
    assert (tmp_path / "demo_out" / "blender" / "sfm.blend").is_file()
    assert (tmp_path / "demo_out" / "ocio" / "config.ocio").is_file()
    assert all((tmp_path / "demo_out" / "icc" / f"{name}.icc").is_file() for name in ("left", "right"))


def test_demo_package_does_not_import_the_cli():
    """The demo runs verbs in a child ``python -m camcal``; importing it never loads camcal.cli."""
    code = "import sys, camcal.demo, camcal.demo.stages_colour; sys.exit('camcal.cli' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
