"""Where a baked colour model must hold: chart gamut and plausible surface colours, and the bake of a model.

A characterisation model (linear camera RGB -> XYZ) is baked
(:func:`camcal.colour.bake.transforms.transform_from_callable`) over
camera RGB that real scenes give: the reference chart's XYZ and plausible
surface colours (CIE 13.3 test colour samples, a Pointer's-gamut grid),
inverted through the model (:func:`invert_model`). :func:`bake_model` is the
one check every exporter and ``--model auto`` share.

References
----------
- Pointer, M. R. (1980). The gamut of real surface colours. Color
  Research & Application, 5(3), 145-155.
- CIE 13.3-1995: Method of measuring and specifying colour rendering
  properties of light sources (test colour samples).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.bake.transforms import LUT_SIZES, BakedTransform, transform_from_callable
from camcal.colour.chart.reference import DEFAULT_CHART, reference_chart
from camcal.colour.spectral.data import adapt_XYZ, cie_1995_test_colour_samples, illuminant_white_XYZ

__all__ = [
    "invert_model",
    "model_chart_samples",
    "POINTER_LIGHTNESS",
    "POINTER_STEP",
    "MIN_CHANNEL_RATIO",
    "plausible_surface_XYZ",
    "plausible_surface_samples",
    "model_samples",
    "bake_model",
]


def _newton_inverse(apply: Callable[[np.ndarray], np.ndarray], XYZ: np.ndarray, x: np.ndarray,
                    iterations: int) -> np.ndarray:
    """Damped Newton steps (central-difference Jacobians, steps clipped to 0.1) towards ``apply(x) = XYZ``."""
    h = 1e-6
    for _ in range(iterations):
        F = apply(x) - XYZ
        if np.abs(F).max() < 1e-12:
            break
        J = np.stack([(apply(x + h * e) - apply(x - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
        try:
            step = np.linalg.solve(J, F[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        x = x - np.clip(step, -0.1, 0.1)
    return x


def invert_model(apply: Callable[[np.ndarray], np.ndarray], XYZ: Any, iterations: int = 40) -> np.ndarray:
    """Linear camera RGB whose ``apply`` gives ``XYZ``: damped Newton from two starts.

    A non-linear fit (root-polynomial, polynomial) can map several RGB to the
    same XYZ; the physical preimage of a reflective colour has non-negative
    RGB. Newton starts from the nearest point (relative XYZ distance) of a
    non-negative 25^3 RGB grid and from the best linear inverse; per target
    the converged solution (residual < 1e-9) with the least negative
    component is kept.

    Parameters
    ----------
    apply
        The fit's ``RGB -> XYZ``.
    XYZ
        ``(N, 3)`` targets.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` RGB (the last iterate where Newton did not converge).
    """
    XYZ = np.asarray(XYZ, dtype=np.float64).reshape(-1, 3)
    g = np.linspace(0.0, 1.0, 25)
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    mapped = apply(grid)
    scale = np.linalg.norm(XYZ, axis=1) + 1e-3
    nearest = np.array([np.argmin(np.linalg.norm(mapped - target, axis=1)) for target in XYZ], dtype=int)
    coarse = grid.reshape(25, 25, 25, 3)[::6, ::6, ::6].reshape(-1, 3)  # 5^3: 0, 0.25 ... 1
    M = np.linalg.lstsq(coarse, apply(coarse), rcond=None)[0].T
    candidates = [_newton_inverse(apply, XYZ, start, iterations)
                  for start in (grid[nearest], XYZ @ np.linalg.inv(M).T)]
    scores = []
    for x in candidates:
        residual = np.abs(apply(x) - XYZ).max(axis=1) / scale
        scores.append(np.where(residual < 1e-9, 0.0, 10.0 + residual) + np.maximum(-x.min(axis=1), 0.0))
    best = np.argmin(np.stack(scores), axis=0)
    return np.stack(candidates)[best, np.arange(len(XYZ))]


def _hull_samples(patches: np.ndarray, n: int) -> np.ndarray:
    """``patches`` plus the points of an ``n^3`` grid over their box inside the hull of them and them / 4."""
    from scipy.spatial import Delaunay

    vertices = np.vstack([patches, patches / 4.0])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    axes = [np.linspace(lo, hi, n) for lo, hi in zip(low, high)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = Delaunay(vertices).find_simplex(grid) >= 0
    return np.vstack([patches, grid[inside]])


def model_chart_samples(model, white_XYZ: Any, reference: str | None, n: int = 21) -> np.ndarray:
    """Linear camera RGB spanning a reference chart's gamut through ``model`` (see :func:`camcal.colour.export.ocio_fit.chart_gamut_samples`)."""
    try:
        chart = reference_chart(reference or DEFAULT_CHART, "D50")
    except CamcalError:  # not a chart (e.g. a spectral training set): the default chart's gamut
        chart = reference_chart(DEFAULT_CHART, "D50")
    white = np.asarray(white_XYZ, dtype=np.float64)
    XYZ = chart.XYZ if np.allclose(chart.white_XYZ, white, atol=1e-6) else adapt_XYZ(
        chart.XYZ, chart.white_XYZ, white, "CAT02")
    patches = _recordable_preimages(model.apply, XYZ)
    if getattr(model, "kind", "") == "rbf":
        patches = np.vstack([patches, model.centres])
    return _hull_samples(patches, n)


#: CIELAB lightness levels and a*, b* step of the Pointer's-gamut grid of plausible surface colours.
POINTER_LIGHTNESS = (15.0, 30.0, 45.0, 60.0, 75.0, 90.0)
POINTER_STEP = 10.0
#: Smallest channel of a plausible surface's camera RGB, relative to its largest.
MIN_CHANNEL_RATIO = 0.02


def plausible_surface_XYZ(white_XYZ: Any, illuminant: str | None = None) -> np.ndarray:
    """XYZ of plausible surface colours under a white: test colour samples and a Pointer's-gamut grid.

    Parameters
    ----------
    white_XYZ
        White of the output XYZ (Y = 1).
    illuminant
        CIE illuminant the reflectances are lit by (``SDS_ILLUMINANTS``
        name); ``None`` or an unknown name uses D65. Their XYZ are adapted
        (CAT02) from the illuminant's white to ``white_XYZ``.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)``: the 14 CIE 13.3 test colour samples, then the CIELAB
        grid (lightness :data:`POINTER_LIGHTNESS`, a*, b* every
        :data:`POINTER_STEP`) inside Pointer's gamut of real surface colours
        (tested under its illuminant C after CAT02).

    References
    ----------
    - Pointer, M. R. (1980). The gamut of real surface colours. Color
      Research & Application, 5(3), 145-155.
    - CIE 13.3-1995: Method of measuring and specifying colour rendering
      properties of light sources (test colour samples).
    """
    colour = require("colour")
    white = np.asarray(white_XYZ, dtype=np.float64)
    name = illuminant if illuminant in colour.SDS_ILLUMINANTS else "D65"
    shape = colour.SpectralShape(380, 780, 5)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values
    light = colour.SDS_ILLUMINANTS[name].copy().align(shape).values
    R = np.array([sd.copy().align(shape).values for sd in cie_1995_test_colour_samples().values()])
    XYZ = (R * light) @ cmfs / (light @ cmfs[:, 1])
    source_white = light @ cmfs / (light @ cmfs[:, 1])
    if not np.allclose(source_white, white, atol=1e-4):
        XYZ = adapt_XYZ(XYZ, source_white, white, "CAT02")
    ab = np.arange(-120.0, 120.0 + 1e-9, POINTER_STEP)
    Lab = np.stack(np.meshgrid(POINTER_LIGHTNESS, ab, ab, indexing="ij"), axis=-1).reshape(-1, 3)
    grid = colour.Lab_to_XYZ(Lab, colour.XYZ_to_xy(white))
    C = illuminant_white_XYZ("C")
    inside = colour.volume.is_within_pointer_gamut(adapt_XYZ(grid, white, C, "CAT02"))
    return np.vstack([XYZ, grid[inside]])


def plausible_surface_samples(apply: Callable[[np.ndarray], np.ndarray], white_XYZ: Any,
                              illuminant: str | None = None) -> np.ndarray:
    """Linear camera RGB of :func:`plausible_surface_XYZ`, inverted through ``apply``.

    Only preimages a camera records from a surface are kept: Newton
    converged (:func:`invert_model`) and no channel below
    :data:`MIN_CHANNEL_RATIO` of the largest one. Broadband reflectances
    under a broadband light never zero a channel of a camera whose
    sensitivities overlap; colours that would need it lie on the edge of the
    camera's own gamut.

    Returns
    -------
    numpy.ndarray
        ``(M, 3)`` linear camera RGB.
    """
    return _recordable_preimages(apply, plausible_surface_XYZ(white_XYZ, illuminant))


def _recordable_preimages(apply: Callable[[np.ndarray], np.ndarray], XYZ: np.ndarray) -> np.ndarray:
    """:func:`invert_model`, keeping converged preimages with no channel below :data:`MIN_CHANNEL_RATIO`."""
    RGB = invert_model(apply, XYZ)
    with np.errstate(invalid="ignore"):
        residual = np.abs(apply(RGB) - XYZ).max(axis=1) / (np.linalg.norm(XYZ, axis=1) + 1e-3)
        keep = (residual < 1e-6) & (RGB.min(axis=1) >= MIN_CHANNEL_RATIO * RGB.max(axis=1))
    return RGB[keep & np.all(np.isfinite(RGB), axis=1)]


def model_samples(model, white_XYZ: Any, reference: str | None, illuminant: str | None) -> np.ndarray:
    """The chart gamut and plausible surface samples of ``model`` (where its bake must hold)."""
    surfaces = plausible_surface_samples(model.apply, white_XYZ, illuminant)
    return np.vstack([model_chart_samples(model, white_XYZ, reference), surfaces])


def bake_model(model, white_XYZ: Any, *, reference: str | None = None, illuminant: str | None = None,
               max_delta_E: float = 0.2, lut_sizes: Sequence[int] = LUT_SIZES) -> BakedTransform:
    """A characterisation model as OCIO transforms: the one check every exporter and ``auto`` share.

    A ``matrix3x3`` model is an exact ``MatrixTransform``; any other is baked
    (:func:`transform_from_callable`) over the chart gamut of ``reference``
    and the plausible surface colours lit by ``illuminant``
    (:func:`bake_samples`), within ``max_delta_E`` CIEDE2000 or refused.

    Parameters
    ----------
    model
        ``LinearTermsModel`` or ``RBFModel`` (linear camera RGB -> XYZ).
    white_XYZ
        The model's target white (Y = 1).
    reference, illuminant
        The fit's reference chart and training illuminant.
    max_delta_E, lut_sizes
        See :func:`transform_from_callable`.

    Raises
    ------
    CamcalError
        The largest Lut3D still exceeds ``max_delta_E`` somewhere.
    """
    if model.kind == "matrix3x3":
        return transform_from_callable(model.apply, matrix=model.M)
    return transform_from_callable(model.apply, samples=model_samples(model, white_XYZ, reference, illuminant),
                                   white_XYZ=white_XYZ, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
