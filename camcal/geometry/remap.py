"""One-resampling image warps: undistortion, rectification, or both at once.

A warp is defined by a homography ``H`` from UNDISTORTED pixels of the
source camera to output pixels. For each output pixel ``x_o`` the source
pixel to sample is ``distort(H^-1 x_o)``: undistortion uses
``H = K_new K^-1``, rectification the rig's ``rectification.H``; both are
done by ONE ``cv2.remap`` (never two resamplings). Pixel (0, 0) is the
centre of the top-left pixel in both images, as ``cv2.remap`` assumes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.errors import CamcalError
from camcal.rig import Camera

__all__ = ["RemapMaps", "build_maps", "undistort_homography"]


@dataclass(frozen=True)
class RemapMaps:
    """Float32 source-pixel maps for ``cv2.remap``, built once per camera.

    Attributes
    ----------
    map_x, map_y : ndarray, shape (H_out, W_out), float32
        Source pixel of each output pixel; -1 where no source pixel exists
        (beyond the range of the distortion model).
    """

    map_x: NDArray[np.float32]
    map_y: NDArray[np.float32]

    @property
    def output_size(self) -> tuple[int, int]:
        """(width, height) of the output image."""
        return self.map_x.shape[1], self.map_x.shape[0]

    def apply(
        self,
        image: NDArray,
        interpolation: int = cv2.INTER_LINEAR,
        border_value: float = 0.0,
    ) -> NDArray:
        """Warp ``image`` (any depth and channel count ``cv2.remap`` takes)."""
        return cv2.remap(
            image, self.map_x, self.map_y, interpolation,
            borderMode=cv2.BORDER_CONSTANT, borderValue=border_value,
        )


def undistort_homography(camera: Camera, K_new: ArrayLike) -> NDArray[np.float64]:
    """``H = K_new K^-1``: undistorted pixels of ``camera`` -> pixels of ``K_new``."""
    return np.asarray(K_new, dtype=np.float64) @ np.linalg.inv(camera.K)


def build_maps(camera: Camera, H: ArrayLike, output_size: tuple[int, int]) -> RemapMaps:
    """Maps that sample ``camera``'s image at ``distort(H^-1 x_o)``.

    Parameters
    ----------
    camera : Camera
        The source camera (its K and distortion).
    H : array_like, shape (3, 3)
        Undistorted source pixels -> output pixels.
    output_size : (int, int)
        Output (width, height).

    Returns
    -------
    RemapMaps
    """
    width, height = output_size
    if width <= 0 or height <= 0:
        raise CamcalError(f"output size must be positive, got {width}x{height}")
    H_inv = np.linalg.inv(np.asarray(H, dtype=np.float64))
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    output = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    undistorted = output @ H_inv.T
    with np.errstate(divide="ignore", invalid="ignore"):
        undistorted = undistorted[:, :2] / undistorted[:, 2:]
    source = camera.distortion.distort(undistorted, camera.K)
    source[~np.all(np.isfinite(source), axis=1)] = -1.0
    return RemapMaps(
        map_x=source[:, 0].reshape(height, width).astype(np.float32),
        map_y=source[:, 1].reshape(height, width).astype(np.float32),
    )
