"""Lensfun's vignetting entries from camcal flat fields: the ``pa`` terms about the lens' centre and the
``<vignetting>`` element, shared by ``colour flatfield --lensfun`` (:mod:`camcal.io.flatfield`) and a lens profile's
export per lens state (:func:`camcal.io.lensfun.export_states`).

Lensfun's ``pa`` model (``LF_VIGNETTING_MODEL_PA``, lensfun.h; Pablo d'Angelo's, as Hugin fits it) corrects a
pixel's value ``C_s`` to ``C_d = C_s / (1 + k1 r^2 + k2 r^4 + k3 r^6)``, ``r`` 1 at the half diagonal of the image
about the lens' centre (mod-color.cpp, Lensfun 0.3.4): camcal's flat field ``V`` (:mod:`camcal.colour.flatfield`),
one term set for every channel (:func:`~camcal.colour.flatfield.common_radial_terms`). A Lensfun lens has one
centre (``<center>``, in units of half the shorter side ``(min(W, H) - 1) / 2`` about the image centre, y down,
modifier.cpp) for distortion and vignetting, so the terms are fitted about it, and what the flat field holds
beyond (colour shading, a non-radial term, another optical centre) is the deviation reported.

Each entry is for one lens state: ``focal`` (mm), ``aperture`` (f-number) and ``distance`` (m); Lensfun
interpolates between entries over focal length, ``1 / aperture`` and ``1 / distance`` (lens.cpp,
``__vignetting_dist``). A focus at infinity is written as ``distance="1000"``, as Lensfun's own calibration tool
writes it (tools/calibrate/calibrate.py).

References
----------
Lensfun, include/lensfun/lensfun.h (``lfVignettingModel``), libs/lensfun/mod-color.cpp, lens.cpp; database
format: https://lensfun.github.io/manual/latest/elem_calibration.html (``<vignetting focal aperture distance model
k1 k2 k3>``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.colour.flatfield import FlatField, RadialTerms, common_radial_terms
from camcal.io.lensfun_units import lensfun_aspect, lensfun_centre_px, lensfun_number

__all__ = ["LENSFUN_INFINITY_M", "VignettingState", "add_vignetting", "check_aspect", "check_vignetting",
           "describe", "vignetting_element", "vignetting_terms"]

#: The ``distance`` Lensfun's calibration tool writes for a focus at infinity (metres).
LENSFUN_INFINITY_M = 1000.0


@dataclass(frozen=True)
class VignettingState:
    """A flat field and the lens state it was shot at.

    Attributes
    ----------
    focal_mm : float
    aperture : float
        The f-number.
    distance_m : float
        The focus distance, ``math.inf`` possible.
    flat : FlatField
    """

    focal_mm: float
    aperture: float
    distance_m: float
    flat: FlatField

    def __post_init__(self) -> None:
        for name, value in (("focal length", self.focal_mm), ("aperture", self.aperture),
                            ("focus distance", self.distance_m)):
            if not (value > 0 and not math.isnan(value) and (name == "focus distance" or math.isfinite(value))):
                raise CamcalError(f"the Lensfun vignetting entry needs a {name} > 0, got {value}")


def check_aspect(flat: FlatField, aspect: float, where: str) -> None:
    """Refuse a flat field whose images have not got the lens' aspect ratio ``(max - 1) / (min - 1)``."""
    if abs(lensfun_aspect(flat.image_size) / aspect - 1.0) > 0.01:
        width, height = flat.image_size
        raise CamcalError(f"{where}: the flat field is of {width}x{height} images (aspect ratio "
                          f"{lensfun_aspect(flat.image_size):.4g}), the lens' images have {aspect:.4g}")


def check_vignetting(states: Sequence[VignettingState], aspect: float) -> None:
    """Refuse a flat field whose images have not got the lens' aspect ratio (:func:`check_aspect`)."""
    for state in states:
        check_aspect(state.flat, aspect, f"vignetting at {state.focal_mm:g} mm")


def vignetting_terms(flat: FlatField, center: NDArray | tuple[float, float]) -> RadialTerms:
    """The ``pa`` terms of ``flat`` about a Lensfun lens centre ``center`` (normalised: half the shorter side,
    about the image centre) and the largest deviation from the flat field they leave over the frame."""
    return common_radial_terms(flat, lensfun_centre_px(np.asarray(center, dtype=np.float64), flat.image_size))


def vignetting_element(calibration: ElementTree.Element, state: VignettingState,
                       terms: RadialTerms) -> ElementTree.Element:
    """Append ``<vignetting model="pa" focal aperture distance k1 k2 k3/>`` to a ``<calibration>``, replacing an
    entry of the same lens state."""
    distance = LENSFUN_INFINITY_M if math.isinf(state.distance_m) else state.distance_m
    key = [lensfun_number(state.focal_mm), lensfun_number(state.aperture), lensfun_number(distance)]
    for old in calibration.findall("vignetting"):
        if [old.get(name) for name in ("focal", "aperture", "distance")] == key:
            calibration.remove(old)
    return ElementTree.SubElement(calibration, "vignetting", model="pa", focal=key[0], aperture=key[1],
                                  distance=key[2], k1=lensfun_number(terms.k[0]), k2=lensfun_number(terms.k[1]),
                                  k3=lensfun_number(terms.k[2]))


def describe(state: VignettingState, terms: RadialTerms) -> str:
    """One line: the lens state, the terms written and the deviation they leave."""
    focus = "inf" if math.isinf(state.distance_m) else f"{state.distance_m:g} m"
    k = terms.k
    return (f"vignetting at {state.focal_mm:g} mm f/{state.aperture:g} focus {focus}: pa k1 {k[0]:.5g} k2 {k[1]:.5g} "
            f"k3 {k[2]:.5g}, within {100 * terms.max_deviation:.2f} % of the flat field over the frame")


def add_vignetting(calibration: ElementTree.Element, states: Sequence[VignettingState],
                   center: NDArray | tuple[float, float]) -> list[str]:
    """Each flat field's entry fitted about the lens centre ``center`` (normalised) appended to the
    ``<calibration>``; one note per entry (:func:`describe`)."""
    notes = []
    for state in states:
        terms = vignetting_terms(state.flat, center)
        vignetting_element(calibration, state, terms)
        notes.append(describe(state, terms))
    return notes
