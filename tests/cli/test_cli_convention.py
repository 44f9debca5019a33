"""One convention on the command line: former spellings still parse (with one note), flags that need another, no
third-party log lines, one chromatic adaptation default."""

import argparse
import inspect
import json
import os
import subprocess
import sys

import pytest

from camcal.api.colour import fit_colour
from camcal.cli import build_parser, main
from camcal.cli.app import leaf_parsers
from camcal.colour.fit.characterise import characterise

# (former command line, today's): both parse to the same options, the former with one deprecation line
RENAMED = [
    (["calibrate", "board", "--board", "chessboard:9x6:1", "--camera", "left=L/*.png", "right=R/*.png", "--out", "o"],
     ["calibrate", "board", "--board", "chessboard:9x6:1", "--images", "left=L/*.png", "right=R/*.png", "--out", "o"]),
    (["solve", "DIR", "--camera", "left=*_L.png", "--out", "o"], ["solve", "DIR", "--images", "left=*_L.png", "--out", "o"]),
    (["undistort", "r.rig.json", "--camera", "left", "a.png", "b.png", "--out", "u"],
     ["undistort", "r.rig.json", "--camera", "left", "--images", "a.png", "b.png", "--out", "u"]),
    (["distortion", "fit", "a.png", "--pattern", "9x6", "--out", "l.json"],
     ["distortion", "fit", "--images", "a.png", "--board", "chessboard:9x6", "--out", "l.json"]),
    (["colour", "fit", "--patches", "p.csv", "--camera", "nikon", "--out", "f.colour.json"],
     ["colour", "fit", "--patches", "p.csv", "--camera-name", "nikon", "--out", "f.colour.json"]),
    (["colour", "sensitivities", "--measured", "m.csv", "--camera", "nikon", "--out", "n.ssf.json"],
     ["colour", "sensitivities", "--measured", "m.csv", "--camera-name", "nikon", "--out", "n.ssf.json"]),
    (["colour", "export", "f.colour.json", "--ocio", "o", "--cat", "CAT02"],
     ["colour", "export", "f.colour.json", "--ocio", "o", "--adaptation", "CAT02"]),
    (["batch", "r.rig.json", "--camera", "left", "--in", "p.%04d.exr", "--frames", "1-2", "--out", "o.%04d.exr"],
     ["batch", "r.rig.json", "--camera", "left", "--images", "p.%04d.exr", "--frames", "1-2", "--out", "o.%04d.exr"]),
]


def _options(namespace: argparse.Namespace) -> dict:
    return {key: value for key, value in vars(namespace).items() if key not in ("func", "_deprecated")}


@pytest.mark.parametrize("former, today", RENAMED, ids=[" ".join(t[:2]) for _, t in RENAMED])
def test_former_spellings_parse_the_same_with_one_note(former, today, capsys):
    parser = build_parser()
    new = parser.parse_args(today)
    assert capsys.readouterr().err == "" and not hasattr(new, "_deprecated")
    old = parser.parse_args(former)
    notes = capsys.readouterr().err.splitlines()
    assert _options(old) == _options(new)
    assert len(notes) == len(old._deprecated) >= 1
    assert all(line.startswith(f"camcal {new._verb}: warning: ") and "deprecated, use --" in line for line in notes)


def test_deprecation_note_is_in_the_json_summary(capsys):
    code = main(["colour", "fit", "--patches", "missing.csv", "--camera", "nikon", "--out", "f.colour.json", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 2 and summary["warnings"] == ["--camera is deprecated, use --camera-name"]


# a flag that has no effect without another: a usage error naming both
NEEDS_ANOTHER = [
    (["undistort", "r.rig.json", "--camera", "c", "--images", "a.png", "--out", "u", "--overscan", "1.3"],
     "--overscan has no effect without --mode overscan"),
    (["undistort", "r.rig.json", "--camera", "c", "--images", "a.png", "--out", "u", "--distance", "2"],
     "--distance has no effect without --sigma"),
    (["batch", "r.rig.json", "--camera", "c", "--images", "p.%04d.exr", "--frames", "1-2", "--out", "o.%04d.exr",
      "--undistort", "--overscan", "1.3"], "--overscan has no effect without --mode overscan"),
    (["batch", "r.rig.json", "--camera", "c", "--images", "p.%04d.exr", "--frames", "1-2", "--out", "o.%04d.exr",
      "--rectify", "--mode", "keep"], "--mode has no effect without --undistort"),
    (["batch", "r.rig.json", "--camera", "c", "--images", "p.%04d.exr", "--frames", "1-2", "--out", "o.%04d.exr",
      "--colour-space", "ACEScg"], "--colour-space has no effect without --colour"),
    (["colour", "fit", "--patches", "p.csv", "--out", "f.colour.json", "--adaptation", "CAT02"],
     "--adaptation has no effect without --target-white"),
    (["colour", "export", "f.colour.json", "--icc", "f.icc", "--adaptation", "CAT02"],
     "--adaptation has no effect without --ocio, --clf or --dctl"),
    (["colour", "export", "f.colour.json", "--ocio", "o", "--icc-version", "2"], "--icc-version has no effect without --icc"),
    (["distortion", "fit", "--lines", "l.json", "--board", "chessboard:9x6", "--out", "l.json"],
     "--board has no effect without images (--images)"),
    (["calibrate", "board", "--board", "chessboard:9x6:1", "--images", "l=a.png", "--out", "o.rig.json",
      "--suggest-preview", "s.png"], "--suggest-preview has no effect without --suggest N"),
    (["stmap", "r.rig.json", "--camera", "c", "--out", "s", "--distance", "2"], "--distance has no effect without --sigma"),
    (["rectify", "r.rig.json", "--method", "hartley", "--refine", "--matches", "m.csv", "--out", "r.rig.json"],
     "--refine has no effect without --method camera"),
    (["solve", "images/left", "images/right", "--frames", "1-3", "--out", "s"],
     "--frames has no effect without a frame placeholder in IMAGES_DIR or --images (left.%04d.exr)"),
    (["solve", "shots/", "--images", "left=*_L.png", "right=*_R.png", "--frames", "1-3", "--out", "s"],
     "--frames has no effect without a frame placeholder in IMAGES_DIR or --images (left.%04d.exr)"),
]


@pytest.mark.parametrize("argv, reason", NEEDS_ANOTHER, ids=[f"{' '.join(a[:1])} {r.split()[0]}" for a, r in NEEDS_ANOTHER])
def test_flag_without_the_one_it_needs_is_a_usage_error(argv, reason, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    verb = " ".join(word for word in argv[:2] if word.isalpha())
    assert capsys.readouterr().err.splitlines() == [f"camcal {verb}: error: {reason}", f"see 'camcal {verb} --help'"]
    assert list(tmp_path.iterdir()) == []


def test_defaults_filled_when_the_flag_is_not_given():
    parser = build_parser()
    undistort = parser.parse_args(["undistort", "r.rig.json", "--camera", "c", "--images", "a.png", "--out", "u"])
    overscan = parser.parse_args(["undistort", "r.rig.json", "--camera", "c", "--images", "a.png", "--out", "u",
                                  "--mode", "overscan", "--overscan", "1.3"])
    assert (undistort.mode, undistort.overscan, undistort.distance) == ("crop", 1.1, None)
    assert (overscan.mode, overscan.overscan) == ("overscan", 1.3)
    fit = parser.parse_args(["colour", "fit", "--patches", "p.csv", "--out", "f.colour.json"])
    export = parser.parse_args(["colour", "export", "f.colour.json", "--ocio", "o"])
    assert fit.adaptation == export.cat == "Bradford" and export.icc_version == 4


def test_one_adaptation_default_in_the_library_and_every_verb():
    """``--adaptation`` means one thing with one default: every verb's and the library's ``characterise``."""
    defaults = {" ".join(path): action.help for path, leaf in leaf_parsers(build_parser())
                for action in leaf._actions if "--adaptation" in action.option_strings}
    assert set(defaults) == {"colour fit", "colour export"}
    assert all(text.endswith("(default: Bradford)") for text in defaults.values())
    assert inspect.signature(characterise).parameters["adaptation"].default == "Bradford"
    assert inspect.signature(fit_colour).parameters["adaptation"].default == "Bradford"


def test_no_opencv_log_line_before_the_error(tmp_path):
    """OpenCV's ``[ WARN:0@0.4] ... imread_('missing.png')`` must not precede camcal's one line: the file is checked
    first, and below that the command line keeps OpenCV's log at ERROR (OpenCV's own read of a missing file)."""
    env = {key: value for key, value in os.environ.items() if key != "OPENCV_LOG_LEVEL"}
    missing = tmp_path / "missing.png"
    run = subprocess.run([sys.executable, "-m", "camcal", "distortion", "fit", "--images", str(missing),
                          "--out", str(tmp_path / "l.json")], capture_output=True, text=True, env=env)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == f"camcal: error: cannot read {missing} (missing file)\n"
    script = (f"import cv2, camcal.cli; camcal.cli.main(['rig', 'show', {str(missing)!r}]); "
              f"assert cv2.imread({str(missing)!r}) is None")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert run.returncode == 0 and run.stderr == f"camcal: error: rig file not found: {missing}\n"
    bare = subprocess.run([sys.executable, "-c", f"import cv2; cv2.imread({str(missing)!r})"], capture_output=True,
                          text=True, env=env)
    assert "WARN" in bare.stderr  # the line the command line holds back
