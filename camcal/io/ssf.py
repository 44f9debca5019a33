"""Spectral files: ``*.ssf.json`` sensitivities (and the CSV beside them), measured curves, spectral patches, illuminant CSVs.

The file format is documented in :mod:`camcal.colour.spectral.sensitivities`
(:class:`~camcal.colour.spectral.sensitivities.Sensitivities` holds the data).
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.clock import utc_timestamp
from camcal.base.extras import require
from camcal.base.jsonfile import read_json, write_json
from camcal.colour.spectral.captures import Capture
from camcal.colour.spectral.data import resample_spectral
from camcal.colour.spectral.sensitivities import DEFAULT_WAVELENGTHS, Sensitivities, normalised_spd
from camcal.io.points_csv import finite_numbers

__all__ = [
    "read_illuminant_spd",
    "read_sensitivities_csv",
    "load_sensitivities",
    "write_sensitivities",
    "read_spectral_patch_csv",
]


def read_illuminant_spd(spec: str, wavelengths: Any) -> np.ndarray:
    """Spectral power of an illuminant on ``wavelengths``, largest value 1.

    Parameters
    ----------
    spec
        A name of colour-science's ``SDS_ILLUMINANTS`` (``D65``, ``A``,
        ``FL2``, ``LED-B3``...) or a CSV file ``wavelength,value`` (a header
        line is allowed).
    wavelengths
        ``(W,)`` nm.
    """
    colour = require("colour")

    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if spec in colour.SDS_ILLUMINANTS:
        values = resample_spectral(colour.SDS_ILLUMINANTS[spec], wavelengths)
    elif str(spec).lower().endswith(".csv"):
        table = _read_numeric_csv(Path(spec), 2, "wavelength,value")
        values = np.interp(wavelengths, table[:, 0], table[:, 1])
    else:
        raise CamcalError(f"unknown illuminant {spec!r}: expected a name of colour.SDS_ILLUMINANTS "
                          f"(D65, A, FL2, LED-B3...) or a CSV file wavelength,value")
    return normalised_spd(values, spec, wavelengths)


def _read_numeric_csv(path: Path, columns: int, header: str) -> np.ndarray:
    if not path.is_file():
        raise CamcalError(f"file not found: {path}")
    rows = []
    for number, row in enumerate(csv.reader(io.StringIO(path.read_text(encoding="utf-8-sig"))), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if not rows and not _is_number(cells[0]):
            continue  # header
        if len(cells) != columns:
            raise CamcalError(f"{path}:{number}: expected {columns} columns ({header}), got {len(cells)}")
        rows.append(finite_numbers(cells, f"{path}:{number}"))
    if len(rows) < 3:
        raise CamcalError(f"{path}: need at least 3 rows of {header}, got {len(rows)}")
    table = np.array(rows)
    if np.any(np.diff(table[:, 0]) <= 0):
        raise CamcalError(f"{path}: wavelengths must increase from row to row")
    return table


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_sensitivities_csv(path: str | os.PathLike, camera: str | None = None) -> Sensitivities:
    """Measured sensitivities from ``wavelength,R,G,B[,sigma_R,sigma_G,sigma_B]`` (regular grid).

    A header line is allowed; the sigma columns become a diagonal covariance.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"sensitivities file not found: {path}")
    first = next((r for r in csv.reader(io.StringIO(path.read_text(encoding="utf-8-sig")))
                  if r and r[0].strip() and not r[0].strip().startswith("#")), [])
    columns = len(first)
    if columns not in (4, 7):
        raise CamcalError(f"{path}: expected 4 columns (wavelength,R,G,B) or 7 (with sigma_R,sigma_G,sigma_B), "
                          f"got {columns}")
    table = _read_numeric_csv(path, columns, "wavelength,R,G,B[,sigma_R,sigma_G,sigma_B]")
    cov = None
    if columns == 7:
        cov = np.stack([np.diag(table[:, 4 + c] ** 2) for c in range(3)])
    try:
        return Sensitivities(table[:, 0], table[:, 1:4], cov, camera or path.stem.removesuffix(".ssf"),
                             "measured", None, {"tool": _tool(), "created": utc_timestamp(), "source": str(path)})
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None


def load_sensitivities(path: str | os.PathLike) -> Sensitivities:
    """Load ``*.ssf.json`` or a measured CSV (see :func:`read_sensitivities_csv`).

    Raises
    ------
    CamcalError
        ``"<path>: <field>: <what is wrong>"``.
    """
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_sensitivities_csv(path)
    data = read_json(path, "sensitivities file")
    try:
        return Sensitivities.from_dict(data)
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None


def write_sensitivities(path: str | os.PathLike, sens: Sensitivities) -> list[Path]:
    """Write ``*.ssf.json`` and the CSV beside it (``*.ssf.csv``), atomically.

    The curves are written normalised (largest value 1).
    """
    path = Path(path)
    sens = sens.normalised()
    written = [write_json(path, sens.to_dict())]
    stem = path.name.removesuffix(".json")
    csv_path = path.with_name(stem + ".csv" if stem.endswith(".ssf") else stem + ".ssf.csv")
    sigma = sens.sigma
    lines = ["wavelength,R,G,B" + (",sigma_R,sigma_G,sigma_B" if sigma is not None else "")]
    for i, wl in enumerate(sens.wavelengths):
        row = [wl, *sens.values[i]] + ([] if sigma is None else list(sigma[i]))
        lines.append(",".join(repr(float(v)) for v in row))
    atomic_write_text(csv_path, "\n".join(lines) + "\n")
    written.append(csv_path)
    return written


def _tool() -> str:
    from camcal import __version__

    return f"camcal {__version__}"


def read_spectral_patch_csv(path: str | os.PathLike, illuminant: str, wavelengths: Any = DEFAULT_WAVELENGTHS) -> Capture:
    """Patches with their reflectance spectra: ``name,R,G,B,<nm>,<nm>,...``.

    The header names the wavelength of each reflectance column (e.g. ``400,
    410, ...``); the spectra are interpolated onto ``wavelengths`` (end values
    held outside their range). ``R,G,B`` are the camera's LINEAR values.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"patch file not found: {path}")
    rows = [r for r in csv.reader(io.StringIO(path.read_text(encoding="utf-8-sig")))
            if r and any(c.strip() for c in r) and not r[0].strip().startswith("#")]
    if not rows:
        raise CamcalError(f"{path}: empty patch file")
    header = [c.strip() for c in rows[0]]
    if header[:4] != ["name", "R", "G", "B"] or len(header) < 7 or not all(_is_number(h) for h in header[4:]):
        raise CamcalError(f"{path}: header must be name,R,G,B followed by at least 3 wavelengths in nm, "
                          f"got {','.join(header)[:80]}")
    source_wl = np.array([float(h) for h in header[4:]])
    if np.any(np.diff(source_wl) <= 0):
        raise CamcalError(f"{path}: header wavelengths must increase")
    names, values = [], []
    for number, row in enumerate(rows[1:], start=2):
        cells = [c.strip() for c in row]
        if len(cells) != len(header):
            raise CamcalError(f"{path}:{number}: expected {len(header)} columns, got {len(cells)}")
        names.append(cells[0])
        values.append(finite_numbers(cells[1:], f"{path}:{number}"))
    if not values:
        raise CamcalError(f"{path}: no patches after the header")
    table = np.array(values)
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    R = np.array([np.interp(wavelengths, source_wl, r) for r in table[:, 3:]])
    return Capture(tuple(names), R, table[:, :3], read_illuminant_spd(illuminant, wavelengths), illuminant, str(path))
