"""Straight-line observations: points on straight world lines, from chessboards or from image edges.

Line observations come from (a) the rows and columns of detected
chessboard corners or (b) edges in ordinary images (Canny, then chaining
of nearly straight pieces, located to sub-pixel along the gradient,
Devernay 1995); the plumb-line fit (:mod:`camcal.geometry.plumbline`)
makes them straight. Pixel (0, 0) is the centre of the top-left pixel.

References
----------
Devernay, F. (1995). A non-maxima suppression method for edge detection
with sub-pixel accuracy. INRIA research report 2724.
Strand, R. & Hayman, E. (2005). Correcting radial distortion by circle
fitting. Proc. British Machine Vision Conference (BMVC).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.ndimage
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, detect_board

__all__ = [
    "LineSet",
    "detect_chessboard_lines",
    "fit_circle",
    "lines_from_chessboard",
    "lines_from_edges",
    "lines_from_images",
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


def lines_from_images(images: Iterable[NDArray], pattern_size: tuple[int, int] | None = None) -> tuple[LineSet, list[int]]:
    """Lines from several images: chessboard rows/columns, or edges.

    Parameters
    ----------
    images : iterable of ndarray
        Images of one camera (same size), taken one at a time (a generator
        of video frames holds one frame in memory).
    pattern_size : (int, int), optional
        Inner corners (cols, rows) of a chessboard; ``None`` uses edges.

    Returns
    -------
    lines : LineSet
        All lines together.
    skipped : list of int
        Indices of images that gave no lines.
    """
    total, skipped = None, []
    for number, image in enumerate(images):
        size = (image.shape[1], image.shape[0])
        if total is None:
            total = LineSet((), size)
        elif size != total.image_size:
            raise CamcalError(f"images must all have the same size, got {sorted({tuple(total.image_size), size})}")
        found = detect_chessboard_lines(image, pattern_size) if pattern_size else lines_from_edges(image)
        if found is None or not found.lines:
            skipped.append(number)
            continue
        total = total + found
    if total is None:
        raise CamcalError("no images given")
    return total, skipped
