"""Sigma overlays: which file a camera's background overlay may show (pure Python, no bpy, no numpy).

``camcal sigma RIG --camera NAME --out sigma.exr --heatmap sigma.png``
writes a camera's projection-sigma map pixel for pixel with its plate: the
EXR holds sigma in pixels, the PNG a viridis heat map of it (0 to the
worst value, which the PNG's ``camcal.sigma_max`` text holds). The add-on
shows either as the camera's background overlay once its size is the
camera's image size: a map of another size would not line up.
"""

from __future__ import annotations

import struct
import zlib

__all__ = ["OverlayError", "check_overlay", "image_size", "sigma_max"]

_PNG = b"\x89PNG\r\n\x1a\n"
_EXR = 20000630  # OpenEXR's magic number (little-endian int)


class OverlayError(ValueError):
    """The overlay file cannot be shown on the camera (one line for the operator's report)."""


def _png_chunks(data):
    offset = len(_PNG)
    while offset + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[offset:offset + 8])
        yield kind, data[offset + 8:offset + 8 + length]
        offset += 12 + length
        if kind == b"IEND":
            return


def _exr_size(data):
    """(width, height) from the EXR header's ``dataWindow`` (box2i: xMin, yMin, xMax, yMax)."""
    offset = 8
    while offset < len(data) and data[offset] != 0:
        name_end = data.index(b"\x00", offset)
        type_end = data.index(b"\x00", name_end + 1)
        (size,) = struct.unpack("<i", data[type_end + 1:type_end + 5])
        value = data[type_end + 5:type_end + 5 + size]
        if data[offset:name_end] == b"dataWindow":
            x0, y0, x1, y1 = struct.unpack("<4i", value[:16])
            return x1 - x0 + 1, y1 - y0 + 1
        offset = type_end + 5 + size
    raise OverlayError("the EXR header has no dataWindow")


def image_size(path):
    """(width, height) of a PNG or OpenEXR file, read from its header."""
    with open(path, "rb") as handle:
        data = handle.read(1 << 16)
    if data.startswith(_PNG):
        for kind, payload in _png_chunks(data):
            if kind == b"IHDR":
                return struct.unpack(">II", payload[:8])
        raise OverlayError(f"{path}: a PNG without its IHDR chunk")
    if len(data) >= 4 and struct.unpack("<i", data[:4])[0] == _EXR:
        try:
            return _exr_size(data)
        except (ValueError, struct.error):
            raise OverlayError(f"{path}: unreadable OpenEXR header") from None
    raise OverlayError(f"{path}: not a PNG or OpenEXR file")


def sigma_max(path):
    """The worst sigma (pixels) a camcal heat-map PNG's colour scale ends at, or None."""
    with open(path, "rb") as handle:
        data = handle.read()
    if not data.startswith(_PNG):
        return None
    for kind, payload in _png_chunks(data):
        if kind == b"tEXt" and payload.startswith(b"camcal.sigma_max\x00"):
            return float(payload.split(b"\x00", 1)[1])
        if kind == b"zTXt" and payload.startswith(b"camcal.sigma_max\x00"):
            return float(zlib.decompress(payload.split(b"\x00", 1)[1][1:]))
    return None


def check_overlay(path, camera_size):
    """Raise :class:`OverlayError` unless the file is a PNG / EXR of the camera's (width, height)."""
    size = tuple(image_size(path))
    if size != tuple(camera_size):
        raise OverlayError(f"{path} is {size[0]}x{size[1]}, the camera {camera_size[0]}x{camera_size[1]}: "
                           "a sigma map lines up only with its own camera's plate")
    return size
