"""bench/bench_colour.py runs, and says so when ArgyllCMS is absent; bench/bench_colour_lights.py runs."""

import importlib.util
import shutil
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_colour.py"


def test_bench_without_colprof_prints_skipped(monkeypatch, capsys):
    spec = importlib.util.spec_from_file_location("bench_colour", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    real_which = shutil.which
    monkeypatch.setattr(bench.shutil, "which", lambda name: None if name in ("colprof", "xicclu") else real_which(name))
    monkeypatch.setattr(bench, "SCENES", bench.SCENES[:1])
    monkeypatch.setattr(bench, "CAMCAL_MODELS", ["matrix3x3", "auto"])
    monkeypatch.setattr(bench.CAMERAS, "FLOOR_MODELS", ("matrix3x3",))
    assert bench.main() == 0
    out = capsys.readouterr().out
    assert "skipped: colprof not installed" in out
    assert "colour-science best" in out and "ratio" in out
    assert "auto gap: picked" in out and "(target <= 2 %)" in out
    assert "auto chart resolution (24 patches held out one at a time)" in out
    assert "2 % apart are ranked right with probability 0." in out
    assert "trained on the independent colours themselves (10-fold cross-validation, the best of 1 models" in out


@pytest.mark.slow  # ~12 s: auto and the bake checks on one scene; selection_gap and scene run fast above
def test_lights_bench_prints_pick_best_and_gap(monkeypatch, capsys):
    spec = importlib.util.spec_from_file_location("bench_colour_lights", BENCH.with_name("bench_colour_lights.py"))
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    monkeypatch.setattr(bench, "CAMERAS", bench.CAMERAS[:1])
    monkeypatch.setattr(bench, "LIGHTS", ("FL11",))
    assert bench.main() == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("Nikon 5100, FL11"))
    pick, best, gap = row.split()[3:6]
    assert float(pick) >= float(best) and float(gap.rstrip("%")) == pytest.approx(
        100 * (float(pick) / float(best) - 1), abs=0.1)
    assert "within 2 % on" in out and "best candidate with hindsight: ours" in out
