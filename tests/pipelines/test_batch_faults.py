"""Batch survives faults: a worker SIGKILLed mid-write, then the client killed mid-run, then a rerun.

The cluster is separate from the client (a ``LocalCluster`` of 2 worker
processes in this test process, the client ``python -m camcal batch
--scheduler ADDR`` in its own process group), as on a farm. A worker
plugin makes the kills land midway through a write, deterministically: the
first write of a chosen frame stops after truncating its temporary file to
half, records its process id in a marker file and waits there, the way a
process killed mid-write leaves it.
"""

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from camcal.base.atomic import TEMPORARY_TAG
from camcal.cli import main
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig
from camcal.pipelines.batch import RECORD_DIR, make_job, process_frame, run_batch
from camcal.synthetic import example_camera
from dask_faults import StallOnce, drain, temporaries, wait_for_pid

SIZE = (64, 48)
FRAMES = tuple(range(1001, 1013))
ROOT = Path(__file__).resolve().parents[2]

def _rig(tmp: Path) -> Path:
    camera = example_camera("left", image_size=SIZE, fx=60.0, fy=60.0, principal_point=(31.7, 24.2),
                            distortion=Distortion("division", {"lambda": -4e-5}))
    return Rig((camera,)).save(tmp / "set.rig.json")


def _sequence(tmp: Path, frames=FRAMES) -> str:
    (tmp / "plates").mkdir(exist_ok=True)
    pattern = str(tmp / "plates" / "left.%04d.exr")
    for frame in frames:
        rng = np.random.default_rng(frame)
        rgb = rng.random((SIZE[1], SIZE[0], 3)).astype(np.float16)
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION},
                          {name: np.ascontiguousarray(rgb[..., i]) for i, name in enumerate("RGB")}) as exr:
            exr.write(pattern % frame)
    return pattern


@pytest.mark.slow
def test_worker_killed_mid_write_then_client_killed_then_rerun(tmp_path):
    from distributed import Client, LocalCluster

    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path)
    out_dir = tmp_path / "out"
    reference = make_job(rig, "left", pattern, str(tmp_path / "uninterrupted" / "left.%04d.exr"), "undistort")
    for frame in FRAMES:
        process_frame(frame, reference)
    worker_victim, client_victim = 1003, 1008
    markers = {frame: tmp_path / f"stalled.{frame}" for frame in (worker_victim, client_victim)}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        dask.register_plugin(StallOnce("camcal.io.frames", "_write_exr", {f"left.{frame}.exr": str(path) for frame, path in markers.items()}))
        command = ["batch", str(rig), "--camera", "left", "--images", pattern, "--frames", f"{FRAMES[0]}-{FRAMES[-1]}",
                   "--undistort", "--out", str(out_dir / "left.%04d.exr"), "--scheduler", cluster.scheduler_address,
                   "--quiet"]
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        process = subprocess.Popen([sys.executable, "-m", "camcal", *command], cwd=tmp_path, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            os.kill(wait_for_pid(markers[worker_victim], process), signal.SIGKILL)  # a worker, mid-write
            stalled = wait_for_pid(markers[client_victim], process)  # the other frame's write, later
        finally:
            os.killpg(process.pid, signal.SIGKILL)  # the client, mid-run
            process.wait(timeout=30)
        os.kill(stalled, signal.SIGKILL)  # and the worker still writing for it
        partial = temporaries(out_dir)
        assert [name.split(f".{TEMPORARY_TAG}.")[0] for name in partial] == [
            f".left.{frame}.exr" for frame in sorted(markers)]  # the killed writes' half files, as before the fix
        before = sorted(p.name for p in out_dir.glob("left.*.exr"))
        assert 0 < len(before) < len(FRAMES)

        drain(dask)  # the killed client's tasks still queued or running finish (or are forgotten)
        assert main(command + ["--resume"]) == 0
        drain(dask)

    written = sorted(p.relative_to(out_dir).as_posix() for p in out_dir.rglob("*") if p.is_file())
    assert written == sorted([f"left.{f}.exr" for f in FRAMES] + [f"{RECORD_DIR}/left.{f}.exr.json" for f in FRAMES])
    assert temporaries(tmp_path) == []
    for frame in FRAMES:  # every output complete and equal to the uninterrupted run's, byte for byte
        assert (out_dir / f"left.{frame}.exr").read_bytes() == reference.output_path(frame).read_bytes(), frame


def test_a_run_removes_camcal_temporaries_of_its_own_outputs_only(tmp_path):
    """The fast sibling: what killed writers left (outputs and records) goes; everything else stays."""
    rig = _rig(tmp_path)
    frames = FRAMES[:2]
    pattern = _sequence(tmp_path, frames)
    out_dir = tmp_path / "out"
    (out_dir / RECORD_DIR).mkdir(parents=True)
    stale = [out_dir / f".left.1001.exr.{TEMPORARY_TAG}.0jfiou1u.exr",
             out_dir / RECORD_DIR / f".left.1002.exr.json.{TEMPORARY_TAG}.a_b9z0x1.json"]
    kept = [out_dir / ".left.1001.exr.0jfiou1u.exr",  # not camcal's name
            out_dir / f".left.1003.exr.{TEMPORARY_TAG}.0jfiou1u.exr",  # not an output of this run
            out_dir / f".other.1001.exr.{TEMPORARY_TAG}.0jfiou1u.exr",
            out_dir / "notes.txt"]
    for path in stale + kept:
        path.write_bytes(b"partial")
    job = make_job(rig, "left", pattern.replace("%04d", "####"), str(out_dir / "left.####.exr"), "undistort")
    report = run_batch(job, frames, workers=1, progress=False)
    assert report.ok and [Path(result.output).name for result in report.written] == ["left.1001.exr", "left.1002.exr"]
    assert not any(path.exists() for path in stale) and all(path.read_bytes() == b"partial" for path in kept)
