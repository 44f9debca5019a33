"""One NAME=VALUE convention: repeated and multi-valued options mean the same."""

import os

import cv2
import numpy as np
import pytest

import camcal.pipelines.solve as solve
from camcal.cli import build_parser, main
from camcal.cli.options import expand_glob
from camcal.base.errors import CamcalError
from camcal.model.rig import Rig
from camcal.synthetic import example_camera

# every NAME=VALUE option: (verb argv before the option, option, the rest of a valid command line)
NAMED_OPTIONS = [
    (["calibrate", "board", "--board", "chessboard:9x6:1"], "--images", ["--out", "x.rig.json"]),
    (["solve", "DIR"], "--images", ["--out", "o"]),
    (["rectify", "R.rig.json"], "--images", ["--out", "r.rig.json"]),
    (["colour", "match"], "--images", ["--out", "m.colour.json"]),
    (["colour", "match"], "--fits", ["--out", "m.colour.json"]),
    (["colour", "match"], "--patches", ["--out", "m.colour.json"]),
    (["colour", "match"], "--test-patches", ["--out", "m.colour.json"]),
]
IDS = [" ".join(head[:2]) + " " + option for head, option, _ in NAMED_OPTIONS]


@pytest.mark.parametrize("head, option, tail", NAMED_OPTIONS, ids=IDS)
def test_repeated_and_multi_valued_mean_the_same(head, option, tail):
    parser = build_parser()
    dest = "camera" if head[0] in ("calibrate", "solve") else option.lstrip("-").replace("-", "_")  # dest kept
    repeated = parser.parse_args([*head, option, "left=/abs/L_*.png", option, "right=R/*.png", *tail])
    multi = parser.parse_args([*head, option, "left=/abs/L_*.png", "right=R/*.png", *tail])
    expected = {"left": "/abs/L_*.png", "right": "R/*.png"}
    assert getattr(repeated, dest) == getattr(multi, dest) == expected
    assert list(getattr(multi, dest)) == ["left", "right"]  # order kept: the first camera is the reference


@pytest.mark.parametrize("head, option, tail", NAMED_OPTIONS, ids=IDS)
@pytest.mark.parametrize("spelling", ["repeated", "multi"])
def test_duplicate_name_rejected_in_one_line(head, option, tail, spelling, capsys):
    entries = [option, "left=a", option, "left=b"] if spelling == "repeated" else [option, "left=a", "left=b"]
    assert main([*head, *entries, *tail]) == 2
    err = capsys.readouterr().err
    verb = " ".join(word for word in head[:2] if word.isalpha() and word.islower())  # the verb, not its RIG or DIR
    assert err == f"camcal {verb}: error: {option} left=b: name 'left' given twice\nsee 'camcal {verb} --help'\n"


@pytest.mark.parametrize("head, option, tail", NAMED_OPTIONS, ids=IDS)
def test_missing_equals_rejected_in_one_line(head, option, tail, capsys):
    assert main([*head, option, "left", *tail]) == 2
    err = capsys.readouterr().err
    line, hint = err.splitlines()
    assert line.startswith("camcal ") and f": error: {option}: expected NAME=" in line and line.endswith(", got 'left'")
    assert hint.startswith("see 'camcal ") and hint.endswith(" --help'")


@pytest.fixture
def frames(tmp_path):
    folder = tmp_path / "shots"
    folder.mkdir()
    for name in ("L_01.png", "L_02.png", "R_01.png", "notes.txt"):
        (folder / name).write_bytes(b"x")
    return folder


def test_globs_absolute_and_relative(frames, monkeypatch):
    absolute = expand_glob("--camera", "left", str(frames / "L_*.png"))
    assert absolute == [str(frames / "L_01.png"), str(frames / "L_02.png")]
    monkeypatch.chdir(frames.parent)
    assert expand_glob("--camera", "left", "shots/L_*.png") == [os.path.join("shots", "L_01.png"),
                                                                os.path.join("shots", "L_02.png")]
    # relative to a root (solve's IMAGES_DIR); an absolute pattern ignores the root
    assert expand_glob("--camera", "right", "R_*.png", root=frames) == [str(frames / "R_01.png")]
    assert expand_glob("--camera", "right", str(frames / "R_*.png"), root="/elsewhere") == [str(frames / "R_01.png")]
    with pytest.raises(CamcalError, match=r"^--camera left=shots/X_\*.png: no image matches$"):
        expand_glob("--camera", "left", "shots/X_*.png")


@pytest.mark.parametrize("kind", ["absolute", "relative"])
def test_solve_takes_absolute_and_relative_globs(frames, monkeypatch, tmp_path, kind):
    """``solve DIR --images left=/abs/L_*.png`` (a pathlib traceback before) reaches the solver."""
    seen = {}

    def fake_solve(images, out, **options):
        seen.update(images)
        raise CamcalError("stop here")

    monkeypatch.setattr(solve, "solve_sfm", fake_solve)
    left = str(frames / "L_*.png") if kind == "absolute" else "L_*.png"
    code = main(["solve", str(frames), "--images", f"left={left}", "right=R_*.png", "--out", str(tmp_path / "o")])
    assert code == 2 and seen == {"left": [frames / "L_01.png", frames / "L_02.png"], "right": [frames / "R_01.png"]}


@pytest.mark.parametrize("spelling", ["repeated", "multi"])
def test_rectify_writes_every_camera_of_either_spelling(tmp_path, spelling):
    """The issue's bug: a second ``--images`` replaced the first, so only one camera was written."""
    size = (320, 240)
    left = example_camera("left", image_size=size, fx=300, fy=300, principal_point=(159.5, 119.5))
    right = example_camera("right", image_size=size, fx=300, fy=300, principal_point=(159.5, 119.5),
                           centre=(0.7, -6.0, 1.4))
    rig_path = Rig((left, right)).save(tmp_path / "rig.rig.json")
    rng = np.random.default_rng(0)
    for name in ("left", "right"):
        (tmp_path / name).mkdir()
        for k in range(2):
            cv2.imwrite(str(tmp_path / name / f"{name}_{k}.png"), rng.integers(0, 255, (240, 320), np.uint8))
    images = [f"left={tmp_path}/left/*.png", f"right={tmp_path}/right/*.png"]
    options = ["--images", images[0], "--images", images[1]] if spelling == "repeated" else ["--images", *images]
    out = tmp_path / "rect"
    assert main(["rectify", str(rig_path), *options, "--write", str(out), "--out", str(tmp_path / "r.rig.json")]) == 0
    assert sorted(p.name for p in out.rglob("*.png")) == ["left_0.png", "left_1.png", "right_0.png", "right_1.png"]
