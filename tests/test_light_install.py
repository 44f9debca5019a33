"""The light install: ``pip install camcal`` alone shows, exports and imports rigs, undistorts and writes ST-maps.

The slow test builds a fresh virtual environment with ``pip install .`` only
(the lock file as constraints) and runs the command line there; the heavy verbs
(``solve``, ``colour fit``, ``rig export --to usd``, ``batch``, ``blender import``)
must then say in one line which extra they need. Its fast sibling runs the same
commands in this environment with every optional module hidden
(``sys.modules[name] = None`` for each module of :data:`camcal.base.extras.EXTRAS`).
Both check the outputs against OpenCV's own reading of the exported file and
against camcal's undistortion and ST-maps computed here, with every extra.
"""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.base.extras import EXTRAS
from camcal.geometry.stmap import make_stmaps
from camcal.geometry.undistort import make_undistorter
from camcal.io.stmap import read_exr
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig
from camcal.synthetic import example_camera
from fresh_venv import make_venv, run

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements" / "lock-py313.txt"
OPENCV_LENS = (-0.21, 0.05, 1.0e-3, -5.0e-4, 0.0)  # k3 = 0: Kalibr's radtan holds it exactly
#: distributions that only the extras install
HEAVY = {"pycolmap", "pyceres", "colour-science", "opencolorio", "rawpy", "matplotlib", "dask", "distributed",
         "usd-core", "openimageio", "bpy"}

# Runs several `camcal` command lines in one process with every optional module hidden; prints the exit code and
# the standard error of each.
_WITHOUT_EXTRAS = """
import contextlib, io, json, sys
for name in json.loads(sys.argv[1]):
    sys.modules[name] = None
from camcal.cli import main
results = []
for argv in json.loads(sys.argv[2]):
    with contextlib.redirect_stderr(io.StringIO()) as stderr:
        results.append((main(argv), stderr.getvalue()))
print("RESULTS", json.dumps(results))
"""


def _inputs(tmp_path: Path) -> tuple[Path, Path]:
    """A one-camera rig with an OpenCV lens, and a plate of that camera."""
    camera = example_camera("left", image_size=(160, 120), fx=150.0, fy=149.0, principal_point=(79.3, 61.2),
                            distortion=Distortion.from_opencv_coefficients(OPENCV_LENS))
    rig_path = Rig((camera,)).save(tmp_path / "one.rig.json")
    plate = cv2.GaussianBlur(np.random.default_rng(7).integers(0, 255, (120, 160, 3), dtype=np.uint8), (0, 0), 2.0)
    plate_path = tmp_path / "plate.png"
    cv2.imwrite(str(plate_path), plate)
    return rig_path, plate_path


def _light_commands(tmp_path: Path, rig: Path, plate: Path) -> list[list[str]]:
    out = tmp_path / "out"
    return [
        ["rig", "show", str(rig)],
        ["rig", "export", str(rig), "--to", "opencv", str(out / "left.yaml")],
        ["rig", "export", str(rig), "--to", "kalibr", str(out / "camchain.yaml")],
        ["rig", "export", str(rig), "--to", "nuke", str(out / "left.nk")],
        ["rig", "export", str(rig), "--to", "colmap", str(out / "colmap")],
        ["rig", "import", str(out / "left.yaml"), "--from", "opencv", "--out", str(out / "imported.rig.json")],
        ["rig", "import", str(out / "camchain.yaml"), "--from", "kalibr", "--out", str(out / "kalibr.rig.json")],
        ["undistort", str(rig), "--camera", "left", "--images", str(plate), "--out", str(out / "undistorted")],
        ["stmap", str(rig), "--camera", "left", "--out", str(out / "stmaps")],
    ]


def _heavy_commands(tmp_path: Path, rig: Path) -> list[tuple[list[str], str]]:
    """Heavy verbs on valid inputs, each with the extra it needs (nothing written without it)."""
    shots = tmp_path / "shots"
    shots.mkdir()
    for index in range(2):
        cv2.imwrite(str(shots / f"{index:02d}.png"), np.full((48, 64), 40 * index, dtype=np.uint8))
    heavy = tmp_path / "heavy"
    return [
        (["solve", str(shots), "--out", str(heavy / "solve")], "calibrate"),
        (["colour", "fit", "--chart", str(shots / "00.png"), "--reference", "babel", "--illuminant", "D65",
          "--camera-name", "cam", "--out", str(heavy / "cam.colour.json")], "colour"),
        (["rig", "export", str(rig), "--to", "usd", str(heavy / "one.usda")], "usd"),
        (["batch", str(rig), "--camera", "left", "--images", str(shots / "%02d.png"), "--frames", "0-1",
          "--out", str(heavy / "%02d.png"), "--undistort"], "dask"),
        (["blender", "import", str(rig), "--blend", str(heavy / "one.blend")], "blender"),
    ]


def _check_missing_extra(argv: list[str], extra: str, code: int, stderr: str, tmp_path: Path) -> None:
    """Exit 2, one line naming the verb and its extra, nothing written."""
    verb = " ".join(argv[:2]) if argv[0] in ("colour", "rig", "blender") else argv[0]
    assert code == 2, f"camcal {' '.join(argv)}: exit {code}\n{stderr}"
    lines = [[f"camcal: error: camcal {verb} needs the '{extra}' extra ({module} is not installed): "
              f"pip install 'camcal[{extra}]'"] for module, its_extra in EXTRAS.items() if its_extra == extra]
    assert stderr.splitlines() in lines, stderr
    assert not (tmp_path / "heavy").exists()


def _check_outputs(tmp_path: Path, rig: Path, plate: Path) -> None:
    out = tmp_path / "out"
    camera = Rig.load(rig).camera("left")
    storage = cv2.FileStorage(str(out / "left.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(storage.getNode("camera_matrix").mat(), camera.K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(storage.getNode("distortion_coefficients").mat().ravel()[:5], OPENCV_LENS,
                               rtol=0, atol=1e-15)
    storage.release()
    for name in ("imported.rig.json", "kalibr.rig.json"):
        back = Rig.load(out / name).cameras[0]
        np.testing.assert_allclose(back.K, camera.K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(back.distortion.opencv_coefficients(5), OPENCV_LENS, rtol=0, atol=1e-12)
    assert (out / "left.nk").read_text().count("Camera") >= 1
    assert (out / "colmap" / "cameras.txt").is_file()
    undistorted = cv2.imread(str(out / "undistorted" / "plate.png"), cv2.IMREAD_UNCHANGED)
    expected = make_undistorter(camera).apply(cv2.imread(str(plate), cv2.IMREAD_UNCHANGED))
    assert undistorted.shape == expected.shape and np.array_equal(undistorted, expected)
    maps = make_stmaps(camera, 1.1)
    assert np.array_equal(read_exr(out / "stmaps" / "left_undistort.exr"), maps.undistort.astype(np.float32))
    assert np.array_equal(read_exr(out / "stmaps" / "left_redistort.exr"), maps.redistort.astype(np.float32))


def test_light_verbs_run_with_every_optional_module_missing(tmp_path):
    rig, plate = _inputs(tmp_path)
    commands = _light_commands(tmp_path, rig, plate)
    heavy = _heavy_commands(tmp_path, rig)
    argvs = commands + [argv for argv, _ in heavy]
    result = subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS, json.dumps(sorted(EXTRAS)), json.dumps(argvs)],
                            capture_output=True, text=True, cwd=tmp_path)
    lines = [line for line in result.stdout.splitlines() if line.startswith("RESULTS ")]
    assert result.returncode == 0 and lines, result.stderr
    results = json.loads(lines[-1].split(" ", 1)[1])
    for argv, (code, stderr) in zip(commands, results):
        assert code == 0, f"camcal {' '.join(argv)}: exit {code}\n{stderr}"
    assert "camera 'left': 160x120 px" in result.stdout
    _check_outputs(tmp_path, rig, plate)
    for (argv, extra), (code, stderr) in zip(heavy, results[len(commands):]):
        _check_missing_extra(argv, extra, code, stderr, tmp_path)


@pytest.mark.slow
def test_pip_install_without_extras_in_a_fresh_venv(tmp_path):
    venv = make_venv(tmp_path / "venv")
    venv.pip_install("-c", LOCK, ROOT, cwd=tmp_path)
    installed = venv.installed()
    assert "camcal" in installed and not installed & HEAVY, installed & HEAVY
    assert str(venv.path) in venv.camcal_location()

    rig, plate = _inputs(tmp_path)
    for argv in _light_commands(tmp_path, rig, plate):
        run([venv.camcal, *argv], tmp_path, venv.env, check=True)
    _check_outputs(tmp_path, rig, plate)

    for argv, extra in _heavy_commands(tmp_path, rig):
        result = run([venv.camcal, *argv], tmp_path, venv.env)
        _check_missing_extra(argv, extra, result.returncode, result.stderr, tmp_path)



def test_models_refused_for_a_missing_extra_are_ranked_out_on_one_line(monkeypatch):
    """Without pycolmap and pyceres each lens model the Ceres engine fits is refused; ``calibrate board``'s ranking
    says why once, on one line naming every such model and the extra, where a scored model keeps its own line."""
    from camcal.geometry.board import Board
    from camcal.geometry.zhang_fit import calibrate_model
    from camcal.geometry.zhang_result import ModelScore, ranking_lines
    from camcal.geometry.zhang_starts import FIT_ERRORS, one_line
    from tests.geometry.test_zhang_models import views

    board = Board("chessboard", 9, 6, 0.03)
    camera = example_camera("cam", image_size=(640, 480), fx=600.0, fy=600.0, principal_point=(321.0, 238.0),
                            distortion=Distortion("polynomial", {"k1": -0.1, "k2": 0.02}))
    training = [dict(enumerate(views(camera, board, 5, np.random.default_rng(3), distance=(0.4, 0.6))["cam"]))]
    for module in ("pycolmap", "pyceres"):
        monkeypatch.setitem(sys.modules, module, None)
    ceres_models = ("none", "polynomial")
    scores = []
    for model in ceres_models:
        with pytest.raises(FIT_ERRORS) as refused:
            calibrate_model(board, ["cam"], training, model, set(), scoring=True, units="m", outlier_factor=3.0,
                            min_outlier_px=1.0, loss="trivial", loss_scale=1.0)
        scores.append(ModelScore(model, None, 4, one_line(refused.value)))
    scored = ModelScore("opencv-thin-prism", 0.25, 16)
    ranking = (scored, *scores, ModelScore("kannala-brandt", None, 8, "OpenCV fisheye.calibrate failed"))
    lines = ranking_lines(ranking)
    extra = [line for line in lines if "extra" in line]
    assert extra == [f"{', '.join(ceres_models)}: ranked out: the Ceres engine's fit needs the 'calibrate' extra "
                     "(pycolmap is not installed): pip install 'camcal[calibrate]'"], "\n".join(lines)
    assert lines == [scored.describe(), extra[0], "kannala-brandt: ranked out: OpenCV fisheye.calibrate failed"]


@pytest.mark.slow
def test_auto_without_the_calibrate_extra_names_it_once(tmp_path):
    """``calibrate board`` (model auto) on the shipped board set with pycolmap and pyceres hidden: it calibrates on
    OpenCV's fits, the camera the set was rendered with comes back, and the extra is named on one line."""
    argv = ["calibrate", "board", "--board", "chessboard:9x6:0.03",
            "--images", f"cam={ROOT / 'tests/data/boards/*.png'}",
            "--no-cache", "--out", str(tmp_path / "cam.rig.json")]
    result = subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS, json.dumps(["pycolmap", "pyceres"]),
                             json.dumps([argv])], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 0 and json.loads(result.stdout.split("RESULTS ", 1)[1])[0][0] == 0, result.stderr
    extra = [line for line in result.stdout.splitlines() if "'calibrate' extra" in line]
    assert len(extra) == 1 and extra[0].count("ranked out") == 1, result.stdout
    camera = Rig.load(tmp_path / "cam.rig.json").cameras[0]
    np.testing.assert_allclose([camera.K[0, 0], camera.K[1, 1]], [700.0, 700.0], rtol=0.01)
