"""Chart images: a photo or raw file as float RGB code values in [0, 1]."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["read_image"]


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float RGB normalised code values ``(H, W, 3)`` in [0, 1].

    8- and 16-bit integer images are divided by 255 or 65535; float images
    (EXR, TIFF) are returned as they are; raw camera files (DNG, CR2, NEF,
    ARW ...) give camera-native linear RGB at half size with black 0 and
    white 1, saturated pixels at 1 (:func:`camcal.io.raw.read_raw`).
    """
    from camcal.io.frames import imread  # noqa: PLC0415 - cv2 only when an image is read
    from camcal.io.raw import is_raw, read_raw  # noqa: PLC0415

    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"chart image not found: {path}")
    if is_raw(path):
        return read_raw(path).RGB
    image = imread(path)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    image = image[:, :, :3][:, :, ::-1]
    if image.dtype == np.uint8:
        return image.astype(np.float64) / 255.0
    if image.dtype == np.uint16:
        return image.astype(np.float64) / 65535.0
    return image.astype(np.float64)
