"""A moving rig's frames: its pose at each frame and, for a zoom or a refocus, each camera's lens there.

File form of one entry of a rig file's ``frames`` (:mod:`camcal.model.rig`)::

    {"index": 12, "R": [[...]], "c": [...],
     "images": {"cam": "plate.0012.exr"},                       (optional)
     "lenses": {"cam": {"K": [[...]], "distortion": {...},       (optional)
                        "focal_mm": 32.0, "focus_m": 2.5}},
     "rolling_shutter": {"cam": {"displacement_px": 2.4,          (optional)
                                 "flagged": true}}}

A camera named in ``lenses`` has that lens (``K`` and distortion) at that
frame; a camera absent keeps its own. ``focal_mm`` and ``focus_m`` record
the lens state the lens came from (a zoom's focal length in mm, the focus
distance in m); no mapping uses them. A camera named in ``rolling_shutter``
was checked for a rolling shutter's effect at that frame (``solve
--readout-ms``, :mod:`camcal.geometry.rolling_shutter`): the largest image
displacement of its points between their row's time and the frame's, and
whether it passed the solve's threshold.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.model.rig_fields import DictEquality, as_matrix, check_K, check_keys, check_rotation

__all__ = ["Frame", "Lens", "ShutterCheck"]


def _lens_state(value: Any, name: str) -> float | None:
    """``None`` or a positive finite number as a float."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise CamcalError(f"{name} must be a positive number, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)
class Lens(DictEquality):
    """A camera's lens at one frame: intrinsics, distortion and the lens state they belong to.

    Parameters
    ----------
    K : array_like, shape (3, 3)
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels of the camera's
        image, pixel (0, 0) at the centre of the top-left pixel.
    distortion : Distortion
        Maps undistorted pixels to distorted pixels; the same model as the
        camera's (checked by the rig).
    focal_mm : float, optional
        The lens's focal length setting in mm (a zoom's state), recorded only.
    focus_m : float, optional
        The focus distance in m, recorded only.
    """

    K: NDArray[np.float64]
    distortion: Distortion
    focal_mm: float | None = None
    focus_m: float | None = None

    def __post_init__(self) -> None:
        K = as_matrix(self.K, (3, 3), "K")
        check_K(K, "K")
        object.__setattr__(self, "K", K)
        if not isinstance(self.distortion, Distortion):
            raise CamcalError(f"distortion must be a Distortion, got {type(self.distortion).__name__}")
        object.__setattr__(self, "focal_mm", _lens_state(self.focal_mm, "focal_mm"))
        object.__setattr__(self, "focus_m", _lens_state(self.focus_m, "focus_m"))

    def to_dict(self) -> dict:
        """The lens's entry in a frame's ``lenses`` (``focal_mm`` / ``focus_m`` omitted when unknown)."""
        out: dict = {"K": self.K.tolist(), "distortion": self.distortion.to_dict()}
        if self.focal_mm is not None:
            out["focal_mm"] = self.focal_mm
        if self.focus_m is not None:
            out["focus_m"] = self.focus_m
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> Lens:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        check_keys(data, "lens", ("K", "distortion"), ("focal_mm", "focus_m"))
        return cls(data["K"], Distortion.from_dict(data["distortion"]), data.get("focal_mm"), data.get("focus_m"))


@dataclass(frozen=True, eq=False)
class ShutterCheck(DictEquality):
    """A rolling shutter's effect on one camera at one frame.

    Parameters
    ----------
    displacement_px : float
        The largest image displacement of the frame's points between their
        row's readout time and the frame's time, in pixels (>= 0).
    flagged : bool
        Whether it passed the threshold the solve was given.
    """

    displacement_px: float
    flagged: bool

    def __post_init__(self) -> None:
        value = self.displacement_px
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or value < 0:
            raise CamcalError(f"displacement_px must be a number >= 0, got {value!r}")
        object.__setattr__(self, "displacement_px", float(value))
        if not isinstance(self.flagged, (bool, np.bool_)):
            raise CamcalError(f"flagged must be true or false, got {self.flagged!r}")
        object.__setattr__(self, "flagged", bool(self.flagged))

    def to_dict(self) -> dict:
        """The entry in a frame's ``rolling_shutter``."""
        return {"displacement_px": self.displacement_px, "flagged": self.flagged}

    @classmethod
    def from_dict(cls, data: Mapping) -> ShutterCheck:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        check_keys(data, "rolling_shutter entry", ("displacement_px", "flagged"), ())
        return cls(data["displacement_px"], data["flagged"])


@dataclass(frozen=True, eq=False)
class Frame(DictEquality):
    """The rig's pose at one frame of a sequence (``rig_from_world``), its images and lenses.

    Parameters
    ----------
    index : int
        Frame number.
    R : array_like, shape (3, 3)
        Rotation world -> rig.
    c : array_like, shape (3,)
        Rig origin in world coordinates.
    images : mapping of str to str
        Camera name -> image path (relative to the rig file).
    lenses : mapping of str to Lens
        Camera name -> that camera's lens at this frame; cameras absent keep
        their own (:meth:`camcal.model.rig.Rig.camera_at_frame`).
    rolling_shutter : mapping of str to ShutterCheck
        Camera name -> the rolling shutter's effect on it at this frame (only
        when a solve was given a readout time).
    """

    index: int
    R: NDArray[np.float64]
    c: NDArray[np.float64]
    images: Mapping[str, str] = field(default_factory=dict)
    lenses: Mapping[str, Lens] = field(default_factory=dict)
    rolling_shutter: Mapping[str, ShutterCheck] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)):
            raise CamcalError(f"frame index must be an integer, got {self.index!r}")
        object.__setattr__(self, "index", int(self.index))
        R = as_matrix(self.R, (3, 3), "R")
        check_rotation(R, "R")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", as_matrix(self.c, (3,), "c"))
        if not isinstance(self.images, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.images.items()
        ):
            raise CamcalError("frame images must map camera names to path strings")
        object.__setattr__(self, "images", MappingProxyType(dict(self.images)))
        if not isinstance(self.lenses, Mapping) or not all(
            isinstance(k, str) and isinstance(v, Lens) for k, v in self.lenses.items()
        ):
            raise CamcalError("frame lenses must map camera names to Lens objects")
        object.__setattr__(self, "lenses", MappingProxyType(dict(self.lenses)))
        if not isinstance(self.rolling_shutter, Mapping) or not all(
            isinstance(k, str) and isinstance(v, ShutterCheck) for k, v in self.rolling_shutter.items()
        ):
            raise CamcalError("frame rolling_shutter must map camera names to ShutterCheck objects")
        object.__setattr__(self, "rolling_shutter", MappingProxyType(dict(self.rolling_shutter)))

    def to_dict(self) -> dict:
        """The frame's entry in the rig file (``images``, ``lenses`` and ``rolling_shutter`` omitted when empty)."""
        out: dict = {"index": self.index, "R": self.R.tolist(), "c": self.c.tolist()}
        if self.images:
            out["images"] = dict(self.images)
        if self.lenses:
            out["lenses"] = {name: lens.to_dict() for name, lens in self.lenses.items()}
        if self.rolling_shutter:
            out["rolling_shutter"] = {name: check.to_dict() for name, check in self.rolling_shutter.items()}
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> Frame:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        check_keys(data, "frame", ("index", "R", "c"), ("images", "lenses", "rolling_shutter"))
        raw_lenses = data.get("lenses") or {}
        if not isinstance(raw_lenses, Mapping):
            raise CamcalError(f"lenses must be an object (camera name -> lens), got {type(raw_lenses).__name__}")
        lenses = {}
        for name, entry in raw_lenses.items():
            try:
                lenses[name] = Lens.from_dict(entry)
            except CamcalError as error:
                raise CamcalError(f"lenses[{name!r}]: {error}") from None
        raw_shutter = data.get("rolling_shutter") or {}
        if not isinstance(raw_shutter, Mapping):
            raise CamcalError("rolling_shutter must be an object (camera name -> its check), got "
                              f"{type(raw_shutter).__name__}")
        shutter = {}
        for name, entry in raw_shutter.items():
            try:
                shutter[name] = ShutterCheck.from_dict(entry)
            except CamcalError as error:
                raise CamcalError(f"rolling_shutter[{name!r}]: {error}") from None
        return cls(data["index"], data["R"], data["c"], data.get("images") or {}, lenses, shutter)
