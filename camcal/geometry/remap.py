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

from camcal.base.errors import CamcalError
from camcal.model.rig import Camera

__all__ = ["RemapMaps", "build_maps", "build_maps_reference", "undistort_homography"]


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


def _output_pixels(H_inv: NDArray[np.float64], width: int, height: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Undistorted source pixels ``H^-1 x_o`` of every output pixel, as two (H_out, W_out) arrays."""
    u = np.arange(width, dtype=np.float64)[None, :]
    v = np.arange(height, dtype=np.float64)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = H_inv[2, 0] * u + H_inv[2, 1] * v + H_inv[2, 2]
        x = (H_inv[0, 0] * u + H_inv[0, 1] * v + H_inv[0, 2]) / w
        y = (H_inv[1, 0] * u + H_inv[1, 1] * v + H_inv[1, 2]) / w
    return x, y


def _finish(x: NDArray[np.float64], y: NDArray[np.float64]) -> RemapMaps:
    """float32 maps with the no-source sentinel -1 wherever either coordinate is not finite."""
    bad = ~(np.isfinite(x) & np.isfinite(y))
    map_x = x.astype(np.float32)
    map_y = y.astype(np.float32)
    map_x[bad] = -1.0
    map_y[bad] = -1.0
    return RemapMaps(map_x=map_x, map_y=map_y)


def _check_size(output_size: tuple[int, int]) -> tuple[int, int]:
    width, height = output_size
    if width <= 0 or height <= 0:
        raise CamcalError(f"output size must be positive, got {width}x{height}")
    return int(width), int(height)


def build_maps_reference(camera: Camera, H: ArrayLike, output_size: tuple[int, int]) -> RemapMaps:
    """:func:`build_maps` evaluated point by point with :meth:`Distortion.distort` (float64).

    The reference the fast paths of :func:`build_maps` are tested against;
    same parameters and result.
    """
    width, height = _check_size(output_size)
    x, y = _output_pixels(np.linalg.inv(np.asarray(H, dtype=np.float64)), width, height)
    source = camera.distortion.distort(np.stack([x.ravel(), y.ravel()], axis=1), camera.K)
    return _finish(source[:, 0].reshape(height, width), source[:, 1].reshape(height, width))


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

    Notes
    -----
    Two fast evaluations of the same formula as
    :func:`build_maps_reference` (they agree to float32 rounding, tested
    to < 1e-3 px):

    - ``none`` / ``polynomial`` / ``opencv`` without skew:
      ``cv2.initUndistortRectifyMap(K, dist, I, H K, size, CV_32FC1)``
      (``dist`` OpenCV's 5-, 8- or 12-vector, rational and thin prism
      included).
      OpenCV samples ``K distort((P R)^-1 x_o)`` for a new camera matrix
      ``P`` and rectifying rotation ``R``; with ``R = I`` and ``P = H K``,
      ``(H K)^-1 x_o = K^-1 H^-1 x_o`` is the normalised undistorted point
      of ``H^-1 x_o``, exactly the reference. OpenCV ignores the skew of
      ``K``, so a skewed camera takes the reference path.
    - ``kannala-brandt`` without skew, when the model is one-to-one up to
      90 degrees: ``cv2.fisheye.initUndistortRectifyMap(K, D, I, H K,
      size, CV_32FC1)``, the same construction with OpenCV's fisheye
      projection (``theta = atan(r)``, ``theta_d`` scaled onto ``x / r``).
    - ``division``: the closed-form inverse of Strand & Hayman's model
      (:meth:`Distortion.distort`), evaluated on (H_out, W_out) arrays
      built by broadcasting a row and a column, without (N, 2) copies.
    """
    width, height = _check_size(output_size)
    H = np.asarray(H, dtype=np.float64)
    distortion = camera.distortion
    if distortion.has_correction:  # OpenCV's maps know no correction field: the lens's own inverse
        return build_maps_reference(camera, H, output_size)
    if distortion.model in ("none", "polynomial", "opencv") and camera.K[0, 1] == 0.0:
        map_x, map_y = cv2.initUndistortRectifyMap(
            camera.K, distortion.opencv_coefficients(), np.eye(3), H @ camera.K, (width, height), cv2.CV_32FC1
        )
        return _finish(map_x, map_y)
    if distortion.model == "kannala-brandt" and camera.K[0, 1] == 0.0 and distortion.max_angle_rad >= 0.5 * np.pi:
        coefficients = np.array([distortion.params[k] for k in ("k1", "k2", "k3", "k4")])
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(
            camera.K, coefficients, np.eye(3), H @ camera.K, (width, height), cv2.CV_32FC1
        )
        return _finish(map_x, map_y)
    if distortion.model == "division":
        x, y = _output_pixels(np.linalg.inv(H), width, height)
        cx, cy = distortion.center if distortion.center is not None else camera.K[:2, 2]
        x -= cx
        y -= cy
        aspect = distortion.params.get("aspect", 1.0)
        discriminant = 1.0 - 4.0 * distortion.params["lambda"] * (x * x + aspect * aspect * y * y)
        with np.errstate(invalid="ignore"):
            scale = 2.0 / (1.0 + np.sqrt(discriminant))
        scale[discriminant < 0.0] = np.nan
        x *= scale
        y *= scale
        return _finish(x + cx, y + cy)
    return build_maps_reference(camera, H, output_size)
