"""Lines files: ``{"image_size": [W, H], "lines": [[[x, y], ...], ...]}`` <-> :class:`~camcal.geometry.lines.LineSet`."""

from __future__ import annotations

import os
from pathlib import Path

from camcal.base.errors import CamcalError
from camcal.base.jsonfile import read_json, write_json
from camcal.geometry.lines import LineSet

__all__ = ["read_lines", "write_lines"]


def read_lines(path: str | os.PathLike) -> LineSet:
    """Read ``{"image_size": [W, H], "lines": [[[x, y], ...], ...]}``."""
    data = read_json(path, "lines file")
    if not isinstance(data, dict) or set(data) != {"image_size", "lines"}:
        raise CamcalError(f"{path}: a lines file holds exactly the keys image_size and lines")
    if not isinstance(data["lines"], list):
        raise CamcalError(f"{path}: 'lines' must be a list of lines")
    try:
        return LineSet(tuple(data["lines"]), tuple(data["image_size"]) if isinstance(data["image_size"], list) else data["image_size"])
    except (CamcalError, TypeError, ValueError) as error:
        raise CamcalError(f"{path}: {error}") from None


def write_lines(path: str | os.PathLike, lines: LineSet) -> Path:
    """Write a lines file (atomically); inverse of :func:`read_lines`."""
    return write_json(path, {"image_size": list(lines.image_size), "lines": [line.tolist() for line in lines.lines]})
