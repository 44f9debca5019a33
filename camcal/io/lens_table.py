"""A lens table: a lens profile sampled over its encoder range, in OpenTrackIO's lens terms (JSON).

Virtual-production tools read a lens as a table of samples over the lens
encoders (Mo-Sys / Mark Roberts Motion Control's Open Lens File, Unreal's
Lens File, SMPTE RIS OpenTrackIO). camcal writes the profile at a grid of
encoder values::

    {
      "format": "camcal.lens_table", "version": 1,
      "static": {"lens": {"make": "camcal", "model": "zoom"}},
      "image_size": [1920, 1080],
      "encoderRanges": {"zoom": {"0": 24.0, "1": 70.0, "unit": "mm", "mapping": "linear"},
                        "focus": {"0": "inf", "1": 0.5, "unit": "m", "mapping": "linear in 1 / distance"}},
      "samples": [{"lens": {"encoders": {"zoom": 0.0, "focus": 0.0}, "focusDistance": "inf"},
                   "focalLength_mm": 24.0, "K": [[...]], "distortion": {...}, "sigma": {...},
                   "worstProjectionSigma_px": 0.3}, ...]
    }

The encoders are OpenTrackIO's normalised ones (zoom 0 at the widest, 1 at
the longest focal length; focus 0 at the farthest distance, 1 at the
nearest), over the range the profile was calibrated on
(:meth:`camcal.model.lens_profile.LensProfile.from_encoders`). The
intrinsics are camcal's (``K`` in pixels, pixel (0, 0) at the centre of the
top-left pixel, the lens in camcal's rig-file form): the profile holds no
sensor size, so OpenTrackIO's millimetre fields (``pinholeFocalLength``,
``projectionOffset``) are not written.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.jsonfile import dumps
from camcal.model.rig import Camera

__all__ = ["LENS_TABLE_FORMAT", "write_lens_table"]

LENS_TABLE_FORMAT = "camcal.lens_table"


def _distance(focus_m: float) -> float | str:
    return "inf" if math.isinf(focus_m) else focus_m


def write_lens_table(out: Path, samples: Sequence[tuple[float, float, float, float, Camera]], *, name: str,
                     image_size: tuple[int, int], focal_range: tuple[float, float],
                     focus_range: tuple[float, float]) -> Path:
    """Write a lens table (the module docstring's form) atomically.

    Parameters
    ----------
    out : Path
        The ``.json`` file.
    samples : sequence of (float, float, float, float, Camera)
        ``(zoom encoder, focus encoder, focal_mm, focus_m, camera)``, the camera at that lens state with its
        quality's ``sigma`` and ``worst_projection_sigma_px``.
    name : str
        The lens' ``model``.
    image_size : (int, int)
    focal_range, focus_range : (float, float)
        The calibrated ranges (mm; m, nearest first, ``inf`` possible).
    """
    if out.suffix.lower() != ".json":
        raise CamcalError(f"a lens table is a .json file, got {out.name!r}")
    near, far = focus_range
    table = {
        "format": LENS_TABLE_FORMAT, "version": 1,
        "static": {"lens": {"make": "camcal", "model": name}},
        "image_size": list(image_size),
        "encoderRanges": {
            "zoom": {"0": focal_range[0], "1": focal_range[1], "unit": "mm", "mapping": "linear"},
            "focus": {"0": _distance(far), "1": _distance(near), "unit": "m", "mapping": "linear in 1 / distance"},
        },
        "samples": [{"lens": {"encoders": {"zoom": zoom, "focus": focus}, "focusDistance": _distance(focus_m)},
                     "focalLength_mm": focal_mm, "K": camera.K.tolist(), "distortion": camera.distortion.to_dict(),
                     "sigma": dict(camera.quality.sigma),
                     "worstProjectionSigma_px": camera.quality.worst_projection_sigma_px}
                    for zoom, focus, focal_mm, focus_m, camera in samples],
    }
    atomic_write_text(out, dumps(table))
    return out
