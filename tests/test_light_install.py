"""The light install: ``pip install camcal`` alone shows, exports and imports rigs, undistorts and writes ST-maps.

The slow test builds a fresh virtual environment with ``pip install .`` only
(the lock file as constraints) and runs the command line there; ``camcal solve``
must then say in one line which extra it needs. Its fast sibling runs the same
commands in this environment with every optional module hidden
(``sys.modules[name] = None`` for each module of :data:`camcal.base.extras.EXTRAS`).
Both check the outputs against OpenCV's own reading of the exported file and
against camcal's undistortion and ST-maps computed here, with every extra.
"""

import json
import os
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

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements" / "lock-py313.txt"
OPENCV_LENS = (-0.21, 0.05, 1.0e-3, -5.0e-4, 0.0)  # k3 = 0: Kalibr's radtan holds it exactly
#: distributions that only the extras install
HEAVY = {"pycolmap", "pyceres", "colour-science", "opencolorio", "rawpy", "matplotlib", "dask", "distributed",
         "usd-core", "bpy"}

# Runs several `camcal` command lines in one process with every optional module hidden; prints their exit codes.
_WITHOUT_EXTRAS = """
import json, sys
for name in json.loads(sys.argv[1]):
    sys.modules[name] = None
from camcal.cli import main
print("EXIT_CODES", json.dumps([main(argv) for argv in json.loads(sys.argv[2])]))
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
    result = subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS, json.dumps(sorted(EXTRAS)), json.dumps(commands)],
                            capture_output=True, text=True, cwd=tmp_path)
    codes = [line for line in result.stdout.splitlines() if line.startswith("EXIT_CODES ")]
    assert result.returncode == 0 and codes, result.stderr
    assert json.loads(codes[-1].split(" ", 1)[1]) == [0] * len(commands), result.stderr
    assert "camera 'left': 160x120 px" in result.stdout
    _check_outputs(tmp_path, rig, plate)


def _run(argv: list, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, env=env)


@pytest.mark.slow
def test_pip_install_without_extras_in_a_fresh_venv(tmp_path):
    venv = tmp_path / "venv"
    assert _run([sys.executable, "-m", "venv", venv], tmp_path).returncode == 0
    python, camcal = venv / "bin" / "python", venv / "bin" / "camcal"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CAMCAL_ADDON_DIR", "CAMCAL_OCIO_CONFIGS")}
    install = _run([python, "-m", "pip", "install", "-q", "-c", LOCK, ROOT], tmp_path, env)
    assert install.returncode == 0, install.stderr
    listed = _run([python, "-m", "pip", "list", "--format=json"], tmp_path, env)
    installed = {entry["name"].lower().replace("_", "-") for entry in json.loads(listed.stdout)}
    assert "camcal" in installed and not installed & HEAVY, installed & HEAVY
    where = _run([python, "-c", "import camcal; print(camcal.__file__)"], tmp_path, env)
    assert str(venv) in where.stdout, where.stdout + where.stderr

    rig, plate = _inputs(tmp_path)
    for argv in _light_commands(tmp_path, rig, plate):
        result = _run([camcal, *argv], tmp_path, env)
        assert result.returncode == 0, f"camcal {' '.join(argv)}\n{result.stdout}\n{result.stderr}"
    _check_outputs(tmp_path, rig, plate)

    folder = tmp_path / "shots"
    folder.mkdir()
    for index in range(2):
        cv2.imwrite(str(folder / f"{index:02d}.png"), np.full((48, 64), 40 * index, dtype=np.uint8))
    solve = _run([camcal, "solve", folder, "--out", tmp_path / "solve"], tmp_path, env)
    assert solve.returncode == 2
    assert solve.stderr.splitlines() == ["camcal: error: camcal solve needs the 'calibrate' extra "
                                         "(pycolmap is not installed): pip install 'camcal[calibrate]'"]
    assert not (tmp_path / "solve").exists()
