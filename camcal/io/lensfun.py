"""Lensfun lens database XML: camcal cameras as Lensfun lens entries, and back.

Lensfun (the lens correction library darktable, RawTherapee, Hugin and
GIMP read) keeps lenses in XML files of ``<lens>`` entries; camcal writes
one entry per camera (:func:`export`), or one lens at several focal lengths
(:func:`export_states`, with vignetting and TCA entries per lens state given,
:mod:`camcal.io.lensfun_vignetting`, :mod:`camcal.io.lensfun_tca`)::

    <lensdatabase version="1">
      <lens>
        <maker>camcal</maker>
        <model>cam0</model>
        <mount>Generic</mount>
        <center x="..." y="..."/>
        <cropfactor>1.047</cropfactor>
        <aspect-ratio>1.778</aspect-ratio>
        <calibration>
          <distortion model="poly3" focal="35.2" k1="-0.0123"/>
          <real-focal-length focal="35.2" real-focal="35.2"/>
        </calibration>
      </lens>
      <!-- camcal image_size 1920 1080 -->
    </lensdatabase>

Lensfun's models (``lfLens::GetDistortionModelDesc``, lens.cpp) map the
undistorted radius ``Ru`` to the distorted ``Rd`` in its normalised
coordinates::

    poly3   Rd = Ru (1 - k1 + k1 Ru^2)
    poly5   Rd = Ru (1 + k1 Ru^2 + k2 Ru^4)
    ptlens  Rd = Ru (a Ru^3 + b Ru^2 + c Ru + 1 - a - b - c)

The normalisation (``lfModifier::lfModifier``, modifier.cpp, Lensfun 0.3.4
and later): pixel coordinates are pixel indices (the top-left pixel's centre
is ``(0, 0)``, as in camcal), the origin is the image centre
``((W - 1) / 2, (H - 1) / 2)`` moved by the lens' ``<center>`` (in the same
units), and the unit ``s = (min(W, H) - 1) / 2`` pixels, half the shorter
side measured between the extreme pixel centres, when the image's crop
factor and aspect ratio ``(max(W, H) - 1) / (min(W, H) - 1)`` are the
calibration's (else Lensfun rescales through the sensor diagonal). The
undistorted image is a pinhole image with focal length ``F`` pixels; in
Lensfun's units (those of its geometry conversions) ``F = F_mm s / m``,
``m = 21.633 / sqrt(aspect^2 + 1) / cropfactor`` the unit in millimetres,
and ``F_mm d`` is the lens' real focal length, ``d = Rd / Ru`` at the
centre (``1 - k1``, ``1``, ``1 - a - b - c``; Hugin's focal length
correction, ``get_hugin_focal_correction``). camcal writes the camera's
focal length in mm as ``focal`` (or the lens state's, :func:`export_states`)
and ``F_mm d`` as ``<real-focal-length real-focal>``.

A camcal ``polynomial`` lens ``x_d = x_u (1 + k1 r^2 + k2 r^4)`` (focal
``f`` pixels, square pixels) is exactly ``poly5`` with ``F = f``,
``k1' = k1 s^2 / f^2``, ``k2' = k2 s^4 / f^4``, and with ``k2 = 0``
``poly3`` with ``k1' / (1 - k1')^3 = k1 s^2 / f^2``, ``F = f / (1 - k1')``
(for ``k1 s^2 / f^2 > -4/27``). A Kannala-Brandt (fisheye) lens is written
as Lensfun's ``<type>fisheye</type>`` (equidistant: its undistorted image
puts a ray at ``F theta`` from the centre), where the same formulas hold
with the ray's angle ``theta`` for ``tan theta``: ``k1..k4`` with ``k3 = k4
= 0`` is exactly ``poly5``. Every other lens (opencv, division, a fisheye with k3 or k4, a
polynomial ``k3``, non-square pixels or skew) is refitted to each model
through :func:`camcal.io.conversion.refit_projection` (the core of
:func:`~camcal.io.conversion.refit_camera`: its dense grid, weights and
Levenberg-Marquardt, ``F`` and the terms fitted, the principal point kept
and written as ``<center>``). The model written is the simplest (``poly3``,
``poly5``, ``ptlens``) within 0.01 px RMS of the best; every model's
residual inside the image is printed. ``ptlens`` has odd powers of the
radius no camcal lens has: read back, it needs ``a = c = 0`` (``poly3``
with ``k1 = b``).

Checked against Lensfun 0.3.4 (lensfunpy 1.18.0). Lensfun 0.3.95 and later
keep the corrected image's focal length: they scale it by ``d = 1 - a - b - c``
(``1 - k1`` for ``poly3``), the same lens with a corrected image of focal
``F d``.

The crop factor is the full-frame diagonal (43.27 mm) over the sensor's
(the camera's ``sensor_width_mm``, 36 mm without one, or the
``sensor_width_mm`` given to :func:`export`). A Lensfun
file holds no image size: camcal writes it in a comment
(``<!-- camcal image_size W H -->``) that :func:`load` reads.

References
----------
Lensfun, libs/lensfun/lens.cpp (``GetDistortionModelDesc``), modifier.cpp
(the coordinate systems, ``lfModifier::lfModifier``), database.cpp (the
elements read), https://lensfun.github.io/manual/latest/ (database format).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ElementTree
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    ExportResult,
    ImportResult,
    LensConversion,
    Refit,
    projection_figures,
    refit_projection,
    select_cameras,
)
from camcal.io.lensfun_tca import TCAState, add_tca, check_tca
from camcal.io.lensfun_units import lensfun_aspect, lensfun_centre_px, lensfun_number, lensfun_unit_px
from camcal.io.lensfun_vignetting import VignettingState, add_vignetting, check_vignetting
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

__all__ = ["DEFAULT_SENSOR_WIDTH_MM", "MODEL_TERMS", "LensfunLens", "camera_of", "crop_factor", "export",
           "export_states", "fit_lens", "load", "radius_ratio"]

#: Sensor width of cameras without ``sensor_width_mm``.
DEFAULT_SENSOR_WIDTH_MM = 36.0
#: Full frame's diagonal in mm, the crop factor's reference.
_FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: A model with more terms is written only when its RMS residual is smaller by more than this (px).
_SIMPLER_WITHIN_PX = 0.01
#: Lensfun's ``<type>`` camcal reads: the pinhole and the equidistant fisheye.
_LENS_TYPES = ("rectilinear", "fisheye")
_SIZE_COMMENT = re.compile(r"^\s*camcal image_size\s+(\d+)\s+(\d+)\s*$")


class LensfunLens:
    """One Lensfun distortion entry and the normalisation it lives in.

    Attributes
    ----------
    model : str
        ``poly3``, ``poly5`` or ``ptlens``.
    terms : dict of str to float
        ``k1`` (``k2``; ``a b c``).
    focal_mm : float
        The entry's ``focal`` (the lens state's nominal focal length).
    crop : float
    aspect : float
        ``(max(W, H) - 1) / (min(W, H) - 1)``.
    center : (float, float)
        The lens centre's offset from the image centre in normalised units.
    real_focal_mm : float, optional
        ``<real-focal-length real-focal>``: the lens' pinhole focal length
        at the centre, ``F d`` with ``d = Rd / Ru`` at ``Ru = 0``
        (Lensfun's default without it: ``focal_mm d``).
    lens_type : str
        ``<type>``: ``rectilinear`` (Lensfun's default) or ``fisheye`` (equidistant).
    """

    def __init__(self, model: str, terms: Mapping[str, float], focal_mm: float, crop: float, aspect: float,
                 center: tuple[float, float], real_focal_mm: float | None = None,
                 lens_type: str = "rectilinear") -> None:
        self.model, self.terms, self.focal_mm = model, dict(terms), float(focal_mm)
        self.crop, self.aspect, self.center = float(crop), float(aspect), (float(center[0]), float(center[1]))
        self.real_focal_mm = real_focal_mm
        self.lens_type = lens_type

    def centre_scale(self) -> float:
        """``d = Rd / Ru`` at the centre (``1 - k1``, ``1``, ``1 - a - b - c``)."""
        return float(radius_ratio(self.model, [self.terms.get(t, 0.0) for t in MODEL_TERMS[self.model]],
                                  np.zeros(1))[0])

    def undistorted_focal_px(self, image_size: tuple[int, int]) -> float:
        """``F``: the undistorted image's focal length in pixels at ``image_size`` (modifier.cpp's units)."""
        undistorted_mm = self.focal_mm if self.real_focal_mm is None else self.real_focal_mm / self.centre_scale()
        return undistorted_mm * lensfun_unit_px(image_size) / self.unit_mm()

    def unit_mm(self) -> float:
        """Lensfun's ``NormalizedInMillimeters``: the normalised unit in mm."""
        return _FULL_FRAME_DIAGONAL_MM / 2.0 / math.sqrt(self.aspect**2 + 1.0) / self.crop


def _aspect(image_size: tuple[int, int]) -> float:
    if min(image_size) < 2:
        raise CamcalError(f"a Lensfun lens needs an image of at least 2x2 pixels, got {image_size}")
    return lensfun_aspect(image_size)


def crop_factor(camera: Camera, sensor_width_mm: float | None = None) -> float:
    """Full frame's diagonal over the sensor's (``sensor_width_mm`` or the camera's, else 36 mm wide)."""
    width_mm = sensor_width_mm or camera.sensor_width_mm or DEFAULT_SENSOR_WIDTH_MM
    width, height = camera.image_size
    return _FULL_FRAME_DIAGONAL_MM / (width_mm * math.hypot(width, height) / width)


#: Lensfun's distortion models and their terms, in the order a simpler one is preferred.
MODEL_TERMS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "poly3": ("k1",),
    "poly5": ("k1", "k2"),
    "ptlens": ("a", "b", "c"),
})


def radius_ratio(model: str, terms: Sequence[float], ru: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lensfun's ``Rd / Ru`` at the undistorted normalised radius ``ru`` (lens.cpp's model descriptions)."""
    if model == "poly3":
        [k1] = terms
        return 1.0 - k1 + k1 * ru**2
    if model == "poly5":
        k1, k2 = terms
        return 1.0 + k1 * ru**2 + k2 * ru**4
    a, b, c = terms
    return a * ru**3 + b * ru**2 + c * ru + 1.0 - a - b - c


#: A rectilinear lens images the rays at least this far (radians) in front of its image plane; the others are not
#: imaged (counted as lost), instead of residuals of 1e16 pixels near 90 degrees.
_MIN_ELEVATION_RAD = math.radians(3.0)


def _projector(model: str, centre: NDArray[np.float64], unit: float, fisheye: bool = False
               ) -> Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]:
    """``project(vector, rays)``: distorted pixels of a Lensfun lens, ``vector`` its undistorted focal ``F``
    (pixels) and terms, about the lens centre ``centre`` (pixels), ``unit`` pixels to the normalised unit;
    ``fisheye``: the equidistant undistorted image (``F theta``), else the pinhole one (``F tan theta``, NaN
    for rays within 3 degrees of the image plane or behind it)."""
    def project(vector: NDArray[np.float64], rays: NDArray[np.float64]) -> NDArray[np.float64]:
        rho = np.hypot(rays[:, 0], rays[:, 1])
        depth = rays[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if fisheye:
                scale = np.where(rho > 0.0, np.arctan2(rho, depth) / rho, 1.0 / np.where(depth > 0, depth, np.nan))
            else:
                scale = np.where(depth > np.sin(_MIN_ELEVATION_RAD) * np.hypot(rho, depth), 1.0 / depth, np.nan)
            offset = vector[0] * rays[:, :2] * scale[:, None]
        ratio = radius_ratio(model, vector[1:], np.linalg.norm(offset, axis=1) / unit)
        return centre + offset * ratio[:, None]

    return project


def _exact_lens(camera: Camera, model: str, crop: float) -> LensfunLens | None:
    """The Lensfun lens of ``model`` that is ``camera``'s polynomial lens exactly, or None when there is none.

    Square pixels, no skew and ``x_d = x_u (1 + k1 r^2 + k2 r^4)``: ``poly5``
    with ``F = f``, ``k1' = k1 s^2 / f^2``, ``k2' = k2 s^4 / f^4``; ``poly3``
    (``k2 = 0``) with ``k1' / (1 - k1')^3 = k1 s^2 / f^2`` and
    ``F = f / (1 - k1')`` (increasing in ``k1' > -1/2``, where it is ``-4/27``).
    """
    K, lens = camera.K, camera.distortion
    params = lens.params
    higher = ("k3", "k4") if lens.is_fisheye else ("k3",)
    if (lens.has_correction or lens.model not in ("none", "polynomial", "kannala-brandt") or K[0, 0] != K[1, 1]
            or K[0, 1] != 0.0 or model == "ptlens" or any(params.get(name, 0.0) != 0.0 for name in higher)
            or (model == "poly3" and params.get("k2", 0.0))):
        return None
    focal, unit = K[0, 0], lensfun_unit_px(camera.image_size)
    k1, k2 = params.get("k1", 0.0) * unit**2 / focal**2, params.get("k2", 0.0) * unit**4 / focal**4
    if model == "poly5":
        terms, undistorted_focal = {"k1": k1, "k2": k2}, focal
    else:
        if k1 <= -4.0 / 27.0:
            return None
        k1 = 0.0 if k1 == 0.0 else scipy.optimize.brentq(lambda t: t / (1.0 - t) ** 3 - k1, -0.5, 1.0 - 1e-12,
                                                         xtol=1e-15, rtol=1e-15)
        terms, undistorted_focal = {"k1": k1}, focal / (1.0 - k1)
    return _lens(camera, model, terms, undistorted_focal, crop)


def _lens(camera: Camera, model: str, terms: Mapping[str, float], undistorted_focal: float, crop: float,
          nominal_mm: float | None = None, centre_px: NDArray[np.float64] | None = None) -> LensfunLens:
    """A Lensfun entry about ``centre_px`` (default the principal point) with undistorted focal
    ``undistorted_focal`` pixels, keyed by ``nominal_mm`` (default the camera's focal length in mm); a fisheye
    camera's is Lensfun's equidistant fisheye type."""
    width, height = camera.image_size
    unit = lensfun_unit_px(camera.image_size)
    centre_px = camera.K[:2, 2] if centre_px is None else centre_px
    centre = (centre_px[0] - (width - 1) / 2.0) / unit, (centre_px[1] - (height - 1) / 2.0) / unit
    lens = LensfunLens(model, terms, 0.0, crop, _aspect(camera.image_size), centre,
                       lens_type="fisheye" if camera.distortion.is_fisheye else "rectilinear")
    lens.focal_mm = math.sqrt(camera.K[0, 0] * camera.K[1, 1]) * lens.unit_mm() / unit if nominal_mm is None \
        else nominal_mm
    lens.real_focal_mm = undistorted_focal * lens.unit_mm() / unit * lens.centre_scale()
    return lens


def fit_lens(camera: Camera, model: str, crop: float, *, nominal_mm: float | None = None,
             centre_px: NDArray[np.float64] | None = None) -> tuple[LensfunLens, Refit]:
    """``camera``'s lens in a Lensfun model: exact where the model holds it, else refitted (a fisheye camera
    in Lensfun's equidistant fisheye type).

    The refit (:func:`camcal.io.conversion.refit_projection`, the core of
    :func:`~camcal.io.conversion.refit_camera`) fits the undistorted focal
    length ``F`` and the model's terms about ``centre_px`` (default the
    principal point; Lensfun holds one lens centre); non-square pixels and
    skew, which Lensfun has not, are part of the residual. ``nominal_mm``
    is the entry's ``focal`` (default the camera's focal length in mm).
    """
    unit = lensfun_unit_px(camera.image_size)
    centre = np.array(camera.K[:2, 2] if centre_px is None else centre_px, dtype=np.float64)
    project = _projector(model, centre, unit, camera.distortion.is_fisheye)
    exact = _exact_lens(camera, model, crop) if np.array_equal(centre, camera.K[:2, 2]) else None
    if exact is not None:
        vector = np.array([exact.undistorted_focal_px(camera.image_size), *exact.terms.values()])
        refit = projection_figures(camera, lambda rays: project(vector, rays), model)
        lens = _lens(camera, model, exact.terms, vector[0], crop, nominal_mm)
        return lens, replace(refit, exact=True)
    start = [math.sqrt(camera.K[0, 0] * camera.K[1, 1]), *[0.0] * len(MODEL_TERMS[model])]
    vector, refit = refit_projection(camera, model, project, start)
    terms = dict(zip(MODEL_TERMS[model], (float(v) for v in vector[1:])))
    return _lens(camera, model, terms, vector[0], crop, nominal_mm, centre), refit


def _best_fit(camera: Camera, crop: float, nominal_mm: float | None = None,
              centre_px: NDArray[np.float64] | None = None) -> tuple[LensfunLens, Refit, dict[str, Refit]]:
    """The simplest Lensfun model within 0.01 px RMS of the best one, and every model's refit."""
    fitted = {model: fit_lens(camera, model, crop, nominal_mm=nominal_mm, centre_px=centre_px)
              for model in MODEL_TERMS}
    best = min(refit.rms_px for _, refit in fitted.values())
    model = next(name for name, (_, refit) in fitted.items() if refit.rms_px <= best + _SIMPLER_WITHIN_PX)
    return fitted[model][0], fitted[model][1], {name: refit for name, (_, refit) in fitted.items()}


def camera_of(lens: LensfunLens, image_size: tuple[int, int], name: str) -> Camera:
    """The camcal camera a Lensfun entry describes at ``image_size`` (exact): a ``polynomial`` lens, or for
    Lensfun's fisheye type a ``kannala-brandt`` one (``k3 = k4 = 0``).

    ``ptlens`` needs ``a = c = 0`` (it is then ``poly3`` with ``k1 = b``).
    """
    unit = lensfun_unit_px(image_size)
    undistorted_focal = lens.undistorted_focal_px(image_size)
    terms = lens.terms
    if lens.model == "ptlens":
        if terms.get("a", 0.0) or terms.get("c", 0.0):
            raise CamcalError(f"lens {name!r}: a ptlens lens with a or c non-zero has no camcal model "
                              "(odd powers of the radius)")
        terms = {"k1": terms.get("b", 0.0)}
    k1 = terms.get("k1", 0.0)
    if lens.model == "poly5":
        focal, params = undistorted_focal, {"k1": k1 * undistorted_focal**2 / unit**2,
                                            "k2": terms.get("k2", 0.0) * undistorted_focal**4 / unit**4, "k3": 0.0}
    else:
        focal = undistorted_focal * (1.0 - k1)
        params = {"k1": k1 * undistorted_focal**2 / (unit**2 * (1.0 - k1)), "k2": 0.0, "k3": 0.0}
    width, height = image_size
    cx, cy = lensfun_centre_px(lens.center, image_size)
    K = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
    sensor_width_mm = _FULL_FRAME_DIAGONAL_MM / lens.crop * width / math.hypot(width, height)
    distortion = Distortion("kannala-brandt", {**params, "k3": 0.0, "k4": 0.0}) if lens.lens_type == "fisheye" \
        else Distortion("polynomial", params)
    return Camera(name, image_size, K, distortion, np.eye(3), np.zeros(3), sensor_width_mm=sensor_width_mm)


def _lens_element(root: ElementTree.Element, name: str, maker: str, mount: str,
                  lenses: Sequence[LensfunLens]) -> ElementTree.Element:
    """One ``<lens>`` (the first lens' centre, crop and aspect ratio, every distortion entry); its calibration."""
    entry = ElementTree.SubElement(root, "lens")
    for tag, text in (("maker", maker), ("model", name), ("mount", mount)):
        ElementTree.SubElement(entry, tag).text = text
    first = lenses[0]
    if first.lens_type != "rectilinear":
        ElementTree.SubElement(entry, "type").text = first.lens_type
    if first.center != (0.0, 0.0):
        ElementTree.SubElement(entry, "center", x=lensfun_number(first.center[0]), y=lensfun_number(first.center[1]))
    ElementTree.SubElement(entry, "cropfactor").text = lensfun_number(first.crop)
    ElementTree.SubElement(entry, "aspect-ratio").text = lensfun_number(first.aspect)
    calibration = ElementTree.SubElement(entry, "calibration")
    for lens in lenses:
        ElementTree.SubElement(calibration, "distortion", model=lens.model, focal=lensfun_number(lens.focal_mm),
                               **{term: lensfun_number(value) for term, value in lens.terms.items()})
    for lens in lenses:
        ElementTree.SubElement(calibration, "real-focal-length", focal=lensfun_number(lens.focal_mm),
                               **{"real-focal": lensfun_number(lens.real_focal_mm)})
    return calibration


def _conversion(camera: Camera, lens: LensfunLens, refit: Refit, refits: Mapping[str, Refit],
                state: str = "") -> tuple[LensConversion, str]:
    source = f"{camera.distortion.model}{' with skew' if camera.K[0, 1] else ''}"
    note = (f"camera {camera.name!r}{state}: RMS residual inside the image " + ", ".join(
        f"{name} {'exact' if fit.exact else f'{fit.rms_px:.3g} px'}" for name, fit in refits.items())
        + f"; {lens.model} written")
    return LensConversion(camera.name, source, f"Lensfun {lens.model}", refit.exact, refit.max_px, "refit",
                          refit), note


def _write(root: ElementTree.Element, out: Path, image_size: tuple[int, int]) -> None:
    root.append(ElementTree.Comment(f" camcal image_size {image_size[0]} {image_size[1]} "))
    ElementTree.indent(root)
    atomic_write_text(out, '<?xml version="1.0" encoding="utf-8"?>\n' + ElementTree.tostring(root, "unicode") + "\n")


def _check_out(out: Path) -> None:
    if out.suffix.lower() != ".xml":
        raise CamcalError(f"a Lensfun database file must end in .xml, got {out.name!r}")


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None,
           maker: str = "camcal", mount: str = "Generic", sensor_width_mm: float | None = None) -> ExportResult:
    """Write each camera's lens as a Lensfun ``<lens>`` entry at its focal length (see the module docstring).

    Parameters
    ----------
    rig : Rig
    out : Path
        The ``.xml`` file.
    cameras : sequence of str, optional
    rig_path : Path, optional
        Unused (a Lensfun file holds no points).
    maker, mount : str
        The entries' ``<maker>`` and ``<mount>`` (``<model>`` is the camera's name).
    sensor_width_mm : float, optional
        Sensor width for the crop factor, instead of the cameras'.

    Returns
    -------
    ExportResult
        One conversion per camera with the written model's residual (max
        and RMS inside the image and over the overscan border); the notes
        give every model's RMS.
    """
    _check_out(out)
    chosen = select_cameras(rig, cameras)
    sizes = {camera.image_size for camera in chosen}
    if len(sizes) != 1:
        raise CamcalError("a Lensfun file from camcal holds cameras of one image size; export them one by one "
                          f"(--camera): sizes {sorted(sizes)}")
    root = ElementTree.Element("lensdatabase", version="1")
    conversions, notes = [], []
    for camera in chosen:
        lens, refit, refits = _best_fit(camera, crop_factor(camera, sensor_width_mm))
        _lens_element(root, camera.name, maker, mount, [lens])
        conversion, note = _conversion(camera, lens, refit, refits)
        conversions.append(conversion)
        notes.append(note)
    _write(root, out, sizes.pop())
    notes.append("a Lensfun lens holds no pose: the cameras' positions and orientations are not written")
    return ExportResult((out,), tuple(conversions), tuple(notes))


def export_states(states: Sequence[tuple[float, Camera]], out: Path, *, name: str, maker: str = "camcal",
                  mount: str = "Generic", sensor_width_mm: float | None = None,
                  vignetting: Sequence[VignettingState] = (), tca: Sequence[TCAState] = ()) -> ExportResult:
    """Write one lens at several focal lengths (a zoom's states) as one Lensfun ``<lens>``.

    Parameters
    ----------
    states : sequence of (float, Camera)
        Each state's nominal focal length in mm (the entries' ``focal``,
        which Lensfun interpolates between) and the camera calibrated at
        it; one image size.
    out : Path
    name : str
        The lens' ``<model>``.
    maker, mount : str
    sensor_width_mm : float, optional
    vignetting, tca : sequence of VignettingState, sequence of TCAState
        Flat fields per lens state, a board's corners per channel per focal length: a ``pa`` vignetting entry
        each, a ``poly3`` TCA entry each (:mod:`camcal.io.lensfun_vignetting`, :mod:`camcal.io.lensfun_tca`).

    Returns
    -------
    ExportResult
        One conversion per state. Lensfun holds one distortion model and one
        lens centre per lens: the simplest model within 0.01 px of the best
        worst-state RMS, about the states' mean principal point (its drift
        is part of the residual). A note per vignetting and TCA entry: what
        it misses.
    """
    _check_out(out)
    focals = [focal for focal, _ in states]
    if not states or len(set(focals)) != len(focals) or not all(math.isfinite(f) and f > 0 for f in focals):
        raise CamcalError(f"a Lensfun lens needs states of distinct positive focal lengths, got {focals}")
    sizes = {camera.image_size for _, camera in states}
    if len(sizes) != 1:
        raise CamcalError(f"the lens states have different image sizes: {sorted(sizes)}")
    size = sizes.pop()
    check_vignetting(vignetting, _aspect(size))
    check_tca(tca, size)
    centre = np.mean([camera.K[:2, 2] for _, camera in states], axis=0)
    states = sorted(states, key=lambda state: state[0])
    fitted = [{model: fit_lens(camera, model, crop_factor(camera, sensor_width_mm), nominal_mm=focal, centre_px=centre)
               for model in MODEL_TERMS} for focal, camera in states]
    # Lensfun reads one distortion model per lens (lfLens::InterpolateDistortion): the simplest within 0.01 px of
    # the best worst-state RMS
    worst = {model: max(state[model][1].rms_px for state in fitted) for model in MODEL_TERMS}
    model = next(name for name in MODEL_TERMS if worst[name] <= min(worst.values()) + _SIMPLER_WITHIN_PX)
    lenses, conversions, notes = [], [], []
    for (focal, camera), state in zip(states, fitted):
        lens, refit = state[model]
        lenses.append(lens)
        conversion, note = _conversion(camera, lens, refit, {name: fit for name, (_, fit) in state.items()},
                                       f" at {focal:g} mm")
        conversions.append(conversion)
        notes.append(note)
    root = ElementTree.Element("lensdatabase", version="1")
    calibration = _lens_element(root, name, maker, mount, lenses)
    notes += add_vignetting(calibration, vignetting, lenses[0].center)
    notes += add_tca(calibration, tca, lenses[0].center, size)
    _write(root, out, size)
    return ExportResult((out,), tuple(conversions), tuple(notes))


def _float(element: ElementTree.Element, name: str, what: str) -> float:
    text = element.get(name) if name in element.attrib else element.text
    try:
        value = float(text if text is not None else "")
    except ValueError:
        raise CamcalError(f"{what} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise CamcalError(f"{what} is not finite")
    return value


def load(path: Path, *, image_size: tuple[int, int] | None = None, focal_mm: float | None = None) -> ImportResult:
    """Read a Lensfun database file's lenses as cameras (one per ``<lens>``, at one focal length).

    Parameters
    ----------
    path : Path
    image_size : (int, int), optional
        Default: the size camcal wrote in the file's comment.
    focal_mm : float, optional
        The ``<distortion>`` entry of this ``focal`` (default: the lens'
        only one).

    Raises
    ------
    CamcalError
        Not a Lensfun file, no image size, no distortion entry at the
        focal length (or several and none chosen), an unknown model, or a
        ``ptlens`` lens with odd terms.
    """
    check_file_size(path, FILE_BYTES, "Lensfun file")
    try:
        root = ElementTree.fromstring(path.read_text(errors="replace"))  # the comments are dropped
        comments = re.findall(r"<!--(.*?)-->", path.read_text(errors="replace"), flags=re.S)
    except ElementTree.ParseError as error:
        raise CamcalError(f"not XML: {error}") from None
    if root.tag != "lensdatabase":
        raise CamcalError(f"not a Lensfun database: its root element is <{root.tag}>, not <lensdatabase>")
    for comment in comments:
        match = _SIZE_COMMENT.match(comment)
        if match and image_size is None:
            image_size = (int(match.group(1)), int(match.group(2)))
    if image_size is None:
        raise CamcalError("the Lensfun file holds no image size (Lensfun lenses have none): give it")
    cameras, conversions = [], []
    for entry in root.findall("lens"):
        name = (entry.findtext("model") or "lens").strip()
        crop_element, aspect_element = entry.find("cropfactor"), entry.find("aspect-ratio")
        if crop_element is None:
            raise CamcalError(f"lens {name!r} has no <cropfactor>")
        crop = _float(crop_element, "", f"lens {name!r}: <cropfactor>")
        aspect = 1.5  # Lensfun's default
        if aspect_element is not None:
            text = (aspect_element.text or "").strip()
            numerator, _, denominator = text.partition(":")
            try:
                aspect = float(numerator) / float(denominator or 1.0)
            except (ValueError, ZeroDivisionError):
                raise CamcalError(f"lens {name!r}: <aspect-ratio> must be a number or W:H, got {text!r}") from None
        if not (crop > 0.0 and math.isfinite(aspect) and aspect >= 1.0):
            raise CamcalError(f"lens {name!r}: the crop factor must be > 0 and the aspect ratio >= 1, got {crop:g} "
                              f"and {aspect:g}")
        center_element = entry.find("center")
        center = (0.0, 0.0) if center_element is None else (
            _float(center_element, "x", f"lens {name!r}: <center x>"),
            _float(center_element, "y", f"lens {name!r}: <center y>"))
        entries = entry.findall("calibration/distortion")
        if focal_mm is not None:
            entries = [e for e in entries if _float(e, "focal", f"lens {name!r}: focal") == focal_mm]
        if len(entries) != 1:
            at = f" at {focal_mm:g} mm" if focal_mm is not None else ""
            raise CamcalError(f"lens {name!r} has {len(entries)} distortion entries{at}; camcal reads a lens at "
                              "one focal length")
        [distortion] = entries
        model = distortion.get("model")
        if model not in MODEL_TERMS:
            raise CamcalError(f"lens {name!r}: unknown distortion model {model!r}, expected one of: "
                              + ", ".join(MODEL_TERMS))
        terms = {term: _float(distortion, term, f"lens {name!r}: {term}") if term in distortion.attrib else 0.0
                 for term in MODEL_TERMS[model]}
        focal = _float(distortion, "focal", f"lens {name!r}: focal")
        real = [_float(e, "real-focal", f"lens {name!r}: real-focal") for e in entry.findall(
            "calibration/real-focal-length") if _float(e, "focal", f"lens {name!r}: focal") == focal]
        lens_type = (entry.findtext("type") or "rectilinear").strip()
        if lens_type not in _LENS_TYPES:
            raise CamcalError(f"lens {name!r}: camcal reads Lensfun's {' and '.join(_LENS_TYPES)} lenses, not "
                              f"{lens_type!r}")
        lens = LensfunLens(model, terms, focal, crop, aspect, center, real[0] if real else None, lens_type)
        if focal <= 0.0 or lens.centre_scale() <= 0.0 or (real and real[0] <= 0.0):
            raise CamcalError(f"lens {name!r}: a {model} lens needs focal lengths > 0 and Rd / Ru > 0 at the centre, "
                              f"got focal {focal:g}, Rd / Ru {lens.centre_scale():g}")
        camera = camera_of(lens, image_size, name)
        cameras.append(camera)
        conversions.append(LensConversion(name, f"Lensfun {model}", camera.distortion.model, True))
    if not cameras:
        raise CamcalError("the Lensfun file holds no <lens>")
    return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions),
                        ("a Lensfun lens holds no pose: the cameras are at the origin",))
