"""Lens conversions between camcal cameras and other formats' models, and what exporters and importers return.

The shared vocabulary of the interchange formats (:mod:`camcal.io.opencv`,
:mod:`camcal.io.kalibr`, :mod:`camcal.io.colmap_text`, :mod:`camcal.io.usd`,
:mod:`camcal.io.nuke`, :mod:`camcal.io.tde`): each imports this module and
nothing of :mod:`camcal.io.interchange`, which finds them by name.

One conversion core: :func:`refit_camera` takes any camcal camera to any
lens family (a camcal model name, see :data:`EXACT_FAMILIES`) and measures
what it cost with :func:`residual_figures` (max and RMS in pixels inside
the image and over an overscan border); :data:`EXACT_FAMILIES` is the one
table of which camcal model a family holds exactly, and
:func:`exactness_table` prints it for ``camcal rig export --help``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import FISHEYE_MODELS, MODEL_PARAMS, Distortion, frame_grid
from camcal.model.rig import Camera, Rig
from camcal.model.tde4 import FILMBACK_KEYS, LDPK_PARAMETERS, TDE4_MODELS

__all__ = [
    "DEFAULT_OVERSCAN",
    "EXACT_FAMILIES",
    "FORMAT_FAMILIES",
    "TDE_FAMILIES",
    "LensConversion",
    "ExportResult",
    "ImportResult",
    "Refit",
    "exact_distortion",
    "exactness_table",
    "max_pixel_residual",
    "nearest_camera",
    "nearest_family",
    "projection_figures",
    "refit_camera",
    "refit_projection",
    "residual_figures",
    "select_cameras",
]

_GRID_STEP_PX = 16.0
#: The refit's dense grid: this many samples across the image's longer side (edges included).
_REFIT_SAMPLES = 96
#: Overscan border of the residual figures: the frame scaled by this factor about its centre.
DEFAULT_OVERSCAN = 1.25

#: 3DEqualizer's lens distortion families (LDPK), as camcal names them (:mod:`camcal.model.tde4`).
TDE_FAMILIES = TDE4_MODELS

#: Lens family -> the camcal models it holds exactly. A family holds itself; ``none`` is any rectilinear
#: family with its coefficients at zero (3DE's squeezes at one); a wider family holds a narrower one with
#: the extra terms at zero. Every other pair is a refit (:func:`refit_camera`) with its residual printed.
EXACT_FAMILIES: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "none": ("none",),
    "polynomial": ("none", "polynomial"),
    "opencv": ("none", "polynomial", "opencv"),
    "division": ("none", "division"),
    "kannala-brandt": ("kannala-brandt",),
    "kannala-brandt-thin-prism": ("kannala-brandt", "kannala-brandt-thin-prism"),
    "3de-classic": ("none", "3de-classic"),
    "3de4-radial-deg4": ("none", "3de4-radial-deg4"),
    "3de4-anamorphic-deg4": ("none", "3de4-anamorphic-deg4"),
    "3de4-fisheye-deg8": ("3de4-fisheye-deg8",),
})

#: Export format -> the lens families its file holds (the first is the refit target of a rectilinear lens,
#: the fisheye family, when there is one, that of a fisheye lens).
FORMAT_FAMILIES: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "opencv": ("opencv", "kannala-brandt"),
    "kalibr": ("opencv", "kannala-brandt"),
    "colmap": ("opencv", "division", "kannala-brandt", "kannala-brandt-thin-prism"),
    "usd": ("opencv", "division", "kannala-brandt", "kannala-brandt-thin-prism", *TDE_FAMILIES),
    "nuke": ("3de4-radial-deg4", "3de-classic", "3de4-anamorphic-deg4", "3de4-fisheye-deg8"),
    "3de": ("3de4-radial-deg4", "3de-classic", "3de4-anamorphic-deg4", "3de4-fisheye-deg8"),
    "lensfun": ("polynomial",),
})

#: What the table of :func:`exactness_table` cannot say in one word per cell.
_FORMAT_NOTES = (
    "kalibr: radtan is k1 k2 p1 p2 (k3, rational and thin-prism terms at zero are exact, else refit)",
    "colmap: no pinhole thin prism; a division lens centred on the principal point",
    "usd: camcal's own lens attributes, read back by camcal",
    "nuke: LensDistortion (3DEqualizer preset) and LDPK nodes; its ST-maps hold every lens exactly",
    "lensfun: poly3 / poly5 / ptlens, square pixels: polynomial k1 k2 exact, any other lens refit to the best",
)


@dataclass(frozen=True)
class Refit:
    """What a refit cost: where the refitted camera puts the source camera's rays, in pixels.

    Attributes
    ----------
    family : str
        The lens family refitted to.
    exact : bool
        True when the family holds the source lens (no fit was needed).
    max_px, rms_px : float
        Largest and RMS distance over the image (its dense grid).
    border_max_px, border_rms_px : float
        The same over the overscan border (outside the image, inside the
        frame scaled by ``overscan`` about its centre); NaN when the
        refitted lens images none of the border's rays.
    overscan : float
    n_lost : int
        Grid pixels whose ray the source images but the refitted lens does
        not (beyond a rectilinear lens' 90 degrees, or its range).
    border_usable : float
        Share of the border's grid pixels the source images one-to-one
        (a ray, inside the source lens' fold): the border figures and the
        fit cover these only.
    image_usable : float
        The same share over the image: below 1 for a lens that turns over
        inside its own frame (beyond the views that calibrated it); the
        image's figures and the fit cover these pixels only.
    """

    family: str
    exact: bool
    max_px: float
    rms_px: float
    border_max_px: float
    border_rms_px: float
    overscan: float
    n_lost: int = 0
    border_usable: float = 1.0
    image_usable: float = 1.0

    def describe(self) -> str:
        """``max / RMS`` inside the image and over the border, in one line."""
        lost = f", {self.n_lost} grid pixels not imaged" if self.n_lost else ""
        usable = (f" ({100 * self.border_usable:.0f} % of it inside the source lens' fold)"
                  if self.border_usable < 1.0 else "")
        image = (f" ({100 * self.image_usable:.1f} % of it inside the source lens' fold)"
                 if self.image_usable < 1.0 else "")
        return (f"max residual {self.max_px:.3g} px, RMS {self.rms_px:.3g} px inside the image{image}; "
                f"max {self.border_max_px:.3g} px, RMS {self.border_rms_px:.3g} px over the "
                f"{self.overscan:g} overscan border{usable}{lost}")


@dataclass(frozen=True)
class LensConversion:
    """How one camera's projection went into (or came from) another format.

    Attributes
    ----------
    camera : str
        Camera name.
    source, target : str
        The model on each side, e.g. ``"division"`` and ``"radtan"``.
    exact : bool
        True when the target projects exactly like the source.
    max_px : float
        Largest distance in pixels between the two projections of the same
        rays over the frame (0.0 when exact).
    loss : str
        What makes it inexact (``"nearest fit"``, or e.g. the format's
        32-bit float attributes).
    """

    camera: str
    source: str
    target: str
    exact: bool
    max_px: float = 0.0
    loss: str = "nearest fit"
    refit: Refit | None = None

    def describe(self) -> str:
        """One line for the command's summary (with the lens refit's figures when there was one)."""
        head = f"camera {self.camera!r}: {self.source} -> {self.target}: "
        if self.refit is not None and self.max_px == self.refit.max_px:  # the conversion is the refit
            return head + ("exact" if self.exact else f"{self.loss}, {self.refit.describe()}")
        text = head + ("exact" if self.exact else f"{self.loss}, max residual {self.max_px:.3g} px")
        if self.refit is not None:
            text += f"; {self.refit.family}: " + ("exact" if self.refit.exact else self.refit.describe())
        return text


@dataclass(frozen=True)
class ExportResult:
    """What an exporter wrote.

    Attributes
    ----------
    paths : tuple of Path
        The files written.
    conversions : tuple of LensConversion
        One per exported camera.
    notes : tuple of str
        What the format does not hold (dropped frames, world pose, ...).
    """

    paths: tuple[Path, ...]
    conversions: tuple[LensConversion, ...]
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class ImportResult:
    """A rig read from another tool's file, with how each camera was converted.

    Attributes
    ----------
    rig : Rig
    conversions : tuple of LensConversion
    notes : tuple of str
    points_xyz : ndarray, shape (N, 3), optional
        Sparse points the file holds (world coordinates), to be written
        beside the rig (:func:`camcal.io.ply.write_points_ply`).
    points_rgb : ndarray, shape (N, 3), uint8, optional
    """

    rig: Rig
    conversions: tuple[LensConversion, ...]
    notes: tuple[str, ...] = ()
    points_xyz: NDArray[np.float64] | None = None
    points_rgb: NDArray[np.uint8] | None = None


def max_pixel_residual(source: Camera, target: Camera, *, lens: bool = True) -> float:
    """Largest pixel distance between two cameras' projections of the same rays.

    For every pixel ``x`` of a 16 px grid over ``source``'s frame (edges
    included), the ray ``r = K_s^-1 undistort_s(x)`` is projected by
    ``target``: ``x' = distort_t(K_t r)``; the result is ``max |x' - x|``.
    With ``lens=False`` both sides are pinholes (for formats without a lens
    model): ``max |K_t r - K_s r|`` over the same rays. Only the intrinsics
    matter (both cameras share the pose).
    """
    distorted = frame_grid(source.image_size, _GRID_STEP_PX)
    ideal = source.distortion.undistort(distorted, source.K)
    rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(source.K).T
    mapped = rays @ target.K.T
    projected = mapped[:, :2] / mapped[:, 2:]
    if lens:
        projected = target.distortion.distort(projected, target.K)
    distance = np.linalg.norm(projected - (distorted if lens else ideal), axis=1)
    distance = distance[np.isfinite(distance)]
    if len(distance) == 0:
        raise CamcalError(f"camera {source.name!r}: no ray of the frame projects through the converted camera")
    return float(distance.max())


def _describe_model(camera: Camera) -> str:
    skew = " with skew" if camera.K[0, 1] != 0.0 else ""
    return f"{camera.distortion.model}{skew}"


def nearest_camera(
    camera: Camera,
    holds: Callable[[Distortion], bool],
    fit_model: str,
    target_name: str,
    *,
    skew: bool = False,
    with_k3: bool | None = None,
) -> tuple[Camera, LensConversion]:
    """``camera`` itself when the format holds its lens (and skew), else the nearest one it holds.

    Parameters
    ----------
    camera : Camera
    holds : callable
        True when the format holds a distortion exactly.
    fit_model : str
        The lens family to refit to when it does not (``opencv``,
        ``kannala-brandt``, ...; :func:`refit_camera`).
    target_name : str
        The format's name for its model (reported).
    skew : bool
        Whether the format holds ``K[0, 1]``; when not, it is set to 0.
    with_k3 : bool, optional
        ``False`` holds ``k3`` at zero (Kalibr's radtan is ``k1 k2 p1 p2``);
        the default fits it for ``opencv`` and not for ``polynomial``.

    Returns
    -------
    (Camera, LensConversion)
        The conversion's ``max_px`` is :func:`max_pixel_residual`'s (a 16 px
        grid over the image), its ``refit`` the refit's figures, when there
        was one.
    """
    has_skew = camera.K[0, 1] != 0.0
    if not camera.distortion.has_correction and holds(camera.distortion) and (skew or not has_skew):
        return camera, LensConversion(camera.name, _describe_model(camera), target_name, True)
    K = camera.K.copy()
    if not skew:
        K[0, 1] = 0.0
    refit = None
    if camera.distortion.has_correction or not holds(camera.distortion):  # no format holds a correction field
        fixed = {"k3": 0.0} if with_k3 is False or (with_k3 is None and fit_model == "polynomial") else None
        converted, refit = refit_camera(camera, fit_model, K=K, fixed=fixed)
    else:
        converted = replace(camera, K=K)
    residual = max_pixel_residual(camera, converted)
    return converted, LensConversion(camera.name, _describe_model(camera), target_name, False, residual, refit=refit)


def select_cameras(rig: Rig, names: Sequence[str] | None) -> tuple[Camera, ...]:
    """The rig's cameras named in ``names`` (all when None), in that order."""
    if not names:
        return rig.cameras
    return tuple(rig.camera(name) for name in names)


# -- the conversion core: any camcal camera to any lens family ---------------------------

#: The families that image rays beyond 90 degrees off the axis.
_FISHEYE_FAMILIES = ("kannala-brandt", "kannala-brandt-thin-prism", "3de4-fisheye-deg8")
#: Parameters a refit to each camcal family fits (the 3DE families' come from their model).
_FIT_PARAMS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "none": (),
    "polynomial": ("k1", "k2", "k3"),
    "opencv": ("k1", "k2", "p1", "p2", "k3"),
    "division": ("lambda",),
    "kannala-brandt": MODEL_PARAMS["kannala-brandt"][0],
    "kannala-brandt-thin-prism": MODEL_PARAMS["kannala-brandt-thin-prism"][0],
})
#: 3DE parameters a refit leaves at their LDPK default.
_TDE_FIXED = ("anamorphic_squeeze", "cylindric_direction_deg", "cylindric_bending", "lens_rotation_deg", "squeeze_x",
              "squeeze_y")
#: Weight of the overscan border's pixels in a refit (the image's weigh 1): the plate comes first, the border is
#: kept from running away.
_BORDER_WEIGHT = 0.1
#: Families whose refit fits the focal length too (``K`` scaled about the principal point): 3DE's fisheye is
#: equisolid with the camera's focal length, which a wide lens' pinhole focal length does not make it.
_FOCAL_FITTED = ("3de4-fisheye-deg8",)
#: A ray the refit of a rectilinear family uses is at least this far in front of the camera (cos of its angle).
_MIN_DEPTH = 0.05


def _family_parameters(family: str, image_size: tuple[int, int]) -> tuple[dict[str, float], dict[str, float]]:
    """The family's fitted parameters at their neutral values (the identity, or the equidistant fisheye), and
    the ones a refit holds fixed (3DE's film back, squeezes, rotations and cylindric bending: ``K`` carries the
    pixel aspect)."""
    if family in TDE_FAMILIES:
        neutral = {p.key: p.default for p in LDPK_PARAMETERS[family]}
        fixed = {key: neutral.pop(key) for key in _TDE_FIXED if key in neutral}
        return neutral, {**fixed, **dict(zip(FILMBACK_KEYS, (float(v) for v in image_size)))}
    if family not in _FIT_PARAMS:
        raise CamcalError(f"unknown lens family {family!r}, expected one of: "
                          + ", ".join((*_FIT_PARAMS, *TDE_FAMILIES)))
    return dict.fromkeys(_FIT_PARAMS[family], 0.0), {}


def exact_distortion(distortion: Distortion, family: str, image_size: tuple[int, int]) -> Distortion | None:
    """``distortion`` written in ``family`` when the family holds it exactly (:data:`EXACT_FAMILIES`), else None.

    A lens with a correction field (:mod:`camcal.model.spline`) is held by
    no family; ``image_size`` is the film back a 3DE family's lens is
    normalised on.
    """
    if family not in EXACT_FAMILIES:
        raise CamcalError(f"unknown lens family {family!r}, expected one of: {', '.join(EXACT_FAMILIES)}")
    if distortion.has_correction or distortion.model not in EXACT_FAMILIES[family]:
        return None
    if distortion.model == family:
        return distortion
    neutral, fixed = _family_parameters(family, image_size)
    params = {**neutral, **fixed}
    params.update({name: value for name, value in distortion.params.items() if name in params})
    return Distortion(family, {} if family == "none" else params)


def nearest_family(distortion: Distortion, families: Sequence[str]) -> str:
    """The family of ``families`` that holds ``distortion`` exactly, else the one a refit should go to.

    A fisheye lens goes to the first fisheye family (if there is one), any
    other lens to the first rectilinear family.
    """
    for family in families:
        if not distortion.has_correction and distortion.model in EXACT_FAMILIES[family]:
            return family
    fisheye = distortion.model in _FISHEYE_FAMILIES
    matching = [f for f in families if (f in _FISHEYE_FAMILIES) == fisheye]
    return (matching or list(families))[0]


def _dense_grid(image_size: tuple[int, int], overscan: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Distorted pixels on a grid over the frame scaled by ``overscan`` about its centre, and which are inside it.

    The grid has :data:`_REFIT_SAMPLES` samples across the longer side and
    holds the image's edge pixels (centres ``0`` and ``W - 1``) and the
    scaled frame's edges (``(W - 1) / 2 +- overscan W / 2``).
    """
    if not np.isfinite(overscan) or overscan < 1.0:
        raise CamcalError(f"overscan must be a number >= 1, got {overscan}")
    width, height = image_size
    step = max(width, height) / _REFIT_SAMPLES
    axes = []
    for size in (width, height):
        # the frame's edges (pixel centres -1/2 and size - 1/2 away from them) scaled about its centre
        margin = (overscan - 1.0) * size / 2 + 0.5 if overscan > 1.0 else 0.0
        inside = np.linspace(0.0, size - 1.0, int(np.ceil((size - 1) / step)) + 1)
        outside = np.linspace(0.0, margin, int(np.ceil(margin / step)) + 1)[1:]  # evenly, the edge included
        axes.append(np.unique(np.concatenate([-outside[::-1], inside, size - 1.0 + outside])))
    points = np.stack(np.meshgrid(*axes), axis=-1).reshape(-1, 2)
    inside = (points[:, 0] >= 0) & (points[:, 0] <= width - 1) & (points[:, 1] >= 0) & (points[:, 1] <= height - 1)
    return points, inside


def _figures(distances: NDArray[np.float64]) -> tuple[float, float]:
    finite = distances[np.isfinite(distances)]
    if len(finite) == 0:
        return float("nan"), float("nan")
    return float(finite.max()), float(np.sqrt(np.mean(finite**2)))


def residual_figures(source: Camera, target: Camera, overscan: float = DEFAULT_OVERSCAN) -> Refit:
    """Where ``target`` puts ``source``'s rays, over the image and over the overscan border.

    For each distorted pixel ``x`` of a dense grid (96 samples across the
    longer side) over the frame scaled by ``overscan`` about its centre,
    the ray ``source.rays_from_pixels(x)`` is projected by ``target``
    (:meth:`~camcal.model.distortion.Distortion.project_rays`, wide angles
    included); the distances ``|x' - x|`` give the max and RMS inside the
    image and over the border. Pixels whose ray ``source`` does not image
    are left out; those ``target`` does not image are counted in ``n_lost``.

    Returns
    -------
    Refit
        With ``family = target.distortion.model`` and ``exact = False``.
    """
    return projection_figures(source, lambda rays: target.distortion.project_rays(rays, target.K),
                              target.distortion.model, overscan)


def projection_figures(source: Camera, project: Callable[[NDArray[np.float64]], NDArray[np.float64]], family: str,
                       overscan: float = DEFAULT_OVERSCAN) -> Refit:
    """:func:`residual_figures` of a lens given as its projection ``project(rays) -> distorted pixels`` (NaN where
    it images no ray), for a family camcal has no lens model of."""
    grid, inside = _dense_grid(source.image_size, overscan)
    rays = _source_rays(source, grid)
    seen = np.all(np.isfinite(rays), axis=1)
    projected = project(rays[seen])
    distances = np.linalg.norm(projected - grid[seen], axis=1)
    n_lost = int(np.count_nonzero(~np.isfinite(distances)))
    max_px, rms_px = _figures(distances[inside[seen]])
    if not np.isfinite(max_px):
        raise CamcalError(f"camera {source.name!r}: no pixel of the image has its ray imaged by the "
                          f"{family} lens")
    border_max, border_rms = _figures(distances[~inside[seen]])
    usable = float(np.mean(seen[~inside])) if np.any(~inside) else 1.0
    return Refit(family, False, max_px, rms_px, border_max, border_rms, float(overscan), n_lost, usable,
                 float(np.mean(seen[inside])))


#: Steps along the great circle from the optical axis to a border pixel's ray on which the source lens' image must
#: move steadily away from its centre (:func:`_source_rays`).
_FOLD_STEPS = 32
#: A border pixel's ray must project back onto it within this distance (the source's inverse converged).
_ROUND_TRIP_PX = 1e-3
#: Rays closer than this to the axis (radians) are the axis: no fold to test.
_AXIS_RAD = 1e-9


def _source_rays(camera: Camera, grid: NDArray[np.float64]) -> NDArray[np.float64]:
    """The source camera's rays of the grid's pixels, NaN for a pixel beyond the lens' fold.

    A lens with a polynomial or rational radial function turns over at
    some angle (its distorted radius stops growing): past that the pixels
    of the overscan border are imaged twice, and their ray (Newton's
    inverse) lies on the folded branch, where no lens of another family
    follows, so that fitting them drags the fit inside the image away.
    A border pixel's ray ``v`` (angle ``theta`` from the axis, azimuth
    ``phi``) is kept when the distance from the image of the axis to the
    source's image of the rays ``(sin(t theta) cos(phi), sin(t theta)
    sin(phi), cos(t theta))``, ``t = 1/32 ... 1``, grows strictly: the
    mapping is one-to-one from the axis out to ``v`` (the monotone radial
    distortion condition; cf. Kannala & Brandt 2006 on the turning point
    of their polynomial), and when the source projects ``v`` back onto
    the pixel (its inverse converged). Pixels inside the image are tested
    alike: a lens calibrated on views that did not reach its frame's
    corners may turn over inside the image (an OpenCV fit of a wide
    action camera: distances of 1e19 px where Newton's inverse found no
    ray).
    """
    rays = camera.distortion.rays_from_pixels(grid, camera.K)
    imaged = np.all(np.isfinite(rays), axis=1)
    if not np.any(imaged):
        return rays
    ray = rays[imaged]
    theta = np.arctan2(np.hypot(ray[:, 0], ray[:, 1]), ray[:, 2])
    phi = np.arctan2(ray[:, 1], ray[:, 0])
    angles = theta[:, None] * np.linspace(0.0, 1.0, _FOLD_STEPS + 1)[None, 1:]
    path = np.stack([np.sin(angles) * np.cos(phi)[:, None], np.sin(angles) * np.sin(phi)[:, None], np.cos(angles)],
                    axis=-1).reshape(-1, 3)
    centre = camera.distortion.project_rays(np.array([[0.0, 0.0, 1.0]]), camera.K)[0]
    images = camera.distortion.project_rays(path, camera.K).reshape(len(ray), _FOLD_STEPS, 2)
    with np.errstate(invalid="ignore"):
        radius = np.linalg.norm(images - centre, axis=2)
        monotone = np.all(np.diff(radius, axis=1) > 0.0, axis=1) | (theta < _AXIS_RAD)  # the axis itself is kept
        monotone &= np.all(np.isfinite(radius), axis=1)
        # and the ray is the pixel's (the inverse converged): its image is the pixel
        monotone &= np.linalg.norm(images[:, -1] - grid[imaged], axis=1) < _ROUND_TRIP_PX
    folded = np.flatnonzero(imaged)[~monotone]
    rays[folded] = np.nan
    return rays


def refit_camera(camera: Camera, family: str, *, overscan: float = DEFAULT_OVERSCAN, K: NDArray[np.float64] | None = None,
                 fixed: Mapping[str, float] | None = None) -> tuple[Camera, Refit]:
    """``camera`` with its lens in ``family``: exact where the family holds it, else a dense-grid refit.

    Parameters
    ----------
    camera : Camera
        Any camcal camera (its correction field, if any, included).
    family : str
        A camcal lens model or one of :data:`TDE_FAMILIES`.
    overscan : float
        The residual figures (and the fit) cover the frame scaled by this
        factor about its centre.
    K : ndarray, shape (3, 3), optional
        The refitted camera's matrix (default ``camera.K``, without skew for
        the 3DE families); the fit takes it into account.
    fixed : mapping, optional
        Parameters of the family held at these values (``{"k3": 0.0}``).

    Returns
    -------
    (Camera, Refit)
        The camera with the family's lens (``K`` kept; skew dropped for
        the 3DE families, which have none) and what it cost
        (:func:`residual_figures`).

    Notes
    -----
    The refit minimises ``sum w |target(ray(x)) - x|^2`` over the distorted
    pixels ``x`` of the dense grid of :func:`residual_figures`, ``ray`` the
    source camera's ray of ``x``: distances in the distorted image, where
    the plate is, with ``w = 1`` inside the image and ``w = 0.1^2`` over
    the overscan border (the plate first; the border kept from running
    away, its figures printed). It starts from
    the family's neutral lens (the identity, or the equidistant fisheye)
    and runs ``scipy.optimize.least_squares`` (Levenberg-Marquardt); 3DE's
    fisheye (equisolid on the camera's focal length) fits the focal length
    as well, from the shortest that images every pixel. The
    3DE families, defined distorted -> undistorted, are fitted in that
    direction (closed form) with each pixel's undistorted distance mapped
    back to distorted pixels by the source lens' local stretch
    (first order); the figures returned are measured, not estimated.
    A family that images rays in front of the camera only (all but the
    Kannala-Brandt ones) is fitted on the rays at least 3 degrees in front
    of the image plane.
    """
    K = np.array(camera.K if K is None else K, dtype=np.float64)
    if family in TDE_FAMILIES:
        K[0, 1] = 0.0
    fixed = dict(fixed or {})
    exact = exact_distortion(camera.distortion, family, camera.image_size)
    if (exact is not None and np.array_equal(K, camera.K)
            and all(exact.params.get(name, 0.0) == value for name, value in fixed.items())):
        converted = replace(camera, distortion=exact)
        return converted, replace(residual_figures(camera, converted, overscan), exact=True)
    grid, rays, weights = _fitting_grid(camera, family, overscan, family in FISHEYE_MODELS)
    neutral, held = _family_parameters(family, camera.image_size)
    held.update(fixed)
    names = tuple(name for name in neutral if name not in held)

    def lens(vector: NDArray[np.float64]) -> Distortion:
        return Distortion(family, {**held, **dict(zip(names, (float(v) for v in vector)))})

    def distorting(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        # a ray beyond the candidate's range: a large finite penalty
        return np.nan_to_num(weights * (lens(vector).project_rays(rays, K) - grid), nan=1e6).ravel()

    start = np.array([neutral[name] for name in names])
    if family in _FOCAL_FITTED:
        start = np.append(start, 0.0)
    if family in TDE_FAMILIES:  # defined distorted -> undistorted: fitted in that direction, in closed form
        residuals = _undistorting_residuals(lens, camera, grid, rays, weights, K, family in _FOCAL_FITTED)
    else:
        residuals = distorting
    if family in _FOCAL_FITTED:  # from a focal length long enough for the equisolid image to hold every pixel
        while np.any(np.abs(residuals(start)) >= 1e6) and start[-1] < 2.0:
            start[-1] += 0.05
    if len(start):
        start = _least_squares(residuals, start)
    if family in _FOCAL_FITTED:
        K = _scaled(K, start[-1])
    converted = replace(camera, K=K, distortion=lens(start[:len(names)]))
    return converted, residual_figures(camera, converted, overscan)


def refit_projection(camera: Camera, family: str,
                     project: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
                     start: Sequence[float], *,
                     overscan: float = DEFAULT_OVERSCAN) -> tuple[NDArray[np.float64], Refit]:
    """:func:`refit_camera`'s fit (its grid, weights and Levenberg-Marquardt) for a rectilinear family camcal
    has no lens model of (Lensfun's, :mod:`camcal.io.lensfun`), given as ``project(vector, rays) -> distorted
    pixels``; from ``start``, it returns the fitted vector and its :func:`projection_figures`.
    """
    grid, rays, weights = _fitting_grid(camera, family, overscan, False)

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.nan_to_num(weights * (project(vector, rays) - grid), nan=1e6).ravel()

    vector = _least_squares(residuals, np.asarray(start, dtype=np.float64))
    return vector, projection_figures(camera, lambda rays: project(vector, rays), family, overscan)


def _fitting_grid(camera: Camera, family: str, overscan: float,
                  fisheye: bool) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The refit's distorted pixels, their rays (at least 3 degrees in front of the image plane unless
    ``fisheye``) and weights (1 inside the image, :data:`_BORDER_WEIGHT` over the border)."""
    grid, inside = _dense_grid(camera.image_size, overscan)
    rays = _source_rays(camera, grid)
    usable = np.all(np.isfinite(rays), axis=1)
    if not fisheye:  # the others image rays in front of the camera only
        usable &= rays[:, 2] > _MIN_DEPTH * np.linalg.norm(rays, axis=1)
    if np.count_nonzero(usable) < 10:
        raise CamcalError(f"camera {camera.name!r}: too few rays of the frame for a {family} lens")
    return grid[usable], rays[usable], np.where(inside[usable], 1.0, _BORDER_WEIGHT)[:, None]


def _least_squares(residuals: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                   start: NDArray[np.float64]) -> NDArray[np.float64]:
    return scipy.optimize.least_squares(residuals, start, x_scale="jac", method="lm", xtol=1e-15, ftol=1e-15).x


def _scaled(K: NDArray[np.float64], log_scale: float) -> NDArray[np.float64]:
    """``K`` with its focal lengths (and skew) times ``exp(log_scale)``, the principal point kept."""
    scaled = K.copy()
    scaled[:2, :2] *= np.exp(log_scale)
    return scaled


def _undistorting_residuals(lens: Callable[[NDArray[np.float64]], Distortion], camera: Camera,
                            grid: NDArray[np.float64], rays: NDArray[np.float64], weights: NDArray[np.float64],
                            K: NDArray[np.float64], focal: bool) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """Residuals of a lens defined distorted -> undistorted, in distorted pixels to first order.

    ``J^-1 (target.undistort(x) - u(x))``, ``u(x)`` the pinhole pixel (in
    ``K``) of the source's ray of ``x`` and ``J = du/dx`` its local stretch
    (central differences, 0.25 px): the distorted-image distance the
    undistorted one stands for, without inverting the candidate lens at
    every step. With ``focal``, the vector's last entry scales ``K``'s focal
    lengths by its exponential (``u - c`` and ``J`` scale with it).
    """
    def pinhole(points: NDArray[np.float64]) -> NDArray[np.float64]:
        directions = camera.distortion.rays_from_pixels(points, camera.K) @ K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return directions[:, :2] / directions[:, 2:]

    ideal = (rays @ K.T)[:, :2] / (rays @ K.T)[:, 2:]
    step = 0.25
    stretch = np.stack([(pinhole(grid + [step, 0.0]) - pinhole(grid - [step, 0.0])) / (2 * step),
                        (pinhole(grid + [0.0, step]) - pinhole(grid - [0.0, step])) / (2 * step)], axis=2)
    keep = np.isfinite(stretch).all(axis=(1, 2)) & np.isfinite(ideal).all(axis=1)
    keep[keep] = np.abs(np.linalg.det(stretch[keep])) > 1e-9
    grid, ideal, inverse = grid[keep], ideal[keep], np.linalg.inv(stretch[keep]) * weights[keep][:, :, None]

    centre = K[:2, 2]

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        scale = np.exp(vector[-1]) if focal else 1.0
        coefficients = vector[:-1] if focal else vector
        difference = lens(coefficients).undistort(grid, _scaled(K, np.log(scale))) - (centre + scale * (ideal - centre))
        return np.nan_to_num(np.einsum("nij,nj->ni", inverse, difference) / scale, nan=1e6).ravel()

    return residuals


def exactness_table() -> str:
    """Which camcal lens model each export format holds exactly (``exact``) or refits (``refit``), as text.

    Rows are camcal's lens models, columns the formats of
    :data:`FORMAT_FAMILIES`; a cell is ``exact`` when one of the format's
    families holds the model (:data:`EXACT_FAMILIES`), else ``refit``.
    """
    models = list(dict.fromkeys((*MODEL_PARAMS, *TDE_FAMILIES)))
    formats = list(FORMAT_FAMILIES)
    width = max(len(m) for m in models) + 2
    lines = ["camcal model".ljust(width) + "  ".join(f.ljust(6) for f in formats)]
    for model in models:
        cells = []
        for fmt in formats:
            held = any(model in EXACT_FAMILIES[family] for family in FORMAT_FAMILIES[fmt])
            cells.append(("exact" if held else "refit").ljust(6))
        lines.append(model.ljust(width) + "  ".join(cells).rstrip())
    return "\n".join([*lines, *_FORMAT_NOTES])
