"""Spectral data: reflectance sets, camera sensitivities, illuminant whites, chromatic adaptation.

Conventions: spectra are sampled on one wavelength grid ``wavelengths``
(nm, shape ``(W,)``); integrals are sums on that grid. XYZ is relative with
Y = 1 for the perfect white. :func:`adapt_XYZ` is chromatic adaptation (von
Kries with CAT02 or Bradford, colour-science).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require

__all__ = [
    "CAMERAS",
    "REFLECTANCE_SETS",
    "MUNSELL_SUBSET",
    "CAT_TRANSFORMS",
    "CMFS_NAME",
    "spectral_shape",
    "resample_spectral",
    "reflectance_XYZ",
    "camera_sensitivities",
    "reflectance_set",
    "illuminant_white_XYZ",
    "adapt_XYZ",
    "cie_1995_test_colour_samples",
]

CAMERAS = ("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)")


REFLECTANCE_SETS = ("BabelColor Average", "ColorChecker N Ohta", "ISO 17321-1", "PMC", "rawtoaces 190",
                    "CIE 1995 TCS", "CIE 2017 TCS", "NIST CQS 9.0", "Munsell validation", "Munsell held-out")
MUNSELL_SUBSET = 300
CAT_TRANSFORMS = ("CAT02", "Bradford")
CMFS_NAME = "CIE 1931 2 Degree Standard Observer"


def spectral_shape(wavelengths: Any) -> Any:
    """The ``colour.SpectralShape`` of a regular 1-D wavelength grid (nm); raises on any other grid."""
    colour = require("colour")

    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    steps = np.diff(wavelengths)
    if wavelengths.ndim != 1 or wavelengths.size < 3 or not np.allclose(steps, steps[0]):
        raise CamcalError("wavelengths must be a regular 1-D grid of at least 3 samples")
    return colour.SpectralShape(float(wavelengths[0]), float(wavelengths[-1]), float(steps[0]))


def resample_spectral(sd_or_msds: Any, wavelengths: Any) -> np.ndarray:
    """Values of a colour-science spectral object on ``wavelengths`` (extrapolated constant)."""
    shape = spectral_shape(wavelengths)
    copy = sd_or_msds.copy()
    copy.interpolator_kwargs = {}
    copy.extrapolator_kwargs = {"method": "Constant", "left": None, "right": None}
    return np.asarray(copy.align(shape).values, dtype=np.float64)


def reflectance_XYZ(reflectances: Any, illuminant: Any,
                    shape: tuple[float, float, float] = (380.0, 780.0, 5.0)) -> tuple[np.ndarray, np.ndarray]:
    """XYZ of reflectance spectra under an illuminant, and of the perfect white (Y = 1).

    The one spectral integration of camcal (chart references, the demo's
    truth, :meth:`SimulatedCamera.XYZ`, :func:`camcal.colour.fit.illuminant.reflectance_XYZ`).

    Parameters
    ----------
    reflectances : colour-science spectral distributions or array_like
        A dict or list of ``SpectralDistribution``, a ``MultiSpectralDistributions``,
        or ``(N, W)`` reflectances sampled on ``shape``.
    illuminant : str or array_like
        CIE illuminant name (``colour.SDS_ILLUMINANTS``), or ``(W,)`` spectral
        power sampled on ``shape``.
    shape : (start, end, interval)
        Wavelength grid in nm of the integration (default 380 to 780 nm every 5 nm).

    Returns
    -------
    XYZ : ndarray, shape (N, 3)
    white : ndarray, shape (3,)

    Notes
    -----
    ``XYZ = k sum_l R(l) S(l) xyz(l)``, ``k = 1 / sum_l S(l) y(l)`` with the CIE
    1931 2 degree observer: colour-science's ``msds_to_XYZ`` / ``sd_to_XYZ``
    (method ``"Integration"``, ASTM E308 without its tables) divided by 100.
    """
    colour = require("colour")
    from colour.colorimetry import sds_and_msds_to_msds

    grid = colour.SpectralShape(*shape)
    if isinstance(illuminant, str):
        if illuminant not in colour.SDS_ILLUMINANTS:
            raise CamcalError(f"unknown illuminant {illuminant!r}, expected a name of colour.SDS_ILLUMINANTS")
        S = colour.SDS_ILLUMINANTS[illuminant].copy().align(grid)
    else:
        values = np.asarray(illuminant, dtype=np.float64)
        if values.shape != grid.wavelengths.shape:
            raise CamcalError(f"illuminant has {values.size} samples, the grid {shape} has {grid.wavelengths.size}")
        S = colour.SpectralDistribution(values, grid.wavelengths)
    # aligned here as colour-science would (reshape = align), so it does not warn that it aligns it
    cmfs = colour.MSDS_CMFS[CMFS_NAME].copy().align(grid)
    if isinstance(reflectances, Mapping):
        reflectances = list(reflectances.values())
    if isinstance(reflectances, (list, tuple)):
        reflectances = sds_and_msds_to_msds(reflectances)
    XYZ = colour.msds_to_XYZ(reflectances, cmfs=cmfs, illuminant=S, method="Integration", shape=grid)
    white = colour.sd_to_XYZ(colour.sd_ones(grid), cmfs=cmfs, illuminant=S, method="Integration")
    return np.asarray(XYZ, dtype=np.float64) / 100.0, np.asarray(white, dtype=np.float64) / 100.0


def camera_sensitivities(name: str, wavelengths: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Measured sensitivities of one of colour-science's cameras.

    Parameters
    ----------
    name
        ``"Nikon 5100 (NPL)"`` or ``"Sigma SDMerill (NPL)"``.
    wavelengths
        Grid to resample on; the camera's own grid when ``None``.

    Returns
    -------
    wavelengths, sensitivities
        ``(W,)`` nm and ``(W, 3)`` R, G, B (each scaled to peak 1 by the
        data set).
    """
    colour = require("colour")

    if name not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise CamcalError(f"unknown camera {name!r}, expected one of: {', '.join(CAMERAS)}")
    msds = colour.MSDS_CAMERA_SENSITIVITIES[name]
    if wavelengths is None:
        wavelengths = msds.wavelengths
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    return wavelengths, resample_spectral(msds, wavelengths)


def reflectance_set(name: str, wavelengths: Any) -> tuple[list[str], np.ndarray]:
    """Measured reflectance spectra shipped with colour-science.

    Parameters
    ----------
    name
        ``"BabelColor Average"``, ``"ColorChecker N Ohta"``, ``"ISO 17321-1"``
        (ColorChecker 24 spectra), ``"PMC"`` (30 patches), ``"rawtoaces
        190"`` (the 190 training reflectances of RAW to ACES), ``"CIE 1995
        TCS"`` (the 14 test colour samples of CIE 13.3), ``"CIE 2017 TCS"``
        (the 99 colour evaluation samples of CIE 224:2017 and IES TM-30:
        measured natural objects, skins, textiles, paints and prints chosen
        to span colour space and spectral shapes), ``"NIST CQS 9.0"``
        (15 samples), or ``"Munsell validation"`` / ``"Munsell held-out"``:
        two disjoint sets of :data:`MUNSELL_SUBSET` real Munsell colours
        (renotation xyY under illuminant C, seeded draw) turned into
        reflectances by Otsu et al. (2018) spectral recovery (smooth,
        plausible surfaces; not measured spectra).
    wavelengths
        ``(W,)`` grid in nm; spectra are interpolated, and extended with
        their end values outside their measured range.

    Returns
    -------
    names, reflectances
        Patch names and ``(N, W)`` reflectances.
    """
    colour = require("colour")

    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if name == "rawtoaces 190":
        msds = colour.characterisation.read_training_data_rawtoaces_v1()
        values = resample_spectral(msds, wavelengths).T
        return [str(label) for label in msds.labels], values
    if name.startswith("Munsell "):
        if name not in REFLECTANCE_SETS:
            raise CamcalError(f"unknown reflectance set {name!r}, expected one of: {', '.join(REFLECTANCE_SETS)}")
        names, grid, values = _munsell_reflectances(name.endswith("held-out"))
        return list(names), np.array([np.interp(wavelengths, grid, v) for v in values])
    if name == "CIE 2017 TCS":
        from colour.quality.cfi2017 import load_TCS_CIE2017

        msds = load_TCS_CIE2017(colour.SpectralShape(380, 780, 5))
        return [str(label) for label in msds.labels], resample_spectral(msds, wavelengths).T
    if name in ("CIE 1995 TCS", "NIST CQS 9.0"):
        from colour.quality.datasets import SDS_VS

        sds = cie_1995_test_colour_samples() if name == "CIE 1995 TCS" else SDS_VS["NIST CQS 9.0"]
        return list(sds.keys()), np.array([resample_spectral(sd, wavelengths) for sd in sds.values()])
    if name not in colour.SDS_COLOURCHECKERS:
        raise CamcalError(
            f"unknown reflectance set {name!r}, expected one of: {', '.join(REFLECTANCE_SETS)}"
        )
    sds = colour.SDS_COLOURCHECKERS[name]
    return list(sds.keys()), np.array([resample_spectral(sd, wavelengths) for sd in sds.values()])


@functools.cache
def _munsell_reflectances(held_out: bool) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Names, grid and reflectances of one of the two disjoint Munsell sets (cached)."""
    colour = require("colour")
    from colour.notation.datasets import MUNSELL_COLOURS_REAL

    order = np.random.default_rng(0).permutation(len(MUNSELL_COLOURS_REAL))
    picked = order[MUNSELL_SUBSET:2 * MUNSELL_SUBSET] if held_out else order[:MUNSELL_SUBSET]
    illuminant_C = colour.SDS_ILLUMINANTS["C"]
    names, values = [], []
    for i in picked:
        (hue, value, chroma), xyY = MUNSELL_COLOURS_REAL[i]
        XYZ = colour.xyY_to_XYZ(np.array([xyY[0], xyY[1], xyY[2] / 100.0]))
        sd = colour.recovery.XYZ_to_sd_Otsu2018(XYZ, illuminant=illuminant_C)
        names.append(f"{hue} {value:g}/{chroma:g}")
        values.append(np.clip(sd.values, 0.0, 1.0))
    return tuple(names), np.asarray(sd.wavelengths, dtype=np.float64), np.array(values)


def illuminant_white_XYZ(name: str) -> np.ndarray:
    """XYZ (Y = 1) of a CIE illuminant's chromaticity, CIE 1931 observer.

    Examples
    --------
    >>> illuminant_white_XYZ("D65").round(4).tolist()
    [0.9505, 1.0, 1.0891]
    """
    colour = require("colour")

    table = colour.CCS_ILLUMINANTS[CMFS_NAME]
    if name not in table:
        raise CamcalError(f"unknown illuminant {name!r}, expected a CIE name such as D50, D65, A")
    return np.asarray(colour.xy_to_XYZ(table[name]), dtype=np.float64)


def adapt_XYZ(XYZ: Any, white_source: Any, white_target: Any, transform: str = "CAT02") -> np.ndarray:
    """Chromatic adaptation of XYZ from one white to another (von Kries).

    Parameters
    ----------
    XYZ
        ``(..., 3)`` relative XYZ under ``white_source``.
    white_source, white_target
        XYZ of the two whites (Y = 1).
    transform
        ``"CAT02"`` or ``"Bradford"`` (colour-science's
        ``chromatic_adaptation`` with method ``Von Kries``).

    Returns
    -------
    numpy.ndarray
        ``(..., 3)`` corresponding colours under ``white_target``.
    """
    colour = require("colour")

    if transform not in CAT_TRANSFORMS:
        raise CamcalError(f"unknown adaptation {transform!r}, expected one of: CAT02, Bradford")
    return np.asarray(
        colour.chromatic_adaptation(
            np.asarray(XYZ, dtype=np.float64),
            np.asarray(white_source, dtype=np.float64),
            np.asarray(white_target, dtype=np.float64),
            method="Von Kries",
            transform=transform,
        ),
        dtype=np.float64,
    )


def cie_1995_test_colour_samples() -> Any:
    """The 14 test colour samples of CIE 13.3-1995 (``TCS01`` ... ``TCS14``), name -> spectral distribution.

    colour-science 0.4.7 files them under ``SDS_TCS["CIE 1995"]`` beside the
    CIE 2024 set; 0.4.6 holds them alone, at the top of ``SDS_TCS``.
    """
    from colour.quality.datasets import SDS_TCS

    return SDS_TCS["CIE 1995"] if "CIE 1995" in SDS_TCS else SDS_TCS
