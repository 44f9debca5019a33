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

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.difference import XYZ_to_Lab
from camcal.colour.spectral.data import adapt_XYZ, illuminant_white_XYZ, reflectance_XYZ

__all__ = ["DEFAULT_CHART", "CHART_ALIASES", "ReferenceChart", "reference_chart"]


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
    """

    name: str
    patch_names: tuple[str, ...]
    XYZ: np.ndarray
    illuminant: str
    white_XYZ: np.ndarray
    rows: int
    columns: int

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
