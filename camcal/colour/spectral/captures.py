"""Sensitivity estimation from chart captures with unknown exposures.

:func:`estimate_from_captures` estimates a camera's sensitivities from one
or more captures (patch reflectances, the illuminant, the camera's linear
RGB), each capture with its own unknown exposure: the exposures by profile
least squares (:func:`capture_exposures`), then
:func:`camcal.colour.spectral.estimate.estimate_sensitivities` (weighted
least squares for relative noise, positivity, second-difference smoothness,
``lambda`` by K-fold cross-validation). Several illuminants give more
independent stimuli than one chart under one light. Captures come from
chart photos (:func:`camcal.pipelines.colour.capture_from_chart`, with
:func:`chart_reflectances`) or spectral patch files
(:func:`camcal.io.ssf.read_spectral_patch_csv`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.clock import utc_timestamp
from camcal.base.extras import require
from camcal.colour.spectral.data import resample_spectral
from camcal.colour.spectral.estimate import estimate_sensitivities
from camcal.colour.spectral.sensitivities import DEFAULT_WAVELENGTHS, Sensitivities

__all__ = [
    "CHART_SPECTRA",
    "EXPOSURE_LAMBDA",
    "Capture",
    "check_chart_spectra",
    "chart_reflectances",
    "capture_exposures",
    "estimate_from_captures",
]

#: colour-science's ColorChecker 24 spectral data a chart capture may use.
CHART_SPECTRA = ("BabelColor Average", "ColorChecker N Ohta", "ISO 17321-1")


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


def check_chart_spectra(reflectances: str) -> None:
    """Raise unless ``reflectances`` is one of :data:`CHART_SPECTRA`."""
    if reflectances not in CHART_SPECTRA:
        raise CamcalError(f"unknown chart spectra {reflectances!r}, expected one of: BabelColor Average, "
                          f"ColorChecker N Ohta, ISO 17321-1")


def chart_reflectances(names: Sequence[str], reflectances: str, wavelengths: Any) -> np.ndarray:
    """Reflectances ``(N, W)`` of ColorChecker 24 patches, matched by name, on ``wavelengths``.

    ``reflectances`` is colour-science's spectral data set (one of
    :data:`CHART_SPECTRA`).
    """
    colour = require("colour")

    check_chart_spectra(reflectances)
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    sds = colour.SDS_COLOURCHECKERS[reflectances]
    missing = [n for n in names if n not in sds]
    if missing:
        raise CamcalError(f"chart spectra {reflectances!r} lack patches: {', '.join(missing)}")
    return np.array([resample_spectral(sds[n], wavelengths) for n in names])


EXPOSURE_LAMBDA = 1e-2


def capture_exposures(captures: Sequence[Capture]) -> np.ndarray:
    """Relative exposure ``k_c`` of each capture (``k_0 = 1``) by profile least squares.

    Minimises, over ``log k_c``, the penalised misfit of the ridge solution
    ``s(k) = argmin sum_c |k_c A_c s - RGB_c|^2 + lambda |D s|^2`` (all
    channels, unconstrained, ``lambda`` = :data:`EXPOSURE_LAMBDA` in the
    units of :func:`~camcal.colour.spectral.estimate.estimate_sensitivities`): a
    fairly smooth ``s`` so that the exposures cannot trade off against the
    curves' shape (with several illuminants they otherwise would). Started
    from exposures matching each capture's mean G to its mean stimulus power.
    """
    from scipy.optimize import minimize

    from camcal.colour.spectral.estimate import second_difference

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
    then :func:`~camcal.colour.spectral.estimate.estimate_sensitivities` runs on all
    captures' RGB divided by them (positivity, smoothness, ``lambda`` per
    channel by K-fold cross-validation).

    Returns
    -------
    Sensitivities
        Normalised to largest value 1, with the covariance (posterior plus
        smoothing bias, see :class:`~camcal.colour.spectral.estimate.SensitivityEstimate`) and
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


def _tool() -> str:
    from camcal import __version__

    return f"camcal {__version__}"
