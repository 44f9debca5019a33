"""ST-map files: the undistort and redistort maps of a camera as 32-bit float OpenEXR, and its undistorted rig.

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
from camcal.geometry.stmap import make_stmaps
from camcal.io.frames import imread, imwrite
from camcal.model.rig import Rig, make_provenance

__all__ = ["read_exr", "write_exr", "write_stmaps"]


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
