"""OpenCV FileStorage camera files (YAML or XML), written and read with ``cv2.FileStorage``.

The file's suffix picks the encoding: ``.yaml`` / ``.yml`` YAML, ``.xml`` XML.

One camera (the names of OpenCV's ``calibration.cpp`` sample)::

    camera_name, image_width, image_height, camera_matrix (3x3),
    distortion_coefficients (1x5: k1 k2 p1 p2 k3; 1x8 with the rational
    k4 k5 k6; 1x12 with the thin-prism s1 s2 s3 s4 too)

A stereo pair (the names of OpenCV's ``stereo_calib.cpp`` sample)::

    image_width, image_height, camera_name_1, camera_name_2,
    K1 D1 K2 D2 R T E F
    R1 R2 P1 P2 Q        (when both cameras are rectified by rotation)

``R, T`` take points from the first camera to the second
(``X_2 = R X_1 + T``): ``R = R_2 R_1^T``, ``T = R_2 (c_1 - c_2)``;
``E = [T]_x R``, ``F = K_2^-T E K_1^-1``. The rectification entries are the
ones ``cv2.stereoRectify`` writes: ``R_i`` rotates camera ``i`` into the
common rectified frame, ``P_1 = K_r1 [I | 0]``, ``P_2 = K_r2 [I | t]`` with
``t = R_2' (c_1 - c_2)`` (``R_2'`` = world to rectified camera 2) and
``Q = [[1, 0, 0, -cx_1], [0, 1, 0, -cy_1], [0, 0, 0, f], [0, 0, -1/t_x,
(cx_1 - cx_2)/t_x]]``. camcal's rectifying homography of camera ``i`` is
``H_i = K_ri R_i K_i^-1``; OpenCV has no rectified image size, so camcal
adds ``rectified_width`` / ``rectified_height`` (readers ignore them).

A fisheye file (camcal's ``kannala-brandt`` lens, OpenCV's ``cv2.fisheye``
model) adds ``fisheye_model: 1`` (the key of OpenCV's calibration sample,
``camera_calibration.cpp``) and holds the ``cv2.fisheye`` D vector
``k1 k2 k3 k4`` (1x4) in ``distortion_coefficients`` or ``D1`` / ``D2``;
the rectification entries are then the ones ``cv2.fisheye.stereoRectify``
writes, with the same meaning. Both cameras of a stereo file are of one
kind; a ``kannala-brandt-thin-prism`` lens is written as the nearest
``cv2.fisheye`` lens (k1..k4 fitted over the frame, max residual reported).

OpenCV's pixel convention is camcal's (pixel (0, 0) at the centre of the
top-left pixel). Its distortion is camcal's ``opencv`` model, rational and
thin-prism terms included (written as the shortest of OpenCV's 5-, 8- and
12-coefficient vectors that holds the lens); ``polynomial`` and ``none``
map exactly, the ``division`` lens is fitted (nearest ``opencv`` model,
residual reported). OpenCV's projection ignores skew
(``cv2.projectPoints`` uses fx, fy, cx, cy; ``cv2.fisheye`` takes skew as a
separate ``alpha``): a camera with skew is written without it, with the
residual reported. On reading, 4, 5, 8, 12 or 14 coefficients are accepted
(exactly 4 in a fisheye file); the 14-vector's tilt ``tauX, tauY`` only
when zero (camcal has no tilted-sensor model: a non-zero tilt is refused).

The first camera's pose is the file's origin; a rig's world pose, frames
and sparse points are not held (the summary says so).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import OPENCV_COEFFICIENTS, Distortion
from camcal.base.atomic import atomic_path
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    ExportResult,
    ImportResult,
    LensConversion,
    nearest_camera,
    select_cameras,
)
from camcal.model.rig import Camera, Rectification, Rig

__all__ = ["SUFFIXES", "export", "load", "rectification_rotation"]

#: File suffixes and the FileStorage encoding they pick.
SUFFIXES = {".yaml": "YAML", ".yml": "YAML", ".xml": "XML"}

#: A rectification is written as OpenCV's rotation when H is K_r R K^-1 to this many pixels.
_ROTATION_TOL_PX = 1e-6

_FISHEYE = "kannala-brandt"
#: The most coefficients an OpenCV distortion vector has (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tx ty).
_MAX_COEFFICIENTS = 14
_FISHEYE_FORMAT = "opencv fisheye (k1 k2 k3 k4)"
_PINHOLE_FORMAT = "opencv (k1 k2 p1 p2 k3)"


def _check_suffix(path: Path) -> None:
    if path.suffix.lower() not in SUFFIXES:
        raise CamcalError(f"an OpenCV file must end in {', '.join(SUFFIXES)}, got {path.name!r}")


def _holds(distortion: Distortion) -> bool:
    return distortion.model in ("none", "polynomial", "opencv")


def _format(distortion: Distortion) -> str:
    """The OpenCV vector a lens is written as: ``opencv (k1 ... k3)``, with k4..k6 and s1..s4 when it has them."""
    if distortion.model == _FISHEYE:
        return _FISHEYE_FORMAT
    if not _holds(distortion):
        return _PINHOLE_FORMAT
    return f"opencv ({' '.join(OPENCV_COEFFICIENTS[:distortion.opencv_terms])})"


def _holds_fisheye(distortion: Distortion) -> bool:
    return distortion.model == _FISHEYE


def _coefficients(distortion: Distortion) -> NDArray[np.float64]:
    p = distortion.params
    if distortion.model == _FISHEYE:
        return np.array([[p["k1"], p["k2"], p["k3"], p["k4"]]])
    return distortion.opencv_coefficients()[None, :]


def rectification_rotation(camera: Camera) -> tuple[NDArray[np.float64], float]:
    """OpenCV's rectifying rotation ``R_i`` of a rectified camera, and how well it holds H.

    Returns
    -------
    R : ndarray, shape (3, 3)
        The rotation nearest (Frobenius, by SVD) to ``K_r^-1 H K``.
    max_px : float
        Largest distance over the frame between ``H x`` and ``K_r R K^-1 x``
        in rectified pixels (0 up to rounding for camera-based rectification).
    """
    rect = camera.rectification
    M = np.linalg.inv(rect.K_rect) @ rect.H @ camera.K
    M = M / np.cbrt(np.linalg.det(M))
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    width, height = camera.image_size
    corners = np.array([[0, 0, 1], [width - 1, 0, 1], [0, height - 1, 1], [width - 1, height - 1, 1],
                        [(width - 1) / 2, (height - 1) / 2, 1]], float)
    exact = corners @ rect.H.T
    rotated = corners @ (rect.K_rect @ R @ np.linalg.inv(camera.K)).T
    distance = np.linalg.norm(exact[:, :2] / exact[:, 2:] - rotated[:, :2] / rotated[:, 2:], axis=1)
    return R, float(distance.max())


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write one camera or a stereo pair as OpenCV FileStorage (see the module docstring)."""
    import cv2

    _check_suffix(out)
    chosen = select_cameras(rig, cameras)
    if len(chosen) > 2:
        raise CamcalError(f"an OpenCV file holds one camera or a stereo pair; the rig has {len(chosen)} cameras "
                          f"({', '.join(c.name for c in chosen)}): choose one or two with --camera")
    fisheye = [camera.distortion.is_fisheye for camera in chosen]
    if any(fisheye) and not all(fisheye):
        raise CamcalError(f"an OpenCV stereo file holds two cv2.fisheye lenses or two pinhole lenses; "
                          f"{chosen[fisheye.index(True)].name!r} is {_FISHEYE}, "
                          f"{chosen[fisheye.index(False)].name!r} {chosen[fisheye.index(False)].distortion.model}")
    fisheye = all(fisheye)
    converted, conversions = [], []
    for camera in chosen:
        # a thin-prism fisheye goes as the nearest cv2.fisheye lens (k1..k4), its residual printed
        camera_out, conversion = nearest_camera(camera, _holds_fisheye if fisheye else _holds,
                                                _FISHEYE if fisheye else "opencv",
                                                _FISHEYE_FORMAT if fisheye else _format(camera.distortion))
        converted.append(camera_out)
        conversions.append(conversion)
    notes = []
    if rig.frames:
        notes.append(f"the rig's {len(rig.frames)} frame pose(s) are not written (OpenCV files hold one pose)")
    with atomic_path(out) as tmp:
        storage = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            if fisheye:
                storage.write("fisheye_model", 1)
            if len(converted) == 1:
                _write_single(storage, converted[0])
            else:
                notes.extend(_write_stereo(storage, *converted))
        finally:
            storage.release()
    return ExportResult((out,), tuple(conversions), tuple(notes))


def _write_single(storage, camera: Camera) -> None:
    width, height = camera.image_size
    storage.write("camera_name", camera.name)
    storage.write("image_width", width)
    storage.write("image_height", height)
    storage.write("camera_matrix", camera.K)
    storage.write("distortion_coefficients", _coefficients(camera.distortion))


def _cross(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _write_stereo(storage, first: Camera, second: Camera) -> list[str]:
    if first.image_size != second.image_size:
        raise CamcalError(f"an OpenCV stereo file holds one image size; {first.name!r} is "
                          f"{first.image_size[0]}x{first.image_size[1]}, {second.name!r} "
                          f"{second.image_size[0]}x{second.image_size[1]}")
    R = second.R @ first.R.T
    T = second.R @ (first.c - second.c)
    E = _cross(T) @ R
    F = np.linalg.inv(second.K).T @ E @ np.linalg.inv(first.K)
    width, height = first.image_size
    storage.write("image_width", width)
    storage.write("image_height", height)
    storage.write("camera_name_1", first.name)
    storage.write("camera_name_2", second.name)
    for key, value in (("K1", first.K), ("D1", _coefficients(first.distortion)), ("K2", second.K),
                       ("D2", _coefficients(second.distortion)), ("R", R), ("T", T.reshape(3, 1)),
                       ("E", E), ("F", F / F[2, 2] if F[2, 2] != 0 else F)):
        storage.write(key, value)
    if first.rectification is None or second.rectification is None:
        return []
    (R1, err1), (R2, err2) = rectification_rotation(first), rectification_rotation(second)
    world_to_rect_1, world_to_rect_2 = R1 @ first.R, R2 @ second.R
    frame_gap = np.abs(world_to_rect_1 - world_to_rect_2).max()
    if max(err1, err2) > _ROTATION_TOL_PX or frame_gap > 1e-9:
        return [f"rectification not written: it is not a rotation into one common frame as OpenCV's is "
                f"(H off a rotation by {max(err1, err2):.3g} px, frames differ by {frame_gap:.3g})"]
    K_r1, K_r2 = first.rectification.K_rect, second.rectification.K_rect
    t = world_to_rect_2 @ (first.c - second.c)
    P1 = np.hstack([K_r1, np.zeros((3, 1))])
    P2 = np.hstack([K_r2, (K_r2 @ t).reshape(3, 1)])
    Q = np.array([[1.0, 0.0, 0.0, -K_r1[0, 2]], [0.0, 1.0, 0.0, -K_r1[1, 2]], [0.0, 0.0, 0.0, K_r1[0, 0]],
                  [0.0, 0.0, -1.0 / t[0], (K_r1[0, 2] - K_r2[0, 2]) / t[0]]])
    for key, value in (("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2), ("Q", Q)):
        storage.write(key, value)
    rect_width, rect_height = first.rectification.image_size
    storage.write("rectified_width", rect_width)
    storage.write("rectified_height", rect_height)
    return []


# -- reading ---------------------------------------------------------------------


def load(path: Path) -> ImportResult:
    """Read a FileStorage file with one camera or a stereo pair (see the module docstring)."""
    import cv2

    _check_suffix(path)
    check_file_size(path, FILE_BYTES, "OpenCV file")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:  # a parse error surfaces as SystemError from the binding
        reason = str(getattr(error, "__cause__", None) or error).strip().splitlines()[-1]
        raise CamcalError(f"{path}: not an OpenCV FileStorage file ({reason})") from None
    try:
        if not storage.isOpened():
            raise CamcalError(f"{path}: not an OpenCV FileStorage file")
        keys = set(storage.root().keys())
        fisheye = _fisheye_flag(storage, keys)
        if {"K1", "K2"} & keys:
            rig = _read_stereo(storage, keys, fisheye)
        elif "camera_matrix" in keys:
            rig = Rig((_read_camera(storage, "camera_matrix", "distortion_coefficients",
                                    _text(storage, "camera_name") or "camera", _size(storage, keys),
                                    np.eye(3), np.zeros(3), fisheye),), units="unknown")
        elif {"D1", "D2", "R", "T"} & keys:
            raise CamcalError("a stereo file needs K1, D1, K2, D2, R and T; K1/K2 are missing")
        else:
            raise CamcalError("no camera_matrix (one camera) and no K1, K2 (stereo pair) in the file")
    except cv2.error as error:  # a node of the wrong kind (a matrix without dt, a root that is no map...)
        reason = str(error).strip().splitlines()[-1].split(" error: ", 1)[-1]
        raise CamcalError(f"{path}: OpenCV cannot read the file ({reason})") from None
    except UnicodeDecodeError as error:  # a key or a string that is not UTF-8
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start} of a key or a string)") from None
    finally:
        storage.release()
    conversions = tuple(LensConversion(c.name, _format(c.distortion), c.distortion.model, True) for c in rig.cameras)
    return ImportResult(rig, conversions, ("the first camera is the origin; units are those of T",))


def _declared_elements(node, key: str) -> float:
    """rows x cols an ``!!opencv-matrix`` declares, read before OpenCV allocates them."""
    if not node.isMap():
        return 0.0
    sizes = [node.getNode(name) for name in ("rows", "cols")]
    if any(not (size.isInt() or size.isReal()) for size in sizes):
        raise CamcalError(f"{key} is not a matrix (rows and cols must be numbers)")
    rows, cols = (size.real() for size in sizes)
    if not all(np.isfinite(v) and v == int(v) and v >= 0 for v in (rows, cols)):
        raise CamcalError(f"{key} declares {rows} x {cols}: rows and cols must be non-negative integers")
    return rows * cols


def _matrix(storage, key: str, shape: tuple[int, ...] | None = None, max_elements: int = _MAX_COEFFICIENTS
            ) -> NDArray[np.float64]:
    """A finite matrix of ``shape`` (any shape up to ``max_elements`` when None), its declared size checked first."""
    node = storage.getNode(key)
    if node.empty() or node.isNone():
        raise CamcalError(f"missing {key}")
    limit = int(np.prod(shape)) if shape is not None else max_elements
    declared = _declared_elements(node, key)
    if declared > limit:
        rows, cols = (int(node.getNode(name).real()) for name in ("rows", "cols"))
        raise CamcalError(f"{key} declares {rows} x {cols} values, expected at most {limit}")
    value = node.mat()
    if value is None:
        raise CamcalError(f"{key} is not a matrix")
    value = np.asarray(value, dtype=np.float64)
    if shape is not None and value.size == int(np.prod(shape)):
        value = value.reshape(shape)
    if shape is not None and value.shape != shape:
        raise CamcalError(f"{key} must be {'x'.join(map(str, shape))}, got {'x'.join(map(str, value.shape))}")
    if not np.all(np.isfinite(value)):
        raise CamcalError(f"{key} contains NaN or infinite values")
    return value


def _text(storage, key: str) -> str | None:
    node = storage.getNode(key)
    return None if node.empty() or not node.isString() else node.string()


def _size(storage, keys: set[str]) -> tuple[int, int]:
    if {"image_width", "image_height"} <= keys:
        return _pixels(storage.getNode("image_width").real(), storage.getNode("image_height").real(), "image size")
    if "image_size" in keys or "imageSize" in keys:
        node = storage.getNode("image_size" if "image_size" in keys else "imageSize")
        if not node.isSeq() or node.size() != 2:
            raise CamcalError("image_size must be a sequence [width, height]")
        return _pixels(node.at(0).real(), node.at(1).real(), "image size")
    raise CamcalError("no image size (image_width and image_height) in the file")


def _pixels(width: float, height: float, what: str) -> tuple[int, int]:
    if not (np.isfinite(width) and np.isfinite(height) and width == int(width) and height == int(height)
            and width > 0 and height > 0):
        raise CamcalError(f"{what} must be two positive integers, got {width} x {height}")
    return int(width), int(height)


def _fisheye_flag(storage, keys: set[str]) -> bool:
    """``fisheye_model``: absent or 0 for OpenCV's pinhole lens, 1 for ``cv2.fisheye``."""
    if "fisheye_model" not in keys:
        return False
    node = storage.getNode("fisheye_model")
    value = node.real() if node.isInt() or node.isReal() else None
    if value not in (0.0, 1.0):
        raise CamcalError(f"fisheye_model must be 0 or 1, got {node.string() if node.isString() else value!r}")
    return value == 1.0


def _distortion(storage, key: str, fisheye: bool) -> Distortion:
    values = _matrix(storage, key).ravel()
    if fisheye:
        if len(values) != 4:
            raise CamcalError(f"{key} has {len(values)} coefficients; a cv2.fisheye lens (fisheye_model: 1) has 4")
        return Distortion(_FISHEYE, dict(zip(("k1", "k2", "k3", "k4"), values)))
    try:
        return Distortion.from_opencv_coefficients(values)
    except CamcalError as error:
        raise CamcalError(f"{key}: {error}") from None


def _read_camera(storage, K_key: str, D_key: str, name: str, size: tuple[int, int], R, c, fisheye: bool) -> Camera:
    try:
        return Camera(name, size, _matrix(storage, K_key, (3, 3)), _distortion(storage, D_key, fisheye), R, c)
    except CamcalError as error:
        raise CamcalError(f"camera {name!r}: {error}") from None


def _read_stereo(storage, keys: set[str], fisheye: bool) -> Rig:
    missing = [key for key in ("K1", "D1", "K2", "D2", "R", "T") if key not in keys]
    if missing:
        raise CamcalError(f"a stereo file needs K1, D1, K2, D2, R and T; missing {', '.join(missing)}")
    size = _size(storage, keys)
    names = (_text(storage, "camera_name_1") or "left", _text(storage, "camera_name_2") or "right")
    if names[0] == names[1]:
        names = (names[0] + "_1", names[1] + "_2")
    R, T = _matrix(storage, "R", (3, 3)), _matrix(storage, "T", (3,))
    first = _read_camera(storage, "K1", "D1", names[0], size, np.eye(3), np.zeros(3), fisheye)
    second = _read_camera(storage, "K2", "D2", names[1], size, R, -R.T @ T, fisheye)
    rectified = {"R1", "R2", "P1", "P2"} <= keys
    if rectified:
        rect_size = size
        if {"rectified_width", "rectified_height"} <= keys:
            rect_size = _pixels(storage.getNode("rectified_width").real(), storage.getNode("rectified_height").real(),
                                "rectified size")
        cameras = []
        for camera, R_key, P_key in ((first, "R1", "P1"), (second, "R2", "P2")):
            R_rect, P = _matrix(storage, R_key, (3, 3)), _matrix(storage, P_key, (3, 4))
            K_rect = P[:, :3]
            H = K_rect @ R_rect @ np.linalg.inv(camera.K)
            cameras.append(Camera(camera.name, camera.image_size, camera.K, camera.distortion, camera.R, camera.c,
                                  rectification=Rectification(H, K_rect, rect_size)))
        first, second = cameras
    return Rig((first, second), units="unknown")

