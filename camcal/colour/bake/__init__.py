"""Bake stage: a colour function as OpenColorIO transforms, and where the bake must hold.

Modules: ``transforms`` (:func:`transform_from_callable`: exact matrix or
log-chromaticity shaper + Lut3D), ``samples`` (:func:`bake_model`: the check
every exporter and ``--model auto`` share; chart gamut and plausible surfaces).
"""

from camcal.colour.bake.samples import bake_model, invert_model
from camcal.colour.bake.transforms import BakedTransform, transform_from_callable

__all__ = ["transform_from_callable", "BakedTransform", "bake_model", "invert_model"]
