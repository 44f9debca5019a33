"""Image dimensions read from a file's header, before any pixel is decoded (PNG, JPEG, TIFF, EXR).

:func:`check_image_header` is what every image reader calls first: a header
declaring more pixels than :data:`camcal.base.limits.IMAGE_PIXELS` stops
there, in one line naming the file, its declared size and the cap, instead
of asking the decoder for the memory. A file whose header cannot be read
here is left to the decoder (which then says what is wrong with it).
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import BinaryIO

from camcal.base.limits import check_image_size

__all__ = ["check_image_header", "declared_size"]

_PNG = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (C0-CF but DHT C4, JPG C8 and DAC CC): they hold the frame's size
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_MAX_SEGMENTS = 1024
_TIFF_TYPES = {3: ("H", 2), 4: ("I", 4), 16: ("Q", 8)}  # SHORT, LONG, LONG8


def check_image_header(path: Path, content: bytes | None = None) -> None:
    """Refuse ``path`` when its header declares more pixels than the cap (see the module docstring).

    ``content``: the file's bytes when already read (``cv2.imdecode``
    callers); else the header is read from ``path``.
    """
    size = declared_size(path, content)
    if size is not None:
        check_image_size(*size, f"{path}: the header declares")


def declared_size(path: Path, content: bytes | None = None) -> tuple[int, int] | None:
    """(width, height) from the header of a PNG, JPEG, TIFF or EXR file; None when not one of them or unreadable."""
    try:
        with (open(path, "rb") if content is None else io.BytesIO(content)) as stream:
            start = stream.read(8)
            if start.startswith(_PNG):
                return _png(stream)
            if start.startswith(b"\xff\xd8"):
                return _jpeg(stream)
            if start[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
                return _tiff(stream, start)
            if start.startswith(b"\x76\x2f\x31\x01"):
                return _exr(path, content)
    except (OSError, struct.error):
        return None
    return None


def _png(stream: BinaryIO) -> tuple[int, int] | None:
    chunk = stream.read(16)  # length, "IHDR", width, height
    if len(chunk) < 16 or chunk[4:8] != b"IHDR":
        return None
    return struct.unpack(">II", chunk[8:16])


def _jpeg(stream: BinaryIO) -> tuple[int, int] | None:
    stream.seek(2)
    for _ in range(_JPEG_MAX_SEGMENTS):
        if stream.read(1) != b"\xff":
            return None
        marker = stream.read(1)
        while marker == b"\xff":  # fill bytes
            marker = stream.read(1)
        if not marker or marker[0] in (0xD9, 0xDA):  # end of image or start of scan before any frame header
            return None
        if 0xD0 <= marker[0] <= 0xD7 or marker[0] == 0x01:  # markers without a segment
            continue
        length = struct.unpack(">H", stream.read(2))[0]
        if marker[0] in _SOF:
            _, height, width = struct.unpack(">BHH", stream.read(5))
            return width, height
        stream.seek(length - 2, 1)
    return None


def _tiff(stream: BinaryIO, start: bytes) -> tuple[int, int] | None:
    order = "<" if start[:2] == b"II" else ">"
    big = start[2:4] in (b"+\x00", b"\x00+")
    if big:
        stream.seek(8)
        offset = struct.unpack(order + "Q", stream.read(8))[0]
    else:
        offset = struct.unpack(order + "I", start[4:8])[0]
    stream.seek(offset)
    count = struct.unpack(order + ("Q" if big else "H"), stream.read(8 if big else 2))[0]
    entry, value_at = (20, 12) if big else (12, 8)
    found = {}
    for _ in range(min(count, 4096)):
        raw = stream.read(entry)
        if len(raw) < entry:
            return None
        tag, kind = struct.unpack(order + "HH", raw[:4])
        if tag in (256, 257) and kind in _TIFF_TYPES:
            code, width = _TIFF_TYPES[kind]
            found[tag] = struct.unpack(order + code, raw[value_at:value_at + width])[0]
            if len(found) == 2:
                return found[256], found[257]
    return None


def _exr(path: Path, content: bytes | None) -> tuple[int, int] | None:
    """The largest data window of the file's parts (the header only is read)."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path) if content is None else io.BytesIO(content), header_only=True) as exr:
            windows = [part.header["dataWindow"] for part in exr.parts]
    except (RuntimeError, ValueError, KeyError, TypeError):
        return None
    sizes = []
    for low, high in windows:
        (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in (low, high))
        sizes.append((x1 - x0 + 1, y1 - y0 + 1))
    return max(sizes, key=lambda size: size[0] * size[1], default=None)
