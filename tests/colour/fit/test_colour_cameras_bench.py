"""bench/bench_colour_cameras.py: the measured cameras it reads and one camera through it."""

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[3] / "bench" / "bench_colour_cameras.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_colour_cameras", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cameras_are_measured_curves_no_test_uses(bench):
    files = sorted(bench.DATA.glob("*.json"))
    assert len(files) >= 8 and not any("d5100" in f.name for f in files)
    cam = bench.load_camera(files[0], "D65")
    assert cam.sensitivities.shape == (81, 3) and np.all(cam.sensitivities >= 0)
    assert cam.RGB_white[1] == pytest.approx(1.0) and cam.white_XYZ[1] == pytest.approx(1.0)


def test_one_camera_prints_ours_against_the_peer(bench, tmp_path, monkeypatch, capsys):
    name = "sony_ilce-7rm2_380_780_5.json"
    shutil.copy(bench.DATA / name, tmp_path / name)
    monkeypatch.setattr(bench, "DATA", tmp_path)
    monkeypatch.setattr(bench, "FLOOR_MODELS", ("matrix3x3", "root-polynomial:2"))
    assert bench.main(["D65"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("sony_ilce-7rm2"))
    ours, peer = float(row.split()[1]), float(row.split("|")[1].split()[0])
    assert 0 < ours < 3 and 0 < peer < 3
    assert "colour 1 cameras under D65, camcal auto / colour-science best: mean ratio" in out
    floor = float(row.split("|")[2].split()[0])
    assert 0 < floor < 3
    assert "trained on the independent colours themselves (10-fold cross-validation" in out


def test_floor_is_zero_when_a_matrix_is_the_truth(bench):
    """Constructed truth: XYZ = M @ RGB exactly, so the cross-validated matrix reproduces every held-out colour."""
    from camcal.colour.chart.patches import PatchSet

    rng = np.random.default_rng(3)
    RGB = rng.uniform(0.02, 1.0, (60, 3))
    M = np.array([[0.41, 0.36, 0.18], [0.21, 0.72, 0.07], [0.02, 0.12, 0.95]])
    white = M @ np.ones(3)
    XYZ = RGB @ M.T
    value, label = bench.same_distribution_floor(PatchSet([f"p{i}" for i in range(60)], RGB, XYZ), white,
                                                 models=("matrix3x3", "root-polynomial:2"))
    assert value < 1e-6 and label.startswith(("matrix3x3", "root-polynomial:2"))
    noisy = RGB * (1 + 0.01 * rng.standard_normal(RGB.shape))
    worse, _ = bench.same_distribution_floor(PatchSet([f"p{i}" for i in range(60)], noisy, XYZ), white,
                                             models=("matrix3x3",))
    assert worse > 0.05
