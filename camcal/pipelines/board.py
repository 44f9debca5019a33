"""Calibration boards found in image files: worker threads and a cache keyed by content.

Detection over many images (:func:`detect_in_images`) runs in worker
threads and keeps each image's result in a cache keyed by the file's
content (SHA-256) and the detector settings
(:data:`camcal.geometry.board.DETECTOR_SETTINGS`), so that calibrating again
with other options does not detect again.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from camcal.base.atomic import atomic_path
from camcal.base.errors import CamcalError
from camcal.geometry.board import DETECTOR_SETTINGS, Board, Detection, DetectionReport, detect_board
from camcal.io.frames import imread
from camcal.io.headers import check_image_header

__all__ = ["default_cache_dir", "detect_in_images"]


def default_cache_dir() -> Path:
    """Where detections are cached by default: ``$XDG_CACHE_HOME/camcal/corners`` (``~/.cache/camcal/corners``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "camcal" / "corners"


def _cache_key(board: Board, content: bytes) -> str:
    """SHA-256 of the image bytes, the board and the detector settings."""
    digest = hashlib.sha256(content)
    digest.update(f"|{board.spec()}|{DETECTOR_SETTINGS}".encode())
    return digest.hexdigest()


def _read_cached(path: Path) -> tuple[tuple[int, int] | None, Detection | None] | None:
    """A cached result ``(image size or None if unreadable, detection or None)``; None when absent or unreadable."""
    try:
        data = json.loads(path.read_text())
        size = tuple(data["size"]) if data["size"] is not None else None
        if data["detection"] is None:
            return size, None
        d = data["detection"]
        return size, Detection(d["image"], tuple(d["image_size"]), np.asarray(d["ids"], dtype=np.int64),
                               np.asarray(d["corners_px"], dtype=np.float64).reshape(-1, 2), d["detector"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write_cached(path: Path, size: tuple[int, int] | None, detection: Detection | None) -> None:
    """Write one result atomically (temp file + rename); a cache that cannot be written is skipped."""
    payload = {"size": list(size) if size else None, "detection": None if detection is None else {
        "image": detection.image, "image_size": list(detection.image_size), "ids": detection.ids.tolist(),
        "corners_px": detection.corners_px.tolist(), "detector": detection.detector}}
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
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            with ThreadPoolExecutor(max_workers=n_workers) as pool:
                futures = [(index, pool.submit(_detect_file, board, str(paths[index]), content))
                           for index, content in pending]
                for index, future in futures:
                    results[index] = future.result()
                    count += 1
                    report_progress()
        finally:
            cv2.setNumThreads(threads)
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
