"""Sub-pixel chessboard X-corners: a fit of the blurred X-junction's intensity model.

A chessboard's inner corner is, in the image, two straight edges crossing
(a homography maps lines to lines; lens distortion bends them slightly),
blurred by the lens and the pixel. :func:`refine_corners` fits, around
every corner at once (numpy, vectorised over the corners), the intensity
model of such a blurred X-junction by Levenberg-Marquardt over a window
scaled to the local square size, on the level of an area-averaging image
pyramid where that window is at most :data:`WINDOW_CAP_PX` pixels wide in
radius (4K frames with 300 px squares stay fast; the averaging keeps the
noise down in proportion to what it drops).

Pixel (0, 0) is the centre of the top-left pixel (OpenCV), x right, y down.

References
----------
Placht, S. et al. (2014). ROCHADE: Robust checkerboard advanced detection
for camera calibration. ECCV.
Duda, A. & Frese, U. (2018). Accurate detection and localization of
checkerboard corners for calibration. BMVC.
Schops, T., Larsson, V., Pollefeys, M. & Sattler, T. (2020). Why having
10,000 parameters in your camera model is better than twelve. CVPR.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from camcal.base.errors import CamcalError

__all__ = ["CornerRefinement", "refine_corners", "grid_spacing_px", "WINDOW_CAP_PX", "WINDOW_FRACTION"]

#: Largest window radius, in pixels of the pyramid level the fit runs on.
WINDOW_CAP_PX = 24.0
#: Window radius as a fraction of the clear square around the corner.
WINDOW_FRACTION = 0.65
#: Largest accepted move from the start, as a fraction of the square.
MAX_SHIFT_FRACTION = 0.25
_N_PARAMS = 13  # cx, cy, theta1, theta2, s, m, a, gx, gy, q1, q2, sx, sy
_SQRT2 = np.sqrt(2.0)
#: |z| beyond which erf(z) rounds to +-1 in double precision (erfc(6) = 2.2e-17).
_ERF_FLAT = 6.0
#: Prior standard deviation of the edges' sagitta at the window's rim (px at the level).
_SAGITTA_PRIOR_PX = 0.5
#: Largest sagitta of an edge at the window's rim, as a fraction of the window's radius, and in prior sigmas (the
#: larger of the two bounds). A straight edge bent by a lens stays far below both (real fisheye, action-camera and
#: car-camera boards: at most 0.83 px and 0.048 r, 9 cameras, 14,700 fits; an edge of curvature radius R has r^2 / (2 R):
#: 0.15 r is R = 3.3 window radii; rendered boards, strong barrel lenses included: at most 0.13 r, in windows of a few
#: px where the prior sets q); the X model fitted to another junction bends both edges to mimic it (the corner of a
#: square on the board's margin, put on the grid by OpenCV's classic search on a real fisheye view: 6.6 px, 0.36 r).
_MAX_SAGITTA_FRACTION = 0.15
_MAX_SAGITTA_PRIOR_SIGMAS = 4.0
#: Fewest blur widths (Gaussian sigma) in the window's radius for the additive gradient to be fitted: on rendered
#: boards without glare it cost 3-4 % of accuracy at 6.5, 17-30 % at 4.3-4.9, nothing at 9.8 and above.
_GLARE_WINDOW_BLURS = 8.0
#: Fewest blur widths in the window's radius for the illumination gradient to be fitted: a narrower window sees a
#: saddle, whose shift is a linear ramp (on rendered boards of 15-20 px squares blurred by 3-4 px, fitting it
#: left 0.29-0.68 px RMS, holding it 0.10 px).
_GAIN_WINDOW_BLURS = 4.0


@dataclass(frozen=True)
class CornerRefinement:
    """Refined corners and how well the model fitted each of them.

    Attributes
    ----------
    corners_px : ndarray, shape (N, 2)
        Refined corners; the input corner where ``ok`` is False.
    ok : ndarray of bool, shape (N,)
        The fit converged, stayed within the square and found an X-junction.
    residual_rms : ndarray, shape (N,)
        RMS of the intensity residual over the window (image units), NaN
        where the fit did not run.
    blur_px : ndarray, shape (N,)
        Fitted edge blur (Gaussian standard deviation, full-resolution px).
    sigma_px : ndarray, shape (N,)
        The fit's own standard deviation of the position,
        ``sqrt(trace(Cov_xy) / 2)`` from the Gauss-Newton covariance scaled
        by the residual variance (sampling noise only, not model error).
    """

    corners_px: NDArray[np.float64]
    ok: NDArray[np.bool_]
    residual_rms: NDArray[np.float64]
    blur_px: NDArray[np.float64]
    sigma_px: NDArray[np.float64]


def _level_images(gray: NDArray[np.float32], levels: int) -> list[NDArray[np.float32]]:
    """The image and its 2x area-averaged reductions (pixel x at level l is 2^l x + (2^l - 1) / 2 at level 0)."""
    pyramid = [gray]
    for _ in range(levels):
        top = pyramid[-1]
        h, w = (top.shape[0] // 2) * 2, (top.shape[1] // 2) * 2
        if h < 2 or w < 2:
            break
        top = top[:h, :w]
        pyramid.append(0.25 * (top[0::2, 0::2] + top[1::2, 0::2] + top[0::2, 1::2] + top[1::2, 1::2]))
    return pyramid


def _initial_angles(patches: NDArray, weights: NDArray) -> NDArray[np.float64]:
    """The two edge normals' angles (mod pi) of each patch, from its gradient-orientation histogram."""
    gx = 0.5 * (patches[:, 1:-1, 2:] - patches[:, 1:-1, :-2])
    gy = 0.5 * (patches[:, 2:, 1:-1] - patches[:, :-2, 1:-1])
    w = (gx * gx + gy * gy) * weights[:, 1:-1, 1:-1]
    n_bins = 36
    phi = np.mod(np.arctan2(gy, gx), np.pi)
    bins = np.minimum((phi / np.pi * n_bins).astype(np.int64), n_bins - 1)
    n = len(patches)
    rows = np.repeat(np.arange(n), bins[0].size)
    hist = np.bincount(rows * n_bins + bins.reshape(-1), w.reshape(-1), minlength=n * n_bins).reshape(n, n_bins)
    hist = 0.5 * hist + 0.25 * (np.roll(hist, 1, axis=1) + np.roll(hist, -1, axis=1))
    first = np.argmax(hist, axis=1)
    distance = np.abs((np.arange(n_bins)[None, :] - first[:, None] + n_bins // 2) % n_bins - n_bins // 2)
    second = np.argmax(np.where(distance > 4, hist, -1.0), axis=1)

    def peak(index: NDArray) -> NDArray:
        left = hist[np.arange(n), (index - 1) % n_bins]
        mid = hist[np.arange(n), index]
        right = hist[np.arange(n), (index + 1) % n_bins]
        denominator = left - 2 * mid + right
        offset = np.where(denominator < 0, 0.5 * (left - right) / np.where(denominator < 0, denominator, -1.0), 0.0)
        return (index + 0.5 + np.clip(offset, -0.5, 0.5)) * np.pi / n_bins

    return np.stack([peak(first), peak(second)], axis=1)


def _model(params: NDArray, offsets: NDArray, radius: NDArray) -> tuple[NDArray, NDArray]:
    """Intensity ``I`` (N, M) and Jacobian (N, 13, M) of the X-junction model at sample offsets (N, M, 2)."""
    cx, cy, t1, t2, s, m, a, gx, gy, q1, q2, sx, sy = (params[:, k : k + 1] for k in range(_N_PARAMS))
    vx = offsets[..., 0] - cx
    vy = offsets[..., 1] - cy
    inv_r2 = 1.0 / (radius[:, None] ** 2)
    jac = np.empty((vx.shape[0], _N_PARAMS, vx.shape[1]))
    edges = []
    for theta, q in ((t1, q1), (t2, q2)):
        nx, ny = np.cos(theta), np.sin(theta)
        normal = nx * vx + ny * vy
        along = -ny * vx + nx * vy
        u = normal + q * along * along * inv_r2
        z = u / (_SQRT2 * s)
        # beyond |z| = 6 erf is +-1 in double precision and its slope below 3e-16 of its peak: most of a window
        near = np.abs(z) < _ERF_FLAT
        value = np.sign(z)
        value[near] = erf(z[near])
        slope = np.zeros_like(z)
        slope[near] = np.exp(-z[near] ** 2)
        slope *= np.sqrt(2.0 / np.pi) / s  # d erf(u / (sqrt2 s)) / du
        du_dcx = -nx + 2 * q * along * inv_r2 * ny
        du_dcy = -ny - 2 * q * along * inv_r2 * nx
        du_dtheta = along - 2 * q * along * normal * inv_r2
        edges.append((value, slope, du_dcx, du_dcy, du_dtheta, along * along * inv_r2, u))
    (e1, d1, ax1, ay1, at1, aq1, u1), (e2, d2, ax2, ay2, at2, aq2, u2) = edges
    f = e1 * e2
    gain = 1.0 + gx * vx + gy * vy
    base = m + a * f
    scale = a * gain
    jac[:, 0] = scale * (e2 * d1 * ax1 + e1 * d2 * ax2) - base * gx - sx
    jac[:, 1] = scale * (e2 * d1 * ay1 + e1 * d2 * ay2) - base * gy - sy
    jac[:, 2] = scale * e2 * d1 * at1
    jac[:, 3] = scale * e1 * d2 * at2
    jac[:, 4] = -scale * (e2 * d1 * u1 + e1 * d2 * u2) / s
    jac[:, 5] = gain
    jac[:, 6] = f * gain
    jac[:, 7] = base * vx
    jac[:, 8] = base * vy
    jac[:, 9] = scale * e2 * d1 * aq1
    jac[:, 10] = scale * e1 * d2 * aq2
    jac[:, 11] = vx
    jac[:, 12] = vy
    return base * gain + sx * vx + sy * vy, jac


def _taper(offsets: NDArray, centre: NDArray, radius: NDArray) -> NDArray:
    """Window weights: 1 inside 0.7 r of the current centre, falling linearly to 0 at r."""
    rho = np.hypot(offsets[..., 0] - centre[:, 0:1], offsets[..., 1] - centre[:, 1:2])
    return np.clip((radius[:, None] - rho) / (0.3 * radius[:, None]), 0.0, 1.0)


def _levenberg_marquardt(params: NDArray, fixed: NDArray, offsets: NDArray, flat: NDArray, valid: NDArray,
                         radius: NDArray, max_iterations: int) -> tuple[NDArray, NDArray]:
    """Levenberg-Marquardt on the model, parameters where ``fixed`` (N, 13) held: (params, converged)."""
    params = params.copy()
    n = len(params)
    lam = np.full(n, 1e-3)
    active = np.ones(n, dtype=bool)
    converged = np.zeros(n, dtype=bool)
    eye = np.eye(_N_PARAMS)
    # the model and its Jacobian at the current parameters of the active corners: each iteration evaluates them
    # once, at the trial, and keeps them where the trial is accepted
    model, jac = _model(params, offsets, radius)
    jac *= ~fixed[:, :, None]
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        p, off, rad = params[idx], offsets[idx], radius[idx]
        w = _taper(off, p[:, :2], rad) * valid[idx]
        res = flat[idx] - model
        cost = (w * res * res).sum(1)
        jw = jac * w[:, None, :]
        normal = jw @ jac.transpose(0, 2, 1)
        gradient = (jw @ res[..., None])[..., 0]
        noise_var = cost / np.maximum(w.sum(1), 1.0)
        prior = noise_var / _SAGITTA_PRIOR_PX**2
        normal[:, 9, 9] += prior
        normal[:, 10, 10] += prior
        gradient[:, 9] -= prior * p[:, 9]
        gradient[:, 10] -= prior * p[:, 10]
        normal += fixed[idx, :, None] * eye
        diagonal = np.einsum("nii->ni", normal)
        damped = normal + lam[idx, None, None] * (diagonal[:, :, None] * eye + 1e-9 * eye)
        try:
            step = np.linalg.solve(damped, gradient[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.stack([np.linalg.lstsq(d, g_, rcond=None)[0] for d, g_ in zip(damped, gradient)])
        step[fixed[idx]] = 0.0
        trial = p + step
        trial[:, 4] = np.maximum(trial[:, 4], 0.25)
        model_t, jac_t = _model(trial, off, rad)
        jac_t *= ~fixed[idx, :, None]
        res_t = flat[idx] - model_t
        cost_t = (w * res_t * res_t).sum(1) + prior * (trial[:, 9] ** 2 + trial[:, 10] ** 2)
        cost_p = cost + prior * (p[:, 9] ** 2 + p[:, 10] ** 2)
        better = np.isfinite(cost_t) & (cost_t <= cost_p)
        params[idx[better]] = trial[better]
        if better.all():
            model, jac = model_t, jac_t
        else:
            model[better], jac[better] = model_t[better], jac_t[better]
        lam[idx] = np.where(better, np.maximum(lam[idx] / 3, 1e-7), np.minimum(lam[idx] * 4, 1e7))
        small = np.hypot(step[:, 0], step[:, 1]) < 1e-5
        done = (better & small) | (lam[idx] >= 1e7)
        converged[idx[better & small]] = True
        active[idx[done]] = False
        if done.any():
            model, jac = model[~done], jac[~done]
    converged |= active & (lam < 1e7)  # still improving at the last iteration: keep, checked below
    return params, converged


def _fit_level(image: NDArray[np.float32], start: NDArray, radius: NDArray, max_iterations: int
               ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Fit the model around ``start`` (N, 2), level pixels: (params, converged, rms, sigma_xy, shift-ok mask)."""
    n = len(start)
    half = int(np.ceil(radius.max())) + 2
    grid = np.arange(-half, half + 1)
    oy, ox = np.meshgrid(grid, grid, indexing="ij")
    base = np.rint(start).astype(np.int64)
    xs = base[:, 0, None, None] + ox[None]
    ys = base[:, 1, None, None] + oy[None]
    height, width = image.shape
    inside = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
    patches = image[np.clip(ys, 0, height - 1), np.clip(xs, 0, width - 1)].astype(np.float64)
    valid = inside & np.isfinite(patches)
    patches = np.where(valid, patches, 0.0)
    # offsets relative to the integer centre keep the numbers small
    offsets = np.stack([np.broadcast_to(ox, xs.shape), np.broadcast_to(oy, ys.shape)], axis=-1).astype(np.float64)
    offsets = offsets.reshape(n, -1, 2)
    centre0 = start - base
    weights = _taper(offsets, centre0, radius) * valid.reshape(n, -1)
    angles = _initial_angles(patches, weights.reshape(patches.shape))
    flat = patches.reshape(n, -1)
    g = np.hypot(0.5 * (patches[:, 1:-1, 2:] - patches[:, 1:-1, :-2]), 0.5 * (patches[:, 2:, 1:-1] - patches[:, :-2, 1:-1]))
    g_peak = np.max(g * (weights.reshape(patches.shape)[:, 1:-1, 1:-1] > 0), axis=(1, 2))
    # the fit weighs only the disc inscribed in the patch (a window that moved by up to 2 px): a fifth fewer samples
    disc = (ox * ox + oy * oy <= half * half).ravel()
    offsets, flat, weights = offsets[:, disc], flat[:, disc], weights[:, disc]
    valid = valid.reshape(n, -1)[:, disc]
    params = np.zeros((n, _N_PARAMS))
    params[:, 0:2] = centre0
    params[:, 2:4] = angles
    params[:, 4] = 1.0
    # linear start of mean and amplitude on the start geometry
    params[:, 6] = 1.0
    _, jac = _model(params, offsets, radius)
    f = jac[:, 6]
    sw, sf, sff = weights.sum(1), (weights * f).sum(1), (weights * f * f).sum(1)
    si, sfi = (weights * flat).sum(1), (weights * f * flat).sum(1)
    det = sw * sff - sf * sf
    det = np.where(np.abs(det) > 1e-12, det, 1.0)
    params[:, 5] = (sff * si - sf * sfi) / det
    params[:, 6] = (sw * sfi - sf * si) / det
    # the additive gradient (glare) is free only where the window spans enough blur widths to tell it from a shift:
    # the blur of an edge of contrast 2 a whose steepest gradient is g_peak is 2 a / (sqrt(2 pi) g_peak)
    blur = 2.0 * np.abs(params[:, 6]) / (np.sqrt(2 * np.pi) * np.maximum(g_peak, 1e-12))
    tied = ~(radius >= _GLARE_WINDOW_BLURS * blur)
    fixed = np.zeros((n, _N_PARAMS), dtype=bool)
    fixed[:, 11:] = tied[:, None]
    params, converged = _levenberg_marquardt(params, fixed, offsets, flat, valid, radius, max_iterations)
    # a window within a few fitted blur widths sees a saddle, whose shift is a linear ramp: the illumination
    # gradient then trades off against the centre; held at zero there, the fit runs again from its result
    narrow = np.flatnonzero(radius < _GAIN_WINDOW_BLURS * params[:, 4])
    if narrow.size:
        start_narrow = params[narrow].copy()
        start_narrow[:, 7:9] = 0.0
        fixed[narrow, 7:9] = True
        params[narrow], converged[narrow] = _levenberg_marquardt(start_narrow, fixed[narrow], offsets[narrow],
                                                                 flat[narrow], valid[narrow], radius[narrow],
                                                                 max_iterations)
    w = _taper(offsets, params[:, :2], radius) * valid
    model, jac = _model(params, offsets, radius)
    jac *= ~fixed[:, :, None]
    res = flat - model
    dof = np.maximum(w.sum(1) - _N_PARAMS + fixed.sum(1), 1.0)
    rms = np.sqrt((w * res * res).sum(1) / dof)
    normal = (jac * w[:, None, :]) @ jac.transpose(0, 2, 1)
    normal += fixed[:, :, None] * np.eye(_N_PARAMS)
    normal[:, 9, 9] += rms**2 / _SAGITTA_PRIOR_PX**2
    normal[:, 10, 10] += rms**2 / _SAGITTA_PRIOR_PX**2
    sigma = np.full(n, np.nan)
    finite = np.isfinite(normal).all(axis=(1, 2)) & (np.linalg.cond(np.where(np.isfinite(normal), normal, 0.0)) < 1e14)
    if finite.any():
        cov = np.linalg.inv(normal[finite])
        sigma[finite] = rms[finite] * np.sqrt(np.maximum(cov[:, 0, 0] + cov[:, 1, 1], 0.0) / 2)
    params[:, 0:2] += base
    return params, converged, rms, sigma, valid.any(axis=1)


def refine_corners(
    image: ArrayLike,
    corners_px: ArrayLike,
    square_px: ArrayLike,
    *,
    window_fraction: float = WINDOW_FRACTION,
    max_iterations: int = 40,
) -> CornerRefinement:
    """Refine chessboard X-corners by fitting a blurred X-junction model (Placht 2014; Duda & Frese 2018).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image, uint8 or float (any scale); non-finite pixels are ignored.
    corners_px : array_like, shape (N, 2)
        Starting corners (x, y), within a fraction of a square of the truth
        (e.g. a detector's integer or sub-pixel corners).
    square_px : float or array_like, shape (N,)
        The side, in pixels, of the clear square around each corner: for a
        chessboard the local square size (the smallest distance to a grid
        neighbour), for ChArUco less (``board.py`` passes 0.8 x the square
        minus the marker: the window stays off the markers).
    window_fraction : float
        Window radius as a fraction of ``square_px`` (default 0.65: the four
        squares around a corner cover the disc of radius one square, and
        the taper keeps the blurred neighbouring corners out).
    max_iterations : int
        Levenberg-Marquardt iterations at most.

    Returns
    -------
    CornerRefinement
        Refined corners, a per-corner ``ok`` flag (False: the input corner
        is returned unchanged), residual, blur and the fit's own sigma.

    Raises
    ------
    CamcalError
        ``image`` not 2-D, ``corners_px`` not (N, 2), ``square_px`` not a
        scalar or (N,).

    Notes
    -----
    Around each corner ``c``, with ``v = p - c``, normals
    ``n_i = (cos theta_i, sin theta_i)`` and tangents ``t_i`` of the two
    edges, the model is

    ``I(p) = (m + a E(u_1) E(u_2)) (1 + g . v) + g_G . v``,
    ``u_i = n_i . v + q_i (t_i . v)^2 / r^2``,
    ``E(u) = erf(u / (sqrt(2) s))``

    (the erf product is the exact blur of an X-junction with perpendicular
    edges, a point-symmetric approximation otherwise, so the centre stays
    unbiased): 13 parameters per corner (11 where the window is narrow), the centre, both edge angles (free:
    perspective), the blur ``s``, the mean ``m`` and amplitude ``a``, an
    illumination gradient ``g`` (light reflected off the board, ``I = L R``,
    scales both), an additive gradient ``g_G`` (glare or flare added to it,
    ``I = L R + G``, shifts the mean only: without it, under a glare
    gradient strong enough that a dark square outshines the light one
    opposite, the centre is dragged, 0.096 px against 0.049 px on rendered
    boards; it is fitted only where the window's radius spans at least
    8 blur widths, estimated from the window's
    contrast and steepest gradient, since in a narrower window it trades
    off against the centre) and each edge's sagitta ``q_i`` at the window's
    rim (lens distortion bends edges; a weak prior of
    0.5 px holds it where the window cannot tell). Where the window's
    radius is within 4 fitted blur widths, the window sees a saddle, whose
    shift is a linear ramp: the fit runs again from its result with ``g``
    held at zero. The fit weighs pixels by
    a taper that moves with the centre (flat to 0.7 r, zero at r), so that
    a point-symmetric corner sees a point-symmetric window. It runs on the
    level of a 2x area-averaging pyramid where ``r <= WINDOW_CAP_PX``
    (a corner in 4K with 300 px squares: level 3), then once more on a
    window clear of the neighbouring corners by three fitted blur widths
    where the blur reaches them, and once more a level finer where the
    edges are sharper than half a pixel of the level (on half the window:
    the same cost). A corner is rejected
    (``ok`` False) when the fit diverges, moves by more than a quarter of
    the square, finds no contrast above its residual, the two edges
    within 12 degrees of each other, or an edge bent by more than 0.15 of
    the window's radius and 4 sigmas of its prior (not an X-junction: the
    corner of a square on the board's margin).

    Examples
    --------
    >>> import numpy as np
    >>> y, x = np.mgrid[0:41, 0:41].astype(float)
    >>> xc, yc = 20.3, 19.6
    >>> from scipy.special import erf
    >>> image = 128 + 100 * erf((x - xc) / 1.5) * erf((y - yc) / 1.5)
    >>> result = refine_corners(image, [[20.0, 20.0]], 30.0)
    >>> np.round(result.corners_px, 3).tolist(), bool(result.ok[0])
    ([[20.3, 19.6]], True)
    """
    gray = np.asarray(image)
    if gray.ndim != 2:
        raise CamcalError(f"image must be a 2-D grey array, got shape {gray.shape}")
    corners = np.asarray(corners_px, dtype=np.float64)
    if corners.size == 0:
        corners = corners.reshape(0, 2)
    if corners.ndim != 2 or corners.shape[1] != 2:
        raise CamcalError(f"corners must have shape (N, 2), got {corners.shape}")
    n = len(corners)
    squares = np.asarray(square_px, dtype=np.float64)
    if squares.ndim == 0:
        squares = np.full(n, float(squares))
    if squares.shape != (n,):
        raise CamcalError(f"square_px must be a number or have shape ({n},), got {squares.shape}")
    out = corners.copy()
    ok = np.zeros(n, dtype=bool)
    rms = np.full(n, np.nan)
    blur = np.full(n, np.nan)
    sigma = np.full(n, np.nan)
    usable = np.isfinite(corners).all(axis=1) & np.isfinite(squares) & (squares >= 4.0)
    if not usable.any():
        return CornerRefinement(out, ok, rms, blur, sigma)
    radius_full = window_fraction * squares
    level = np.zeros(n, dtype=np.int64)
    level[usable] = np.maximum(0, np.ceil(np.log2(radius_full[usable] / WINDOW_CAP_PX))).astype(np.int64)
    pyramid = _level_images(gray.astype(np.float32), int(level[usable].max()))
    level = np.minimum(level, len(pyramid) - 1)

    def fit(idx: NDArray, starts: NDArray, radii: NDArray, lv: int) -> None:
        """Fit corners ``idx`` at level ``lv``; a refit replaces only the earlier results it improves on."""
        k = 2.0**lv
        radius = np.maximum(radii / k, 2.5)
        params, converged, res_rms, sig, seen = _fit_level(pyramid[lv], (starts - (k - 1) / 2) / k, radius, max_iterations)
        refined = params[:, :2] * k + (k - 1) / 2
        shift = np.hypot(*(refined - corners[idx]).T)
        angle = np.abs(np.mod(params[:, 2] - params[:, 3] + np.pi / 2, np.pi) - np.pi / 2)
        good = (converged & seen & np.isfinite(refined).all(axis=1) & (shift <= MAX_SHIFT_FRACTION * squares[idx])
                & (np.abs(params[:, 6]) > 3 * res_rms) & (angle > np.radians(12)) & (params[:, 4] < radius)
                & (np.max(np.abs(params[:, 9:11]), axis=1)
                   <= np.maximum(_MAX_SAGITTA_FRACTION * radius, _MAX_SAGITTA_PRIOR_SIGMAS * _SAGITTA_PRIOR_PX)))
        write = good | ~ok[idx]
        idx, good = idx[write], good[write]
        out[idx] = np.where(good[:, None], refined[write], corners[idx])
        ok[idx] = good
        rms[idx] = res_rms[write]
        blur[idx] = params[write, 4] * k
        sigma[idx] = sig[write] * k

    for lv in np.unique(level[usable]):
        idx = np.flatnonzero(usable & (level == lv))
        fit(idx, corners[idx], radius_full[idx], int(lv))
    # blur that reaches the next corners: a window clear of them by 3 blur widths, from the fit's corner
    clear = squares - 3.0 * blur
    again = np.flatnonzero(ok & (clear < radius_full) & (clear >= 0.25 * squares))
    for lv in np.unique(level[again]):
        idx = again[level[again] == lv]
        fit(idx, out[idx], clear[idx], int(lv))
    # edges sharper than half a pixel of the level: once more a level finer, on a window of the same size there
    finer = np.flatnonzero(ok & (level >= 1) & (blur < 0.5 * 2.0**level))
    for lv in np.unique(level[finer]):
        idx = finer[level[finer] == lv]
        fit(idx, out[idx], np.minimum(np.minimum(radius_full[idx], clear[idx]), WINDOW_CAP_PX * 2.0 ** (lv - 1)), int(lv) - 1)
    return CornerRefinement(out, ok, rms, blur, sigma)


def grid_spacing_px(corners_px: ArrayLike, grid_xy: ArrayLike) -> NDArray[np.float64]:
    """Each corner's smallest distance to a found grid neighbour (px): the local square size.

    Parameters
    ----------
    corners_px : array_like, shape (N, 2)
        Corners in the image.
    grid_xy : array_like of int, shape (N, 2)
        Each corner's (column, row) on the board.

    Returns
    -------
    ndarray, shape (N,)
        NaN for a corner none of whose four grid neighbours was found.

    Examples
    --------
    >>> grid_spacing_px([[0, 0], [10, 0], [0, 12]], [[0, 0], [1, 0], [0, 1]]).tolist()
    [10.0, 10.0, 12.0]
    """
    corners = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    grid = np.asarray(grid_xy, dtype=np.int64).reshape(-1, 2)
    if len(grid) != len(corners):
        raise CamcalError(f"need one grid position per corner, got {len(grid)} for {len(corners)} corners")
    spacing = np.full(len(corners), np.inf)
    index = {(int(c), int(r)): i for i, (c, r) in enumerate(grid)}
    for i, (c, r) in enumerate(grid):
        for neighbour in ((c + 1, r), (c - 1, r), (c, r + 1), (c, r - 1)):
            j = index.get((int(neighbour[0]), int(neighbour[1])))
            if j is not None:
                spacing[i] = min(spacing[i], float(np.hypot(*(corners[i] - corners[j]))))
    spacing[~np.isfinite(spacing)] = np.nan
    return spacing
