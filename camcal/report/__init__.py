"""Reports: plots, tables and HTML that verbs write with ``--report DIR``.

One signature everywhere: ``write_report(result, out_dir, ...) -> list[Path]``
(the result first, then the folder; options after), writing atomically and
returning the files written:

- :mod:`camcal.report.characterisation` (``colour fit``),
- :mod:`camcal.report.colour_match` (``colour match``),
- :mod:`camcal.report.calibration` (``calibrate board``),
- :mod:`camcal.report.rectification` (``rectify``: its page, with ``--sigma`` the sigma heat maps),
- ``camcal.demo.report.write_html`` (``camcal demo``).

Conventions every plot follows:

- A reprojection residual is ``observed - projected`` (detected corner or
  feature minus the model's projection of it), in pixels; arrows point
  from the projection to the observation. :data:`RESIDUAL_LABEL` is the
  axis / legend text.
- Pixel (0, 0) is the centre of the top-left pixel (COLMAP's 0.5 is
  converted at the boundary, :func:`camcal.model.camera.pixels_from_colmap`).
"""

from __future__ import annotations

__all__ = ["RESIDUAL_LABEL"]

#: Axis / legend text of a reprojection residual (see the module docstring).
RESIDUAL_LABEL = "observed - projected (px)"

