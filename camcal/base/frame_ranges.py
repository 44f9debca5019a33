"""Frame ranges: ``1001-1240``, ``1001-1240x2`` or ``1,5,10-12`` as sorted frame numbers and back; held-out frames."""

from __future__ import annotations

import re

from camcal.base.errors import CamcalError

__all__ = ["MAX_FRAMES", "frame_runs", "parse_frames", "parse_holdout"]

#: The most frames one list may name.
MAX_FRAMES = 10_000_000


def parse_frames(text: str) -> tuple[int, ...]:
    """Frame numbers from ``"1001-1240"``, ``"1001-1240x2"`` (every 2nd) or ``"1,5,10-12"``.

    Returns
    -------
    tuple of int
        Sorted, without repeats.

    Examples
    --------
    >>> parse_frames("1001-1009x4,1,2")
    (1, 2, 1001, 1005, 1009)
    """
    frames: set[int] = set()
    for item in str(text).replace(" ", "").split(","):
        match = re.fullmatch(r"(-?\d{1,18})(?:-(-?\d{1,18})(?:x(\d{1,18}))?)?", item)
        if not match:
            raise CamcalError(f"bad frame range {text!r}: expected e.g. 1001-1240, 1001-1240x2 or 1,5,10-12")
        start = int(match.group(1))
        end = int(match.group(2)) if match.group(2) is not None else start
        step = int(match.group(3) or 1)
        if end < start:
            raise CamcalError(f"bad frame range {item!r}: the last frame is before the first")
        if step < 1:
            raise CamcalError(f"bad frame range {item!r}: the step must be at least 1")
        if (end - start) // step + len(frames) > MAX_FRAMES:
            raise CamcalError(f"frame range {text!r} has more than {MAX_FRAMES} frames")
        frames.update(range(start, end + 1, step))
    return tuple(sorted(frames))


def parse_holdout(text: str, frames: list[int]) -> set[int]:
    """``--holdout``: frame numbers and ranges (``21-25,3``, as
    :func:`parse_frames`) or a fraction of the frames (``0.2``, evenly spaced)."""
    text = text.strip()
    if re.fullmatch(r"0?\.\d+", text):
        if not frames:
            return set()
        fraction = float(text)
        count = max(1, round(fraction * len(frames)))
        step = len(frames) / count
        return {frames[min(len(frames) - 1, int((k + 0.5) * step))] for k in range(count)}
    try:
        return set(parse_frames(text))
    except CamcalError as error:
        raise CamcalError(f"bad --holdout {text!r} ({error}): expected frame numbers and ranges (21-25,3) "
                          "or a fraction (0.2)") from None


def frame_runs(frames: list[int]) -> list[str]:
    """Sorted frame numbers as runs, for messages.

    Examples
    --------
    >>> frame_runs([1, 2, 3, 7])
    ['1-3', '7']
    """
    runs: list[list[int]] = []
    for frame in frames:
        if runs and frame == runs[-1][1] + 1:
            runs[-1][1] = frame
        else:
            runs.append([frame, frame])
    return [str(a) if a == b else f"{a}-{b}" for a, b in runs]
