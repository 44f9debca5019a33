"""Reading camcal's rig file (``*.rig.json``) without camcal, numpy or bpy.

The add-on must not import camcal, so this module reads the parts of the
rig file it needs and checks them, with one clear message naming the bad
field (``cameras[1].K: expected a 3x3 matrix, got 2 rows``). It is not a
second implementation of ``camcal.rig``: unknown keys are ignored, and only
what the importer uses is validated.

Conventions (camcal's DESIGN): ``P = K [R | -R c]``; ``R`` rotates world to
camera, ``c`` is the camera centre in world coordinates; camera axes x
right, y down, z forward; pixel (0, 0) is the centre of the top-left pixel.

Frames (``camcal.rig``): ``frames`` holds the rig's pose per frame,
``{"index", "R", "c", "images"?, "lenses"?}`` with ``R, c`` the ``rig_from_world``
pose; the cameras' own ``R, c`` are then relative to the rig
(``cam_from_rig``), so a camera's world pose at a frame is
``R_world = R_cam R_frame``, ``c_world = c_frame + R_frame^T c_cam``.
``images`` maps camera names to plate paths. ``lenses`` maps camera names
to that camera's lens at the frame (a zoom, a refocus: ``K``, ``distortion``
of the camera's model, ``focal_mm`` / ``focus_m`` recorded); cameras absent
keep their own. Paths (plates, ``points``: a sibling PLY or null) are
relative to the rig file.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

__all__ = [
    "RigFileError",
    "Distortion",
    "Rectification",
    "RigCamera",
    "RigFrame",
    "RigLens",
    "Rig",
    "load_rig",
    "parse_rig",
    "DISTORTION_PARAMS",
    "FISHEYE_MODELS",
]

RIG_FORMAT = "camcal.rig"
RIG_VERSIONS = (1,)

# Parameters each distortion model needs (optional ones after the "|").
DISTORTION_PARAMS = {
    "none": ((), ()),
    "division": (("lambda",), ("aspect",)),
    "polynomial": (("k1", "k2"), ("k3",)),
    "opencv": (("k1", "k2", "p1", "p2", "k3"), ("k4", "k5", "k6", "s1", "s2", "s3", "s4")),
    "kannala-brandt": (("k1", "k2", "k3", "k4"), ()),
    "kannala-brandt-thin-prism": (("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "s1", "s2", "s3", "s4"), ()),
}
#: The Kannala-Brandt models (Cycles' panoramic fisheye camera carries their radial part).
FISHEYE_MODELS = ("kannala-brandt", "kannala-brandt-thin-prism")

ORTHONORMAL_TOL = 1e-6


class RigFileError(Exception):
    """A rig file that cannot be imported; the message names the bad field."""


@dataclass(frozen=True)
class Distortion:
    """A lens distortion model (undistorted -> distorted pixels).

    ``center`` is the distortion centre in pixels (pixel centres at
    integers): the division model's own centre, the principal point for the
    others (``polynomial`` and ``opencv`` work in normalised coordinates
    around it).
    """

    model: str = "none"
    params: dict = field(default_factory=dict)
    center: tuple | None = None


@dataclass(frozen=True)
class Rectification:
    """The rectifying homography of a camera and its rectified intrinsics."""

    H: tuple
    K_rect: tuple
    image_size: tuple


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig, as read from the file (matrices as tuples of rows)."""

    name: str
    image_size: tuple
    K: tuple
    R: tuple
    c: tuple
    distortion: Distortion
    sensor_width_mm: float
    rectification: Rectification | None
    quality: dict
    raw: dict


@dataclass(frozen=True)
class RigLens:
    """A camera's lens at one frame: ``K`` (tuple of rows), its distortion, the lens state (mm, m or None)."""

    K: tuple
    distortion: Distortion
    focal_mm: float | None = None
    focus_m: float | None = None


@dataclass(frozen=True)
class RigFrame:
    """One frame: its index, the rig's pose ``rig_from_world`` (R, c), plates and lenses by camera."""

    index: int
    R: tuple
    c: tuple
    images: dict
    lenses: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Rig:
    """The parts of a rig file the Blender importer uses."""

    path: str
    name: str
    units: str
    cameras: tuple
    frames: tuple
    points: str | None
    provenance: dict

    def camera(self, name):
        """The camera called ``name``; ``KeyError`` naming the known ones otherwise."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        known = ", ".join(c.name for c in self.cameras)
        raise KeyError(f"no camera {name!r} in the rig (cameras: {known})")

    def lens_frames(self, name):
        """The frames with a lens of camera ``name`` (a zoom, a refocus), in the file's order."""
        return tuple(frame for frame in self.frames if name in frame.lenses)

    def lens_at(self, name, frame):
        """``(K, distortion)`` of camera ``name`` at a :class:`RigFrame`: the frame's lens, else the camera's own."""
        lens = frame.lenses.get(name)
        if lens is not None:
            return lens.K, lens.distortion
        camera = self.camera(name)
        return camera.K, camera.distortion


def load_rig(path):
    """Read and check a rig file.

    Parameters
    ----------
    path : str or os.PathLike
        A ``*.rig.json`` file written by camcal.

    Returns
    -------
    Rig
        Cameras, frames and the absolute path of the points PLY (or None).

    Raises
    ------
    RigFileError
        Unreadable file, malformed JSON or a bad field (named in the message).
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except OSError as error:
        raise RigFileError(f"cannot read rig file {path}: {error.strerror or error}") from None
    except json.JSONDecodeError as error:
        raise RigFileError(f"{path}: not valid JSON ({error.msg} at line {error.lineno})") from None
    return parse_rig(data, path)


def parse_rig(data, path="<memory>"):
    """Check the decoded JSON of a rig file and return a :class:`Rig`.

    Relative paths (points, plates) are resolved against the folder of
    ``path``.
    """
    if not isinstance(data, dict):
        raise RigFileError(f"{path}: expected a JSON object, got {type(data).__name__}")
    fmt = data.get("format")
    if fmt != RIG_FORMAT:
        raise RigFileError(f"format: expected {RIG_FORMAT!r}, got {fmt!r}")
    version = data.get("version")
    if version not in RIG_VERSIONS:
        allowed = ", ".join(str(v) for v in RIG_VERSIONS)
        raise RigFileError(f"version: unsupported {version!r}, expected one of: {allowed}")
    base = os.path.dirname(os.path.abspath(path)) if path != "<memory>" else os.getcwd()

    cams_data = _require(data, "cameras", list, "cameras")
    if not cams_data:
        raise RigFileError("cameras: the rig has no cameras")
    cameras = tuple(_parse_camera(c, f"cameras[{i}]") for i, c in enumerate(cams_data))
    names = [c.name for c in cameras]
    for name in names:
        if names.count(name) > 1:
            raise RigFileError(f"cameras: duplicate camera name {name!r}")

    frames_data = data.get("frames") or []
    if not isinstance(frames_data, list):
        raise RigFileError(f"frames: expected a list, got {type(frames_data).__name__}")
    by_name = {cam.name: cam for cam in cameras}
    frames = tuple(_parse_frame(f, f"frames[{i}]", by_name, base) for i, f in enumerate(frames_data))
    indices = [f.index for f in frames]
    for index in indices:
        if indices.count(index) > 1:
            raise RigFileError(f"frames: duplicate frame index {index}")

    points = data.get("points")
    if isinstance(points, dict):
        points = points.get("path")
    if points is not None:
        if not isinstance(points, str) or not points:
            raise RigFileError(f"points: expected a PLY path or null, got {points!r}")
        points = os.path.normpath(os.path.join(base, points))

    units = data.get("units", "m")
    if not isinstance(units, str):
        raise RigFileError(f"units: expected a string, got {units!r}")
    stem = os.path.basename(path)
    for suffix in (".rig.json", ".json"):
        if stem.endswith(suffix):
            stem = stem[: -len(suffix)]
            break
    provenance = data.get("provenance") or {}
    return Rig(
        path=os.path.abspath(path) if path != "<memory>" else path,
        name=str(data.get("name") or stem or "rig"),
        units=units,
        cameras=cameras,
        frames=frames,
        points=points,
        provenance=provenance if isinstance(provenance, dict) else {},
    )


def _parse_camera(data, where):
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: expected an object, got {type(data).__name__}")
    name = _require(data, "name", str, where)
    if not name:
        raise RigFileError(f"{where}.name: must not be empty")
    where = f"{where} ({name})"
    size = _require(data, "image_size", list, where)
    if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in size):
        raise RigFileError(f"{where}.image_size: expected [width, height] integers, got {size!r}")
    if size[0] <= 0 or size[1] <= 0:
        raise RigFileError(f"{where}.image_size: must be positive, got {size!r}")
    K = _intrinsics(data, where)
    R = _rotation(data, "R", where)
    c = _vector(data, "c", 3, where)
    sensor = data.get("sensor_width_mm", 36.0)
    if sensor is None:
        sensor = 36.0
    if not _is_number(sensor) or not sensor > 0:
        raise RigFileError(f"{where}.sensor_width_mm: expected a positive number, got {sensor!r}")
    distortion = _parse_distortion(data.get("distortion"), f"{where}.distortion", K)
    rect = data.get("rectification")
    rectification = None
    if rect is not None:
        rwhere = f"{where}.rectification"
        if not isinstance(rect, dict):
            raise RigFileError(f"{rwhere}: expected an object or null")
        rsize = rect.get("image_size", list(size))
        if not (isinstance(rsize, list) and len(rsize) == 2 and all(isinstance(v, int) for v in rsize)):
            raise RigFileError(f"{rwhere}.image_size: expected [width, height] integers, got {rsize!r}")
        rectification = Rectification(
            H=_matrix(rect, "H", 3, 3, rwhere),
            K_rect=_matrix(rect, "K_rect", 3, 3, rwhere),
            image_size=tuple(rsize),
        )
    quality = data.get("quality") or {}
    if not isinstance(quality, dict):
        raise RigFileError(f"{where}.quality: expected an object, got {type(quality).__name__}")
    return RigCamera(
        name=name,
        image_size=tuple(size),
        K=K,
        R=R,
        c=c,
        distortion=distortion,
        sensor_width_mm=float(sensor),
        rectification=rectification,
        quality=quality,
        raw=data,
    )


def _parse_distortion(data, where, K):
    if data is None:
        return Distortion()
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: expected an object or null, got {type(data).__name__}")
    model = data.get("model", "none")
    if model not in DISTORTION_PARAMS:
        allowed = ", ".join(DISTORTION_PARAMS)
        raise RigFileError(f"{where}.model: unknown model {model!r}, expected one of: {allowed}")
    params = data.get("params") or {}
    if not isinstance(params, dict):
        raise RigFileError(f"{where}.params: expected an object")
    required, optional = DISTORTION_PARAMS[model]
    for key in required:
        if key not in params:
            raise RigFileError(f"{where}.params: model {model!r} needs {key!r}")
    for key in required + optional:
        if key in params and not _is_number(params[key]):
            raise RigFileError(f"{where}.params.{key}: expected a finite number, got {params[key]!r}")
    center = data.get("center") if model == "division" else None
    if center is None:
        center = (K[0][2], K[1][2])
    else:
        if not (isinstance(center, list) and len(center) == 2 and all(_is_number(v) for v in center)):
            raise RigFileError(f"{where}.center: expected [x, y] numbers, got {center!r}")
        center = (float(center[0]), float(center[1]))
    clean = {k: float(params[k]) for k in required + optional if k in params}
    return Distortion(model=model, params=clean, center=center)


def _parse_frame(data, where, names, base):
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: expected an object, got {type(data).__name__}")
    index = _require(data, "index", int, where)
    if isinstance(index, bool):
        raise RigFileError(f"{where}.index: expected an integer, got {index!r}")
    where = f"{where} (index {index})"
    R = _rotation(data, "R", where)
    c = _vector(data, "c", 3, where)
    images = {}
    images_data = data.get("images") or {}
    if not isinstance(images_data, dict):
        raise RigFileError(f"{where}.images: expected an object {{camera: path}}")
    for cam, entry in images_data.items():
        if cam not in names:
            raise RigFileError(f"{where}.images: unknown camera {cam!r}")
        if not isinstance(entry, str) or not entry:
            raise RigFileError(f"{where}.images.{cam}: expected a path, got {entry!r}")
        images[cam] = os.path.normpath(os.path.join(base, entry))
    lenses_data = data.get("lenses") or {}
    if not isinstance(lenses_data, dict):
        raise RigFileError(f"{where}.lenses: expected an object {{camera: lens}}")
    lenses = {cam: _parse_lens(entry, f"{where}.lenses.{cam}", cam, names) for cam, entry in lenses_data.items()}
    return RigFrame(index=index, R=R, c=c, images=images, lenses=lenses)


def _parse_lens(data, where, name, cameras):
    if name not in cameras:
        raise RigFileError(f"{where}: unknown camera {name!r}")
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: expected an object, got {type(data).__name__}")
    K = _intrinsics(data, where)
    if "distortion" not in data:
        raise RigFileError(f"{where}: missing key 'distortion'")
    distortion = _parse_distortion(data["distortion"], f"{where}.distortion", K)
    if distortion.model != cameras[name].distortion.model:
        raise RigFileError(f"{where}.distortion.model: {distortion.model!r}, but the camera's lens is "
                           f"{cameras[name].distortion.model!r} (one model over a camera's frames)")
    state = {}
    for key in ("focal_mm", "focus_m"):
        value = data.get(key)
        if value is not None and (not _is_number(value) or not value > 0):
            raise RigFileError(f"{where}.{key}: expected a positive number, got {value!r}")
        state[key] = None if value is None else float(value)
    return RigLens(K=K, distortion=distortion, **state)


def _intrinsics(data, where):
    """``data["K"]``: upper triangular, ``K[2][2] = 1``, positive focal lengths."""
    K = _matrix(data, "K", 3, 3, where)
    if K[1][0] != 0 or K[2][0] != 0 or K[2][1] != 0 or K[2][2] != 1:
        raise RigFileError(
            f"{where}.K: expected upper-triangular with K[2][2] = 1, got rows {K[1]!r}, {K[2]!r}"
        )
    if K[0][0] <= 0 or K[1][1] <= 0:
        raise RigFileError(f"{where}.K: focal lengths must be positive, got fx={K[0][0]}, fy={K[1][1]}")
    return K


def _require(data, key, kind, where):
    if key not in data:
        raise RigFileError(f"{where}: missing key {key!r}")
    value = data[key]
    if not isinstance(value, kind):
        raise RigFileError(f"{where}.{key}: expected {kind.__name__}, got {type(value).__name__}")
    return value


def _is_number(value):
    return (
        isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    )


def _matrix(data, key, rows, cols, where):
    value = _require(data, key, list, where)
    if len(value) != rows or not all(isinstance(r, list) and len(r) == cols for r in value):
        raise RigFileError(f"{where}.{key}: expected a {rows}x{cols} matrix, got {value!r}")
    for row in value:
        for v in row:
            if not _is_number(v):
                raise RigFileError(f"{where}.{key}: expected finite numbers, got {v!r}")
    return tuple(tuple(float(v) for v in row) for row in value)


def _vector(data, key, n, where):
    value = _require(data, key, list, where)
    if len(value) != n or not all(_is_number(v) for v in value):
        raise RigFileError(f"{where}.{key}: expected {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def _rotation(data, key, where):
    R = _matrix(data, key, 3, 3, where)
    worst = 0.0
    for i in range(3):
        for j in range(3):
            dot = sum(R[i][k] * R[j][k] for k in range(3))
            worst = max(worst, abs(dot - (1.0 if i == j else 0.0)))
    if worst > ORTHONORMAL_TOL:
        raise RigFileError(f"{where}.{key}: not orthonormal (|R R^T - I| = {worst:.2e})")
    det = (
        R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
        - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
        + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0])
    )
    if det < 0:
        raise RigFileError(f"{where}.{key}: a reflection (det = {det:.3f}), expected a rotation")
    return R
