"""Cameras and rigs: camcal's data model and its ``*.rig.json`` file.

The rig file is the one hand-off between camcal's parts (DESIGN.md)::

    {"format": "camcal.rig", "version": 1, "units": "m",
     "cameras": [{"name", "image_size", "K", "distortion", "R", "c",
                  "sensor_width_mm"?, "rectification"?, "quality"?}, ...],
     "frames": [{"index", "R", "c", "images"?, "lenses"?, "rolling_shutter"?}, ...],
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
- ``frames[i].lenses`` (a zoom, a refocus) gives a camera's lens at that
  frame (``K``, ``distortion`` of the camera's model, the lens state
  ``focal_mm`` / ``focus_m``); cameras absent keep their own
  (:mod:`camcal.model.rig_frames`).
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
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal import __version__
from camcal.base.errors import CamcalError
from camcal.model.camera import compose_P, project_pinhole, rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.model.rig_fields import DictEquality, as_matrix, check_K, check_keys, check_plausible, check_rotation, \
    image_size_field
from camcal.model.rig_frames import Frame, Lens
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
    "Lens",
    "Rig",
    "make_provenance",
]

RIG_FORMAT = "camcal.rig"
RIG_VERSION = 1
#: What a rig file without ``provenance`` (or without one of its keys) gets on load.
UNKNOWN_PROVENANCE = "unknown"

# -- data model -------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Rectification(DictEquality):
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
        H = as_matrix(self.H, (3, 3), "rectification.H")
        if abs(np.linalg.det(H)) <= 1e-12 * np.abs(H).max() ** 3:
            raise CamcalError("rectification.H is singular")
        K_rect = as_matrix(self.K_rect, (3, 3), "rectification.K_rect")
        check_K(K_rect, "rectification.K_rect")
        image_size = image_size_field(self.image_size, "rectification.image_size")
        check_plausible(K_rect, image_size, "rectification.K_rect")
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "K_rect", K_rect)
        object.__setattr__(self, "image_size", image_size)

    def to_dict(self) -> dict:
        return {"H": self.H.tolist(), "K_rect": self.K_rect.tolist(), "image_size": list(self.image_size)}

    @classmethod
    def from_dict(cls, data: Mapping) -> Rectification:
        check_keys(data, "rectification", ("H", "K_rect", "image_size"))
        return cls(data["H"], data["K_rect"], data["image_size"])


@dataclass(frozen=True, eq=False)
class Camera(DictEquality):
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
        object.__setattr__(self, "image_size", image_size_field(self.image_size, "image_size"))
        K = as_matrix(self.K, (3, 3), "K")
        check_K(K, "K")
        check_plausible(K, self.image_size, "K")
        object.__setattr__(self, "K", K)
        if not isinstance(self.distortion, Distortion):
            raise CamcalError(f"distortion must be a Distortion, got {type(self.distortion).__name__}")
        if self.distortion.model in TDE4_MODELS:
            check_filmback(self.distortion.model, self.distortion.params, self.image_size)
        R = as_matrix(self.R, (3, 3), "R")
        check_rotation(R, "R")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", as_matrix(self.c, (3,), "c"))
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
        check_keys(
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


def make_provenance(method: str, **details: Any) -> dict:
    """Provenance for a new rig: tool and version, method, UTC creation time."""
    return {
        "tool": f"camcal {__version__}",
        "method": method,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **details,
    }


@dataclass(frozen=True, eq=False)
class Rig(DictEquality):
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
            for name, lens in frame.lenses.items():
                if name not in names:
                    raise CamcalError(f"frame {frame.index} has a lens for unknown camera {name!r}; "
                                      f"the rig has: {', '.join(names)}")
                _check_frame_lens(cameras[names.index(name)], lens, f"frame {frame.index} lens of {name!r}")
            unknown = sorted(set(frame.rolling_shutter) - set(names))
            if unknown:
                raise CamcalError(f"frame {frame.index} has a rolling-shutter check of unknown camera(s): "
                                  f"{', '.join(unknown)}")
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
        """Camera ``name`` posed in the world at frame ``index``, with its lens there.

        Where the frame has a lens for the camera (:attr:`Frame.lenses`), the
        camera takes that lens's ``K`` and distortion; otherwise its own.

        Notes
        -----
        ``R_world = R_cam R_frame`` and ``c_world = c_frame + R_frame^T c_cam``,
        composing ``cam_from_rig`` after ``rig_from_world``.
        """
        camera = self.camera(name)
        for frame in self.frames:
            if frame.index == index:
                lens = frame.lenses.get(name)
                intrinsics = {} if lens is None else {"K": lens.K, "distortion": lens.distortion}
                return dataclasses.replace(camera, R=camera.R @ frame.R, c=frame.c + frame.R.T @ camera.c, **intrinsics)
        raise CamcalError(f"no frame {index} in the rig")

    def lens_frames(self, name: str) -> tuple[int, ...]:
        """The indices of the frames with a lens of camera ``name`` (:attr:`Frame.lenses`), in the rig's order."""
        self.camera(name)
        return tuple(frame.index for frame in self.frames if name in frame.lenses)

    def with_camera(self, camera: Camera, lenses: Mapping[int, Lens] | None = None, **changes: Any) -> Rig:
        """This rig with ``camera`` in place of the camera of its name, and that camera's per-frame lenses replaced.

        Parameters
        ----------
        camera : Camera
            Replaces the rig's camera of the same name (e.g. its undistorted camera).
        lenses : mapping of int to Lens, optional
            Frame index -> the camera's lens there; frames absent get none
            (the camera's own). ``None``: no frame keeps a lens of it.
        **changes
            Other fields of the new rig (``provenance=...``).
        """
        self.camera(camera.name)
        lenses = dict(lenses or {})
        unknown = sorted(set(lenses) - {frame.index for frame in self.frames})
        if unknown:
            raise CamcalError(f"no frame {unknown[0]} in the rig")
        frames = []
        for frame in self.frames:
            frame_lenses = {name: lens for name, lens in frame.lenses.items() if name != camera.name}
            if frame.index in lenses:
                frame_lenses[camera.name] = lenses[frame.index]
            frames.append(dataclasses.replace(frame, lenses=frame_lenses))
        cameras = tuple(camera if c.name == camera.name else c for c in self.cameras)
        return dataclasses.replace(self, cameras=cameras, frames=tuple(frames), **changes)

    def summary(self) -> str:
        """A readable multi-line description (what ``camcal rig show`` prints)."""
        lens_frames = sum(1 for frame in self.frames if frame.lenses)
        lines = [
            f"rig: {len(self.cameras)} camera(s), units {self.units}, "
            f"{len(self.frames)} frame(s){f' (per-frame lens on {lens_frames} frames)' if lens_frames else ''}, "
            f"points: {self.points or 'none'}",
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
        check_keys(
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


def _check_frame_lens(camera: Camera, lens: Lens, name: str) -> None:
    """A frame's lens fits its camera: the same distortion model, a plausible K (and 3DE film back) on its image."""
    if lens.distortion.model != camera.distortion.model:
        raise CamcalError(f"{name} has distortion model {lens.distortion.model!r}, the camera has "
                          f"{camera.distortion.model!r}; a camera keeps one lens model over its frames")
    try:
        check_plausible(lens.K, camera.image_size, "K")
        if lens.distortion.model in TDE4_MODELS:
            check_filmback(lens.distortion.model, lens.distortion.params, camera.image_size)
    except CamcalError as error:
        raise CamcalError(f"{name}: {error}") from None


def _plain(value: Any) -> Any:
    """Mapping proxies back to plain dicts for JSON."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
