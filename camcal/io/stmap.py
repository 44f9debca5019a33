"""ST-map files: the undistort and redistort maps of a camera as 32-bit float OpenEXR, its undistorted rig,
and the projection-sigma maps beside them (one channel, pixel for pixel with a map).

Written with the OpenEXR bindings (the OpenCV 5 wheels have no EXR codec):
32-bit float R, G, B; the undistort map's overscan border as the EXR's data
window beyond its display window (Nuke's bounding box beyond its format). The maps are
:func:`camcal.geometry.stmap.make_stmaps`'s.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_dir, atomic_path, final_path
from camcal.base.errors import CamcalError
from camcal.geometry.stmap import make_stmaps, pixels_from_st, stmap_view
from camcal.geometry.uncertainty import SigmaSummary, projection_sigma_map, summarise_sigma
from camcal.geometry.undistort import undistorted_rig
from camcal.io.frames import imread, imwrite
from camcal.model.rig import Rig, make_provenance

__all__ = ["read_exr", "read_exr_window", "read_sigma_map", "stmap_frame_name", "write_exr", "write_sigma_map",
           "write_stmap_frames", "write_stmap_sigmas", "write_stmaps"]


def write_exr(path: str | os.PathLike, rgb: NDArray, border: tuple[int, int] = (0, 0)) -> Path:
    """Write a float32 RGB image as OpenEXR (FLOAT, ZIP, atomically), its data window beyond its display window.

    Parameters
    ----------
    path : path
    rgb : ndarray, shape (H + 2 by, W + 2 bx, 3)
        The pixels of the whole data window, top row first.
    border : (int, int)
        ``(bx, by)``: the display window (the image's format, what Nuke
        calls its format) is the ``W x H`` box inside the border, from
        ``(0, 0)``; the data window (Nuke's bounding box) runs from
        ``(-bx, -by)`` to ``(W + bx - 1, H + by - 1)``, the EXR convention
        for overscan.

    Returns
    -------
    Path
    """
    import OpenEXR

    pixels = np.asarray(rgb, dtype=np.float32)
    bx, by = (int(v) for v in border)
    height, width = pixels.shape[0] - 2 * by, pixels.shape[1] - 2 * bx
    if pixels.ndim != 3 or pixels.shape[2] != 3 or width < 1 or height < 1 or bx < 0 or by < 0:
        raise CamcalError(f"cannot write {path}: expected (H, W, 3) pixels with a border inside them, "
                          f"got {pixels.shape} and border {border}")
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "dataWindow": (np.array([-bx, -by], np.int32), np.array([width + bx - 1, height + by - 1], np.int32)),
        "displayWindow": (np.array([0, 0], np.int32), np.array([width - 1, height - 1], np.int32)),
    }
    planes = {name: np.ascontiguousarray(pixels[..., i]) for i, name in enumerate("RGB")}
    with atomic_path(path) as tmp:
        try:
            with OpenEXR.File(header, planes) as exr:
                exr.write(str(tmp))
        except (RuntimeError, ValueError, TypeError) as error:
            raise CamcalError(f"cannot write EXR {path}: {error}") from None
    return Path(path)


def read_exr_window(path: str | os.PathLike) -> tuple[NDArray[np.float32], tuple[int, int]]:
    """Read an RGB EXR written by :func:`write_exr`: its data window's pixels and its border ``(bx, by)``.

    The display window must start at ``(0, 0)`` and lie inside the data
    window, the same distance from each pair of sides.
    """
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            header = dict(exr.header())  # the bindings clear theirs when the file closes
            planes = {name: channel.pixels.copy() for name, channel in exr.channels().items()}
    except (RuntimeError, ValueError, OSError) as error:
        raise CamcalError(f"cannot read EXR {path}: {error}") from None
    if not {"R", "G", "B"} <= set(planes):
        raise CamcalError(f"{path}: expected R, G and B channels, got {', '.join(sorted(planes))}")
    (low, high), (display_low, display_high) = (
        [np.asarray(corner).tolist() for corner in header[key]] for key in ("dataWindow", "displayWindow")
    )
    bx, by = -low[0], -low[1]
    if display_low != [0, 0] or bx < 0 or by < 0 or [high[0] - display_high[0], high[1] - display_high[1]] != [bx, by]:
        raise CamcalError(f"{path}: data window {low}-{high} is not the display window {display_low}-{display_high} "
                          "with the same border on each side")
    return np.stack([planes[name].astype(np.float32) for name in "RGB"], axis=2), (bx, by)


def read_exr(path: str | os.PathLike) -> NDArray[np.float32]:
    """The RGB pixels of an EXR's data window (:func:`read_exr_window` without the border)."""
    return read_exr_window(path)[0]


def write_stmaps(rig: Rig, camera_name: str, out_dir: str | os.PathLike, overscan: float | None = None,
                 border: int | tuple[int, int] | None = None) -> list[Path]:
    """Write ``<camera>_undistort.exr``, ``<camera>_redistort.exr`` and the undistorted rig into ``out_dir``.

    The folder is built under a temporary name and renamed at the end
    (:func:`camcal.base.atomic.atomic_dir`). The overscan is a factor or a
    border in pixels (:func:`camcal.geometry.stmap.make_stmaps`).

    Returns
    -------
    list of Path
        The two maps (the undistort map with its border as the EXR's data
        window beyond the plate-sized display window) and
        ``<camera>_undistorted.rig.json`` (the rig with the camera replaced
        by its undistorted camera: the whole data window, ``K`` with the
        principal point moved by the border, distortion none).
    """
    camera = rig.camera(camera_name)
    if rig.lens_frames(camera_name):
        raise CamcalError(f"camera {camera_name!r}'s lens changes over the rig's frames: its ST-maps are a pair per "
                          "frame (write_stmap_frames)")
    maps = make_stmaps(camera, overscan, border)
    cameras = tuple(maps.undistorted if c.name == camera_name else c for c in rig.cameras)
    provenance = make_provenance("stmap", source_camera=camera_name, overscan=overscan, border=list(maps.border))
    with atomic_dir(out_dir) as staging:
        paths = [
            write_exr(staging / f"{camera_name}_undistort.exr", maps.undistort, maps.border),
            write_exr(staging / f"{camera_name}_redistort.exr", maps.redistort),
            Rig(cameras, rig.units, rig.frames, rig.points, provenance).save(staging / f"{camera_name}_undistorted.rig.json"),
        ]
    return [final_path(path, staging, out_dir) for path in paths]


def stmap_frame_name(camera_name: str, kind: str, frame: int) -> str:
    """``<camera>_<kind>.%04d.exr`` at ``frame``: the file of one frame of a per-frame map sequence."""
    return f"{camera_name}_{kind}.{frame:04d}.exr"


def write_stmap_frames(rig: Rig, camera_name: str, out_dir: str | os.PathLike, overscan: float | None = None,
                       border: int | tuple[int, int] | None = None) -> tuple[list[Path], list[Path], Path]:
    """The ST-maps of a camera whose lens changes over the rig's frames: one pair per frame, and the undistorted rig.

    Each frame's maps are :func:`write_stmaps`' maps of the camera with
    that frame's lens (:meth:`camcal.model.rig.Rig.camera_at_frame`), named
    ``<camera>_undistort.%04d.exr`` and ``<camera>_redistort.%04d.exr``
    with the frame number (:func:`stmap_frame_name`). The overscan border
    depends on the image size only, so every frame's undistorted image has
    the same size; ``<camera>_undistorted.rig.json`` holds the undistorted
    camera of each frame's lens as that frame's lens (distortion none,
    the lens state kept). The folder is written atomically.

    Returns
    -------
    (list of Path, list of Path, Path)
        The undistort maps and the redistort maps in frame order, and the undistorted rig.
    """
    if not rig.frames:
        raise CamcalError(f"the rig has no frames: write the ST-maps of {camera_name!r} with write_stmaps")
    undistort_paths, redistort_paths = [], []
    with atomic_dir(out_dir) as staging:
        for frame in rig.frames:
            maps = make_stmaps(rig.camera_at_frame(camera_name, frame.index), overscan, border)
            undistort_paths.append(write_exr(staging / stmap_frame_name(camera_name, "undistort", frame.index),
                                             maps.undistort, maps.border))
            redistort_paths.append(write_exr(staging / stmap_frame_name(camera_name, "redistort", frame.index),
                                             maps.redistort))
        provenance = make_provenance("stmap", source_camera=camera_name, overscan=overscan, border=list(maps.border))
        undistorted = undistorted_rig(rig, camera_name, lambda camera: stmap_view(camera, overscan, border), provenance)
        rig_path = undistorted.save(staging / f"{camera_name}_undistorted.rig.json")
    return ([final_path(path, staging, out_dir) for path in undistort_paths],
            [final_path(path, staging, out_dir) for path in redistort_paths], final_path(rig_path, staging, out_dir))


def write_sigma_map(path: str | os.PathLike, sigma: NDArray) -> Path:
    """Write a (H, W) sigma map as a one-channel (``Y``) 32-bit float OpenEXR, atomically."""
    return imwrite(path, np.asarray(sigma, dtype=np.float32))


def read_sigma_map(path: str | os.PathLike) -> NDArray[np.float32]:
    """Read a map written by :func:`write_sigma_map`, shape (H, W)."""
    image = imread(path)
    return image if image.ndim == 2 else image[..., 0]


def write_stmap_sigmas(rig: Rig, camera_name: str, out_dir: str | os.PathLike, overscan: float | None = None,
                       distance: float | None = None,
                       border: int | tuple[int, int] | None = None) -> list[tuple[Path, SigmaSummary]]:
    """Write the projection-sigma maps beside :func:`write_stmaps`'s maps.

    ``<camera>_sigma.exr`` is plate-sized: pixel for pixel with the plate
    and with ``<camera>_redistort.exr``. ``<camera>_undistort_sigma.exr``
    is pixel for pixel with ``<camera>_undistort.exr``: each pixel holds the
    sigma of the plate pixel that map samples (NaN where it samples none).
    Both in pixels of the plate (:mod:`camcal.geometry.uncertainty`).
    """
    camera = rig.camera(camera_name)
    maps = make_stmaps(camera, overscan, border)
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
