"""Patch sets: camera RGB beside reference XYZ, and their CSV file.

CSV header ``R,G,B,X,Y,Z`` (camera RGB, reference XYZ under the scene
illuminant with the perfect white Y = 1), with an optional first column
``name``. One patch per line; blank lines and lines starting with ``#`` are
skipped.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.io.points_csv import finite_numbers

__all__ = ["PatchSet", "read_patch_csv", "write_patch_csv"]


@dataclass(frozen=True, eq=False)
class PatchSet:
    """``N`` patches: names, camera RGB ``(N, 3)``, reference XYZ ``(N, 3)``."""

    names: tuple[str, ...]
    RGB: np.ndarray
    XYZ: np.ndarray

    def __post_init__(self) -> None:
        RGB = np.array(self.RGB, dtype=np.float64)
        XYZ = np.array(self.XYZ, dtype=np.float64)
        if RGB.ndim != 2 or RGB.shape[1] != 3 or XYZ.shape != RGB.shape or len(self.names) != RGB.shape[0]:
            raise CamcalError(
                f"a patch set needs N names, RGB (N, 3) and XYZ (N, 3), got {len(self.names)}, "
                f"{RGB.shape}, {XYZ.shape}"
            )
        object.__setattr__(self, "RGB", RGB)
        object.__setattr__(self, "XYZ", XYZ)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, keep: Any) -> PatchSet:
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        return PatchSet(tuple(self.names[i] for i in idx), self.RGB[idx], self.XYZ[idx])


def _shown(text: str) -> str:
    """``text`` for a one-line message: as is when printable, else its repr (a quoted cell may hold newlines)."""
    return text if text.isprintable() else repr(text)


def read_patch_csv(path: str | os.PathLike) -> PatchSet:
    """Read a patch CSV (see the module docstring).

    Raises
    ------
    CamcalError
        Naming the file and line of the first problem.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"patch file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
        if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise CamcalError(f"{path}: empty patch file")
    header = [cell.strip() for cell in rows[0][1]]
    expected = ["R", "G", "B", "X", "Y", "Z"]
    has_name = header[:1] == ["name"]
    if (header[1:] if has_name else header) != expected:
        raise CamcalError(f"{path}: header must be R,G,B,X,Y,Z with an optional first column name, got {_shown(','.join(header))}")
    names, values = [], []
    for number, row in rows[1:]:
        cells = [cell.strip() for cell in row]
        if len(cells) != len(header):
            raise CamcalError(f"{path}:{number}: expected {len(header)} columns, got {len(cells)}")
        if has_name:
            names.append(cells[0])
            cells = cells[1:]
        else:
            names.append(f"patch{len(names) + 1}")
        values.append(finite_numbers(cells, f"{path}:{number}"))
    if not values:
        raise CamcalError(f"{path}: no patches after the header")
    array = np.array(values)
    return PatchSet(tuple(names), array[:, :3], array[:, 3:])


def write_patch_csv(path: str | os.PathLike, patches: PatchSet) -> None:
    """Write a patch CSV with names, full float precision, atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["name", "R", "G", "B", "X", "Y", "Z"])
        for name, rgb, xyz in zip(patches.names, patches.RGB, patches.XYZ):
            writer.writerow([name, *(repr(float(v)) for v in rgb), *(repr(float(v)) for v in xyz)])
    os.replace(tmp, path)
