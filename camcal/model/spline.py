"""A smooth correction field over the image: a tensor cubic B-spline displacement, pixels to pixels.

A lens model with a field (:class:`camcal.model.distortion.Distortion` ``field``) projects a ray first
through its parametric model to the pixel ``q0``, then moves it by the field:
``q = q0 + F(q0)``, with

    F(x, y) = sum_{a, b = 0..3} B_a(u) B_b(v) c[j + b, i + a]

on a uniform grid of ``nx x ny`` control displacements ``c`` (pixels) whose spans tile the image:
knot spacing ``hx = (W - 1) / (nx - 3)``, ``hy = (H - 1) / (ny - 3)``, ``x / hx = i + u`` with ``i``
clipped to the spans (a point outside the image extends its edge span's cubic), and the uniform cubic
B-spline basis ``B_0 = (1 - u)^3 / 6``, ``B_1 = (3u^3 - 6u^2 + 4) / 6``, ``B_2 = (-3u^3 + 3u^2 + 3u + 1) / 6``,
``B_3 = u^3 / 6`` (de Boor 1978). Its inverse (:meth:`SplineField.remove`) is Newton on ``q0 + F(q0) = q``.

The field is what a parametric model cannot follow on a real lens (moulded aspheres, decentred
elements, a sensor not flat): the generic models of Schöps et al. (2020) and mrcal's splined
stereographic model (Kogan, mrcal documentation, "splined models") in the same spirit, here as a
correction on top of camcal's best parametric model so that it stays small and the parametric part
keeps its meaning (focal length, principal point) for exports that take the nearest parametric model.

References
----------
de Boor, C. (1978). A Practical Guide to Splines. Springer.
Schöps, T., Larsson, V., Pollefeys, M. & Sattler, T. (2020). Why having 10,000 parameters in your
camera model is better than twelve. CVPR.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError

__all__ = ["SplineField"]

_NEWTON_TOL_PX = 1e-10
_NEWTON_MAX_ITER = 30
#: Fewest control points per axis (one cubic span needs four).
MIN_KNOTS = 4
#: Most control points per axis a rig file may declare.
MAX_KNOTS = 256


def _basis(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Uniform cubic B-spline weights of the four control points of a span, shape (N, 4)."""
    u2, u3 = u * u, u * u * u
    return np.stack([(1 - u) ** 3, 3 * u3 - 6 * u2 + 4, -3 * u3 + 3 * u2 + 3 * u + 1, u3], axis=1) / 6.0


def _basis_slope(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """d(:func:`_basis`)/du, shape (N, 4)."""
    u2 = u * u
    return np.stack([-3 * (1 - u) ** 2, 9 * u2 - 12 * u, -9 * u2 + 6 * u + 3, 3 * u2], axis=1) / 6.0


@dataclass(frozen=True, eq=False)
class SplineField:
    """A displacement field ``F`` (pixels) over a ``W x H`` image; see the module docstring.

    Parameters
    ----------
    image_size : (int, int)
        ``(W, H)`` of the image the knots tile.
    coefficients : array_like, shape (ny, nx, 2)
        Control displacements in pixels, ``nx, ny >= 4``.
    """

    image_size: tuple[int, int]
    coefficients: NDArray[np.float64]

    def __post_init__(self) -> None:
        size = tuple(int(v) for v in self.image_size)
        if len(size) != 2 or min(size) < 2:
            raise CamcalError(f"spline field image size must be two sizes >= 2, got {self.image_size!r}")
        c = np.array(self.coefficients, dtype=np.float64)
        if c.ndim != 3 or c.shape[2] != 2 or not MIN_KNOTS <= min(c.shape[:2]) or max(c.shape[:2]) > MAX_KNOTS:
            raise CamcalError(f"spline field coefficients must have shape (ny, nx, 2) with {MIN_KNOTS} to "
                              f"{MAX_KNOTS} knots per axis, got {c.shape}")
        if not np.all(np.isfinite(c)):
            raise CamcalError("spline field coefficients are not all finite")
        c.setflags(write=False)
        object.__setattr__(self, "image_size", size)
        object.__setattr__(self, "coefficients", c)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, SplineField) and self.image_size == other.image_size
                and np.array_equal(self.coefficients, other.coefficients))

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def zeros(cls, image_size: tuple[int, int], nx: int, ny: int) -> SplineField:
        """The zero field on an ``nx x ny`` grid."""
        return cls(image_size, np.zeros((ny, nx, 2)))

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)`` control points."""
        return self.coefficients.shape[0], self.coefficients.shape[1]

    def _spans(self, points: NDArray[np.float64]):
        ny, nx = self.shape
        W, H = self.image_size
        tx = points[:, 0] / ((W - 1) / (nx - 3))
        ty = points[:, 1] / ((H - 1) / (ny - 3))
        i = np.clip(np.floor(tx), 0, nx - 4).astype(np.int64)
        j = np.clip(np.floor(ty), 0, ny - 4).astype(np.int64)
        return i, tx - i, j, ty - j

    def basis_matrix(self, points: ArrayLike) -> scipy.sparse.csr_matrix:
        """``M`` (N, ny nx) with ``F(points) = M c`` per component (``c`` raveled in (ny, nx) order)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        ny, nx = self.shape
        i, u, j, v = self._spans(points)
        bu, bv = _basis(u), _basis(v)
        rows = np.repeat(np.arange(len(points)), 16)
        cols = ((j[:, None, None] + np.arange(4)[None, :, None]) * nx
                + i[:, None, None] + np.arange(4)[None, None, :]).reshape(-1)
        values = (bv[:, :, None] * bu[:, None, :]).reshape(-1)
        return scipy.sparse.csr_matrix((values, (rows, cols)), shape=(len(points), ny * nx))

    def evaluate(self, points: ArrayLike) -> NDArray[np.float64]:
        """``F(points)``, shape (N, 2); NaN in, NaN out."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        finite = np.all(np.isfinite(points), axis=1)
        out = np.full(points.shape, np.nan)
        matrix = self.basis_matrix(points[finite])
        out[finite] = matrix @ self.coefficients.reshape(-1, 2)
        return out

    def jacobian(self, points: ArrayLike) -> NDArray[np.float64]:
        """``dF/d(x, y)``, shape (N, 2, 2)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        ny, nx = self.shape
        W, H = self.image_size
        i, u, j, v = self._spans(points)
        bu, bv, du, dv = _basis(u), _basis(v), _basis_slope(u), _basis_slope(v)
        jj = j[:, None] + np.arange(4)
        ii = i[:, None] + np.arange(4)
        patch = self.coefficients[jj[:, :, None], ii[:, None, :]]  # (N, 4, 4, 2)
        dx = np.einsum("nb,na,nbac->nc", bv, du, patch) / ((W - 1) / (nx - 3))
        dy = np.einsum("nb,na,nbac->nc", dv, bu, patch) / ((H - 1) / (ny - 3))
        return np.stack([dx, dy], axis=2)

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """``q = q0 + F(q0)``."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return points + self.evaluate(points)

    def remove(self, points: ArrayLike) -> NDArray[np.float64]:
        """``q0`` with ``q0 + F(q0) = q`` (Newton to 1e-10 px; NaN where it does not converge)."""
        target = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        estimate = target - self.evaluate(target)
        for _ in range(_NEWTON_MAX_ITER):
            residual = self.apply(estimate) - target
            if np.all(~(np.abs(residual) >= _NEWTON_TOL_PX)):
                break
            jac = self.jacobian(estimate) + np.eye(2)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                estimate = estimate - np.linalg.solve(jac, np.nan_to_num(residual)[:, :, None])[:, :, 0]
        bad = ~np.all(np.abs(self.apply(estimate) - target) < 1e-6, axis=1)
        estimate[bad] = np.nan
        return estimate

    def rms_px(self, step_px: float = 8.0) -> float:
        """RMS of ``|F|`` over a grid of the image (every ``step_px`` pixels): what the field adds."""
        W, H = self.image_size
        xs, ys = np.meshgrid(np.arange(0.0, W, step_px), np.arange(0.0, H, step_px))
        values = self.evaluate(np.column_stack([xs.ravel(), ys.ravel()]))
        return float(np.sqrt(np.mean(np.sum(values * values, axis=1))))

    def to_dict(self) -> dict:
        """The rig-file form: ``{"image_size": [W, H], "coefficients": [[[dx, dy], ...], ...]}``."""
        return {"image_size": list(self.image_size), "coefficients": self.coefficients.tolist()}

    @classmethod
    def from_dict(cls, data: Mapping) -> SplineField:
        """Inverse of :meth:`to_dict`; unknown keys and sizes past :data:`MAX_KNOTS` are rejected."""
        if not isinstance(data, Mapping):
            raise CamcalError(f"spline field must be an object, got {type(data).__name__}")
        unknown = sorted(set(data) - {"image_size", "coefficients"})
        if unknown or "image_size" not in data or "coefficients" not in data:
            raise CamcalError("spline field needs exactly 'image_size' and 'coefficients'"
                              + (f" (unknown: {', '.join(unknown)})" if unknown else ""))
        size = data["image_size"]
        if (not isinstance(size, (list, tuple)) or len(size) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in size)):
            raise CamcalError(f"spline field 'image_size' must be [W, H] integers, got {size!r}")
        rows = data["coefficients"]
        if not isinstance(rows, list) or not rows or len(rows) > MAX_KNOTS or not all(
                isinstance(row, list) and len(row) <= MAX_KNOTS for row in rows):
            raise CamcalError(f"spline field 'coefficients' must be a (ny, nx, 2) list of at most {MAX_KNOTS}^2 pairs")
        try:
            values = np.array(rows, dtype=np.float64)
        except (TypeError, ValueError):
            raise CamcalError("spline field 'coefficients' must be a (ny, nx, 2) list of numbers") from None
        if not all(math.isfinite(v) for v in values.ravel()):
            raise CamcalError("spline field coefficients are not all finite")
        return cls(tuple(size), values)
