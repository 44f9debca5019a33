"""Board detection at the scale of a capture volume: N cameras x M frames of 1280x720 video, Dask vs one process.

Writes N mp4 videos (the ChArUco board of issue 29, inverted and two-sided,
warped once per frame along a smooth pose track per camera: one
``cv2.warpPerspective`` of the printed board, light noise, MPEG-4 part 2),
then detects the board in every frame twice, each run in a fresh process
whose whole tree (the Dask workers too) is sampled for memory:

- one process: :func:`camcal.pipelines.board.detect_in_video` camera after
  camera, ``--workers`` threads (camcal's in-process path);
- Dask: :func:`camcal.pipelines.distributed.detect_in_videos` on a local
  cluster of ``--workers`` processes, start-up included.

Printed: frames per second, end-to-end time, CPU time per frame (user +
system of the whole process tree: what a shared machine's load does not
change), peak memory of the process tree (resident set, sampled every
0.1 s) and the ratio Dask / one process; the
corners of the two runs are compared (identical count of detections and
corners). Usage::

    nice -n 10 python bench/bench_volume_scale.py                      # 16 cameras x 2000 frames
    python bench/bench_volume_scale.py --cameras 4 --frames 200        # smaller

Measured at full scale (16 x 2000 = 32,000 frames, 590 MB of mp4, this 2-core
machine shared with other jobs, the bench's processes given priority): one
process 14.9 frames/s (2150 s), Dask 23.4 frames/s (1371 s): 1.57x; CPU 78 vs
81 ms/frame; peak memory 231 vs 510 MB (960 frames: ~150 vs ~430 MB); the
board in 32,000 / 32,000 frames, corners identical. The one process's two
threads used 1.2 cores (decoding and the corner fit's Python hold the GIL),
Dask's two processes 1.9.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided"
SIZE = (1280, 720)
PX_PER_M, MARGIN = 4000, 40


def write_videos(folder: Path, n_cameras: int, n_frames: int, seed: int = 0) -> list[Path]:
    """One mp4 per camera: the board along a smooth track of poses 0.7-1.3 m in front of the camera."""
    import cv2

    from camcal.geometry.board import parse_board

    board = parse_board(SPEC)
    texture = board.charuco_board().generateImage(
        (round(board.columns * board.square * PX_PER_M) + 2 * MARGIN,
         round(board.rows * board.square * PX_PER_M) + 2 * MARGIN), marginSize=MARGIN)
    texture = 255 - texture
    width, height = SIZE
    K = np.array([[1000.0, 0, (width - 1) / 2], [0, 1000.0, (height - 1) / 2], [0, 0, 1]])
    A = np.array([[1 / PX_PER_M, 0, (0.5 - MARGIN) / PX_PER_M], [0, 1 / PX_PER_M, (0.5 - MARGIN) / PX_PER_M],
                  [0, 0, 1]])
    middle = np.array([board.columns * board.square / 2, board.rows * board.square / 2, 0.0])
    rng = np.random.default_rng(seed)
    paths = []
    for camera in range(n_cameras):
        phase = rng.uniform(0, 2 * np.pi, 6)
        path = folder / f"cam_{camera}.mp4"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, SIZE, isColor=False)
        for f in range(n_frames):
            s = 2 * np.pi * f / 300
            rvec = np.array([0.5 * np.sin(s + phase[0]), 0.5 * np.sin(1.3 * s + phase[1]),
                             0.3 * np.sin(0.7 * s + phase[2])])
            R = cv2.Rodrigues(rvec)[0]
            centre = np.array([0.25 * np.sin(0.9 * s + phase[3]), 0.12 * np.sin(1.1 * s + phase[4]),
                               1.0 + 0.3 * np.sin(0.5 * s + phase[5])])
            t = centre - R @ middle
            H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ A
            image = cv2.warpPerspective(texture, H, SIZE, flags=cv2.INTER_AREA, borderValue=150)
            noise = rng.integers(-2, 3, image.shape, dtype=np.int16)
            writer.write(np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8))
        writer.release()
        paths.append(path)
    return paths


def run(mode: str, folder: Path, workers: int, out: Path) -> None:
    """One detection run (in this process): write its figures as JSON to ``out``."""
    from camcal.geometry.board import parse_board

    board = parse_board(SPEC)
    videos = {f"cam{k}": path for k, path in enumerate(sorted(folder.glob("cam_*.mp4"),
                                                             key=lambda p: int(p.stem.split("_")[1])))}
    start = time.perf_counter()
    if mode == "dask":
        from camcal.pipelines.distributed import detect_in_videos

        reports = detect_in_videos(board, videos, workers=workers)
    else:
        from camcal.pipelines.board import detect_in_video

        reports = {name: detect_in_video(board, path, workers=workers) for name, path in videos.items()}
    seconds = time.perf_counter() - start
    corners = {name: {d.image: np.asarray(d.corners_px).round(6).tolist() for d in report.detections}
               for name, report in reports.items()}
    out.write_text(json.dumps({"seconds": seconds, "frames": sum(r.n_images for r in reports.values()),
                               "found": sum(len(r.detections) for r in reports.values()), "corners": corners}))


def measure(mode: str, folder: Path, workers: int) -> dict:
    """Run ``mode`` in a fresh process; its figures and the peak resident memory of its process tree."""
    import psutil

    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as handle:
        out = Path(handle.name)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    child = subprocess.Popen([sys.executable, __file__, "--run", mode, "--folder", str(folder),
                              "--workers", str(workers), "--result", str(out)])
    peak, stop = [0], threading.Event()

    def sample() -> None:
        process = psutil.Process(child.pid)
        while not stop.is_set():
            try:
                tree = [process, *process.children(recursive=True)]
                peak[0] = max(peak[0], sum(p.memory_info().rss for p in tree if p.is_running()))
            except psutil.Error:
                pass
            time.sleep(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    code = child.wait()
    stop.set()
    sampler.join()
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)  # the child and every descendant it waited for
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if code != 0:
        raise SystemExit(f"the {mode} run failed (exit {code})")
    figures = json.loads(out.read_text())
    out.unlink()
    return {**figures, "wall": wall, "cpu": cpu, "peak_mb": peak[0] / 2**20}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=16)
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--folder", type=Path, help="videos here (written when missing)")
    parser.add_argument("--run", choices=("dask", "process"), help=argparse.SUPPRESS)
    parser.add_argument("--result", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.run:
        run(args.run, args.folder, args.workers, args.result)
        return
    with tempfile.TemporaryDirectory(prefix="camcal-volume-") as scratch:
        folder = args.folder or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        if len(list(folder.glob("cam_*.mp4"))) != args.cameras:
            start = time.perf_counter()
            write_videos(folder, args.cameras, args.frames)
            size = sum(p.stat().st_size for p in folder.glob("cam_*.mp4")) / 2**20
            print(f"wrote {args.cameras} videos x {args.frames} frames of {SIZE[0]}x{SIZE[1]} ({size:.0f} MB) "
                  f"in {time.perf_counter() - start:.0f} s")
        results = {mode: measure(mode, folder, args.workers) for mode in ("process", "dask")}
    total = results["process"]["frames"]
    for mode, label in (("process", f"one process, {args.workers} threads"),
                        ("dask", f"Dask, {args.workers} local worker processes")):
        r = results[mode]
        print(f"{label:34s} {r['frames'] / r['seconds']:7.2f} frames/s  detection {r['seconds']:7.1f} s  "
              f"end-to-end {r['wall']:7.1f} s  CPU {1e3 * r['cpu'] / r['frames']:5.0f} ms/frame  "
              f"peak memory {r['peak_mb']:6.0f} MB  (board in {r['found']} / "
              f"{r['frames']} frames)")
    same = results["process"]["corners"] == results["dask"]["corners"]
    print(f"ratio Dask / one process: {results['process']['seconds'] / results['dask']['seconds']:.2f}x frames/s, "
          f"{results['process']['wall'] / results['dask']['wall']:.2f}x end-to-end; corners identical: {same} "
          f"({total} frames, {args.cameras} cameras)")
    if not same:
        raise SystemExit("the two runs found different corners")


if __name__ == "__main__":
    main()
