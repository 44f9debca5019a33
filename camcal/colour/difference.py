"""Colour differences: CIELAB, Delta E (colour-science's formulas) and their statistics.

Every colour difference comes from colour-science (``colour.delta_E``):
CIE 1976, CIE 1994, CMC (l:c = 2:1) and CIE 2000, computed in CIELAB with
the white of the target space.

Conventions: ``XYZ`` is relative with ``Y = 1`` for the perfect white of the
target space; ``white_XYZ`` is that white (its Y is 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require

__all__ = ["DELTA_E_METHODS", "XYZ_to_Lab", "delta_E", "DeltaEStats"]


DELTA_E_METHODS = ("CIE 1976", "CIE 1994", "CMC", "CIE 2000")


def XYZ_to_Lab(XYZ: Any, white_XYZ: Any) -> np.ndarray:
    """CIELAB of relative XYZ (white Y = 1) under the white ``white_XYZ``.

    Parameters
    ----------
    XYZ
        ``(..., 3)`` relative XYZ.
    white_XYZ
        XYZ of the reference white; only its chromaticity is used, the
        white's luminance is taken as Y = 1.

    Returns
    -------
    numpy.ndarray
        ``(..., 3)`` L*, a*, b*.

    Examples
    --------
    >>> [round(float(v), 6) + 0 for v in XYZ_to_Lab([0.9505, 1.0, 1.089], [0.9505, 1.0, 1.089])]
    [100.0, 0.0, 0.0]
    """
    colour = require("colour")

    white = np.asarray(white_XYZ, dtype=np.float64)
    return colour.XYZ_to_Lab(np.asarray(XYZ, dtype=np.float64), colour.XYZ_to_xy(white))


def delta_E(
    XYZ_a: Any,
    XYZ_b: Any,
    white_XYZ: Any,
    method: str = "CIE 2000",
    reference_is_Lab: bool = False,
) -> np.ndarray:
    """Colour difference between two XYZ arrays (colour-science's formulas).

    Parameters
    ----------
    XYZ_a, XYZ_b
        ``(..., 3)`` relative XYZ; ``XYZ_b`` is CIELAB already when
        ``reference_is_Lab`` is true.
    white_XYZ
        White of the target space.
    method
        ``"CIE 1976"``, ``"CIE 1994"``, ``"CMC"`` or ``"CIE 2000"``.

    Returns
    -------
    numpy.ndarray
        ``(...)`` Delta E.

    References
    ----------
    Sharma, G., Wu, W., Dalal, E. N. (2005). The CIEDE2000 color-difference
    formula. Color Research & Application, 30(1), 21-30.

    Examples
    --------
    >>> w = [0.9505, 1.0, 1.089]
    >>> float(delta_E([0.2, 0.2, 0.2], [0.2, 0.2, 0.2], w))
    0.0
    """
    colour = require("colour")

    if method not in DELTA_E_METHODS:
        raise CamcalError(
            f"unknown Delta E method {method!r}, expected one of: {', '.join(DELTA_E_METHODS)}"
        )
    Lab_a = XYZ_to_Lab(XYZ_a, white_XYZ)
    Lab_b = np.asarray(XYZ_b, dtype=np.float64) if reference_is_Lab else XYZ_to_Lab(XYZ_b, white_XYZ)
    return np.asarray(colour.delta_E(Lab_a, Lab_b, method=method), dtype=np.float64)


@dataclass(frozen=True)
class DeltaEStats:
    """Summary of a set of Delta E values (units: Delta E)."""

    n: int
    mean: float
    median: float
    p90: float
    p95: float
    max: float

    @classmethod
    def from_values(cls, values: Any) -> DeltaEStats:
        """Statistics of a 1-D array of Delta E (linear-interpolated percentiles)."""
        v = np.asarray(values, dtype=np.float64).ravel()
        if v.size == 0:
            raise CamcalError("no Delta E values to summarise")
        return cls(
            n=int(v.size),
            mean=float(np.mean(v)),
            median=float(np.median(v)),
            p90=float(np.percentile(v, 90)),
            p95=float(np.percentile(v, 95)),
            max=float(np.max(v)),
        )

    def to_dict(self) -> dict:
        return {"n": self.n, "mean": self.mean, "median": self.median,
                "p90": self.p90, "p95": self.p95, "max": self.max}

    def __str__(self) -> str:
        return (f"mean {self.mean:.2f}, median {self.median:.2f}, p95 {self.p95:.2f}, "
                f"max {self.max:.2f} (n = {self.n})")
