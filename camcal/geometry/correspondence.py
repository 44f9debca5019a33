"""Dense stereo correspondences of a rectified pair: SGBM both ways with a left-right check.

Hirschmuller (2008). Used by the image route of ``colour match``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = [
    "Correspondences",
    "stereo_correspondences",
]


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
