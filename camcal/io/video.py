"""Video files as numbered frames: streamed by OpenCV's FFmpeg backend, one frame in memory at a time.

Frame ``k`` of a video (counted from 0 in decoding order) is frame number
``k``: views of several cameras recorded in sync match by that number.
Files ending in :data:`VIDEO_SUFFIXES` are videos; anything FFmpeg
decodes inside them is read (H.264, HEVC, MPEG-4, MJPEG, FFV1...).

FFmpeg's own log is silenced (``OPENCV_FFMPEG_LOGLEVEL``, unless the user
set it, before OpenCV's first video is opened): a file that cannot be
decoded is one :class:`CamcalError` naming it, not a screen of libav
messages.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

import contextlib  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.base.native_log import OPENCV_LOG_SILENT, set_opencv_log_level  # noqa: E402

__all__ = ["VIDEO_SUFFIXES", "VideoInfo", "first_frame", "frame_file_name", "is_video", "iter_frames", "video_info"]

#: File name suffixes read as video.
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv")


@dataclass(frozen=True)
class VideoInfo:
    """What a video's container says about it.

    Attributes
    ----------
    path : str
    size : (int, int)
        Width, height in pixels.
    fps : float
        Frames per second as stored (0 when unknown).
    frame_count : int
        The container's frame count: an estimate for some formats; the
        frames :func:`iter_frames` yields are the truth.
    """

    path: str
    size: tuple[int, int]
    fps: float
    frame_count: int


def is_video(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a video by its suffix (:data:`VIDEO_SUFFIXES`)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


@contextlib.contextmanager
def _capture(path: str | os.PathLike) -> Iterator[cv2.VideoCapture]:
    """An opened ``cv2.VideoCapture`` on the FFmpeg backend, released on exit; one line when it cannot be opened."""
    path = Path(path)
    if not cv2.videoio_registry.hasBackend(cv2.CAP_FFMPEG):
        raise CamcalError(f"{path.name}: this OpenCV build has no FFmpeg video backend to decode it")
    if not path.is_file():
        raise CamcalError(f"{path}: no such video file")
    level = set_opencv_log_level(cv2, OPENCV_LOG_SILENT)  # OpenCV's own "can't open" warning
    try:
        capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    finally:
        set_opencv_log_level(cv2, level)
    try:
        if not capture.isOpened():
            raise CamcalError(f"{path.name}: cannot be decoded as a video (FFmpeg cannot open it)")
        yield capture
    finally:
        capture.release()


def video_info(path: str | os.PathLike) -> VideoInfo:
    """Size, frame rate and frame count of a video (its first frame is decoded to check it can be).

    Raises
    ------
    CamcalError
        No FFmpeg backend, the file cannot be opened, or its first frame
        cannot be decoded.
    """
    with _capture(path) as capture:
        ok, frame = capture.read()
        if not ok or frame is None:
            raise CamcalError(f"{Path(path).name}: cannot be decoded as a video (no frame could be read)")
        return VideoInfo(str(path), (frame.shape[1], frame.shape[0]), float(capture.get(cv2.CAP_PROP_FPS) or 0.0),
                         int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0))


def iter_frames(path: str | os.PathLike, every: int = 1, wanted=None, gray: bool = True, start: int = 0,
                stop: int | None = None) -> Iterator[tuple[int, NDArray[np.uint8]]]:
    """Yield ``(frame_number, image)`` of every ``every``-th frame (0, every, 2 every...), decoded in order.

    Parameters
    ----------
    path : path
        A video file.
    every : int
        Keep frame ``k`` when ``k % every == 0``.
    wanted : callable, optional
        ``wanted(k) -> bool``: of the kept frames, those converted and
        yielded (the others are grabbed, i.e. decoded and skipped); by
        default all of them.
    gray : bool
        8-bit grey images (default) or OpenCV's BGR.
    start, stop : int
        Only frames ``start <= k < stop`` (``stop`` None: to the end). The
        decoder seeks to ``start`` (FFmpeg: the key frame before it, then
        decoding forward); when it cannot say it landed on ``start``, the
        frames before it are decoded and skipped instead, so frame numbers
        are the same as when decoding from 0.

    Raises
    ------
    CamcalError
        The video cannot be opened or its first frame cannot be decoded;
        ``every < 1``.

    Notes
    -----
    One decoded frame is held at a time: memory does not grow with the
    video's length. Decoding stops at the first frame FFmpeg cannot read
    (the end, or a truncated file).
    """
    if int(every) < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    start = max(0, int(start))
    with _capture(path) as capture:
        k = 0
        if start > 0:
            if capture.set(cv2.CAP_PROP_POS_FRAMES, start) and capture.get(cv2.CAP_PROP_POS_FRAMES) == start:
                k = start
            else:  # back to frame 0 (a failed seek may leave the decoder anywhere), then skip forward
                capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                while k < start and capture.grab():
                    k += 1
                if k < start:
                    return
        while stop is None or k < stop:
            if not capture.grab():
                if k == 0:
                    raise CamcalError(f"{Path(path).name}: cannot be decoded as a video (no frame could be read)")
                return
            if k % every == 0 and (wanted is None or wanted(k)):  # asked only of frames that exist
                ok, frame = capture.retrieve()
                if not ok or frame is None:
                    if k == 0:
                        raise CamcalError(f"{Path(path).name}: cannot be decoded as a video (no frame could be read)")
                    return
                if gray and frame.ndim == 3:
                    frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                yield k, frame
            k += 1


def first_frame(path: str | os.PathLike, gray: bool = False) -> NDArray[np.uint8]:
    """Frame 0 of a video (8-bit grey or BGR), e.g. to match features between cameras."""
    for _, image in iter_frames(path, gray=gray):
        return image
    raise CamcalError(f"{Path(path).name}: cannot be decoded as a video (no frame could be read)")


def frame_file_name(path: str | os.PathLike, frame: int, suffix: str = ".png") -> str:
    """The file a verb writes frame ``frame`` of a video to: ``cam_0_000012.png`` for ``cam_0.mp4``."""
    return f"{Path(path).stem}_{int(frame):06d}{suffix}"
