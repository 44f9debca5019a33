"""Raw camera files (DNG, CR2, NEF, ARW ...) as camera-native linear RGB, via rawpy (LibRaw).

What comes out is what a colour characterisation needs and nothing more:
no white balance, no colour matrix, no gamma, no brightening.

- :func:`read_raw_mosaic`: the visible photosites as floats,
  ``(v - black_c) / (white - black_c)`` with each photosite's own black
  level (LibRaw's ``black_level_per_channel``) and the white level: exact,
  before any demosaicing. Photosites at or above the white level are
  flagged saturated.
- :func:`read_raw`: an ``(H, W, 3)`` image from the mosaic, either
  ``half`` size (each 2x2 CFA cell becomes one pixel: its R, the mean of
  its two Gs, its B; exact, no interpolation) or ``bilinear`` full size
  (OpenCV's Bayer demosaicing of the normalised mosaic). Saturated pixels
  (a saturated photosite in the cell, or within the 3x3 neighbourhood for
  ``bilinear``) are set to 1.0 in every channel and flagged, so the chart
  sampler's clipped test drops their patches.
- :func:`raw_metadata`: make and model (the TIFF IFD0 tags of the
  TIFF-based formats), black and white levels, CFA pattern.

Only 2x2 colour filter arrays with one R, two G and one B (RGGB, BGGR,
GRBG, GBRG) are supported; X-Trans and other layouts raise an error.
Pixel (0, 0) is the centre of the top-left visible photosite; a
half-size pixel (i, j) covers photosites (2i..2i+1, 2j..2j+1).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require

__all__ = ["RAW_SUFFIXES", "DEMOSAIC_METHODS", "RawMetadata", "RawMosaic", "RawImage", "is_raw",
           "read_raw_mosaic", "read_raw", "raw_metadata"]

RAW_SUFFIXES = (".dng", ".cr2", ".nef", ".arw", ".cr3", ".raf", ".orf", ".rw2", ".pef", ".srw", ".nrw")
DEMOSAIC_METHODS = ("half", "bilinear")
# OpenCV names a Bayer layout by the second row's second and third photosites.
_OPENCV_BAYER = {"RGGB": "COLOR_BayerBG2RGB", "BGGR": "COLOR_BayerRG2RGB",
                 "GRBG": "COLOR_BayerGB2RGB", "GBRG": "COLOR_BayerGR2RGB"}


def is_raw(path: str | os.PathLike) -> bool:
    """Whether ``path`` has a raw camera file suffix (:data:`RAW_SUFFIXES`)."""
    return Path(path).suffix.lower() in RAW_SUFFIXES


@dataclass(frozen=True)
class RawMetadata:
    """What the fit file records about a raw capture (its ``capture`` block)."""

    format: str
    make: str
    model: str
    black_level: tuple[float, ...]
    white_level: float
    cfa_pattern: str
    demosaic: str = ""
    saturated_fraction: float = 0.0

    def to_dict(self) -> dict:
        return {"format": self.format, "make": self.make, "model": self.model,
                "black_level": [float(v) for v in self.black_level], "white_level": float(self.white_level),
                "cfa_pattern": self.cfa_pattern, "demosaic": self.demosaic,
                "saturated_fraction": float(self.saturated_fraction)}


@dataclass(frozen=True, eq=False)
class RawMosaic:
    """Normalised photosites ``(H, W)``, their colour (0 R, 1 G, 2 B), saturation flags, metadata."""

    values: np.ndarray
    colour: np.ndarray
    saturated: np.ndarray
    metadata: RawMetadata


@dataclass(frozen=True, eq=False)
class RawImage:
    """Camera-native linear RGB ``(H, W, 3)`` (black 0, white 1) and saturated pixels ``(H, W)``."""

    RGB: np.ndarray
    saturated: np.ndarray
    metadata: RawMetadata


def _tiff_make_model(path: Path) -> tuple[str, str]:
    """Make and Model from IFD0 of a TIFF-based raw file ("" when absent or not TIFF)."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
            if head[:2] not in (b"II", b"MM"):
                return "", ""
            order = "<" if head[:2] == b"II" else ">"
            if struct.unpack(order + "H", head[2:4])[0] != 42:
                return "", ""
            handle.seek(struct.unpack(order + "I", head[4:8])[0])
            count = struct.unpack(order + "H", handle.read(2))[0]
            entries = [struct.unpack(order + "HHII", handle.read(12)) for _ in range(min(count, 4096))]
            found = {}
            for tag, kind, n, value in entries:
                if tag in (271, 272) and kind == 2:
                    if n <= 4:
                        raw = struct.pack(order + "I", value)[:n]
                    else:
                        handle.seek(value)
                        raw = handle.read(n)
                    found[tag] = raw.split(b"\0")[0].decode("ascii", "replace").strip()
            return found.get(271, ""), found.get(272, "")
    except (OSError, struct.error):
        return "", ""


def _open(path: Path):
    rawpy = require("rawpy")

    if not path.is_file():
        raise CamcalError(f"raw file not found: {path}")
    try:
        return rawpy.imread(str(path))
    except (rawpy.LibRawError, OSError, ValueError) as error:
        raise CamcalError(f"cannot read raw file {path}: {type(error).__name__} {error}".strip()) from None


def read_raw_mosaic(path: str | os.PathLike) -> RawMosaic:
    """The visible photosites normalised by their black and white levels (exact, see the module docstring)."""
    rawpy = require("rawpy")

    path = Path(path)
    with _open(path) as raw:
        try:
            desc = raw.color_desc.decode("ascii")
            pattern = np.asarray(raw.raw_pattern)
            values = np.asarray(raw.raw_image_visible, dtype=np.float64).copy()
            index = np.asarray(raw.raw_colors_visible).copy()
            black = np.asarray(raw.black_level_per_channel, dtype=np.float64)
            white = float(raw.white_level)
        except (rawpy.LibRawError, AttributeError) as error:
            raise CamcalError(f"cannot read the photosites of raw file {path}: {error}") from None
    if pattern is None or pattern.shape != (2, 2):
        raise CamcalError(f"{path}: only 2x2 colour filter arrays are supported, got {None if pattern is None else pattern.shape}")
    letters = "".join(desc[i] for i in pattern.ravel())
    if letters.replace("G", "").replace("R", "", 1).replace("B", "", 1) or letters.count("G") != 2:
        raise CamcalError(f"{path}: unsupported colour filter array {letters!r} (expected RGGB, BGGR, GRBG or GBRG)")
    if not np.all(black < white):
        raise CamcalError(f"{path}: black level {black.tolist()} is not below the white level {white:g}")
    saturated = values >= white
    normalised = (values - black[index]) / (white - black[index])
    colour = np.array(["RGB".index(c) for c in desc])[index]
    make, model = _tiff_make_model(path)
    metadata = RawMetadata(path.suffix.lower().lstrip("."), make, model, tuple(float(b) for b in black), white,
                           letters, "", float(saturated.mean()))
    return RawMosaic(normalised, colour, saturated, metadata)


def read_raw(path: str | os.PathLike, demosaic: str = "half") -> RawImage:
    """Camera-native linear RGB of a raw file (see the module docstring).

    Parameters
    ----------
    path
        A raw file LibRaw reads (DNG, CR2, NEF, ARW ...).
    demosaic
        ``"half"`` (exact, half size) or ``"bilinear"`` (full size).

    Returns
    -------
    RawImage
    """
    import cv2

    if demosaic not in DEMOSAIC_METHODS:
        raise CamcalError(f"unknown demosaic {demosaic!r}, expected one of: {', '.join(DEMOSAIC_METHODS)}")
    mosaic = read_raw_mosaic(path)
    values, colour, saturated = mosaic.values, mosaic.colour, mosaic.saturated
    height, width = (values.shape[0] // 2) * 2, (values.shape[1] // 2) * 2
    values, colour, saturated = values[:height, :width], colour[:height, :width], saturated[:height, :width]
    if demosaic == "half":
        cells = values.reshape(height // 2, 2, width // 2, 2).transpose(0, 2, 1, 3).reshape(height // 2, width // 2, 4)
        kinds = colour[:2, :2].ravel()
        RGB = np.stack([cells[:, :, kinds == c].mean(axis=2) for c in range(3)], axis=2)
        flags = saturated.reshape(height // 2, 2, width // 2, 2).any(axis=(1, 3))
    else:
        scale = 65535.0
        code = getattr(cv2, _OPENCV_BAYER[mosaic.metadata.cfa_pattern])
        bayer = np.round(np.clip(values, 0.0, 1.0) * scale).astype(np.uint16)
        RGB = cv2.cvtColor(bayer, code).astype(np.float64) / scale
        flags = cv2.dilate(saturated.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    RGB[flags] = 1.0
    metadata = RawMetadata(**{**mosaic.metadata.__dict__, "demosaic": demosaic})
    return RawImage(RGB, flags, metadata)


def raw_metadata(path: str | os.PathLike, demosaic: str = "half") -> RawMetadata:
    """The ``capture`` block of a raw file as :func:`read_raw` would record it."""
    return read_raw(path, demosaic).metadata
