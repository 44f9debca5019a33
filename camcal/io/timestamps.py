"""Frame timestamps as CSV (header ``camera,frame,time``) and the synchronisation of cameras by time.

One row per frame: the camera's name (as given to ``--camera``), the frame
number (frame ``k`` of a video is the ``k``-th decoded frame, from 0; of an
image sequence, the number in the file name) and the frame's time in
seconds on a clock shared by every camera (any origin). A camera's times
must increase strictly with its frame numbers.

:func:`synchronise` matches the frames of every camera to the first
camera's by nearest time: a frame takes the number of the first camera's
frame nearest in time when it is within the tolerance (by default half the
first camera's median frame period), the nearer of two frames taking one
number; the others are unmatched.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.limits import FILE_BYTES, check_file_size

__all__ = ["TIMESTAMPS_HEADER", "Synchronisation", "Timestamps", "read_timestamps", "synchronise"]

TIMESTAMPS_HEADER = ("camera", "frame", "time")
#: Longest frame number accepted (digits): a frame past 10^12 is not a frame of any video.
_MAX_FRAME_DIGITS = 12


@dataclass(frozen=True)
class Timestamps:
    """The times of a timestamps file.

    Attributes
    ----------
    path : str
    times : mapping of str to (frames, times)
        Camera -> its frame numbers (int64, increasing) and their times
        (float64 seconds, strictly increasing).
    """

    path: str
    times: Mapping[str, tuple[np.ndarray, np.ndarray]]

    def period(self, camera: str) -> float:
        """Median time per frame of ``camera`` (``dt / dframe`` over consecutive rows), in seconds."""
        frames, times = self.times[camera]
        if len(frames) < 2:
            raise CamcalError(f"{self.path}: camera {camera!r} has one timestamp: no frame period to set the "
                              "tolerance from (give --time-tolerance)")
        return float(np.median(np.diff(times) / np.diff(frames)))

    def check_cameras(self, cameras: Sequence[str]) -> None:
        """Every camera given has times and every camera of the file is given, else one line."""
        unknown = [name for name in self.times if name not in cameras]
        if unknown:
            raise CamcalError(f"{self.path}: unknown camera {unknown[0]!r} (the cameras are: {', '.join(cameras)})")
        missing = [name for name in cameras if name not in self.times]
        if missing:
            raise CamcalError(f"{self.path}: no timestamps for camera {missing[0]!r}")

    def check_frames(self, camera: str, n_frames: int, video: str) -> None:
        """Every frame of ``camera`` in the file is one of the ``n_frames`` decoded from ``video``, else one line."""
        frames = self.times[camera][0]
        if len(frames) and frames[-1] >= n_frames:
            raise CamcalError(f"{self.path}: camera {camera!r} frame {int(frames[-1])} is beyond its video {video} "
                              f"({n_frames} frames, 0 to {n_frames - 1})")


def read_timestamps(path: str | os.PathLike) -> Timestamps:
    """Read a timestamps CSV (``camera,frame,time``; see the module docstring).

    Raises
    ------
    CamcalError
        One line naming the file (and the line): missing or unreadable file,
        over :data:`camcal.base.limits.FILE_BYTES`, not UTF-8, wrong header,
        a row without three values, an empty camera name, a frame that is
        not a non-negative integer, a time that is not a finite number, a
        frame given twice, times not increasing with the frame numbers, or
        no rows.
    """
    path = Path(path)
    check_file_size(path, FILE_BYTES, "timestamps file")
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise CamcalError(f"timestamps file not found: {path}") from None
    except OSError as error:
        raise CamcalError(f"cannot read timestamps file {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    rows: dict[str, dict[int, float]] = {}
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader, None)
        if header is None or tuple(cell.strip() for cell in header) != TIMESTAMPS_HEADER:
            got = ",".join(header or [])[:80] or "an empty file"
            raise CamcalError(f"{path}: expected the header {','.join(TIMESTAMPS_HEADER)}, got {got!r}")
        for row in reader:
            if not row or all(not cell.strip() for cell in row):
                continue
            where = f"{path}, line {reader.line_num}"
            if len(row) != 3:
                raise CamcalError(f"{where}: expected 3 values (camera,frame,time), got {len(row)}")
            camera, frame_text, time_text = (cell.strip() for cell in row)
            if not camera or not camera.isprintable():
                raise CamcalError(f"{where}: the camera name is empty or holds a control character")
            if not frame_text.isdigit() or not frame_text.isascii() or len(frame_text) > _MAX_FRAME_DIGITS:
                raise CamcalError(f"{where}: the frame must be a whole number from 0, got {frame_text[:40]!r}")
            try:
                time = float(time_text)
            except ValueError:
                raise CamcalError(f"{where}: the time must be a number of seconds, got {time_text[:40]!r}") from None
            if not math.isfinite(time):
                raise CamcalError(f"{where}: the time is {time_text[:40]!r}, not a finite number of seconds")
            frames = rows.setdefault(camera, {})
            frame = int(frame_text)
            if frame in frames:
                raise CamcalError(f"{where}: camera {camera[:40]!r} frame {frame} given twice")
            frames[frame] = time
    except csv.Error as error:
        raise CamcalError(f"{path}: not a readable CSV file ({error})") from None
    if not rows:
        raise CamcalError(f"{path}: no timestamps (only the header)")
    times = {}
    for camera, frames in rows.items():
        numbers = np.array(sorted(frames), dtype=np.int64)
        values = np.array([frames[k] for k in numbers.tolist()], dtype=np.float64)
        steps = np.flatnonzero(np.diff(values) <= 0.0)
        if len(steps):
            n = steps[0]
            raise CamcalError(f"{path}: times of camera {camera[:40]!r} do not increase with its frames (frame "
                              f"{numbers[n]} at {float(values[n])!r} s, frame {numbers[n + 1]} at {float(values[n + 1])!r} s)")
        times[camera] = (numbers, values)
    return Timestamps(str(path), times)


@dataclass(frozen=True)
class Synchronisation:
    """Each camera's frames on the first camera's frame numbers.

    Attributes
    ----------
    reference : str
        The first camera: its frames keep their numbers.
    tolerance_s : float
    numbers : mapping of str to mapping of int to int
        Camera -> {its frame: the reference frame it is matched to}.
    offsets_s : mapping of str to float
        Camera -> median of (its frame's time - the matched reference
        frame's time) over its matched frames (0 for the reference).
    """

    reference: str
    tolerance_s: float
    numbers: Mapping[str, Mapping[int, int]]
    offsets_s: Mapping[str, float]


def synchronise(timestamps: Timestamps, cameras: Sequence[str], tolerance_s: float | None = None) -> Synchronisation:
    """Match every camera's frames to the first camera's by nearest time.

    Parameters
    ----------
    timestamps : Timestamps
    cameras : sequence of str
        The cameras, the reference first (each must be in ``timestamps``).
    tolerance_s : float, optional
        Largest time difference of a match, seconds; by default half the
        reference's median frame period.

    Returns
    -------
    Synchronisation

    Notes
    -----
    For camera ``j``'s frame at time ``t``, the reference frame ``k`` with
    ``|t - t_ref(k)|`` least (the two neighbours of ``t`` in the sorted
    reference times) is its match when ``|t - t_ref(k)| <= tolerance``;
    when two frames of ``j`` match one reference frame, the nearer keeps
    it (the earlier on a tie).
    """
    timestamps.check_cameras(cameras)
    reference = cameras[0]
    if tolerance_s is None:
        tolerance_s = 0.5 * timestamps.period(reference)
    if not (math.isfinite(tolerance_s) and tolerance_s > 0):
        raise CamcalError(f"the time tolerance must be a positive number of seconds, got {tolerance_s}")
    ref_frames, ref_times = timestamps.times[reference]
    numbers: dict[str, dict[int, int]] = {reference: {int(k): int(k) for k in ref_frames}}
    offsets = {reference: 0.0}
    for camera in cameras[1:]:
        frames, times = timestamps.times[camera]
        if len(ref_times) == 1:
            nearest = np.zeros(len(times), dtype=np.int64)
        else:  # the two reference times around each time, the nearer wins
            right = np.clip(np.searchsorted(ref_times, times), 1, len(ref_times) - 1)
            left = right - 1
            nearest = np.where(np.abs(times - ref_times[left]) <= np.abs(times - ref_times[right]), left, right)
        gap = np.abs(times - ref_times[nearest])
        best: dict[int, int] = {}
        for n in np.flatnonzero(gap <= tolerance_s):
            k = int(nearest[n])
            if k not in best or gap[n] < gap[best[k]]:
                best[k] = int(n)
        numbers[camera] = {int(frames[n]): int(ref_frames[k]) for k, n in sorted(best.items(), key=lambda kv: kv[1])}
        matched = np.array(sorted(best.values()), dtype=np.int64)
        offsets[camera] = float(np.median(times[matched] - ref_times[nearest[matched]])) if len(matched) else 0.0
    return Synchronisation(reference, float(tolerance_s), numbers, offsets)
