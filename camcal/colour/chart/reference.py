"""Reference colour charts: patch names and reference XYZ from colour-science.

- ``ColorChecker24 - After November 2014`` (default; alias ``cc24``),
  ``ColorChecker24 - Before November 2014`` (``cc24-2005``),
  ``BabelColor Average`` (``babel``), ``ColorCheckerSG - After November
  2014`` (``sg``, 140 patches) and the other ``CCS_COLOURCHECKERS`` entries:
  xyY under their D50 illuminant;
- ``ISO 17321-1`` and ``ColorChecker N Ohta``: reflectance spectra,
  integrated with the CIE 1931 observer under the chosen illuminant.

Reference XYZ are relative with Y = 1 for the perfect white. A chart's
``illuminant`` is the white its XYZ are relative to (D50 for xyY data).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.difference import XYZ_to_Lab
from camcal.colour.spectral.data import adapt_XYZ, illuminant_white_XYZ, reflectance_XYZ

__all__ = ["DEFAULT_CHART", "CHART_ALIASES", "ReferenceChart", "reference_chart", "reference_from_measurements"]


DEFAULT_CHART = "ColorChecker24 - After November 2014"
CHART_ALIASES = {
    "cc24": "ColorChecker24 - After November 2014",
    "cc24-2014": "ColorChecker24 - After November 2014",
    "cc24-2005": "ColorChecker24 - Before November 2014",
    "babel": "BabelColor Average",
    "sg": "ColorCheckerSG - After November 2014",
    "sg-2005": "ColorCheckerSG - Before November 2014",
}
_SPECTRAL = ("ISO 17321-1", "ColorChecker N Ohta")


@dataclass(frozen=True, eq=False)
class ReferenceChart:
    """A chart's patch names and reference XYZ (white Y = 1).

    Attributes
    ----------
    name
        colour-science's name of the data.
    patch_names
        ``N`` names in chart order (row by row from the top-left).
    XYZ
        ``(N, 3)`` relative XYZ under ``illuminant``.
    illuminant
        Name of the white the XYZ are relative to (e.g. ``"D50"``).
    white_XYZ
        XYZ of that white (Y = 1).
    rows, columns
        Patch grid.
    layout
        The chart's layout (:data:`camcal.colour.chart.layouts.LAYOUTS`):
        ``classic`` for a 4 x 6 grid, ``digital-sg`` for 10 x 14 unless named.
    """

    name: str
    patch_names: tuple[str, ...]
    XYZ: np.ndarray
    illuminant: str
    white_XYZ: np.ndarray
    rows: int
    columns: int
    layout: str = ""

    def __post_init__(self) -> None:
        if not self.layout:
            object.__setattr__(self, "layout", {(4, 6): "classic", (10, 14): "digital-sg"}.get(
                (self.rows, self.columns), ""))

    @property
    def neutral(self) -> np.ndarray:
        """Indices of the neutral patches (CIELAB chroma below 4)."""
        Lab = XYZ_to_Lab(self.XYZ, self.white_XYZ)
        return np.flatnonzero(np.hypot(Lab[:, 1], Lab[:, 2]) < 4.0)


def reference_chart(name: str = DEFAULT_CHART, illuminant: str = "D50") -> ReferenceChart:
    """Reference XYZ of a colour chart from colour-science.

    Parameters
    ----------
    name
        A ``CCS_COLOURCHECKERS`` name, an alias of :data:`CHART_ALIASES`,
        or a spectral set (``ISO 17321-1``, ``ColorChecker N Ohta``).
    illuminant
        For spectral sets, the CIE illuminant to integrate under; xyY charts
        are measured under D50 and are chromatically adapted (CAT02) when
        another illuminant is asked for.

    Returns
    -------
    ReferenceChart
    """
    colour = require("colour")


    key = CHART_ALIASES.get(str(name).lower(), name)
    white = illuminant_white_XYZ(illuminant)
    if key in _SPECTRAL:
        sds = colour.SDS_COLOURCHECKERS[key]
        if illuminant not in colour.SDS_ILLUMINANTS:
            raise CamcalError(f"unknown illuminant {illuminant!r} for spectral chart {key!r}")
        XYZ, white = reflectance_XYZ(sds, illuminant)
        return ReferenceChart(key, tuple(sds.keys()), XYZ, illuminant, white, 4, 6)
    if key not in colour.CCS_COLOURCHECKERS:
        names = [k for k in colour.CCS_COLOURCHECKERS if " " in k] + list(_SPECTRAL)
        raise CamcalError(
            f"unknown reference chart {name!r}, expected one of: {', '.join(names)} "
            f"(aliases: {', '.join(CHART_ALIASES)})"
        )
    cc = colour.CCS_COLOURCHECKERS[key]
    xyY = np.array(list(cc.data.values()), dtype=np.float64)
    XYZ = np.asarray(colour.xyY_to_XYZ(xyY), dtype=np.float64)
    chart_white = np.asarray(colour.xy_to_XYZ(cc.illuminant), dtype=np.float64)
    if np.allclose(colour.XYZ_to_xy(white), cc.illuminant, atol=1e-4):
        white = chart_white
    else:
        XYZ = adapt_XYZ(XYZ, chart_white, white, "CAT02")
    return ReferenceChart(key, tuple(cc.data.keys()), XYZ, illuminant, white, int(cc.rows), int(cc.columns))


def _patch_key(name: str) -> str:
    """A patch name compared without case or leading zeros (``A01`` = ``a1``, ``GS00`` = ``GS0``)."""
    head = name.rstrip("0123456789")
    digits = name[len(head):]
    return head.upper() + (str(int(digits)) if digits else "")


def reference_from_measurements(name: str, names: Any, XYZ: Any, layout: str, *, measured_under: str = "D50",
                                illuminant: str = "D50") -> ReferenceChart:
    """A reference chart from measured XYZ (a chart's own CGATS file), in the layout's patch order.

    Parameters
    ----------
    name
        What the data are called (the file's name, say).
    names, XYZ
        The measured patches (any order; names matched without case or
        leading zeros, ``A01`` = ``A1``) and their XYZ, white Y = 1.
    layout
        A layout of :data:`camcal.colour.chart.layouts.LAYOUTS`; for
        ``it8`` the patches are :func:`camcal.colour.chart.layouts.it8_patch_names`.
    measured_under, illuminant
        The white the XYZ are relative to, and the white wanted (adapted with CAT02).

    Raises
    ------
    CamcalError
        When a patch of the layout is missing from the data.
    """
    from camcal.colour.chart.layouts import chart_layout, it8_patch_names

    chart = chart_layout(layout)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    given = {_patch_key(str(n)): k for k, n in enumerate(names)}
    wanted = it8_patch_names() if chart.name == "it8" else tuple(str(n) for n in names)
    missing = [n for n in wanted if _patch_key(n) not in given]
    if missing:
        raise CamcalError(f"reference data {name!r} lack {len(missing)} patch(es) of the {chart.title} "
                          f"chart: {', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}")
    if len(wanted) != chart.n_patches:
        raise CamcalError(f"reference data {name!r} hold {len(wanted)} patches, the {chart.title} chart "
                          f"{chart.n_patches}")
    XYZ = XYZ[[given[_patch_key(n)] for n in wanted]]
    source, white = illuminant_white_XYZ(measured_under), illuminant_white_XYZ(illuminant)
    if not np.allclose(source, white, atol=1e-6):
        XYZ = adapt_XYZ(XYZ, source, white, "CAT02")
    return ReferenceChart(name, wanted, XYZ, illuminant, white, chart.rows, chart.columns, chart.name)
