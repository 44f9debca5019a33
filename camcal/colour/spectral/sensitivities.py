"""Camera spectral sensitivities: the data of a ``*.ssf.json``, quality figures, illuminant spectra.

A camera's spectral sensitivity functions (SSF) ``s(lambda)`` give its linear
RGB of any stimulus: ``RGB = sum_lambda R(lambda) L(lambda) s(lambda)``
(reflectance ``R``, illuminant ``L``, sums on one regular wavelength grid).

- :class:`Sensitivities` holds them (estimated or measured), reports the
  Vora-Trussell mu-factor and the Luther-Ives deviation
  (:func:`luther_ives_deviation`), renders a
  :class:`~camcal.colour.spectral.simulate.SimulatedCamera` under any
  illuminant and draws plausible curves from the estimate's uncertainty
  (posterior plus smoothing bias, :meth:`Sensitivities.samples`).
- :func:`illuminant_spd` is an illuminant's spectral power on a grid.

The file ``*.ssf.json`` (read and written by :mod:`camcal.io.ssf`; JSON,
versioned, validated on load by :meth:`Sensitivities.from_dict`, written
atomically, round-trips exactly)::


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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.spectral.data import CMFS_NAME, resample_spectral, spectral_shape
from camcal.colour.spectral.estimate import mu_factor
from camcal.colour.spectral.simulate import SimulatedCamera

__all__ = [
    "FORMAT",
    "VERSION",
    "DEFAULT_WAVELENGTHS",
    "SOURCES",
    "Sensitivities",
    "LutherIves",
    "luther_ives_deviation",
    "relative_rms_error",
    "cmfs_on",
    "illuminant_spd",
    "normalised_spd",
]

FORMAT = "camcal.ssf"
VERSION = 1
DEFAULT_WAVELENGTHS = tuple(float(v) for v in np.arange(400.0, 701.0, 10.0))
SOURCES = ("estimated", "measured")


def cmfs_on(wavelengths: Any) -> np.ndarray:
    """CIE 1931 2 degree colour matching functions on ``wavelengths``, ``(W, 3)``."""
    colour = require("colour")

    return resample_spectral(colour.MSDS_CMFS[CMFS_NAME], np.asarray(wavelengths, dtype=np.float64))


def illuminant_spd(name: str, wavelengths: Any) -> np.ndarray:
    """Spectral power of a CIE illuminant on ``wavelengths``, largest value 1.

    Parameters
    ----------
    name
        A name of colour-science's ``SDS_ILLUMINANTS`` (``D65``, ``A``,
        ``FL2``, ``LED-B3``...); :func:`camcal.io.ssf.read_illuminant_spd`
        also reads a CSV file ``wavelength,value``.
    wavelengths
        ``(W,)`` nm.
    """
    colour = require("colour")

    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if name not in colour.SDS_ILLUMINANTS:
        raise CamcalError(f"unknown illuminant {name!r}: expected a name of colour.SDS_ILLUMINANTS "
                          f"(D65, A, FL2, LED-B3...)")
    return normalised_spd(resample_spectral(colour.SDS_ILLUMINANTS[name], wavelengths), name, wavelengths)


def normalised_spd(values: Any, spec: str, wavelengths: Any) -> np.ndarray:
    """An illuminant's power ``(W,)`` on ``wavelengths`` scaled to largest value 1 (``spec`` names it in errors)."""
    values = np.asarray(values, dtype=np.float64)
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if not np.all(np.isfinite(values)) or values.max() <= 0:
        raise CamcalError(f"illuminant {spec!r}: no positive power on {wavelengths[0]:g}-{wavelengths[-1]:g} nm")
    return values / values.max()


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
