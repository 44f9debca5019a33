"""A solve whose features are extracted and matched on Dask survives faults: a worker SIGKILLed mid-write, then the
client, in either stage.

As in ``test_batch_faults.py``: the cluster is separate from the client (a
``LocalCluster`` of 2 worker processes in this test process, the client
``python -m camcal solve --scheduler ADDR`` in its own process group), and a
worker plugin makes each kill land midway through the write of a frame's
features (or a block's matches), deterministically: the first write of a
chosen file stops after truncating its temporary file to half, records its
process id in a marker file and waits there. The fast siblings are in
``test_solve_features.py`` and ``test_solve_matching.py``.
"""

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from camcal.base.atomic import TEMPORARY_TAG
from camcal.cli import main
from camcal.pipelines.solve_features import FEATURE_CACHE
from camcal.pipelines.solve_matching import BLOCK_PAIRS
from camcal.synthetic import render_stereo_sequence
from dask_faults import StallOnce, drain, temporaries, wait_for_pid
from test_solve import _numbers

ROOT = Path(__file__).resolve().parents[2]
N_FRAMES = 6


def _render(folder, n_frames):
    width = 256
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(folder, n_frames=n_frames, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))


def _killed_run(command, cwd, markers, worker_victim, client_victim) -> None:
    """Run the solve ``command`` in its own process group; SIGKILL the worker stalled on ``worker_victim``'s write,
    then the client (and the worker stalled for it) once ``client_victim``'s write stalls."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    process = subprocess.Popen([sys.executable, "-m", "camcal", *command], cwd=cwd, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        os.kill(wait_for_pid(markers[worker_victim], process), signal.SIGKILL)  # a worker, mid-write
        stalled = wait_for_pid(markers[client_victim], process)  # another write, later
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the client, mid-run
        process.wait(timeout=30)
    os.kill(stalled, signal.SIGKILL)  # and the worker still writing for it


def _same_as_uninterrupted(out, uninterrupted):
    """No temporary, no cache; the same files, rig and points as the uninterrupted in-process run, bit for bit (the
    same features and matches in the same database order, then the same seeded, single-threaded mapping and
    refinement)."""
    assert temporaries(out.parent) == [] and not (out / FEATURE_CACHE).exists()
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(uninterrupted).as_posix() for p in uninterrupted.rglob("*") if p.is_file())
    ours = dict(_numbers(json.loads((out / "solve.rig.json").read_text())))
    theirs = dict(_numbers(json.loads((uninterrupted / "solve.rig.json").read_text())))
    assert ours == theirs and len(ours) > 50
    assert (out / "points.ply").read_bytes() == (uninterrupted / "points.ply").read_bytes()
    return ours


@pytest.mark.slow
def test_worker_killed_mid_extraction_then_client_killed_then_rerun(tmp_path, monkeypatch, capsys):
    from distributed import Client, LocalCluster

    _render(tmp_path / "in", N_FRAMES)
    solve = ["solve", "in/left", "--features", "512"]
    monkeypatch.chdir(tmp_path)
    assert main(solve + ["--out", "uninterrupted"]) == 0  # in this process, no Dask

    worker_victim, client_victim = 1, 4
    markers = {index: tmp_path / f"stalled.{index}" for index in (worker_victim, client_victim)}
    out = tmp_path / "out"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        dask.register_plugin(StallOnce("camcal.pipelines.solve_features", "_write_features", {f"{index:06d}.png.npz": str(path) for index, path in markers.items()}))
        command = solve + ["--scheduler", cluster.scheduler_address, "--out", "out"]
        _killed_run(command, tmp_path, markers, worker_victim, client_victim)
        drain(dask)  # the killed client's tasks still running finish (or are forgotten)

        cache = out / FEATURE_CACHE / "left"
        assert [re.sub(r"camcal-tmp\.\w{8}", "camcal-tmp.*", name) for name in temporaries(tmp_path)] == [
            f".out.{TEMPORARY_TAG}.*"] + [f"out/{FEATURE_CACHE}/left/.{index:06d}.png.npz.{TEMPORARY_TAG}.*.npz"
                                          for index in sorted(markers)]  # the staging folder, the cut writes
        complete = sorted(p.name for p in cache.glob("*.npz") if not p.name.startswith("."))
        assert 0 < len(complete) < N_FRAMES and f"{client_victim:06d}.png.npz" not in complete
        capsys.readouterr()
        assert main(command) == 0  # the rerun, on the same cluster
        drain(dask)
    err = capsys.readouterr().err
    assert (f"extracting features from {N_FRAMES} images on Dask ({len(complete)} taken from an interrupted run's "
            "cache)") in err
    assert any(".sigma." in key for key in _same_as_uninterrupted(out, tmp_path / "uninterrupted"))


@pytest.mark.slow
def test_worker_killed_mid_matching_then_client_killed_then_rerun(tmp_path, monkeypatch, capsys):
    """Exhaustive matching of 21 frames: 210 pairs in 3 blocks. A worker is killed writing block 0's matches (Dask
    matches it again), the client once block 2's write stalls (block 1 done); the rerun takes every image's
    features and the complete blocks, matches the others, and gives the uninterrupted in-process run's rig."""
    from distributed import Client, LocalCluster

    n_frames = 21
    n_blocks = -(-n_frames * (n_frames - 1) // 2 // BLOCK_PAIRS)
    assert n_blocks == 3
    _render(tmp_path / "in", n_frames)
    solve = ["solve", "in/left", "--features", "512", "--no-refine"]
    monkeypatch.chdir(tmp_path)
    assert main(solve + ["--out", "uninterrupted"]) == 0  # in this process, no Dask

    worker_victim, client_victim = 0, n_blocks - 1
    markers = {index: tmp_path / f"stalled.{index}" for index in (worker_victim, client_victim)}
    out = tmp_path / "out"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        dask.register_plugin(StallOnce("camcal.pipelines.solve_matching", "_write_rows",
                                       {f"matches-exhaustive-{index:05d}.npz": str(path)
                                        for index, path in markers.items()}))
        command = solve + ["--scheduler", cluster.scheduler_address, "--out", "out"]
        _killed_run(command, tmp_path, markers, worker_victim, client_victim)
        drain(dask)

        cut = [f"out/{FEATURE_CACHE}/.matches-exhaustive-{index:05d}.npz.{TEMPORARY_TAG}.*.npz" for index in markers]
        assert [re.sub(r"camcal-tmp\.\w{8}", "camcal-tmp.*", name) for name in temporaries(tmp_path)] == [
            f".out.{TEMPORARY_TAG}.*"] + sorted(cut)  # the staging folder, the cut writes
        complete = sorted(p.name for p in (out / FEATURE_CACHE).glob("matches-*.npz"))
        assert 0 < len(complete) < n_blocks and f"matches-exhaustive-{client_victim:05d}.npz" not in complete
        capsys.readouterr()
        assert main(command) == 0  # the rerun, on the same cluster
        drain(dask)
    err = capsys.readouterr().err
    assert (f"extracting features from {n_frames} images on Dask ({n_frames} taken from an interrupted run's "
            "cache)") in err
    assert (f"matching {n_frames * (n_frames - 1) // 2} image pairs in {n_blocks} blocks on Dask ({len(complete)} "
            "taken from an interrupted run's cache)") in err
    _same_as_uninterrupted(out, tmp_path / "uninterrupted")
