"""Lens distortion models: map undistorted pixels to distorted pixels and back.

Conventions (DESIGN.md): pixel (0, 0) is the centre of the top-left pixel;
``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.

Models
------
``none``
    Identity.
``polynomial`` (k1, k2[, k3])
    Radial, in normalised coordinates ``x_n = K^-1 u`` centred on the
    principal point (as OpenCV, COLMAP and Blender's POLYNOMIAL):
    ``x_d = x_u (1 + k1 r_u^2 + k2 r_u^4 + k3 r_u^6)``, ``r_u = |x_u|``.
``opencv`` (k1, k2, p1, p2, k3[, k4, k5, k6][, s1, s2, s3, s4])
    Brown-Conrady with OpenCV's rational and thin-prism terms, exactly
    OpenCV's formula (calib3d, "Camera Calibration and 3D Reconstruction";
    ``cv2.projectPoints``) in normalised coordinates, ``r^2 = x^2 + y^2``::

        radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
        x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4
        y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4

    The optional terms are absent (zero) unless given: OpenCV's 5-, 8- and
    12-coefficient vectors ``(k1, k2, p1, p2, k3[, k4, k5, k6[, s1, s2, s3,
    s4]])`` map one to one (:meth:`Distortion.opencv_coefficients`,
    :meth:`Distortion.from_opencv_coefficients`); the 14-vector's tilt
    ``(tauX, tauY)`` (a tilted sensor, a homography after the distortion)
    is accepted only when zero.
``division`` (lambda[, aspect])
    Strand & Hayman's one-parameter division model in PIXELS around the
    distortion centre ``center`` (default: the principal point):
    ``x_u = c + (x_d - c) / (1 + lambda r_d^2)``, ``r_d = |x_d - c|`` in px,
    ``lambda`` in 1/px^2 (negative for barrel distortion). With the optional
    ``aspect`` (default 1) the radius is measured in x pixels,
    ``r_d^2 = dx^2 + (aspect dy)^2``: with ``aspect = fx / fy`` the lens is
    round in normalised coordinates, not in pixels (non-square pixels, an
    anamorphic squeeze), which is COLMAP's ``DIVISION`` with two focal
    lengths, ``k = lambda fx^2``.
``kannala-brandt`` (k1, k2, k3, k4)
    Kannala & Brandt's fisheye model as OpenCV's ``cv2.fisheye`` and
    COLMAP's ``OPENCV_FISHEYE`` use it, in normalised coordinates centred on
    the principal point: a ray at angle ``theta`` from the optical axis
    lands at radius ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 +
    k3 theta^6 + k4 theta^8)``, so ``x_d = (theta_d / r_u) x_u`` with
    ``r_u = |x_u| = tan(theta)``.
``kannala-brandt-thin-prism`` (k1..k6, p1, p2, s1, s2, s3, s4)
    COLMAP's ``RAD_TAN_THIN_PRISM_FISHEYE``: Kannala-Brandt with six radial
    terms, ``theta_d = theta (1 + k1 theta^2 + ... + k6 theta^12)``, giving
    ``(x_r, y_r) = (theta_d / r_u) x_u``, then OpenCV's tangential and
    thin-prism terms on that point, ``rho^2 = x_r^2 + y_r^2``::

        x_d = x_r + 2 p1 x_r y_r + p2 (rho^2 + 2 x_r^2) + s1 rho^2 + s2 rho^4
        y_d = y_r + p1 (rho^2 + 2 y_r^2) + 2 p2 x_r y_r + s3 rho^2 + s4 rho^4

    COLMAP's parameters ``k0..k5, p0, p1, s0..s3`` are ``k1..k6, p2, p1,
    s1..s4`` (its ``p0`` plays OpenCV's ``p2``). The inverse undoes the
    tangential and prism terms by Newton iterations (their 2x2 Jacobian),
    then the radial part on the angle as for ``kannala-brandt``.
``3de-classic``, ``3de4-radial-deg4``, ``3de4-anamorphic-deg4``, ``3de4-fisheye-deg8``
    3DEqualizer's standard models as the Lens Distortion Plugin Kit
    defines them ("3DE Classic LD Model", "3DE4 Radial - Standard, Degree
    4", "3DE4 Anamorphic - Standard, Degree 4", "3DE4 Radial - Fisheye,
    Degree 8"): formulas, parameters and LDPK's names in
    :mod:`camcal.model.tde4`. Their coefficients map distorted to
    undistorted points in diagonally normalised coordinates of the film
    back, which the lens carries in pixels (``filmback_width_px``,
    ``filmback_height_px``, the camera's image size); the pixel aspect is
    ``fy / fx`` and the lens centre the principal point. :meth:`undistort`
    is LDPK's closed-form model function, :meth:`distort` its Newton inverse.


The division model inverts in closed form; the polynomial models invert by
Newton iterations to 1e-10 px; Kannala-Brandt inverts ``theta_d(theta)``
by safeguarded Newton iterations on the angle, to 1e-15 rad.

Rays and the field of view: pinhole ("undistorted") pixels exist only for
rays in front of the camera (``theta < 90 deg``), so :meth:`Distortion.distort`
and :meth:`Distortion.undistort` cover that half-space. Wider lenses go
through :meth:`Distortion.project_rays` and :meth:`Distortion.rays_from_pixels`,
which for ``kannala-brandt`` hold up to :attr:`Distortion.max_angle_rad`
(where ``theta_d(theta)`` stops increasing, at most 180 deg); pixels beyond
that map to NaN.

Conversions between models are fits (:func:`fit_distortion`): the target
model that best reproduces the source model's distorted pixels over the
image, returned with its RMS and max residual in pixels.

References
----------
Strand, R. & Hayman, E. (2005). Correcting radial distortion by circle
fitting. BMVC.
Brown, D. C. (1966). Decentering distortion of lenses. Photogrammetric
Engineering.
Weng, J., Cohen, P. & Herniou, M. (1992). Camera calibration with
distortion models and accuracy evaluation. IEEE TPAMI 14(10) (thin prism).
Claus, D. & Fitzgibbon, A. W. (2005). A rational function lens distortion
model for general cameras. CVPR.
OpenCV calib3d documentation, "Camera Calibration and 3D Reconstruction"
(the rational, thin-prism and tilt terms of ``cv2.projectPoints``).
Kannala, J. & Brandt, S. S. (2006). A generic camera model and calibration
method for conventional, wide-angle, and fish-eye lenses. IEEE TPAMI 28(8).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.model import tde4
from camcal.model.spline import SplineField

__all__ = ["FISHEYE_MODELS", "MODEL_PARAMS", "OPENCV_COEFFICIENTS", "Distortion", "DistortionFit", "capped_rays",
           "fit_distortion", "frame_grid"]

#: Parameter names of each model: (required, optional).
MODEL_PARAMS: Mapping[str, tuple[tuple[str, ...], tuple[str, ...]]] = MappingProxyType(
    {
        "none": ((), ()),
        "polynomial": (("k1", "k2"), ("k3",)),
        "opencv": (("k1", "k2", "p1", "p2", "k3"), ("k4", "k5", "k6", "s1", "s2", "s3", "s4")),
        "division": (("lambda",), ("aspect",)),
        "kannala-brandt": (("k1", "k2", "k3", "k4"), ()),
        "kannala-brandt-thin-prism": (("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "s1", "s2", "s3", "s4"), ()),
        # 3DE's models: the film back required, each coefficient optional (LDPK's default)
        **{model: (tde4.FILMBACK_KEYS, tuple(p.key for p in tde4.LDPK_PARAMETERS[model])) for model in tde4.TDE4_MODELS},
    }
)

#: OpenCV's distortion vector, in its order (the 14-vector adds the tilt ``tauX, tauY``, never held).
OPENCV_COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
_RATIONAL = ("k4", "k5", "k6")
_THIN_PRISM = ("s1", "s2", "s3", "s4")

#: Models defined in normalised coordinates ``K^-1 u`` around the principal point.
_NORMALISED_MODELS = ("polynomial", "opencv", "kannala-brandt", "kannala-brandt-thin-prism")
#: The fisheye models: radius from the ray's angle, rays imaged up to :attr:`Distortion.max_angle_rad`.
FISHEYE_MODELS = ("kannala-brandt", "kannala-brandt-thin-prism")

_NEWTON_TOL_PX = 1e-10
_NEWTON_MAX_ITER = 50
#: Determinant of the normalised distortion Jacobian (about 1 at the centre) below which a point is past the fold.
_SINGULAR_JACOBIAN = 1e-12


def _as_points(points: ArrayLike, name: str = "points") -> NDArray[np.float64]:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 2:
        raise CamcalError(f"{name} must have shape (N, 2), got {array.shape}")
    return array


@dataclass(frozen=True)
class Distortion:
    """A lens distortion model with its parameters.

    Parameters
    ----------
    model : str
        One of :data:`MODEL_PARAMS`: ``none``, ``polynomial``, ``opencv``,
        ``division``, ``kannala-brandt``, ``kannala-brandt-thin-prism`` and
        3DE's ``3de-classic``, ``3de4-radial-deg4``,
        ``3de4-anamorphic-deg4``, ``3de4-fisheye-deg8``.
    params : Mapping[str, float]
        The model's parameters (see the module docstring), exactly the
        required names plus any optional ones.
    center : tuple of float, optional
        Distortion centre in pixels, only for ``division``; ``None`` means
        the principal point of the camera's K.
    correction : SplineField, optional
        A smooth displacement field over the image applied after the
        model (:mod:`camcal.model.spline`): ``q = q0 + F(q0)`` with ``q0``
        the model's distorted pixel; every mapping of this class includes
        it, :meth:`without_correction` is the parametric part alone.

    Examples
    --------
    >>> import numpy as np
    >>> d = Distortion("division", {"lambda": -1e-7}, center=(959.5, 539.5))
    >>> K = np.array([[1000., 0, 959.5], [0, 1000., 539.5], [0, 0, 1]])
    >>> u = np.array([[1800.0, 1000.0]])
    >>> bool(np.allclose(d.undistort(d.distort(u, K), K), u, atol=1e-9))
    True
    """

    model: str
    params: Mapping[str, float] = field(default_factory=dict)
    center: tuple[float, float] | None = None
    correction: SplineField | None = None

    def __post_init__(self) -> None:
        if self.correction is not None and not isinstance(self.correction, SplineField):
            raise CamcalError(f"distortion correction must be a SplineField, got {type(self.correction).__name__}")
        if self.model not in MODEL_PARAMS:
            raise CamcalError(
                f"unknown distortion model {self.model!r}, expected one of: "
                + ", ".join(MODEL_PARAMS)
            )
        required, optional = MODEL_PARAMS[self.model]
        given = set(self.params)
        missing = [name for name in required if name not in given]
        if missing:
            raise CamcalError(
                f"distortion model {self.model!r} needs parameter(s) {', '.join(missing)}"
            )
        unknown = sorted(given - set(required) - set(optional))
        if unknown:
            raise CamcalError(
                f"distortion model {self.model!r} has no parameter(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(required + optional) or 'none'}"
            )
        params = {}
        for name, value in self.params.items():
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise CamcalError(f"distortion parameter {name!r} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise CamcalError(f"distortion parameter {name!r} is not finite ({value})")
            params[name] = float(value)
        if params.get("aspect", 1.0) <= 0.0:
            raise CamcalError(f"division 'aspect' must be positive, got {params['aspect']!r}")
        if self.model in tde4.TDE4_MODELS:
            tde4.check_params(self.model, params)
        object.__setattr__(self, "params", MappingProxyType(params))
        if self.center is not None:
            if self.model != "division":
                raise CamcalError(
                    f"distortion model {self.model!r} is centred on the principal point; "
                    "'center' applies only to the division model"
                )
            center = tuple(float(v) for v in self.center)
            if len(center) != 2 or not all(math.isfinite(v) for v in center):
                raise CamcalError(f"distortion center must be two finite numbers, got {self.center!r}")
            object.__setattr__(self, "center", center)

    @classmethod
    def none(cls) -> Distortion:
        """The identity model."""
        return cls("none", {})

    @property
    def is_fisheye(self) -> bool:
        """True for the Kannala-Brandt models (:data:`FISHEYE_MODELS`): they image rays beyond 90 degrees."""
        return self.model in FISHEYE_MODELS

    @property
    def is_identity(self) -> bool:
        """True when the model leaves every point where it is (never for ``kannala-brandt``:
        with every k at 0 it is the equidistant fisheye, not the pinhole)."""
        if self.correction is not None:
            return False
        if self.model == "division":
            return self.params["lambda"] == 0.0
        if self.model in tde4.TDE4_MODELS:
            return tde4.is_identity(self.model, self.params)
        return self.model not in FISHEYE_MODELS and all(value == 0.0 for value in self.params.values())

    # -- OpenCV's distortion vector ------------------------------------------------

    @property
    def opencv_terms(self) -> int:
        """Length of the shortest OpenCV vector that holds this lens exactly: 5, 8 or 12.

        ``none``, ``polynomial`` and ``opencv`` only; 8 when a rational term
        (k4, k5, k6) is non-zero, 12 when a thin-prism term (s1..s4) is.
        """
        if self.model not in ("none", "polynomial", "opencv"):
            raise CamcalError(f"a {self.model} lens has no OpenCV distortion vector")
        if self.correction is not None:
            raise CamcalError(f"a {self.model} lens with a correction field has no exact OpenCV distortion vector "
                              "(take its nearest parametric model: fit_distortion of without_correction())")
        p = self.params
        if any(p.get(name, 0.0) for name in _THIN_PRISM):
            return 12
        if any(p.get(name, 0.0) for name in _RATIONAL):
            return 8
        return 5

    def opencv_coefficients(self, length: int | None = None) -> NDArray[np.float64]:
        """OpenCV's distortion vector ``(k1, k2, p1, p2, k3[, k4, k5, k6[, s1, s2, s3, s4]])``.

        Parameters
        ----------
        length : int, optional
            5, 8, 12 or 14 (tilt zero); default :attr:`opencv_terms`, the
            shortest exact one. A length that drops non-zero terms is refused.

        Returns
        -------
        ndarray, shape (length,)
            Zeros where the model has no term (``none``, ``polynomial``).
        """
        needed = self.opencv_terms
        length = needed if length is None else int(length)
        if length not in (5, 8, 12, 14):
            raise CamcalError(f"OpenCV distortion vectors have 5, 8, 12 or 14 coefficients, not {length}")
        if length < needed:
            raise CamcalError(f"this lens needs {needed} OpenCV coefficients, {length} would drop terms")
        values = [self.params.get(name, 0.0) for name in OPENCV_COEFFICIENTS] + [0.0, 0.0]
        return np.array(values[:length], dtype=np.float64)

    @classmethod
    def from_opencv_coefficients(cls, values: ArrayLike) -> Distortion:
        """The ``opencv`` lens of an OpenCV distortion vector of 4, 5, 8, 12 or 14 coefficients.

        Coefficients beyond the vector are zero (k3 of a 4-vector, the
        rational and thin-prism terms of a 5-vector) and not stored; a
        14-vector's tilt ``(tauX, tauY)`` must be zero (camcal's lens
        models have no tilted sensor).
        """
        values = np.asarray(values, dtype=np.float64).ravel()
        if len(values) not in (4, 5, 8, 12, 14):
            raise CamcalError(f"OpenCV distortion vectors have 4, 5, 8, 12 or 14 coefficients, got {len(values)}")
        if len(values) == 14 and np.any(values[12:] != 0.0):
            raise CamcalError(f"OpenCV tilt terms tauX = {values[12]:.6g}, tauY = {values[13]:.6g} (a tilted "
                              "sensor) are not held by camcal's lens models; only a zero tilt is accepted")
        names = OPENCV_COEFFICIENTS[:max(5, min(len(values), 12))]
        padded = np.concatenate([values, np.zeros(max(0, 5 - len(values)))])
        return cls("opencv", dict(zip(names, (float(v) for v in padded))))

    @property
    def has_correction(self) -> bool:
        """True when a correction field (:mod:`camcal.model.spline`) follows the parametric model."""
        return self.correction is not None

    def without_correction(self) -> Distortion:
        """The parametric model alone (the correction field dropped)."""
        return Distortion(self.model, dict(self.params), self.center)

    # -- file boundary -------------------------------------------------------

    def to_dict(self) -> dict:
        """The rig-file form: ``{"model", "params"[, "center"][, "correction"]}``."""
        out: dict = {"model": self.model, "params": dict(self.params)}
        if self.center is not None:
            out["center"] = list(self.center)
        if self.correction is not None:
            out["correction"] = self.correction.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> Distortion:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        if not isinstance(data, Mapping):
            raise CamcalError(f"distortion must be an object, got {type(data).__name__}")
        unknown = sorted(set(data) - {"model", "params", "center", "correction"})
        if unknown:
            raise CamcalError(f"distortion has unknown key(s): {', '.join(unknown)}")
        if "model" not in data:
            raise CamcalError("distortion is missing key 'model'")
        params = data.get("params", {})
        if not isinstance(params, Mapping):
            raise CamcalError("distortion 'params' must be an object")
        center = data.get("center")
        if center is not None and (not isinstance(center, (list, tuple)) or len(center) != 2):
            raise CamcalError(f"distortion 'center' must be [x, y], got {center!r}")
        correction = None if data.get("correction") is None else SplineField.from_dict(data["correction"])
        return cls(str(data["model"]), dict(params), None if center is None else tuple(center), correction)

    # -- mappings --------------------------------------------------------------

    def _centre(self, K: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.center is not None:
            return np.asarray(self.center, dtype=np.float64)
        return np.asarray(K, dtype=np.float64)[:2, 2]

    def distort(self, points_px: ArrayLike, K: ArrayLike) -> NDArray[np.float64]:
        """Map undistorted pixels to distorted pixels.

        Parameters
        ----------
        points_px : array_like, shape (N, 2)
            Undistorted (ideal pinhole) pixel coordinates.
        K : array_like, shape (3, 3)
            Camera matrix: normalises the ``polynomial`` / ``opencv`` /
            ``kannala-brandt`` models and gives the default ``division``
            centre.

        Returns
        -------
        ndarray, shape (N, 2)
            Distorted pixel coordinates. For the division model a point
            beyond the model's range (``1 - 4 lambda r_u^2 < 0``) maps to NaN,
            for ``kannala-brandt`` a ray beyond :attr:`max_angle_rad`.
        """
        points = _as_points(points_px)
        K = np.asarray(K, dtype=np.float64)
        if self.model == "none":
            distorted = points.copy()
        elif self.model == "division":
            distorted = self._division_distort(points, self._centre(K), self.params.get("aspect", 1.0))
        elif self.model in tde4.TDE4_MODELS:
            distorted = tde4.distort_pixels(self.model, self.params, points, K)
        else:
            distorted = _normalised_to_pixels(self.distort_normalised(_pixels_to_normalised(points, K)), K)
        return distorted if self.correction is None else self.correction.apply(distorted)

    def undistort(self, points_px: ArrayLike, K: ArrayLike) -> NDArray[np.float64]:
        """Map distorted pixels to undistorted pixels (inverse of :meth:`distort`).

        Parameters
        ----------
        points_px : array_like, shape (N, 2)
            Distorted pixel coordinates.
        K : array_like, shape (3, 3)
            Camera matrix (see :meth:`distort`).

        Returns
        -------
        ndarray, shape (N, 2)
            Undistorted pixel coordinates; closed form for ``division``,
            Newton iterations to 1e-10 px otherwise. ``kannala-brandt``
            pixels whose ray is at or beyond 90 degrees from the axis (no
            pinhole image) or beyond :attr:`max_angle_rad` give NaN.
        """
        points = _as_points(points_px)
        K = np.asarray(K, dtype=np.float64)
        if self.correction is not None:
            points = self.correction.remove(points)
        if self.model == "none":
            return points.copy()
        if self.model in tde4.TDE4_MODELS:
            return tde4.undistort_pixels(self.model, self.params, points, K)
        if self.is_fisheye:
            xy_d = self._undo_tangential_prism(_pixels_to_normalised(points, K), K)
            theta_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
            theta = self._theta_from_theta_d(theta_d)
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(theta_d == 0.0, 1.0, np.tan(theta) / theta_d)
            scale[~(theta < 0.5 * np.pi)] = np.nan
            return _normalised_to_pixels(xy_d * scale[:, None], K)
        if self.model == "division":
            centre = self._centre(K)
            offset = points - centre
            r2 = offset[:, 0:1] ** 2 + (self.params.get("aspect", 1.0) * offset[:, 1:2]) ** 2
            return centre + offset / (1.0 + self.params["lambda"] * r2)
        # Newton on the normalised coordinates; tolerance scaled to pixels.
        target = _pixels_to_normalised(points, K)
        tol = _NEWTON_TOL_PX / max(K[0, 0], K[1, 1])
        estimate = target.copy()
        for _ in range(_NEWTON_MAX_ITER):
            residual = self.distort_normalised(estimate) - target
            if np.all(np.abs(residual) < tol):
                break
            jac = self._jacobian_normalised(estimate)
            # a point past the lens's fold (singular Jacobian) or already lost has no inverse: NaN, not an error
            solvable = np.isfinite(jac).all(axis=(1, 2)) & np.isfinite(residual).all(axis=1)
            solvable[solvable] = np.abs(np.linalg.det(jac[solvable])) > _SINGULAR_JACOBIAN
            step = np.full_like(estimate, np.nan)
            step[solvable] = np.linalg.solve(jac[solvable], residual[solvable][:, :, None])[:, :, 0]
            estimate = estimate - step
        return _normalised_to_pixels(estimate, K)

    def distort_normalised(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Apply a ``polynomial`` / ``opencv`` / Kannala-Brandt model to normalised coordinates (N, 2)."""
        xy = _as_points(xy, "normalised points")
        if self.model not in _NORMALISED_MODELS:
            raise CamcalError(f"model {self.model!r} is not defined in normalised coordinates")
        p = self.params
        x, y = xy[:, 0], xy[:, 1]
        if self.is_fisheye:
            r = np.hypot(x, y)
            theta = np.arctan(r)
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(r == 0.0, 1.0, self.theta_d(theta) / r)
            scale[theta > self.max_angle_rad] = np.nan
            return self._tangential_prism(xy * scale[:, None])
        r2 = x * x + y * y
        radial = 1.0 + r2 * (p["k1"] + r2 * (p["k2"] + r2 * p.get("k3", 0.0)))
        if self.model == "opencv" and any(p.get(name, 0.0) for name in _RATIONAL):
            radial = radial / (1.0 + r2 * (p.get("k4", 0.0) + r2 * (p.get("k5", 0.0) + r2 * p.get("k6", 0.0))))
        xd = x * radial
        yd = y * radial
        if self.model == "opencv":
            p1, p2 = p["p1"], p["p2"]
            xd = xd + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = yd + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            if any(p.get(name, 0.0) for name in _THIN_PRISM):
                xd = xd + r2 * (p.get("s1", 0.0) + r2 * p.get("s2", 0.0))
                yd = yd + r2 * (p.get("s3", 0.0) + r2 * p.get("s4", 0.0))
        return np.stack([xd, yd], axis=1)

    # -- rays (wide lenses) ----------------------------------------------------------

    def theta_d(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Kannala-Brandt: ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``.

        Parameters
        ----------
        theta : array_like
            Angles from the optical axis, radians.

        Returns
        -------
        ndarray
            The normalised image radius of each angle (``theta_d`` in the
            notation of OpenCV's fisheye module).
        """
        if not self.is_fisheye:
            raise CamcalError(f"theta_d is the Kannala-Brandt radius; this model is {self.model!r}")
        theta = np.asarray(theta, dtype=np.float64)
        t2 = theta * theta
        series = np.zeros_like(t2)
        for k in reversed(self._radial_terms()):
            series = t2 * (k + series)
        return theta * (1.0 + series)

    def _radial_terms(self) -> tuple[float, ...]:
        """Kannala-Brandt's k1..k4 (k1..k6 with the thin prism)."""
        names = ("k1", "k2", "k3", "k4", "k5", "k6") if self.model == "kannala-brandt-thin-prism" else ("k1", "k2", "k3", "k4")
        return tuple(self.params[name] for name in names)

    def _theta_d_slope(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``d theta_d / d theta = 1 + 3 k1 theta^2 + 5 k2 theta^4 + ...``."""
        t2 = theta * theta
        series = np.zeros_like(t2)
        for n, k in reversed(list(enumerate(self._radial_terms()))):
            series = t2 * ((2 * n + 3) * k + series)
        return 1.0 + series

    def _tangential_prism(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """``kannala-brandt-thin-prism``: OpenCV's tangential and thin-prism terms on the fisheye point (identity otherwise)."""
        if self.model != "kannala-brandt-thin-prism":
            return xy
        p = self.params
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        xd = x + 2.0 * p["p1"] * x * y + p["p2"] * (r2 + 2.0 * x * x) + r2 * (p["s1"] + r2 * p["s2"])
        yd = y + p["p1"] * (r2 + 2.0 * y * y) + 2.0 * p["p2"] * x * y + r2 * (p["s3"] + r2 * p["s4"])
        return np.stack([xd, yd], axis=1)

    def _tangential_prism_jacobian(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """d(:meth:`_tangential_prism`)/d(x, y), shape (N, 2, 2)."""
        p = self.params
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        prism_x = 2.0 * (p["s1"] + 2.0 * p["s2"] * r2)
        prism_y = 2.0 * (p["s3"] + 2.0 * p["s4"] * r2)
        jac = np.empty((len(xy), 2, 2))
        jac[:, 0, 0] = 1.0 + 2.0 * p["p1"] * y + 6.0 * p["p2"] * x + prism_x * x
        jac[:, 0, 1] = 2.0 * p["p1"] * x + 2.0 * p["p2"] * y + prism_x * y
        jac[:, 1, 0] = 2.0 * p["p1"] * x + 2.0 * p["p2"] * y + prism_y * x
        jac[:, 1, 1] = 1.0 + 6.0 * p["p1"] * y + 2.0 * p["p2"] * x + prism_y * y
        return jac

    def _undo_tangential_prism(self, xy_d: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
        """Inverse of :meth:`_tangential_prism` by Newton iterations to 1e-10 px (NaN where they do not converge)."""
        if self.model != "kannala-brandt-thin-prism":
            return xy_d
        tol = _NEWTON_TOL_PX / max(K[0, 0], K[1, 1])
        estimate = xy_d.copy()
        for _ in range(_NEWTON_MAX_ITER):
            residual = self._tangential_prism(estimate) - xy_d
            if np.all(~(np.abs(residual) >= tol)):
                break
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                estimate = estimate - np.linalg.solve(self._tangential_prism_jacobian(estimate), residual[:, :, None])[:, :, 0]
        bad = ~np.all(np.abs(self._tangential_prism(estimate) - xy_d) < 1e3 * tol, axis=1)
        estimate[bad] = np.nan
        return estimate

    @property
    def max_angle_rad(self) -> float:
        """Largest angle from the optical axis the model maps one-to-one, radians.

        Kannala-Brandt: the first angle where ``d theta_d / d theta =
        1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8``
        (``+ 11 k5 theta^10 + 13 k6 theta^12`` with the thin prism) reaches 0, at most pi (180 deg); every other model: pi / 2 (a
        pinhole image exists only in front of the camera).
        """
        if not self.is_fisheye:
            return 0.5 * np.pi
        # roots in t = theta^2 of ... + 9 k4 t^4 + 7 k3 t^3 + 5 k2 t^2 + 3 k1 t + 1
        terms = self._radial_terms()
        coefficients = np.trim_zeros([(2 * n + 3) * terms[n] for n in reversed(range(len(terms)))] + [1.0], "f")
        roots = np.roots(coefficients) if len(coefficients) > 1 else np.array([])
        real = roots[(np.abs(roots.imag) <= 1e-12 * np.abs(roots)) & (roots.real > 0.0)].real
        return float(min(np.pi, np.sqrt(real.min()))) if len(real) else float(np.pi)

    def _theta_from_theta_d(self, theta_d: NDArray[np.float64]) -> NDArray[np.float64]:
        """Invert ``theta_d(theta)`` on ``[0, max_angle_rad]``; NaN beyond its range.

        Start from a table of the monotone function (linear interpolation on
        4097 angles), take two Newton steps (clipped to the range), then
        finish any point not yet at 1e-15 rad with safeguarded Newton: a
        step that would leave the bracket ``[low, high]`` known to hold the
        root is replaced by bisection.
        """
        theta_max = self.max_angle_rad
        theta_d = np.asarray(theta_d, dtype=np.float64)
        flat = theta_d.ravel()
        valid = np.isfinite(flat) & (flat >= 0.0) & (flat <= self.theta_d(theta_max))
        result = np.full(flat.size, np.nan)
        active = np.flatnonzero(valid)
        target = flat[active]
        table = np.linspace(0.0, theta_max, 4097)
        theta = np.interp(target, self.theta_d(table), table)

        def newton_step(theta, target):
            residual = self.theta_d(theta) - target
            slope = self._theta_d_slope(theta)
            with np.errstate(divide="ignore", invalid="ignore"):
                return theta - residual / slope, residual

        for _ in range(2):
            theta = np.clip(newton_step(theta, target)[0], 0.0, theta_max)
        step = newton_step(theta, target)[0]
        done = np.abs(step - theta) <= 1e-15 * np.maximum(1.0, theta)
        result[active[done]] = np.clip(step[done], 0.0, theta_max)
        # the rest (near max_angle_rad, where the slope vanishes): safeguarded Newton
        keep = ~done
        active, target, theta = active[keep], target[keep], theta[keep]
        low, high = np.zeros_like(target), np.full_like(target, theta_max)
        for _ in range(100):
            if not len(active):
                break
            step, residual = newton_step(theta, target)
            low = np.where(residual < 0.0, theta, low)
            high = np.where(residual > 0.0, theta, high)
            new = np.where((step > low) & (step < high), step, 0.5 * (low + high))
            done = np.abs(new - theta) <= 1e-15 * np.maximum(1.0, theta)
            result[active[done]] = new[done]
            keep = ~done
            active, target, low, high, theta = active[keep], target[keep], low[keep], high[keep], new[keep]
        result[active] = theta
        return result.reshape(theta_d.shape)

    def project_rays(self, rays: ArrayLike, K: ArrayLike) -> NDArray[np.float64]:
        """Distorted pixels of directions in the camera frame, wide angles included.

        Parameters
        ----------
        rays : array_like, shape (N, 3)
            Directions (any length) in camera axes: +x right, +y down,
            +z forward.
        K : array_like, shape (3, 3)
            Camera matrix.

        Returns
        -------
        ndarray, shape (N, 2)
            Distorted pixels. ``kannala-brandt``: ``theta = atan2(|(x, y)|, z)``
            and ``x_d = theta_d (x, y) / |(x, y)|``, defined up to
            :attr:`max_angle_rad` (beyond the 90 degrees of a pinhole);
            other models: ``distort(K (x/z, y/z, 1))``. NaN where the model
            has no image of the ray (``z <= 0`` for the pinhole models).

        Examples
        --------
        >>> import numpy as np
        >>> fisheye = Distortion("kannala-brandt", {"k1": 0.02, "k2": 0.0, "k3": 0.0, "k4": 0.0})
        >>> K = np.array([[300.0, 0, 640.0], [0, 300.0, 480.0], [0, 0, 1]])
        >>> behind = np.array([[1.0, 0.0, -0.2]])  # 101 degrees off the axis
        >>> pixel = fisheye.project_rays(behind, K)
        >>> bool(np.allclose(fisheye.rays_from_pixels(pixel, K), behind / np.linalg.norm(behind)))
        True
        """
        rays = np.asarray(rays, dtype=np.float64)
        if rays.ndim != 2 or rays.shape[1] != 3:
            raise CamcalError(f"rays must have shape (N, 3), got {rays.shape}")
        K = np.asarray(K, dtype=np.float64)
        if self.is_fisheye:
            rho = np.hypot(rays[:, 0], rays[:, 1])
            theta = np.arctan2(rho, rays[:, 2])
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(rho > 0.0, self.theta_d(theta) / rho, 0.0)
            scale[~(theta <= self.max_angle_rad)] = np.nan
            pixels = _normalised_to_pixels(self._tangential_prism(rays[:, :2] * scale[:, None]), K)
            return pixels if self.correction is None else self.correction.apply(pixels)
        depth = rays[:, 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            normalised = np.where(depth > 0.0, rays[:, :2] / depth, np.nan)
        return self.distort(_normalised_to_pixels(normalised, K), K)

    def rays_from_pixels(self, points_px: ArrayLike, K: ArrayLike) -> NDArray[np.float64]:
        """Unit directions in the camera frame of distorted pixels (inverse of :meth:`project_rays`).

        Parameters
        ----------
        points_px : array_like, shape (N, 2)
            Distorted pixels.
        K : array_like, shape (3, 3)
            Camera matrix.

        Returns
        -------
        ndarray, shape (N, 3)
            Unit rays (+z forward); NaN for pixels beyond the model's range
            (``kannala-brandt``: beyond :attr:`max_angle_rad`).
        """
        points = _as_points(points_px)
        K = np.asarray(K, dtype=np.float64)
        if self.is_fisheye:
            if self.correction is not None:
                points = self.correction.remove(points)
            xy_d = self._undo_tangential_prism(_pixels_to_normalised(points, K), K)
            theta_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
            theta = self._theta_from_theta_d(theta_d)
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(theta_d == 0.0, 1.0, np.sin(theta) / theta_d)
            return np.column_stack([xy_d * scale[:, None], np.cos(theta)])
        xy = _pixels_to_normalised(self.undistort(points, K), K)
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def _jacobian_normalised(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """d(distort_normalised)/d(x, y), shape (N, 2, 2)."""
        p = self.params
        x, y = xy[:, 0], xy[:, 1]
        k1, k2, k3 = p["k1"], p["k2"], p.get("k3", 0.0)
        k4, k5, k6 = p.get("k4", 0.0), p.get("k5", 0.0), p.get("k6", 0.0)
        r2 = x * x + y * y
        numerator = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dnumerator_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        denominator = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        ddenominator_dr2 = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
        radial = numerator / denominator
        dradial_dr2 = (dnumerator_dr2 * denominator - numerator * ddenominator_dr2) / denominator**2
        jac = np.empty((len(xy), 2, 2))
        jac[:, 0, 0] = radial + 2.0 * x * x * dradial_dr2
        jac[:, 0, 1] = 2.0 * x * y * dradial_dr2
        jac[:, 1, 0] = jac[:, 0, 1]
        jac[:, 1, 1] = radial + 2.0 * y * y * dradial_dr2
        if self.model == "opencv":
            p1, p2 = p["p1"], p["p2"]
            jac[:, 0, 0] += 2.0 * p1 * y + 6.0 * p2 * x
            jac[:, 0, 1] += 2.0 * p1 * x + 2.0 * p2 * y
            jac[:, 1, 0] += 2.0 * p1 * x + 2.0 * p2 * y
            jac[:, 1, 1] += 6.0 * p1 * y + 2.0 * p2 * x
            # thin prism: d(s1 r^2 + s2 r^4)/dx = 2 x (s1 + 2 s2 r^2), likewise for y and s3, s4
            prism_x = 2.0 * (p.get("s1", 0.0) + 2.0 * p.get("s2", 0.0) * r2)
            prism_y = 2.0 * (p.get("s3", 0.0) + 2.0 * p.get("s4", 0.0) * r2)
            jac[:, 0, 0] += prism_x * x
            jac[:, 0, 1] += prism_x * y
            jac[:, 1, 0] += prism_y * x
            jac[:, 1, 1] += prism_y * y
        return jac

    def _division_distort(self, points: NDArray[np.float64], centre: NDArray[np.float64],
                          aspect: float = 1.0) -> NDArray[np.float64]:
        """Closed-form inverse of the division model.

        Notes
        -----
        With ``r_u = r_d / (1 + lambda r_d^2)``, ``r_d`` solves
        ``lambda r_u r_d^2 - r_d + r_u = 0``; the root continuous at
        ``r_u = 0`` is ``r_d = 2 r_u / (1 + sqrt(1 - 4 lambda r_u^2))``
        (radii in x pixels: ``r^2 = dx^2 + (aspect dy)^2``).
        """
        lam = self.params["lambda"]
        offset = points - centre
        r2_u = offset[:, 0:1] ** 2 + (aspect * offset[:, 1:2]) ** 2
        discriminant = 1.0 - 4.0 * lam * r2_u
        with np.errstate(invalid="ignore"):
            scale = 2.0 / (1.0 + np.sqrt(discriminant))
        scale = np.where(discriminant >= 0.0, scale, np.nan)
        return centre + offset * scale


def capped_rays(rays: NDArray[np.float64], axis: NDArray[np.float64], half_angle: float | None) -> NDArray[np.float64]:
    """Each ray (unit length out) turned towards the unit ``axis`` (in its plane) to at most ``half_angle`` from it:
    a fisheye's rays brought within its :attr:`Distortion.max_angle_rad`, a rectified frame's within its cap."""
    if half_angle is None:
        return rays
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    along = rays @ axis
    across = rays - along[:, None] * axis[None, :]
    norm = np.linalg.norm(across, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        side = np.where(norm > 0.0, across / norm, 0.0)
    theta = np.minimum(np.arccos(np.clip(along, -1.0, 1.0)), half_angle)[:, None]
    return np.cos(theta) * axis[None, :] + np.sin(theta) * side


def _pixels_to_normalised(points: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x_n = K^-1 [u, v, 1]^T`` (skew included)."""
    fx, s, cx = K[0]
    fy, cy = K[1, 1], K[1, 2]
    y = (points[:, 1] - cy) / fy
    x = (points[:, 0] - cx - s * y) / fx
    return np.stack([x, y], axis=1)


def _normalised_to_pixels(xy: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    """``u = K [x, y, 1]^T``."""
    fx, s, cx = K[0]
    fy, cy = K[1, 1], K[1, 2]
    return np.stack([fx * xy[:, 0] + s * xy[:, 1] + cx, fy * xy[:, 1] + cy], axis=1)


# -- fits between models ------------------------------------------------------------


@dataclass(frozen=True)
class DistortionFit:
    """A distortion model fitted to another one over an image.

    Attributes
    ----------
    distortion : Distortion
        The fitted model.
    rms_px, max_px : float
        RMS and maximum distance, in distorted pixels, between where the
        source and the fitted model put the points of the sample grid.
    n_points : int
        Number of grid points the residuals cover.
    """

    distortion: Distortion
    rms_px: float
    max_px: float
    n_points: int


def frame_grid(image_size: tuple[int, int], step_px: float) -> NDArray[np.float64]:
    """Distorted pixels on a regular grid over the frame, edges included."""
    width, height = image_size
    u = np.unique(np.append(np.arange(0.0, width - 1, step_px), width - 1.0))
    v = np.unique(np.append(np.arange(0.0, height - 1, step_px), height - 1.0))
    return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)


def _model_from_vector(model: str, names: tuple[str, ...], vector: NDArray, fit_center: bool) -> Distortion:
    n = len(names)
    center = (float(vector[n]), float(vector[n + 1])) if fit_center else None
    params = dict(zip(names, (float(v) for v in vector[:n])))
    if model == "opencv":
        params.setdefault("k3", 0.0)  # fitted without k3
    return Distortion(model, params, center=center)


def fit_distortion(
    source: Distortion,
    K: ArrayLike,
    image_size: tuple[int, int],
    model: str,
    *,
    fit_center: bool = False,
    with_k3: bool | None = None,
    step_px: float = 16.0,
) -> DistortionFit:
    """Fit a distortion model of another kind to ``source`` over the image.

    Parameters
    ----------
    source : Distortion
        The model to imitate.
    K : array_like, shape (3, 3)
        Camera matrix both models are used with (normalisation, and the
        default division centre).
    image_size : (int, int)
        (width, height) in pixels; the fit covers the whole frame.
    model : str
        Target model: ``division``, ``polynomial``, ``opencv`` or
        ``kannala-brandt``.
    fit_center : bool
        Division target only: fit the distortion centre too (else it is the
        principal point).
    with_k3 : bool, optional
        Polynomial and opencv targets: fit ``k3`` as well (default: no for
        ``polynomial``, yes for ``opencv``; ``False`` with ``opencv`` fits
        ``k1, k2, p1, p2`` with ``k3 = 0``, Kalibr's radtan).
    step_px : float
        Spacing of the sample grid in pixels.

    Returns
    -------
    DistortionFit
        The fitted model with its RMS and max residual in pixels.

    Notes
    -----
    For each distorted pixel ``x_d`` of a grid over the frame, the ideal
    pixel is ``x_u = source.undistort(x_d)``; the fit minimises
    ``sum |target.distort(x_u) - x_d|^2`` (distances in the distorted image,
    where an artist sees them) with ``scipy.optimize.least_squares``,
    started from the linear least-squares solution of the target written
    in the undistorting direction (the division model is linear in
    ``lambda``: ``(x_u - c)(1 + lambda r_d^2) = x_d - c``; the polynomial
    models are linear in their coefficients in normalised coordinates, and
    so is Kannala-Brandt in ``theta_d - theta = k1 theta^3 + ... + k4
    theta^9``). Only the pixels whose ray the source model maps to a
    pinhole pixel (in front of the camera) take part.

    Examples
    --------
    >>> import numpy as np
    >>> K = np.array([[1000.0, 0, 639.5], [0, 1000.0, 359.5], [0, 0, 1]])
    >>> lens = Distortion("polynomial", {"k1": -0.05, "k2": 0.0})
    >>> fit = fit_distortion(lens, K, (1280, 720), "division")
    >>> fit.distortion.params["lambda"] < 0, fit.max_px < 0.5
    (True, True)
    """
    K = np.asarray(K, dtype=np.float64)
    if model not in ("division", "polynomial", "opencv", "kannala-brandt"):
        raise CamcalError(f"cannot fit model {model!r}, expected one of: division, polynomial, opencv, kannala-brandt")
    if fit_center and model != "division":
        raise CamcalError("fit_center applies only to the division model")
    if with_k3 is not None and model == "division":
        raise CamcalError("with_k3 applies only to the polynomial and opencv models")
    if step_px <= 0:
        raise CamcalError(f"step_px must be positive, got {step_px}")
    distorted = frame_grid(image_size, step_px)
    ideal = source.undistort(distorted, K)
    keep = np.all(np.isfinite(ideal), axis=1)
    distorted, ideal = distorted[keep], ideal[keep]
    if len(distorted) < 10:
        raise CamcalError("the source model maps too few pixels of the frame to finite points")

    if model == "division":
        names: tuple[str, ...] = ("lambda",)
        centre = K[:2, 2]
        offset_u, offset_d = ideal - centre, distorted - centre
        r2 = np.sum(offset_d**2, axis=1)
        a = (offset_u * r2[:, None]).ravel()
        b = (offset_d - offset_u).ravel()
        start = np.array([a @ b / (a @ a)]) if a @ a > 0 else np.zeros(1)
        if fit_center:
            start = np.append(start, centre)
    elif model == "kannala-brandt":
        names = MODEL_PARAMS[model][0]
        theta = np.arctan(np.linalg.norm(_pixels_to_normalised(ideal, K), axis=1))
        theta_d = np.linalg.norm(_pixels_to_normalised(distorted, K), axis=1)
        design = np.stack([theta ** (2 * n + 3) for n in range(4)], axis=1)
        start = np.linalg.lstsq(design, theta_d - theta, rcond=None)[0]
    else:
        if model == "polynomial":
            names = ("k1", "k2", "k3") if with_k3 else ("k1", "k2")
        else:
            names = ("k1", "k2", "p1", "p2", "k3") if with_k3 in (None, True) else ("k1", "k2", "p1", "p2")
        xy = _pixels_to_normalised(ideal, K)
        xy_d = _pixels_to_normalised(distorted, K)
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        columns = {
            "k1": np.concatenate([x * r2, y * r2]),
            "k2": np.concatenate([x * r2**2, y * r2**2]),
            "k3": np.concatenate([x * r2**3, y * r2**3]),
            "p1": np.concatenate([2 * x * y, r2 + 2 * y * y]),
            "p2": np.concatenate([r2 + 2 * x * x, 2 * x * y]),
        }
        design = np.stack([columns[name] for name in names], axis=1)
        target = np.concatenate([xy_d[:, 0] - x, xy_d[:, 1] - y])
        start = np.linalg.lstsq(design, target, rcond=None)[0]

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        candidate = _model_from_vector(model, names, vector, fit_center)
        predicted = candidate.distort(ideal, K)
        # beyond the division / Kannala-Brandt model's range: a large finite penalty
        return np.nan_to_num(predicted - distorted, nan=1e6).ravel()

    solution = scipy.optimize.least_squares(residuals, start, x_scale="jac", method="lm", xtol=1e-15, ftol=1e-15)
    fitted = _model_from_vector(model, names, solution.x, fit_center)
    distances = np.linalg.norm(fitted.distort(ideal, K) - distorted, axis=1)
    return DistortionFit(
        distortion=fitted,
        rms_px=float(np.sqrt(np.mean(distances**2))),
        max_px=float(np.max(distances)),
        n_points=int(len(distances)),
    )
