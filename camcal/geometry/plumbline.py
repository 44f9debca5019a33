"""Plumb-line lens calibration: straight lines in the world must be straight in the image.

Line observations (:class:`camcal.geometry.lines.LineSet`) come from the rows
and columns of detected chessboard corners or from edges in ordinary images
(:mod:`camcal.geometry.lines`). Two estimators follow the literature:

1. Strand & Hayman (2005): under the one-parameter division model
   ``x_u = c + (x_d - c) / (1 + lambda r_d^2)`` a straight line images to
   a circle ``x^2 + y^2 + a x + b y + k = 0``. A linear least-squares fit
   per line gives ``(a, b, k)``; with the distortion centre ``c`` known,
   ``1 / lambda = k + a c_x + b c_y + |c|^2`` (the power of ``c`` with
   respect to the circle), one ``lambda`` per line, combined robustly.
   The centre itself has equal power with respect to every circle (it is
   their radical centre), which gives it linearly from two or more circles.
2. Devernay & Faugeras (2001): minimise the straightness residual, the
   distance of each corrected point to the best (total least-squares)
   line through its line's corrected points, over ``lambda`` (and the
   centre) or over polynomial ``k1, k2``.

Conventions: pixel (0, 0) is the centre of the top-left pixel; ``lambda``
in 1/px^2, negative for barrel distortion; straightness is reported in
pixels of the corrected image (per line, RMS of point-to-line distances).

References
----------
Strand, R. & Hayman, E. (2005). Correcting radial distortion by circle
fitting. Proc. British Machine Vision Conference (BMVC).
Devernay, F. & Faugeras, O. (2001). Straight lines have to be straight.
Machine Vision and Applications 13(1), 14-24.
Devernay, F. (1995). A non-maxima suppression method for edge detection
with sub-pixel accuracy. INRIA research report 2724.
Wang, A., Qiu, T. & Shao, L. (2009). A simple method of radial distortion
correction with centre of distortion estimation. J. Math. Imaging Vis. 35,
165-172 (the distortion centre from the circles' radical centre).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.lines import LineSet, fit_circle
from camcal.model.distortion import Distortion, fit_distortion

__all__ = [
    "PlumblineResult",
    "StrandHaymanEstimate",
    "estimate_division_StrandHayman2005",
    "fit_plumbline",
    "refine_DevernayFaugeras2001",
    "straightness_rms",
]


@dataclass(frozen=True)
class StrandHaymanEstimate:
    """The closed-form division-model estimate from circle fits.

    Attributes
    ----------
    distortion : Distortion
        Division model with the combined ``lambda`` (1/px^2) and centre (px).
    lambda_per_line : ndarray, shape (n_lines,)
        ``lambda`` from each line's circle alone, 1/px^2.
    weights : ndarray, shape (n_lines,)
        Weight of each line in the robust combination (sums to 1).
    """

    distortion: Distortion
    lambda_per_line: NDArray[np.float64]
    weights: NDArray[np.float64]


def _normaliser(image_size: tuple[int, int]) -> tuple[NDArray[np.float64], float]:
    """Origin (image centre) and scale (half diagonal) of normalised coordinates."""
    width, height = image_size
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0]), float(np.hypot(width, height) / 2.0)


def _weighted_median(values: NDArray[np.float64], weights: NDArray[np.float64]) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def estimate_division_StrandHayman2005(
    lines: LineSet, *, fit_center: bool = False, center: ArrayLike | None = None
) -> StrandHaymanEstimate:
    """Division-model ``lambda`` (and centre) from one circle per line.

    Parameters
    ----------
    lines : LineSet
        At least 2 lines (3 when fitting the centre).
    fit_center : bool
        Estimate the distortion centre as the circles' radical centre.
    center : array_like, shape (2,), optional
        Known centre in pixels (default: the image centre); ignored when
        ``fit_center``.

    Returns
    -------
    StrandHaymanEstimate

    Notes
    -----
    In coordinates centred on the distortion centre, a straight line
    ``n . x_u = d`` under ``x_u = x_d / (1 + lambda r_d^2)`` becomes
    ``d lambda |x_d|^2 - n . x_d + d = 0``: a circle with
    ``x^2 + y^2 + a x + b y + 1 / lambda = 0`` (Strand & Hayman 2005). For
    a circle ``A |x|^2 + B x + C y + D = 0`` in any frame, the centre ``c``
    thus satisfies ``lambda P_i(c) = A_i`` with the power
    ``P_i(c) = A_i |c|^2 + B_i c_x + C_i c_y + D_i``. Each line gives
    ``lambda_i = A_i / P_i(c)``; they are combined by the median weighted by
    ``P_i^2`` (the robust counterpart of the least-squares solution of
    ``lambda P_i = A_i``). Equal powers for all circles give the centre:
    ``B_i c_x + C_i c_y + D_i - A_i m = 0`` with ``m = 1/lambda - |c|^2``,
    a homogeneous linear system in ``(c_x, c_y, 1, m)`` solved by SVD
    (Wang et al. 2009). Lines through the centre stay straight and only
    constrain the centre. Computed in coordinates normalised by the half
    diagonal, reported in pixels.
    """
    n_needed = 3 if fit_center else 2
    if len(lines.lines) < n_needed:
        raise CamcalError(f"need at least {n_needed} lines, got {len(lines.lines)}")
    origin, scale = _normaliser(lines.image_size)
    circles = np.array([fit_circle((line - origin) / scale) for line in lines.lines])
    A, B, C, D = circles.T
    if fit_center:
        system = np.stack([B, C, D, -A], axis=1)
        solution = np.linalg.svd(system, full_matrices=False)[2][-1]
        if abs(solution[2]) < 1e-9 * np.abs(solution).max():
            raise CamcalError("the lines do not locate a distortion centre (they are all parallel or concurrent)")
        centre_n = solution[:2] / solution[2]
        if np.abs(centre_n).max() > 1.0:
            raise CamcalError(
                "the lines put the distortion centre outside the image; use more lines spread over the frame "
                "or do not fit the centre"
            )
    else:
        centre_px = origin if center is None else np.asarray(center, dtype=np.float64).reshape(2)
        centre_n = (centre_px - origin) / scale
    power = A * (centre_n @ centre_n) + B * centre_n[0] + C * centre_n[1] + D
    with np.errstate(divide="ignore", invalid="ignore"):
        lambda_n = np.where(np.abs(power) > 1e-15, A / power, 0.0)
    weights = power**2 / np.sum(power**2)
    lam_n = _weighted_median(lambda_n, weights)
    centre_px = origin + scale * centre_n
    distortion = Distortion("division", {"lambda": lam_n / scale**2}, center=tuple(centre_px))
    return StrandHaymanEstimate(distortion, lambda_n / scale**2, weights)


# -- straightness (Devernay & Faugeras 2001) ---------------------------------------


def _line_residuals(points: NDArray[np.float64], index: NDArray[np.intp], n_lines: int) -> NDArray[np.float64]:
    """Signed distance of each point to the total-least-squares line of its group."""
    count = np.bincount(index, minlength=n_lines)
    mean = np.stack([np.bincount(index, points[:, k], n_lines) / count for k in range(2)], axis=1)
    centred = points - mean[index]
    sxx = np.bincount(index, centred[:, 0] ** 2, n_lines)
    syy = np.bincount(index, centred[:, 1] ** 2, n_lines)
    sxy = np.bincount(index, centred[:, 0] * centred[:, 1], n_lines)
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # direction of largest spread
    normal = np.stack([-np.sin(angle), np.cos(angle)], axis=1)
    return np.sum(centred * normal[index], axis=1)


def _stack(lines: LineSet) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    points = np.concatenate(lines.lines)
    index = np.repeat(np.arange(len(lines.lines)), [len(line) for line in lines.lines])
    return points, index


def straightness_rms(lines: LineSet, distortion: Distortion | None = None, K: ArrayLike | None = None) -> NDArray[np.float64]:
    """Per-line RMS distance (px) of the corrected points to their best line.

    Parameters
    ----------
    lines : LineSet
        Distorted points.
    distortion : Distortion, optional
        Applied as ``distortion.undistort`` first; ``None`` measures the
        raw points.
    K : array_like, shape (3, 3), optional
        Camera matrix the model needs (normalisation, default centre).

    Returns
    -------
    ndarray, shape (n_lines,)

    Notes
    -----
    For line ``i`` with corrected points ``p_ij``, the total least-squares
    line passes through their mean along the principal axis of their
    scatter; the RMS of the perpendicular distances is Devernay &
    Faugeras' (2001) distortion error for that line.
    """
    points, index = _stack(lines)
    if distortion is not None:
        points = distortion.undistort(points, np.eye(3) if K is None else K)
    residuals = _line_residuals(points, index, len(lines.lines))
    return np.sqrt(np.bincount(index, residuals**2) / np.bincount(index))


def _default_K(image_size: tuple[int, int], center: ArrayLike | None = None) -> NDArray[np.float64]:
    """The normalising K of the polynomial plumb-line fit: f = max(W, H) / 2."""
    width, height = image_size
    f = max(width, height) / 2.0
    cx, cy = ((width - 1) / 2.0, (height - 1) / 2.0) if center is None else tuple(np.asarray(center, dtype=float))
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def refine_DevernayFaugeras2001(
    lines: LineSet,
    initial: Distortion,
    K: ArrayLike,
    *,
    fit_center: bool = False,
) -> tuple[Distortion, NDArray[np.float64]]:
    """Minimise the straightness residual over the model's parameters.

    Parameters
    ----------
    lines : LineSet
        Distorted points.
    initial : Distortion
        Starting model: ``division`` (``lambda``, explicit centre) or
        ``polynomial`` (``k1, k2``).
    K : array_like, shape (3, 3)
        Normalises the polynomial model; its principal point is the
        polynomial's centre.
    fit_center : bool
        Refine the centre too (the division centre, or K's principal point).

    Returns
    -------
    distortion : Distortion
        The refined model.
    K : ndarray, shape (3, 3)
        ``K`` with the refined principal point (polynomial with
        ``fit_center``), else a copy of ``K``.

    Notes
    -----
    Minimises ``sum_i sum_j (n_i . (u(p_ij) - m_i))^2`` where ``u`` is the
    model's undistortion and ``(n_i, m_i)`` the total least-squares line of
    line ``i``'s corrected points (Devernay & Faugeras 2001, section 4),
    by ``scipy.optimize.least_squares`` (trust region, finite differences).
    The distances are in corrected pixels; the division model is the
    identity at its centre, the polynomial one at the principal point, so
    the scale there is fixed.
    """
    K = np.array(K, dtype=np.float64)
    points, index = _stack(lines)
    n_lines = len(lines.lines)
    origin, scale = _normaliser(lines.image_size)
    if initial.model == "division":
        centre = np.asarray(initial.center if initial.center is not None else K[:2, 2], dtype=np.float64)
        start = [initial.params["lambda"] * scale**2]
    elif initial.model == "polynomial":
        centre = K[:2, 2].copy()
        start = [initial.params["k1"], initial.params["k2"]]
    else:
        raise CamcalError(f"plumb-line refinement supports division and polynomial models, got {initial.model!r}")
    if fit_center:
        start = start + list((centre - origin) / scale)

    def unpack(vector: NDArray[np.float64]) -> tuple[Distortion, NDArray[np.float64]]:
        c = origin + scale * np.asarray(vector[-2:]) if fit_center else centre
        if initial.model == "division":
            return Distortion("division", {"lambda": vector[0] / scale**2}, center=tuple(c)), K
        K_c = K.copy()
        K_c[:2, 2] = c
        return Distortion("polynomial", {"k1": vector[0], "k2": vector[1]}), K_c

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        distortion, K_c = unpack(vector)
        corrected = distortion.undistort(points, K_c)
        return np.nan_to_num(_line_residuals(corrected, index, n_lines), nan=1e6)

    solution = scipy.optimize.least_squares(residuals, np.asarray(start, dtype=np.float64), x_scale="jac", method="trf")
    distortion, K_out = unpack(solution.x)
    return distortion, K_out


# -- the dispatcher ------------------------------------------------------------------


@dataclass(frozen=True)
class PlumblineResult:
    """A plumb-line lens fit and its straightness figures.

    Attributes
    ----------
    distortion : Distortion
        The fitted model (division: explicit centre; polynomial: centred on
        ``K``'s principal point, coefficients relative to ``K``'s focal).
    K : ndarray, shape (3, 3)
        The camera matrix the model is used with.
    initial : StrandHaymanEstimate
        The closed-form division estimate the refinement started from.
    rms_before_px, rms_after_px : ndarray, shape (n_lines,)
        Per-line straightness RMS of the raw and of the corrected points.
    straightness_rms_before_px, straightness_rms_px : float
        RMS over all points, before and after correction.
    n_lines, n_points : int
    """

    distortion: Distortion
    K: NDArray[np.float64]
    initial: StrandHaymanEstimate
    rms_before_px: NDArray[np.float64]
    rms_after_px: NDArray[np.float64]
    straightness_rms_before_px: float
    straightness_rms_px: float
    n_lines: int
    n_points: int

    def to_dict(self) -> dict:
        """The ``lens.json`` form: distortion, K, image size and straightness figures."""
        return {
            "distortion": self.distortion.to_dict(),
            "K": self.K.tolist(),
            "straightness_rms_px": self.straightness_rms_px,
            "straightness_rms_before_px": self.straightness_rms_before_px,
            "n_lines": self.n_lines,
            "n_points": self.n_points,
        }


def _overall(per_line: NDArray[np.float64], lines: LineSet) -> float:
    counts = np.array([len(line) for line in lines.lines])
    return float(np.sqrt(np.sum(per_line**2 * counts) / counts.sum()))


def fit_plumbline(
    lines: LineSet,
    model: str = "division",
    *,
    fit_center: bool = False,
    K: ArrayLike | None = None,
) -> PlumblineResult:
    """Plumb-line calibration: Strand & Hayman's estimate, Devernay & Faugeras' refinement.

    Parameters
    ----------
    lines : LineSet
        Distorted points of straight world lines (8 or more lines spread
        over the frame give a stable centre).
    model : {"division", "polynomial"}
        The model to fit.
    fit_center : bool
        Fit the distortion centre (else: K's principal point, or the image
        centre without K).
    K : array_like, shape (3, 3), optional
        Camera matrix when known. Without it the polynomial model is
        normalised by ``f = max(W, H) / 2`` about the image centre (the
        returned ``K``); rescale ``k1, k2`` by ``(f'/f)^2, (f'/f)^4`` for
        another focal length.

    Returns
    -------
    PlumblineResult

    Notes
    -----
    The polynomial model starts from the division estimate converted by
    :func:`camcal.model.distortion.fit_distortion`.

    Examples
    --------
    >>> import numpy as np
    >>> truth = Distortion("division", {"lambda": -4e-7}, center=(319.5, 239.5))
    >>> t = np.linspace(0, 639, 30)
    >>> ideal = [np.stack([t, np.full(30, y)], 1) for y in (40.0, 120.0, 360.0, 440.0)]
    >>> lines = LineSet(tuple(truth.distort(p, np.eye(3)) for p in ideal), (640, 480))
    >>> result = fit_plumbline(lines)
    >>> bool(abs(result.distortion.params["lambda"] / -4e-7 - 1) < 1e-3)
    True
    """
    if model not in ("division", "polynomial"):
        raise CamcalError(f"unknown plumb-line model {model!r}, expected one of: division, polynomial")
    known_centre = None if K is None else np.asarray(K, dtype=np.float64)[:2, 2]
    initial = estimate_division_StrandHayman2005(lines, fit_center=fit_center, center=known_centre)
    if model == "division":
        K_used = _default_K(lines.image_size) if K is None else np.array(K, dtype=np.float64)
        start = initial.distortion
    else:
        K_used = _default_K(lines.image_size, initial.distortion.center) if K is None else np.array(K, dtype=np.float64)
        if fit_center:
            K_used[:2, 2] = initial.distortion.center
        start = fit_distortion(initial.distortion, K_used, lines.image_size, "polynomial").distortion
    distortion, K_used = refine_DevernayFaugeras2001(lines, start, K_used, fit_center=fit_center)
    before = straightness_rms(lines)
    after = straightness_rms(lines, distortion, K_used)
    return PlumblineResult(
        distortion=distortion,
        K=K_used,
        initial=initial,
        rms_before_px=before,
        rms_after_px=after,
        straightness_rms_before_px=_overall(before, lines),
        straightness_rms_px=_overall(after, lines),
        n_lines=len(lines.lines),
        n_points=lines.n_points,
    )
