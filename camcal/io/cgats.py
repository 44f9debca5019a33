"""CGATS.17 files (ANSI CGATS.17, the IT8.7 data format): a chart's reference measurements.

The file is text: a first line naming the format (``IT8.7/2``,
``CGATS.17``...), keyword lines (``ORIGINATOR "..."``), the field names
between ``BEGIN_DATA_FORMAT`` and ``END_DATA_FORMAT``, then one line per
patch between ``BEGIN_DATA`` and ``END_DATA``; ``#`` starts a comment.
camcal reads the patch names (``SAMPLE_ID`` or ``SAMPLE_NAME``) and their
colour: ``XYZ_X XYZ_Y XYZ_Z`` (0-100, the perfect white Y = 100) or, without
them, ``LAB_L LAB_A LAB_B`` (CIELAB under D50, the standard's viewing
condition, ISO 13655), as XYZ with white Y = 1 under D50.
:func:`write_cgats` writes that subset (for tests and round trips).
"""

from __future__ import annotations

import os
import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.limits import FILE_BYTES, check_file_size

__all__ = ["CgatsData", "read_cgats", "write_cgats"]


@dataclass(frozen=True, eq=False)
class CgatsData:
    """A CGATS file's patches: ``names`` and ``XYZ`` ``(N, 3)`` under D50 (white Y = 1), and its keywords."""

    names: tuple[str, ...]
    XYZ: np.ndarray
    keywords: dict[str, str]
    identifier: str


def _lab_D50_to_XYZ(Lab: np.ndarray) -> np.ndarray:
    """CIELAB (D50, CIE 1976) to XYZ with white Y = 1 (CIE 15:2004 inverse)."""
    white = np.array([0.96422, 1.0, 0.82521])
    fy = (Lab[:, 0] + 16.0) / 116.0
    f = np.column_stack([fy + Lab[:, 1] / 500.0, fy, fy - Lab[:, 2] / 200.0])
    delta = 6.0 / 29.0
    return white * np.where(f > delta, f**3, 3 * delta**2 * (f - 4.0 / 29.0))


def _uncommented(line: str) -> str:
    """``line`` without a ``#`` comment outside double quotes, stripped."""
    quoted = False
    for k, char in enumerate(line):
        if char == '"':
            quoted = not quoted
        elif char == "#" and not quoted:
            return line[:k].strip()
    return line.strip()


def read_cgats(path: str | os.PathLike) -> CgatsData:
    """Read a CGATS.17 reference file (see the module docstring).

    Raises
    ------
    CamcalError
        Naming the file and the problem (no data, no names, no XYZ or Lab
        fields, a line with the wrong number of values, a value not a number).
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"CGATS file not found: {path}")
    check_file_size(path, FILE_BYTES, "CGATS file")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        text = path.read_text(encoding="latin-1")
    lines = [line for line in (_uncommented(raw) for raw in text.splitlines()) if line]
    if not lines:
        raise CamcalError(f"{path}: empty CGATS file")
    identifier, keywords = lines[0], {}
    fields: list[str] = []
    rows: list[list[str]] = []
    section = None
    for number, line in enumerate(lines[1:], start=2):
        head = line.split(None, 1)[0].upper()
        if head in ("BEGIN_DATA_FORMAT", "BEGIN_DATA"):
            section = head
            continue
        if head in ("END_DATA_FORMAT", "END_DATA"):
            section = None
            continue
        if section == "BEGIN_DATA_FORMAT":
            fields += [f.upper() for f in line.split()]
        elif section == "BEGIN_DATA":
            try:
                rows.append(shlex.split(line))
            except ValueError:
                raise CamcalError(f"{path}: unbalanced quotes in data line {line!r}") from None
        else:
            parts = line.split(None, 1)
            keywords[parts[0]] = parts[1].strip().strip('"') if len(parts) > 1 else ""
    if not fields or not rows:
        raise CamcalError(f"{path}: not a CGATS file (no BEGIN_DATA_FORMAT / BEGIN_DATA section)")
    name_field = next((f for f in ("SAMPLE_ID", "SAMPLE_NAME", "SAMPLE_LOC") if f in fields), None)
    if name_field is None:
        raise CamcalError(f"{path}: no SAMPLE_ID or SAMPLE_NAME field (fields: {' '.join(fields)})")
    if all(f in fields for f in ("XYZ_X", "XYZ_Y", "XYZ_Z")):
        colour_fields, kind = ("XYZ_X", "XYZ_Y", "XYZ_Z"), "XYZ"
    elif all(f in fields for f in ("LAB_L", "LAB_A", "LAB_B")):
        colour_fields, kind = ("LAB_L", "LAB_A", "LAB_B"), "Lab"
    else:
        raise CamcalError(f"{path}: no XYZ_X/XYZ_Y/XYZ_Z or LAB_L/LAB_A/LAB_B fields (fields: {' '.join(fields)})")
    columns = [fields.index(f) for f in colour_fields]
    names, values = [], []
    for row in rows:
        if len(row) != len(fields):
            raise CamcalError(f"{path}: data line {' '.join(row)!r} has {len(row)} values, the format {len(fields)}")
        try:
            values.append([float(row[k]) for k in columns])
        except ValueError:
            raise CamcalError(f"{path}: a colour value of patch {row[fields.index(name_field)]!r} is not a number") from None
        names.append(row[fields.index(name_field)])
    values = np.array(values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise CamcalError(f"{path}: non-finite colour values")
    XYZ = values / 100.0 if kind == "XYZ" else _lab_D50_to_XYZ(values)
    return CgatsData(tuple(names), XYZ, keywords, identifier)


def write_cgats(path: str | os.PathLike, names, XYZ, *, identifier: str = "CGATS.17",
                descriptor: str = "camcal reference data") -> Path:
    """Write patches as a CGATS.17 file with ``SAMPLE_ID XYZ_X XYZ_Y XYZ_Z`` (XYZ given with white Y = 1)."""
    XYZ = np.asarray(XYZ, dtype=np.float64)
    lines = [identifier, f'DESCRIPTOR "{descriptor}"', "NUMBER_OF_FIELDS 4", "BEGIN_DATA_FORMAT",
             "SAMPLE_ID XYZ_X XYZ_Y XYZ_Z", "END_DATA_FORMAT", f"NUMBER_OF_SETS {len(XYZ)}", "BEGIN_DATA"]
    lines += [f"{name} {x * 100:.4f} {y * 100:.4f} {z * 100:.4f}" for name, (x, y, z) in zip(names, XYZ)]
    lines.append("END_DATA")
    atomic_write_text(Path(path), "\n".join(lines) + "\n")
    return Path(path)
