"""Sparse point clouds as binary little-endian PLY (Blender, MeshLab, CloudCompare read it).

Vertex properties: ``x y z`` (double), ``red green blue`` (uchar) and, when
given, ``track_length`` (int): how many images observe the point.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_path

__all__ = ["write_points_ply", "read_points_ply"]


def _vertex_dtype(with_tracks: bool) -> np.dtype:
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if with_tracks:
        fields.append(("track_length", "<i4"))
    return np.dtype(fields)


def write_points_ply(
    path: str | os.PathLike, xyz: ArrayLike, colours: ArrayLike | None = None, track_lengths: ArrayLike | None = None
) -> Path:
    """Write points (N, 3) with optional colours (N, 3, uint8) and track lengths (N,)."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = len(xyz)
    colours = np.full((n, 3), 255, np.uint8) if colours is None else np.asarray(colours, dtype=np.uint8).reshape(n, 3)
    vertices = np.empty(n, _vertex_dtype(track_lengths is not None))
    vertices["x"], vertices["y"], vertices["z"] = xyz.T
    vertices["red"], vertices["green"], vertices["blue"] = colours.T
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
              "property double x", "property double y", "property double z",
              "property uchar red", "property uchar green", "property uchar blue"]
    if track_lengths is not None:
        vertices["track_length"] = np.asarray(track_lengths, dtype=np.int32).reshape(n)
        header.append("property int track_length")
    header.append("end_header")
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(("\n".join(header) + "\n").encode("ascii"))
            handle.write(vertices.tobytes())
    return path


def read_points_ply(path: str | os.PathLike) -> np.ndarray:
    """Read a PLY written by :func:`write_points_ply` as a structured array."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CamcalError(f"points file not found: {path}") from None
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise CamcalError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise CamcalError(f"{path}: only binary little-endian PLY is read here")
    try:
        count = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    except (StopIteration, IndexError, ValueError):
        raise CamcalError(f"{path}: no vertex count (element vertex N) in the PLY header") from None
    dtype = _vertex_dtype("property int track_length" in header)
    body = data[end + len(b"end_header\n"):]
    if len(body) != count * dtype.itemsize:
        raise CamcalError(f"{path}: truncated PLY ({len(body)} bytes for {count} vertices)")
    return np.frombuffer(body, dtype=dtype)
