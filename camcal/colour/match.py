"""Camera-to-camera colour matching: make camera B's colours match camera A's.

The same object seen by two cameras of a rig does not get the same RGB. A
*match* is a transform ``f`` from LINEAR camera-B RGB to LINEAR camera-A RGB
(``A ≈ f(B)``), fitted by one of two routes:

chart route (:func:`match_charts`)
    both cameras characterised on the same chart (``*.colour.json`` of kind
    ``characterisation``). Each maps its camera RGB to the common reference
    (CIE XYZ); the residual camera-to-camera CIEDE2000 on the patches,
    ``ΔE(fit_A(A), fit_B(B))``, is what the two characterisations still
    disagree on. The match is fitted to map B's RGB to the camera-A RGB that
    A's characterisation sends to B's XYZ: ``f ≈ fit_A^-1 ∘ fit_B`` (exact,
    ``M_A^-1 M_B``, when both fits and the match are 3x3 matrices).
image route (:func:`match_images`)
    no chart: a rectified stereo pair. Disparity from ``cv2.StereoSGBM`` in
    both directions with a left-right consistency check; pixels kept when
    the disparity is reliable (consistent, away from depth edges, so not
    occluded), and both colours are unsaturated and above the noise floor.
    ``f`` is fitted robustly (:func:`fit_match_model`: least median of
    squares start, then iteratively reweighted least squares with Tukey's
    biweight) against speculars, occlusions and mismatches, and evaluated on
    image tiles held out from the fit.

Models (``MATCH_MODELS``): ``matrix3x3`` (``A = M B``), ``root-polynomial:D``
(*Finlayson et al. 2015*, exposure invariant), ``polynomial:N`` (*Cheung et
al. 2004*), and ``lut3d[:N]``: a smooth 3D lookup table, ``N^3`` nodes over a
box ``[domain_min, domain_max]`` of camera-B RGB, trilinear interpolation,
inputs clamped to the box (as OpenColorIO's Lut3D does), fitted by lattice
regression (*Garcia & Gupta 2009*) with a second-difference smoothness
penalty that extends the table smoothly where the data do not reach.

File: a ``*.colour.json`` of kind ``match`` (registered in
:data:`camcal.colour.fitfile.KIND_READERS`)::

    {
      "format": "camcal.colour", "version": 1, "kind": "match",
      "source": "B" | null,          # camera whose RGB goes in
      "target": "A" | null,          # camera whose RGB comes out
      "linearisation": {"channels": [CURVE, CURVE, CURVE]},  # source codes -> linear
      "model": MATCH_MODEL,          # linear source RGB -> linear target RGB
      "fit": {"route": "chart" | "image",
              "robust": "lmeds-irls" | "irls" | "none",
              "n_fit": 12000, "n_inliers": 10890,
              "inlier_threshold": 0.021 | null},  # relative residual (see fit_match_model)
      "evaluation": {
        "metric": "CIE 2000",
        "space": "...",              # how target RGB was turned into XYZ for Delta E
        "train": STATS, "test": STATS | null, "before": STATS | null,
        "n_test_outliers": 40 | null,
        "chart": null | {"common_reference": STATS, "source_vs_reference": STATS | null,
                         "target_vs_reference": STATS | null}
      },
      "provenance": {"tool": "camcal 0.1.0", "created": "...", "source": "..."}
    }

``MATCH_MODEL``: ``{"kind": "matrix3x3" | "polynomial" | "root-polynomial",
"terms": [...], "coefficients": [[...T...] x 3]}`` (rows R, G, B of the
target, ``A = coefficients @ terms(B)``; terms as in
:mod:`camcal.colour.models`), or ``{"kind": "lut3d", "size": N,
"domain_min": [3], "domain_max": [3], "smoothing": s, "table": [[R, G, B] x
N^3]}`` with the table in CLF order: the red index varies slowest, blue
fastest, ``table[(i N + j) N + k]`` is the output at input
``domain_min + (i, j, k) / (N - 1) * (domain_max - domain_min)``.

Evaluation: ``train`` is CIEDE2000 between ``f(B)`` and A on the fit data
(the inliers for a robust fit); ``test`` on held-out data (image route:
held-out tiles, inliers by the fit's threshold, outliers counted in
``n_test_outliers``; chart route: an independent patch set); ``before`` the
same held-out set (or the training set) with B left unmatched. Target RGB
becomes XYZ through camera A's characterisation when one is given, else as
linear Rec. 709 / sRGB primaries with D65 white (``space`` says which).

References
----------
- Hirschmuller, H. (2008). Stereo processing by semiglobal matching and
  mutual information. IEEE TPAMI 30(2), 328-341 (SGBM, left-right check).
- Rousseeuw, P. J. (1984). Least median of squares regression. JASA 79.
- Holland, P. W., Welsch, R. E. (1977). Robust regression using
  iteratively reweighted least-squares. Comm. Statist. 6(9), 813-827.
- Beaton, A. E., Tukey, J. W. (1974). The fitting of power series...
  Technometrics 16(2), 147-185 (the biweight).
- Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction
  using root-polynomial regression. IEEE TIP 24(5), 1460-1470.
- Garcia, E., Gupta, M. R. (2009). Lattice regression. NeurIPS 22.
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camcal.colour.evaluate import DeltaEStats, delta_E, plot_report
from camcal.colour.fitfile import (
    KIND_READERS,
    ColourFit,
    LinearisedModel,
    _check_header,
    _check_linearisation,
    _check_provenance,
    _check_stats,
    _integer,
    _keys,
    _matrix,
    _model_and_linearisation,
    _number,
    _string,
    _vector,
    load_colour_file,
)
from camcal.colour.linearise import Linearisation
from camcal.colour.models import LinearTermsModel, expand, model_from_dict, parse_model_spec
from camcal.colour.spectral import adapt_XYZ
from camcal.errors import CamcalError
from camcal.io.atomic import atomic_path

__all__ = [
    "MATCH_MODELS",
    "ROBUST_METHODS",
    "REC709_SPACE",
    "rec709_XYZ",
    "Lut3DModel",
    "ColourMatch",
    "RobustFit",
    "Correspondences",
    "MatchResult",
    "parse_match_model",
    "fit_match_model",
    "stereo_correspondences",
    "match_images",
    "match_charts",
    "match_image_files",
    "match_patch_files",
    "write_match_report",
    "load_match",
]

MATCH_MODELS = ("matrix3x3", "polynomial", "root-polynomial", "lut3d")
ROBUST_METHODS = ("lmeds-irls", "irls", "none")
REC709_SPACE = "target RGB as linear Rec. 709 primaries, D65 white"
LUT_SIZE = 17
LUT_SMOOTHING = 1e-3
_TUKEY_C = 4.685           # biweight tuning constant (95 % efficiency for Gaussian noise)
_CHI3_MEDIAN = 1.5382      # median of the norm of a 3-vector of unit Gaussians
_RELATIVE_FLOOR = 0.02     # relative residuals use max(mean(A), this) as the scale


# --------------------------------------------------------------------------
# 3D LUT model


def _trilinear(RGB: np.ndarray, size: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lattice node indices ``(N, 8)`` and trilinear weights ``(N, 8)`` of inputs ``(N, 3)``.

    Inputs are clamped to the box ``[lo, hi]``; nodes are numbered with the
    red index slowest: ``(i size + j) size + k``.
    """
    t = np.clip((RGB - lo) / (hi - lo), 0.0, 1.0) * (size - 1)
    base = np.minimum(np.floor(t).astype(np.int64), size - 2)
    frac = t - base
    index = np.empty((RGB.shape[0], 8), dtype=np.int64)
    weight = np.empty((RGB.shape[0], 8))
    for corner in range(8):
        d = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        node = base + d
        index[:, corner] = (node[:, 0] * size + node[:, 1]) * size + node[:, 2]
        weight[:, corner] = np.prod(np.where(d == 1, frac, 1.0 - frac), axis=1)
    return index, weight


@dataclass(frozen=True, eq=False)
class Lut3DModel:
    """A 3D lookup table from linear source RGB to linear target RGB.

    Attributes
    ----------
    table
        ``(size, size, size, 3)`` outputs at the nodes, indexed ``[r, g, b]``.
    domain_min, domain_max
        ``(3,)`` the input box the nodes span; inputs outside are clamped.
    smoothing
        The relative second-difference penalty it was fitted with.

    Notes
    -----
    ``f(x) = sum_c w_c(x) T[n_c]`` over the 8 nodes ``n_c`` of the cell
    holding ``x``, with trilinear weights ``w_c`` (the interpolation
    OpenColorIO's Lut3DTransform uses with ``INTERP_LINEAR``).
    """

    table: np.ndarray
    domain_min: np.ndarray
    domain_max: np.ndarray
    smoothing: float = LUT_SMOOTHING

    kind = "lut3d"

    def __post_init__(self) -> None:
        for name in ("table", "domain_min", "domain_max"):
            value = np.array(getattr(self, name), dtype=np.float64)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        n = self.table.shape[0]
        if n < 2 or self.table.shape != (n, n, n, 3):
            raise CamcalError(f"a 3D LUT table must have shape (N, N, N, 3) with N >= 2, got {self.table.shape}")
        if self.domain_min.shape != (3,) or self.domain_max.shape != (3,) or np.any(self.domain_max <= self.domain_min):
            raise CamcalError("a 3D LUT domain needs domain_min < domain_max, three values each")

    @property
    def size(self) -> int:
        return int(self.table.shape[0])

    @property
    def label(self) -> str:
        return f"lut3d:{self.size}"

    def apply(self, RGB: Any) -> np.ndarray:
        """Map linear source RGB ``(..., 3)`` to linear target RGB ``(..., 3)``."""
        RGB = np.asarray(RGB, dtype=np.float64)
        if RGB.shape[-1:] != (3,):
            raise CamcalError(f"camera RGB must have shape (N, 3), got {RGB.shape}")
        flat = RGB.reshape(-1, 3)
        index, weight = _trilinear(flat, self.size, self.domain_min, self.domain_max)
        out = np.einsum("nc,nck->nk", weight, self.table.reshape(-1, 3)[index])
        return out.reshape(RGB.shape)

    def to_dict(self) -> dict:
        return {
            "kind": "lut3d",
            "size": self.size,
            "domain_min": [float(v) for v in self.domain_min],
            "domain_max": [float(v) for v in self.domain_max],
            "smoothing": float(self.smoothing),
            "table": [[float(v) for v in row] for row in self.table.reshape(-1, 3)],
        }


MatchModel = LinearTermsModel | Lut3DModel


def parse_match_model(text: str) -> tuple[str, int | None]:
    """Parse a match model name: ``matrix3x3``, ``root-polynomial[:D]``, ``polynomial[:N]``, ``lut3d[:N]``.

    Returns
    -------
    kind, order
        ``order`` is the degree, the number of Cheung terms or the LUT size
        (``None`` for ``matrix3x3``).

    Examples
    --------
    >>> parse_match_model("lut3d")
    ('lut3d', 17)
    >>> parse_match_model("root-polynomial:2")
    ('root-polynomial', 2)
    """
    text = str(text).strip()
    kind, _, order = text.partition(":")
    if kind == "lut3d":
        try:
            size = int(order) if order else LUT_SIZE
        except ValueError:
            raise CamcalError(f"malformed LUT size in {text!r}, expected an integer") from None
        if not 3 <= size <= 65:
            raise CamcalError(f"a 3D LUT size must be between 3 and 65, got {size}")
        return "lut3d", size
    if kind not in MATCH_MODELS:
        raise CamcalError(f"unknown match model {text!r}, expected one of: matrix3x3, root-polynomial:D, "
                          "polynomial:N, lut3d[:N]")
    if "white-preserving" in text or "wp" in text.split(":"):
        raise CamcalError(f"match models cannot be white preserving, got {text!r}")
    spec = parse_model_spec(text)
    return spec.kind, spec.order


# --------------------------------------------------------------------------
# Fitting: weighted least squares per model, made robust by IRLS


def _second_differences(size: int):
    """Sparse second differences along each axis of a ``size^3`` lattice (red slowest)."""
    import scipy.sparse as sp

    eye = sp.identity(size, format="csr")
    d1 = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(size - 2, size), format="csr")
    return sp.vstack([sp.kron(sp.kron(d1, eye), eye), sp.kron(sp.kron(eye, d1), eye),
                      sp.kron(sp.kron(eye, eye), d1)]).tocsr()


@dataclass(frozen=True)
class _Design:
    """What a weighted fit needs besides the weights: the model's design."""

    kind: str
    terms: tuple[str, ...] | None
    X: Any                  # (N, T) dense terms or (N, size^3) sparse trilinear weights
    size: int | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    smoothing: float = LUT_SMOOTHING


def _design(kind: str, order: int | None, B: np.ndarray, smoothing: float) -> _Design:
    if kind != "lut3d":
        terms = parse_model_spec(kind if order is None else f"{kind}:{order}").terms()
        return _Design(kind, terms, expand(B, terms))
    import scipy.sparse as sp

    size = int(order or LUT_SIZE)
    lo = np.minimum(B.min(axis=0), 0.0)
    hi = np.max(B, axis=0) * 1.02
    hi = np.where(hi > lo, hi, lo + 1.0)
    index, weight = _trilinear(B, size, lo, hi)
    rows = np.repeat(np.arange(B.shape[0]), 8)
    X = sp.csr_matrix((weight.ravel(), (rows, index.ravel())), shape=(B.shape[0], size**3))
    return _Design("lut3d", None, X, size, lo, hi, float(smoothing))


def _solve(design: _Design, A: np.ndarray, w: np.ndarray, start: MatchModel | None = None) -> MatchModel:
    """Weighted least squares ``min sum_i w_i |f(B_i) - A_i|^2`` (+ smoothness for a LUT).

    A LUT's normal equations are solved by Jacobi-preconditioned conjugate
    gradients, warm-started from ``start`` (the previous IRLS step).
    """
    if design.kind != "lut3d":
        sw = np.sqrt(w)[:, None]
        M = np.linalg.lstsq(design.X * sw, A * sw, rcond=None)[0].T
        return LinearTermsModel(design.kind, design.terms, M)
    import scipy.sparse as sp
    from scipy.sparse.linalg import cg

    X = design.X
    normal = (X.T @ sp.diags(w) @ X).tocsr()
    D = _second_differences(design.size)
    DtD = (D.T @ D).tocsr()
    lam = design.smoothing * normal.diagonal().sum() / DtD.diagonal().sum()
    system = (normal + lam * DtD).tocsr()
    rhs = np.asarray(X.T @ (A * w[:, None]))
    diagonal = system.diagonal()
    preconditioner = sp.diags(1.0 / np.where(diagonal > 0, diagonal, 1.0))
    x0 = None if start is None else start.table.reshape(-1, 3)
    columns = []
    for k in range(3):
        solution, info = cg(system, rhs[:, k], x0=None if x0 is None else x0[:, k], rtol=1e-10,
                            maxiter=5000, M=preconditioner)
        if info != 0:
            raise CamcalError("3D LUT fit did not converge (too little data or too little smoothing)")
        columns.append(solution)
    size = design.size
    table = np.stack(columns, axis=1).reshape(size, size, size, 3)
    return Lut3DModel(table, design.lo, design.hi, design.smoothing)


def _predict(design: _Design, model: MatchModel) -> np.ndarray:
    if design.kind != "lut3d":
        return design.X @ model.M.T
    return np.asarray(design.X @ model.table.reshape(-1, 3))


def _relative_scale(A: np.ndarray) -> np.ndarray:
    return np.maximum(A.mean(axis=1), _RELATIVE_FLOOR)


def _lmeds_matrix(B: np.ndarray, A: np.ndarray, s: np.ndarray, trials: int, rng: np.random.Generator) -> np.ndarray:
    """Relative residuals of the least-median-of-squares 3x3 matrix (random 4-sample fits)."""
    N = B.shape[0]
    picks = rng.integers(0, N, size=(trials, 4))
    check = rng.choice(N, size=min(N, 4000), replace=False)
    best, best_median = None, np.inf
    for pick in picks:
        M = np.linalg.lstsq(B[pick], A[pick], rcond=None)[0]
        median = np.median(np.linalg.norm(B[check] @ M - A[check], axis=1) / s[check])
        if median < best_median:
            best, best_median = M, median
    return np.linalg.norm(B @ best - A, axis=1) / s


@dataclass(frozen=True, eq=False)
class RobustFit:
    """A fitted match model and how the robust fit weighed the data.

    Attributes
    ----------
    model
        :class:`~camcal.colour.models.LinearTermsModel` or :class:`Lut3DModel`.
    weights
        ``(N,)`` final robust weights in [0, 1] (1 everywhere for ``none``).
    inliers
        ``(N,)`` samples whose relative residual is below ``threshold``.
    residuals
        ``(N,)`` relative residuals ``|f(B) - A| / max(mean(A), 0.02)``.
    sigma
        Robust scale of the relative residuals (per channel).
    threshold
        ``4.685 sigma``: the biweight's cut-off (``None`` for ``none``).
    robust
        The method used; ``iterations`` the IRLS steps taken.
    """

    model: Any
    weights: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    sigma: float
    threshold: float | None
    robust: str
    iterations: int

    def is_inlier(self, B: Any, A: Any) -> np.ndarray:
        """Classify new pairs by the fit's threshold (all True for ``none``)."""
        B = np.asarray(B, dtype=np.float64)
        A = np.asarray(A, dtype=np.float64)
        if self.threshold is None:
            return np.ones(B.shape[0], dtype=bool)
        return np.linalg.norm(self.model.apply(B) - A, axis=1) / _relative_scale(A) < self.threshold


def fit_match_model(
    RGB_source: Any,
    RGB_target: Any,
    model: str = "matrix3x3",
    *,
    robust: str = "lmeds-irls",
    smoothing: float = LUT_SMOOTHING,
    max_iterations: int = 50,
    trials: int = 300,
    seed: int = 0,
) -> RobustFit:
    """Fit ``RGB_target ≈ f(RGB_source)``, optionally robust to outliers.

    Parameters
    ----------
    RGB_source, RGB_target
        ``(N, 3)`` linear RGB of the same surfaces seen by camera B (source)
        and camera A (target).
    model
        ``matrix3x3``, ``root-polynomial[:D]``, ``polynomial[:N]`` or
        ``lut3d[:N]`` (see :func:`parse_match_model`).
    robust
        ``"lmeds-irls"``: a least-median-of-squares 3x3 matrix from random
        4-sample fits starts iteratively reweighted least squares (IRLS) with
        Tukey's biweight; ``"irls"``: IRLS started from the least-squares
        fit; ``"none"``: weighted least squares only.
    smoothing
        ``lut3d``: weight of the second-difference penalty, relative to the
        data term (``lambda = smoothing trace(X^T W X) / trace(D^T D)``).
    max_iterations, trials, seed
        IRLS steps, LMedS samples, random seed.

    Returns
    -------
    RobustFit

    Notes
    -----
    A ``lut3d`` fit starts from the weights of a robust ``root-polynomial:2``
    fit. Noise is taken as proportional to the signal, so sample ``i`` carries
    the base weight ``1 / s_i^2`` with ``s_i = max(mean(A_i), 0.02)``, and
    its relative residual is ``r_i = |f(B_i) - A_i| / s_i``. Each IRLS step
    estimates the per-channel scale ``sigma = median(r) / 1.5382`` (the
    median of the norm of three unit Gaussians), gives weights
    ``w_i = (1 - (r_i / c)^2)^2`` for ``r_i < c = 4.685 sigma`` and 0
    beyond (Tukey's biweight), and solves the weighted least squares
    ``min sum_i w_i |f(B_i) - A_i|^2 / s_i^2`` (closed form for the linear
    models; a sparse linear system for the LUT, with the smoothness
    penalty), until the weights change by less than 1e-4 on average.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> B = rng.uniform(0.05, 0.9, (500, 3))
    >>> A = B @ np.diag([1.1, 1.0, 0.9])
    >>> A[:50] += 0.3                      # 10 % speculars
    >>> fit = fit_match_model(B, A, "matrix3x3")
    >>> np.round(np.diag(fit.model.M), 6).tolist(), int((~fit.inliers).sum())
    ([1.1, 1.0, 0.9], 50)
    """
    B = np.asarray(RGB_source, dtype=np.float64)
    A = np.asarray(RGB_target, dtype=np.float64)
    if B.ndim != 2 or B.shape[1] != 3 or A.shape != B.shape:
        raise CamcalError(f"source and target RGB must both be (N, 3), got {B.shape} and {A.shape}")
    keep = np.all(np.isfinite(B), axis=1) & np.all(np.isfinite(A), axis=1)
    if not np.all(keep):
        raise CamcalError(f"source and target RGB contain {int(np.sum(~keep))} non-finite samples")
    if robust not in ROBUST_METHODS:
        raise CamcalError(f"unknown robust method {robust!r}, expected one of: {', '.join(ROBUST_METHODS)}")
    if not (np.isfinite(smoothing) and smoothing > 0):
        raise CamcalError(f"LUT smoothing must be a positive number, got {smoothing}")
    kind, order = parse_match_model(model)
    design = _design(kind, order, B, smoothing)
    n_params = 4 if kind == "lut3d" else len(design.terms)
    if B.shape[0] < max(n_params, 4) * (3 if robust != "none" else 1):
        raise CamcalError(f"a {model} match needs at least {max(n_params, 4) * (3 if robust != 'none' else 1)} "
                          f"samples, got {B.shape[0]}")
    s = _relative_scale(A)
    base = 1.0 / s**2
    rng = np.random.default_rng(seed)

    def residuals(m: MatchModel) -> np.ndarray:
        return np.linalg.norm(_predict(design, m) - A, axis=1) / s

    if robust == "none":
        fitted = _solve(design, A, base)
        r = residuals(fitted)
        return RobustFit(fitted, np.ones(B.shape[0]), np.ones(B.shape[0], dtype=bool), r,
                         float(np.median(r) / _CHI3_MEDIAN), None, robust, 0)
    fitted = None
    if kind == "lut3d":
        # Stage 1: the robust root-polynomial fit gives the LUT's starting weights.
        r = fit_match_model(B, A, "root-polynomial:2", robust=robust, max_iterations=max_iterations,
                            trials=trials, seed=seed).residuals
    elif robust == "lmeds-irls":
        r = _lmeds_matrix(B, A, s, trials, rng)
    else:
        fitted = _solve(design, A, base)
        r = residuals(fitted)
    weights = np.ones(B.shape[0])
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        sigma = max(float(np.median(r)) / _CHI3_MEDIAN, 1e-12)
        u = r / (_TUKEY_C * sigma)
        new = np.where(u < 1.0, (1.0 - u**2) ** 2, 0.0)
        if np.count_nonzero(new) < n_params:
            raise CamcalError("robust fit lost its data: fewer inliers than model parameters")
        change = float(np.mean(np.abs(new - weights)))
        weights = new
        if fitted is not None and change < 1e-4:
            break
        fitted = _solve(design, A, base * weights, fitted)
        r = residuals(fitted)
    sigma = max(float(np.median(r)) / _CHI3_MEDIAN, 1e-12)
    threshold = _TUKEY_C * sigma
    return RobustFit(fitted, weights, r < threshold, r, sigma, threshold, robust, iteration)


# --------------------------------------------------------------------------
# The match file


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _provenance(source: str | None) -> dict:
    from camcal import __version__

    out = {"tool": f"camcal {__version__}", "created": _now()}
    if source:
        out["source"] = str(source)
    return out


def _check_match(data: dict) -> None:
    _keys(data, "colour match", ("format", "version", "kind", "source", "target", "linearisation", "model",
                                 "fit", "evaluation", "provenance"))
    _string(data["source"], "source", nullable=True)
    _string(data["target"], "target", nullable=True)
    _check_linearisation(data["linearisation"])
    model = data["model"]
    kind = _string(_keys(model, "model", ("kind",), ("terms", "coefficients", "size", "domain_min", "domain_max",
                                                     "smoothing", "table"))["kind"], "model.kind", MATCH_MODELS)
    if kind == "lut3d":
        _keys(model, "model", ("kind", "size", "domain_min", "domain_max", "smoothing", "table"))
        size = _integer(model["size"], "model.size", 2)
        _vector(model["domain_min"], "model.domain_min", 3)
        _vector(model["domain_max"], "model.domain_max", 3)
        _number(model["smoothing"], "model.smoothing", 0.0)
        _matrix(model["table"], "model.table", size**3, 3)
    else:
        _keys(model, "model", ("kind", "terms", "coefficients"))
        terms = model["terms"]
        if not isinstance(terms, list) or not terms:
            raise CamcalError(f"model.terms: expected a non-empty list of term strings, got {terms!r}")
        for i, term in enumerate(terms):
            _string(term, f"model.terms[{i}]")
        _matrix(model["coefficients"], "model.coefficients", 3, len(terms))
    fit = _keys(data["fit"], "fit", ("route", "robust", "n_fit", "n_inliers", "inlier_threshold"))
    _string(fit["route"], "fit.route", ("chart", "image"))
    _string(fit["robust"], "fit.robust", ROBUST_METHODS)
    _integer(fit["n_fit"], "fit.n_fit", 1)
    _integer(fit["n_inliers"], "fit.n_inliers", 0)
    if fit["inlier_threshold"] is not None:
        _number(fit["inlier_threshold"], "fit.inlier_threshold", 0.0)
    evaluation = _keys(data["evaluation"], "evaluation", ("metric", "space", "train", "test", "before",
                                                          "n_test_outliers", "chart"))
    _string(evaluation["metric"], "evaluation.metric", ("CIE 2000",))
    _string(evaluation["space"], "evaluation.space")
    _check_stats(evaluation["train"], "evaluation.train", nullable=False)
    _check_stats(evaluation["test"], "evaluation.test")
    _check_stats(evaluation["before"], "evaluation.before")
    if evaluation["n_test_outliers"] is not None:
        _integer(evaluation["n_test_outliers"], "evaluation.n_test_outliers", 0)
    chart = evaluation["chart"]
    if chart is not None:
        _keys(chart, "evaluation.chart", ("common_reference", "source_vs_reference", "target_vs_reference"))
        _check_stats(chart["common_reference"], "evaluation.chart.common_reference", nullable=False)
        _check_stats(chart["source_vs_reference"], "evaluation.chart.source_vs_reference")
        _check_stats(chart["target_vs_reference"], "evaluation.chart.target_vs_reference")
    _check_provenance(data["provenance"])


def _model_from_block(block: dict) -> MatchModel:
    if block["kind"] == "lut3d":
        size = block["size"]
        return Lut3DModel(np.array(block["table"], dtype=np.float64).reshape(size, size, size, 3),
                          np.array(block["domain_min"]), np.array(block["domain_max"]), float(block["smoothing"]))
    return model_from_dict({**block, "white_preserving": False, "objective": "xyz", "regularisation": 0.0})


@dataclass(frozen=True, eq=False)
class ColourMatch(LinearisedModel):
    """A camera-to-camera colour match: linear source (B) RGB -> linear target (A) RGB.

    ``apply(RGB)`` maps LINEAR camera-B RGB ``(N, 3)`` to camera-A RGB;
    ``linearise(codes)`` turns camera-B code values into linear RGB;
    ``apply_codes`` chains both. ``matrix`` is the exact 3x3 matrix of a
    ``matrix3x3`` match (``A = matrix @ B``), ``None`` for other models.
    ``fit``, ``evaluation`` and ``provenance`` are the file's plain
    dictionaries (see the module docstring).
    """

    model: Any
    evaluation: dict
    fit: dict
    source: str | None = None
    target: str | None = None
    linearisation: Linearisation = field(default_factory=Linearisation.identity)
    provenance: dict = field(default_factory=dict)

    kind = "match"

    @property
    def matrix(self) -> np.ndarray | None:
        """The 3x3 matrix of a matrix3x3 match (rows R, G, B of the target), else ``None``."""
        if self.model.kind != "matrix3x3":
            return None
        return np.array(self.model.M)

    def to_dict(self) -> dict:
        """The file's JSON object."""
        model = self.model.to_dict()
        if model["kind"] != "lut3d":
            model = {key: model[key] for key in ("kind", "terms", "coefficients")}
        return {
            "format": "camcal.colour",
            "version": 1,
            "kind": "match",
            "source": self.source,
            "target": self.target,
            "linearisation": self.linearisation.to_dict(),
            "model": model,
            "fit": self.fit,
            "evaluation": self.evaluation,
            "provenance": dict(self.provenance) or _provenance(None),
        }

    @classmethod
    def from_dict(cls, data: dict) -> ColourMatch:
        """Validate a file's JSON object and build the match (errors name the field)."""
        _check_header(data, "match")
        _check_match(data)
        model, linearisation = _model_and_linearisation(data, _model_from_block)
        return cls(model=model, evaluation=data["evaluation"], fit=data["fit"], source=data["source"],
                   target=data["target"], linearisation=linearisation, provenance=dict(data["provenance"]))

    def summary(self) -> str:
        """A few human lines: which way, model, fit, CIEDE2000."""
        ev = self.evaluation
        lines = [f"match {self.source or 'B'} -> {self.target or 'A'}: {self.model.label} "
                 f"({self.fit['route']} route, robust {self.fit['robust']}, "
                 f"{self.fit['n_inliers']} / {self.fit['n_fit']} samples kept)"]
        if ev["chart"] is not None:
            lines.append(f"CIEDE2000 camera-to-camera via XYZ: {DeltaEStats(**ev['chart']['common_reference'])}")
            for key, name in (("source_vs_reference", self.source or "B"), ("target_vs_reference", self.target or "A")):
                if ev["chart"][key] is not None:
                    lines.append(f"CIEDE2000 {name} vs reference: {DeltaEStats(**ev['chart'][key])}")
        for key, name in (("before", "before matching"), ("train", "after, fit data"), ("test", "after, held out")):
            if ev[key] is not None:
                lines.append(f"CIEDE2000 {name}: {DeltaEStats(**ev[key])}")
        if ev["n_test_outliers"] is not None:
            lines.append(f"held-out outliers (beyond the fit's threshold): {ev['n_test_outliers']}")
        return "\n".join(lines)


KIND_READERS["match"] = ColourMatch.from_dict


def load_match(path: str | os.PathLike) -> ColourMatch:
    """Load and validate a ``*.colour.json`` of kind ``match``.

    Raises
    ------
    CamcalError
        ``"<path>: <field>: <what is wrong>"`` for a bad file.
    """
    return load_colour_file(path, "match")


# --------------------------------------------------------------------------
# Colour differences in the target camera's space


def rec709_XYZ(RGB: Any) -> np.ndarray:
    """XYZ (white Y = 1, D65) of RGB read as linear Rec. 709 / sRGB primaries, ``(..., 3)``.

    The Delta E space of a match when the target camera has no
    characterisation (see :data:`REC709_SPACE`).
    """
    import colour

    return np.asarray(RGB, dtype=np.float64) @ colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ.T


def _target_space(fit_target: ColourFit | None):
    """``(to_XYZ, white_XYZ, description)`` for Delta E of target-camera RGB."""
    if fit_target is None:
        import colour

        white = colour.xy_to_XYZ(colour.RGB_COLOURSPACES["sRGB"].whitepoint)
        return rec709_XYZ, np.asarray(white, dtype=np.float64), REC709_SPACE
    name = fit_target.camera or "target"
    return fit_target.apply, np.asarray(fit_target.target_white_XYZ), f"XYZ through the characterisation of {name}"


def _stats(values: np.ndarray) -> dict | None:
    return None if values.size == 0 else DeltaEStats.from_values(values).to_dict()


# --------------------------------------------------------------------------
# Image route


@dataclass(frozen=True, eq=False)
class Correspondences:
    """Dense correspondences of a rectified pair, on camera A's pixel grid.

    Attributes
    ----------
    disparity
        ``(H, W)`` disparity in pixels (NaN where SGBM gave none): camera B
        sees A's pixel ``(x, y)`` at ``(x - d, y)`` when A is the left view,
        ``(x + d, y)`` when A is the right one.
    valid
        ``(H, W)`` pixels kept: disparity found and left-right consistent,
        away from depth edges, both colours unsaturated and above the floor.
    source
        ``(H, W, 3)`` camera B's linear RGB sampled at the correspondences
        (bilinear, after the blur; NaN where no disparity).
    target
        ``(H, W, 3)`` camera A's linear RGB after the same blur.
    a_is_left
        Which view camera A is.
    counts
        Pixels of A's image: ``total``, ``disparity`` (SGBM found one),
        ``consistent`` (left-right check passed), ``smooth`` (away from depth
        edges), ``valid`` (also unsaturated, above the dark floor).
    """

    disparity: np.ndarray
    valid: np.ndarray
    source: np.ndarray
    target: np.ndarray
    a_is_left: bool
    counts: dict


def _grey8(RGB: np.ndarray) -> np.ndarray:
    """8-bit grey for matching: luminance, normalised to its 1-99 % range, gamma 1/2.2."""
    Y = np.nan_to_num(RGB @ np.array([0.2126, 0.7152, 0.0722]))
    lo, hi = np.percentile(Y, [1, 99])
    t = np.clip((Y - lo) / max(hi - lo, 1e-12), 0, 1) ** (1 / 2.2)
    return np.round(255 * t).astype(np.uint8)


def _sgbm(left: np.ndarray, right: np.ndarray, num_disparities: int, block_size: int) -> np.ndarray:
    import cv2

    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=num_disparities, blockSize=block_size,
        P1=8 * block_size**2, P2=32 * block_size**2, disp12MaxDiff=-1,
        uniquenessRatio=10, speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    raw = matcher.compute(left, right).astype(np.float64)
    return np.where(raw >= 0, raw / 16.0, np.nan)


def _disparities(gA: np.ndarray, gB: np.ndarray, a_is_left: bool, n: int, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Disparity on A's grid and on B's grid (both positive)."""
    if a_is_left:
        return _sgbm(gA, gB, n, block), _sgbm(gB[:, ::-1].copy(), gA[:, ::-1].copy(), n, block)[:, ::-1]
    return _sgbm(gA[:, ::-1].copy(), gB[:, ::-1].copy(), n, block)[:, ::-1], _sgbm(gB, gA, n, block)


def _lr_consistent(dA: np.ndarray, dB: np.ndarray, a_is_left: bool, tolerance: float) -> np.ndarray:
    height, width = dA.shape
    x = np.arange(width)[None, :]
    xb = np.round(x + (-1 if a_is_left else 1) * np.nan_to_num(dA, nan=0.0)).astype(np.int64)
    inside = (xb >= 0) & (xb < width)
    back = np.take_along_axis(dB, np.clip(xb, 0, width - 1), axis=1)
    with np.errstate(invalid="ignore"):
        return inside & np.isfinite(dA) & (np.abs(back - dA) <= tolerance)


def stereo_correspondences(
    RGB_A: Any,
    RGB_B: Any,
    *,
    a_is_left: bool | None = None,
    num_disparities: int | None = None,
    block_size: int = 5,
    lr_tolerance: float = 1.0,
    edge_px: float = 1.0,
    saturation: float = 0.98,
    dark: float = 0.005,
    blur_sigma: float = 1.0,
) -> Correspondences:
    """Dense, checked correspondences of a rectified stereo pair (SGBM both ways).

    Parameters
    ----------
    RGB_A, RGB_B
        ``(H, W, 3)`` LINEAR RGB of the rectified views of cameras A and B
        (same size, rows aligned).
    a_is_left
        Whether A is the left view; ``None`` tries both and keeps the one
        with more left-right consistent pixels.
    num_disparities
        SGBM search range (a multiple of 16); default: width / 8 rounded up.
    block_size
        SGBM block size (odd).
    lr_tolerance
        Largest difference in pixels between the disparity of a pixel of A
        and that of its match in B (left-right consistency).
    edge_px
        Drop pixels whose 5x5 neighbourhood spans more than this disparity
        range (depth edges, where occlusions and mixed pixels are).
    saturation
        Drop pixels with a channel at or above this fraction of the image's
        maximum in either view (clipped highlights).
    dark
        Drop pixels whose brightest channel is below this fraction of the
        image's maximum in either view (noise floor, black borders).
    blur_sigma
        Gaussian blur (pixels) of both images before sampling colours: it
        reduces the colour error of sub-pixel misregistration on texture;
        blurring commutes with a matrix match.

    Returns
    -------
    Correspondences
    """
    import cv2

    A = np.asarray(RGB_A, dtype=np.float64)
    B = np.asarray(RGB_B, dtype=np.float64)
    if A.ndim != 3 or A.shape[2] != 3 or B.shape != A.shape:
        raise CamcalError(f"a stereo pair needs two (H, W, 3) images of one size, got {A.shape} and {B.shape}")
    height, width = A.shape[:2]
    if width < 32 or height < 16:
        raise CamcalError(f"images too small for stereo matching: {width}x{height} px")
    if num_disparities is None:
        num_disparities = int(16 * np.ceil(width / 8 / 16))
    if num_disparities % 16 or num_disparities <= 0 or num_disparities >= width:
        raise CamcalError(f"num_disparities must be a positive multiple of 16 below the width, got {num_disparities}")
    if block_size % 2 == 0 or not 1 <= block_size <= 21:
        raise CamcalError(f"block_size must be odd, 1 to 21, got {block_size}")
    gA, gB = _grey8(A), _grey8(B)
    if a_is_left is None:
        scores = {}
        for left in (True, False):
            dA, dB = _disparities(gA, gB, left, num_disparities, block_size)
            scores[left] = (int(_lr_consistent(dA, dB, left, lr_tolerance).sum()), dA, dB)
        a_is_left = scores[True][0] >= scores[False][0]
        dA, dB = scores[a_is_left][1:]
    else:
        dA, dB = _disparities(gA, gB, a_is_left, num_disparities, block_size)
    consistent = _lr_consistent(dA, dB, a_is_left, lr_tolerance)
    d = np.where(consistent, dA, np.nan)
    filled = np.nan_to_num(d, nan=-1e3).astype(np.float32)
    kernel = np.ones((5, 5), np.uint8)
    span = cv2.dilate(filled, kernel) - cv2.erode(filled, kernel)
    smooth = consistent & (span <= edge_px)

    def blurred(image: np.ndarray) -> np.ndarray:
        image = image.astype(np.float32)
        return cv2.GaussianBlur(image, (0, 0), blur_sigma) if blur_sigma > 0 else image

    map_x = (np.arange(width)[None, :] + (-1 if a_is_left else 1) * np.nan_to_num(d, nan=-1e4)).astype(np.float32)
    map_y = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
    source = cv2.remap(blurred(B), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(np.nan, np.nan, np.nan)).astype(np.float64)
    target = blurred(A).astype(np.float64)
    peak = max(float(np.nanmax(A)), float(np.nanmax(B)), 1e-12)
    raw_B = cv2.remap(B.astype(np.float32), map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=(0, 0, 0)).astype(np.float64)
    exposed = ((A.max(axis=2) < saturation * peak) & (raw_B.max(axis=2) < saturation * peak)
               & (A.max(axis=2) > dark * peak) & (raw_B.max(axis=2) > dark * peak))
    valid = smooth & exposed & np.all(np.isfinite(source), axis=2) & np.all(np.isfinite(target), axis=2)
    source[~np.isfinite(d)] = np.nan
    counts = {"total": int(height * width), "disparity": int(np.isfinite(dA).sum()),
              "consistent": int(consistent.sum()), "smooth": int(smooth.sum()), "valid": int(valid.sum())}
    return Correspondences(d, valid, source, target, bool(a_is_left), counts)


@dataclass(frozen=True, eq=False)
class MatchResult:
    """A fitted match with the data behind its figures.

    Attributes
    ----------
    match
        The :class:`ColourMatch` (what the file holds).
    fit
        The :class:`RobustFit` on the training samples.
    train_source, train_target
        ``(N, 3)`` training samples (linear B and A RGB).
    test_source, test_target
        ``(M, 3)`` held-out samples (image tiles or independent patches),
        or ``None``.
    test_inliers
        ``(M,)`` held-out samples within the fit's threshold, or ``None``.
    correspondences
        Image route: the :class:`Correspondences`; ``None`` for charts.
    fit_target
        Camera A's characterisation used for Delta E, or ``None``.
    """

    match: ColourMatch
    fit: RobustFit
    train_source: np.ndarray
    train_target: np.ndarray
    test_source: np.ndarray | None = None
    test_target: np.ndarray | None = None
    test_inliers: np.ndarray | None = None
    correspondences: Correspondences | None = None
    fit_target: ColourFit | None = None


def _tile_split(shape: tuple[int, int], tile: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean ``(H, W)``: pixels of the randomly held-out ``tile`` x ``tile`` tiles."""
    height, width = shape
    rows, cols = -(-height // tile), -(-width // tile)
    held = rng.random((rows, cols)) < fraction
    return np.repeat(np.repeat(held, tile, axis=0), tile, axis=1)[:height, :width]


def match_images(
    RGB_A: Any,
    RGB_B: Any,
    *,
    model: str = "matrix3x3",
    robust: str = "lmeds-irls",
    a_is_left: bool | None = None,
    fit_target: ColourFit | None = None,
    source: str | None = None,
    target: str | None = None,
    linearisation: Linearisation | None = None,
    test_fraction: float = 0.25,
    tile_px: int = 16,
    max_samples: int = 40000,
    smoothing: float = LUT_SMOOTHING,
    seed: int = 0,
    provenance_source: str | None = None,
    **stereo: Any,
) -> MatchResult:
    """Fit a camera B -> camera A colour match from a rectified stereo pair.

    Parameters
    ----------
    RGB_A, RGB_B
        ``(H, W, 3)`` LINEAR RGB of the rectified views of A (target) and B
        (source).
    model, robust, smoothing
        See :func:`fit_match_model`.
    a_is_left
        Whether A is the left view (``None``: found from the data).
    fit_target
        Camera A's characterisation, for Delta E in XYZ; ``None`` reads A's
        RGB as linear Rec. 709 (see the module docstring).
    source, target
        Camera names recorded in the file.
    linearisation
        Camera B's code-value linearisation recorded in the file (identity
        when ``None``).
    test_fraction, tile_px
        Share of ``tile_px`` square image tiles held out from the fit.
    max_samples
        At most this many training pixels (a random subset) enter the fit.
    seed
        Random seed (split, subset, LMedS).
    **stereo
        Options of :func:`stereo_correspondences`.

    Returns
    -------
    MatchResult
    """
    if not 0.0 < test_fraction < 1.0:
        raise CamcalError(f"test_fraction must be between 0 and 1, got {test_fraction}")
    corr = stereo_correspondences(RGB_A, RGB_B, a_is_left=a_is_left, **stereo)
    rng = np.random.default_rng(seed)
    held = _tile_split(corr.valid.shape, tile_px, test_fraction, rng)
    train_idx = np.flatnonzero(corr.valid & ~held)
    test_idx = np.flatnonzero(corr.valid & held)
    need = 200
    if train_idx.size < need or test_idx.size < 20:
        raise CamcalError(f"too few reliable correspondences: {corr.counts['valid']} of {corr.counts['total']} "
                          f"pixels (disparity {corr.counts['disparity']}, left-right consistent "
                          f"{corr.counts['consistent']}); need {need} for the fit")
    if train_idx.size > max_samples:
        train_idx = np.sort(rng.choice(train_idx, max_samples, replace=False))
    src = corr.source.reshape(-1, 3)
    tgt = corr.target.reshape(-1, 3)
    fit = fit_match_model(src[train_idx], tgt[train_idx], model, robust=robust, smoothing=smoothing, seed=seed)
    to_XYZ, white, space = _target_space(fit_target)
    test_B, test_A = src[test_idx], tgt[test_idx]
    inliers = fit.is_inlier(test_B, test_A)
    train_B, train_A = src[train_idx], tgt[train_idx]
    train_keep = fit.inliers

    def dE(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
        return delta_E(to_XYZ(pred), to_XYZ(ref), white)

    evaluation = {
        "metric": "CIE 2000",
        "space": space,
        "train": _stats(dE(fit.model.apply(train_B[train_keep]), train_A[train_keep])),
        "test": _stats(dE(fit.model.apply(test_B[inliers]), test_A[inliers])),
        "before": _stats(dE(test_B[inliers], test_A[inliers])),
        "n_test_outliers": int(np.sum(~inliers)),
        "chart": None,
    }
    match = ColourMatch(
        model=fit.model, evaluation=evaluation,
        fit={"route": "image", "robust": robust, "n_fit": int(train_idx.size), "n_inliers": int(train_keep.sum()),
             "inlier_threshold": fit.threshold},
        source=source, target=target, linearisation=linearisation or Linearisation.identity(),
        provenance=_provenance(provenance_source),
    )
    return MatchResult(match, fit, train_B, train_A, test_B, test_A, inliers, corr, fit_target)


# --------------------------------------------------------------------------
# Chart route


def _invert(fit: ColourFit, XYZ: np.ndarray, start: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Linear RGB that ``fit`` maps to ``XYZ``: batched Newton steps, forward-difference Jacobians."""
    x = np.array(start, dtype=np.float64)
    h = 1e-6
    for _ in range(iterations):
        y = fit.apply(x)
        step = y - XYZ
        if np.max(np.abs(step)) < 1e-12:
            break
        J = np.stack([(fit.apply(x + h * np.eye(3)[k]) - y) / h for k in range(3)], axis=2)  # (N, 3, 3)
        x = x - np.linalg.solve(J, step[..., None])[..., 0]
    return x


def match_charts(
    fit_source: ColourFit,
    fit_target: ColourFit,
    codes_source: Any,
    codes_target: Any,
    *,
    XYZ_reference: Any = None,
    test: tuple[Any, Any] | None = None,
    model: str = "matrix3x3",
    robust: str = "none",
    source: str | None = None,
    target: str | None = None,
    provenance_source: str | None = None,
) -> MatchResult:
    """Match camera B to camera A through their characterisations on one chart.

    Parameters
    ----------
    fit_source, fit_target
        Characterisations of B (source) and A (target) on the same chart.
    codes_source, codes_target
        ``(N, 3)`` code values of the same N patches in B and in A (in each
        fit's encoding: its ``linearise`` is applied).
    XYZ_reference
        ``(N, 3)`` reference XYZ of the patches in A's target white, to
        report each camera's own characterisation error; optional.
    test
        ``(codes_source, codes_target)`` of independent patches, optional.
    model, robust
        The match model and fitting (see :func:`fit_match_model`).
    source, target
        Camera names (default: the fits' ``camera``).

    Returns
    -------
    MatchResult

    Notes
    -----
    Both cameras go to XYZ: ``X_A = fit_A(lin_A)``, ``X_B = fit_B(lin_B)``
    (adapted to A's target white with CAT02 when the whites differ). The
    camera-to-camera residual on the common reference is
    ``ΔE2000(X_A, X_B)``. The training target of the match is
    ``fit_A^-1(X_B)`` (batched Newton, started from ``lin_A``), so that
    ``fit_A(f(lin_B)) ≈ fit_B(lin_B)``; ``train`` / ``test`` report
    ``ΔE2000(fit_A(f(lin_B)), X_A)``, the camera-to-camera difference
    after matching, and ``before`` the same with ``f`` the identity.
    """
    to_XYZ, white, space = _target_space(fit_target)
    source_white = np.asarray(fit_source.target_white_XYZ)

    def prepare(codes_B: Any, codes_A: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lin_B = fit_source.linearise(np.asarray(codes_B, dtype=np.float64))
        lin_A = fit_target.linearise(np.asarray(codes_A, dtype=np.float64))
        if lin_B.ndim != 2 or lin_B.shape != lin_A.shape:
            raise CamcalError(f"source and target patches must both be (N, 3), got {lin_B.shape} and {lin_A.shape}")
        X_B = fit_source.apply(lin_B)
        if not np.allclose(source_white, white, atol=1e-6):
            X_B = adapt_XYZ(X_B, source_white, white, "CAT02")
        return lin_B, lin_A, X_B, to_XYZ(lin_A)

    lin_B, lin_A, X_B, X_A = prepare(codes_source, codes_target)
    goal = _invert(fit_target, X_B, lin_A)
    fit = fit_match_model(lin_B, goal, model, robust=robust)
    common = delta_E(X_B, X_A, white)
    chart = {"common_reference": DeltaEStats.from_values(common).to_dict(),
             "source_vs_reference": None, "target_vs_reference": None}
    if XYZ_reference is not None:
        ref = np.asarray(XYZ_reference, dtype=np.float64)
        if ref.shape != X_A.shape:
            raise CamcalError(f"reference XYZ must be {X_A.shape}, got {ref.shape}")
        chart["source_vs_reference"] = _stats(delta_E(X_B, ref, white))
        chart["target_vs_reference"] = _stats(delta_E(X_A, ref, white))
    test_B = test_A = None
    test_stats = None
    if test is not None:
        test_B, test_A, _, X_A_test = prepare(*test)
        test_stats = _stats(delta_E(to_XYZ(fit.model.apply(test_B)), X_A_test, white))
    before_B, before_A = (lin_B, lin_A) if test is None else (test_B, test_A)
    evaluation = {
        "metric": "CIE 2000",
        "space": space,
        "train": _stats(delta_E(to_XYZ(fit.model.apply(lin_B)), X_A, white)),
        "test": test_stats,
        "before": _stats(delta_E(to_XYZ(before_B), to_XYZ(before_A), white)),
        "n_test_outliers": None,
        "chart": chart,
    }
    match = ColourMatch(
        model=fit.model, evaluation=evaluation,
        fit={"route": "chart", "robust": robust, "n_fit": int(lin_B.shape[0]), "n_inliers": int(fit.inliers.sum()),
             "inlier_threshold": fit.threshold},
        source=source if source is not None else fit_source.camera,
        target=target if target is not None else fit_target.camera,
        linearisation=fit_source.linearisation, provenance=_provenance(provenance_source),
    )
    inliers = None if test_B is None else np.ones(test_B.shape[0], dtype=bool)
    return MatchResult(match, fit, lin_B, lin_A, test_B, test_A, inliers, None, fit_target)


# --------------------------------------------------------------------------
# From files (what the CLI calls)


def _encoding(name: str) -> Linearisation:
    """Linearisation of a named encoding: ``linear`` or a colour-science transfer function."""
    from camcal.colour.linearise import ChannelCurve, named_function

    if name == "linear":
        return Linearisation.identity()
    return Linearisation((ChannelCurve("named", {"function": named_function(name), "scale": 1.0}),) * 3)


def match_image_files(
    images: dict[str, str | os.PathLike],
    *,
    rig: Any = None,
    rectified: bool = False,
    fits: dict[str, ColourFit] | None = None,
    encoding: str = "linear",
    model: str = "matrix3x3",
    robust: str = "lmeds-irls",
    seed: int = 0,
) -> MatchResult:
    """The image route from files: read, linearise, rectify if needed, match.

    Parameters
    ----------
    images
        Two entries ``{target_name: path, source_name: path}`` in that order:
        the first camera is the target (A), the second is matched to it (B).
    rig
        A :class:`camcal.rig.Rig` holding both cameras, or ``None``. With a
        rig, the left view is the camera further along the rectified x axis'
        negative side; unless ``rectified``, both images are rectified with
        :func:`camcal.geometry.rectify.rectify_calibrated` (undistortion and
        rectification in one remap) after linearisation.
    rectified
        The images are rectified already (required without a rig).
    fits
        Characterisations by camera name: a camera's fit gives its
        linearisation, the target's fit the XYZ for Delta E.
    encoding
        Encoding of cameras without a fit: ``linear`` or a transfer
        function name (``sRGB``, ``ITU-R BT.709``, ``ARRI LogC3``...).
    model, robust, seed
        See :func:`match_images`.

    Returns
    -------
    MatchResult
    """
    from camcal.colour.chart import read_image

    if len(images) != 2:
        raise CamcalError(f"colour match needs exactly two cameras' images, got {len(images)}: {', '.join(images)}")
    fits = fits or {}
    for name in fits:
        if name not in images:
            raise CamcalError(f"a fit is given for camera {name!r}, which has no image")
    target, source = list(images)
    if rig is None and not rectified:
        raise CamcalError("without a rig the images must already be rectified (say so with --rectified)")
    linear = {}
    linearisations = {}
    for name, path in images.items():
        lin = fits[name].linearisation if name in fits else _encoding(encoding)
        linearisations[name] = lin
        linear[name] = lin.apply(read_image(path))
    a_is_left = None
    if rig is not None:
        from camcal.geometry.rectify import RectifyWarper, rectify_calibrated

        for name in images:
            rig.camera(name)
        result = rectify_calibrated(rig, [target, source])
        x = {name: float((result.R_rect @ rig.camera(name).c)[0]) for name in images}
        a_is_left = x[target] < x[source]
        if not rectified:
            warper = RectifyWarper(result.rig)
            linear = {name: warper.warp(name, image.astype(np.float32)).astype(np.float64)
                      for name, image in linear.items()}
    if linear[target].shape != linear[source].shape:
        raise CamcalError(f"the two images differ in size: {linear[target].shape[1]}x{linear[target].shape[0]} "
                          f"and {linear[source].shape[1]}x{linear[source].shape[0]} px")
    return match_images(linear[target], linear[source], model=model, robust=robust, a_is_left=a_is_left,
                        fit_target=fits.get(target), source=source, target=target,
                        linearisation=linearisations[source], seed=seed,
                        provenance_source=f"{images[target]}, {images[source]}")


def match_patch_files(
    fits: dict[str, ColourFit],
    patches: dict[str, str | os.PathLike],
    *,
    test_patches: dict[str, str | os.PathLike] | None = None,
    model: str = "matrix3x3",
    robust: str = "none",
) -> MatchResult:
    """The chart route from files: two fits and the two cameras' patch CSVs.

    Parameters
    ----------
    fits
        ``{target_name: fit, source_name: fit}``, target first.
    patches
        Patch CSVs of the same chart by camera name (code values in each
        fit's encoding; the target's XYZ column is the reference, adapted to
        the target fit's white as that fit was).
    test_patches
        Independent patch CSVs by camera name, optional.
    model, robust
        See :func:`match_charts`.

    Returns
    -------
    MatchResult
    """
    from camcal.colour.patches import read_patch_csv

    if len(fits) != 2 or set(patches) != set(fits):
        raise CamcalError("the chart route needs a fit and a patch file for each of two cameras, got fits for "
                          f"{', '.join(fits) or 'none'} and patches for {', '.join(patches) or 'none'}")
    target, source = list(fits)

    def pair(files: dict) -> tuple:
        if set(files) != set(fits):
            raise CamcalError(f"patch files must name the cameras {target} and {source}, got {', '.join(files)}")
        sets = {name: read_patch_csv(path) for name, path in files.items()}
        if sets[target].names != sets[source].names:
            raise CamcalError(f"the patch files of {target} and {source} list different patches "
                              f"({len(sets[target])} and {len(sets[source])})")
        return sets[source], sets[target]

    train_B, train_A = pair(patches)
    test = None
    if test_patches:
        test_B, test_A = pair(test_patches)
        test = (test_B.RGB, test_A.RGB)
    reference = train_A.XYZ
    fit_A = fits[target]
    if fit_A.adaptation is not None:
        reference = adapt_XYZ(reference, fit_A.training_white_XYZ, fit_A.target_white_XYZ, fit_A.adaptation)
    return match_charts(fits[source], fits[target], train_B.RGB, train_A.RGB, XYZ_reference=reference,
                        test=test, model=model, robust=robust, source=source, target=target,
                        provenance_source=f"{patches[target]}, {patches[source]}")


# --------------------------------------------------------------------------
# Report


def _write_png(path: Path, image: np.ndarray) -> Path:
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image):
            raise CamcalError(f"cannot write image {path}")
    return path


def _display(RGB: np.ndarray, peak: float) -> np.ndarray:
    """8-bit BGR for viewing: linear RGB / peak, sRGB encoded, NaN black."""
    import colour

    encoded = colour.cctf_encoding(np.clip(np.nan_to_num(RGB / peak), 0, 1), function="sRGB")
    return np.round(255 * encoded[..., ::-1]).astype(np.uint8)


def _heat(values: np.ndarray, vmax: float) -> np.ndarray:
    """8-bit BGR colour map of a ``(H, W)`` map in [0, vmax] (NaN black)."""
    import matplotlib

    rgba = matplotlib.colormaps["inferno"](np.clip(np.nan_to_num(values, nan=0.0) / vmax, 0, 1))
    rgba[~np.isfinite(values)] = (0, 0, 0, 1)
    return np.round(255 * rgba[..., 2::-1]).astype(np.uint8)


def write_match_report(directory: str | os.PathLike, result: MatchResult, delta_E_max: float = 10.0) -> list[Path]:
    """Write the match report into ``directory``.

    Image route: ``target.png`` (A), ``source_before.png`` (B at A's pixels)
    and ``source_after.png`` (matched B), ``difference_before.png`` /
    ``difference_after.png`` (``|B - A|`` and ``|f(B) - A|``, x4, on the
    kept pixels), ``delta_E_before.png`` / ``delta_E_after.png``
    (CIEDE2000 maps, colour map 0 to ``delta_E_max``, black where no
    correspondence was kept) and ``valid.png`` (white: kept pixels). Chart
    route: the swatches, histogram and a*b* plots of
    :func:`camcal.colour.evaluate.plot_report`, reference A and prediction
    ``f(B)``, both through A's characterisation. Both: ``summary.txt``.

    Returns
    -------
    list of Path
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    to_XYZ, white, _ = _target_space(result.fit_target)
    written: list[Path] = []
    corr = result.correspondences
    if corr is None:
        names = [f"patch{i + 1}" for i in range(result.train_source.shape[0])]
        written += plot_report(directory, names, to_XYZ(result.train_target),
                               to_XYZ(result.match.apply(result.train_source)), white,
                               title=f"{result.match.source} -> {result.match.target}: {result.match.model.label}")
    else:
        A = corr.target
        B = corr.source
        after = result.match.apply(np.nan_to_num(B.reshape(-1, 3))).reshape(B.shape)
        after[~np.isfinite(B)] = np.nan
        peak = float(np.nanpercentile(A, 99.5)) or 1.0
        keep = corr.valid[..., None]
        images = {
            "target.png": _display(A, peak),
            "source_before.png": _display(B, peak),
            "source_after.png": _display(after, peak),
            "difference_before.png": _display(np.where(keep, 4 * np.abs(B - A), np.nan), peak),
            "difference_after.png": _display(np.where(keep, 4 * np.abs(after - A), np.nan), peak),
            "valid.png": (255 * corr.valid).astype(np.uint8),
        }
        for name, pred in (("delta_E_before.png", B), ("delta_E_after.png", after)):
            dE = np.full(corr.valid.shape, np.nan)
            dE[corr.valid] = delta_E(to_XYZ(pred[corr.valid]), to_XYZ(A[corr.valid]), white)
            images[name] = _heat(dE, delta_E_max)
        for name, image in images.items():
            written.append(_write_png(directory / name, image))
    lines = [result.match.summary()]
    if corr is not None:
        counts = corr.counts
        lines.append(f"pixels: {counts['valid']} kept of {counts['total']} (disparity {counts['disparity']}, "
                     f"left-right consistent {counts['consistent']}, away from depth edges {counts['smooth']}); "
                     f"A is the {'left' if corr.a_is_left else 'right'} view")
        lines.append(f"Delta E maps: colour map 0 to {delta_E_max:g}, black where no correspondence was kept")
    path = directory / "summary.txt"
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    written.append(path)
    return written
