"""The lens profile file (``*.profile.json``): one lens calibrated at several states, and its smooth surfaces.

A zoom or refocused lens changes its focal length, principal point and
distortion with the lens state (focal length in mm, focus distance in m).
A profile holds every state calibrated (its parameters, their covariance,
image count and RMS) and, for each parameter, a low-order polynomial
surface over the state (:class:`Surface`)::

    {
      "camcal_lens_profile": 1,
      "model": "polynomial",                 lens model of every state
      "image_size": [1920, 1080],
      "board": "chessboard:9x6:0.03",
      "parameters": ["fx", "fy", "cx", "cy", "k1", "k2"],
      "states": [{"label": "24mm@1.2m", "focal_mm": 24, "focus_m": 1.2, "params": {...}, "sigma": {...},
                  "covariance": [[...]], "n_images": 12, "rms_px": 0.21}, ...],
      "surfaces": {"fx": {"terms": [[0, 0], [1, 0]], "coefficients": [...], "scale": 1.0,
                          "loso_rms": 0.8}, ...},
      "provenance": {...}
    }

``focus_m`` is a distance in metres or ``"inf"`` (focused at infinity).
The surfaces are polynomials in the state's normalised coordinates
(:func:`state_coordinates`): the focal length and the focus *vergence*
``1 / focus`` (dioptres; infinity is 0), each mapped linearly onto
``[-1, 1]`` over the calibrated range. A term ``[i, j]`` is
``u^i v^j``. The fitting and the uncertainty are
:mod:`camcal.geometry.lens_profile`; this module is the data and its file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.jsonfile import dumps, read_json
from camcal.base.schema import schema_errors
from camcal.model.distortion import MODEL_PARAMS

__all__ = ["INTRINSIC_NAMES", "PROFILE_SCHEMA", "PROFILE_VERSION", "LensProfile", "LensState", "Surface",
           "format_state", "parse_state", "state_coordinates"]

PROFILE_VERSION = 1
#: The pinhole parameters every profile holds, before the lens model's.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")

_NUMBER = {"type": "number"}
_FOCUS = {"oneOf": [{"type": "number", "exclusiveMinimum": 0}, {"const": "inf"}]}
_NUMBERS = {"type": "object", "additionalProperties": _NUMBER}
#: The profile file's JSON Schema (checked by :meth:`LensProfile.from_dict` before its own checks).
PROFILE_SCHEMA: Mapping[str, Any] = MappingProxyType({
    "type": "object",
    "required": ["camcal_lens_profile", "model", "image_size", "board", "parameters", "states", "surfaces"],
    "additionalProperties": False,
    "properties": {
        "camcal_lens_profile": {"const": PROFILE_VERSION},
        "model": {"enum": list(MODEL_PARAMS)},
        "image_size": {"type": "array", "prefixItems": [{"type": "integer", "minimum": 1}] * 2, "minItems": 2,
                       "maxItems": 2},
        "board": {"type": "string"},
        "parameters": {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 4},
        "states": {"type": "array", "minItems": 2, "items": {
            "type": "object", "additionalProperties": False,
            "required": ["label", "focal_mm", "focus_m", "params", "sigma", "n_images", "rms_px"],
            "properties": {
                "label": {"type": "string", "minLength": 1},
                "focal_mm": {"type": "number", "exclusiveMinimum": 0},
                "focus_m": _FOCUS,
                "params": _NUMBERS, "sigma": _NUMBERS,
                "covariance": {"type": "array", "items": {"type": "array", "items": _NUMBER}},
                "n_images": {"type": "integer", "minimum": 0},
                "rms_px": {"type": "number", "minimum": 0},
            }}},
        "surfaces": {"type": "object", "additionalProperties": {
            "type": "object", "additionalProperties": False,
            "required": ["terms", "coefficients", "scale"],
            "properties": {
                "terms": {"type": "array", "minItems": 1, "items": {
                    "type": "array", "prefixItems": [{"type": "integer", "minimum": 0}] * 2, "minItems": 2,
                    "maxItems": 2}},
                "coefficients": {"type": "array", "minItems": 1, "items": _NUMBER},
                "scale": {"type": "number", "minimum": 1},
                "loso_rms": {"type": ["number", "null"], "minimum": 0},
            }}},
        "provenance": {"type": "object"},
    },
})

_STATE = re.compile(r"^\s*(?P<focal>[0-9.eE+-]+)\s*(mm)?\s*@\s*(?:(?P<inf>inf(inity)?)|(?P<focus>[0-9.eE+-]+)\s*"
                    r"(?P<unit>mm|cm|m)?)\s*$", re.IGNORECASE)
_UNIT_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, None: 1.0}


def parse_state(text: str) -> tuple[float, float]:
    """``(focal_mm, focus_m)`` of a lens state written ``24mm@1.2m`` (``35@2.5``, ``50mm@120cm``, ``85mm@inf``).

    Raises
    ------
    CamcalError
        Not of that form, or a focal length or focus distance that is not positive.
    """
    match = _STATE.match(text)
    example = "e.g. 24mm@1.2m, 35mm@120cm or 50mm@inf"
    if match is None:
        raise CamcalError(f"lens state {text!r}: expected FOCALmm@FOCUSm ({example})")
    try:
        focal = float(match["focal"])
        focus = math.inf if match["inf"] else float(match["focus"]) * _UNIT_M[(match["unit"] or "m").lower()]
    except ValueError:
        raise CamcalError(f"lens state {text!r}: expected FOCALmm@FOCUSm ({example})") from None
    if not (math.isfinite(focal) and focal > 0 and focus > 0 and not math.isnan(focus)):
        raise CamcalError(f"lens state {text!r}: the focal length and the focus distance must be positive")
    return focal, focus


def format_state(focal_mm: float, focus_m: float) -> str:
    """``24mm@1.2m`` (``@inf`` at infinity): the label :func:`parse_state` reads back."""
    return f"{focal_mm:g}mm@" + ("inf" if math.isinf(focus_m) else f"{focus_m:g}m")


def state_coordinates(focal_mm: NDArray | float, focus_m: NDArray | float, focal_range: tuple[float, float],
                      vergence_range: tuple[float, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The surfaces' coordinates ``(u, v)`` of lens states: focal length and ``1 / focus`` on ``[-1, 1]``.

    ``u = (2 f - f_min - f_max) / (f_max - f_min)`` and the same for the
    vergence ``1 / focus`` (dioptres, 0 at infinity) over its range; a
    range of one value maps to 0.
    """
    def unit(value: NDArray, low: float, high: float) -> NDArray[np.float64]:
        return np.zeros_like(value) if high <= low else (2.0 * value - low - high) / (high - low)

    focal = np.asarray(focal_mm, dtype=np.float64)
    vergence = 1.0 / np.asarray(focus_m, dtype=np.float64)
    return unit(focal, *focal_range), unit(vergence, *vergence_range)


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise CamcalError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise CamcalError(f"{name} is not finite ({value})")
    return float(value)


@dataclass(frozen=True, eq=False)
class LensState:
    """One calibrated lens state.

    Attributes
    ----------
    label : str
        As given (``24mm@1.2m``).
    focal_mm, focus_m : float
        The state; ``focus_m`` may be ``math.inf``.
    params : mapping of str to float
        Every parameter of the profile (``fx fy cx cy`` in pixels, then the lens model's).
    covariance : ndarray, shape (P, P)
        The parameters' covariance in the order of the profile's ``parameters`` (from the board
        calibration's Jacobian; diagonal when only the sigmas are known).
    n_images : int
    rms_px : float
        The state's calibration RMS reprojection error.
    """

    label: str
    focal_mm: float
    focus_m: float
    params: Mapping[str, float]
    covariance: NDArray[np.float64]
    n_images: int
    rms_px: float

    @property
    def sigma(self) -> dict[str, float]:
        """One-sigma of each parameter (the covariance's diagonal)."""
        return {name: float(math.sqrt(max(v, 0.0))) for name, v in zip(self.params, np.diag(self.covariance))}

    @property
    def vergence(self) -> float:
        """``1 / focus_m`` in dioptres (0 at infinity)."""
        return 1.0 / self.focus_m

    def to_dict(self) -> dict:
        return {"label": self.label, "focal_mm": self.focal_mm,
                "focus_m": "inf" if math.isinf(self.focus_m) else self.focus_m, "params": dict(self.params),
                "sigma": self.sigma, "covariance": self.covariance.tolist(), "n_images": self.n_images,
                "rms_px": self.rms_px}


@dataclass(frozen=True, eq=False)
class Surface:
    """One parameter as a polynomial over the lens state.

    Attributes
    ----------
    terms : tuple of (int, int)
        ``(i, j)``: the term ``u^i v^j`` (:func:`state_coordinates`).
    coefficients : ndarray, shape (T,)
    scale : float
        The factor (>= 1) the propagated sigma is multiplied by: the root mean
        square of the leave-one-state-out residuals over their sigmas, when above 1.
    loso_rms : float or None
        RMS of the leave-one-state-out residuals, in the parameter's units (None with two states).
    """

    terms: tuple[tuple[int, int], ...]
    coefficients: NDArray[np.float64]
    scale: float = 1.0
    loso_rms: float | None = None

    def design(self, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """The design matrix ``[u^i v^j]``, shape ``(N, T)``."""
        u, v = np.atleast_1d(u), np.atleast_1d(v)
        return np.column_stack([u**i * v**j for i, j in self.terms])

    def describe(self) -> str:
        """``focal^2 x focus^1`` (the highest power of each)."""
        return f"focal^{max(i for i, _ in self.terms)} x 1/focus^{max(j for _, j in self.terms)}"

    def to_dict(self) -> dict:
        return {"terms": [list(t) for t in self.terms], "coefficients": self.coefficients.tolist(),
                "scale": self.scale, "loso_rms": self.loso_rms}


@dataclass(frozen=True, eq=False)
class LensProfile:
    """One lens over its states: the states calibrated and a :class:`Surface` per parameter.

    Attributes
    ----------
    model : str
        The lens model of every state (:data:`camcal.model.distortion.MODEL_PARAMS`).
    image_size : (int, int)
    board : str
        The board spec every state was calibrated with.
    parameters : tuple of str
        ``fx fy cx cy`` and the lens model's parameters, the order of every covariance.
    states : tuple of LensState
        Sorted by focal length, then focus distance.
    surfaces : mapping of str to Surface
        One per parameter.
    provenance : mapping
    """

    model: str
    image_size: tuple[int, int]
    board: str
    parameters: tuple[str, ...]
    states: tuple[LensState, ...]
    surfaces: Mapping[str, Surface]
    provenance: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.model not in MODEL_PARAMS:
            raise CamcalError(f"unknown lens model {self.model!r}")
        if tuple(self.parameters[:4]) != INTRINSIC_NAMES:
            raise CamcalError(f"a profile's parameters start with {', '.join(INTRINSIC_NAMES)}, got "
                              f"{', '.join(self.parameters[:4])}")
        required, optional = MODEL_PARAMS[self.model]
        lens = self.parameters[4:]
        unknown = [name for name in lens if name not in required + optional]
        missing = [name for name in required if name not in lens]
        if unknown or missing or len(set(lens)) != len(lens):
            raise CamcalError(f"a {self.model} profile's lens parameters are {', '.join(required + optional)} "
                              f"(needs {', '.join(required) or 'none'}), got {', '.join(lens) or 'none'}")
        if len(self.states) < 2:
            raise CamcalError(f"a lens profile needs at least 2 states, got {len(self.states)}")
        keys = [(s.focal_mm, s.focus_m) for s in self.states]
        duplicates = sorted({s.label for s, key in zip(self.states, keys) if keys.count(key) > 1})
        if duplicates:
            raise CamcalError(f"duplicate lens states: {', '.join(duplicates)} (one calibration per state)")
        size = len(self.parameters)
        for state in self.states:
            if list(state.params) != list(self.parameters):
                raise CamcalError(f"state {state.label}: its parameters {', '.join(state.params)} are not the "
                                  f"profile's {', '.join(self.parameters)}")
            if state.covariance.shape != (size, size) or not np.all(np.isfinite(state.covariance)):
                raise CamcalError(f"state {state.label}: its covariance must be a finite {size}x{size} matrix")
        if set(self.surfaces) != set(self.parameters):
            raise CamcalError(f"the profile needs one surface per parameter ({', '.join(self.parameters)}), got "
                              f"{', '.join(self.surfaces) or 'none'}")
        for name, surface in self.surfaces.items():
            if len(surface.terms) != len(surface.coefficients) or not np.all(np.isfinite(surface.coefficients)):
                raise CamcalError(f"surface {name}: one finite coefficient per term")
        object.__setattr__(self, "states", tuple(sorted(self.states, key=lambda s: (s.focal_mm, s.focus_m))))

    @property
    def focal_range(self) -> tuple[float, float]:
        """Smallest and largest focal length calibrated, in mm."""
        focals = [s.focal_mm for s in self.states]
        return min(focals), max(focals)

    @property
    def focus_range(self) -> tuple[float, float]:
        """Nearest and farthest focus distance calibrated, in m (``inf`` possible)."""
        focuses = [s.focus_m for s in self.states]
        return min(focuses), max(focuses)

    @property
    def vergence_range(self) -> tuple[float, float]:
        """Smallest and largest ``1 / focus`` calibrated, in dioptres."""
        near, far = self.focus_range
        return 1.0 / far, 1.0 / near

    def from_encoders(self, focal: NDArray | float, focus: NDArray | float
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lens states ``(focal_mm, focus_m)`` of encoder values from 0 to 1 over the calibrated ranges.

        OpenTrackIO's normalised encoders: zoom from the shortest focal length
        (0) to the longest (1), linearly; focus from the farthest focus (0,
        infinity when calibrated there) to the nearest (1), linearly in the
        vergence ``1 / focus``.
        """
        (f_low, f_high), (v_low, v_high) = self.focal_range, self.vergence_range
        focal_mm = f_low + np.asarray(focal, dtype=np.float64) * (f_high - f_low)
        vergence = v_low + np.asarray(focus, dtype=np.float64) * (v_high - v_low)
        with np.errstate(divide="ignore"):
            return focal_mm, np.where(vergence > 0, 1.0 / np.where(vergence > 0, vergence, 1.0), np.inf)

    def coordinates(self, focal_mm: NDArray | float, focus_m: NDArray | float
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The surfaces' ``(u, v)`` of lens states (:func:`state_coordinates` over this profile's ranges)."""
        return state_coordinates(focal_mm, focus_m, self.focal_range, self.vergence_range)

    def to_dict(self) -> dict:
        return {"camcal_lens_profile": PROFILE_VERSION, "model": self.model, "image_size": list(self.image_size),
                "board": self.board, "parameters": list(self.parameters),
                "states": [state.to_dict() for state in self.states],
                "surfaces": {name: self.surfaces[name].to_dict() for name in self.parameters},
                "provenance": dict(self.provenance)}

    @classmethod
    def from_dict(cls, data: Any) -> LensProfile:
        """Inverse of :meth:`to_dict`, checked against :data:`PROFILE_SCHEMA` and then for consistency."""
        errors = schema_errors(data, PROFILE_SCHEMA)
        if errors:
            raise CamcalError(f"not a lens profile: {errors[0]}" + (f" (and {len(errors) - 1} more)"
                                                                    if len(errors) > 1 else ""))
        parameters = tuple(data["parameters"])
        states = []
        for entry in data["states"]:
            label = entry["label"]
            if list(entry["params"]) != list(parameters):
                raise CamcalError(f"state {label}: its params are not the profile's {', '.join(parameters)}")
            params = {name: _number(entry["params"][name], f"state {label}: {name}") for name in parameters}
            if "covariance" in entry:
                covariance = np.array(entry["covariance"], dtype=np.float64)
            else:
                sigma = [_number(entry["sigma"].get(name, math.nan), f"state {label}: sigma {name}")
                         for name in parameters]
                covariance = np.diag(np.square(sigma))
            focus = math.inf if entry["focus_m"] == "inf" else float(entry["focus_m"])
            states.append(LensState(label, float(entry["focal_mm"]), focus, params, covariance,
                                    int(entry["n_images"]), float(entry["rms_px"])))
        surfaces = {name: Surface(tuple((int(i), int(j)) for i, j in surface["terms"]),
                                  np.array(surface["coefficients"], dtype=np.float64), float(surface["scale"]),
                                  surface.get("loso_rms"))
                    for name, surface in data["surfaces"].items()}
        return cls(data["model"], (int(data["image_size"][0]), int(data["image_size"][1])), data["board"],
                   parameters, tuple(states), surfaces, data.get("provenance") or {})

    @classmethod
    def load(cls, path: str | os.PathLike) -> LensProfile:
        """Read and validate a ``*.profile.json``; errors are one line starting with the file name."""
        data = read_json(path, "lens profile")
        try:
            return cls.from_dict(data)
        except CamcalError as error:
            raise CamcalError(f"{path}: {error}") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the profile atomically and return its path."""
        path = Path(path)
        atomic_write_text(path, dumps(self.to_dict()))
        return path

