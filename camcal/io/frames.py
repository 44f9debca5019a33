"""Image frames of a plate sequence: read and write one frame keeping its depth, channels and metadata.

Formats
-------
OpenEXR (``.exr``)
    Read and written with the OpenEXR Python bindings: every HALF or FLOAT
    channel, each written back with its own pixel type, and the header's
    attributes (compression, ``owner``, ``capDate``, ``framesPerSecond``,
    timecode, custom attributes, tiling) copied to the output; the data and
    display windows follow the output size. Single-part scan-line or tiled
    images whose data window equals their display window, starting at
    (0, 0); UINT channels, sub-sampled channels, deep and multi-part files
    are refused with a message naming the problem.
PNG, TIFF (8/16-bit, TIFF also 32-bit float), JPEG (8-bit)
    Read with ``cv2.imread(..., IMREAD_UNCHANGED)`` and written with
    ``cv2.imwrite``; same depth and channel count out. OpenCV neither reads
    nor writes their metadata (text chunks, ICC profiles, TIFF tags): the
    outputs do not carry it. TIFFs are written LZW-compressed (lossless;
    OpenCV's default for 3-channel float would be the lossy LogLuv).

Pixels are held as an (H, W, C) array: float32 for EXR (half channels are
widened exactly and narrowed back on writing, round to nearest even), the
file's own dtype otherwise, with OpenCV's channel order (B, G, R[, A]; grey
is ``Y``).

OpenCV reads ``OPENCV_IO_ENABLE_OPENEXR`` at its first EXR use; this module
sets it (unless the user did) before importing ``cv2``, like
:mod:`camcal.geometry.stmap`.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import dataclasses  # noqa: E402
from collections.abc import Mapping  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from types import MappingProxyType  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from camcal.base.atomic import atomic_path  # noqa: E402
from camcal.base.errors import CamcalError  # noqa: E402
from camcal.base.limits import IMAGE_PIXELS  # noqa: E402
from camcal.io.headers import check_image_header  # noqa: E402

__all__ = ["FORMATS", "ImageFrame", "frame_format", "imread", "imwrite", "read_frame", "write_frame"]

#: File name suffix -> format name, and the pixel types each format holds.
FORMATS: Mapping[str, str] = MappingProxyType(
    {".exr": "exr", ".png": "png", ".tif": "tiff", ".tiff": "tiff", ".jpg": "jpeg", ".jpeg": "jpeg"}
)
_DEPTHS = {
    "exr": (np.float32,),
    "png": (np.uint8, np.uint16),
    "tiff": (np.uint8, np.uint16, np.float32),
    "jpeg": (np.uint8,),
}
_CV_CHANNELS = {1: ("Y",), 2: ("Y", "A"), 3: ("B", "G", "R"), 4: ("B", "G", "R", "A")}
# OpenCV writes 3-channel float TIFF as lossy LogLuv unless told otherwise: LZW keeps every bit
_CV_PARAMS = {"tiff": [cv2.IMWRITE_TIFF_COMPRESSION, 5]}
# header attributes that describe the pixel layout: rebuilt from the pixels on writing
_EXR_LAYOUT = ("channels", "dataWindow", "displayWindow")


def frame_format(path: str | os.PathLike) -> str:
    """The format of ``path`` by its suffix (see :data:`FORMATS`)."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise CamcalError(f"unsupported image format {suffix or '(no suffix)'!r} of {path}; "
                          f"expected one of: {', '.join(FORMATS)}")
    return FORMATS[suffix]


@dataclass(frozen=True)
class ImageFrame:
    """One image with what is needed to write it back the way it was read.

    Attributes
    ----------
    pixels : ndarray, shape (H, W, C)
        float32 for EXR, else the file's dtype (uint8, uint16, float32).
    channels : tuple of str
        Channel names in the order of the last axis (EXR names, or
        OpenCV's ``B, G, R[, A]`` / ``Y[, A]``).
    exr_types : tuple of numpy dtype, optional
        EXR only: the stored type of each channel (float16 for HALF,
        float32 for FLOAT).
    header : mapping, optional
        EXR only: the header attributes other than the channel list and
        the data / display windows.
    """

    pixels: NDArray
    channels: tuple[str, ...]
    exr_types: tuple[np.dtype, ...] | None = None
    header: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.pixels.ndim != 3 or self.pixels.shape[2] != len(self.channels):
            raise CamcalError(f"pixels of shape {self.pixels.shape} do not hold the channels {self.channels}")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.pixels.shape[1], self.pixels.shape[0]

    def with_pixels(self, pixels: NDArray) -> ImageFrame:
        """The same channels, types and metadata with new pixels (any size)."""
        if pixels.ndim == 2:
            pixels = pixels[:, :, None]
        return dataclasses.replace(self, pixels=pixels)

    def channel_index(self, name: str) -> int:
        """Position of channel ``name`` on the last axis."""
        if name not in self.channels:
            raise CamcalError(f"the image has no {name!r} channel (it has {', '.join(self.channels)})")
        return self.channels.index(name)


def imread(path: str | os.PathLike, flags: int = cv2.IMREAD_UNCHANGED) -> NDArray:
    """``cv2.imread`` that raises one-line :class:`CamcalError` instead of returning None.

    EXR files are read with the OpenEXR bindings (the OpenCV 5 wheels have
    no EXR codec) and returned the way ``cv2.imread`` returned them: float32,
    ``(H, W)`` for one channel, else ``B, G, R[, A]``. With
    ``IMREAD_GRAYSCALE`` they become one grey channel (``cv2.cvtColor``
    weights), and unless ``IMREAD_ANYDEPTH`` or ``IMREAD_UNCHANGED`` is given
    8-bit (``round(255 v)``, clipped), as OpenCV's own EXR decoder did.

    The header's image size is checked against
    :data:`camcal.base.limits.IMAGE_PIXELS` before any pixel is decoded
    (:func:`camcal.io.headers.check_image_header`; for the formats it does
    not parse, OpenCV's own cap is reported the same way).

    Raises
    ------
    CamcalError
        ``"cannot read <path> (...)"`` for a missing, corrupt or unsupported
        file; an image past the pixel cap, naming its size and the cap.
    """
    if Path(path).suffix.lower() == ".exr":
        return _imread_exr(Path(path), flags)
    if not Path(path).is_file():  # before OpenCV, which would log its own warning line first
        raise CamcalError(f"cannot read {path} (missing file)")
    check_image_header(Path(path))
    try:
        pixels = cv2.imread(str(path), flags)
    except cv2.error as error:
        if "CV_IO_MAX_IMAGE" in str(error):
            raise CamcalError(f"{path}: the image is larger than OpenCV's own cap (OPENCV_IO_MAX_IMAGE_PIXELS, "
                              f"2^30 pixels by default); camcal's cap is {IMAGE_PIXELS.value:,} "
                              f"{IMAGE_PIXELS.what} ({IMAGE_PIXELS.how_to_raise()})") from None
        raise CamcalError(f"cannot read {path} ({str(error).strip().splitlines()[-1]})") from None
    if pixels is None:
        raise CamcalError(f"cannot read {path} (missing, corrupt or not an image OpenCV reads)")
    return pixels


def _imread_exr(path: Path, flags: int) -> NDArray:
    if not path.is_file():
        raise CamcalError(f"cannot read {path} (missing file)")
    frame = _read_exr(path)
    pixels = frame.pixels[:, :, _opencv_channel_order(frame.channels, path)]
    if flags < 0:  # IMREAD_UNCHANGED
        return pixels[:, :, 0] if pixels.shape[2] == 1 else pixels
    colour = pixels[:, :, :3] if pixels.shape[2] >= 3 else pixels[:, :, 0]
    if flags & cv2.IMREAD_ANYCOLOR:
        pixels = colour
    elif flags & cv2.IMREAD_COLOR:
        pixels = colour if colour.ndim == 3 else cv2.cvtColor(colour, cv2.COLOR_GRAY2BGR)
    else:  # IMREAD_GRAYSCALE (0)
        pixels = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY) if colour.ndim == 3 else colour
    if not flags & cv2.IMREAD_ANYDEPTH:
        pixels = np.round(np.clip(np.nan_to_num(pixels), 0.0, 1.0) * 255.0).astype(np.uint8)
    return pixels


def _opencv_channel_order(channels: tuple[str, ...], path: Path) -> list[int]:
    """Indices that put an EXR's channels in OpenCV's order: ``B, G, R[, A]`` or ``Y[, A]``."""
    for order in (("B", "G", "R", "A"), ("B", "G", "R"), ("Y", "A"), ("Y",)):
        if set(order) <= set(channels):
            return [channels.index(name) for name in order]
    if len(channels) == 1:
        return [0]
    raise CamcalError(f"{path}: EXR channels {', '.join(channels)} are neither R, G, B[, A] nor Y[, A]")


def imwrite(path: str | os.PathLike, pixels: NDArray, half: bool = False) -> Path:
    """Write an OpenCV-layout image atomically; EXR through the OpenEXR bindings.

    Parameters
    ----------
    path
        Output file; its suffix picks the format (any ``cv2.imwrite`` writes,
        or ``.exr``).
    pixels : ndarray, shape (H, W) or (H, W, C)
        OpenCV channel order (``B, G, R[, A]``; one channel is ``Y``). EXR
        takes float data, stored as FLOAT (float32) or, with ``half``, HALF.
    half
        EXR only: store HALF (float16, round to nearest even) channels.

    Returns
    -------
    Path
    """
    path = Path(path)
    pixels = np.ascontiguousarray(pixels)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".exr":
            import OpenEXR

            if pixels.dtype.kind != "f":
                raise CamcalError(f"cannot write {path}: EXR takes float pixels, got {pixels.dtype}")
            planes = pixels[:, :, None] if pixels.ndim == 2 else pixels
            if planes.shape[2] not in _CV_CHANNELS:
                raise CamcalError(f"cannot write {path}: {planes.shape[2]} channels (1 to 4 allowed)")
            dtype = np.dtype(np.float16 if half else np.float32)
            channels = _CV_CHANNELS[planes.shape[2]]
            _write_exr(tmp, ImageFrame(planes.astype(np.float32), channels, (dtype,) * len(channels),
                                       {"compression": OpenEXR.ZIP_COMPRESSION}))
        else:
            try:
                ok = cv2.imwrite(str(tmp), pixels, _CV_PARAMS.get(FORMATS.get(path.suffix.lower(), ""), []))
            except cv2.error as error:
                raise CamcalError(f"cannot write {path}: {str(error).strip().splitlines()[-1]}") from None
            if not ok:
                raise CamcalError(f"cannot write {path}")
    return path


def read_frame(path: str | os.PathLike) -> ImageFrame:
    """Read one frame (see the module docstring for what is kept).

    Raises
    ------
    CamcalError
        Missing, unreadable or corrupt file, or an EXR layout that is not
        supported, in one line naming the file.
    """
    path = Path(path)
    kind = frame_format(path)
    if not path.exists():
        raise CamcalError(f"missing input {path}")
    if kind == "exr":
        return _read_exr(path)
    pixels = imread(path)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return ImageFrame(pixels, _CV_CHANNELS[pixels.shape[2]])


def _read_exr(path: Path) -> ImageFrame:
    import OpenEXR

    check_image_header(path)
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            if not exr.parts:
                raise CamcalError(f"cannot read {path} (corrupt EXR: no readable part)")
            if len(exr.parts) != 1:
                raise CamcalError(f"{path}: multi-part EXR ({len(exr.parts)} parts) is not supported")
            header = dict(exr.header())
            planes = {name: channel.pixels.copy() for name, channel in exr.channels().items()}
    except CamcalError:
        raise
    except (RuntimeError, ValueError) as error:
        raise CamcalError(f"cannot read {path} (corrupt EXR: {error})") from None
    low, high = (np.asarray(corner).tolist() for corner in header["dataWindow"])
    display = [np.asarray(corner).tolist() for corner in header["displayWindow"]]
    if [low, high] != display or low != [0, 0]:
        raise CamcalError(f"{path}: data window {low}-{high} differs from the display window "
                          f"{display[0]}-{display[1]} or does not start at 0,0; not supported")
    for channel in header["channels"]:
        if channel.xSampling != 1 or channel.ySampling != 1:
            raise CamcalError(f"{path}: channel {channel.name!r} is sub-sampled; not supported")
    names = tuple(planes)
    types = []
    for name in names:
        if planes[name].dtype not in (np.float16, np.float32):
            raise CamcalError(f"{path}: channel {name!r} is {planes[name].dtype} (UINT); only HALF and FLOAT are supported")
        types.append(planes[name].dtype)
    pixels = np.stack([planes[name].astype(np.float32) for name in names], axis=2)
    attributes = MappingProxyType({key: value for key, value in header.items() if key not in _EXR_LAYOUT})
    return ImageFrame(pixels, names, tuple(types), attributes)


def write_frame(path: str | os.PathLike, frame: ImageFrame) -> Path:
    """Write ``frame`` atomically in the format of ``path``'s suffix.

    The pixel type must be one the format holds (EXR: the frame must come
    from an EXR; PNG: 8/16-bit; TIFF: 8/16-bit or float32; JPEG: 8-bit).
    """
    path = Path(path)
    kind = frame_format(path)
    is_exr = frame.exr_types is not None
    if (kind == "exr") != is_exr or frame.pixels.dtype.type not in _DEPTHS[kind]:
        raise CamcalError(f"a {'EXR ' if is_exr else ''}{frame.pixels.dtype} image cannot be written as "
                          f"{kind.upper()} ({path}); write the format it was read from")
    with atomic_path(path) as tmp:
        if is_exr:
            _write_exr(tmp, frame)
        else:
            pixels = frame.pixels[:, :, 0] if frame.pixels.shape[2] == 1 else frame.pixels
            try:
                ok = cv2.imwrite(str(tmp), np.ascontiguousarray(pixels), _CV_PARAMS.get(kind, []))
            except cv2.error as error:
                raise CamcalError(f"cannot write {path}: {str(error).strip().splitlines()[-1]}") from None
            if not ok:
                raise CamcalError(f"cannot write {path}")
    return path


def _write_exr(path: Path, frame: ImageFrame) -> None:
    import OpenEXR

    planes = {
        name: np.ascontiguousarray(frame.pixels[:, :, i]).astype(dtype, copy=False)
        for i, (name, dtype) in enumerate(zip(frame.channels, frame.exr_types))
    }
    try:
        with OpenEXR.File(dict(frame.header or {}), planes) as exr:
            exr.write(str(path))
    except (RuntimeError, ValueError, TypeError) as error:
        raise CamcalError(f"cannot write EXR {path}: {error}") from None
