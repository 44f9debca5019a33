"""Rendered chessboard views with exact corner truth, for the corner tests and bench.

The ideal pattern is integrated over each pixel's area (pixels that an edge
crosses are supersampled on a jittered stratified grid, the others take
their one colour), projected by a homography and, optionally, a
division-model lens; then Gaussian defocus blur, shot and read noise,
8-bit quantisation and JPEG. The corners are the exact images of the
board's inner corners. Pixel (0, 0) is the centre of the top-left pixel;
pixel ``(x, y)`` covers ``[x - 0.5, x + 0.5] x [y - 0.5, y + 0.5]``.
Seeded: the same generator state gives the same view.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

__all__ = ["BoardView", "board_homography", "render_board_view", "corner_crb_px"]


@dataclass(frozen=True)
class BoardView:
    """One rendered view.

    Attributes
    ----------
    image : ndarray of uint8, shape (H, W)
        What a camera delivers (blurred, noisy, quantised, JPEG unless None).
    clean : ndarray of float32, shape (H, W)
        The noise-free blurred render (glare included), in the image's 8-bit units.
    corners_px : ndarray, shape (rows * columns, 2)
        Exact inner corners, row-major (id = row * columns + col).
    columns, rows : int
        Inner corners per row and per column.
    square_px : ndarray, shape (rows * columns,)
        Smallest distance from each corner to a grid neighbour (px).
    noise_var : ndarray of float32, shape (H, W)
        Per-pixel variance of the noise (shot + read + quantisation), in
        8-bit units squared; JPEG is not in it.
    """

    image: NDArray[np.uint8]
    clean: NDArray[np.float32]
    corners_px: NDArray[np.float64]
    columns: int
    rows: int
    square_px: NDArray[np.float64]
    noise_var: NDArray[np.float32]


def board_homography(image_size: tuple[int, int], columns: int, rows: int, square_px: float, tilt_deg: float = 0.0,
                     tilt_axis_deg: float = 0.0, roll_deg: float = 0.0, centre_px: tuple[float, float] | None = None,
                     focal_px: float | None = None) -> NDArray[np.float64]:
    """Homography from board units (inner corner ``(i, j)`` at ``(i, j)``) to undistorted pixels.

    A pinhole camera (focal ``focal_px``, default 1.2 x the larger image
    side) sees the board's centre at ``centre_px`` at unit depth, rolled by
    ``roll_deg`` and tilted by ``tilt_deg`` about an in-plane axis at
    ``tilt_axis_deg``; squares near the board's centre are ``square_px`` wide.
    """
    width, height = image_size
    f = focal_px or 1.2 * max(width, height)
    cx, cy = centre_px if centre_px is not None else ((width - 1) / 2, (height - 1) / 2)
    axis = np.radians(tilt_axis_deg)
    R = (Rotation.from_rotvec(np.radians(tilt_deg) * np.array([np.cos(axis), np.sin(axis), 0.0]))
         * Rotation.from_rotvec([0.0, 0.0, np.radians(roll_deg)])).as_matrix()
    scale = square_px / f
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    centre = scale * np.array([(columns - 1) / 2, (rows - 1) / 2, 0.0])
    t = np.array([0.0, 0.0, 1.0]) - R @ centre
    return K @ np.column_stack([R[:, 0] * scale, R[:, 1] * scale, t])


def _undistort(x: NDArray, y: NDArray, centre: tuple[float, float], lam: float) -> tuple[NDArray, NDArray]:
    """Division model: ``x_u = c + (x_d - c) / (1 + lambda r_d^2)``."""
    if lam == 0:
        return x, y
    dx, dy = x - centre[0], y - centre[1]
    factor = 1.0 / (1.0 + lam * (dx * dx + dy * dy))
    return centre[0] + dx * factor, centre[1] + dy * factor


def _distort(points: NDArray, centre: tuple[float, float], lam: float) -> NDArray:
    """Inverse of :func:`_undistort`: ``r_d = (1 - sqrt(1 - 4 lambda r_u^2)) / (2 lambda r_u)``."""
    if lam == 0:
        return points.copy()
    d = points - np.asarray(centre)
    r_u = np.hypot(d[:, 0], d[:, 1])
    disc = 1.0 - 4.0 * lam * r_u**2
    if np.any(disc < 0):
        raise ValueError("a corner lies beyond the division model's fold")
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(r_u > 0, (1.0 - np.sqrt(disc)) / (2.0 * lam * np.where(r_u > 0, r_u, 1.0) ** 2), 1.0)
    return np.asarray(centre) + d * ratio[:, None]


def _pattern(x: NDArray, y: NDArray, Hinv: NDArray, columns: int, rows: int, lens: tuple[tuple[float, float], float],
             levels: tuple[float, float, float]) -> NDArray:
    """Ideal intensity at distorted pixel positions: squares, a white margin, a grey background."""
    xu, yu = _undistort(x, y, *lens)
    w = Hinv[2, 0] * xu + Hinv[2, 1] * yu + Hinv[2, 2]
    u = (Hinv[0, 0] * xu + Hinv[0, 1] * yu + Hinv[0, 2]) / w
    v = (Hinv[1, 0] * xu + Hinv[1, 1] * yu + Hinv[1, 2]) / w
    black, white, background = levels
    on_board = (u >= -1) & (u < columns) & (v >= -1) & (v < rows) & (w > 0)
    on_margin = (u >= -1.6) & (u < columns + 0.6) & (v >= -1.6) & (v < rows + 0.6) & (w > 0)
    dark = (np.floor(u) + np.floor(v)) % 2 == 0
    return np.where(on_board, np.where(dark, black, white), np.where(on_margin, white, background))


def render_board_view(
    rng: np.random.Generator,
    image_size: tuple[int, int],
    H: NDArray,
    columns: int,
    rows: int,
    blur_px: float,
    *,
    distortion: float = 0.0,
    distortion_centre: tuple[float, float] | None = None,
    levels: tuple[float, float, float] = (30.0, 210.0, 110.0),
    full_well_e: float = 5000.0,
    read_noise_e: float = 5.0,
    jpeg_quality: int | None = 90,
    supersample: int = 16,
    glare: NDArray | None = None,
) -> BoardView:
    """Render one view of a chessboard with ``columns x rows`` inner corners.

    Parameters
    ----------
    rng : numpy.random.Generator
        Jitter of the supersampling and the noise.
    image_size : (int, int)
        Width, height.
    H : ndarray, shape (3, 3)
        Board units to undistorted pixels (:func:`board_homography`).
    blur_px : float
        Gaussian defocus, standard deviation in pixels (0: none).
    distortion : float
        Division-model lambda (px^-2) about ``distortion_centre`` (default
        the image centre); negative is barrel.
    levels : (float, float, float)
        Black, white and background in 8-bit units.
    full_well_e, read_noise_e : float
        Electrons at 255 and the read noise (electrons, rms).
    jpeg_quality : int or None
        JPEG quality of the delivered image; None keeps the 8-bit image.
    supersample : int
        Stratified samples per side in pixels that an edge crosses.
    glare : ndarray, shape (H, W), optional
        Light added to the blurred render before the noise (8-bit units):
        veiling glare or a reflection, which brightens dark and light
        squares alike (a dark square can end up brighter than a light one).
    """
    width, height = image_size
    centre = distortion_centre if distortion_centre is not None else ((width - 1) / 2, (height - 1) / 2)
    lens = (centre, float(distortion))
    Hinv = np.linalg.inv(H)
    # the colour at every pixel corner: pixels whose four corners agree are uniform
    ys, xs = np.mgrid[-0.5 : height, -0.5 : width]
    lattice = _pattern(xs, ys, Hinv, columns, rows, lens, levels)
    del xs, ys
    image = _pattern(*np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)),
                     Hinv, columns, rows, lens, levels)
    corners4 = np.stack([lattice[:-1, :-1], lattice[1:, :-1], lattice[:-1, 1:], lattice[1:, 1:]])
    ey, ex = np.nonzero(corners4.min(0) != corners4.max(0))
    del lattice, corners4
    n = supersample
    cells = (np.arange(n) + 0.0) / n - 0.5
    for start in range(0, len(ex), 20000):
        bx, by = ex[start : start + 20000], ey[start : start + 20000]
        jitter = rng.random((len(bx), n, n, 2)) / n
        sx = bx[:, None, None] + cells[None, None, :] + jitter[..., 0]
        sy = by[:, None, None] + cells[None, :, None] + jitter[..., 1]
        image[by, bx] = _pattern(sx, sy, Hinv, columns, rows, lens, levels).mean(axis=(1, 2))
    clean = image.astype(np.float32)
    if blur_px > 0:
        clean = cv2.GaussianBlur(clean, (0, 0), blur_px, borderType=cv2.BORDER_REFLECT)
    if glare is not None:
        clean = clean + np.asarray(glare, dtype=np.float32)
    gain = full_well_e / 255.0  # electrons per 8-bit unit
    electrons = rng.poisson(np.maximum(clean, 0.0) * gain).astype(np.float64)
    noisy = (electrons + rng.normal(0.0, read_noise_e, clean.shape)) / gain
    image8 = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    if jpeg_quality is not None:
        ok, buffer = cv2.imencode(".jpg", image8, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        image8 = cv2.imdecode(buffer, cv2.IMREAD_GRAYSCALE)
    noise_var = (np.maximum(clean, 0.0) / gain + (read_noise_e / gain) ** 2 + 1.0 / 12.0).astype(np.float32)
    j, i = np.mgrid[0:rows, 0:columns]
    board = np.stack([i.ravel(), j.ravel(), np.ones(i.size)], axis=1) @ H.T
    corners = _distort(board[:, :2] / board[:, 2:], centre, float(distortion))
    grid = corners.reshape(rows, columns, 2)
    spacing = np.full((rows, columns), np.inf)
    for axis in (0, 1):
        step = np.linalg.norm(np.diff(grid, axis=axis), axis=2)
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        before = np.pad(step, pad, constant_values=np.inf)
        pad[axis] = (0, 1)
        after = np.pad(step, pad, constant_values=np.inf)
        spacing = np.minimum(spacing, np.minimum(before, after))
    return BoardView(image8, clean, corners, columns, rows, spacing.ravel(), noise_var)


def corner_crb_px(view: BoardView, window_fraction: float = 0.65) -> NDArray[np.float64]:
    """Cramer-Rao lower bound of each corner's position (px per axis), from the noise-free render.

    The Fisher information of the 2-D translation of the corner's noise-free
    neighbourhood (a disc of radius ``window_fraction`` x the local square
    size) under the render's noise (shot + read + quantisation, per pixel;
    JPEG left out): ``F = sum_p g_p g_p^T / var_p``, ``g`` the central-difference
    gradient of :attr:`BoardView.clean`. Returns ``sqrt(trace(F^-1) / 2)``,
    NaN for corners whose disc leaves the image.
    """
    height, width = view.clean.shape
    out = np.full(len(view.corners_px), np.nan)
    for i, ((x, y), square) in enumerate(zip(view.corners_px, view.square_px)):
        radius = window_fraction * square
        half = int(np.ceil(radius)) + 1
        xi, yi = int(round(x)), int(round(y))
        if xi - half - 1 < 0 or yi - half - 1 < 0 or xi + half + 1 >= width or yi + half + 1 >= height:
            continue
        patch = view.clean[yi - half - 1 : yi + half + 2, xi - half - 1 : xi + half + 2].astype(np.float64)
        var = view.noise_var[yi - half : yi + half + 1, xi - half : xi + half + 1].astype(np.float64)
        gx = 0.5 * (patch[1:-1, 2:] - patch[1:-1, :-2])
        gy = 0.5 * (patch[2:, 1:-1] - patch[:-2, 1:-1])
        oy, ox = np.mgrid[yi - half : yi + half + 1, xi - half : xi + half + 1]
        weight = (np.hypot(ox - x, oy - y) <= radius) / var
        F = np.array([[np.sum(weight * gx * gx), np.sum(weight * gx * gy)],
                      [np.sum(weight * gx * gy), np.sum(weight * gy * gy)]])
        out[i] = np.sqrt(np.trace(np.linalg.inv(F)) / 2)
    return out
