"""ST-maps: float images that tell a comp package (Nuke STMap, Fusion, Natron) where to sample.

Each pixel of an ST-map holds, in its red and green channels, the position
of the SOURCE pixel to sample, normalised to the source image's format
(its display window, the plate's size ``W x H``):

    R = (x + 0.5) / W,    G = 1 - (y + 0.5) / H

with ``(x, y)`` the source pixel (pixel (0, 0) at the centre of the
top-left pixel, y down; so R = 0 is the left edge of the format and G = 0
its bottom edge, Nuke's UV origin); blue is 0. Values outside [0, 1] reach
beyond the format, into the source's overscan border.

Two maps per camera, both on the plate's format ``W x H``:

- undistort: its output is the undistorted image, a pinhole camera with
  the plate's ``K``, on the plate's format plus an overscan border of
  ``(bx, by)`` whole pixels on each side: the map covers the data window
  ``[-bx, W + bx) x [-by, H + by)`` (written as the EXR's data window
  beyond its display window, the bounding box Nuke keeps); it samples the
  distorted plate;
- redistort: its output is the plate-sized distorted image; it samples the
  undistorted image (in that image's format, so values outside [0, 1]
  read its overscan border), e.g. a CG render with overscan.

The overscan is a factor of the plate (``1.25``: ``bx = round(0.125 W)``)
or a border in pixels. Written as 32-bit float OpenEXR by
:mod:`camcal.io.stmap`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import FISHEYE_MODELS, Distortion
from camcal.geometry.undistort import UndistortedView, Undistorter
from camcal.model.rig import Camera

__all__ = ["DEFAULT_OVERSCAN", "STMaps", "stmap_view", "overscan_border", "st_from_pixels", "pixels_from_st", "st_of_distorted_grid",
           "undistorted_grid", "make_stmaps"]

#: The models :func:`_distort_arrays` evaluates on a grid; the others (3DE's) go through ``Distortion.distort``.
_VECTORISED_MODELS = ("none", "polynomial", "opencv", "division", *FISHEYE_MODELS)
#: The overscan factor when none is given.
DEFAULT_OVERSCAN = 1.1
#: Rows per block of the map computations (a block's arrays stay in the CPU's cache).
_BLOCK_ROWS = 64


def overscan_border(image_size: tuple[int, int], overscan: float | None = None,
                    border: int | tuple[int, int] | None = None) -> tuple[int, int]:
    """The overscan border ``(bx, by)`` in whole pixels on each side of the plate.

    Parameters
    ----------
    image_size : (int, int)
        The plate's (W, H).
    overscan : float, optional
        A factor (>= 1) of the plate: ``bx = round((overscan - 1) W / 2)``,
        ``by = round((overscan - 1) H / 2)``.
    border : int or (int, int), optional
        The border itself (>= 0), the same on both axes or per axis. Give
        ``overscan`` or ``border``, not both; neither means no border.

    Returns
    -------
    (int, int)
    """
    if overscan is not None and border is not None:
        raise CamcalError("give the overscan as a factor or as a border in pixels, not both")
    if border is not None:
        values = (border, border) if isinstance(border, (int, np.integer)) else tuple(border)
        if len(values) != 2 or not all(isinstance(v, (int, np.integer)) and v >= 0 for v in values):
            raise CamcalError(f"overscan border must be whole pixels >= 0 (one number or x, y), got {border!r}")
        return int(values[0]), int(values[1])
    if overscan is None:
        return 0, 0
    if not math.isfinite(overscan) or overscan < 1.0:
        raise CamcalError(f"overscan must be a number >= 1, got {overscan}")
    width, height = image_size
    return int(round((overscan - 1.0) * width / 2.0)), int(round((overscan - 1.0) * height / 2.0))


def st_from_pixels(x: NDArray, y: NDArray, source_size: tuple[int, int]) -> NDArray[np.float32]:
    """ST values of source pixels: ``R = (x + 0.5) / W``, ``G = 1 - (y + 0.5) / H``, ``B = 0``.

    Parameters
    ----------
    x, y : ndarray, shape (H_out, W_out)
        Source pixel of each output pixel, in the source's format (pixel
        centres at integers).
    source_size : (int, int)
        (W, H) of the source's format.

    Returns
    -------
    ndarray, shape (H_out, W_out, 3), float32
        RGB order (``write_exr`` swaps to OpenCV's BGR).
    """
    width, height = source_size
    st = np.zeros(np.shape(x) + (3,), dtype=np.float32)
    st[..., 0] = (np.asarray(x, dtype=np.float64) + 0.5) / width
    st[..., 1] = 1.0 - (np.asarray(y, dtype=np.float64) + 0.5) / height
    return st


def pixels_from_st(st: NDArray, source_size: tuple[int, int]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`st_from_pixels`: source pixels ``(x, y)`` (in its format) from an RGB ST-map."""
    width, height = source_size
    st = np.asarray(st, dtype=np.float64)
    return st[..., 0] * width - 0.5, (1.0 - st[..., 1]) * height - 0.5


def _blocks(rows: int, work, block_rows: int = _BLOCK_ROWS) -> None:
    """Run ``work(start, stop)`` over blocks of ``block_rows`` rows, on every core (numpy and OpenCV release the GIL)."""
    starts = range(0, rows, block_rows)
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for future in [pool.submit(work, start, min(start + block_rows, rows)) for start in starts]:
            future.result()


def _distort_arrays(distortion: Distortion, K: NDArray, u: NDArray, v: NDArray) -> tuple[NDArray, NDArray]:
    """``distortion.distort`` of the ideal pixels ``(u, v)`` (broadcastable arrays, float32 or float64, kept).

    The same formulas as :meth:`camcal.model.distortion.Distortion.distort`
    (OpenCV's pinhole and fisheye models, Strand & Hayman's division model)
    on arrays instead of a point list: given a grid as a row ``u[None, :]``
    and a column ``v[:, None]``, the normalised ``x`` depends on the column
    and ``y`` on the row (``K^-1``; skew makes ``x`` depend on both), so only
    the radius and what follows is per pixel. In float32 the result is
    within about 1e-3 px of the double-precision model at 4K, the order of
    what a float32 ST value holds.
    """
    p = distortion.params
    real = np.result_type(u, v).type
    fx, skew, cx = (float(value) for value in K[0])
    fy, cy = float(K[1, 1]), float(K[1, 2])
    if distortion.model == "division":
        centre_x, centre_y = distortion.center if distortion.center is not None else (cx, cy)
        dx, dy = u - real(centre_x), v - real(centre_y)
        r2 = dx * dx + (real(p.get("aspect", 1.0)) * dy) ** 2
        r2 *= real(-4.0 * p["lambda"])
        r2 += real(1.0)
        with np.errstate(invalid="ignore"):
            scale = np.sqrt(r2, out=r2)
        scale += real(1.0)
        np.divide(real(2.0), scale, out=scale)
        return real(centre_x) + dx * scale, real(centre_y) + dy * scale
    y = (v - real(cy)) / real(fy)
    x = (u - real(cx) - real(skew) * y) / real(fx) if skew else (u - real(cx)) / real(fx)
    r2 = x * x + y * y
    theta = None
    if distortion.is_fisheye:
        r = np.sqrt(r2)
        theta = np.arctan(r)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(r > 0, distortion.theta_d(theta).astype(real) / r, real(1.0))
        x, y = x * scale, y * scale
        r2 = x * x + y * y
        xd, yd = x.copy(), y.copy()
    elif distortion.model in ("polynomial", "opencv"):
        radial = r2 * real(p.get("k3", 0.0))
        radial += real(p["k2"])
        radial *= r2
        radial += real(p["k1"])
        radial *= r2
        radial += real(1.0)
        if any(p.get(name, 0.0) for name in ("k4", "k5", "k6")):
            radial /= 1.0 + r2 * (real(p.get("k4", 0.0)) + r2 * (real(p.get("k5", 0.0)) + r2 * real(p.get("k6", 0.0))))
        xd = radial * x
        yd = np.multiply(radial, y, out=radial)
    else:  # none
        xd, yd = np.broadcast_to(x, r2.shape).copy(), np.broadcast_to(y, r2.shape).copy()
    if distortion.model in ("opencv", "kannala-brandt-thin-prism"):
        p1, p2 = real(p["p1"]), real(p["p2"])
        s1, s2, s3, s4 = (real(p.get(name, 0.0)) for name in ("s1", "s2", "s3", "s4"))
        xy = x * y
        xd += (2.0 * p1) * xy + (2.0 * p2) * (x * x) + r2 * (p2 + s1 + r2 * s2)
        yd += (2.0 * p2) * xy + (2.0 * p1) * (y * y) + r2 * (p1 + s3 + r2 * s4)
    if theta is not None:  # beyond the fisheye's widest ray: no pixel
        xd[np.broadcast_to(theta > distortion.max_angle_rad, xd.shape)] = np.nan
    xd *= real(fx)
    if skew:
        xd += real(skew) * yd
    xd += real(cx)
    yd *= real(fy)
    yd += real(cy)
    return xd, yd


def _polynomial_degree(distortion: Distortion) -> int | None:
    """Total degree of the lens as a polynomial in the pixel ``(u, v)``, or None when it is not one.

    ``polynomial`` and ``opencv`` without the rational terms are polynomials
    in the normalised ``(x, y)`` (``x (1 + k1 r^2 + k2 r^4 + k3 r^6)``:
    degree 7; the tangential and thin-prism terms are of lower degree), and
    ``K^-1`` is affine.
    """
    if distortion.correction is not None:
        return None
    if distortion.model == "none":
        return 1
    if distortion.model == "polynomial" or (
        distortion.model == "opencv" and not any(distortion.params.get(name, 0.0) for name in ("k4", "k5", "k6"))
    ):
        return 7
    return None


def _chebyshev_nodes(values: NDArray, degree: int) -> tuple[NDArray, NDArray]:
    """``degree + 1`` Chebyshev nodes over the range of ``values``, and ``values`` mapped to [-1, 1]."""
    low, high = float(values[0]), float(values[-1])
    half = max(0.5 * (high - low), 0.5)
    middle = 0.5 * (high + low)
    nodes = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
    return middle + half * nodes, (np.asarray(values, dtype=np.float64) - middle) / half


def _st_polynomial(distortion: Distortion, K: NDArray, xs: NDArray, ys: NDArray, degree: int,
                   source_size: tuple[int, int], planes: NDArray[np.float32]) -> None:
    """ST values of a polynomial lens on the grid ``xs x ys``, written into the R and G ``planes`` (shape (3, H, W)).

    A polynomial of degree ``d`` in ``(u, v)`` equals its tensor-product
    Chebyshev interpolant on ``(d + 1)^2`` nodes (exactly, up to rounding):
    ``S = P_v C P_u^T``, with ``C = V^-1 F V^-T`` from the lens evaluated at
    the nodes (``F``, by :meth:`Distortion.distort` itself) and ``P`` the
    Chebyshev polynomials at each row and column, ``C`` cut to its
    numerical rank (``U S V^T``, singular values above 1e-12 of the
    largest: the lens's structure leaves about 5 of 8); the undistorted
    pixel's own ST value (a function of the column for R, of the row for G)
    joins as one more rank-one term. A float32 matrix product per channel
    and block of rows (OpenCV's ``cv2.gemm``), on every core.
    """
    from numpy.polynomial import chebyshev

    u_nodes, u_scaled = _chebyshev_nodes(xs, degree)
    v_nodes, v_scaled = _chebyshev_nodes(ys, degree)
    uu, vv = np.meshgrid(u_nodes, v_nodes)
    nodes = np.stack([uu.ravel(), vv.ravel()], axis=1)
    displacement = distortion.distort(nodes, K) - nodes
    width, height = source_size
    vander = chebyshev.chebvander(np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1)), degree)
    columns = chebyshev.chebvander(u_scaled, degree).T
    rows = chebyshev.chebvander(v_scaled, degree)
    factors = []
    for channel, scale in ((0, 1.0 / width), (1, -1.0 / height)):
        values = scale * displacement[:, channel].reshape(degree + 1, degree + 1)
        coefficients = np.linalg.solve(vander, np.linalg.solve(vander, values.T).T)
        # the lens's structure leaves the coefficients of low rank (about 5 of 8): keep what is not rounding
        left, singular, right = np.linalg.svd(coefficients)
        rank = int(np.sum(singular > 1e-12 * max(singular[0], 1e-300)))
        row_terms, column_terms = rows @ (left[:, :rank] * singular[:rank]), right[:rank] @ columns
        # the undistorted pixel's ST as one more rank-one term: a function of the column (R) or the row (G)
        if channel == 0:
            identity = ((xs + 0.5) / width)[None, :]
            row_terms, column_terms = np.c_[row_terms, np.ones(len(ys))], np.r_[column_terms, identity]
        else:
            identity = (1.0 - (ys + 0.5) / height)[:, None]
            row_terms, column_terms = np.c_[row_terms, identity], np.r_[column_terms, np.ones((1, len(xs)))]
        factors.append((row_terms.astype(np.float32), column_terms.astype(np.float32, order="C")))

    def work(start: int, stop: int) -> None:
        for channel, (row_terms, column_terms) in enumerate(factors):
            # OpenCV's GEMM into the block in place
            cv2.gemm(row_terms[start:stop], column_terms, 1.0, None, 0.0, planes[channel, start:stop])

    # a few large blocks per core: each product streams its rows, and fewer calls cost less
    _blocks(len(ys), work, max(_BLOCK_ROWS, -(-len(ys) // (4 * (os.cpu_count() or 1)))))


def st_of_distorted_grid(distortion: Distortion, K: NDArray, xs: NDArray, ys: NDArray,
                         source_size: tuple[int, int]) -> NDArray[np.float32]:
    """ST values (:func:`st_from_pixels`) of ``distort`` of the ideal pixel grid ``xs x ys``.

    Shape (len(ys), len(xs), 3), a view of channel planes.

    Polynomial lenses (``polynomial``, ``opencv`` without rational terms) as
    matrix products (:func:`_st_polynomial`); the other OpenCV, division and
    fisheye lenses in float32 blocks (:func:`_distort_arrays`); 3DE's lenses
    and a lens with a correction field through :meth:`Distortion.distort`
    itself; in blocks of rows on every core.
    """
    K = np.asarray(K, dtype=np.float64)
    # channel planes, each written contiguously; zeros from the allocator, so blue's pages are never touched here
    planes = np.zeros((3, len(ys), len(xs)), dtype=np.float32)
    degree = _polynomial_degree(distortion)
    if degree is not None:
        _st_polynomial(distortion, K, xs, ys, degree, source_size, planes)
        return np.moveaxis(planes, 0, -1)
    xs32, ys32 = np.asarray(xs, dtype=np.float32), np.asarray(ys, dtype=np.float32)
    width, height = source_size
    generic = distortion.correction is not None or distortion.model not in _VECTORISED_MODELS

    def work(start: int, stop: int) -> None:
        if generic:
            u, v = np.meshgrid(np.asarray(xs, dtype=np.float64), np.asarray(ys[start:stop], dtype=np.float64))
            points = distortion.distort(np.stack([u.ravel(), v.ravel()], axis=1), K)
            X, Y = (points[:, i].reshape(u.shape) for i in (0, 1))
        else:
            X, Y = _distort_arrays(distortion, K, xs32[None, :], ys32[start:stop, None])
        X[~np.isfinite(X) | ~np.isfinite(Y)] = -1.0  # no source pixel: outside the format
        np.divide(X + np.float32(0.5), np.float32(width), out=planes[0, start:stop])
        np.subtract(np.float32(1.0), (Y + np.float32(0.5)) / np.float32(height), out=planes[1, start:stop])

    _blocks(len(ys), work)
    return np.moveaxis(planes, 0, -1)


def undistorted_grid(distortion: Distortion, K: NDArray, size: tuple[int, int]) -> tuple[NDArray, NDArray]:
    """``distortion.undistort`` of every pixel of a ``size`` frame (float64, blocks of rows on every core).

    The ``polynomial`` and ``opencv`` lenses by Newton's method on
    :func:`_distort_arrays` in float64 (the Jacobian by forward
    differences of 1e-4 px, the residual exact), from the distorted pixel,
    to 1e-10 px as :meth:`Distortion.undistort`; a pixel that does not
    converge in 30 steps (past the lens's fold) is NaN. The others (the
    division model's closed form, the fisheyes' radial solve, a correction
    field) through :meth:`Distortion.undistort` itself.
    """
    width, height = size
    X = np.empty((height, width))
    Y = np.empty_like(X)
    xs = np.arange(width, dtype=np.float64)
    generic = distortion.model not in ("polynomial", "opencv") or distortion.correction is not None

    def work(start: int, stop: int) -> None:
        u, v = np.meshgrid(xs, np.arange(start, stop, dtype=np.float64))
        if generic:
            points = distortion.undistort(np.stack([u.ravel(), v.ravel()], axis=1), K)
            X[start:stop], Y[start:stop] = (points[:, i].reshape(u.shape) for i in (0, 1))
            return
        X[start:stop], Y[start:stop] = _newton_inverse(distortion, K, u, v)

    _blocks(height, work)
    return X, Y


def _newton_inverse(distortion: Distortion, K: NDArray, u: NDArray, v: NDArray) -> tuple[NDArray, NDArray]:
    """The ideal pixels ``(x, y)`` whose :func:`_distort_arrays` is ``(u, v)`` (see :func:`undistorted_grid`)."""
    step = 1e-4
    x, y = u.copy(), v.copy()
    for _ in range(30):
        fx, fy = _distort_arrays(distortion, K, x, y)
        rx, ry = fx - u, fy - v
        with np.errstate(invalid="ignore"):
            if np.all((np.abs(rx) < 1e-10) & (np.abs(ry) < 1e-10)):
                return x, y
        ax, ay = _distort_arrays(distortion, K, x + step, y)
        bx, by = _distort_arrays(distortion, K, x, y + step)
        jxx, jyx, jxy, jyy = (ax - fx) / step, (ay - fy) / step, (bx - fx) / step, (by - fy) / step
        with np.errstate(invalid="ignore", divide="ignore"):
            determinant = jxx * jyy - jxy * jyx
            x = x - (jyy * rx - jxy * ry) / determinant
            y = y - (jxx * ry - jyx * rx) / determinant
    fx, fy = _distort_arrays(distortion, K, x, y)
    with np.errstate(invalid="ignore"):
        lost = ~((np.abs(fx - u) < 1e-6) & (np.abs(fy - v) < 1e-6))
    x[lost] = np.nan
    y[lost] = np.nan
    return x, y


@dataclass(frozen=True)
class STMaps:
    """Undistort and redistort ST-maps of one camera.

    Attributes
    ----------
    undistort : ndarray, shape (H + 2 by, W + 2 bx, 3), float32
        For each pixel of the undistorted image's data window (the plate's
        format and the border), the plate pixel to sample.
    redistort : ndarray, shape (H, W, 3), float32
        For each plate pixel, the pixel of the undistorted image (in its
        format, the plate's) to sample.
    plate_size : (int, int)
        The plate's (W, H): the format of both images and of both maps.
    border : (int, int)
        The overscan border ``(bx, by)`` on each side.
    undistorted : Camera
        The undistorted image's whole data window as a camera: ``K`` with
        the principal point moved by the border, no distortion, size
        ``(W + 2 bx, H + 2 by)`` (what a CG render with overscan uses).
    """

    undistort: NDArray[np.float32]
    redistort: NDArray[np.float32]
    plate_size: tuple[int, int]
    border: tuple[int, int]
    undistorted: Camera


def stmap_view(camera: Camera, overscan: float | None = None,
               border: int | tuple[int, int] | None = None) -> UndistortedView:
    """The undistorted image of :func:`make_stmaps`: the plate's ``K`` shifted by the overscan border, the bigger canvas.

    ``overscan`` and ``border`` as :func:`make_stmaps` (by default
    :data:`DEFAULT_OVERSCAN`).
    """
    if overscan is None and border is None:
        overscan = DEFAULT_OVERSCAN
    bx, by = overscan_border(camera.image_size, overscan, border)
    K_new = camera.K.copy()
    K_new[:2, 2] += (bx, by)
    return UndistortedView(K_new, (camera.image_size[0] + 2 * bx, camera.image_size[1] + 2 * by))


def make_stmaps(camera: Camera, overscan: float | None = None,
                border: int | tuple[int, int] | None = None) -> STMaps:
    """Build the undistort and redistort ST-maps of ``camera``.

    Parameters
    ----------
    camera : Camera
        The plate's camera (K, distortion, image size).
    overscan : float, optional
        Overscan factor of the undistorted image (>= 1, see
        :func:`overscan_border`); by default :data:`DEFAULT_OVERSCAN`
        unless ``border`` is given.
    border : int or (int, int), optional
        The overscan border in pixels instead of a factor.

    Returns
    -------
    STMaps

    Notes
    -----
    The undistorted image is a pinhole camera with the plate's own ``K``, so
    its pixel ``x_u`` (in the plate's format, the border at negative and
    beyond-size coordinates) is the ideal pixel itself. Undistort: for
    ``x_u``, the plate pixel ``distort(x_u)`` (the forward model, as OpenCV's
    ``initUndistortRectifyMap``; :func:`st_of_distorted_grid`). Redistort:
    for plate pixel ``x_d``, ``undistort(x_d)`` (the model's inverse to
    1e-10 px; :func:`undistorted_grid`). Pixels with no image (past a
    lens's fold, a fisheye ray beyond its widest angle) sample pixel
    ``(-1, y)``, outside the format (R < 0).
    """
    view = stmap_view(camera, overscan, border)
    width, height = camera.image_size
    bx, by = (view.image_size[0] - width) // 2, (view.image_size[1] - height) // 2
    K = camera.K
    undistort = st_of_distorted_grid(camera.distortion, K, np.arange(-bx, width + bx, dtype=np.float64),
                                     np.arange(-by, height + by, dtype=np.float64), camera.image_size)
    x_u, y_u = undistorted_grid(camera.distortion, K, camera.image_size)
    x_u[~np.isfinite(x_u) | ~np.isfinite(y_u)] = -1.0  # no undistorted pixel: outside the format
    redistort = st_from_pixels(x_u, y_u, camera.image_size)
    undistorted = Undistorter(camera, view, maps=None).undistorted_camera()
    return STMaps(undistort, redistort, camera.image_size, (bx, by), undistorted)
