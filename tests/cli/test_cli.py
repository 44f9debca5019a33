"""The command line: --help for every verb, bad input gives one line and exit 2."""

import subprocess
import sys

import numpy as np
import pytest

from camcal import __version__
from camcal.cli import build_parser, main
from camcal.io.points_csv import write_correspondences
from camcal.model.rig import Rig
from camcal.synthetic import example_camera, points_in_view


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camcal", *args], capture_output=True, text=True)


def all_verbs():
    """Every leaf verb path of the parser, e.g. ('calibrate', 'dlt')."""

    def walk(parser, prefix):
        actions = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        if not actions:
            yield prefix
            return
        for name, sub in actions[0].choices.items():
            yield from walk(sub, prefix + (name,))

    return list(walk(build_parser(), ()))


def test_version():
    result = run("--version")
    assert result.returncode == 0 and result.stdout.strip() == f"camcal {__version__}"


@pytest.mark.parametrize("verb", all_verbs(), ids=" ".join)
def test_every_verb_has_help(verb, capsys):
    with pytest.raises(SystemExit) as info:
        main([*verb, "--help"])
    assert info.value.code == 0
    assert "usage: camcal " + " ".join(verb) in capsys.readouterr().out


@pytest.fixture
def points_csv(tmp_path):
    truth = example_camera("cam")
    rng = np.random.default_rng(4)
    X = points_in_view(truth, 30, rng)
    x = truth.project(X) + rng.normal(0, 0.3, (30, 2))
    return write_correspondences(tmp_path / "points.csv", X, x), truth


def test_calibrate_dlt_writes_a_rig(points_csv, tmp_path):
    path, truth = points_csv
    out = tmp_path / "out" / "cam.rig.json"
    result = run("calibrate", "dlt", "--points", str(path), "--image-size", "1920", "1080", "--name", "A", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "RMS reprojection error" in result.stdout
    camera = Rig.load(out).camera("A")
    assert abs(camera.K[0, 0] / truth.K[0, 0] - 1) < 0.01
    assert camera.quality["n_observations"] == 30
    shown = run("rig", "show", str(out))
    assert shown.returncode == 0 and "camera 'A': 1920x1080 px" in shown.stdout


def _bad_csv(tmp_path, points_csv, kind):
    path, _ = points_csv
    lines = path.read_text().splitlines()
    bad = tmp_path / f"{kind}.csv"
    if kind == "header":
        lines[0] = "x,y,z,u,v"
    elif kind == "few":
        lines = lines[:6]
    elif kind == "nan":
        lines[3] = "nan," + lines[3].split(",", 1)[1]
    elif kind == "text":
        lines[2] = "a,b,c,d,e"
    elif kind == "coplanar":
        lines = [lines[0]] + [",".join(v if i != 2 else "1.0" for i, v in enumerate(line.split(","))) for line in lines[1:]]
    bad.write_text("\n".join(lines) + "\n")
    return bad


@pytest.mark.parametrize(
    "kind, message",
    [
        ("header", "expected the header X,Y,Z,u,v"),
        ("few", "need at least 6 correspondences, got 5"),
        ("nan", "NaN or infinite"),
        ("text", "not a number"),
        ("coplanar", "coplanar"),
        ("missing", "points file not found"),
    ],
)
def test_calibrate_dlt_bad_input(tmp_path, points_csv, kind, message):
    bad = tmp_path / "missing.csv" if kind == "missing" else _bad_csv(tmp_path, points_csv, kind)
    out = tmp_path / "cam.rig.json"
    result = run("calibrate", "dlt", "--points", str(bad), "--image-size", "1920", "1080", "--out", str(out))
    assert result.returncode == 2
    assert result.stderr.startswith("camcal: error: ") and message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not out.exists()
    assert not any(p.name.startswith(".cam.rig.json") for p in tmp_path.iterdir())


def test_calibrate_dlt_bad_image_size(points_csv, tmp_path):
    path, _ = points_csv
    out = tmp_path / "cam.rig.json"
    result = run("calibrate", "dlt", "--points", str(path), "--image-size", "0", "1080", "--out", str(out))
    assert result.returncode == 2 and "--image-size must be two positive integers" in result.stderr
    assert not out.exists()


def test_rig_show_bad_input(tmp_path):
    result = run("rig", "show", str(tmp_path / "none.rig.json"))
    assert result.returncode == 2 and result.stderr.strip() == f"camcal: error: rig file not found: {tmp_path / 'none.rig.json'}"
    bad = tmp_path / "bad.rig.json"
    bad.write_text("[1, 2")
    result = run("rig", "show", str(bad))
    assert result.returncode == 2 and "not valid JSON" in result.stderr


def test_unknown_verb_exits_2():
    assert run("calibrate", "sorcery").returncode == 2
