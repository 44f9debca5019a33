"""Field checks shared by the rig file's objects (:mod:`camcal.model.rig`, :mod:`camcal.model.rig_frames`).

Each check raises :class:`~camcal.base.errors.CamcalError` with one message
naming the bad field; :class:`DictEquality` gives the rig's objects equality
through their file form.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.limits import check_image_size

__all__ = ["DictEquality", "as_matrix", "check_K", "check_keys", "check_plausible", "check_rotation", "image_size_field"]

_ORTHONORMAL_TOL = 1e-6
#: Focal lengths (and skew) are plausible within this factor of the larger image side, either way.
_FOCAL_RANGE = 1000.0
#: Principal points are plausible up to this many image sizes beyond the image's edges (generous: a diverged
#: calibration, written with ``--force`` past the quality gate, has had one 2.5 widths off the image).
_PP_MARGIN = 10.0


def as_matrix(value: Any, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    """A read-only float64 copy of ``value`` with the given shape, all finite."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CamcalError(f"{name} must be a {'x'.join(map(str, shape))} array of numbers") from None
    if array.shape != shape:
        raise CamcalError(f"{name} must have shape {'x'.join(map(str, shape))}, got {'x'.join(map(str, array.shape)) or 'a scalar'}")
    if not np.all(np.isfinite(array)):
        raise CamcalError(f"{name} contains NaN or infinite values")
    array.setflags(write=False)
    return array


def check_K(K: NDArray[np.float64], name: str) -> None:
    """``K`` is ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with positive focal lengths."""
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0:
        raise CamcalError(f"{name} must be upper triangular ([[fx, s, cx], [0, fy, cy], [0, 0, 1]])")
    if K[2, 2] != 1.0:
        raise CamcalError(f"{name}[2][2] must be 1, got {float(K[2, 2])!r}")  # numpy 2 reprs np.float64(x)
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise CamcalError(f"{name} must have positive fx and fy, got fx={float(K[0, 0])!r}, fy={float(K[1, 1])!r}")


def check_plausible(K: NDArray[np.float64], image_size: tuple[int, int], name: str) -> None:
    """A focal length and skew within a generous multiple of the image, a principal point near it."""
    width, height = image_size
    largest = max(width, height)
    low, high = largest / _FOCAL_RANGE, largest * _FOCAL_RANGE
    for label, value in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if not low <= value <= high:
            raise CamcalError(f"{name}: {label} = {float(value)!r} is not a plausible focal length for a "
                              f"{width}x{height} image (expected {low:.6g} <= {label} <= {high:.6g})")
    if abs(K[0, 1]) > high:
        raise CamcalError(f"{name}: skew = {float(K[0, 1])!r} is not plausible for a {width}x{height} image "
                          f"(expected |skew| <= {high:.6g})")
    for label, value, side in (("cx", K[0, 2], width), ("cy", K[1, 2], height)):
        if not -_PP_MARGIN * side <= value <= (1 + _PP_MARGIN) * side:
            raise CamcalError(f"{name}: {label} = {float(value)!r} is not a plausible principal point for a "
                              f"{width}x{height} image (expected {-_PP_MARGIN * side:.6g} <= {label} <= "
                              f"{(1 + _PP_MARGIN) * side:.6g})")


def check_rotation(R: NDArray[np.float64], name: str) -> None:
    """``R`` is orthonormal (to 1e-6) with determinant +1."""
    error = np.abs(R.T @ R - np.eye(3)).max()
    if error > _ORTHONORMAL_TOL:
        raise CamcalError(f"{name} is not orthonormal (max |R^T R - I| = {error:.3g})")
    if np.linalg.det(R) < 0:
        raise CamcalError(f"{name} has determinant -1 (a reflection, not a rotation)")


def image_size_field(value: Any, name: str) -> tuple[int, int]:
    """``[width, height]``, two positive integers within the pixel cap (:data:`camcal.base.limits.IMAGE_PIXELS`)."""
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 2
        or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in value)
    ):
        raise CamcalError(f"{name} must be [width, height] as two positive integers, got {value!r:.80}")
    width, height = int(value[0]), int(value[1])
    check_image_size(width, height, f"{name} declares")
    return width, height


def check_keys(data: Any, name: str, required: Iterable[str], optional: Iterable[str] = ()) -> None:
    """``data`` is a mapping with every ``required`` key and no key beyond ``required`` and ``optional``."""
    if not isinstance(data, Mapping):
        raise CamcalError(f"{name} must be an object, got {type(data).__name__}")
    required = tuple(required)
    for key in required:
        if key not in data:
            raise CamcalError(f"{name} is missing key '{key}'")
    unknown = sorted(set(data) - set(required) - set(optional))
    if unknown:
        raise CamcalError(f"{name} has unknown key(s): {', '.join(map(str, unknown))}")


class DictEquality:
    """Equality through the file form: two objects are equal when their files are."""

    def to_dict(self) -> dict:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]
