"""Batch undistortion of a 2048x1080 float EXR sequence: 1 process against 2 local Dask workers,
and the batch's cost per frame against the single-frame ``camcal undistort`` path.

The frames (RGB FLOAT, ZIP-compressed, smooth content plus noise) are
generated in a temporary directory. Timings:

- ``1 process``: :func:`camcal.pipelines.batch.process_frame` in a loop in this
  process (no Dask): maps built once, then read, remap, write per frame;
- ``Dask N workers``: :func:`camcal.pipelines.batch.run_batch` on a new
  ``LocalCluster`` of N worker processes (start-up included);
- ``camcal undistort``: :func:`camcal.pipelines.undistort.undistort_images`
  called once per frame, as a script calling the single-frame verb per
  frame would (map rebuilt on every call), and the CLI itself for one frame
  (``python -m camcal undistort``, interpreter start-up included).

Prints ``name: ours X, peer Y, ratio Y/X``. ``--frames N`` runs a shorter
sequence (default 200).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR

from camcal.pipelines.batch import make_job, process_frame, run_batch
from camcal.model.distortion import Distortion
from camcal.pipelines.undistort import undistort_images
from camcal.model.rig import Rig
from camcal.synthetic import example_camera

SIZE = (2048, 1080)
FIRST = 1001


def _write_plate(path: Path, frame: int) -> None:
    rng = np.random.default_rng(frame)
    v, u = np.mgrid[0 : SIZE[1], 0 : SIZE[0]].astype(np.float32)
    rgb = [0.5 + 0.4 * np.sin(u / (40.0 + 7 * c) + frame) * np.cos(v / 55.0) for c in range(3)]
    planes = {name: (plane + 0.01 * rng.standard_normal(plane.shape)).astype(np.float32) for name, plane in zip("RGB", rgb)}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "owner": "bench"}, planes) as exr:
        exr.write(str(path))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200, help="sequence length (default 200)")
    parser.add_argument("--single-frame-samples", type=int, default=10,
                        help="frames timed through the single-frame path (default 10)")
    args = parser.parse_args()
    n = args.frames
    frames = list(range(FIRST, FIRST + n))
    camera = example_camera("plate", image_size=SIZE, fx=1800.0, fy=1800.0, principal_point=(1025.0, 538.0),
                            distortion=Distortion("division", {"lambda": -6e-8}))
    with tempfile.TemporaryDirectory(prefix="camcal-bench-batch-") as tmp:
        tmp = Path(tmp)
        rig = Rig((camera,)).save(tmp / "bench.rig.json")
        (tmp / "plates").mkdir()
        pattern = str(tmp / "plates" / "plate.%04d.exr")
        start = time.perf_counter()
        for frame in frames:
            _write_plate(Path(pattern % frame), frame)
        print(f"(generated {n} frames of {SIZE[0]}x{SIZE[1]} RGB float EXR in {time.perf_counter() - start:.1f} s)")

        def job(out: str):
            return make_job(rig, "plate", pattern, str(tmp / out / "plate.%04d.exr"), "undistort")

        # 1 process, no Dask
        serial_job = job("serial")
        start = time.perf_counter()
        for frame in frames:
            process_frame(frame, serial_job)
        serial = (time.perf_counter() - start) / n
        shutil.rmtree(tmp / "serial")

        per_frame = {}
        for workers in (1, 2):
            report = run_batch(job(f"dask{workers}"), frames, workers=workers, progress=False)
            if not report.ok:
                raise SystemExit(report.summary())
            per_frame[workers] = report.seconds / n
            shutil.rmtree(tmp / f"dask{workers}")

        # the single-frame path, once per frame
        samples = frames[: max(1, min(args.single_frame_samples, n))]
        start = time.perf_counter()
        for frame in samples:
            undistort_images(Rig.load(rig), "plate", [pattern % frame], tmp / "single")
        single = (time.perf_counter() - start) / len(samples)
        env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "camcal", "undistort", str(rig), "--camera", "plate",
                        pattern % frames[0], "--out", str(tmp / "cli")], check=True, env=env, stdout=subprocess.DEVNULL)
        cli = time.perf_counter() - start

    print(f"batch {n} frames, s/frame, 2 Dask workers vs 1 process: ours {per_frame[2]:.4f}, peer {serial:.4f}, "
          f"ratio {serial / per_frame[2]:.2f}")
    print(f"  frames/s: 1 process {1 / serial:.2f}, Dask 1 worker {1 / per_frame[1]:.2f}, "
          f"Dask 2 workers {1 / per_frame[2]:.2f} (cluster start-up included)")
    print(f"batch s/frame (2 Dask workers) vs single-frame undistort_images per frame: ours {per_frame[2]:.4f}, "
          f"peer {single:.4f}, ratio {single / per_frame[2]:.2f}")
    print(f"batch s/frame (2 Dask workers) vs `python -m camcal undistort` for one frame: ours {per_frame[2]:.4f}, "
          f"peer {cli:.4f}, ratio {cli / per_frame[2]:.2f}")


if __name__ == "__main__":
    main()
