"""Matches files: CSV ``camera_a,u_a,v_a,camera_b,u_b,v_b`` -> :data:`camcal.geometry.rectify.Matches`."""

from __future__ import annotations

import csv
import math
import os

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError

__all__ = ["read_matches_csv"]


def read_matches_csv(path: str | os.PathLike) -> dict[tuple[str, str], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Read matches from a CSV with the header ``camera_a,u_a,v_a,camera_b,u_b,v_b``.

    Pixels are in the original (distorted) images, pixel (0, 0) at the
    centre of the top-left pixel.

    Returns
    -------
    dict
        :data:`Matches`.
    """
    header = ["camera_a", "u_a", "v_a", "camera_b", "u_b", "v_b"]
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise CamcalError(f"cannot read matches file {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    if not rows or [cell.strip() for cell in rows[0]] != header:
        raise CamcalError(f"{path}: the first line must be {','.join(header)}")
    collected: dict[tuple[str, str], list[list[float]]] = {}
    for number, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != 6:
            raise CamcalError(f"{path}, line {number}: expected 6 fields, got {len(row)}")
        try:
            values = [float(row[1]), float(row[2]), float(row[4]), float(row[5])]
        except ValueError:
            raise CamcalError(f"{path}, line {number}: pixel coordinates must be numbers") from None
        if not all(math.isfinite(v) for v in values):
            raise CamcalError(f"{path}, line {number}: pixel coordinates must be finite")
        collected.setdefault((row[0].strip(), row[3].strip()), []).append(values)
    if not collected:
        raise CamcalError(f"{path}: no matches")
    return {key: (np.array(v)[:, :2], np.array(v)[:, 2:]) for key, v in collected.items()}
