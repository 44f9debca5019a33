"""The colour accuracy must-shows, measured as bench/bench_colour.py and bench/bench_colour_cameras.py measure them.

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
    return pytest.mark.xfail(strict=True, raises=AssertionError, reason=f"must-show not met: {reason}")


FLOOR_TARGET = 1.02  # the default within this factor of the independent set's own cross-validation


@pytest.mark.slow
@pytest.mark.parametrize("camera, illuminant", [
    pytest.param("Nikon 5100 (NPL)", "D65", marks=_unmet(
        "0.779 = 1.025 x the floor (the 190's own 10-fold cross-validation, nine models with auto's ridge grid, "
        "best with hindsight: 0.761); the best of auto's chart candidates with hindsight, root-polynomial:3 (xyz, "
        "lambda 1e-06, shrunk 0.1 to matrix), gives 0.773 = 1.017 x, but the chart's leave-one-out prefers the pick "
        "by 4.4 +- 4.6 %, below what 24 patches resolve (bench_colour's chart resolution)")),
    pytest.param("Nikon 5100 (NPL)", "A", marks=_unmet(
        "0.919 = 1.024 x the floor (0.898); the best of auto's chart candidates with hindsight, root-polynomial:3 "
        "(xyz, lambda 1e-06, shrunk 0.1 to matrix), 0.898 = 1.000 x, is ranked below the pick by leave-one-out "
        "(by 3.5 +- 4.4 %)")),
    ("Sigma SDMerill (NPL)", "D65"),
])
def test_independent_mean_within_target_of_the_floor(sim_factory, camera, illuminant):
    sim = sim_factory(camera, illuminant)
    _, test, out = _auto(sim, illuminant)
    floor, _ = _bench("bench_colour_cameras").same_distribution_floor(test, sim.white)
    assert out.result.stats_test.mean <= FLOOR_TARGET * floor


@pytest.mark.slow
@pytest.mark.parametrize("camera, illuminant", [
    ("Nikon 5100 (NPL)", "D65"),
    pytest.param("Nikon 5100 (NPL)", "A", marks=_unmet(
        "auto picks root-polynomial:3 (xyz+de2000, lambda 1e-06) at 0.919 where root-polynomial:3 (xyz, lambda "
        "1e-06, shrunk 0.1 to matrix) gives 0.898 (+2.4 %): the chart's leave-one-out prefers the pick by "
        "3.5 +- 4.4 %, within one standard error (two candidates 2 % apart are ranked right with probability 0.69)")),
    ("Sigma SDMerill (NPL)", "D65"),
    pytest.param("Sigma SDMerill (NPL)", "A", marks=_unmet(
        "auto picks root-polynomial:2 (xyz, lambda 0, shrunk 0.1 to matrix) at 2.227 where root-polynomial:2 "
        "(xyz+de2000, lambda 0, shrunk 0.2 to matrix) gives 2.154 (+3.4 %): the better candidates fail the "
        "exporters' bake check; the pick is the best candidate that exports (0.0 %)")),
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
@_unmet("mean ratio 0.926 over 15 cameras (0.851 Dalsa to 0.996 Nikon D70) against <= 0.90; the best of auto's chart "
        "candidates picked with hindsight on the independent colours gives 0.900, so only a pick made with hindsight "
        "reaches 0.90 (bench_colour_cameras); trained on the 190 colours themselves the ratio is 0.879")
def test_mean_ratio_to_colour_science_best_on_unseen_cameras(cameras):
    assert np.mean(list(cameras.values())) <= 0.90
