"""Lens metadata: a CSV of each frame's lens state, as a smart lens or a camera records it, and the lens state
of each board image (a CSV, or the image's EXIF).

Per frame, two forms, by their header::

    frame,focal_mm,focus_m          focal length in mm, focus distance in m (or inf)
    12,32.5,2.4
    13,32.6,inf

    frame,focal,focus               encoders 0-1 (``--encoders``; OpenTrackIO's: zoom 0 wide, focus 0 far)
    12,0.41,0.72

Frames are whole numbers from 0, each once, with none missing between the
first and the last (a matchmove needs the lens at every frame).

Per board image (``calibrate profile --states-from csv``), paths relative to the CSV's folder::

    image,focal_mm,focus_m
    grids/a01.jpg,24,1.2
    grids/b07.jpg,35,inf
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
from camcal.base.extras import require
from camcal.base.limits import FILE_BYTES, check_file_size

__all__ = ["ENCODER_HEADER", "EXIF_INFINITY_M", "IMAGE_STATE_HEADER", "STATE_HEADER", "LensMetadata",
           "read_exif_lens_state", "read_image_lens_states", "read_lens_metadata"]

STATE_HEADER = ("frame", "focal_mm", "focus_m")
IMAGE_STATE_HEADER = ("image", "focal_mm", "focus_m")
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


def _rows(path: Path, expected: tuple[str, ...], what: str, other: str = ""):
    """``(where, cells)`` of each non-empty row of a CSV whose header is ``expected`` (``where`` names the file and
    line); a missing, unreadable or non-UTF-8 file, or another header, is one error naming the file."""
    check_file_size(path, FILE_BYTES, what)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise CamcalError(f"{what} not found: {path}") from None
    except OSError as error:
        raise CamcalError(f"cannot read {what} {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, None)
    if header is None or tuple(cell.strip() for cell in header) != expected:
        got = ",".join(header or [])[:80] or "an empty file"
        raise CamcalError(f"{path}: expected the header {','.join(expected)}{other}, got {got!r}")
    for row in reader:
        if not row or all(not cell.strip() for cell in row):
            continue
        where = f"{path}, line {reader.line_num}"
        if len(row) != len(expected):
            raise CamcalError(f"{where}: expected {len(expected)} values ({','.join(expected)}), got {len(row)}")
        yield where, [cell.strip() for cell in row]


def _values(where: str, names: tuple[str, ...], texts: list[str], encoders: bool = False) -> tuple[float, float]:
    """The focal length and focus distance (or encoder values) of a row; ``inf`` only as a focus distance."""
    values = []
    for name, value_text in zip(names, texts):
        try:
            value = float(value_text)
        except ValueError:
            raise CamcalError(f"{where}: {name} must be a number, got {value_text[:40]!r}") from None
        if math.isnan(value) or (math.isinf(value) and (encoders or name != "focus_m" or value < 0)):
            raise CamcalError(f"{where}: {name} is not a finite number ({value_text[:40]})")
        values.append(value)
    return values[0], values[1]


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
    expected = ENCODER_HEADER if encoders else STATE_HEADER
    other = "" if encoders else " (encoder values 0-1: the header frame,focal,focus and --encoders)"
    rows: dict[int, tuple[float, float]] = {}
    for where, (frame_text, focal_text, focus_text) in _rows(path, expected, "lens metadata file", other):
        if not frame_text.isdigit() or not frame_text.isascii() or len(frame_text) > _MAX_FRAME_DIGITS:
            raise CamcalError(f"{where}: the frame must be a whole number from 0, got {frame_text[:40]!r}")
        frame = int(frame_text)
        if frame in rows:
            raise CamcalError(f"{where}: frame {frame} is given twice")
        rows[frame] = _values(where, expected[1:], [focal_text, focus_text], encoders)
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


def read_image_lens_states(path: str | os.PathLike) -> list[tuple[Path, float, float]]:
    """Read a CSV of board images and the lens state each was shot at (the module docstring's third form).

    Returns
    -------
    list of (Path, float, float)
        Each image (relative paths resolved against the CSV's folder), its focal length in mm and focus distance in
        m (``inf`` possible), in the file's order.

    Raises
    ------
    CamcalError
        One line naming the file (and the line): missing, unreadable or not UTF-8, the wrong header, a row without
        three values, an image not found or given twice, a value that is not a number or not positive, or no rows.
    """
    path = Path(path)
    rows: list[tuple[Path, float, float]] = []
    seen: set[Path] = set()
    for where, (image_text, focal_text, focus_text) in _rows(path, IMAGE_STATE_HEADER, "lens state file"):
        image = path.parent / Path(image_text).expanduser()
        if not image_text or not image.is_file():
            raise CamcalError(f"{where}: image not found: {image_text[:200]!r}")
        if image.resolve() in seen:
            raise CamcalError(f"{where}: image {image_text[:200]!r} is given twice")
        seen.add(image.resolve())
        focal, focus = _values(where, IMAGE_STATE_HEADER[1:], [focal_text, focus_text])
        if not (focal > 0 and focus > 0):
            raise CamcalError(f"{where}: the focal length and the focus distance must be positive, got {focal:g} and "
                              f"{focus:g}")
        rows.append((image, focal, focus))
    if not rows:
        raise CamcalError(f"{path}: no images")
    return rows


#: EXIF writes a SubjectDistance of infinity as the numerator 0xFFFFFFFF; over any denominator up to 10000 it is
#: at least this many metres.
EXIF_INFINITY_M = 0xFFFFFFFF / 10000


def read_exif_lens_state(path: str | os.PathLike) -> tuple[float | None, float | None]:
    """The focal length (mm) and focus distance (m) an image's EXIF records: ``FocalLength`` and
    ``SubjectDistance`` (read with OpenImageIO: JPEG, TIFF, PNG and the raw formats it reads).

    A tag that is absent, or 0 (EXIF's "unknown"), is None; a ``SubjectDistance`` of at least
    :data:`EXIF_INFINITY_M` is infinity (EXIF 2.32, tag 0x9206: numerator 0xFFFFFFFF). Maker notes (a lens'
    own focus distance) are not read.

    Raises
    ------
    CamcalError
        OpenImageIO missing, or a file it cannot open.
    """
    oiio = require("OpenImageIO")
    image = oiio.ImageInput.open(os.fspath(path))
    if image is None:
        raise CamcalError(f"cannot read {path} ({oiio.geterror().strip() or 'not an image OpenImageIO reads'})")
    try:
        spec = image.spec()
        focal, focus = (spec.getattribute(name) for name in ("Exif:FocalLength", "Exif:SubjectDistance"))
    finally:
        image.close()

    def known(value: object) -> float | None:
        if isinstance(value, (int, float)) and math.isfinite(value) and value > 0:
            return float(value)
        return None

    focal, focus = known(focal), known(focus)
    return focal, (math.inf if focus is not None and focus >= EXIF_INFINITY_M else focus)
