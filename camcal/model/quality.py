"""A camera's fit quality: the typed ``quality`` entry of the rig file.

Every writer (``calibrate dlt``, ``calibrate board``, ``solve``, ...) stores
the same documented keys, with their units in their names::

    "quality": {"rms_px": 0.21, "worst_px": 0.84, "heldout_rms_px": 0.23,
                "n_views": 18, "n_observations": 972, "n_outliers": 0,
                "sigma": {"fx": 0.4, "fy": 0.4, "cx": 0.3, "cy": 0.3, "skew": 0.0,
                          "k1": 1e-4, "lambda": 2e-9,
                          "rotation_deg": 0.01, "baseline_rel": 0.001,
                          "baseline_direction_deg": 0.02},
                "worst_projection_sigma_px": 0.12,
                "covariance": {"names": ["fx", "fy", ..., "gauge_tz"],
                               "matrix": [[...], ...]}}

Keys (every one optional):

- ``rms_px``, ``worst_px``: RMS and largest reprojection error of the fit's
  own observations, in pixels.
- ``heldout_rms_px``: RMS reprojection error on views the fit did not use.
- ``rms_seed_px``: RMS of the seed (e.g. COLMAP's) before camcal refined it.
- ``n_views``, ``n_observations``, ``n_outliers``: images with the target
  (or registered), observed points used, observations dropped as outliers.
- ``sigma``: one-sigma uncertainties from the Jacobian at the solution
  (they measure sampling noise, not model error):

  - intrinsics ``fx``, ``fy``, ``cx``, ``cy``, ``skew`` in pixels;
  - each distortion parameter under its own name (``k1``, ``lambda``...),
    in that parameter's unit;
  - the camera's pose relative to the reference camera: ``rotation_deg``
    (degrees, the rotation's angle), ``baseline_rel`` (sigma of the
    baseline's length over its length, no unit) and
    ``baseline_direction_deg`` (degrees, the baseline's direction).
- ``worst_projection_sigma_px``: the largest, over the frame, worst-direction
  standard deviation of the projection of a ray at infinity (pixels;
  :mod:`camcal.geometry.uncertainty`).
- ``covariance``: what projection uncertainty needs
  (:class:`ParameterCovariance`): the covariance of the camera's
  intrinsics under their sigma names (``fx``, ``fy``, ``cx``, ``cy``, the
  distortion parameters), its pose relative to the reference camera
  (``rx, ry, rz``: rotation vector applied on the left of
  ``cam_from_reference``, radians; ``tx, ty, tz``: translation, rig units)
  and the board gauge (``gauge_rx .. gauge_tz``: the mean perturbation of
  the board poses in the reference camera's frame, mrcal's gauge; a
  ``solve`` rig has none), and the intrinsics and poses of the cameras
  before it in the rig under ``NAME.param`` (the cross-covariance a pair's
  figures use: ``rectify --sigma``). Optional: files written before it
  load without it.

Older files are read too: ``n_points`` is ``n_observations``; sigma ``s``
is ``skew``, ``f`` (one focal length) is ``fx`` and ``fy``, and so is a
covariance row ``f`` (or ``NAME.f``: fully correlated ``fx`` and ``fy``
rows); an absolute
``baseline`` / ``baseline_m`` (in the rig's units) becomes ``baseline_rel``
given the camera's distance to the reference.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["INTRINSIC_SIGMAS", "POSE_SIGMAS", "ParameterCovariance", "Quality"]

#: Sigma keys of the intrinsics, in pixels.
INTRINSIC_SIGMAS = ("fx", "fy", "cx", "cy", "skew")
#: Sigma keys of the pose relative to the reference camera.
POSE_SIGMAS = ("rotation_deg", "baseline_rel", "baseline_direction_deg")

_COUNTS = ("n_views", "n_observations", "n_outliers")


@dataclass(frozen=True)
class ParameterCovariance:
    """A covariance matrix with the name of each of its rows (the ``quality.covariance`` of the rig file).

    Attributes
    ----------
    names : tuple of str
        One distinct name per row (see the module docstring).
    matrix : tuple of tuple of float
        Symmetric, finite, non-negative diagonal; :attr:`array` is it as an ndarray.

    Examples
    --------
    >>> c = ParameterCovariance.from_dict({"names": ["fx", "cx"], "matrix": [[0.25, 0.0], [0.0, 0.04]]})
    >>> float(c.array[1, 1]), c.to_dict()["names"]
    (0.04, ['fx', 'cx'])
    """

    names: tuple[str, ...]
    matrix: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        names = tuple(self.names)
        if not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
            raise CamcalError(f"quality.covariance.names must be distinct non-empty strings, got {list(names)!r}")
        try:
            array = np.array(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise CamcalError("quality.covariance.matrix must be a square array of numbers") from None
        if array.shape != (len(names), len(names)):
            raise CamcalError(f"quality.covariance.matrix must be {len(names)}x{len(names)} (one row per name), "
                              f"got shape {'x'.join(map(str, array.shape)) or 'a scalar'}")
        if not np.all(np.isfinite(array)):
            raise CamcalError("quality.covariance.matrix contains NaN or infinite values")
        scale = max(float(np.max(np.abs(array))), 1e-300) if array.size else 1.0
        if not np.allclose(array, array.T, rtol=1e-9, atol=1e-12 * scale) or np.any(np.diag(array) < 0):
            raise CamcalError("quality.covariance.matrix must be symmetric with a non-negative diagonal")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "matrix", tuple(tuple(float(v) for v in row) for row in array))

    @property
    def array(self) -> np.ndarray:
        """The matrix as a (P, P) float64 array."""
        return np.array(self.matrix, dtype=np.float64).reshape(len(self.names), len(self.names))

    def to_dict(self) -> dict[str, Any]:
        """``{"names": [...], "matrix": [[...], ...]}``."""
        return {"names": list(self.names), "matrix": [list(row) for row in self.matrix]}

    @classmethod
    def from_dict(cls, data: Any) -> ParameterCovariance:
        """Read ``quality.covariance``; a :class:`ParameterCovariance` is returned as is."""
        if isinstance(data, ParameterCovariance):
            return data
        if not isinstance(data, Mapping) or set(data) != {"names", "matrix"}:
            raise CamcalError("quality.covariance must be an object with exactly 'names' and 'matrix'")
        if not isinstance(data["names"], (list, tuple)):
            raise CamcalError(f"quality.covariance.names must be a list of strings, got {data['names']!r}")
        return _split_focal(cls(tuple(data["names"]), data["matrix"]))


def _split_focal(covariance: ParameterCovariance) -> ParameterCovariance:
    """One focal length ``f`` (or ``NAME.f``) as ``fx`` and ``fy``, fully correlated (``fx = fy = f``).

    ``x = A f`` with ``A`` duplicating the row: ``Sigma' = A Sigma A^T``.
    """
    names = list(covariance.names)
    if not any(name == "f" or name.endswith(".f") for name in names):
        return covariance
    source, out = [], []
    for index, name in enumerate(names):
        if name == "f" or name.endswith(".f"):
            stem = name[:-1]
            for axis in ("fx", "fy"):
                if stem + axis in names:
                    raise CamcalError(f"quality.covariance.names has both {name!r} and {stem + axis!r}")
                source.append(index)
                out.append(stem + axis)
        else:
            source.append(index)
            out.append(name)
    array = covariance.array[np.ix_(source, source)]
    return ParameterCovariance(tuple(out), array)


_LEGACY_TOP = {"n_points": "n_observations"}


@dataclass(frozen=True)
class Quality(Mapping):
    """Fit quality of one camera (see the module docstring for keys and units).

    A read-only mapping of its file form too (``quality["rms_px"]``,
    ``quality["sigma"]["fx"]``), so code reading the rig file's dict works
    unchanged; ``Quality()`` is empty (falsy).

    Examples
    --------
    >>> q = Quality(rms_px=0.21, n_views=18, sigma={"fx": 0.4, "rotation_deg": 0.01})
    >>> q["sigma"]["fx"], q.to_dict()["n_views"]
    (0.4, 18)
    >>> Quality.from_dict({"rms_px": 0.3, "n_points": 40, "sigma": {"f": 0.5}}).to_dict()
    {'rms_px': 0.3, 'n_observations': 40, 'sigma': {'fx': 0.5, 'fy': 0.5}}
    """

    rms_px: float | None = None
    worst_px: float | None = None
    heldout_rms_px: float | None = None
    rms_seed_px: float | None = None
    n_views: int | None = None
    n_observations: int | None = None
    n_outliers: int | None = None
    sigma: Mapping[str, float] = field(default_factory=dict)
    worst_projection_sigma_px: float | None = None
    covariance: ParameterCovariance | None = None

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "sigma" or value is None:
                continue
            if item.name == "covariance":
                object.__setattr__(self, "covariance", ParameterCovariance.from_dict(value))
                continue
            if item.name in _COUNTS:
                if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                    raise CamcalError(f"quality.{item.name} must be a count (integer >= 0), got {value!r}")
                object.__setattr__(self, item.name, int(value))
            else:
                object.__setattr__(self, item.name, _non_negative(value, f"quality.{item.name}"))
        if not isinstance(self.sigma, Mapping):
            raise CamcalError(f"quality.sigma must be an object of numbers, got {self.sigma!r}")
        sigma = {str(k): _non_negative(v, f"quality.sigma.{k}") for k, v in self.sigma.items()}
        object.__setattr__(self, "sigma", MappingProxyType(sigma))

    # -- file boundary ----------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The rig file's ``quality`` object (keys that are set, in documented order)."""
        out: dict[str, Any] = {}
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "sigma":
                if value:
                    out["sigma"] = dict(value)
            elif item.name == "covariance":
                if value is not None:
                    out["covariance"] = value.to_dict()
            elif value is not None:
                out[item.name] = value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], baseline_length: float | None = None) -> Quality:
        """Read a rig file's ``quality`` object, older key names included.

        Parameters
        ----------
        data : mapping
            The ``quality`` object.
        baseline_length : float, optional
            The camera's distance to the reference camera (rig units): turns an
            older absolute ``baseline`` sigma into ``baseline_rel``.

        Raises
        ------
        CamcalError
            An unknown key or a value that is not a finite number >= 0.
        """
        if isinstance(data, Quality):
            return data
        if not isinstance(data, Mapping):
            raise CamcalError(f"quality must be an object, got {type(data).__name__}")
        known = {item.name for item in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            key = _LEGACY_TOP.get(key, key)
            if key not in known:
                raise CamcalError(f"quality has unknown key {key!r}, expected some of: {', '.join(sorted(known))}")
            values[key] = value
        if "sigma" in values:
            values["sigma"] = _modern_sigma(values["sigma"], baseline_length)
        return cls(**values)

    # -- read-only mapping of the file form ---------------------------------------------

    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())

    __hash__ = None  # type: ignore[assignment]


def _non_negative(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CamcalError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or value < 0:
        raise CamcalError(f"{name} must be a finite number >= 0, got {value}")
    return value


def _modern_sigma(sigma: Any, baseline_length: float | None) -> dict[str, Any]:
    """Older sigma keys under their documented names."""
    if not isinstance(sigma, Mapping):
        raise CamcalError(f"quality.sigma must be an object of numbers, got {sigma!r}")
    out: dict[str, Any] = {}
    for key, value in sigma.items():
        if key == "s":
            out["skew"] = value
        elif key == "f":
            out.setdefault("fx", value)
            out.setdefault("fy", value)
        elif key in ("baseline", "baseline_m"):
            if baseline_length and baseline_length > 0 and isinstance(value, (int, float)):
                out["baseline_rel"] = value / baseline_length
        else:
            out[key] = value
    return out
