"""Cameras and rigs: camcal's data model and its ``*.rig.json`` file.

The rig file is the one hand-off between camcal's parts (DESIGN.md)::

    {"format": "camcal.rig", "version": 1, "units": "m",
     "cameras": [{"name", "image_size", "K", "distortion", "R", "c",
                  "sensor_width_mm"?, "rectification"?, "quality"?}, ...],
     "frames": [{"index", "R", "c", "images"?}, ...],
     "points": null | "points.ply",
     "provenance": {"tool", "method", "created", ...}}   (optional: "unknown")

Conventions
-----------
- ``x ~ K [R | -R c] X``: ``R`` rotates world to camera, ``c`` is the
  camera centre; camera axes +x right, +y down, +z forward.
- Pixel (0, 0) is the centre of the top-left pixel.
- ``distortion`` maps undistorted pixels to distorted ones (see
  :mod:`camcal.model.distortion`).
- ``rectification.H`` maps UNDISTORTED pixels of the original camera to
  rectified pixels of a camera ``K_rect`` with image size ``image_size``.
- ``frames`` (moving rigs, e.g. SfM of a sequence) hold the rig's pose per
  frame, ``rig_from_world`` as ``(R, c)``; the cameras' own ``R, c`` are then
  relative to the rig (``cam_from_rig``) and a camera's world pose at a frame
  is ``R_world = R_cam R_frame``, ``c_world = c_frame + R_frame^T c_cam``
  (:meth:`Rig.camera_at_frame`). With no frames, cameras' poses are world
  poses.
- ``points`` names a sibling PLY of sparse points, relative to the rig file.
- Angles in files are radians (rotation matrices here); lengths in ``units``.

The file is validated on load with one message naming the bad field,
written atomically, and round-trips exactly (floats are written with
``repr`` precision).
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal import __version__
from camcal.base.errors import CamcalError
from camcal.base.limits import check_image_size
from camcal.model.camera import compose_P, project_pinhole, rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.model.tde4 import TDE4_MODELS, check_filmback
from camcal.base.atomic import atomic_write_text
from camcal.base.jsonfile import dumps, read_json
from camcal.model.quality import Quality

__all__ = [
    "RIG_FORMAT",
    "RIG_VERSION",
    "UNKNOWN_PROVENANCE",
    "Camera",
    "Rectification",
    "Frame",
    "Rig",
    "make_provenance",
]

RIG_FORMAT = "camcal.rig"
RIG_VERSION = 1
#: What a rig file without ``provenance`` (or without one of its keys) gets on load.
UNKNOWN_PROVENANCE = "unknown"

_ORTHONORMAL_TOL = 1e-6
#: Focal lengths (and skew) are plausible within this factor of the larger image side, either way.
_FOCAL_RANGE = 1000.0
#: Principal points are plausible up to this many image sizes beyond the image's edges (generous: a diverged
#: calibration, written with ``--force`` past the quality gate, has had one 2.5 widths off the image).
_PP_MARGIN = 10.0


# -- field validation helpers ---------------------------------------------------


def _matrix(value: Any, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
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


def _check_K(K: NDArray[np.float64], name: str) -> None:
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0:
        raise CamcalError(f"{name} must be upper triangular ([[fx, s, cx], [0, fy, cy], [0, 0, 1]])")
    if K[2, 2] != 1.0:
        raise CamcalError(f"{name}[2][2] must be 1, got {float(K[2, 2])!r}")  # numpy 2 reprs np.float64(x)
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise CamcalError(f"{name} must have positive fx and fy, got fx={float(K[0, 0])!r}, fy={float(K[1, 1])!r}")


def _check_plausible(K: NDArray[np.float64], image_size: tuple[int, int], name: str) -> None:
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


def _check_rotation(R: NDArray[np.float64], name: str) -> None:
    error = np.abs(R.T @ R - np.eye(3)).max()
    if error > _ORTHONORMAL_TOL:
        raise CamcalError(f"{name} is not orthonormal (max |R^T R - I| = {error:.3g})")
    if np.linalg.det(R) < 0:
        raise CamcalError(f"{name} has determinant -1 (a reflection, not a rotation)")


def _image_size(value: Any, name: str) -> tuple[int, int]:
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


def _check_keys(data: Any, name: str, required: Iterable[str], optional: Iterable[str] = ()) -> None:
    if not isinstance(data, Mapping):
        raise CamcalError(f"{name} must be an object, got {type(data).__name__}")
    required = tuple(required)
    for key in required:
        if key not in data:
            raise CamcalError(f"{name} is missing key '{key}'")
    unknown = sorted(set(data) - set(required) - set(optional))
    if unknown:
        raise CamcalError(f"{name} has unknown key(s): {', '.join(map(str, unknown))}")


class _DictEquality:
    """Equality through the file form: two objects are equal when their files are."""

    def to_dict(self) -> dict:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


# -- data model -------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Rectification(_DictEquality):
    """A camera's rectifying homography.

    Parameters
    ----------
    H : array_like, shape (3, 3)
        Maps UNDISTORTED pixels of the original camera to rectified pixels.
    K_rect : array_like, shape (3, 3)
        Intrinsics of the rectified camera.
    image_size : (int, int)
        Rectified image size (width, height) in pixels.
    """

    H: NDArray[np.float64]
    K_rect: NDArray[np.float64]
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        H = _matrix(self.H, (3, 3), "rectification.H")
        if abs(np.linalg.det(H)) <= 1e-12 * np.abs(H).max() ** 3:
            raise CamcalError("rectification.H is singular")
        K_rect = _matrix(self.K_rect, (3, 3), "rectification.K_rect")
        _check_K(K_rect, "rectification.K_rect")
        image_size = _image_size(self.image_size, "rectification.image_size")
        _check_plausible(K_rect, image_size, "rectification.K_rect")
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "K_rect", K_rect)
        object.__setattr__(self, "image_size", image_size)

    def to_dict(self) -> dict:
        return {"H": self.H.tolist(), "K_rect": self.K_rect.tolist(), "image_size": list(self.image_size)}

    @classmethod
    def from_dict(cls, data: Mapping) -> Rectification:
        _check_keys(data, "rectification", ("H", "K_rect", "image_size"))
        return cls(data["H"], data["K_rect"], data["image_size"])


@dataclass(frozen=True, eq=False)
class Camera(_DictEquality):
    """One calibrated camera.

    Parameters
    ----------
    name : str
        Unique within its rig.
    image_size : (int, int)
        Width, height in pixels.
    K : array_like, shape (3, 3)
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, pixel (0, 0) at
        the centre of the top-left pixel.
    distortion : Distortion
        Maps undistorted pixels to distorted pixels.
    R : array_like, shape (3, 3)
        Rotation world (or rig) -> camera, camera axes x right, y down, z forward.
    c : array_like, shape (3,)
        Camera centre in world (or rig) coordinates, in the rig's units.
    sensor_width_mm : float, optional
        Physical sensor width, for Blender's lens in mm.
    rectification : Rectification, optional
    quality : Quality or mapping, optional
        Fit quality with documented keys and units (:class:`camcal.model.quality.Quality`),
        e.g. ``Quality(rms_px=0.21, n_views=18, sigma={"fx": 0.3})``; a mapping
        of the file form (older key names too) is converted.
    """

    name: str
    image_size: tuple[int, int]
    K: NDArray[np.float64]
    distortion: Distortion
    R: NDArray[np.float64]
    c: NDArray[np.float64]
    sensor_width_mm: float | None = None
    rectification: Rectification | None = None
    quality: Quality = field(default_factory=Quality)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise CamcalError(f"camera name must be a non-empty string, got {self.name!r}")
        object.__setattr__(self, "image_size", _image_size(self.image_size, "image_size"))
        K = _matrix(self.K, (3, 3), "K")
        _check_K(K, "K")
        _check_plausible(K, self.image_size, "K")
        object.__setattr__(self, "K", K)
        if not isinstance(self.distortion, Distortion):
            raise CamcalError(f"distortion must be a Distortion, got {type(self.distortion).__name__}")
        if self.distortion.model in TDE4_MODELS:
            check_filmback(self.distortion.model, self.distortion.params, self.image_size)
        R = _matrix(self.R, (3, 3), "R")
        _check_rotation(R, "R")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", _matrix(self.c, (3,), "c"))
        if self.sensor_width_mm is not None:
            width = self.sensor_width_mm
            if isinstance(width, bool) or not isinstance(width, (int, float)) or not math.isfinite(width) or width <= 0:
                raise CamcalError(f"sensor_width_mm must be a positive number, got {width!r}")
            object.__setattr__(self, "sensor_width_mm", float(width))
        if self.rectification is not None and not isinstance(self.rectification, Rectification):
            raise CamcalError("rectification must be a Rectification")
        quality = Quality.from_dict(self.quality, baseline_length=float(np.linalg.norm(self.c)))
        object.__setattr__(self, "quality", quality)

    # -- geometry -------------------------------------------------------------------

    @property
    def P(self) -> NDArray[np.float64]:
        """The 3x4 projection matrix ``K [R | -R c]`` (distortion not included)."""
        return compose_P(self.K, self.R, self.c)

    def project(self, X: ArrayLike) -> NDArray[np.float64]:
        """Project world points to distorted pixels.

        Parameters
        ----------
        X : array_like, shape (N, 3)
            World points (rig coordinates when the rig has frames).

        Returns
        -------
        ndarray, shape (N, 2)
            ``distort(K R (X - c))`` in pixels, pixel (0, 0) at the centre of
            the top-left pixel; NaN for points at or behind the camera plane,
            except for a Kannala-Brandt lens, which images rays up to its
            :attr:`~camcal.model.distortion.Distortion.max_angle_rad`
            (:meth:`~camcal.model.distortion.Distortion.project_rays`).
        """
        X = np.asarray(X, dtype=np.float64)
        if not self.distortion.is_fisheye:
            return self.distortion.distort(project_pinhole(self.K, self.R, self.c, X), self.K)
        if X.ndim != 2 or X.shape[1] != 3:
            raise CamcalError(f"world points must have shape (N, 3), got {X.shape}")
        return self.distortion.project_rays((X - self.c) @ self.R.T, self.K)

    # -- file boundary --------------------------------------------------------------

    def to_dict(self) -> dict:
        """The camera's entry in the rig file."""
        out: dict = {
            "name": self.name,
            "image_size": list(self.image_size),
            "K": self.K.tolist(),
            "distortion": self.distortion.to_dict(),
            "R": self.R.tolist(),
            "c": self.c.tolist(),
        }
        if self.sensor_width_mm is not None:
            out["sensor_width_mm"] = self.sensor_width_mm
        if self.rectification is not None:
            out["rectification"] = self.rectification.to_dict()
        out["quality"] = self.quality.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> Camera:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        _check_keys(
            data,
            "camera",
            ("name", "image_size", "K", "distortion", "R", "c"),
            ("sensor_width_mm", "rectification", "quality"),
        )
        rectification = data.get("rectification")
        return cls(
            name=data["name"],
            image_size=data["image_size"],
            K=data["K"],
            distortion=Distortion.from_dict(data["distortion"]),
            R=data["R"],
            c=data["c"],
            sensor_width_mm=data.get("sensor_width_mm"),
            rectification=None if rectification is None else Rectification.from_dict(rectification),
            quality=data.get("quality") or {},
        )


@dataclass(frozen=True, eq=False)
class Frame(_DictEquality):
    """The rig's pose at one frame of a sequence (``rig_from_world``).

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
    """

    index: int
    R: NDArray[np.float64]
    c: NDArray[np.float64]
    images: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)):
            raise CamcalError(f"frame index must be an integer, got {self.index!r}")
        object.__setattr__(self, "index", int(self.index))
        R = _matrix(self.R, (3, 3), "R")
        _check_rotation(R, "R")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", _matrix(self.c, (3,), "c"))
        if not isinstance(self.images, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.images.items()
        ):
            raise CamcalError("frame images must map camera names to path strings")
        object.__setattr__(self, "images", MappingProxyType(dict(self.images)))

    def to_dict(self) -> dict:
        out: dict = {"index": self.index, "R": self.R.tolist(), "c": self.c.tolist()}
        if self.images:
            out["images"] = dict(self.images)
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> Frame:
        _check_keys(data, "frame", ("index", "R", "c"), ("images",))
        return cls(data["index"], data["R"], data["c"], data.get("images") or {})


def make_provenance(method: str, **details: Any) -> dict:
    """Provenance for a new rig: tool and version, method, UTC creation time."""
    return {
        "tool": f"camcal {__version__}",
        "method": method,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **details,
    }


@dataclass(frozen=True, eq=False)
class Rig(_DictEquality):
    """A set of cameras in one coordinate frame, optionally moving over frames.

    Parameters
    ----------
    cameras : sequence of Camera
        At least one, with unique names.
    units : str
        World length unit (``"m"`` by default; a board may say ``"squares"``).
    frames : sequence of Frame
        Per-frame rig poses (see the module docstring); empty for a static rig.
    points : str, optional
        Sibling PLY of sparse points, relative to the rig file.
    provenance : mapping
        ``tool``, ``method``, ``created`` and any further details; absent
        keys are filled with :data:`UNKNOWN_PROVENANCE` ("unknown").
    """

    cameras: tuple[Camera, ...]
    units: str = "m"
    frames: tuple[Frame, ...] = ()
    points: str | None = None
    provenance: Mapping[str, Any] = field(default_factory=lambda: make_provenance("manual"))

    def __post_init__(self) -> None:
        cameras = tuple(self.cameras)
        if not cameras:
            raise CamcalError("a rig needs at least one camera")
        for index, camera in enumerate(cameras):
            if not isinstance(camera, Camera):
                raise CamcalError(f"cameras[{index}] must be a Camera, got {type(camera).__name__}")
        names = [camera.name for camera in cameras]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise CamcalError(f"camera names must be unique, repeated: {', '.join(duplicates)}")
        object.__setattr__(self, "cameras", cameras)
        if not isinstance(self.units, str) or not self.units:
            raise CamcalError(f"units must be a non-empty string, got {self.units!r}")
        frames = tuple(self.frames)
        indices = [frame.index for frame in frames]
        if len(set(indices)) != len(indices):
            raise CamcalError("frame indices must be unique")
        for frame in frames:
            unknown = sorted(set(frame.images) - set(names))
            if unknown:
                raise CamcalError(f"frame {frame.index} has images of unknown camera(s): {', '.join(unknown)}")
        object.__setattr__(self, "frames", frames)
        if self.points is not None and (not isinstance(self.points, str) or not self.points):
            raise CamcalError(f"points must be null or a file name, got {self.points!r}")
        if not isinstance(self.provenance, Mapping):
            raise CamcalError("provenance must be an object")
        # optional metadata: a rig typed by hand or imported from another tool loads
        provenance = {key: UNKNOWN_PROVENANCE for key in ("tool", "method", "created")}
        provenance.update(copy.deepcopy(dict(self.provenance)))
        object.__setattr__(self, "provenance", MappingProxyType(provenance))

    def camera(self, name: str) -> Camera:
        """The camera called ``name``."""
        for camera in self.cameras:
            if camera.name == name:
                return camera
        raise CamcalError(f"no camera {name!r} in the rig; it has: {', '.join(c.name for c in self.cameras)}")

    def camera_at_frame(self, name: str, index: int) -> Camera:
        """Camera ``name`` posed in the world at frame ``index``.

        Notes
        -----
        ``R_world = R_cam R_frame`` and ``c_world = c_frame + R_frame^T c_cam``,
        composing ``cam_from_rig`` after ``rig_from_world``.
        """
        camera = self.camera(name)
        for frame in self.frames:
            if frame.index == index:
                return dataclasses.replace(camera, R=camera.R @ frame.R, c=frame.c + frame.R.T @ camera.c)
        raise CamcalError(f"no frame {index} in the rig")

    def summary(self) -> str:
        """A readable multi-line description (what ``camcal rig show`` prints)."""
        lines = [
            f"rig: {len(self.cameras)} camera(s), units {self.units}, "
            f"{len(self.frames)} frame(s), points: {self.points or 'none'}",
            f"made by {self.provenance.get('tool')} ({self.provenance.get('method')}) "
            f"on {self.provenance.get('created')}",
        ]
        reference = self.cameras[0]
        for camera in self.cameras:
            K = camera.K
            width, height = camera.image_size
            lines.append(f"camera {camera.name!r}: {width}x{height} px")
            lines.append(
                f"  fx {K[0, 0]:.3f}  fy {K[1, 1]:.3f}  skew {K[0, 1]:.4g}  "
                f"principal point ({K[0, 2]:.3f}, {K[1, 2]:.3f}) px"
            )
            params = ", ".join(f"{k} {v:.6g}" for k, v in camera.distortion.params.items())
            centre = "" if camera.distortion.center is None else f" about ({camera.distortion.center[0]:.2f}, {camera.distortion.center[1]:.2f})"
            lines.append(f"  distortion {camera.distortion.model}{': ' + params if params else ''}{centre}")
            view = camera.R[2]
            lines.append(
                f"  centre ({camera.c[0]:.4f}, {camera.c[1]:.4f}, {camera.c[2]:.4f}) {self.units}, "
                f"looking along ({view[0]:.3f}, {view[1]:.3f}, {view[2]:.3f})"
            )
            if camera is not reference:
                angle = rotation_angle_deg(camera.R @ reference.R.T)
                baseline = np.linalg.norm(camera.c - reference.c)
                lines.append(f"  from {reference.name!r}: baseline {baseline:.4f} {self.units}, rotation {angle:.3f} deg")
            if camera.sensor_width_mm is not None:
                lines.append(f"  sensor width {camera.sensor_width_mm:g} mm")
            if camera.rectification is not None:
                rw, rh = camera.rectification.image_size
                lines.append(f"  rectified to {rw}x{rh} px, fx {camera.rectification.K_rect[0, 0]:.3f}")
            if camera.quality:
                quality = ", ".join(
                    f"{k} {v:.4g}" if not isinstance(v, Mapping) else f"{k} {{...}}" for k, v in camera.quality.items()
                )
                lines.append(f"  quality: {quality}")
        return "\n".join(lines)

    # -- file boundary --------------------------------------------------------------

    def to_dict(self) -> dict:
        """The rig file's JSON object."""
        return {
            "format": RIG_FORMAT,
            "version": RIG_VERSION,
            "units": self.units,
            "cameras": [camera.to_dict() for camera in self.cameras],
            "frames": [frame.to_dict() for frame in self.frames],
            "points": self.points,
            "provenance": copy.deepcopy(_plain(self.provenance)),
        }

    @classmethod
    def from_dict(cls, data: Any) -> Rig:
        """Validate a rig file's JSON object; errors name the bad field."""
        _check_keys(
            data, "rig", ("format", "version", "cameras"), ("units", "frames", "points", "provenance")
        )
        if data["format"] != RIG_FORMAT:
            raise CamcalError(f"format must be {RIG_FORMAT!r}, got {data['format']!r}")
        if data["version"] != RIG_VERSION:
            raise CamcalError(f"unsupported rig version {data['version']!r}, this camcal reads version {RIG_VERSION}")
        if not isinstance(data["cameras"], list):
            raise CamcalError("cameras must be a list")
        cameras = []
        for index, entry in enumerate(data["cameras"]):
            label = f"cameras[{index}]"
            if isinstance(entry, Mapping) and isinstance(entry.get("name"), str):
                label += f" ({entry['name']!r})"
            try:
                cameras.append(Camera.from_dict(entry))
            except CamcalError as error:
                raise CamcalError(f"{label}: {error}") from None
        frames = []
        raw_frames = data.get("frames", [])
        if not isinstance(raw_frames, list):
            raise CamcalError("frames must be a list")
        for index, entry in enumerate(raw_frames):
            try:
                frames.append(Frame.from_dict(entry))
            except CamcalError as error:
                raise CamcalError(f"frames[{index}]: {error}") from None
        return cls(
            cameras=tuple(cameras),
            units=data.get("units", "m"),
            frames=tuple(frames),
            points=data.get("points"),
            provenance=data.get("provenance") or {},
        )

    def to_json(self) -> str:
        """The rig file's text (JSON, matrices row by row, exact floats)."""
        return dumps(self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike) -> Rig:
        """Read and validate a ``*.rig.json`` file.

        Raises
        ------
        CamcalError
            Missing or unreadable file, malformed JSON, or an invalid field,
            in one line starting with the file name.
        """
        data = read_json(path, "rig file")
        try:
            return cls.from_dict(data)
        except CamcalError as error:
            raise CamcalError(f"{path}: {error}") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig file atomically (temporary file, then rename)."""
        path = Path(path)
        atomic_write_text(path, self.to_json())
        return path


def _plain(value: Any) -> Any:
    """Mapping proxies back to plain dicts for JSON."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
