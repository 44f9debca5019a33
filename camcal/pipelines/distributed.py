"""Board detection over N cameras x M video frames on Dask: frame ranges decoded in the workers, corners sent back.

Each video is cut into ranges of :data:`CHUNK_FRAMES` frames; one Dask task
per range (:func:`detect_frame_range`) opens the video from its path, seeks
to the range's first frame (:func:`camcal.io.video.iter_frames`), decodes
and detects frame after frame, and returns only the corners: a worker holds
one decoded frame at a time and the client only corners, so memory does not
grow with the number of frames. The results are the in-process path's
(:func:`camcal.pipelines.board.detect_in_video`) frame for frame: the same
decoder, frame numbers and detector, and the same per-video cache.

Where it runs: an embedded ``distributed.LocalCluster`` of worker processes
(one thread each) by default, or the user's cluster by scheduler address,
whose workers must see the video paths and have camcal installed. The rule
for ``calibrate board``: Dask when a scheduler is given, or when the videos
hold at least :data:`DASK_MIN_FRAMES` frames to detect; below that the
local cluster's start-up (about 5-7 s for two workers here) outweighs what
it saves, and detection runs in-process in threads. On one machine Dask is
not cheaper (``bench/bench_volume_scale.py`` on 2 cores shared with other
jobs, 1280x720: 1.62x the frames per second of the threads at 16 cameras x
60 frames, 0.99x at 4 x 120, but 1.4-1.5x the CPU time per frame and 3x the
memory, its scheduler and worker processes); what it adds is more machines
(``--scheduler``) and processes where the detector holds the GIL.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Collection, Hashable, Iterator, Mapping
from typing import Any

import cv2

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.board import Board, Detection, DetectionReport, detect_board, video_frame_label
from camcal.io.video import iter_frames, video_info
from camcal.pipelines.board import read_video_cache, video_cache_file, video_report, write_video_cache

__all__ = ["CHUNK_FRAMES", "DASK_MIN_FRAMES", "cancel_and_wait", "dask_client", "detect_frame_range",
           "detect_in_videos", "run_tasks", "use_dask"]

#: Frames of one video per Dask task: enough tasks to balance the workers and move the progress line, while the
#: seek at a range's start (decoding from the key frame before it) stays small beside decoding the range.
CHUNK_FRAMES = 200

#: Frames to detect (all videos, after ``--every``) from which ``calibrate board`` starts a local Dask cluster.
DASK_MIN_FRAMES = 2000


def use_dask(n_frames: int, scheduler: str | None) -> bool:
    """Whether detection of ``n_frames`` video frames runs on Dask: a scheduler given, or :data:`DASK_MIN_FRAMES`."""
    return scheduler is not None or n_frames >= DASK_MIN_FRAMES


@contextlib.contextmanager
def dask_client(workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """A ``distributed.Client``: on the scheduler at ``scheduler``, else on a new ``LocalCluster`` of ``workers``.

    Raises
    ------
    CamcalError
        The scheduler cannot be reached, or ``workers < 1``.
    """
    require("distributed")
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as error:
            raise CamcalError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from None
        with client:
            yield client
        return
    if workers is not None and workers < 1:
        raise CamcalError(f"--workers must be at least 1, got {workers}")
    # dashboard_address=":0": the scheduler's HTTP server (always started) on a free port, not 8787
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.CRITICAL) as cluster, Client(cluster) as client:
        yield client


def _running_keys(dask_worker: Any) -> list[str]:
    """On a worker: the keys of the tasks occupying its threads, cancelled ones included."""
    return [str(task.key) for task in dask_worker.state.all_running_tasks]


def cancel_and_wait(client: Any, futures: Collection[Any], timeout: float = 600.0) -> None:
    """Cancel ``futures`` and wait, at most ``timeout`` seconds, until none of them still runs on a worker.

    Dask cannot stop a task that has started: cancelled, it runs to its end on its worker, side effects (files
    written) included. A job that fails and removes what its tasks wrote waits here first.
    """
    keys = {str(future.key) for future in futures}
    client.cancel(list(futures))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        running = client.run(_running_keys, on_error="ignore")
        if not keys.intersection(key for worker_keys in running.values() for key in worker_keys):
            return
        time.sleep(0.05)


def run_tasks(client: Any, tasks: Mapping[Hashable, tuple[Callable[..., Any], tuple]],
              failed: Callable[[Hashable, str], str]) -> dict[Hashable, Any]:
    """Run one Dask task per entry of ``tasks`` (label -> function and arguments) and wait for them all.

    The first task that fails (its own error, or its workers lost: ``distributed.KilledWorker``) cancels the
    others, waits until none of them still runs (:func:`cancel_and_wait`: they write no file after the caller
    has cleaned up) and raises ``CamcalError(failed(label, what))``, ``what`` being a :class:`CamcalError`'s
    text or the error's type and text.

    Returns
    -------
    dict
        Label -> the task's result.
    """
    from distributed import as_completed

    futures = {client.submit(function, *arguments, pure=False): label
               for label, (function, arguments) in tasks.items()}
    results = {}
    for future in as_completed(futures):
        label = futures[future]
        try:
            results[label] = future.result()
        except Exception as error:  # a task's error, or its workers lost (distributed.KilledWorker)
            cancel_and_wait(client, futures)
            what = str(error) if isinstance(error, CamcalError) else f"failed on Dask: {type(error).__name__}: {error}"
            raise CamcalError(failed(label, what)) from None
        future.release()
    return results


def detect_frame_range(board: Board, path: str, start: int, stop: int | None, every: int,
                       skip: frozenset[int] = frozenset(),
                       label: str | None = None) -> tuple[list[tuple[int, Detection | None]], int]:
    """One task: detect ``board`` in frames ``start <= k < stop`` (``k % every == 0``, not in ``skip``) of a video.

    ``label`` names the detections (``LABEL#K``; default ``path``): the path as the user gave it, where ``path``
    is the absolute one a farm's worker opens (it does not share the client's working directory).

    Returns
    -------
    results : list of (int, Detection or None)
        Frame number and its detection (named ``VIDEO#K``), None where the board is not found.
    seen : int
        One past the last frame ``k % every == 0`` decoded (0 when the range lies past the video's end), as
        :func:`camcal.pipelines.board.detect_in_video` counts the video's frames.
    """
    seen = 0

    def wanted(k: int) -> bool:
        nonlocal seen
        seen = k + 1
        return k not in skip

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one thread per worker process: the processes are the parallelism
    try:
        results = [(k, detect_board(board, image, video_frame_label(label or path, k)))
                   for k, image in iter_frames(path, every=every, wanted=wanted, start=start, stop=stop)]
    finally:
        cv2.setNumThreads(threads)
    return results, seen


def detect_in_videos(
    board: Board,
    videos: Mapping[str, str | os.PathLike],
    every: int = 1,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    cache: str | os.PathLike | None = None,
    chunk_frames: int = CHUNK_FRAMES,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, DetectionReport]:
    """Detect ``board`` in every ``every``-th frame of every video, on Dask, one task per range of frames.

    Parameters
    ----------
    board : Board
    videos : mapping of str to path
        Camera name -> its video.
    every : int
        Frames 0, every, 2 every... of each video are detected.
    workers : int, optional
        Worker processes of the embedded ``LocalCluster`` (default: one per core).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) instead.
    client : distributed.Client, optional
        An existing client (no cluster is created).
    cache : path, optional
        The corner cache of :func:`camcal.pipelines.board.detect_in_video`
        (one file per video): frames in it are not detected again, and the
        results are written back to it.
    chunk_frames : int
        Frames per task.
    progress : callable, optional
        ``progress(done, total)`` in frames, over all videos, as ranges finish.

    Returns
    -------
    dict of str to DetectionReport
        Per camera, the same as :func:`camcal.pipelines.board.detect_in_video`.

    Raises
    ------
    CamcalError
        ``every`` or ``chunk_frames`` below 1, a video that cannot be
        decoded, an unreachable scheduler; a task's error (one line naming
        the video) stops the run.
    """
    if int(every) < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    if int(chunk_frames) < 1:
        raise CamcalError(f"chunk_frames must be 1 or more, got {chunk_frames}")
    chunk = -(-int(chunk_frames) // every) * every  # whole strides, so ranges start on detected frames
    state, tasks, total = {}, [], 0
    for name, path in videos.items():
        path = str(path)
        count = video_info(path).frame_count
        cache_file = video_cache_file(board, path, cache)
        done, n_frames = read_video_cache(cache_file)
        state[name] = (path, cache_file, done, n_frames)
        end = n_frames if n_frames is not None else count
        starts = list(range(0, max(end, 1), chunk))
        for a in starts:
            b = a + chunk if (a != starts[-1] or n_frames is not None) else None  # the last range runs to the end
            todo = [k for k in range(a, min(a + chunk, max(end, 1)), every) if k not in done]
            if n_frames is not None and not todo:
                continue
            skip = frozenset(k for k in done if a <= k and (b is None or k < b))
            tasks.append((name, path, a, b, skip))
            total += len(todo)
    if not tasks:
        if progress is not None:
            progress(total, total)
        return {name: video_report(path, done, n_frames, every) for name, (path, _, done, n_frames) in state.items()}
    seen = {name: state[name][3] or 0 for name in state}
    owned = contextlib.nullcontext(client) if client is not None else dask_client(workers, scheduler)
    finished = 0
    with owned as dask:
        from distributed import as_completed

        [shared_board] = dask.scatter([board], broadcast=True, hash=False)
        futures = {dask.submit(detect_frame_range, shared_board, os.path.abspath(path), a, b, every, skip, path,
                               pure=False): name
                   for name, path, a, b, skip in tasks}
        if progress is not None:
            progress(0, total)
        for future in as_completed(futures):
            name = futures[future]
            results, end = future.result()
            state[name][2].update(results)
            seen[name] = max(seen[name], end)
            finished += len(results)
            future.release()
            if progress is not None:
                progress(min(finished, total), max(total, finished))
    reports = {}
    for name, (path, cache_file, done, n_frames) in state.items():
        n_frames = seen[name] if n_frames is None else n_frames
        write_video_cache(cache_file, n_frames, done)
        reports[name] = video_report(path, done, n_frames, every)
    return reports
