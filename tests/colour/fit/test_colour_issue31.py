"""Issue 31's must-shows, measured the way bench/bench_colour.py and bench/bench_colour_cameras.py measure them.

Simulated cameras (measured sensitivities, 0.2 % noise), ColorChecker 24
training, 190 independent RAW-to-ACES reflectances; ``colour fit``'s default
(``--model auto`` on the chart). The ones not met are strict xfails with the
figures measured.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from camcal.colour.chart.patches import PatchSet
from camcal.colour.fit.characterise import characterise

BENCH = Path(__file__).resolve().parents[3] / "bench"


def _bench(name):
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _auto(sim, illuminant):
    w = sim.white
    train = PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train)
    test = PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test)
    xy = f"{w[0] / w.sum():.10f},{w[1] / w.sum():.10f}"
    return train, test, characterise(train, white=xy, model="auto", test=test, loo=False, illuminant=illuminant)


def _unmet(reason):
    return pytest.mark.xfail(strict=True, reason=f"issue 31 must-show not met: {reason}")


@pytest.mark.slow
@pytest.mark.parametrize("camera, illuminant, target", [
    pytest.param("Nikon 5100 (NPL)", "D65", 0.75, marks=_unmet(
        "0.794 mean (p95 1.776); the target is below what these models reach even trained on the 190 colours: "
        "10-fold cross-validation on them, nine models with auto's ridge grid, best with hindsight, gives 0.761 "
        "(bench_colour); --spectra (CIE 2017 + Munsell colours through sensitivities estimated from the chart) "
        "0.777")),
    pytest.param("Nikon 5100 (NPL)", "A", 0.85, marks=_unmet(
        "0.919 mean (p95 2.334); the 190's own 10-fold cross-validation 0.898; --spectra keeps the chart fit")),
    pytest.param("Sigma SDMerill (NPL)", "D65", 1.7, marks=_unmet(
        "1.916 mean (p95 4.397); the 190's own 10-fold cross-validation 1.829; --spectra 1.988 (its "
        "root-polynomial:3 fits, 1.82, fail the bake check)")),
])
def test_independent_mean_within_target(sim_factory, camera, illuminant, target):
    _, _, out = _auto(sim_factory(camera, illuminant), illuminant)
    assert out.result.stats_test.mean <= target


@pytest.mark.slow
@pytest.mark.parametrize("camera, illuminant", [
    ("Nikon 5100 (NPL)", "D65"), ("Nikon 5100 (NPL)", "A"), ("Sigma SDMerill (NPL)", "D65"),
    pytest.param("Sigma SDMerill (NPL)", "A", marks=_unmet(
        "auto picks root-polynomial:3 (xyz+de2000) at 2.401 where root-polynomial:2 (xyz+de2000) gives 2.279 "
        "(+5.3 %): every root-polynomial:2 fit fails the exporters' bake check (0.24 to 3.52 > 0.2); the pick is "
        "the best candidate that exports (0.0 %)")),
])
def test_auto_pick_within_two_percent_of_best_candidate(sim_factory, camera, illuminant):
    bench = _bench("bench_colour")
    sim = sim_factory(camera, illuminant)
    train, test, out = _auto(sim, illuminant)
    picked, best, _, _, _ = bench.selection_gap(out, train, test, sim.white, illuminant)
    assert picked <= 1.02 * best


@pytest.fixture(scope="module")
def cameras():
    bench = _bench("bench_colour_cameras")
    files = sorted(bench.DATA.glob("*.json"))
    ratios = {}
    for path in files:
        cam = bench.load_camera(path, "D65")
        train, test = bench.scene(cam)
        w = cam.white_XYZ
        xy = f"{w[0] / w.sum():.10f},{w[1] / w.sum():.10f}"
        ours = characterise(train, white=xy, model="auto", test=test, loo=False).result.stats_test.mean
        ratios[cam.name] = ours / bench.colour_science_best(train, test, w)[0]
    return ratios


@pytest.mark.slow
def test_better_than_colour_science_best_on_every_unseen_camera(cameras):
    assert len(cameras) >= 8
    assert all(r < 1 for r in cameras.values()), cameras


@pytest.mark.slow
@_unmet("mean ratio 0.930 over 15 cameras (0.851 Dalsa to 0.979 ARRI D-21) against <= 0.85; trained on the 190 "
        "colours themselves (10-fold cross-validation, nine models, best with hindsight) the ratio is 0.879, so no "
        "training set of these models is expected to reach 0.85 (bench_colour_cameras)")
def test_mean_ratio_to_colour_science_best_on_unseen_cameras(cameras):
    assert np.mean(list(cameras.values())) <= 0.85
