"""Patch files: the patch CSV (camera RGB beside reference XYZ) and per-patch Delta E tables.

CSV header ``R,G,B,X,Y,Z`` (camera RGB, reference XYZ under the scene
illuminant with the perfect white Y = 1), with an optional first column
``name``. One patch per line; blank lines and lines starting with ``#`` are
skipped.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_path
from camcal.base.errors import CamcalError
from camcal.colour.chart.patches import PatchSet
from camcal.io.points_csv import finite_numbers

__all__ = ["read_patch_csv", "write_patch_csv", "write_patch_table"]


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


def write_patch_table(path: str | os.PathLike, rows: list[dict]) -> None:
    """Write :func:`camcal.colour.fit.evaluate.patch_table` rows as CSV (atomically)."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})
