"""Calibration boards found in image and video files: worker threads and a cache keyed by content.

Detection over many images (:func:`detect_in_images`) runs in worker
threads and keeps each image's result in a cache keyed by the file's
content (SHA-256) and the detector settings
(:data:`camcal.geometry.board.DETECTOR_SETTINGS`), so that calibrating again
with other options does not detect again. Detection over a video's frames
(:func:`detect_in_video`) streams them (one decoded frame per worker in
memory) and caches every frame's result in one file per video, keyed by
the video's content, the board and the detector settings. Views of
several cameras are matched by frame number, or by time from a timestamps
file (:func:`synchronise_detections`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from camcal.base.atomic import atomic_path
from camcal.base.errors import CamcalError
from camcal.geometry.board import (DETECTOR_SETTINGS, Board, Detection, DetectionReport, detect_board,
                                   frame_number, opencv_threads_off, synchronised_label, video_frame_label)
from camcal.io.frames import imread
from camcal.io.headers import check_image_header
from camcal.io.timestamps import Synchronisation, Timestamps, synchronise
from camcal.io.video import iter_frames, video_info

__all__ = ["default_cache_dir", "detect_in_images", "detect_in_video", "read_video_cache", "synchronise_detections",
           "video_cache_file", "video_report", "write_video_cache"]


def default_cache_dir() -> Path:
    """Where detections are cached by default: ``$XDG_CACHE_HOME/camcal/corners`` (``~/.cache/camcal/corners``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "camcal" / "corners"


def _cache_key(board: Board, content: bytes) -> str:
    """SHA-256 of the image bytes, the board and the detector settings."""
    digest = hashlib.sha256(content)
    digest.update(f"|{board.spec()}|{DETECTOR_SETTINGS}".encode())
    return digest.hexdigest()


def _detection_from_json(d: dict | None) -> Detection | None:
    if d is None:
        return None
    return Detection(d["image"], tuple(d["image_size"]), np.asarray(d["ids"], dtype=np.int64),
                     np.asarray(d["corners_px"], dtype=np.float64).reshape(-1, 2), d["detector"])


def _detection_to_json(detection: Detection | None) -> dict | None:
    if detection is None:
        return None
    return {"image": detection.image, "image_size": list(detection.image_size), "ids": detection.ids.tolist(),
            "corners_px": detection.corners_px.tolist(), "detector": detection.detector}


def _read_cached(path: Path) -> tuple[tuple[int, int] | None, Detection | None] | None:
    """A cached result ``(image size or None if unreadable, detection or None)``; None when absent or unreadable."""
    try:
        data = json.loads(path.read_text())
        size = tuple(data["size"]) if data["size"] is not None else None
        return size, _detection_from_json(data["detection"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write_cached(path: Path, size: tuple[int, int] | None, detection: Detection | None) -> None:
    """Write one result atomically (temp file + rename); a cache that cannot be written is skipped."""
    payload = {"size": list(size) if size else None, "detection": _detection_to_json(detection)}
    _write_json(path, payload)


def _write_json(path: Path, payload: dict) -> None:
    """Write a cache file atomically (temp file + rename); a cache that cannot be written is skipped."""
    try:
        with atomic_path(path) as temporary:
            temporary.write_text(json.dumps(payload))
    except OSError:
        pass


def _detect_file(board: Board, path: str, content: bytes) -> tuple[tuple[int, int] | None, Detection | None]:
    """Decode and detect one image: ``(size or None if unreadable, detection)``."""
    if content and Path(path).suffix.lower() == ".exr":  # the OpenCV 5 wheels decode no EXR
        try:
            image = imread(path, cv2.IMREAD_GRAYSCALE)
        except CamcalError:
            image = None
    else:
        if content:
            check_image_header(Path(path), content)  # a forged size stops here, not in OpenCV's allocator
        image = cv2.imdecode(np.frombuffer(content, np.uint8), cv2.IMREAD_GRAYSCALE) if content else None
    if image is None:
        return None, None
    return (image.shape[1], image.shape[0]), detect_board(board, image, Path(path).name)


def detect_in_images(
    board: Board,
    paths: Iterable[str | os.PathLike],
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
    cache: str | os.PathLike | None = None,
) -> DetectionReport:
    """Detect ``board`` in every image; the ones where it is missing are listed, not fatal.

    Parameters
    ----------
    board : Board
    paths : iterable of path
        Image files (anything ``cv2.imdecode`` reads, and EXR).
    progress : callable, optional
        Called as ``progress(done, total)`` after each image (and once at
        the start for the images found in the cache), e.g. the
        :meth:`camcal.base.progress.Progress.report` of a progress bar.
    workers : int
        Images detected at once (default 1). Worker threads: OpenCV releases
        the GIL while it decodes and detects, so threads use every core
        without the start-up cost of processes (a spawned process imports
        numpy and OpenCV again, about 0.5 s each; a forked child of a
        process whose OpenCV thread pool runs can hang). OpenCV's own
        threading is set to 1 while they run.
    cache : path, optional
        Directory of cached detections (one JSON file per image, keyed by
        the SHA-256 of the file's bytes, the board and the detector
        settings); None detects every image.

    Returns
    -------
    DetectionReport
        Unreadable images are skipped like images without the board.

    Raises
    ------
    CamcalError
        No paths, images of different sizes, or an image whose header
        declares more pixels than :data:`camcal.base.limits.IMAGE_PIXELS`
        (checked before decoding: :func:`camcal.io.headers.check_image_header`).
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise CamcalError("no images given")
    results: list = [None] * len(paths)
    pending = []
    cache_files: list[Path | None] = [None] * len(paths)
    for index, path in enumerate(paths):
        try:
            content = path.read_bytes()
        except OSError:
            content = b""
        if cache is not None and content:
            cache_files[index] = Path(cache) / f"{_cache_key(board, content)}.json"
            cached = _read_cached(cache_files[index])
            if cached is not None:
                size, detection = cached
                # the cached detection was named after the file it was first found in
                results[index] = (size, None if detection is None else Detection(
                    path.name, detection.image_size, detection.ids, detection.corners_px, detection.detector))
                continue
        pending.append((index, content))
    count = sum(result is not None for result in results)

    def report_progress() -> None:
        if progress is not None:
            progress(count, len(paths))

    n_workers = min(max(1, workers), len(pending))
    if n_workers > 1:
        with opencv_threads_off(), ThreadPoolExecutor(max_workers=n_workers) as pool:
            futures = [(index, pool.submit(_detect_file, board, str(paths[index]), content))
                       for index, content in pending]
            for index, future in futures:
                results[index] = future.result()
                count += 1
                report_progress()
    else:
        for index, content in pending:
            results[index] = _detect_file(board, str(paths[index]), content)
            count += 1
            report_progress()
    if not pending:
        report_progress()
    for index, _ in pending:
        if cache_files[index] is not None:
            _write_cached(cache_files[index], *results[index])
    detections, skipped = [], []
    sizes = set()
    for path, (size, detection) in zip(paths, results):
        if size is None:
            skipped.append(path.name)
            continue
        sizes.add(size)
        if len(sizes) > 1:
            raise CamcalError(f"images of one camera must share a size; {path.name} is {size[0]}x{size[1]}")
        if detection is None:
            skipped.append(path.name)
        else:
            detections.append(detection)
    return DetectionReport(tuple(detections), tuple(skipped))


def _video_cache_key(board: Board, path: Path) -> str:
    """SHA-256 of the video's bytes (read in blocks), the board and the detector settings."""
    with open(path, "rb") as stream:
        digest = hashlib.file_digest(stream, "sha256")
    # "video-v2": the frame count of caches written before it was one too many (the frame after the last)
    digest.update(f"|video-v2|{board.spec()}|{DETECTOR_SETTINGS}".encode())
    return digest.hexdigest()


def video_cache_file(board: Board, path: str | os.PathLike, cache: str | os.PathLike | None) -> Path | None:
    """The file in ``cache`` holding the detections of ``board`` in the video at ``path`` (None without a cache)."""
    return Path(cache) / f"video-{_video_cache_key(board, Path(path))}.json" if cache is not None else None


def read_video_cache(path: Path | None) -> tuple[dict[int, Detection | None], int | None]:
    """The cached frames ``{frame: detection or None}`` and the video's frame count (None if never decoded whole)."""
    if path is None:
        return {}, None
    try:
        data = json.loads(path.read_text())
        frames = {int(k): _detection_from_json(d) for k, d in data["frames"].items()}
        return frames, (int(data["n_frames"]) if data["n_frames"] is not None else None)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}, None


def detect_in_video(
    board: Board,
    path: str | os.PathLike,
    every: int = 1,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
    cache: str | os.PathLike | None = None,
) -> DetectionReport:
    """Detect ``board`` in every ``every``-th frame of a video, streamed (:func:`camcal.io.video.iter_frames`).

    Parameters
    ----------
    board : Board
    path : path
        A video file (:data:`camcal.io.video.VIDEO_SUFFIXES`).
    every : int
        Frames 0, every, 2 every... are detected.
    progress : callable, optional
        ``progress(done, total)`` after each frame; ``total`` is the
        container's frame count (an estimate) divided by ``every``.
    workers : int
        Frames detected at once (threads, as :func:`detect_in_images`); at
        most ``2 x workers`` decoded frames are held at a time.
    cache : path, optional
        Directory of cached detections: one JSON file per video (keyed by
        the SHA-256 of its bytes, the board and the detector settings)
        holding every frame detected so far; a run whose frames are all in
        it decodes nothing. None detects every frame.

    Returns
    -------
    DetectionReport
        Detections named ``VIDEO#K`` (:func:`camcal.geometry.board.video_frame_label`,
        frame number ``K``); frames without the board are listed as skipped;
        ``n_frames`` is the number of frames the video decoded to.

    Raises
    ------
    CamcalError
        The video cannot be decoded (one line naming it), or ``every < 1``.
    """
    path = Path(path)
    if int(every) < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    info = video_info(path)
    cache_file = video_cache_file(board, path, cache)
    done, n_frames = read_video_cache(cache_file)
    total = max(1, -(-(n_frames or info.frame_count) // every))
    count, reported = 0, [-1]

    def report_progress() -> None:
        if progress is not None and min(count, total) != reported[0]:
            reported[0] = min(count, total)
            progress(reported[0], total)

    complete = n_frames is not None and all(k in done for k in range(0, n_frames, every))
    if not complete:
        seen = [0]

        def wanted(k: int) -> bool:
            seen[0] = k + 1
            return k % every == 0 and k not in done

        count = sum(1 for k in done if k % every == 0)
        report_progress()
        n_workers = max(1, workers)
        with opencv_threads_off(n_workers > 1), ThreadPoolExecutor(max_workers=n_workers) as pool:
            in_flight: list = []

            def collect(n_left: int) -> None:
                nonlocal count
                while len(in_flight) > n_left:
                    k, future = in_flight.pop(0)
                    done[k] = future.result()
                    count += 1
                    report_progress()

            for k, image in iter_frames(path, every=1, wanted=wanted):
                in_flight.append((k, pool.submit(detect_board, board, image, video_frame_label(path, k))))
                collect(2 * n_workers)
            collect(0)
        n_frames = seen[0]
        write_video_cache(cache_file, n_frames, done)
    count = total
    report_progress()
    return video_report(path, done, n_frames, every)


def write_video_cache(path: Path | None, n_frames: int, done: dict[int, Detection | None]) -> None:
    """Write a video's detections ``{frame: detection or None}`` and frame count (atomic; skipped when None)."""
    if path is not None:
        _write_json(path, {"n_frames": n_frames,
                           "frames": {str(k): _detection_to_json(d) for k, d in sorted(done.items())}})


def video_report(path: str | os.PathLike, done: dict[int, Detection | None], n_frames: int,
                 every: int) -> DetectionReport:
    """The report of frames ``0, every, 2 every... < n_frames`` from ``done``, detections named ``VIDEO#K``."""
    detections, skipped = [], []
    for k in range(0, n_frames, every):
        detection = done.get(k)
        label = video_frame_label(path, k)
        if detection is None:
            skipped.append(label)
        else:  # the cached detection was named after the file it was first found in
            detections.append(Detection(label, detection.image_size, detection.ids, detection.corners_px,
                                        detection.detector))
    return DetectionReport(tuple(detections), tuple(skipped), n_frames)


def synchronise_detections(reports: Mapping[str, DetectionReport], timestamps: Timestamps,
                           tolerance_s: float | None = None, sources: Mapping[str, str] | None = None,
                           every: int = 1) -> tuple[dict[str, list[Detection]], Synchronisation, dict[str, int]]:
    """The views of every camera numbered by time (:func:`camcal.io.timestamps.synchronise`) instead of by index.

    Parameters
    ----------
    reports : mapping of str to DetectionReport
        Camera -> its detections (:func:`detect_in_video` or
        :func:`detect_in_images`), the reference camera first.
    timestamps : Timestamps
    tolerance_s : float, optional
        Largest time difference of a match (default: half the reference's frame period).
    sources : mapping of str to str, optional
        Camera -> its video's name, for the messages.
    every : int
        Keep the views matched to the reference's frames 0, every, 2 every...
        (detect the reference's every ``every``-th frame and the other
        cameras' every frame: their frames matching those are not the same
        numbers).

    Returns
    -------
    detections, synchronisation, dropped
        Camera -> its matched views, renamed ``LABEL@K`` with ``K`` the
        reference frame they are matched to
        (:func:`camcal.geometry.board.synchronised_label`); per camera the
        number of views dropped (no time, or no reference frame within the
        tolerance; the views matched to frames ``every`` leaves out are not
        counted).

    Raises
    ------
    CamcalError
        A camera of the file not given, a camera given without times, or a
        frame past the end of its video (one line).
    """
    cameras = list(reports)
    timestamps.check_cameras(cameras)
    for camera, report in reports.items():
        if report.n_frames is not None:
            timestamps.check_frames(camera, report.n_frames, (sources or {}).get(camera, camera))
    synchronisation = synchronise(timestamps, cameras, tolerance_s)
    detections, dropped = {}, {}
    for camera, report in reports.items():
        numbers = synchronisation.numbers[camera]
        kept, n_dropped = [], 0
        for detection in report.detections:
            number = numbers.get(frame_number(detection.image))
            if number is None:
                n_dropped += 1
            elif number % every == 0:
                kept.append(dataclasses.replace(detection, image=synchronised_label(detection.image, number)))
        detections[camera] = kept
        dropped[camera] = n_dropped
    return detections, synchronisation, dropped
