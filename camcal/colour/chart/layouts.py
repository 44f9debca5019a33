"""The charts crews carry: their patch grids, where each patch sits, and their reference data.

A layout is the geometry of a chart's patches in *grid units*: ``u`` across
the ``columns`` of the main patch grid, ``v`` down its ``rows``, both 0 to 1
over the whole grid (the coordinates of
:class:`camcal.colour.chart.detect.ChartDetection`). Patches are numbered
row by row from the top-left of the chart seen from its front, the order of
their reference data.

=============  ===========  =======  ==================================================
layout         grid         patches  reference data
=============  ===========  =======  ==================================================
classic        4 x 6        24       ColorChecker24 (colour-science, X-Rite's values)
passport       4 x 6        24       the same (the Passport's classic page; its other
                                     page, the creative enhancement target, is ignored)
mini           4 x 6        24       the same
nano           4 x 6        24       the same
digital-sg     10 x 14      140      ColorCheckerSG (colour-science, X-Rite's values)
it8            12 x 22 +    288      the chart's own CGATS file (batch-specific)
               24 greys
=============  ===========  =======  ==================================================

Published sizes (X-Rite; approximate, for rendering and for the sampled
square, which stays inside a patch): the Classic is a 279 x 216 mm card of
patches a little under 2 in square; the Passport's page is 125 x 90 mm,
the Mini's card 64 x 108 mm, the Nano 40 x 25 mm; the ColorChecker
Digital SG (8.5 x 11 in) has 14 x 10 patches whose border ring alternates
white, grey and black. Classic, Passport, Mini and Nano have the same 24
colours in the same 4 x 6 order, so an image cannot tell them apart: they
are detected as one 24-patch family (named by the user, by default
``classic``).

IT8.7/2 (ISO 12641): rows ``A`` to ``L`` of 22 columns (``A1`` ... ``L22``)
and below them a grey scale of 24 steps ``GS0`` (white) to ``GS23``
(black) across the width of the 22 columns (each step 22 / 24 of a column
wide), half a row below row ``L``. The reference XYZ come from the CGATS
file shipped with each chart batch (:mod:`camcal.io.cgats`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["ChartLayout", "LAYOUTS", "LAYOUT_FAMILIES", "chart_layout", "it8_patch_names"]


def it8_patch_names() -> tuple[str, ...]:
    """The 288 IT8.7/2 patch names in chart order: ``A1`` ... ``L22``, then ``GS0`` ... ``GS23``."""
    rows = "ABCDEFGHIJKL"
    return tuple(f"{r}{c}" for r in rows for c in range(1, 23)) + tuple(f"GS{k}" for k in range(24))


@dataclass(frozen=True)
class ChartLayout:
    """A chart's patch geometry (see the module docstring).

    Attributes
    ----------
    name
        The layout's short name (``classic``, ``digital-sg``...).
    title
        What the chart is called.
    rows, columns
        The main patch grid (what detection finds).
    patch_fraction
        A patch's side over the grid pitch (1: patches touching).
    reference
        colour-science's name of its reference data, or ``None`` when the
        chart's own CGATS file is needed.
    grey_scale
        Steps of a grey-scale strip below the main grid (IT8.7/2: 24), 0 for none.
    """

    name: str
    title: str
    rows: int
    columns: int
    patch_fraction: float
    reference: str | None
    grey_scale: int = 0

    @property
    def n_patches(self) -> int:
        """Patches in the reference data: the main grid and the grey scale."""
        return self.rows * self.columns + self.grey_scale

    @property
    def family(self) -> str:
        """The layouts an image cannot tell apart share a family (``24``, ``digital-sg``, ``it8``)."""
        return "24" if (self.rows, self.columns) == (4, 6) else self.name

    def patch_uv(self) -> np.ndarray:
        """``(n_patches, 2)`` patch centres in grid units, chart order."""
        r, c = np.divmod(np.arange(self.rows * self.columns), self.columns)
        uv = np.column_stack([(c + 0.5) / self.columns, (r + 0.5) / self.rows])
        if self.grey_scale:
            k = np.arange(self.grey_scale)
            grey = np.column_stack([(k + 0.5) / self.grey_scale, np.full(self.grey_scale, 1.0 + 1.0 / self.rows)])
            uv = np.vstack([uv, grey])
        return uv

    def patch_half_size(self) -> np.ndarray:
        """``(n_patches, 2)`` half widths of each patch in grid units (u, v)."""
        half = np.tile([0.5 * self.patch_fraction / self.columns, 0.5 * self.patch_fraction / self.rows],
                       (self.n_patches, 1))
        if self.grey_scale:
            half[self.rows * self.columns:, 0] = 0.5 * self.patch_fraction / self.grey_scale
        return half


LAYOUTS: dict[str, ChartLayout] = {
    layout.name: layout
    for layout in (
        ChartLayout("classic", "ColorChecker Classic", 4, 6, 0.84, "ColorChecker24 - After November 2014"),
        ChartLayout("passport", "ColorChecker Passport", 4, 6, 0.84, "ColorChecker24 - After November 2014"),
        ChartLayout("mini", "ColorChecker Mini", 4, 6, 0.80, "ColorChecker24 - After November 2014"),
        ChartLayout("nano", "ColorChecker Nano", 4, 6, 0.70, "ColorChecker24 - After November 2014"),
        ChartLayout("digital-sg", "ColorChecker Digital SG", 10, 14, 0.90, "ColorCheckerSG - After November 2014"),
        ChartLayout("it8", "IT8.7/2", 12, 22, 1.0, None, grey_scale=24),
    )
}

#: One layout per family an image can tell apart, the largest first (the order auto-detection tries them in).
LAYOUT_FAMILIES = ("it8", "digital-sg", "classic")


def chart_layout(name: str) -> ChartLayout:
    """The layout called ``name`` (:data:`LAYOUTS`), or one clear error."""
    key = str(name).lower()
    if key not in LAYOUTS:
        raise CamcalError(f"unknown chart type {name!r}, expected one of: {', '.join(LAYOUTS)}")
    return LAYOUTS[key]
