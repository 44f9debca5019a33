"""3D-2D correspondences as CSV: header ``X,Y,Z,u,v``, one point per row.

``X, Y, Z`` are world coordinates (the rig's units); ``u, v`` pixels with
(0, 0) at the centre of the top-left pixel.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_path

__all__ = ["CORRESPONDENCE_HEADER", "finite_numbers", "read_correspondences", "write_correspondences"]

CORRESPONDENCE_HEADER = ("X", "Y", "Z", "u", "v")


def finite_numbers(cells: list[str], where: str) -> list[float]:
    """The cells of a CSV row as finite floats, or one error naming ``where`` (file and line)."""
    try:
        values = [float(cell) for cell in cells]
    except ValueError:
        raise CamcalError(f"{where}: not a number in {','.join(cells)}") from None
    if not all(math.isfinite(v) for v in values):
        raise CamcalError(f"{where}: NaN or infinite value in {','.join(cells)}")
    return values


def read_correspondences(path: str | os.PathLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read a correspondence CSV.

    Returns
    -------
    X : ndarray, shape (N, 3)
    x : ndarray, shape (N, 2)

    Raises
    ------
    CamcalError
        Missing file, wrong header, a row with a missing or non-numeric
        value, or a NaN / infinite value (the message gives the line).
    """
    path = Path(path)
    try:
        handle = open(path, newline="", encoding="utf-8")
    except FileNotFoundError:
        raise CamcalError(f"points file not found: {path}") from None
    except OSError as error:
        raise CamcalError(f"cannot read points file {path}: {error}") from None
    rows = []
    with handle:
        reader = csv.reader(handle)
        try:
            header = next(reader, None)
            if header is None or tuple(h.strip() for h in header) != CORRESPONDENCE_HEADER:
                raise CamcalError(
                    f"{path}: expected the header {','.join(CORRESPONDENCE_HEADER)}, got {','.join(header or []) or 'an empty file'}"
                )
            for row in reader:
                if not row or all(not cell.strip() for cell in row):
                    continue
                line = reader.line_num
                if len(row) != len(CORRESPONDENCE_HEADER):
                    raise CamcalError(f"{path}, line {line}: expected 5 values, got {len(row)}")
                rows.append(finite_numbers(row, f"{path}, line {line}"))
        except (csv.Error, UnicodeDecodeError) as error:
            raise CamcalError(f"{path}: not a readable CSV file ({error})") from None
    data = np.array(rows, dtype=np.float64).reshape(-1, 5)
    return data[:, :3], data[:, 3:]


def write_correspondences(path: str | os.PathLike, X: NDArray[np.float64], x: NDArray[np.float64]) -> Path:
    """Write a correspondence CSV atomically (floats at full precision)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as handle:
            writer = csv.writer(handle)
            writer.writerow(CORRESPONDENCE_HEADER)
            for point, pixel in zip(np.asarray(X), np.asarray(x)):
                writer.writerow([repr(float(v)) for v in (*point, *pixel)])
    return path
