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

import cloudpickle
import pytest
from distributed.diagnostics.plugin import WorkerPlugin

from camcal.base.atomic import TEMPORARY_TAG
from camcal.cli import main
from camcal.pipelines.solve_features import FEATURE_CACHE
from camcal.synthetic import render_stereo_sequence

ROOT = Path(__file__).resolve().parents[2]
N_FRAMES = 6

cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the plugin below, for the worker processes


class _StallOnce(WorkerPlugin):
    """Worker plugin: the first write of each chosen feature file stops halfway and waits to be killed."""

    name = "camcal-test-solve-stall-once"

    def __init__(self, markers: dict[str, str]) -> None:
        self.markers = markers  # feature file name -> marker file (created by the one write that stalls)

    def setup(self, worker) -> None:
        import camcal.pipelines.solve_features as features

        original = getattr(features, "_unstalled_write_features", features._write_features)
        features._unstalled_write_features = original
        markers = self.markers

        def stalling_write(path, keypoints, descriptors, key):
            original(path, keypoints, descriptors, key)
            output = Path(path).name.split(f".{TEMPORARY_TAG}.")[0][1:]
            if output not in markers:
                return
            try:
                handle = os.open(markers[output], os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return  # stalled once already: this is the retry
            os.truncate(path, os.path.getsize(path) // 2)
            os.write(handle, str(os.getpid()).encode())
            os.close(handle)
            time.sleep(600)

        features._write_features = stalling_write


def _wait_for_pid(marker: Path, process: subprocess.Popen) -> int:
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        text = marker.read_text() if marker.exists() else ""
        if text:
            return int(text)
        assert process.poll() is None, "the solve ended before the write stalled"
        time.sleep(0.05)
    raise AssertionError(f"no write stalled on {marker.name}")


def _running_keys(dask_worker):
    return [str(task.key) for task in dask_worker.state.all_running_tasks]


def _drain(dask) -> None:
    """Wait until the scheduler holds no task and no worker runs one (a killed client's tasks run to their end)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if not dask.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) and not any(
                dask.run(_running_keys, on_error="ignore").values()):
            return
        time.sleep(0.1)


def _numbers(value, path=""):
    """Every leaf of a rig file's JSON by its path, the creation time left out (it is the clock's)."""
    if isinstance(value, dict):
        for key, item in value.items():
            if key != "created":
                yield from _numbers(item, f"{path}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _numbers(item, f"{path}[{index}]")
    else:
        yield path, value


def _temporaries(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if TEMPORARY_TAG in p.name)


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
        dask.register_plugin(_StallOnce({f"{index:06d}.png.npz": str(path) for index, path in markers.items()}))
        command = solve + ["--scheduler", cluster.scheduler_address, "--out", "out"]
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        process = subprocess.Popen([sys.executable, "-m", "camcal", *command], cwd=tmp_path, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            os.kill(_wait_for_pid(markers[worker_victim], process), signal.SIGKILL)  # a worker, mid-write
            stalled = _wait_for_pid(markers[client_victim], process)  # another frame's write, later
        finally:
            os.killpg(process.pid, signal.SIGKILL)  # the client, mid-run
            process.wait(timeout=30)
        os.kill(stalled, signal.SIGKILL)  # and the worker still writing for it
        _drain(dask)  # the killed client's tasks still running finish (or are forgotten)

        cache = out / FEATURE_CACHE / "left"
        assert [re.sub(r"camcal-tmp\.\w{8}", "camcal-tmp.*", name) for name in _temporaries(tmp_path)] == [
            f".out.{TEMPORARY_TAG}.*"] + [f"out/{FEATURE_CACHE}/left/.{index:06d}.png.npz.{TEMPORARY_TAG}.*.npz"
                                          for index in sorted(markers)]  # the staging folder, the cut writes
        complete = sorted(p.name for p in cache.glob("*.npz") if not p.name.startswith("."))
        assert 0 < len(complete) < N_FRAMES and f"{client_victim:06d}.png.npz" not in complete
        capsys.readouterr()
        assert main(command) == 0  # the rerun, on the same cluster
        _drain(dask)
    err = capsys.readouterr().err
    assert (f"extracting features from {N_FRAMES} images on Dask ({len(complete)} taken from an interrupted run's "
            "cache)") in err

    assert _temporaries(tmp_path) == [] and not (out / FEATURE_CACHE).exists()
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "uninterrupted").as_posix()
                           for p in (tmp_path / "uninterrupted").rglob("*") if p.is_file())
    # the solved rig equals the uninterrupted in-process run's, bit for bit: the same features in the same
    # database order, then the same seeded, single-threaded mapping and refinement
    ours = dict(_numbers(json.loads((out / "solve.rig.json").read_text())))
    theirs = dict(_numbers(json.loads((tmp_path / "uninterrupted" / "solve.rig.json").read_text())))
    assert ours == theirs and any(".sigma." in key for key in ours)
    assert (out / "points.ply").read_bytes() == (tmp_path / "uninterrupted" / "points.ply").read_bytes()
