"""Per-frame lens metadata: a CSV of each frame's lens state, as a smart lens or a camera records it.

Two forms, by their header::

    frame,focal_mm,focus_m          focal length in mm, focus distance in m (or inf)
    12,32.5,2.4
    13,32.6,inf

    frame,focal,focus               encoders 0-1 (``--encoders``; OpenTrackIO's: zoom 0 wide, focus 0 far)
    12,0.41,0.72

Frames are whole numbers from 0, each once, with none missing between the
first and the last (a matchmove needs the lens at every frame).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.limits import FILE_BYTES, check_file_size

__all__ = ["ENCODER_HEADER", "STATE_HEADER", "LensMetadata", "read_lens_metadata"]

STATE_HEADER = ("frame", "focal_mm", "focus_m")
ENCODER_HEADER = ("frame", "focal", "focus")
_MAX_FRAME_DIGITS = 9


@dataclass(frozen=True)
class LensMetadata:
    """Each frame's lens state (or encoder values), in frame order.

    Attributes
    ----------
    frames : ndarray of int, shape (N,)
    focal, focus : ndarray, shape (N,)
        Focal length (mm) and focus distance (m, ``inf`` possible), or encoder values 0-1.
    encoders : bool
        True for the ``frame,focal,focus`` form.
    """

    frames: NDArray[np.int64]
    focal: NDArray[np.float64]
    focus: NDArray[np.float64]
    encoders: bool


def read_lens_metadata(path: str | os.PathLike, *, encoders: bool = False) -> LensMetadata:
    """Read a lens metadata CSV (the module docstring's forms; ``encoders`` selects the second).

    Raises
    ------
    CamcalError
        One line naming the file (and the line): missing, unreadable or not UTF-8, the wrong header, a row
        without three values, a frame that is not a whole number or given twice, frames missing between the
        first and the last, a value that is not a number (an encoder outside 0-1 is the caller's check), or no rows.
    """
    path = Path(path)
    check_file_size(path, FILE_BYTES, "lens metadata file")
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise CamcalError(f"lens metadata file not found: {path}") from None
    except OSError as error:
        raise CamcalError(f"cannot read lens metadata file {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    expected = ENCODER_HEADER if encoders else STATE_HEADER
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, None)
    if header is None or tuple(cell.strip() for cell in header) != expected:
        got = ",".join(header or [])[:80] or "an empty file"
        other = "" if encoders else " (encoder values 0-1: the header frame,focal,focus and --encoders)"
        raise CamcalError(f"{path}: expected the header {','.join(expected)}{other}, got {got!r}")
    rows: dict[int, tuple[float, float]] = {}
    for row in reader:
        if not row or all(not cell.strip() for cell in row):
            continue
        where = f"{path}, line {reader.line_num}"
        if len(row) != 3:
            raise CamcalError(f"{where}: expected 3 values ({','.join(expected)}), got {len(row)}")
        frame_text, focal_text, focus_text = (cell.strip() for cell in row)
        if not frame_text.isdigit() or not frame_text.isascii() or len(frame_text) > _MAX_FRAME_DIGITS:
            raise CamcalError(f"{where}: the frame must be a whole number from 0, got {frame_text[:40]!r}")
        values = []
        for name, value_text in zip(expected[1:], (focal_text, focus_text)):
            try:
                value = float(value_text)
            except ValueError:
                raise CamcalError(f"{where}: {name} must be a number, got {value_text[:40]!r}") from None
            if math.isnan(value) or (math.isinf(value) and (encoders or name != "focus_m" or value < 0)):
                raise CamcalError(f"{where}: {name} is not a finite number ({value_text[:40]})")
            values.append(value)
        frame = int(frame_text)
        if frame in rows:
            raise CamcalError(f"{where}: frame {frame} is given twice")
        rows[frame] = (values[0], values[1])
    if not rows:
        raise CamcalError(f"{path}: no frames")
    frames = np.array(sorted(rows), dtype=np.int64)
    missing = sorted(set(range(int(frames[0]), int(frames[-1]) + 1)) - set(rows))
    if missing:
        shown = ", ".join(str(f) for f in missing[:8]) + (", ..." if len(missing) > 8 else "")
        raise CamcalError(f"{path}: frames {frames[0]}-{frames[-1]} miss {len(missing)} frame(s): {shown} (the lens "
                          "is needed at every frame)")
    values = np.array([rows[int(f)] for f in frames], dtype=np.float64)
    return LensMetadata(frames, values[:, 0], values[:, 1], encoders)
