"""Chart stage: reference charts, detection and sampling in an image array, patch sets, linearisation.

Modules: ``layouts`` (the charts crews carry: where their patches sit),
``reference`` (:func:`reference_chart`), ``detect``
(:func:`detect_chart`, :func:`sample_patches`, :func:`patches_from_image`),
``find`` (the detection view of a raw image and camcal's segmentation detector),
``patches`` (:class:`PatchSet`), ``linearise`` (:func:`fit_linearisation`).
"""

from camcal.colour.chart.detect import detect_chart, patches_from_image, sample_patches
from camcal.colour.chart.linearise import Linearisation, fit_linearisation
from camcal.colour.chart.patches import PatchSet
from camcal.colour.chart.reference import reference_chart

__all__ = ["reference_chart", "detect_chart", "sample_patches", "patches_from_image", "PatchSet",
           "Linearisation", "fit_linearisation"]
