"""A solve whose features are extracted on Dask survives faults: a worker SIGKILLed mid-write, then the client.

As in ``test_batch_faults.py``: the cluster is separate from the client (a
``LocalCluster`` of 2 worker processes in this test process, the client
``python -m camcal solve --scheduler ADDR`` in its own process group), and a
worker plugin makes each kill land midway through the write of a frame's
features, deterministically: the first write of a chosen frame stops after
truncating its temporary file to half, records its process id in a marker
file and waits there. The fast siblings are in ``test_solve_features.py``.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from camcal.base.atomic import TEMPORARY_TAG
from camcal.cli import main
from camcal.pipelines.solve_features import FEATURE_CACHE
from camcal.synthetic import render_stereo_sequence
from dask_faults import StallOnce, drain, temporaries, wait_for_pid
from test_solve import _numbers

ROOT = Path(__file__).resolve().parents[2]
N_FRAMES = 6


@pytest.mark.slow
def test_worker_killed_mid_extraction_then_client_killed_then_rerun(tmp_path, monkeypatch, capsys):
    from distributed import Client, LocalCluster

    width = 256
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(tmp_path / "in", n_frames=N_FRAMES, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
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
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        process = subprocess.Popen([sys.executable, "-m", "camcal", *command], cwd=tmp_path, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            os.kill(wait_for_pid(markers[worker_victim], process), signal.SIGKILL)  # a worker, mid-write
            stalled = wait_for_pid(markers[client_victim], process)  # another frame's write, later
        finally:
            os.killpg(process.pid, signal.SIGKILL)  # the client, mid-run
            process.wait(timeout=30)
        os.kill(stalled, signal.SIGKILL)  # and the worker still writing for it
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

    assert temporaries(tmp_path) == [] and not (out / FEATURE_CACHE).exists()
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "uninterrupted").as_posix()
                           for p in (tmp_path / "uninterrupted").rglob("*") if p.is_file())
    # the solved rig equals the uninterrupted in-process run's, bit for bit: the same features in the same
    # database order, then the same seeded, single-threaded mapping and refinement
    ours = dict(_numbers(json.loads((out / "solve.rig.json").read_text())))
    theirs = dict(_numbers(json.loads((tmp_path / "uninterrupted" / "solve.rig.json").read_text())))
    assert ours == theirs and any(".sigma." in key for key in ours)
    assert (out / "points.ply").read_bytes() == (tmp_path / "uninterrupted" / "points.ply").read_bytes()
