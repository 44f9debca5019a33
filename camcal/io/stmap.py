"""ST-map files: the undistort and redistort maps of a camera as 32-bit float OpenEXR, its undistorted rig,
and the projection-sigma maps beside them (one channel, pixel for pixel with a map).

Written with the OpenEXR bindings (:func:`camcal.io.frames.imwrite`): the
OpenCV 5 wheels have no EXR codec. The maps are
:func:`camcal.geometry.stmap.make_stmaps`'s.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_dir, final_path
from camcal.geometry.stmap import make_stmaps, pixels_from_st
from camcal.geometry.uncertainty import SigmaSummary, projection_sigma_map, summarise_sigma
from camcal.io.frames import imread, imwrite
from camcal.model.rig import Rig, make_provenance

__all__ = ["read_exr", "read_sigma_map", "write_exr", "write_sigma_map", "write_stmap_sigmas", "write_stmaps"]


def write_exr(path: str | os.PathLike, rgb: NDArray) -> Path:
    """Write a float32 RGB image as OpenEXR (FLOAT channels, atomically)."""
    return imwrite(path, np.asarray(rgb, dtype=np.float32)[..., ::-1])


def read_exr(path: str | os.PathLike) -> NDArray[np.float32]:
    """Read an EXR written by :func:`write_exr`, as RGB float32."""
    return imread(path)[..., ::-1].copy()


def write_stmaps(rig: Rig, camera_name: str, out_dir: str | os.PathLike, overscan: float = 1.1) -> list[Path]:
    """Write ``<camera>_undistort.exr``, ``<camera>_redistort.exr`` and the undistorted rig into ``out_dir``.

    The folder is built under a temporary name and renamed at the end
    (:func:`camcal.base.atomic.atomic_dir`).

    Returns
    -------
    list of Path
        The two maps and ``<camera>_undistorted.rig.json`` (the rig with the
        camera replaced by its undistorted camera: ``K_new`` on the
        overscan canvas, distortion none).
    """
    camera = rig.camera(camera_name)
    maps = make_stmaps(camera, overscan)
    cameras = tuple(maps.undistorted if c.name == camera_name else c for c in rig.cameras)
    provenance = make_provenance("stmap", source_camera=camera_name, overscan=overscan)
    with atomic_dir(out_dir) as staging:
        paths = [
            write_exr(staging / f"{camera_name}_undistort.exr", maps.undistort),
            write_exr(staging / f"{camera_name}_redistort.exr", maps.redistort),
            Rig(cameras, rig.units, rig.frames, rig.points, provenance).save(staging / f"{camera_name}_undistorted.rig.json"),
        ]
    return [final_path(path, staging, out_dir) for path in paths]


def write_sigma_map(path: str | os.PathLike, sigma: NDArray) -> Path:
    """Write a (H, W) sigma map as a one-channel (``Y``) 32-bit float OpenEXR, atomically."""
    return imwrite(path, np.asarray(sigma, dtype=np.float32))


def read_sigma_map(path: str | os.PathLike) -> NDArray[np.float32]:
    """Read a map written by :func:`write_sigma_map`, shape (H, W)."""
    image = imread(path)
    return image if image.ndim == 2 else image[..., 0]


def write_stmap_sigmas(rig: Rig, camera_name: str, out_dir: str | os.PathLike, overscan: float = 1.1,
                       distance: float | None = None) -> list[tuple[Path, SigmaSummary]]:
    """Write the projection-sigma maps beside :func:`write_stmaps`'s maps.

    ``<camera>_sigma.exr`` is plate-sized: pixel for pixel with the plate
    and with ``<camera>_redistort.exr``. ``<camera>_undistort_sigma.exr``
    is pixel for pixel with ``<camera>_undistort.exr``: each pixel holds the
    sigma of the plate pixel that map samples (NaN where it samples none).
    Both in pixels of the plate (:mod:`camcal.geometry.uncertainty`).
    """
    camera = rig.camera(camera_name)
    maps = make_stmaps(camera, overscan)
    x, y = pixels_from_st(maps.undistort, maps.plate_size)
    width, height = maps.plate_size
    source = np.stack([x, y], axis=-1)
    source[~((x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5))] = np.nan
    out_dir = Path(out_dir)
    out = []
    for name, sigma in ((f"{camera_name}_sigma.exr", projection_sigma_map(camera, distance)),
                        (f"{camera_name}_undistort_sigma.exr", projection_sigma_map(camera, distance, source))):
        out.append((write_sigma_map(out_dir / name, sigma), summarise_sigma(sigma, distance)))
    return out
