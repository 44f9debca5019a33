"""Spectral stage: spectral data, simulated cameras, sensitivity estimation, illuminants, adaptation.

Modules: ``data`` (reflectance sets, camera sensitivities, illuminant
whites, :func:`adapt_XYZ`), ``simulate`` (:class:`SimulatedCamera`),
``estimate`` (:func:`estimate_sensitivities`, :func:`mu_factor`),
``sensitivities`` (:class:`Sensitivities`, the data of ``*.ssf.json``;
:func:`illuminant_spd`), ``captures`` (:func:`estimate_from_captures`).
"""

from camcal.colour.spectral.captures import Capture, estimate_from_captures
from camcal.colour.spectral.data import adapt_XYZ, camera_sensitivities, illuminant_white_XYZ, reflectance_set
from camcal.colour.spectral.estimate import estimate_sensitivities, mu_factor
from camcal.colour.spectral.sensitivities import Sensitivities, illuminant_spd
from camcal.colour.spectral.simulate import SimulatedCamera

__all__ = [
    "adapt_XYZ",
    "illuminant_white_XYZ",
    "reflectance_set",
    "camera_sensitivities",
    "SimulatedCamera",
    "estimate_sensitivities",
    "mu_factor",
    "Sensitivities",
    "illuminant_spd",
    "Capture",
    "estimate_from_captures",
]
