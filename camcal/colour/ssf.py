"""Camera spectral sensitivities: the ``*.ssf.json`` file, estimation from captures, quality.

A camera's spectral sensitivity functions (SSF) ``s(lambda)`` give its linear
RGB of any stimulus: ``RGB = sum_lambda R(lambda) L(lambda) s(lambda)``
(reflectance ``R``, illuminant ``L``, sums on one regular wavelength grid).
This module holds them in one file kind, estimated or measured:

- :func:`estimate_from_captures` estimates them from one or more chart
  captures (patch reflectances, the illuminant, the camera's linear RGB),
  each capture with its own unknown exposure: alternating least squares
  between the curves (:func:`camcal.colour.spectral.estimate_sensitivities`:
  weighted least squares for relative noise, positivity, second-difference
  smoothness, ``lambda`` by K-fold cross-validation) and one exposure per
  capture. Several illuminants give more independent stimuli than one
  chart under one light.
- :func:`read_sensitivities_csv` reads measured curves (monochromator or a
  data sheet): ``wavelength,R,G,B`` with optional ``sigma_R,sigma_G,sigma_B``.
- :class:`Sensitivities` reports the Vora-Trussell mu-factor and the
  Luther-Ives deviation (:func:`luther_ives_deviation`), renders a
  :class:`~camcal.colour.spectral.SimulatedCamera` under any illuminant and
  draws plausible curves from the estimate's uncertainty (posterior plus
  smoothing bias, :meth:`Sensitivities.samples`).

File ``*.ssf.json`` (JSON, versioned, validated on load, written atomically,
round-trips exactly)::

    {"format": "camcal.ssf", "version": 1, "camera": "Nikon 5100",
     "source": "estimated" | "measured",
     "wavelengths": [400.0, 410.0, ...],            regular grid, nm
     "sensitivities": [[r, g, b], ...],             (W, 3), largest value 1
     "covariance": [[[...]]] | null,                (3, W, W) per channel, same units
     "estimation": {"method": "kfold", "regularisation": [3], "cv_rms": [3],
                    "relative_rgb_rms": 0.004,
                    "captures": [{"illuminant": "D65", "source": "...",
                                  "n_patches": 24, "exposure": 1.0}]} | null,
     "quality": {"mu_factor": 0.93, "mu_factor_D65": 0.92,
                 "luther_ives_residual": [x, y, z], "luther_ives_rms": 0.2},
     "provenance": {"tool": "camcal 0.x", "created": "...", "source": "..."}}

``quality`` is recomputed from the curves whenever the file is written (it is
there for people and other tools; camcal never trusts it on load). A CSV
(``wavelength,R,G,B[,sigma_R,sigma_G,sigma_B]``) is written beside the JSON.

References
----------
- Vora, P. L., Trussell, H. J. (1993). Measure of goodness of a set of
  color-scanning filters. JOSA A, 10(7), 1499-1508.
- Finlayson, G. D., Hordley, S., Hubel, P. M. (1998). Recovering device
  sensitivities with quadratic programming. CIC 6, 90-95.
- Luther, R. (1927). Aus dem Gebiet der Farbreizmetrik. Z. tech. Phys. 8.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camcal.colour.spectral import (
    SimulatedCamera,
    CMFS_NAME,
    resample_spectral,
    spectral_shape,
    estimate_sensitivities,
    mu_factor,
)
from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_write_text
from camcal.base.jsonfile import read_json, utc_timestamp, write_json
from camcal.io.points_csv import finite_numbers

__all__ = [
    "FORMAT",
    "VERSION",
    "DEFAULT_WAVELENGTHS",
    "Sensitivities",
    "LutherIves",
    "luther_ives_deviation",
    "cmfs_on",
    "illuminant_spd",
    "Capture",
    "capture_from_chart",
    "read_spectral_patch_csv",
    "capture_exposures",
    "estimate_from_captures",
    "relative_rms_error",
    "read_sensitivities_csv",
    "load_sensitivities",
    "write_sensitivities",
    "plot_sensitivities",
]

FORMAT = "camcal.ssf"
VERSION = 1
DEFAULT_WAVELENGTHS = tuple(float(v) for v in np.arange(400.0, 701.0, 10.0))
SOURCES = ("estimated", "measured")


def cmfs_on(wavelengths: Any) -> np.ndarray:
    """CIE 1931 2 degree colour matching functions on ``wavelengths``, ``(W, 3)``."""
    import colour

    return resample_spectral(colour.MSDS_CMFS[CMFS_NAME], np.asarray(wavelengths, dtype=np.float64))


def illuminant_spd(spec: str, wavelengths: Any) -> np.ndarray:
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
    import colour

    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if spec in colour.SDS_ILLUMINANTS:
        values = resample_spectral(colour.SDS_ILLUMINANTS[spec], wavelengths)
    elif str(spec).lower().endswith(".csv"):
        table = _read_numeric_csv(Path(spec), 2, "wavelength,value")
        values = np.interp(wavelengths, table[:, 0], table[:, 1])
    else:
        raise CamcalError(f"unknown illuminant {spec!r}: expected a name of colour.SDS_ILLUMINANTS "
                          f"(D65, A, FL2, LED-B3...) or a CSV file wavelength,value")
    if not np.all(np.isfinite(values)) or values.max() <= 0:
        raise CamcalError(f"illuminant {spec!r}: no positive power on {wavelengths[0]:g}-{wavelengths[-1]:g} nm")
    return values / values.max()


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


@dataclass(frozen=True)
class LutherIves:
    """How far sensitivities are from a linear combination of the CIE CMFs.

    Attributes
    ----------
    M
        ``(3, 3)`` least-squares matrix with ``s @ M ~ cmfs`` (columns X, Y, Z).
    residual
        ``(3,)`` relative residual ``|s M_i - cmf_i| / |cmf_i|`` for X, Y, Z.
    rms
        ``|s M - cmfs|_F / |cmfs|_F``: 0 for a camera meeting the
        Luther-Ives condition.
    """

    M: np.ndarray
    residual: np.ndarray
    rms: float


def luther_ives_deviation(sensitivities: Any, cmfs: Any, illuminant: Any = None) -> LutherIves:
    """Distance of camera sensitivities from the Luther-Ives condition.

    Fits ``M = argmin |s M - V|_F`` (``V`` the CMFs, both optionally weighted
    by the illuminant) and reports the relative residual per CMF. The
    condition (Luther 1927, Ives 1915) holds when the residual is 0: the
    camera then sees exactly as the standard observer does, up to a matrix.

    Examples
    --------
    >>> x = np.linspace(0, 1, 40)
    >>> V = np.stack([x, x**2, 1 - x], axis=1)
    >>> round(luther_ives_deviation(V @ np.diag([2.0, 1.0, 3.0]), V).rms, 12)
    0.0
    """
    S = np.asarray(sensitivities, dtype=np.float64)
    V = np.asarray(cmfs, dtype=np.float64)
    if S.ndim != 2 or S.shape[1] != 3 or V.shape != S.shape:
        raise CamcalError(f"sensitivities and CMFs must both be (W, 3) on one grid, got {S.shape} and {V.shape}")
    if illuminant is not None:
        weight = np.asarray(illuminant, dtype=np.float64)[:, None]
        S, V = S * weight, V * weight
    M = np.linalg.lstsq(S, V, rcond=None)[0]
    resid = S @ M - V
    return LutherIves(M, np.linalg.norm(resid, axis=0) / np.linalg.norm(V, axis=0),
                      float(np.linalg.norm(resid) / np.linalg.norm(V)))


def relative_rms_error(estimate: Any, truth: Any) -> tuple[np.ndarray, float]:
    """Relative RMS error of estimated curves after one common scale.

    Sensitivities are known up to one factor (exposure), so ``truth`` is
    first scaled by ``k = <est, truth> / <truth, truth>`` (all channels).

    Returns
    -------
    per_channel, overall
        ``|est_c - k truth_c| / |k truth_c|`` and the same over all channels.
    """
    est = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    k = float(np.sum(est * truth) / np.sum(truth * truth))
    diff = est - k * truth
    return (np.linalg.norm(diff, axis=0) / np.linalg.norm(k * truth, axis=0),
            float(np.linalg.norm(diff) / np.linalg.norm(k * truth)))


@dataclass(frozen=True, eq=False)
class Sensitivities:
    """A camera's spectral sensitivities (estimated or measured).

    Attributes
    ----------
    wavelengths
        ``(W,)`` regular grid, nm.
    values
        ``(W, 3)`` R, G, B curves (the file stores them with largest value 1).
    covariance
        ``(3, W, W)`` per-channel covariance of the curves, or ``None``
        (measured curves without uncertainty).
    camera, source
        Labels; ``source`` is ``"estimated"`` or ``"measured"``.
    estimation
        How an estimate was made (the file's dictionary), ``None`` for
        measured curves.
    provenance
        Tool, creation time, source files.
    """

    wavelengths: np.ndarray
    values: np.ndarray
    covariance: np.ndarray | None = None
    camera: str | None = None
    source: str = "measured"
    estimation: dict | None = None
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl = np.array(self.wavelengths, dtype=np.float64)
        values = np.array(self.values, dtype=np.float64)
        spectral_shape(wl)
        if values.shape != (wl.size, 3) or not np.all(np.isfinite(values)):
            raise CamcalError(f"sensitivities must be finite ({wl.size}, 3) on the grid, got {values.shape}")
        if np.any(values.max(axis=0) <= 0):
            raise CamcalError("sensitivities need a positive peak in every channel")
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=np.float64)
            if cov.shape != (3, wl.size, wl.size) or not np.all(np.isfinite(cov)):
                raise CamcalError(f"covariance must be finite (3, {wl.size}, {wl.size}), got {cov.shape}")
            object.__setattr__(self, "covariance", cov)
        if self.source not in SOURCES:
            raise CamcalError(f"source {self.source!r}: expected one of: {', '.join(SOURCES)}")
        object.__setattr__(self, "wavelengths", wl)
        object.__setattr__(self, "values", values)

    @property
    def sigma(self) -> np.ndarray | None:
        """``(W, 3)`` standard deviation of each curve, or ``None``."""
        if self.covariance is None:
            return None
        return np.sqrt(np.maximum(np.diagonal(self.covariance, axis1=1, axis2=2), 0.0)).T

    def normalised(self) -> Sensitivities:
        """The same curves scaled so the largest value is 1 (covariance scaled too)."""
        k = 1.0 / float(self.values.max())
        cov = None if self.covariance is None else self.covariance * k * k
        return Sensitivities(self.wavelengths, self.values * k, cov, self.camera, self.source,
                             self.estimation, dict(self.provenance))

    def mu_factor(self, illuminant: str | None = None) -> float:
        """Vora-Trussell mu-factor against the CIE 1931 CMFs (equal energy or under ``illuminant``)."""
        weight = None if illuminant is None else illuminant_spd(illuminant, self.wavelengths)
        return mu_factor(self.values, cmfs_on(self.wavelengths), weight)

    def luther_ives(self) -> LutherIves:
        """Luther-Ives deviation against the CIE 1931 CMFs (equal energy)."""
        return luther_ives_deviation(self.values, cmfs_on(self.wavelengths))

    def camera_under(self, illuminant: str, values: Any = None) -> SimulatedCamera:
        """A :class:`SimulatedCamera` with these curves (or ``values``) under ``illuminant``."""
        curves = self.values if values is None else np.asarray(values, dtype=np.float64)
        return SimulatedCamera(self.wavelengths, curves, illuminant_spd(illuminant, self.wavelengths),
                               cmfs_on(self.wavelengths), self.camera or "", illuminant)

    def samples(self, n: int, seed: int = 0) -> np.ndarray:
        """``(n, W, 3)`` plausible curves: draws from ``N(values, covariance)``, clipped at 0.

        Without a covariance every draw is the curves themselves.
        """
        if self.covariance is None:
            return np.repeat(self.values[None], n, axis=0)
        rng = np.random.default_rng(seed)
        out = np.empty((n,) + self.values.shape)
        for ch in range(3):
            out[:, :, ch] = rng.multivariate_normal(self.values[:, ch], self.covariance[ch], size=n,
                                                    method="eigh")
        return np.maximum(out, 0.0)

    def resampled(self, wavelengths: Any) -> Sensitivities:
        """Curves linearly interpolated on another grid (zero outside their range; covariance dropped)."""
        wl = np.asarray(wavelengths, dtype=np.float64)
        spectral_shape(wl)
        values = np.stack([np.interp(wl, self.wavelengths, self.values[:, c], left=0.0, right=0.0)
                           for c in range(3)], axis=1)
        return Sensitivities(wl, values, None, self.camera, self.source, self.estimation, dict(self.provenance))

    def quality(self) -> dict:
        """The file's ``quality`` block (recomputed)."""
        li = self.luther_ives()
        return {"mu_factor": self.mu_factor(), "mu_factor_D65": self.mu_factor("D65"),
                "luther_ives_residual": [float(v) for v in li.residual], "luther_ives_rms": li.rms}

    def summary(self) -> str:
        """Human lines: grid, source, mu-factor, Luther-Ives deviation, regularisation."""
        li = self.luther_ives()
        lines = [f"sensitivities ({self.source}): {self.wavelengths[0]:g}-{self.wavelengths[-1]:g} nm "
                 f"in {self.wavelengths[1] - self.wavelengths[0]:g} nm steps ({self.wavelengths.size} samples)",
                 f"mu-factor (Vora-Trussell): {self.mu_factor():.4f} equal energy, {self.mu_factor('D65'):.4f} D65",
                 "Luther-Ives deviation: " + ", ".join(f"{n} {100 * v:.1f} %" for n, v in zip("XYZ", li.residual))
                 + f" (overall {100 * li.rms:.1f} %)"]
        if self.estimation:
            est = self.estimation
            lines.append(f"estimated from {sum(c['n_patches'] for c in est['captures'])} patches in "
                         f"{len(est['captures'])} capture(s); lambda (K-fold CV) "
                         + ", ".join(f"{v:.2g}" for v in est["regularisation"])
                         + f"; RGB residual {100 * est['relative_rgb_rms']:.2f} % RMS")
        if self.sigma is not None:
            rel = np.linalg.norm(self.sigma, axis=0) / np.linalg.norm(self.values, axis=0)
            lines.append("sigma incl. smoothing bias (relative RMS): " + ", ".join(f"{n} {100 * v:.1f} %" for n, v in zip("RGB", rel)))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The file's JSON object (``quality`` recomputed)."""
        from camcal import __version__

        return {
            "format": FORMAT,
            "version": VERSION,
            "camera": self.camera,
            "source": self.source,
            "wavelengths": [float(v) for v in self.wavelengths],
            "sensitivities": [[float(v) for v in row] for row in self.values],
            "covariance": None if self.covariance is None else
            [[[float(v) for v in row] for row in block] for block in self.covariance],
            "estimation": self.estimation,
            "quality": self.quality(),
            "provenance": dict(self.provenance) or {"tool": f"camcal {__version__}", "created": ""},
        }

    @classmethod
    def from_dict(cls, data: Any) -> Sensitivities:
        """Validate a file's JSON object (errors name the field) and build the curves."""
        if not isinstance(data, dict):
            raise CamcalError(f"sensitivities file: expected a JSON object, got {type(data).__name__}")
        if data.get("format") != FORMAT:
            raise CamcalError(f"format: expected {FORMAT!r}, got {data.get('format')!r}")
        if data.get("version") != VERSION or isinstance(data.get("version"), bool):
            raise CamcalError(f"version: this camcal reads version {VERSION}, got {data.get('version')!r}")
        keys = ("format", "version", "camera", "source", "wavelengths", "sensitivities", "covariance",
                "estimation", "quality", "provenance")
        unknown = sorted(set(data) - set(keys))
        missing = [k for k in keys if k not in data]
        if unknown or missing:
            raise CamcalError(f"sensitivities file: unknown keys {unknown}" if unknown
                              else f"sensitivities file: missing keys {missing}")
        if data["camera"] is not None and not isinstance(data["camera"], str):
            raise CamcalError(f"camera: expected a string or null, got {data['camera']!r:.60}")
        try:
            wl = np.array(data["wavelengths"], dtype=np.float64)
        except (TypeError, ValueError):
            raise CamcalError("wavelengths: expected a list of numbers") from None
        try:
            values = np.array(data["sensitivities"], dtype=np.float64)
        except (TypeError, ValueError):
            raise CamcalError("sensitivities: expected a list of [R, G, B] rows") from None
        cov = data["covariance"]
        if cov is not None:
            try:
                cov = np.array(cov, dtype=np.float64)
            except (TypeError, ValueError):
                raise CamcalError("covariance: expected 3 square matrices or null") from None
        if data["estimation"] is not None and not isinstance(data["estimation"], dict):
            raise CamcalError("estimation: expected an object or null")
        if not isinstance(data["provenance"], dict):
            raise CamcalError("provenance: expected an object")
        try:
            return cls(wl, values, cov, data["camera"], data["source"], data["estimation"], dict(data["provenance"]))
        except CamcalError as error:
            raise CamcalError(f"sensitivities: {error}") from None


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


# --------------------------------------------------------------------------
# captures and estimation


@dataclass(frozen=True, eq=False)
class Capture:
    """One capture for sensitivity estimation.

    Attributes
    ----------
    names
        ``N`` patch names.
    reflectances
        ``(N, W)`` on the estimation grid.
    RGB
        ``(N, 3)`` LINEAR camera RGB (any exposure).
    illuminant
        ``(W,)`` spectral power of the light.
    illuminant_name, source
        Labels recorded in the file.
    """

    names: tuple[str, ...]
    reflectances: np.ndarray
    RGB: np.ndarray
    illuminant: np.ndarray
    illuminant_name: str
    source: str = ""

    @property
    def stimulus(self) -> np.ndarray:
        return self.reflectances * self.illuminant[None, :]


def capture_from_chart(
    image_path: str | os.PathLike,
    illuminant: str,
    wavelengths: Any = DEFAULT_WAVELENGTHS,
    *,
    reflectances: str = "BabelColor Average",
    corners: Any = None,
) -> Capture:
    """A ColorChecker 24 photo (linear: raw or linear TIFF/EXR) as a capture.

    The chart is found and sampled as by ``colour fit`` (clipped patches
    dropped); each patch's reflectance comes from colour-science's spectral
    data ``reflectances`` (``BabelColor Average``, ``ColorChecker N Ohta`` or
    ``ISO 17321-1``), matched by patch name.
    """
    import colour

    from camcal.colour.characterise import patches_from_chart

    if reflectances not in ("BabelColor Average", "ColorChecker N Ohta", "ISO 17321-1"):
        raise CamcalError(f"unknown chart spectra {reflectances!r}, expected one of: BabelColor Average, "
                          f"ColorChecker N Ohta, ISO 17321-1")
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    found = patches_from_chart(image_path, corners=corners)
    sds = colour.SDS_COLOURCHECKERS[reflectances]
    names = found.patches.names
    missing = [n for n in names if n not in sds]
    if missing:
        raise CamcalError(f"chart spectra {reflectances!r} lack patches: {', '.join(missing)}")
    R = np.array([resample_spectral(sds[n], wavelengths) for n in names])
    return Capture(names, R, found.patches.RGB, illuminant_spd(illuminant, wavelengths), illuminant, str(image_path))


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
    return Capture(tuple(names), R, table[:, :3], illuminant_spd(illuminant, wavelengths), illuminant, str(path))


EXPOSURE_LAMBDA = 1e-2


def capture_exposures(captures: Sequence[Capture]) -> np.ndarray:
    """Relative exposure ``k_c`` of each capture (``k_0 = 1``) by profile least squares.

    Minimises, over ``log k_c``, the penalised misfit of the ridge solution
    ``s(k) = argmin sum_c |k_c A_c s - RGB_c|^2 + lambda |D s|^2`` (all
    channels, unconstrained, ``lambda`` = :data:`EXPOSURE_LAMBDA` in the
    units of :func:`~camcal.colour.spectral.estimate_sensitivities`): a
    fairly smooth ``s`` so that the exposures cannot trade off against the
    curves' shape (with several illuminants they otherwise would). Started
    from exposures matching each capture's mean G to its mean stimulus power.
    """
    from scipy.optimize import minimize

    from camcal.colour.spectral import second_difference

    if len(captures) == 1:
        return np.ones(1)
    W = captures[0].reflectances.shape[1]
    A = np.vstack([cap.stimulus for cap in captures])
    C = np.vstack([cap.RGB for cap in captures])
    sizes = np.array([len(cap.names) for cap in captures])
    D = second_difference(W)
    DtD = D.T @ D
    scale = float(np.sum(C**2))

    def misfit(log_k: np.ndarray) -> float:
        rows = np.repeat(np.concatenate([[1.0], np.exp(log_k)]), sizes)
        As = A * rows[:, None]
        AtA = As.T @ As
        lam = EXPOSURE_LAMBDA * np.trace(AtA) / np.trace(DtD)
        S = np.linalg.solve(AtA + lam * DtD, As.T @ C)
        return float(np.sum((As @ S - C) ** 2) + lam * np.sum((D @ S) ** 2)) / scale

    start = np.array([float(np.mean(cap.RGB[:, 1]) / np.mean(cap.stimulus.sum(axis=1))) for cap in captures])
    result = minimize(misfit, np.log(start[1:] / start[0]), method="Nelder-Mead",
                      options={"xatol": 1e-7, "fatol": 1e-14, "maxiter": 4000})
    return np.concatenate([[1.0], np.exp(result.x)])


def estimate_from_captures(
    captures: Sequence[Capture],
    wavelengths: Any = DEFAULT_WAVELENGTHS,
    *,
    camera: str | None = None,
    method: str = "kfold",
    folds: int = 5,
    seed: int = 0,
) -> Sensitivities:
    """Estimate sensitivities from captures with unknown exposures.

    Model: ``RGB_c = k_c (R_c * L_c) @ s`` for capture ``c`` with exposure
    ``k_c`` (``k_0 = 1``). The exposures come first (:func:`capture_exposures`),
    then :func:`~camcal.colour.spectral.estimate_sensitivities` runs on all
    captures' RGB divided by them (positivity, smoothness, ``lambda`` per
    channel by K-fold cross-validation).

    Returns
    -------
    Sensitivities
        Normalised to largest value 1, with the covariance (posterior plus
        smoothing bias, see :class:`~camcal.colour.spectral.SensitivityEstimate`) and
        the ``estimation`` block (per capture: illuminant, source, patch
        count, exposure relative to the first).
    """
    if not captures:
        raise CamcalError("no captures: give at least one chart image or spectral patch file")
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    for cap in captures:
        if cap.reflectances.shape[1] != wavelengths.size:
            raise CamcalError(f"capture {cap.source!r}: spectra on {cap.reflectances.shape[1]} wavelengths, "
                              f"the grid has {wavelengths.size}")
        if not np.all(np.isfinite(cap.RGB)) or np.any(cap.RGB.max(axis=0) <= 0):
            raise CamcalError(f"capture {cap.source!r}: RGB must be finite with a positive value in every channel")
    stimulus = np.vstack([cap.stimulus for cap in captures])
    k = capture_exposures(captures)
    RGB = np.vstack([cap.RGB / kc for cap, kc in zip(captures, k)])
    est = estimate_sensitivities(stimulus, RGB, wavelengths, method=method, folds=folds, seed=seed)
    pred = stimulus @ est.sensitivities
    relative_rms = float(np.sqrt(np.mean((pred - RGB) ** 2)) / np.sqrt(np.mean(RGB**2)))
    estimation = {
        "method": est.method,
        "regularisation": [float(v) for v in est.regularisation],
        "cv_rms": [float(v) for v in est.cv_rms],
        "relative_rgb_rms": relative_rms,
        "captures": [{"illuminant": cap.illuminant_name, "source": cap.source, "n_patches": len(cap.names),
                      "exposure": float(kc)} for cap, kc in zip(captures, k)],
    }
    provenance = {"tool": _tool(), "created": utc_timestamp(), "source": "; ".join(c.source for c in captures)}
    return Sensitivities(wavelengths, est.sensitivities, est.covariance, camera, "estimated", estimation,
                         provenance).normalised()


def plot_sensitivities(
    path: str | os.PathLike,
    sens: Sensitivities,
    truth: Sensitivities | None = None,
    title: str = "",
) -> Path:
    """Plot the curves with ``+-1.96 sigma`` bands and, if given, other curves to compare.

    ``sigma`` includes the smoothing bias (see
    :class:`~camcal.colour.spectral.SensitivityEstimate`): the nominal 95 %
    band covered 94.2 % of the true curves' samples on simulated cameras
    (89.6-96.9 % per case, 84-100 % per draw; tests/colour/test_colour_ssf.py, slow).

    ``truth`` is resampled on the grid and scaled by the common factor of
    :func:`relative_rms_error`. Written with matplotlib's Agg backend.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from camcal.base.atomic import atomic_path

    path = Path(path)
    wl = sens.wavelengths
    fig, ax = plt.subplots(figsize=(7, 4))
    sigma = sens.sigma
    for ch, colour_name in enumerate(("tab:red", "tab:green", "tab:blue")):
        ax.plot(wl, sens.values[:, ch], color=colour_name, label=f"{'RGB'[ch]} ({sens.source})")
        if sigma is not None:
            ax.fill_between(wl, np.maximum(sens.values[:, ch] - 1.96 * sigma[:, ch], 0),
                            sens.values[:, ch] + 1.96 * sigma[:, ch], color=colour_name, alpha=0.2, linewidth=0)
    if truth is not None:
        other = truth.resampled(wl).values
        k = float(np.sum(sens.values * other) / np.sum(other * other))
        for ch, colour_name in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(wl, k * other[:, ch], "--", color=colour_name, linewidth=1,
                    label=f"{'RGB'[ch]} ({truth.camera or 'reference'})")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("relative sensitivity")
    band = ", band: 95 % (+-1.96 sigma)" if sigma is not None else ""
    ax.set_title((title + " " if title else "") + f"mu-factor {sens.mu_factor():.3f}{band}", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path
