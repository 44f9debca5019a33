"""The caps on what a file may declare, in one place, checked before anything is allocated.

camcal trusts nothing in a file: an image header, a JSON rig or another
tool's camera file may declare sizes made to exhaust a worker. Every reader
checks what a file declares against these caps before it allocates, and
stops with one line naming the file, the declared value, the cap and the
environment variable that raises it:

=====================  ==========================  ==========================================
cap                    default                     environment variable
=====================  ==========================  ==========================================
image pixels           2^28 (268,435,456: 16K x    ``CAMCAL_MAX_IMAGE_PIXELS``
                       16K; a 16K plate is 141M)
JSON file size         64 MiB                      ``CAMCAL_MAX_JSON_BYTES``
JSON nesting depth     64 levels                   ``CAMCAL_MAX_JSON_DEPTH``
camera file size       1 GiB (YAML, COLMAP text,   ``CAMCAL_MAX_FILE_BYTES``
                       USD, Nuke scripts)
=====================  ==========================  ==========================================

The image cap bounds every image camcal reads (from its header, before
decoding) and every image size a rig declares (a map of that size is what
``stmap`` and ``undistort`` allocate). For a real giant plate, raise it for
one run: ``CAMCAL_MAX_IMAGE_PIXELS=1073741824 camcal undistort ...``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = ["Limit", "IMAGE_PIXELS", "JSON_BYTES", "JSON_DEPTH", "FILE_BYTES", "check_image_size", "check_file_size"]


@dataclass(frozen=True)
class Limit:
    """One cap: its default and the environment variable that raises (or lowers) it."""

    what: str
    default: int
    env: str

    @property
    def value(self) -> int:
        """The cap in force: the environment variable when set (a positive integer), else the default."""
        text = os.environ.get(self.env)
        if text is None or not text.strip():
            return self.default
        try:
            value = int(text.strip().replace("_", ""))
        except ValueError:
            value = 0
        if value <= 0:
            raise CamcalError(f"{self.env} must be a positive integer, got {text!r}")
        return value

    def how_to_raise(self) -> str:
        """The hint every message ends with."""
        return f"set {self.env} to raise it"


IMAGE_PIXELS = Limit("image pixels", 1 << 28, "CAMCAL_MAX_IMAGE_PIXELS")
JSON_BYTES = Limit("JSON file size in bytes", 64 << 20, "CAMCAL_MAX_JSON_BYTES")
JSON_DEPTH = Limit("JSON nesting depth", 64, "CAMCAL_MAX_JSON_DEPTH")
FILE_BYTES = Limit("camera file size in bytes", 1 << 30, "CAMCAL_MAX_FILE_BYTES")


def check_image_size(width: int, height: int, what: str) -> None:
    """Refuse an image (or a map) of ``width`` x ``height`` pixels past :data:`IMAGE_PIXELS`.

    ``what`` names it in the message (``"/plates/a.png declares"``,
    ``"image_size"``).
    """
    cap = IMAGE_PIXELS.value
    if width * height > cap:
        raise CamcalError(f"{what} {width}x{height} pixels ({width * height:,}), over the cap of {cap:,} "
                          f"{IMAGE_PIXELS.what} ({IMAGE_PIXELS.how_to_raise()})")


def check_file_size(path: Path, limit: Limit, what: str = "file") -> None:
    """Refuse a file larger than ``limit`` before reading it (a missing file is left to the reader)."""
    try:
        size = path.stat().st_size
    except OSError:
        return
    cap = limit.value
    if size > cap:
        raise CamcalError(f"{path}: {what} of {size:,} bytes is over the cap of {cap:,} ({limit.how_to_raise()})")
