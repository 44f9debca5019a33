"""Plumb-line lens calibration: straight lines in the world must be straight in the image.

Line observations come from (a) the rows and columns of detected
chessboard corners or (b) edges in ordinary images (Canny, then chaining
of nearly straight pieces). Two estimators follow the literature:

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

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.ndimage
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, detect_board
from camcal.model.distortion import Distortion, fit_distortion
from camcal.base.jsonfile import read_json, write_json

__all__ = [
    "LineSet",
    "StrandHaymanEstimate",
    "PlumblineResult",
    "lines_from_chessboard",
    "detect_chessboard_lines",
    "lines_from_edges",
    "fit_circle",
    "straightness_rms",
    "estimate_division_StrandHayman2005",
    "refine_DevernayFaugeras2001",
    "fit_plumbline",
    "lines_from_images",
    "read_lines",
    "write_lines",
]

_MIN_POINTS_PER_LINE = 5


# -- line observations ------------------------------------------------------------


@dataclass(frozen=True)
class LineSet:
    """Image points that lie on straight world lines, grouped by line.

    Attributes
    ----------
    lines : tuple of ndarray, each shape (N_i, 2)
        Distorted pixel coordinates of each line's points, N_i >= 5.
    image_size : (int, int)
        (width, height) of the images the points come from.
    """

    lines: tuple[NDArray[np.float64], ...]
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        size = tuple(self.image_size)
        if len(size) != 2 or not all(isinstance(v, (int, np.integer)) and v > 0 for v in size):
            raise CamcalError(f"image_size must be [width, height] as positive integers, got {self.image_size!r}")
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        lines = []
        for index, line in enumerate(self.lines):
            array = np.array(line, dtype=np.float64)
            if array.ndim != 2 or array.shape[1] != 2:
                raise CamcalError(f"line {index} must be a list of [x, y] points, got shape {array.shape}")
            if len(array) < _MIN_POINTS_PER_LINE:
                raise CamcalError(f"line {index} has {len(array)} points, need at least {_MIN_POINTS_PER_LINE}")
            if not np.all(np.isfinite(array)):
                raise CamcalError(f"line {index} contains NaN or infinite coordinates")
            array.setflags(write=False)
            lines.append(array)
        object.__setattr__(self, "lines", tuple(lines))

    def __add__(self, other: LineSet) -> LineSet:
        if self.image_size != other.image_size:
            raise CamcalError(f"lines from images of different sizes: {self.image_size} and {other.image_size}")
        return LineSet(self.lines + other.lines, self.image_size)

    @property
    def n_points(self) -> int:
        """Total number of points over all lines."""
        return int(sum(len(line) for line in self.lines))


def read_lines(path: str | os.PathLike) -> LineSet:
    """Read ``{"image_size": [W, H], "lines": [[[x, y], ...], ...]}``."""
    data = read_json(path, "lines file")
    if not isinstance(data, dict) or set(data) != {"image_size", "lines"}:
        raise CamcalError(f"{path}: a lines file holds exactly the keys image_size and lines")
    if not isinstance(data["lines"], list):
        raise CamcalError(f"{path}: 'lines' must be a list of lines")
    try:
        return LineSet(tuple(data["lines"]), tuple(data["image_size"]) if isinstance(data["image_size"], list) else data["image_size"])
    except (CamcalError, TypeError, ValueError) as error:
        raise CamcalError(f"{path}: {error}") from None


def write_lines(path: str | os.PathLike, lines: LineSet) -> Path:
    """Write a lines file (atomically); inverse of :func:`read_lines`."""
    return write_json(path, {"image_size": list(lines.image_size), "lines": [line.tolist() for line in lines.lines]})


def lines_from_chessboard(corners: ArrayLike, pattern_size: tuple[int, int], image_size: tuple[int, int]) -> LineSet:
    """Rows and columns of a chessboard's inner corners as lines.

    Parameters
    ----------
    corners : array_like, shape (cols * rows, 2) or (cols * rows, 1, 2)
        Corners in OpenCV's order (row by row, ``cols`` per row).
    pattern_size : (int, int)
        Inner corners per row and per column (``cols, rows``), as OpenCV.
    image_size : (int, int)
        (width, height) of the image.

    Returns
    -------
    LineSet
        ``rows`` lines of ``cols`` points and ``cols`` lines of ``rows``
        points (lines with fewer than 5 points are left out).
    """
    cols, rows = pattern_size
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    lines = [grid[r] for r in range(rows)] + [grid[:, c] for c in range(cols)]
    return LineSet(tuple(line for line in lines if len(line) >= _MIN_POINTS_PER_LINE), image_size)


def detect_chessboard_lines(image: NDArray, pattern_size: tuple[int, int]) -> LineSet | None:
    """Find a chessboard (:func:`camcal.geometry.board.detect_board`); its rows and columns.

    Returns ``None`` when the board is not found in ``image``.
    """
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    found = detect_board(Board("chessboard", int(pattern_size[0]), int(pattern_size[1]), 1.0), grey)
    if found is None:
        return None
    return lines_from_chessboard(found.corners_px, pattern_size, (grey.shape[1], grey.shape[0]))


def _split_chains(contour: NDArray[np.intp]) -> list[NDArray[np.float64]]:
    """A contour of a thin edge visits its pixels twice: keep first visits,
    cut where consecutive kept pixels are not neighbours."""
    points = contour.reshape(-1, 2)
    _, first = np.unique(points, axis=0, return_index=True)
    ordered = points[np.sort(first)].astype(np.float64)
    if len(ordered) < 2:
        return []
    jumps = np.flatnonzero(np.abs(np.diff(ordered, axis=0)).max(axis=1) > 1) + 1
    return [piece for piece in np.split(ordered, jumps) if len(piece) >= 2]


def _straight_pieces(chain: NDArray[np.float64], tolerance_px: float, min_length_px: float) -> list[NDArray[np.float64]]:
    """Cut a pixel chain at the vertices of its Douglas-Peucker polygon."""
    vertices = cv2.approxPolyDP(chain.astype(np.float32).reshape(-1, 1, 2), tolerance_px, False).reshape(-1, 2)
    # indices of the polygon vertices along the chain
    index = [int(np.argmin(np.abs(chain - vertex).sum(axis=1))) for vertex in vertices]
    pieces = []
    for start, stop in zip(index[:-1], index[1:]):
        lo, hi = min(start, stop), max(start, stop)
        piece = chain[lo : hi + 1]
        if np.linalg.norm(piece[-1] - piece[0]) >= min_length_px:
            pieces.append(piece)
    return pieces


def _subpixel_edges(blurred: NDArray[np.uint8], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Move integer edge pixels to the gradient-magnitude peak across the edge.

    Notes
    -----
    A parabola through the gradient magnitude at ``p - n``, ``p``, ``p + n``
    (``n`` the unit gradient direction) peaks at offset
    ``0.5 (m_- - m_+) / (m_- - 2 m_0 + m_+)`` along ``n`` (Devernay 1995).
    """
    image = blurred.astype(np.float32)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.hypot(gx, gy)
    cols, rows = points[:, 0].astype(np.intp), points[:, 1].astype(np.intp)
    direction = np.stack([gx[rows, cols], gy[rows, cols]], axis=1)
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)

    def sample(at: NDArray[np.float64]) -> NDArray[np.float64]:
        return scipy.ndimage.map_coordinates(magnitude, [at[:, 1], at[:, 0]], order=1, mode="nearest")

    minus, centre, plus = sample(points - direction), magnitude[rows, cols], sample(points + direction)
    curvature = minus - 2.0 * centre + plus
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (minus - plus) / curvature, 0.0)
    return points + np.clip(offset, -0.5, 0.5)[:, None] * direction


def lines_from_edges(
    image: NDArray,
    *,
    canny_thresholds: tuple[float, float] = (50.0, 150.0),
    piece_tolerance_px: float = 1.0,
    min_piece_px: float = 12.0,
    max_turn_deg: float = 4.0,
    max_gap_frac: float = 0.04,
    min_length_frac: float = 0.15,
    max_rms_px: float = 0.8,
    max_lines: int = 200,
) -> LineSet:
    """Long, nearly straight edges of an ordinary image as line observations.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
        A photograph with straight world edges (buildings, boards, frames).
    canny_thresholds : (float, float)
        Hysteresis thresholds of ``cv2.Canny``.
    piece_tolerance_px : float
        Douglas-Peucker tolerance that cuts edge chains into straight pieces.
    min_piece_px : float
        Shortest piece kept.
    max_turn_deg, max_gap_frac : float
        Two pieces chain when their directions differ by less than
        ``max_turn_deg``, an end of one is within ``max_gap_frac`` times the
        image diagonal of an end of the other (bridging junctions and small
        occlusions), and each end lies within ``2 piece_tolerance_px`` of the
        other piece's line.
    min_length_frac : float
        Shortest chained line kept, as a fraction of the image diagonal.
    max_rms_px : float
        A chained line is kept only if a circle (the image of a line under
        radial distortion) fits its pixels to this RMS.
    max_lines : int
        At most this many lines, the longest.

    Returns
    -------
    LineSet
        Edge points grouped by line: Canny pixels moved to the sub-pixel
        peak of the gradient magnitude across the edge.

    Notes
    -----
    Chaining is greedy over pairs ordered by gap (union-find), so curved
    images of straight lines, cut by Douglas-Peucker into slightly turning
    pieces, join up again while corners (large turns) do not.
    """
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if grey.dtype != np.uint8:
        raise CamcalError(f"edge detection needs an 8-bit image, got {grey.dtype}")
    height, width = grey.shape
    diagonal = float(np.hypot(width, height))
    blurred = cv2.GaussianBlur(grey, (5, 5), 1.0)
    edges = cv2.Canny(blurred, *canny_thresholds, L2gradient=True)
    contours, _ = cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    pieces: list[NDArray[np.float64]] = []
    for contour in contours:
        for chain in _split_chains(contour):
            pieces.extend(_straight_pieces(chain, piece_tolerance_px, min_piece_px))
    if not pieces:
        return LineSet((), (width, height))

    starts = np.array([p[0] for p in pieces])
    ends = np.array([p[-1] for p in pieces])
    directions = (ends - starts) / np.linalg.norm(ends - starts, axis=1, keepdims=True)
    normals = np.stack([-directions[:, 1], directions[:, 0]], axis=1)
    cos_turn = np.abs(directions @ directions.T)
    # smallest distance between any endpoints of two pieces
    endpoints = np.stack([starts, ends], axis=1)  # (n, 2, 2)
    gaps = np.linalg.norm(endpoints[:, None, :, None, :] - endpoints[None, :, None, :, :], axis=-1).min(axis=(2, 3))
    # lateral offsets of each piece's ends from the other's line
    offset_ij = np.abs(np.einsum("jk,ijmk->ijm", normals, endpoints[:, None] - starts[None, :, None, :])).max(axis=2)
    lateral = np.maximum(offset_ij, offset_ij.T)
    joinable = (cos_turn > np.cos(np.radians(max_turn_deg))) & (gaps < max_gap_frac * diagonal) & (lateral < 2 * piece_tolerance_px)
    np.fill_diagonal(joinable, False)
    parent = np.arange(len(pieces))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    pairs = np.argwhere(np.triu(joinable))
    for i, j in pairs[np.argsort(gaps[pairs[:, 0], pairs[:, 1]])]:
        parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(len(pieces)):
        groups.setdefault(root(i), []).append(i)

    candidates = []
    for members in groups.values():
        points = np.unique(np.concatenate([pieces[i] for i in members]), axis=0)
        extent = np.ptp(points @ directions[members[0]])
        if extent < min_length_frac * diagonal or len(points) < _MIN_POINTS_PER_LINE:
            continue
        if _circle_rms(points) > max_rms_px:
            continue
        order = np.argsort(points @ directions[members[0]])
        candidates.append((extent, _subpixel_edges(blurred, points[order])))
    candidates.sort(key=lambda item: -item[0])
    return LineSet(tuple(points for _, points in candidates[:max_lines]), (width, height))


# -- circles (Strand & Hayman 2005) -----------------------------------------------


def fit_circle(points: ArrayLike) -> NDArray[np.float64]:
    """Algebraic circle (or line) through points: ``A (x^2 + y^2) + B x + C y + D = 0``.

    Parameters
    ----------
    points : array_like, shape (N, 2), N >= 3
        Coordinates, ideally of order 1 (normalise pixels first).

    Returns
    -------
    ndarray, shape (4,)
        ``(A, B, C, D)`` with unit norm and ``A >= 0``; ``A = 0`` is a
        straight line. With ``A != 0`` this is Strand & Hayman's
        ``x^2 + y^2 + a x + b y + k = 0`` with ``(a, b, k) = (B, C, D) / A``.

    Notes
    -----
    The smallest right singular vector of the design matrix with rows
    ``[x^2 + y^2, x, y, 1]``: linear least squares on the algebraic
    distance (Strand & Hayman 2005, section 3). Keeping ``A`` free rather
    than dividing by it keeps nearly straight lines (huge radii) well
    conditioned.
    """
    points = np.asarray(points, dtype=np.float64)
    x, y = points[:, 0], points[:, 1]
    design = np.stack([x * x + y * y, x, y, np.ones_like(x)], axis=1)
    coefficients = np.linalg.svd(design, full_matrices=False)[2][-1]
    return coefficients if coefficients[0] >= 0 else -coefficients


def _circle_rms(points: NDArray[np.float64]) -> float:
    """RMS geometric distance of points to their algebraic circle (or line), in input units."""
    centre = points.mean(axis=0)
    scale = max(float(np.abs(points - centre).max()), 1e-12)
    A, B, C, D = fit_circle((points - centre) / scale)
    local = (points - centre) / scale
    if abs(A) < 1e-12:
        distance = (local @ np.array([B, C]) + D) / np.hypot(B, C)
    else:
        middle = -np.array([B, C]) / (2 * A)
        radius = np.sqrt(max(middle @ middle - D / A, 0.0))
        distance = np.linalg.norm(local - middle, axis=1) - radius
    return float(np.sqrt(np.mean(distance**2)) * scale)


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


def lines_from_images(images: Sequence[NDArray], pattern_size: tuple[int, int] | None = None) -> tuple[LineSet, list[int]]:
    """Lines from several images: chessboard rows/columns, or edges.

    Parameters
    ----------
    images : sequence of ndarray
        Images of one camera (same size).
    pattern_size : (int, int), optional
        Inner corners (cols, rows) of a chessboard; ``None`` uses edges.

    Returns
    -------
    lines : LineSet
        All lines together.
    skipped : list of int
        Indices of images that gave no lines.
    """
    if not images:
        raise CamcalError("no images given")
    sizes = {(image.shape[1], image.shape[0]) for image in images}
    if len(sizes) != 1:
        raise CamcalError(f"images must all have the same size, got {sorted(sizes)}")
    size = sizes.pop()
    total = LineSet((), size)
    skipped = []
    for number, image in enumerate(images):
        found = detect_chessboard_lines(image, pattern_size) if pattern_size else lines_from_edges(image)
        if found is None or not found.lines:
            skipped.append(number)
            continue
        total = total + found
    return total, skipped
