"""A tiny PNG writer: the blank lens frame a MovieClip needs.

Blender has no MovieClip without a file, and the Movie Distortion node takes
its calibration size from the clip's frame. When a camera has no plate, the
importer writes a grey 8-bit frame of the camera's size with a faint grid.
"""

from __future__ import annotations

import os
import struct
import tempfile
import zlib

__all__ = ["write_grid_png"]


def _chunk(kind, payload):
    return (
        struct.pack(">I", len(payload))
        + kind
        + payload
        + struct.pack(">I", zlib.crc32(kind + payload) & 0xFFFFFFFF)
    )


def write_grid_png(path, width, height, step=64, background=96, line=160):
    """Write a ``width`` x ``height`` greyscale PNG with grid lines every ``step`` px.

    The file is written atomically (temporary file + rename).
    """
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    plain = bytearray([background]) * width
    for x in range(0, width, step):
        plain[x] = line
    plain_row = b"\x00" + bytes(plain)
    line_row = b"\x00" + bytes([line]) * width
    raw = b"".join(line_row if y % step == 0 else plain_row for y in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    data = (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(raw, 9))
        + _chunk(b"IEND", b"")
    )
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".png.tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
