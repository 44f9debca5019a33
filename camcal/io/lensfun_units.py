"""What every Lensfun database entry camcal writes shares: the text of its numbers and the image geometry
Lensfun normalises by.

Lensfun measures radii and the lens centre in units of half the shorter side of the image, ``(min(W, H) - 1) / 2``
pixels, about the image centre ``((W - 1) / 2, (H - 1) / 2)`` (y down), and an entry's ``<aspect-ratio>`` is
``(max(W, H) - 1) / (min(W, H) - 1)`` (Lensfun 0.3.4, libs/lensfun/modifier.cpp; database format:
https://lensfun.github.io/manual/latest/elem_lens.html).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["lensfun_aspect", "lensfun_centre_px", "lensfun_number", "lensfun_unit_px"]


def lensfun_number(value: float) -> str:
    """A number as the database's text (9 significant digits: float64 values round-trip to ~1e-9)."""
    return f"{value:.9g}"


def lensfun_unit_px(image_size: tuple[int, int]) -> float:
    """Lensfun's normalised unit in pixels: half the shorter side, ``(min(W, H) - 1) / 2``."""
    return (min(image_size) - 1) / 2.0


def lensfun_aspect(image_size: tuple[int, int]) -> float:
    """The ``<aspect-ratio>`` of images of ``image_size``: ``(max(W, H) - 1) / (min(W, H) - 1)``."""
    return (max(image_size) - 1) / (min(image_size) - 1)


def lensfun_centre_px(center: NDArray | tuple[float, float], image_size: tuple[int, int]) -> NDArray[np.float64]:
    """The pixel position of a lens centre ``<center x y>`` (normalised units about the image centre)."""
    width, height = image_size
    unit = lensfun_unit_px(image_size)
    return np.array([(width - 1) / 2.0 + center[0] * unit, (height - 1) / 2.0 + center[1] * unit])
