"""COLMAP's text model (``cameras.txt``, ``images.txt``, ``points3D.txt``) for camcal rigs.

The camera models and the half-pixel shift are :mod:`camcal.model.colmap`'s
exact mappings; this module writes and reads COLMAP's documented text
layout (colmap.github.io/format.html)::

    cameras.txt    CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]
    images.txt     IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME
                   POINTS2D[] as (X Y POINT3D_ID), here empty
    points3D.txt   POINT3D_ID X Y Z R G B ERROR TRACK[], here no track

``(QW, QX, QY, QZ, T)`` is ``cam_from_world``: ``R`` as a unit quaternion
(scalar first) and ``T = -R c``. A static rig gives one image per camera,
named after it; a moving rig one image per camera and frame, named by the
frame's image path when the rig has one, else ``<camera>/<frame>``. The
rig's sparse points (its PLY) become ``points3D.txt`` with empty tracks.

Reading gives one camcal camera per image (world poses, a static rig),
named after the image without its suffix; COLMAP's rigs / frames files are
not read. camcal's ``kannala-brandt`` lens is COLMAP's OPENCV_FISHEYE
(exact). Lenses COLMAP cannot hold exactly (a division lens off the
principal point or with fx != fy) are fitted with the nearest OPENCV /
FULL_OPENCV lens and skew is dropped, with the max pixel residual reported.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path, PurePosixPath

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.camera import from_colmap, to_colmap
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_dir
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.model.colmap import camera_from_colmap, camera_to_colmap
from camcal.io.conversion import ExportResult, ImportResult, LensConversion, nearest_camera, select_cameras
from camcal.io.ply import read_points_ply
from camcal.io.points_csv import finite_numbers
from camcal.model.rig import Camera, Rig

__all__ = ["FILES", "export", "load"]

FILES = ("cameras.txt", "images.txt", "points3D.txt")


def _number(value: float) -> str:
    return repr(float(value))


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write the three text files into the directory ``out`` (see the module docstring)."""
    if out.exists() and not out.is_dir():
        raise CamcalError(f"a COLMAP text model is a directory; {out} is a file")
    chosen = select_cameras(rig, cameras)
    camera_lines, conversions, colmap_ids = [], [], {}
    for camera_id, camera in enumerate(chosen, start=1):
        def holds(distortion: Distortion, camera=camera) -> bool:
            K = camera.K.copy()
            K[0, 1] = 0.0  # skew is dropped whatever the lens: a lens COLMAP holds is kept (a fisheye stays one)
            try:
                camera_to_colmap(Camera(camera.name, camera.image_size, K, distortion, camera.R, camera.c))
            except CamcalError:
                return False
            return True

        converted, conversion = nearest_camera(camera, holds, "opencv", "COLMAP")
        model = camera_to_colmap(converted)
        conversions.append(LensConversion(conversion.camera, conversion.source, f"COLMAP {model.model}",
                                          conversion.exact, conversion.max_px, refit=conversion.refit))
        camera_lines.append(" ".join([str(camera_id), model.model, str(model.width), str(model.height),
                                      *map(_number, model.params)]))
        colmap_ids[camera.name] = camera_id
    image_lines = []
    poses = []
    if rig.frames:
        for frame in rig.frames:
            for camera in chosen:
                posed = rig.camera_at_frame(camera.name, frame.index)
                name = frame.images.get(camera.name, f"{camera.name}/{frame.index}")
                poses.append((posed, name))
    else:
        poses = [(camera, camera.name) for camera in chosen]
    for image_id, (camera, name) in enumerate(poses, start=1):
        if any(ch.isspace() for ch in name):
            raise CamcalError(f"COLMAP image names cannot hold spaces: {name!r}")
        quat_xyzw, t = to_colmap(camera.R, camera.c)
        qx, qy, qz, qw = quat_xyzw
        image_lines += [" ".join([str(image_id), *map(_number, (qw, qx, qy, qz, *t)),
                                  str(colmap_ids[camera.name]), name]), ""]
    point_lines = []
    notes = []
    if rig.points is not None:
        if rig_path is None:
            notes.append(f"points {rig.points!r} not written: the rig file's folder is unknown")
        else:
            points = read_points_ply(rig_path.parent / rig.points)
            for point_id, point in enumerate(points, start=1):
                point_lines.append(" ".join([str(point_id), *map(_number, (point["x"], point["y"], point["z"])),
                                             str(point["red"]), str(point["green"]), str(point["blue"]), "0"]))
    header = "# written by camcal (COLMAP text model, colmap.github.io/format.html)\n"
    texts = {
        "cameras.txt": header + "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: {len(camera_lines)}\n" + "".join(line + "\n" for line in camera_lines),
        "images.txt": header + "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "# POINTS2D[] as (X, Y, POINT3D_ID)\n"
        f"# Number of images: {len(poses)}, mean observations per image: 0\n"
        + "".join(line + "\n" for line in image_lines),
        "points3D.txt": header + "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        f"# Number of points: {len(point_lines)}, mean track length: 0\n" + "".join(line + "\n" for line in point_lines),
    }
    with atomic_dir(out) as staging:
        for name in FILES:
            (staging / name).write_text(texts[name], encoding="utf-8")
    return ExportResult(tuple(Path(out) / name for name in FILES), tuple(conversions), tuple(notes))


# -- reading ---------------------------------------------------------------------


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    """Non-comment lines as (line number, fields); blank lines kept (images.txt pairs them)."""
    check_file_size(path, FILE_BYTES, "COLMAP text file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path.name} is not UTF-8 text (byte {error.start})") from None
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        if line.startswith("#"):
            continue
        rows.append((number, line.split()))
    return rows


def load(path: Path) -> ImportResult:
    """Read a COLMAP text model directory (see the module docstring)."""
    if not path.is_dir():
        raise CamcalError("a COLMAP text model is a directory holding cameras.txt and images.txt")
    for name in FILES[:2]:
        if not (path / name).is_file():
            binary = (path / name.replace(".txt", ".bin")).is_file()
            raise CamcalError(f"no {name} in the directory" + (
                " (it holds the binary model: convert it with `colmap model_converter --output_type TXT`)"
                if binary else ""))
    intrinsics = {}
    for number, fields in _rows(path / "cameras.txt"):
        if not fields:
            continue
        where = f"cameras.txt line {number}"
        if len(fields) < 5:
            raise CamcalError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        try:
            camera_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
        except ValueError:
            raise CamcalError(f"{where}: CAMERA_ID, WIDTH and HEIGHT must be integers") from None
        intrinsics[camera_id] = (fields[1], (width, height), finite_numbers(fields[4:], where))
    cameras, conversions, names = [], [], set()
    image_rows = _rows(path / "images.txt")
    for row, (number, fields) in enumerate(image_rows):
        if row % 2 == 1:
            continue  # the POINTS2D line of the image above
        where = f"images.txt line {number}"
        if len(fields) != 10:
            raise CamcalError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        qw, qx, qy, qz, tx, ty, tz = finite_numbers(fields[1:8], where)
        camera_id = int(fields[8]) if fields[8].isdigit() else -1
        if camera_id not in intrinsics:
            raise CamcalError(f"{where}: camera {fields[8]} is not in cameras.txt")
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        if not 0.5 < norm < 2.0:
            raise CamcalError(f"{where}: the quaternion is not a rotation (norm {norm:.3g})")
        R, c = from_colmap([qx, qy, qz, qw], [tx, ty, tz])
        name = str(PurePosixPath(fields[9]).with_suffix("")).replace("/", "_")
        if name in names:
            name = f"{name}_{fields[0]}"
        names.add(name)
        model, size, params = intrinsics[camera_id]
        try:
            cameras.append(camera_from_colmap(name, model, size, params, R, c))
        except CamcalError as error:
            raise CamcalError(f"{where}: {error}") from None
        conversions.append(LensConversion(name, f"COLMAP {model}", cameras[-1].distortion.model, True))
    if not cameras:
        raise CamcalError("images.txt holds no image")
    xyz, rgb = _points(path / "points3D.txt")
    return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions),
                        ("one camera per image, at its world pose; COLMAP's units are arbitrary",), xyz, rgb)


def _points(path: Path) -> tuple[NDArray[np.float64] | None, NDArray[np.uint8] | None]:
    if not path.is_file():
        return None, None
    xyz, rgb = [], []
    for number, fields in _rows(path):
        if not fields:
            continue
        where = f"points3D.txt line {number}"
        if len(fields) < 8:
            raise CamcalError(f"{where}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]")
        xyz.append(finite_numbers(fields[1:4], where))
        rgb.append(finite_numbers(fields[4:7], where))
    if not xyz:
        return None, None
    return np.array(xyz), np.clip(np.array(rgb), 0, 255).astype(np.uint8)
