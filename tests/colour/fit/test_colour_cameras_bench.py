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
    assert bench.main(["D65"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("sony_ilce-7rm2"))
    ours, peer = float(row.split()[1]), float(row.split("|")[1].split()[0])
    assert 0 < ours < 3 and 0 < peer < 3
    assert "colour 1 cameras under D65, camcal auto / colour-science best: mean ratio" in out
