"""3DEqualizer's standard lens distortion models, as the Lens Distortion Plugin Kit (LDPK) defines them.

The four models every 3DE-aware tool carries (3DEqualizer, Nuke's
LensDistortion presets and the LDPK nodes, Flame, Unreal, SynthEyes,
PFTrack), written from the LDPK's documentation:

================================ ==========================================
camcal model                     LDPK model name
================================ ==========================================
``3de-classic``                  "3DE Classic LD Model"
``3de4-radial-deg4``             "3DE4 Radial - Standard, Degree 4"
``3de4-anamorphic-deg4``         "3DE4 Anamorphic - Standard, Degree 4"
``3de4-fisheye-deg8``            "3DE4 Radial - Fisheye, Degree 8"
================================ ==========================================

Conventions (LDPK's own)
------------------------
- The coefficients map DISTORTED to UNDISTORTED points (camcal's models map
  the other way): LDPK's ``undistort`` is the closed-form model function
  :func:`undistort_dn`, its ``distort`` the inverse :func:`distort_dn`
  (Newton iterations with the analytic Jacobian, to 1e-14 in normalised
  units, NaN where they find no root on the lens's side of its fold).
- Points are in "diagonally normalised" coordinates (``dn``): centred on
  the lens centre, divided by the film back's half-diagonal
  ``r_fb = sqrt(w_fb^2 + h_fb^2) / 2``, y UP (3DE's and Nuke's unit
  coordinates have their origin at the lower-left corner). From LDPK unit
  coordinates ``p_unit`` in ``[0, 1]^2`` over the image::

      x_dn = ((x_unit - 1/2) w_fb - x_lco) / r_fb
      y_dn = ((y_unit - 1/2) h_fb - y_lco) / r_fb

  with the film back ``w_fb x h_fb`` and the lens-centre offset
  ``(x_lco, y_lco)`` in cm.

How LDPK's built-in camera maps onto camcal's ``K`` and image size
------------------------------------------------------------------
A 3DE lens is defined on its film back, so a camcal lens of these models
carries the film back in pixels (params ``filmback_width_px``,
``filmback_height_px``: the image the coefficients are normalised on, the
camera's ``image_size``). With camcal's pixels (``(0, 0)`` the centre of
the top-left pixel, y down) in an image of ``W x H`` pixels,
``x_unit = (u + 1/2) / W`` and ``y_unit = 1 - (v + 1/2) / H`` (Nuke's pixel
centres ``(i + 1/2) / W``), and a pinhole ``K`` with ``fx = fl W / w_fb``,
``fy = fl H / h_fb``:

- pixel aspect ``pa = fy / fx`` (3DE's pixel aspect: a pixel's width over
  its height on the film back, 2 for a 2x anamorphic squeeze);
- lens centre = principal point: ``x_lco = (cx - (W - 1) / 2) w_fb / W``,
  ``y_lco = -(cy - (H - 1) / 2) h_fb / H`` (principal point minus image
  centre, y flipped);
- ``dn = (x_n / R, -y_n / R)`` with ``x_n = K^-1 u`` camcal's normalised
  coordinates and ``R = sqrt((W / fx)^2 + (H / fy)^2) / 2`` the film back's
  half-diagonal in normalised units; LDPK's ``fl / r_fb`` (the focal length
  in ``dn`` units, used by the fisheye model) is ``1 / R``.

Only ratios of the cm values enter the mapping, so the film back's
physical width is free (:class:`LdpkCamera` takes it as an argument). LDPK
has no skew; camcal applies a skewed ``K`` through ``K^-1`` as for its other
models, which no LDPK camera reproduces.

The models (LDPK's ``undistort``, ``p`` the distorted and ``q`` the undistorted point, in ``dn``)
-------------------------------------------------------------------------------------------------
``3de-classic``: with ``ld`` Distortion, ``sq`` Anamorphic Squeeze,
``cx, cy`` Curvature X / Y, ``qu`` Quartic Distortion::

    q_x = x (1 + ld/sq x^2 + (ld + cx)/sq y^2 + qu/sq (x^2 + y^2)^2)
    q_y = y (1 + (ld + cy) x^2 + ld y^2 + qu (x^2 + y^2)^2)

``3de4-radial-deg4``: radial and decentring terms, then the cylindric
bending ``C`` (direction ``phi`` in degrees, bending ``b``)::

    r^2 = x^2 + y^2
    s_x = x (1 + c2 r^2 + c4 r^4) + (r^2 + 2 x^2)(u2 + u4 r^2) + 2 x y (v2 + v4 r^2)
    s_y = y (1 + c2 r^2 + c4 r^4) + (r^2 + 2 y^2)(v2 + v4 r^2) + 2 x y (u2 + u4 r^2)
    q = C s,  C = [[c^2 k + s^2 / k, (k - 1/k) c s], [(k - 1/k) c s, c^2 / k + s^2 k]]

with ``c = cos(phi)``, ``s = sin(phi)``, ``k = sqrt(1 + b)``.

``3de4-anamorphic-deg4``: with ``P = diag(pa, 1)``, the lens rotation
``Rot`` (degrees, counter-clockwise with y up), the squeezes
``Sx = diag(squeeze_x, 1)``, ``Sy = diag(1, squeeze_y)``::

    q = Rot Sx Sy P  A((P Rot)^-1 p)
    A_x(x, y) = x (1 + (cx02 + cx22) x^2 + (cx02 - cx22) y^2
                   + (cx04 + cx24 + cx44) x^4 + (2 cx04 - 6 cx44) x^2 y^2 + (cx04 - cx24 + cx44) y^4)

and ``A_y`` alike with the ``cy`` coefficients and ``y`` in front (the
polar form ``sum c_ij cos(i phi) r^j``, expanded).

``3de4-fisheye-deg8``: the distorted image is equisolid-angle
(``r = 2 f sin(theta / 2)``, ``f = 1 / R``), re-projected to the pinhole
("plain") radius ``f tan(theta)``, then the radial polynomial
``q = s (1 + c2 r_s^2 + c4 r_s^4 + c6 r_s^6 + c8 r_s^8)`` on that plain point
``s``. Its undistorted side is a pinhole image (angles below 90 degrees);
LDPK clamps the plain radius at 5 (and the result at 50 or 100) to keep
its images finite, camcal does not (beyond 90 degrees it gives NaN).

References
----------
Science-D-Visions (2016, 2018). Lens Distortion Plugin Kit (LDPK), versions
1.9.2 and 2.0: the model documentation of ``tde4_ldp_classic_3de_mixed``,
``tde4_ldp_radial_decentered_deg_4_cylindric``,
``tde4_ldp_anamorphic_deg_4_rotate_squeeze_xy``, ``tde4_ldp_radial_deg_8``
and ``ldp_builtin`` (built-in parameters, diagonal normalisation).
Sassenberg, U. (2018). The Standard Models for Lens Distortion in 3DE4.
Science-D-Visions, white paper shipped with the LDPK (``doc/tex``).
Science-D-Visions (2018). tde4_ldm_standard: supplementary documentation,
code and examples (LDPK 2.0).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError

__all__ = ["BUILTIN_PARAMETERS", "FILMBACK_KEYS", "LDPK_MODEL_NAMES", "LDPK_PARAMETERS", "TDE4_MODELS", "LdpkCamera",
           "LdpkParameter", "check_filmback", "check_params", "coefficients", "distort_dn", "distort_pixels", "dn_from_pixels",
           "dn_radius", "is_identity", "pixels_from_dn", "undistort_dn", "undistort_pixels"]


class LdpkParameter(NamedTuple):
    """One model parameter: its LDPK name (3DE's GUI, lens files, Nuke knob labels), camcal's key, LDPK's default."""

    ldpk_name: str
    key: str
    default: float


#: camcal model name -> LDPK model name.
LDPK_MODEL_NAMES: Mapping[str, str] = MappingProxyType({
    "3de-classic": "3DE Classic LD Model",
    "3de4-radial-deg4": "3DE4 Radial - Standard, Degree 4",
    "3de4-anamorphic-deg4": "3DE4 Anamorphic - Standard, Degree 4",
    "3de4-fisheye-deg8": "3DE4 Radial - Fisheye, Degree 8",
})
TDE4_MODELS = tuple(LDPK_MODEL_NAMES)

#: The model parameters of each model, in LDPK's order (angles in degrees, as LDPK takes them).
LDPK_PARAMETERS: Mapping[str, tuple[LdpkParameter, ...]] = MappingProxyType({
    "3de-classic": (
        LdpkParameter("Distortion", "distortion", 0.0),
        LdpkParameter("Anamorphic Squeeze", "anamorphic_squeeze", 1.0),
        LdpkParameter("Curvature X", "curvature_x", 0.0),
        LdpkParameter("Curvature Y", "curvature_y", 0.0),
        LdpkParameter("Quartic Distortion", "quartic_distortion", 0.0),
    ),
    "3de4-radial-deg4": (
        LdpkParameter("Distortion - Degree 2", "c2", 0.0),
        LdpkParameter("U - Degree 2", "u2", 0.0),
        LdpkParameter("V - Degree 2", "v2", 0.0),
        LdpkParameter("Quartic Distortion - Degree 4", "c4", 0.0),
        LdpkParameter("U - Degree 4", "u4", 0.0),
        LdpkParameter("V - Degree 4", "v4", 0.0),
        LdpkParameter("Phi - Cylindric Direction", "cylindric_direction_deg", 0.0),
        LdpkParameter("B - Cylindric Bending", "cylindric_bending", 0.0),
    ),
    "3de4-anamorphic-deg4": (
        *(LdpkParameter(f"C{axis}{term} - Degree {term[1]}", f"c{axis}{term}", 0.0)
          for term in ("02", "22", "04", "24", "44") for axis in "xy"),
        LdpkParameter("Lens Rotation", "lens_rotation_deg", 0.0),
        LdpkParameter("Squeeze-X", "squeeze_x", 1.0),
        LdpkParameter("Squeeze-Y", "squeeze_y", 1.0),
    ),
    "3de4-fisheye-deg8": (
        LdpkParameter("Distortion - Degree 2", "c2", 0.0),
        LdpkParameter("Quartic Distortion - Degree 4", "c4", 0.0),
        LdpkParameter("Degree 6", "c6", 0.0),
        LdpkParameter("Degree 8", "c8", 0.0),
    ),
})

#: The film back in pixels every lens of these models carries (the image its coefficients are normalised on).
FILMBACK_KEYS = ("filmback_width_px", "filmback_height_px")

#: LDPK's built-in camera parameters (``ldp_builtin``), as :meth:`LdpkCamera.builtin_parameters` names them.
BUILTIN_PARAMETERS = ("tde4_focal_length_cm", "tde4_filmback_width_cm", "tde4_filmback_height_cm",
                      "tde4_lens_center_offset_x_cm", "tde4_lens_center_offset_y_cm", "tde4_pixel_aspect")

_NEWTON_MAX_ITER = 60
#: Newton stops when the residual is below this (diagonally normalised units, relative to 1 + |target|).
_NEWTON_TOL = 1e-14
#: A root whose residual is still above this after the iterations is no root: NaN.
_ROOT_TOL = 1e-12

Points = NDArray[np.float64]


def _model(model: str) -> tuple[LdpkParameter, ...]:
    if model not in LDPK_PARAMETERS:
        raise CamcalError(f"unknown 3DE model {model!r}, expected one of: {', '.join(TDE4_MODELS)}")
    return LDPK_PARAMETERS[model]


def coefficients(model: str, params: Mapping[str, float]) -> dict[str, float]:
    """Every model parameter of ``model`` (camcal keys), LDPK's default where ``params`` has none."""
    return {p.key: float(params.get(p.key, p.default)) for p in _model(model)}


def check_params(model: str, params: Mapping[str, float]) -> None:
    """Raise :class:`CamcalError` naming the parameter when a lens of ``model`` cannot be evaluated.

    The film back (``filmback_width_px``, ``filmback_height_px``) must be
    positive; squeezes (``anamorphic_squeeze``, ``squeeze_x``,
    ``squeeze_y``) positive; ``cylindric_bending`` above -1 (its matrix
    takes ``sqrt(1 + b)``).
    """
    values = coefficients(model, params)
    for key in FILMBACK_KEYS:
        if key not in params:
            raise CamcalError(f"a {model} lens needs its film back: parameter {key!r} (the image size it is "
                              "normalised on, in pixels)")
        if not params[key] > 0.0:
            raise CamcalError(f"{model} parameter {key!r} must be positive, got {params[key]!r}")
    for key in ("anamorphic_squeeze", "squeeze_x", "squeeze_y"):
        if key in values and not values[key] > 0.0:
            raise CamcalError(f"{model} parameter {key!r} must be positive, got {values[key]!r}")
    if model == "3de4-radial-deg4" and not values["cylindric_bending"] > -1.0:
        raise CamcalError(f"{model} parameter 'cylindric_bending' must be above -1, got {values['cylindric_bending']!r}")


def check_filmback(model: str, params: Mapping[str, float], image_size: tuple[int, int]) -> None:
    """Raise :class:`CamcalError` unless a lens of ``model`` is normalised on an image of ``image_size`` pixels.

    The coefficients hold only on the film back they were defined on: a
    camera with another image size (a crop, a proxy) needs them
    reparametrised, not copied.
    """
    filmback = tuple(params.get(key) for key in FILMBACK_KEYS)
    if filmback != tuple(float(n) for n in image_size):
        raise CamcalError(f"a {model} lens on a {image_size[0]}x{image_size[1]} image must have that film back "
                          f"(filmback_width_px, filmback_height_px), got {filmback[0]!r} x {filmback[1]!r}")


def is_identity(model: str, params: Mapping[str, float]) -> bool:
    """True when the lens leaves every point where it is (never the fisheye: its image is equisolid).

    The anamorphic model with all coefficients zero and squeezes 1 is the
    identity only without lens rotation (``Rot P Rot^-1 P^-1`` is not the
    identity when ``pa != 1``); the classic model's squeeze only divides
    its coefficients.
    """
    values = coefficients(model, params)
    if model == "3de4-fisheye-deg8":
        return False
    if model == "3de4-anamorphic-deg4":
        return (all(value == 0.0 for key, value in values.items() if key.startswith("c"))
                and values["lens_rotation_deg"] == 0.0 and values["squeeze_x"] == 1.0 and values["squeeze_y"] == 1.0)
    ignored = {"anamorphic_squeeze", "cylindric_direction_deg"}
    return all(value == 0.0 for key, value in values.items() if key not in ignored)


# -- the polynomial pieces -------------------------------------------------------------------


def _even_quartic(xy: Points, ax: tuple[float, ...], ay: tuple[float, ...]) -> Points:
    """``(x E(ax), y E(ay))`` with ``E(a) = 1 + a0 x^2 + a1 y^2 + a2 x^4 + a3 x^2 y^2 + a4 y^4``."""
    x, y = xy[:, 0], xy[:, 1]
    x2, y2 = x * x, y * y

    def even(a: tuple[float, ...]) -> NDArray[np.float64]:
        return 1.0 + x2 * (a[0] + a[2] * x2 + a[3] * y2) + y2 * (a[1] + a[4] * y2)

    return np.stack([x * even(ax), y * even(ay)], axis=1)


def _even_quartic_jacobian(xy: Points, ax: tuple[float, ...], ay: tuple[float, ...]) -> NDArray[np.float64]:
    """d(:func:`_even_quartic`)/d(x, y), shape (N, 2, 2)."""
    x, y = xy[:, 0], xy[:, 1]
    x2, y2 = x * x, y * y
    jac = np.empty((len(xy), 2, 2))
    # d(x E)/dx = E + x dE/dx, dE/dx = 2 x (a0 + 2 a2 x^2 + a3 y^2), dE/dy = 2 y (a1 + a3 x^2 + 2 a4 y^2)
    jac[:, 0, 0] = 1.0 + x2 * (3.0 * ax[0] + 5.0 * ax[2] * x2 + 3.0 * ax[3] * y2) + y2 * (ax[1] + ax[4] * y2)
    jac[:, 0, 1] = 2.0 * x * y * (ax[1] + ax[3] * x2 + 2.0 * ax[4] * y2)
    jac[:, 1, 0] = 2.0 * x * y * (ay[0] + 2.0 * ay[2] * x2 + ay[3] * y2)
    jac[:, 1, 1] = 1.0 + x2 * (ay[0] + ay[2] * x2 + 3.0 * ay[3] * y2) + y2 * (3.0 * ay[1] + 5.0 * ay[4] * y2)
    return jac


def _classic_terms(c: Mapping[str, float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The classic model as :func:`_even_quartic` coefficients (x terms divided by the squeeze)."""
    ld, sq, cx, cy, qu = (c["distortion"], c["anamorphic_squeeze"], c["curvature_x"], c["curvature_y"],
                          c["quartic_distortion"])
    return (ld / sq, (ld + cx) / sq, qu / sq, 2.0 * qu / sq, qu / sq), (ld + cy, ld, qu, 2.0 * qu, qu)


def _anamorphic_terms(c: Mapping[str, float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The polar degree-4 polynomial ``sum c_ij cos(i phi) r^j`` expanded in ``x^2, y^2`` (per axis)."""

    def expanded(axis: str) -> tuple[float, ...]:
        c02, c22, c04, c24, c44 = (c[f"c{axis}{term}"] for term in ("02", "22", "04", "24", "44"))
        return c02 + c22, c02 - c22, c04 + c24 + c44, 2.0 * c04 - 6.0 * c44, c04 - c24 + c44

    return expanded("x"), expanded("y")


def _radial_decentred(xy: Points, c: Mapping[str, float]) -> Points:
    """The radial-decentred degree-4 polynomial of ``3de4-radial-deg4`` (before the cylindric bending)."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (c["c2"] + c["c4"] * r2)
    u = c["u2"] + c["u4"] * r2
    v = c["v2"] + c["v4"] * r2
    return np.stack([x * radial + (r2 + 2.0 * x * x) * u + 2.0 * x * y * v,
                     y * radial + (r2 + 2.0 * y * y) * v + 2.0 * x * y * u], axis=1)


def _radial_decentred_jacobian(xy: Points, c: Mapping[str, float]) -> NDArray[np.float64]:
    """d(:func:`_radial_decentred`)/d(x, y), shape (N, 2, 2); ``d(r^2)/dx = 2 x``."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (c["c2"] + c["c4"] * r2)
    radial_r2 = c["c2"] + 2.0 * c["c4"] * r2
    u = c["u2"] + c["u4"] * r2
    v = c["v2"] + c["v4"] * r2
    ax, ay = r2 + 2.0 * x * x, r2 + 2.0 * y * y
    jac = np.empty((len(xy), 2, 2))
    jac[:, 0, 0] = radial + 2.0 * x * x * radial_r2 + 6.0 * x * u + 2.0 * x * ax * c["u4"] + 2.0 * y * v \
        + 4.0 * x * x * y * c["v4"]
    jac[:, 0, 1] = 2.0 * x * y * radial_r2 + 2.0 * y * u + 2.0 * y * ax * c["u4"] + 2.0 * x * v \
        + 4.0 * x * y * y * c["v4"]
    jac[:, 1, 0] = 2.0 * x * y * radial_r2 + 2.0 * x * v + 2.0 * x * ay * c["v4"] + 2.0 * y * u \
        + 4.0 * x * x * y * c["u4"]
    jac[:, 1, 1] = radial + 2.0 * y * y * radial_r2 + 6.0 * y * v + 2.0 * y * ay * c["v4"] + 2.0 * x * u \
        + 4.0 * x * y * y * c["u4"]
    return jac


def _cylindric_matrix(c: Mapping[str, float]) -> NDArray[np.float64]:
    """The cylindric bending: stretch ``sqrt(1 + b)`` along ``phi``, ``1 / sqrt(1 + b)`` across (determinant 1)."""
    k = math.sqrt(1.0 + c["cylindric_bending"])
    phi = math.radians(c["cylindric_direction_deg"])
    cos, sin = math.cos(phi), math.sin(phi)
    off = (k - 1.0 / k) * cos * sin
    return np.array([[cos * cos * k + sin * sin / k, off], [off, cos * cos / k + sin * sin * k]])


def _radial_even(xy: Points, terms: tuple[float, ...]) -> Points:
    """``p (1 + c2 r^2 + c4 r^4 + c6 r^6 + c8 r^8)`` (the fisheye model's polynomial)."""
    r2 = np.sum(xy * xy, axis=1)
    series = np.zeros_like(r2)
    for term in reversed(terms):
        series = r2 * (term + series)
    return xy * (1.0 + series)[:, None]


def _radial_even_jacobian(xy: Points, terms: tuple[float, ...]) -> NDArray[np.float64]:
    """``g I + 2 g' p p^T`` with ``g = 1 + sum c_2n r^2n`` and ``g' = dg / d(r^2)``."""
    r2 = np.sum(xy * xy, axis=1)
    series = np.zeros_like(r2)
    slope = np.zeros_like(r2)
    for n, term in reversed(list(enumerate(terms, start=1))):
        series = r2 * (term + series)
        slope = n * term + r2 * slope
    jac = 2.0 * slope[:, None, None] * xy[:, :, None] * xy[:, None, :]
    jac[:, 0, 0] += 1.0 + series
    jac[:, 1, 1] += 1.0 + series
    return jac


def _largest(points: Points) -> NDArray[np.float64]:
    """``max(|x|, |y|)`` per point (NaN stays NaN)."""
    return np.maximum(np.abs(points[:, 0]), np.abs(points[:, 1]))


def _newton(function: Callable[[Points], Points], jacobian: Callable[[Points], NDArray[np.float64]],
            target: Points) -> Points:
    """Solve ``function(p) = target`` per point by Newton iterations from ``p = target``.

    Stops per point at a residual below ``1e-14 (1 + |target|)``; a point
    whose residual stays above 1e-12, whose Jacobian turns singular, or
    whose root is not on the lens's own side of its fold gives NaN: the
    Jacobian there must have eigenvalues of positive real part (positive
    determinant and trace, as at the centre where it is about ``I``), which
    rejects the roots past the fold, where the mapping turns back or points
    land on the opposite side of the centre.
    """
    estimate = target.copy()
    index = np.arange(len(target))  # the points still iterating; all of them while most are
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for _ in range(_NEWTON_MAX_ITER):
            current, goal = (estimate, target) if len(index) == len(target) else (estimate[index], target[index])
            residual = function(current) - goal
            moving = _largest(residual) > _NEWTON_TOL * (1.0 + _largest(goal))  # NaN: not moving (lost)
            if not moving.any():
                break
            if 2 * np.count_nonzero(moving) < len(index):  # gather the few still moving
                index, current, residual = index[moving], current[moving], residual[moving]
            jac = jacobian(current)
            det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
            # the 2x2 inverse written out: step = J^-1 residual
            current = current - np.stack([jac[:, 1, 1] * residual[:, 0] - jac[:, 0, 1] * residual[:, 1],
                                          jac[:, 0, 0] * residual[:, 1] - jac[:, 1, 0] * residual[:, 0]],
                                         axis=1) / det[:, None]
            if len(index) == len(target):
                estimate = current
            else:
                estimate[index] = current
        final = _largest(function(estimate) - target)
        jac = jacobian(estimate)
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    estimate[~((final <= _ROOT_TOL) & (det > 0.0) & (jac[:, 0, 0] + jac[:, 1, 1] > 0.0))] = np.nan
    return estimate


# -- the models in diagonally normalised coordinates --------------------------------------------------


def _apply(matrix: NDArray[np.float64], points: Points) -> Points:
    """``matrix @ p`` for each row ``p`` (written out: numpy's matmul of (N, 2) by a 2x2 is slow)."""
    x, y = points[:, 0], points[:, 1]
    return np.stack([matrix[0, 0] * x + matrix[0, 1] * y, matrix[1, 0] * x + matrix[1, 1] * y], axis=1)


def _rotation(degrees: float) -> NDArray[np.float64]:
    phi = math.radians(degrees)
    return np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])


def _anamorphic_frames(c: Mapping[str, float], pixel_aspect: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(M, N)``: the model is ``q = M A(N^-1 p)`` with ``M = Rot Sx Sy P`` and ``N = P Rot``."""
    rotation = _rotation(c["lens_rotation_deg"])
    aspect = np.diag([pixel_aspect, 1.0])
    after = rotation @ np.diag([c["squeeze_x"], c["squeeze_y"]]) @ aspect
    return after, aspect @ rotation


def _plain_from_equisolid(p: Points, focal_dn: float) -> Points:
    """Equisolid-angle radius ``2 f sin(theta / 2)`` -> pinhole radius ``f tan(theta)``; NaN from 90 degrees on."""
    radius = np.hypot(p[:, 0], p[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        theta = 2.0 * np.arcsin(radius / (2.0 * focal_dn))
        scale = np.where(radius > 0.0, focal_dn * np.tan(theta) / radius, 1.0)
    scale[~(theta < 0.5 * np.pi)] = np.nan
    return p * scale[:, None]


def _equisolid_from_plain(p: Points, focal_dn: float) -> Points:
    """Pinhole radius ``f tan(theta)`` -> equisolid-angle radius ``2 f sin(theta / 2)``."""
    radius = np.hypot(p[:, 0], p[:, 1])
    theta = np.arctan2(radius, focal_dn)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(radius > 0.0, 2.0 * focal_dn * np.sin(0.5 * theta) / radius, 1.0)
    return p * scale[:, None]


def _as_points(points: ArrayLike, name: str) -> Points:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 2:
        raise CamcalError(f"{name} must have shape (N, 2), got {array.shape}")
    return array


def undistort_dn(model: str, params: Mapping[str, float], p_dn: ArrayLike, pixel_aspect: float = 1.0,
                 focal_dn: float = 1.0) -> Points:
    """LDPK's ``undistort``: the model function, distorted -> undistorted, in diagonally normalised coordinates.

    Parameters
    ----------
    model : str
        One of :data:`TDE4_MODELS`.
    params : Mapping[str, float]
        The model's parameters by camcal key (:data:`LDPK_PARAMETERS`; LDPK's
        default for any not given); other keys are ignored.
    p_dn : array_like, shape (N, 2)
        Distorted points, centred on the lens centre, in units of the film
        back's half-diagonal, y up.
    pixel_aspect : float
        LDPK's ``tde4_pixel_aspect`` (only the anamorphic model uses it).
    focal_dn : float
        The focal length over the film back's half-diagonal, LDPK's
        ``fl / r_fb`` (only the fisheye model uses it).

    Returns
    -------
    ndarray, shape (N, 2)
        Undistorted points (dn); NaN for fisheye points at or beyond 90
        degrees from the axis.

    Notes
    -----
    The formulas are in the module docstring.

    Examples
    --------
    >>> import numpy as np
    >>> q = undistort_dn("3de4-radial-deg4", {"c2": 0.1}, np.array([[0.6, 0.8]]))
    >>> [round(float(v), 12) for v in q[0]]
    [0.66, 0.88]
    """
    p = _as_points(p_dn, "points")
    c = coefficients(model, params)
    if model == "3de-classic":
        return _even_quartic(p, *_classic_terms(c))
    if model == "3de4-radial-deg4":
        return _apply(_cylindric_matrix(c), _radial_decentred(p, c))
    if model == "3de4-anamorphic-deg4":
        after, before = _anamorphic_frames(c, pixel_aspect)
        return _apply(after, _even_quartic(_apply(np.linalg.inv(before), p), *_anamorphic_terms(c)))
    terms = (c["c2"], c["c4"], c["c6"], c["c8"])
    return _radial_even(_plain_from_equisolid(p, focal_dn), terms)


def distort_dn(model: str, params: Mapping[str, float], q_dn: ArrayLike, pixel_aspect: float = 1.0,
               focal_dn: float = 1.0) -> Points:
    """LDPK's ``distort``: undistorted -> distorted, the inverse of :func:`undistort_dn`.

    Parameters are those of :func:`undistort_dn`, with undistorted points
    ``q_dn`` in.

    Returns
    -------
    ndarray, shape (N, 2)
        Distorted points (dn). The polynomial part is inverted by Newton
        iterations with its analytic Jacobian, started at the target, to
        a residual below 1e-14 (the linear parts — cylindric bending,
        rotation, squeezes, pixel aspect — exactly); NaN where no root is
        found on the lens's side of its fold (LDPK returns whatever its
        iterations reach there, often a root across the image).
    """
    q = _as_points(q_dn, "points")
    c = coefficients(model, params)
    if model == "3de-classic":
        ax, ay = _classic_terms(c)
        return _newton(lambda p: _even_quartic(p, ax, ay), lambda p: _even_quartic_jacobian(p, ax, ay), q)
    if model == "3de4-radial-deg4":
        bent = _apply(np.linalg.inv(_cylindric_matrix(c)), q)
        return _newton(lambda p: _radial_decentred(p, c), lambda p: _radial_decentred_jacobian(p, c), bent)
    if model == "3de4-anamorphic-deg4":
        after, before = _anamorphic_frames(c, pixel_aspect)
        ax, ay = _anamorphic_terms(c)
        inner = _newton(lambda p: _even_quartic(p, ax, ay), lambda p: _even_quartic_jacobian(p, ax, ay),
                        _apply(np.linalg.inv(after), q))
        return _apply(before, inner)
    terms = (c["c2"], c["c4"], c["c6"], c["c8"])
    plain = _newton(lambda p: _radial_even(p, terms), lambda p: _radial_even_jacobian(p, terms), q)
    return _equisolid_from_plain(plain, focal_dn)


# -- camcal's pixels -----------------------------------------------------------------------------


def dn_radius(K: ArrayLike, params: Mapping[str, float]) -> float:
    """``R = sqrt((W / fx)^2 + (H / fy)^2) / 2``: the film back's half-diagonal in normalised units ``K^-1 u``.

    ``W x H`` is the lens's film back in pixels (``filmback_width_px``,
    ``filmback_height_px``); LDPK's focal length in dn units is ``1 / R``.
    """
    K = np.asarray(K, dtype=np.float64)
    return 0.5 * math.hypot(params[FILMBACK_KEYS[0]] / K[0, 0], params[FILMBACK_KEYS[1]] / K[1, 1])


def dn_from_pixels(points_px: ArrayLike, K: ArrayLike, params: Mapping[str, float]) -> Points:
    """camcal pixels (y down, ``(0, 0)`` the top-left pixel's centre) -> diagonally normalised ``(x_n, -y_n) / R``."""
    points = _as_points(points_px, "points")
    K = np.asarray(K, dtype=np.float64)
    radius = dn_radius(K, params)
    y = (points[:, 1] - K[1, 2]) / K[1, 1]
    x = (points[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x / radius, -y / radius], axis=1)


def pixels_from_dn(p_dn: ArrayLike, K: ArrayLike, params: Mapping[str, float]) -> Points:
    """Inverse of :func:`dn_from_pixels`."""
    p = _as_points(p_dn, "points")
    K = np.asarray(K, dtype=np.float64)
    radius = dn_radius(K, params)
    x, y = p[:, 0] * radius, -p[:, 1] * radius
    return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], axis=1)


def undistort_pixels(model: str, params: Mapping[str, float], points_px: ArrayLike, K: ArrayLike) -> Points:
    """Distorted camcal pixels -> undistorted (pinhole ``K``) pixels: LDPK's ``undistort`` (closed form).

    The lens's film back, pixel aspect ``fy / fx`` and lens centre (the
    principal point) come from ``params`` and ``K`` as the module
    docstring says.
    """
    K = np.asarray(K, dtype=np.float64)
    radius = dn_radius(K, params)
    p = dn_from_pixels(points_px, K, params)
    return pixels_from_dn(undistort_dn(model, params, p, K[1, 1] / K[0, 0], 1.0 / radius), K, params)


def distort_pixels(model: str, params: Mapping[str, float], points_px: ArrayLike, K: ArrayLike) -> Points:
    """Undistorted (pinhole ``K``) camcal pixels -> distorted pixels: LDPK's ``distort`` (Newton, to 1e-14 dn)."""
    K = np.asarray(K, dtype=np.float64)
    radius = dn_radius(K, params)
    q = dn_from_pixels(points_px, K, params)
    return pixels_from_dn(distort_dn(model, params, q, K[1, 1] / K[0, 0], 1.0 / radius), K, params)


# -- LDPK's built-in camera ------------------------------------------------------------------------


@dataclass(frozen=True)
class LdpkCamera:
    """LDPK's built-in camera parameters (``ldp_builtin``) of a camcal camera matrix.

    Attributes
    ----------
    focal_length_cm, filmback_width_cm, filmback_height_cm : float
        ``tde4_focal_length_cm``, ``tde4_filmback_width_cm``, ``tde4_filmback_height_cm``.
    lens_center_offset_x_cm, lens_center_offset_y_cm : float
        ``tde4_lens_center_offset_[xy]_cm``: the lens centre minus the film
        back's centre, y up.
    pixel_aspect : float
        ``tde4_pixel_aspect``.

    Notes
    -----
    For an image of ``W x H`` pixels: ``fx = fl W / w_fb``, ``fy = fl H / h_fb``,
    ``pa = fy / fx``, ``cx = (W - 1) / 2 + x_lco W / w_fb``,
    ``cy = (H - 1) / 2 - y_lco H / h_fb``. An LDPK camera whose pixel aspect
    is not its film back's pixel shape ``(w_fb / W) / (h_fb / H)`` has no
    camcal ``K`` (3DE keeps the two equal).

    Examples
    --------
    >>> import numpy as np
    >>> K = np.array([[1000.0, 0, 959.5], [0, 2000.0, 539.5], [0, 0, 1]])
    >>> camera = LdpkCamera.from_camera_matrix(K, (1920, 1080), 3.6)
    >>> camera.pixel_aspect, round(camera.filmback_height_cm, 6), round(camera.focal_length_cm, 6)
    (2.0, 1.0125, 1.875)
    >>> bool(np.allclose(camera.camera_matrix((1920, 1080)), K))
    True
    """

    focal_length_cm: float
    filmback_width_cm: float
    filmback_height_cm: float
    lens_center_offset_x_cm: float
    lens_center_offset_y_cm: float
    pixel_aspect: float

    def __post_init__(self) -> None:
        for name in ("focal_length_cm", "filmback_width_cm", "filmback_height_cm", "pixel_aspect"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise CamcalError(f"LDPK camera: {name} must be a positive number, got {value!r}")
        for name in ("lens_center_offset_x_cm", "lens_center_offset_y_cm"):
            if not math.isfinite(getattr(self, name)):
                raise CamcalError(f"LDPK camera: {name} must be finite, got {getattr(self, name)!r}")

    @classmethod
    def from_camera_matrix(cls, K: ArrayLike, image_size: tuple[int, int], filmback_width_cm: float) -> LdpkCamera:
        """The LDPK camera of ``K`` on an image of ``image_size`` pixels whose film back is ``filmback_width_cm`` wide.

        Raises :class:`CamcalError` for a skewed ``K`` (LDPK has no skew).
        """
        K = np.asarray(K, dtype=np.float64)
        if K[0, 1] != 0.0:
            raise CamcalError(f"LDPK cameras have no skew; this camera matrix has skew {K[0, 1]!r}")
        width, height = image_size
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        pixel_aspect = fy / fx
        w_fb = float(filmback_width_cm)
        h_fb = w_fb * height / (width * pixel_aspect)
        return cls(focal_length_cm=float(fx * w_fb / width), filmback_width_cm=w_fb, filmback_height_cm=float(h_fb),
                   lens_center_offset_x_cm=float((cx - 0.5 * (width - 1)) * w_fb / width),
                   lens_center_offset_y_cm=float(-(cy - 0.5 * (height - 1)) * h_fb / height),
                   pixel_aspect=float(pixel_aspect))

    def camera_matrix(self, image_size: tuple[int, int]) -> NDArray[np.float64]:
        """camcal's ``K`` on an image of ``image_size`` pixels (see the class notes)."""
        width, height = image_size
        shape = (self.filmback_width_cm / width) / (self.filmback_height_cm / height)
        if abs(shape / self.pixel_aspect - 1.0) > 1e-9:
            raise CamcalError(f"LDPK camera: pixel aspect {self.pixel_aspect:.10g} does not match the film back's "
                              f"pixel shape {shape:.10g} on a {width}x{height} image "
                              f"({self.filmback_width_cm:.6g} x {self.filmback_height_cm:.6g} cm)")
        fx = self.focal_length_cm * width / self.filmback_width_cm
        fy = self.focal_length_cm * height / self.filmback_height_cm
        cx = 0.5 * (width - 1) + self.lens_center_offset_x_cm * width / self.filmback_width_cm
        cy = 0.5 * (height - 1) - self.lens_center_offset_y_cm * height / self.filmback_height_cm
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def builtin_parameters(self) -> dict[str, float]:
        """LDPK's built-in parameter names (:data:`BUILTIN_PARAMETERS`) -> values."""
        return dict(zip(BUILTIN_PARAMETERS, (self.focal_length_cm, self.filmback_width_cm, self.filmback_height_cm,
                                             self.lens_center_offset_x_cm, self.lens_center_offset_y_cm,
                                             self.pixel_aspect)))
