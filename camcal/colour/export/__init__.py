"""Export stage: colour fits as OpenColorIO colour spaces, Looks and processors, and as ICC profiles.

Modules: ``ocio_config`` (specs, :func:`build_ocio_config`), ``ocio_fit``
(:func:`colour_space_from_fit`, :func:`look_from_match`,
:func:`fit_processor`), ``icc`` (:func:`icc_profile_from_fit`,
:func:`check_icc`), ``lcms`` (LittleCMS through ctypes, an independent
reader), and the ACES hand-off: ``aces`` (the camera's input transform with
its ACES transform ID, as CLF), ``amf`` (the ACES Metadata File naming it),
``dctl`` (the same transform for DaVinci Resolve). The files are written by
:mod:`camcal.io.ocio`, :mod:`camcal.io.icc` and :mod:`camcal.io.aces`.
"""

from camcal.colour.export.icc import check_icc, icc_profile_from_fit
from camcal.colour.export.ocio_config import build_ocio_config
from camcal.colour.export.ocio_fit import colour_space_from_fit, config_spec_from_fits, fit_processor, look_from_match

__all__ = ["build_ocio_config", "colour_space_from_fit", "look_from_match", "config_spec_from_fits",
           "fit_processor", "icc_profile_from_fit", "check_icc"]
