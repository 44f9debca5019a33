"""Plates: image sequences in VFX notation, checked whole before use and read one frame at a time.

Notation
--------
A sequence is a file pattern with one frame-number placeholder: printf
style ``plate.%04d.exr`` (``%d``: no padding) or hashes ``plate.####.exr``,
each ``#`` one digit of padding (Nuke's convention: ``####`` is
``%04d``). Frame numbers wider than the padding are written in full
(``%04d`` of 12345 is ``12345``), as every tool that writes them does.

Its frames come from a range (``1001-1100``, ``1001-1100x2``,
``1,5,10-12``: :func:`camcal.base.frame_ranges.parse_frames`) or, without
one, from the files on disk (first to last frame found). Every frame of
the range must exist: :func:`sequence_paths` names the missing ones in one
error before anything is read or written.

Pixels
------
Read with OpenImageIO (the optional ``plates`` extra), the VFX industry's
image library: EXR, DPX, Cineon, TIFF, PNG, JPEG and the other formats it
has plugins for (OpenCV reads neither DPX nor Cineon). Frames are read one
at a time (:func:`read_image` per file): a plate is never held in memory whole.
:func:`read_image` returns the file's pixels in R, G, B[, A] order, in the
file's own type (uint8, uint16 for 10/12/16-bit DPX and TIFF code values
in the low bits scaled by OpenImageIO to the full 16-bit range, float32
for half or float data). :func:`feature_image` turns a frame into the
8-bit image feature extraction sees: integer code values scaled to 0-255
(a log DPX stays log, which SIFT handles like any other contrast curve),
scene-linear float data encoded with the sRGB curve (IEC 61966-2-1) so the
shadows keep their detail.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.frame_ranges import frame_runs, parse_frames
from camcal.base.limits import check_image_size

__all__ = [
    "camera_of",
    "feature_image",
    "feature_mask",
    "is_sequence_pattern",
    "printf_pattern",
    "read_image",
    "sequence_frames",
    "sequence_paths",
]

_PRINTF = re.compile(r"%(0\d+)?d")
_HASHES = re.compile(r"#+")
_MAX_LISTED = 20


def is_sequence_pattern(text: str | os.PathLike) -> bool:
    """Whether the file name of ``text`` holds a frame placeholder (``%04d``, ``%d`` or ``####``)."""
    name = Path(text).name
    return bool(_PRINTF.search(name) or _HASHES.search(name))


def printf_pattern(pattern: str | os.PathLike) -> str:
    """``pattern`` with its one placeholder in printf form.

    Examples
    --------
    >>> printf_pattern("plates/a.####.exr")
    'plates/a.%04d.exr'
    >>> printf_pattern("plates/a.%d.dpx")
    'plates/a.%d.dpx'
    """
    pattern = os.fspath(pattern)
    name = Path(pattern).name
    placeholders = _PRINTF.findall(name) + _HASHES.findall(name)
    if len(placeholders) != 1 or name.replace("%%", "").count("%") > 1 or os.path.dirname(pattern).count("%"):
        raise CamcalError(f"sequence {pattern!r} needs exactly one frame number placeholder in its file name, "
                          "like %04d, %d or ####")
    hashes = _HASHES.search(name)
    if hashes is None:
        return pattern
    return str(Path(pattern).with_name(name[:hashes.start()] + f"%0{len(hashes.group())}d" + name[hashes.end():]))


def sequence_frames(pattern: str | os.PathLike) -> tuple[int, ...]:
    """The frames of ``pattern`` on disk, from the first found to the last (gaps included, to be reported)."""
    printf = printf_pattern(pattern)
    folder, name = os.path.split(printf)
    match = _PRINTF.search(name)
    width = int(match.group(1) or "1")
    regex = re.compile(re.escape(name[:match.start()]) + r"(-?\d+)" + re.escape(name[match.end():]))
    try:
        entries = os.listdir(folder or ".")
    except OSError as error:
        raise CamcalError(f"cannot list the folder of sequence {pattern}: {error.strerror}") from None
    found = sorted(int(m.group(1)) for m in map(regex.fullmatch, entries)
                   if m is not None and len(m.group(1).lstrip("-")) >= width)
    if not found:
        raise CamcalError(f"no frame of sequence {pattern} found")
    return tuple(range(found[0], found[-1] + 1))


def sequence_paths(pattern: str | os.PathLike, frames: str | Sequence[int] | None = None) -> list[Path]:
    """Every frame's file of a sequence, in frame order, all checked to exist.

    Parameters
    ----------
    pattern : str or path
        ``plate.%04d.exr`` or ``plate.####.exr``.
    frames : str or sequence of int, optional
        A frame range (``"1001-1100"``) or the frame numbers; None: the
        frames on disk (:func:`sequence_frames`).

    Raises
    ------
    CamcalError
        A bad pattern or range, or frames missing, all named in one line
        (runs of consecutive frames as ``first-last``).
    """
    printf = printf_pattern(pattern)
    numbers = sequence_frames(pattern) if frames is None else (
        parse_frames(frames) if isinstance(frames, str) else tuple(sorted(set(int(f) for f in frames))))
    if not numbers:
        raise CamcalError(f"no frames asked of sequence {pattern}")
    paths = [Path(printf % frame) for frame in numbers]
    missing = [frame for frame, path in zip(numbers, paths) if not path.exists()]
    if missing:
        runs = frame_runs(missing)
        listed = ", ".join(runs[:_MAX_LISTED]) + (f" and {len(runs) - _MAX_LISTED} more runs" if len(runs) > _MAX_LISTED else "")
        raise CamcalError(f"sequence {pattern}: {len(missing)} of {len(numbers)} frames missing "
                          f"({numbers[0]}-{numbers[-1]}): {listed}")
    return paths


def read_image(path: str | os.PathLike) -> NDArray:
    """One image through OpenImageIO, ``(H, W, C)`` in R, G, B[, A] order (see the module docstring).

    Raises
    ------
    CamcalError
        OpenImageIO missing, a file it cannot open or decode, or an image
        past :data:`camcal.base.limits.IMAGE_PIXELS` (checked on the
        header, before decoding).
    """
    oiio = require("OpenImageIO")
    image = oiio.ImageInput.open(os.fspath(path))
    if image is None:
        raise CamcalError(f"cannot read {path} ({oiio.geterror().strip() or 'not an image OpenImageIO reads'})")
    try:
        spec = image.spec()
        check_image_size(spec.width, spec.height, f"{path}: the header declares")
        base = spec.format.basetype
        kind = ("uint8" if base == oiio.UINT8 else
                "float" if base in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE) else "uint16")  # 10/12/16/32-bit integers
        pixels = image.read_image(0, 0, 0, spec.nchannels, kind)
        error = image.geterror()
    finally:
        image.close()
    if pixels is None or error:
        raise CamcalError(f"cannot read {path} ({error.strip() or 'corrupt image'})")
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return pixels.astype(np.float32, copy=False) if kind == "float" else pixels


def feature_image(pixels: NDArray, bgr: bool = False) -> NDArray[np.uint8]:
    """The 8-bit R, G, B (or grey) image feature extraction sees (see the module docstring).

    Float data is encoded with the sRGB transfer function
    ``v <= 0.0031308 ? 12.92 v : 1.055 v^(1/2.4) - 0.055`` (IEC 61966-2-1)
    after clipping to [0, 1]; integer data is scaled by its type's maximum.
    Alpha is dropped; ``bgr`` gives OpenCV's channel order.
    """
    colour = pixels[:, :, :3] if pixels.shape[2] >= 3 else pixels[:, :, :1]
    if np.issubdtype(colour.dtype, np.integer):
        values = colour.astype(np.float32) / np.float32(np.iinfo(colour.dtype).max)
    else:
        linear = np.clip(np.nan_to_num(colour.astype(np.float32)), 0.0, 1.0)
        values = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1.0 / 2.4) - 0.055)
    out = np.rint(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)
    return out[:, :, 0] if out.shape[2] == 1 else (out[:, :, ::-1] if bgr else out)


def feature_mask(matte: NDArray) -> NDArray[np.uint8]:
    """COLMAP's feature mask of a matte frame: 0 (no features) where the matte is at least half on, else 255.

    A matte is white on what must not be tracked (moving actors, the sky),
    as a roto or garbage matte is drawn; its alpha channel is used when it
    has one (2 or 4 channels), else its first channel. Integer values are
    read as fractions of their type's maximum.
    """
    channel = matte[:, :, -1] if matte.shape[2] in (2, 4) else matte[:, :, 0]
    scale = float(np.iinfo(channel.dtype).max) if np.issubdtype(channel.dtype, np.integer) else 1.0
    return np.where(np.nan_to_num(channel.astype(np.float32)) >= 0.5 * scale, 0, 255).astype(np.uint8)


def camera_of(pattern: str | os.PathLike) -> str:
    """A camera name for a sequence: its file name before the placeholder (``left.%04d.exr`` -> ``left``),
    else its folder's name."""
    name = Path(pattern).name
    match = _PRINTF.search(name) or _HASHES.search(name)
    stem = name[:match.start()].rstrip("._- ") if match else Path(name).stem
    return stem or Path(pattern).resolve().parent.name
