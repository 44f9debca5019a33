"""Lensfun's TCA (lateral chromatic aberration) entries from a board's corners seen in each colour channel, for
a lens profile's export per focal length (:func:`camcal.io.lensfun.export_states`).

``<tca model="poly3" focal vr vb cr cb br bb/>``: Lensfun's ``poly3`` model
(:mod:`camcal.geometry.lateral_ca`), fitted about the lens' one centre (its
``<center>``, which distortion and vignetting share) in Lensfun's normalised
units, half the shorter side of the image (Lensfun 0.3.4 modifier.cpp). TCA
depends on the focal length only (lensfun.h): one entry per focal length.

References
----------
Lensfun database format: https://lensfun.github.io/manual/latest/elem_calibration.html (``<tca model focal vr vb
cr cb br bb>``); include/lensfun/lensfun.h (``LF_TCA_MODEL_POLY3``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.lateral_ca import LateralCA, fit_lateral_ca
from camcal.io.lensfun_units import lensfun_centre_px, lensfun_number, lensfun_unit_px

__all__ = ["TCAState", "add_tca", "check_tca"]


@dataclass(frozen=True)
class TCAState:
    """A board's corners seen in each channel at one focal length.

    Attributes
    ----------
    focal_mm : float
    corners : ndarray, shape (N, 3, 2)
        Each corner in the red, green and blue channel (pixels).
    image_size : (int, int)
    found_in : str
        Where the board was found (``"6 / 6 images"``), for the note.
    """

    focal_mm: float
    corners: NDArray[np.float64]
    image_size: tuple[int, int]
    found_in: str = ""


def check_tca(states: Sequence[TCAState], image_size: tuple[int, int]) -> None:
    """Refuse a focal length given twice or corners from images of another size than the lens'."""
    focals = [state.focal_mm for state in states]
    for state in states:
        if not (math.isfinite(state.focal_mm) and state.focal_mm > 0) or focals.count(state.focal_mm) > 1:
            raise CamcalError(f"TCA: each focal length once and > 0, got {', '.join(f'{f:g}' for f in focals)} mm")
        if tuple(state.image_size) != tuple(image_size):
            raise CamcalError(f"TCA at {state.focal_mm:g} mm: the board images are {state.image_size[0]}x"
                              f"{state.image_size[1]} px, the lens' {image_size[0]}x{image_size[1]} px")


def add_tca(calibration: ElementTree.Element, states: Sequence[TCAState], center: tuple[float, float],
            image_size: tuple[int, int]) -> list[str]:
    """Fit each state's ``poly3`` terms about the lens centre ``center`` (normalised), append its ``<tca>`` to the
    ``<calibration>`` and return one note per state: the terms and the residual of the corners in pixels."""
    unit, centre_px = lensfun_unit_px(image_size), lensfun_centre_px(center, image_size)
    notes = []
    for state in sorted(states, key=lambda state: state.focal_mm):
        fit: LateralCA = fit_lateral_ca(state.corners, centre_px, unit)
        terms = {f"{name}{channel}": lensfun_number(value) for channel, values in (("r", fit.red), ("b", fit.blue))
                 for name, value in zip("vcb", values)}
        ElementTree.SubElement(calibration, "tca", model="poly3", focal=lensfun_number(state.focal_mm), **terms)
        found_in = f" in {state.found_in}" if state.found_in else ""
        notes.append(f"TCA at {state.focal_mm:g} mm from {fit.n_corners} corners{found_in}: poly3 red v "
                     f"{fit.red[0]:.6f} c {fit.red[1]:.3g} b {fit.red[2]:.3g}, blue v {fit.blue[0]:.6f} c "
                     f"{fit.blue[1]:.3g} b {fit.blue[2]:.3g}; residual RMS red {fit.rms_px[0]:.3f} px, blue "
                     f"{fit.rms_px[1]:.3f} px "
                     f"(worst {fit.max_px.max():.3f} px)")
    return notes
