"""Robust fitting of a colour match: least median of squares start, IRLS with Tukey's biweight.

Rousseeuw (1984), Holland & Welsch (1977), Beaton & Tukey (1974); see
:func:`fit_match_model`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.colour.match.models import (
    LUT_SIZE,
    LUT_SMOOTHING,
    Lut3DModel,
    MatchModel,
    parse_match_model,
    trilinear_weights,
)
from camcal.base.errors import CamcalError
from camcal.colour.fit.models import LinearTermsModel
from camcal.colour.fit.terms import expand, parse_model_spec

__all__ = [
    "ROBUST_METHODS",
    "RobustFit",
    "fit_match_model",
]


ROBUST_METHODS = ("lmeds-irls", "irls", "none")
_TUKEY_C = 4.685           # biweight tuning constant (95 % efficiency for Gaussian noise)
_CHI3_MEDIAN = 1.5382      # median of the norm of a 3-vector of unit Gaussians
_RELATIVE_FLOOR = 0.02     # relative residuals use max(mean(A), this) as the scale


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
    index, weight = trilinear_weights(B, size, lo, hi)
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
        :class:`~camcal.colour.fit.models.LinearTermsModel` or :class:`Lut3DModel`.
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
