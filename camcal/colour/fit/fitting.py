"""Fitting the characterisation models: least squares, CIEDE2000 refinement, RBF smoothing by leave-one-out.

One dispatcher, :func:`fit_model`, fits any model of
:mod:`camcal.colour.fit.models` from linear camera RGB ``(N, 3)`` and XYZ
``(N, 3)`` (relative, Y = 1 for the perfect white).

Objectives: ``"xyz"`` (regularised linear least squares in XYZ, closed form)
or ``"de2000"`` (sum of squared CIEDE2000 per patch, minimised by
``scipy.optimize.least_squares`` from the least-squares solution; not
available for ``rbf``), or ``"xyz+de2000"``: the mean of those two fits
coefficients (both fit the same terms, so the mean is one model of those
terms and its predictions are the mean of theirs; the model average
``auto`` ranks, :mod:`camcal.colour.fit.select`). Regularisation ``lambda`` is a ridge penalty on the
non-linear terms only: ``|A M^T - XYZ|^2 / N + lambda |M_nl|^2``.

Shrinkage ``alpha`` (0 <= alpha < 1) pulls a polynomial or root-polynomial fit
toward the ``matrix3x3`` fit of the same patches, objective, weights and white
constraint: ``M = (1 - alpha) M_full + alpha [M_3x3, 0]`` (the 3x3 placed on the
terms R, G, B, zeros elsewhere). Its predictions are that convex combination of
the two fits' predictions, held out too: shrinkage of a high-variance estimate
toward a low-variance one (James & Stein 1961), the two-model case of stacked
regression, whose weight is chosen on held-out predictions (Breiman 1996,
Stacked regressions, Machine Learning 24, 49-64); ``auto`` chooses it by the
chart's leave-one-out (:mod:`camcal.colour.fit.select`). A convex combination
of two white-preserving fits preserves the white too.

Weights (``weights``, ``(N,)`` positive, e.g. a chart photo's
signal-to-noise weights, :func:`camcal.colour.chart.detect.snr_weights`)
make every objective a weighted one: each patch's squared residual counts
``w_i / mean(w)`` times (so equal weights change nothing); for an RBF the
smoothing of patch ``i`` is ``lambda / w_i`` (a weighted smoothing spline).

References
----------
- Sharma, G., Wu, W., Dalal, E. N. (2005). The CIEDE2000 color-difference
  formula. Color Research & Application, 30(1), 21-30.
- Thomas, J.-B. et al. (2011). Colorimetric characterization of digital
  cameras using radial basis functions (thin-plate / polyharmonic splines).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.difference import XYZ_to_Lab, delta_E
from camcal.colour.fit.models import LinearTermsModel, Model, RBFModel, rbf_kernel
from camcal.colour.fit.terms import OBJECTIVES, RBF_KERNELS, ModelSpec, expand, nonlinear_mask, parse_model_spec

__all__ = ["RBF_SMOOTHING_GRID", "fit_model", "fit_linear_terms", "fit_rbf", "delta_E2000_components",
           "normalised_weights"]


def normalised_weights(weights: Any, N: int) -> np.ndarray:
    """``(N,)`` weights scaled to mean 1 (ones when ``weights`` is ``None``)."""
    if weights is None:
        return np.ones(N)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (N,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise CamcalError(f"weights must be {N} positive finite numbers, got shape {w.shape}")
    return w / w.mean()


def _check_training(RGB: Any, XYZ: Any, n_params: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    if RGB.ndim != 2 or RGB.shape[1] != 3 or XYZ.shape != RGB.shape:
        raise CamcalError(
            f"training data must be RGB (N, 3) and XYZ (N, 3), got {RGB.shape} and {XYZ.shape}"
        )
    if not (np.all(np.isfinite(RGB)) and np.all(np.isfinite(XYZ))):
        raise CamcalError("training data contains NaN or infinite values")
    if RGB.shape[0] < n_params:
        raise CamcalError(
            f"{what} needs at least {n_params} patches, got {RGB.shape[0]}"
        )
    return RGB, XYZ


def _white_nullspace(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particular direction and null-space basis of the constraint ``r . m = w``."""
    r = r / np.linalg.norm(r)
    _, _, Vt = np.linalg.svd(r[None, :])
    return r, Vt[1:].T  # (T,), (T, T-1)


def fit_linear_terms(
    RGB: Any,
    XYZ: Any,
    terms: tuple[str, ...],
    *,
    kind: str,
    objective: str = "xyz",
    regularisation: float = 0.0,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    RGB_white: Any = None,
    max_nfev: int = 400,
    weights: Any = None,
    shrinkage: float = 0.0,
) -> LinearTermsModel:
    """Fit ``XYZ = M @ expand(RGB, terms)``.

    Parameters
    ----------
    RGB, XYZ
        ``(N, 3)`` linear camera RGB and reference XYZ (white Y = 1).
    terms
        Canonical term strings.
    kind
        Model kind recorded in the result.
    objective
        ``"xyz"``: closed-form regularised least squares in XYZ;
        ``"de2000"``: minimise the sum of squared CIEDE2000, started from
        the ``"xyz"`` solution; ``"xyz+de2000"``: the mean of the two.
    regularisation
        Ridge ``lambda`` on the non-linear terms (see the module docstring).
    white_XYZ
        XYZ of the target white, for CIELAB in the ``de2000`` objective.
    RGB_white
        Camera RGB of the perfect white; when given, the fit is white
        preserving: ``M @ expand(RGB_white) = white_XYZ`` exactly.
    weights
        ``(N,)`` patch weights (see the module docstring), ``None`` for equal.
    shrinkage
        ``alpha`` in [0, 1): the weight of the ``matrix3x3`` fit blended in
        (see the module docstring); the terms must hold R, G and B.

    Returns
    -------
    LinearTermsModel
    """
    if objective not in OBJECTIVES:
        raise CamcalError(f"unknown objective {objective!r}, expected one of: {', '.join(OBJECTIVES)}")
    terms = tuple(terms)
    if not (np.isfinite(shrinkage) and 0.0 <= shrinkage < 1.0):
        raise CamcalError(f"shrinkage must be a number in [0, 1), got {shrinkage}")
    if shrinkage > 0:
        if not {"R", "G", "B"} <= set(terms) or kind == "matrix3x3":
            raise CamcalError(f"shrinkage toward the 3x3 matrix needs a {kind} model with the terms R, G and B")
        options = dict(objective=objective, white_XYZ=white_XYZ, RGB_white=RGB_white, max_nfev=max_nfev,
                       weights=weights)
        full = fit_linear_terms(RGB, XYZ, terms, kind=kind, regularisation=regularisation, **options)
        matrix = fit_linear_terms(RGB, XYZ, ("R", "G", "B"), kind="matrix3x3", **options)
        M = (1 - shrinkage) * full.M
        M[:, [terms.index(t) for t in ("R", "G", "B")]] += shrinkage * matrix.M
        return LinearTermsModel(kind=kind, terms=terms, M=M, white_preserving=full.white_preserving,
                                objective=objective, regularisation=float(regularisation),
                                shrinkage=float(shrinkage))
    T = len(terms)
    RGB, XYZ = _check_training(RGB, XYZ, T if regularisation == 0 else 3, kind)
    N = RGB.shape[0]
    w = normalised_weights(weights, N)
    A = expand(RGB, terms)
    penalty = nonlinear_mask(terms).astype(np.float64) * float(regularisation)
    white_XYZ = np.asarray(white_XYZ, dtype=np.float64)

    if RGB_white is not None:
        r = expand(np.asarray(RGB_white, dtype=np.float64)[None, :], terms)[0]
        r_unit, Nb = _white_nullspace(r)
        norm_r = np.linalg.norm(r)
        M0 = np.outer(white_XYZ / norm_r, r_unit)  # (3, T): M0 @ r = white
        # M = M0 + Z @ Nb.T, Z (3, T-1)
        A_red = A @ Nb
        target = XYZ - A @ M0.T
        P = Nb.T @ np.diag(penalty) @ Nb
        Z = np.linalg.solve(A_red.T @ (w[:, None] * A_red) / N + P + 1e-15 * np.eye(T - 1),
                            A_red.T @ (w[:, None] * target) / N).T
        M = M0 + Z @ Nb.T

        def unpack(p: np.ndarray) -> np.ndarray:
            return M0 + p.reshape(-1, 3, T - 1) @ Nb.T

        p0 = Z.ravel()
    else:
        # least squares on the (weighted) design itself, the ridge as extra rows: the objective of the
        # module docstring without forming the normal equations (as accurate as colour-science's lstsq)
        root = np.sqrt(w / N)[:, None]
        design = np.vstack([root * A, np.diag(np.sqrt(penalty))])
        target = np.vstack([root * XYZ, np.zeros((T, 3))])
        M = np.linalg.lstsq(design, target, rcond=None)[0].T

        def unpack(p: np.ndarray) -> np.ndarray:
            return p.reshape(-1, 3, T)

        p0 = M.ravel()

    if objective == "de2000":
        M = _refine_de2000(A, XYZ, white_XYZ, unpack, p0, penalty, max_nfev, w)
    elif objective == "xyz+de2000":
        M = (M + _refine_de2000(A, XYZ, white_XYZ, unpack, p0, penalty, max_nfev, w)) / 2
    return LinearTermsModel(
        kind=kind,
        terms=terms,
        M=M,
        white_preserving=RGB_white is not None,
        objective=objective,
        regularisation=float(regularisation),
    )


def delta_E2000_components(Lab_1: np.ndarray, Lab_2: np.ndarray) -> np.ndarray:
    """Three residuals whose Euclidean norm is CIEDE2000 (for optimisers).

    CIEDE2000 is ``sqrt(u^2 + v^2 + w^2 + R_T v w)`` with
    ``u = dL'/S_L``, ``v = dC'/S_C``, ``w = dH'/S_H`` (*Sharma et al.
    2005*, k_L = k_C = k_H = 1). Completing the square gives the vector
    ``(u, v + R_T w / 2, w sqrt(1 - R_T^2 / 4))`` of the same norm, which
    is smooth where the scalar Delta E (a square root) is not: a least
    squares solver converges on it in a few Gauss-Newton steps. Reported
    figures always come from colour-science's ``delta_E``; a test checks
    that the norm of this vector equals it.

    Parameters
    ----------
    Lab_1, Lab_2
        ``(..., 3)`` CIELAB.

    Returns
    -------
    numpy.ndarray
        ``(..., 3)``.
    """
    L1, a1, b1 = np.moveaxis(np.asarray(Lab_1, dtype=np.float64), -1, 0)
    L2, a2, b2 = np.moveaxis(np.asarray(Lab_2, dtype=np.float64), -1, 0)
    C_bar = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    G = 0.5 * (1 - np.sqrt(C_bar**7 / (C_bar**7 + 25.0**7)))
    a1p, a2p = (1 + G) * a1, (1 + G) * a2
    C1p, C2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360
    zero = C1p * C2p == 0
    dh = h2p - h1p
    dh = np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh))
    dh = np.where(zero, 0.0, dh)
    dLp = L2 - L1
    dCp = C2p - C1p
    dHp = 2 * np.sqrt(C1p * C2p) * np.sin(np.radians(dh) / 2)
    L_barp = (L1 + L2) / 2
    C_barp = (C1p + C2p) / 2
    h_sum = h1p + h2p
    h_barp = np.where(
        np.abs(h1p - h2p) <= 180, h_sum / 2, np.where(h_sum < 360, (h_sum + 360) / 2, (h_sum - 360) / 2)
    )
    h_barp = np.where(zero, h_sum, h_barp)
    T = (1 - 0.17 * np.cos(np.radians(h_barp - 30)) + 0.24 * np.cos(np.radians(2 * h_barp))
         + 0.32 * np.cos(np.radians(3 * h_barp + 6)) - 0.20 * np.cos(np.radians(4 * h_barp - 63)))
    d_theta = 30 * np.exp(-(((h_barp - 275) / 25) ** 2))
    R_C = 2 * np.sqrt(C_barp**7 / (C_barp**7 + 25.0**7))
    S_L = 1 + 0.015 * (L_barp - 50) ** 2 / np.sqrt(20 + (L_barp - 50) ** 2)
    S_C = 1 + 0.045 * C_barp
    S_H = 1 + 0.015 * C_barp * T
    R_T = -np.sin(np.radians(2 * d_theta)) * R_C
    u, v, w = dLp / S_L, dCp / S_C, dHp / S_H
    return np.stack([u, v + R_T * w / 2, w * np.sqrt(np.clip(1 - R_T**2 / 4, 0, None))], axis=-1)


def _refine_de2000(
    A: np.ndarray,
    XYZ: np.ndarray,
    white_XYZ: np.ndarray,
    unpack,
    p0: np.ndarray,
    penalty: np.ndarray,
    max_nfev: int,
    w: np.ndarray | None = None,
) -> np.ndarray:
    """Minimise the sum of squared CIEDE2000 over the parameters ``p``.

    The residuals are :func:`delta_E2000_components` (3 per patch, their
    norm is the patch's CIEDE2000), with CIELAB from colour-science. The
    Jacobian is a forward difference computed in one batched evaluation.
    The ridge penalty is carried over with the ratio of squared CIEDE2000
    to squared XYZ residuals at the start, so ``lambda`` weighs the same in
    both objectives.
    """
    from scipy.optimize import least_squares


    Lab_ref = XYZ_to_Lab(XYZ, white_XYZ)
    N = A.shape[0]
    root_w = np.ones((N, 1)) if w is None else np.sqrt(w)[:, None]

    def penalties(Ms: np.ndarray) -> np.ndarray:  # (B, 3, T) -> (B, 3*T)
        return (np.sqrt(penalty)[None, None, :] * Ms).reshape(Ms.shape[0], -1)

    def colour_residuals(Ms: np.ndarray) -> np.ndarray:  # (B, 3, T) -> (B, 3N)
        pred = np.einsum("nt,bkt->bnk", A, Ms)
        comp = delta_E2000_components(XYZ_to_Lab(pred, white_XYZ), Lab_ref[None]) * root_w[None]
        return comp.reshape(Ms.shape[0], -1)

    M_start = unpack(p0[None])
    scale = 0.0
    if np.any(penalty):
        xyz_sq = np.sum(root_w**2 * (A @ M_start[0].T - XYZ) ** 2)
        scale = np.sqrt(N * np.sum(colour_residuals(M_start) ** 2) / max(xyz_sq, 1e-300))

    def residuals_batch(P: np.ndarray) -> np.ndarray:
        Ms = unpack(P)
        return np.concatenate([colour_residuals(Ms), scale * penalties(Ms)], axis=1)

    def fun(p: np.ndarray) -> np.ndarray:
        return residuals_batch(p[None])[0]

    def jac(p: np.ndarray) -> np.ndarray:
        h = 1e-7 * np.maximum(1.0, np.abs(p))
        R = residuals_batch(np.vstack([p[None], p[None] + np.diag(h)]))
        return ((R[1:] - R[0][None]) / h[:, None]).T

    result = least_squares(fun, p0, jac=jac, method="trf", max_nfev=max_nfev, ftol=1e-8, xtol=1e-10)
    return unpack(result.x[None])[0]


def _rbf_system(RGB: np.ndarray, kernel: str, smoothing: float, w: np.ndarray | None = None) -> np.ndarray:
    N = RGB.shape[0]
    r = np.linalg.norm(RGB[:, None, :] - RGB[None, :, :], axis=-1)
    Phi = rbf_kernel(r, kernel) + smoothing * np.diag(np.ones(N) if w is None else 1.0 / w)
    P = np.hstack([RGB, np.ones((N, 1))])
    S = np.zeros((N + 4, N + 4))
    S[:N, :N] = Phi
    S[:N, N:] = P
    S[N:, :N] = P.T
    return S


def _rbf_solve(RGB: np.ndarray, XYZ: np.ndarray, kernel: str, smoothing: float, w: np.ndarray | None = None):
    N = RGB.shape[0]
    S = _rbf_system(RGB, kernel, smoothing, w)
    rhs = np.vstack([XYZ, np.zeros((4, 3))])
    sol = np.linalg.lstsq(S, rhs, rcond=None)[0]
    return sol[:N], sol[N:].T  # weights (N, 3), L (3, 4)


def _rbf_loo_predictions(RGB: np.ndarray, XYZ: np.ndarray, kernel: str, smoothing: float,
                         w: np.ndarray | None = None) -> np.ndarray:
    """Exact leave-one-out predictions of a smoothing RBF (a linear smoother).

    With ``H`` the hat matrix (fitted = H XYZ), the leave-one-out residual is
    ``e_i / (1 - H_ii)``; valid for ``smoothing > 0``.
    """
    N = RGB.shape[0]
    S = _rbf_system(RGB, kernel, smoothing, w)
    rhs = np.vstack([np.eye(N), np.zeros((4, N))])
    sol = np.linalg.lstsq(S, rhs, rcond=None)[0]
    Phi0 = rbf_kernel(np.linalg.norm(RGB[:, None, :] - RGB[None, :, :], axis=-1), kernel)
    P = np.hstack([RGB, np.ones((N, 1))])
    H = Phi0 @ sol[:N] + P @ sol[N:]
    fitted = H @ XYZ
    leverage = np.clip(1.0 - np.diag(H), 1e-9, None)
    return XYZ - (XYZ - fitted) / leverage[:, None]


RBF_SMOOTHING_GRID = tuple(float(v) for v in np.logspace(-7, 0, 15))


def fit_rbf(
    RGB: Any,
    XYZ: Any,
    *,
    kernel: str = "polyharmonic-1",
    smoothing: float | None = None,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    objective: str = "xyz",
    weights: Any = None,
) -> RBFModel:
    """Fit a polyharmonic RBF network with a linear part (*Thomas 2011*).

    Parameters
    ----------
    RGB, XYZ
        ``(N, 3)`` training data; the centres are the training RGB.
    kernel
        One of :data:`RBF_KERNELS`.
    smoothing
        ``lambda`` added to the kernel diagonal; ``None`` chooses it from
        :data:`RBF_SMOOTHING_GRID` by exact leave-one-out mean CIEDE2000.
    white_XYZ
        Target white, for CIELAB when choosing ``smoothing``.
    weights
        ``(N,)`` patch weights: smoothing ``lambda / w_i`` per patch and the
        weighted mean CIEDE2000 choosing it.

    Returns
    -------
    RBFModel
    """
    if objective != "xyz":
        raise CamcalError("objective de2000 is not available for rbf models, use xyz")
    RGB, XYZ = _check_training(RGB, XYZ, 5, "rbf")
    if kernel not in RBF_KERNELS:
        raise CamcalError(f"unknown RBF kernel {kernel!r}, expected one of: {', '.join(RBF_KERNELS)}")
    w = None if weights is None else normalised_weights(weights, RGB.shape[0])
    if smoothing is None:
        best = None
        for lam in RBF_SMOOTHING_GRID:
            pred = _rbf_loo_predictions(RGB, XYZ, kernel, lam, w)
            score = float(np.average(delta_E(pred, XYZ, white_XYZ), weights=w))
            if best is None or score < best[0]:
                best = (score, lam)
        smoothing = best[1]
    coefficients, L = _rbf_solve(RGB, XYZ, kernel, float(smoothing), w)
    return RBFModel(kernel=kernel, centres=RGB, weights=coefficients, L=L, smoothing=float(smoothing))


def fit_model(
    spec: ModelSpec | str,
    RGB: Any,
    XYZ: Any,
    *,
    objective: str = "xyz",
    regularisation: float = 0.0,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    RGB_white: Any = None,
    smoothing: float | None = None,
    weights: Any = None,
    shrinkage: float = 0.0,
) -> Model:
    """Fit the model ``spec`` to training patches (the one dispatcher).

    Parameters
    ----------
    spec
        A :class:`ModelSpec` or its string (``"root-polynomial:2"``...).
    RGB, XYZ
        ``(N, 3)`` linear camera RGB and reference XYZ, white Y = 1.
    objective
        ``"xyz"``, ``"de2000"`` or ``"xyz+de2000"`` (the last two for linear-terms models only).
    regularisation
        Ridge ``lambda`` for the non-linear terms.
    white_XYZ
        XYZ of the target white.
    RGB_white
        Camera RGB of the perfect white; required when ``spec`` is white
        preserving, ignored otherwise.
    smoothing
        RBF smoothing; ``None`` picks it by leave-one-out.
    weights
        ``(N,)`` positive patch weights (signal-to-noise weights of a chart
        photo); ``None`` weighs every patch equally.
    shrinkage
        Weight ``alpha`` of the ``matrix3x3`` fit blended into a polynomial
        or root-polynomial one (module docstring); 0 for none.

    Returns
    -------
    LinearTermsModel or RBFModel
    """
    if isinstance(spec, str):
        spec = parse_model_spec(spec)
    if shrinkage and spec.kind in ("rbf", "matrix3x3"):
        raise CamcalError(f"shrinkage toward the 3x3 matrix applies to polynomial and root-polynomial models, "
                          f"not {spec.label}")
    if spec.kind == "rbf":
        return fit_rbf(RGB, XYZ, kernel=spec.kernel, smoothing=smoothing,
                       white_XYZ=white_XYZ, objective=objective, weights=weights)
    if spec.white_preserving and RGB_white is None:
        raise CamcalError(
            f"{spec.label} needs the camera RGB of the white (no neutral patches given)"
        )
    return fit_linear_terms(
        RGB,
        XYZ,
        spec.terms(),
        kind=spec.kind,
        objective=objective,
        regularisation=regularisation,
        white_XYZ=white_XYZ,
        RGB_white=RGB_white if spec.white_preserving else None,
        weights=weights,
        shrinkage=shrinkage,
    )
