"""ST-maps: float images that tell a comp package (Nuke STMap, Fusion, Natron) where to sample.

Each pixel of an ST-map holds, in its red and green channels, the position
of the SOURCE pixel to sample, normalised to the source image:

    R = (x + 0.5) / W,    G = 1 - (y + 0.5) / H

with ``(x, y)`` the source pixel (pixel (0, 0) at the centre of the
top-left pixel, y down) and ``W x H`` the source size; blue is 0. The
flip of G follows Nuke, whose UV origin is the bottom-left corner.

Two maps per camera:

- undistort: output is the undistorted image (``K_new``, canvas
  ``overscan`` times the plate, centred); it samples the distorted plate;
- redistort: output is the plate-sized distorted image; it samples the
  undistorted (overscanned) image, e.g. a CG render made with ``K_new``.

Written as 32-bit float OpenEXR by :mod:`camcal.io.stmap`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.undistort import make_undistorter
from camcal.model.rig import Camera

__all__ = ["STMaps", "st_from_pixels", "pixels_from_st", "make_stmaps"]


def st_from_pixels(x: NDArray, y: NDArray, source_size: tuple[int, int]) -> NDArray[np.float32]:
    """ST values of source pixels: ``R = (x + 0.5) / W``, ``G = 1 - (y + 0.5) / H``, ``B = 0``.

    Parameters
    ----------
    x, y : ndarray, shape (H_out, W_out)
        Source pixel of each output pixel; non-finite or negative-one
        sentinels (no source) give values outside [0, 1].
    source_size : (int, int)
        (W, H) of the image the map samples.

    Returns
    -------
    ndarray, shape (H_out, W_out, 3), float32
        RGB order (``write_exr`` swaps to OpenCV's BGR).
    """
    width, height = source_size
    st = np.zeros(x.shape + (3,), dtype=np.float32)
    st[..., 0] = (np.asarray(x, dtype=np.float64) + 0.5) / width
    st[..., 1] = 1.0 - (np.asarray(y, dtype=np.float64) + 0.5) / height
    return st


def pixels_from_st(st: NDArray, source_size: tuple[int, int]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`st_from_pixels`: source pixels ``(x, y)`` from an RGB ST-map."""
    width, height = source_size
    st = np.asarray(st, dtype=np.float64)
    return st[..., 0] * width - 0.5, (1.0 - st[..., 1]) * height - 0.5


@dataclass(frozen=True)
class STMaps:
    """Undistort and redistort ST-maps of one camera.

    Attributes
    ----------
    undistort : ndarray, shape (H_u, W_u, 3), float32
        Samples the plate (size ``plate_size``) for each undistorted pixel.
    redistort : ndarray, shape (H, W, 3), float32
        Samples the undistorted image (size ``undistorted.image_size``) for
        each plate pixel.
    plate_size : (int, int)
    undistorted : Camera
        The undistorted camera: ``K_new``, no distortion, overscan canvas.
    """

    undistort: NDArray[np.float32]
    redistort: NDArray[np.float32]
    plate_size: tuple[int, int]
    undistorted: Camera


def make_stmaps(camera: Camera, overscan: float = 1.1) -> STMaps:
    """Build the undistort and redistort ST-maps of ``camera``.

    Parameters
    ----------
    camera : Camera
        The plate's camera (K, distortion, image size).
    overscan : float
        Undistorted canvas size as a multiple of the plate (>= 1), same
        focal length, centred (so redistorted CG covers the plate's
        corners under barrel distortion).

    Returns
    -------
    STMaps

    Notes
    -----
    Undistort: for output pixel ``x_o``, the plate pixel
    ``distort(K K_new^-1 x_o)`` (the same map :mod:`camcal.geometry.undistort`
    uses). Redistort: for plate pixel ``x_d``, the undistorted pixel
    ``K_new K^-1 undistort(x_d)``.
    """
    undistorter = make_undistorter(camera, "overscan", overscan)
    undistort = st_from_pixels(undistorter.maps.map_x, undistorter.maps.map_y, camera.image_size)
    width, height = camera.image_size
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    ideal = camera.distortion.undistort(np.stack([u.ravel(), v.ravel()], axis=1), camera.K)
    homography = undistorter.view.K_new @ np.linalg.inv(camera.K)
    target = np.column_stack([ideal, np.ones(len(ideal))]) @ homography.T
    target = target[:, :2] / target[:, 2:]
    target[~np.all(np.isfinite(target), axis=1)] = -1.0
    redistort = st_from_pixels(
        target[:, 0].reshape(height, width), target[:, 1].reshape(height, width), undistorter.view.image_size
    )
    return STMaps(undistort, redistort, camera.image_size, undistorter.undistorted_camera())
