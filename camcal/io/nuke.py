"""Nuke scripts (``.nk``): a Camera3 node per camera and an STMap chain for its lens.

Camera3 (classic 3D system; looks down -Z with +Y up, Nuke's world +Y up).
Nuke's world is camcal's turned half a turn about x (``X_nuke = D X``,
``D = diag(1, -1, -1)``, as in :mod:`camcal.io.usd`); the camera's
local-to-world rotation is ``D R^T D`` written as ``rotate`` with
``rot_order XYZ`` (x first: ``M = R_z R_y R_x``, degrees) and its position
``translate = D c``. Intrinsics, with the film back ``haperture`` the sensor
width in mm (36 without one)::

    focal         = fx haperture / W
    vaperture     = haperture H / W
    win_translate = ((cx - W/2 + 0.5) 2 / W,  (H/2 - 0.5 - cy) 2 / W)

Nuke's camera projection has one focal scale for x and y (the format's
pixel aspect does the rest) and no skew: a camera with ``fx != fy`` or skew
is written with ``fx`` and no skew and the max pixel residual of the
(undistorted) projection is reported.
A moving rig animates ``translate`` and ``rotate`` with one key per frame
(``{curve x<frame> value ...}``). The image size and the camcal lens are
kept on the node as user knobs (``image_width``, ``image_height``,
``lens_model``, ``lens_params``, ``lens_center``) so that the import
reads them back.

Lens: for every camera with a lens, the ST-maps (:mod:`camcal.io.stmap`)
are written beside the script, ``<script>_stmaps/<camera>_undistort.exr``
and ``..._redistort.exr``, and the script holds the chain
``Read (plate) -> STMap (undistort map) -> ... -> STMap (redistort map)``,
each STMap taking its source on input 0 and the map on input 1.

No Nuke was available to check these files: the conventions above are the
ones Foundry documents for Camera3 and STMap; the tests check the script's
syntax (balanced braces, one node per camera) and the numbers against this
docstring's formulas.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_write_text
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    ExportResult,
    ImportResult,
    LensConversion,
    max_pixel_residual,
    select_cameras,
)
from camcal.model.rig import Camera, Frame, Rig

__all__ = ["DEFAULT_HAPERTURE_MM", "nuke_intrinsics", "export", "load"]

#: Film back width of cameras without ``sensor_width_mm``.
DEFAULT_HAPERTURE_MM = 36.0

_D = np.diag([1.0, -1.0, -1.0])


def nuke_intrinsics(camera: Camera) -> dict[str, float | tuple[float, float]]:
    """``focal``, ``haperture``, ``vaperture`` and ``win_translate`` of a camera (see the module docstring)."""
    width, height = camera.image_size
    K = camera.K
    haperture = camera.sensor_width_mm or DEFAULT_HAPERTURE_MM
    return {
        "focal": K[0, 0] * haperture / width,
        "haperture": haperture,
        "vaperture": haperture * height / width,
        "win_translate": ((K[0, 2] - width / 2 + 0.5) * 2 / width, (height / 2 - 0.5 - K[1, 2]) * 2 / width),
    }


def _K_from_nuke(focal: float, haperture: float, win_translate, image_size: tuple[int, int]) -> np.ndarray:
    width, height = image_size
    f = focal * width / haperture
    cx = win_translate[0] * width / 2 + width / 2 - 0.5
    cy = height / 2 - 0.5 - win_translate[1] * width / 2
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def _transform(R: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nuke ``translate`` and ``rotate`` (degrees, rot_order XYZ) of a camcal pose."""
    return _D @ c, Rotation.from_matrix(_D @ R.T @ _D).as_euler("xyz", degrees=True)


def _number(value: float) -> str:
    return repr(float(value))


def _knob(values: np.ndarray, frames: list[int] | None) -> str:
    """A 3-vector knob, constant or animated with one key per frame."""
    if frames is None:
        return "{" + " ".join(_number(v) for v in values) + "}"
    curves = []
    for axis in range(3):
        keys = " ".join(f"x{frame} {_number(values[i][axis])}" for i, frame in enumerate(frames))
        curves.append("{curve " + keys + "}")
    return "{" + " ".join(curves) + "}"


def _node_name(name: str) -> str:
    return re.sub(r"\W", "_", name) if re.match(r"[A-Za-z_]", name) else "cam_" + re.sub(r"\W", "_", name)


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write the script (and the ST-maps of cameras with a lens) (see the module docstring)."""
    from camcal.io.stmap import write_stmaps

    if out.suffix.lower() != ".nk":
        raise CamcalError(f"a Nuke script must end in .nk, got {out.name!r}")
    chosen = select_cameras(rig, cameras)
    frames = [frame.index for frame in rig.frames] or None
    names = [_node_name(camera.name) for camera in chosen]
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names {', '.join(c.name for c in chosen)} give repeated Nuke node names")
    lines = ["#! nuke script written by camcal", "version 15.1 v1", "Root {", " inputs 0",
             f" first_frame {frames[0] if frames else 1}", f" last_frame {frames[-1] if frames else 1}", "}"]
    conversions, written = [], []
    map_dir = out.with_name(out.stem + "_stmaps")
    for index, (camera, node) in enumerate(zip(chosen, names)):
        # one focal scale and no skew; the lens goes through the ST-maps, exactly
        K = camera.K.copy()
        K[0, 1], K[1, 1] = 0.0, K[0, 0]
        converted = Camera(camera.name, camera.image_size, K, camera.distortion, camera.R, camera.c,
                           camera.sensor_width_mm)
        exact = np.array_equal(K, camera.K)
        source = f"{camera.distortion.model}{' with skew' if camera.K[0, 1] else ''}" + (
            "" if camera.K[1, 1] == camera.K[0, 0] else ", fx != fy")
        conversion = LensConversion(camera.name, source, "Nuke Camera3 (+ ST-maps for the lens)", exact,
                                    0.0 if exact else max_pixel_residual(camera, converted, lens=False),
                                    "one focal scale, no skew")
        conversions.append(conversion)
        if frames:
            posed = [rig.camera_at_frame(camera.name, f) for f in frames]
            poses = [_transform(p.R, p.c) for p in posed]
            translate, rotate = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
        else:
            translate, rotate = _transform(camera.R, camera.c)
        intr = nuke_intrinsics(converted)
        width, height = camera.image_size
        lens = camera.distortion
        lines += [
            "Camera3 {", " inputs 0", " rot_order XYZ",
            f" translate {_knob(translate, frames)}", f" rotate {_knob(rotate, frames)}",
            f" focal {_number(intr['focal'])}", f" haperture {_number(intr['haperture'])}",
            f" vaperture {_number(intr['vaperture'])}",
            f" win_translate {{{_number(intr['win_translate'][0])} {_number(intr['win_translate'][1])}}}",
            f" name {node}", f" xpos {index * 150}", " ypos 0",
            " addUserKnob {20 camcal l camcal}",
            " addUserKnob {1 camera_name}", f' camera_name "{camera.name}"',
            " addUserKnob {3 image_width}", f" image_width {width}",
            " addUserKnob {3 image_height}", f" image_height {height}",
            " addUserKnob {1 lens_model}", f' lens_model "{lens.model}"',
            " addUserKnob {1 lens_params}",
            ' lens_params "' + " ".join(f"{k}={_number(v)}" for k, v in lens.params.items()) + '"',
            " addUserKnob {1 lens_center}",
            ' lens_center "' + ("" if lens.center is None else f"{_number(lens.center[0])} {_number(lens.center[1])}") + '"',
            "}",
        ]
        if not lens.is_identity:
            undistort, redistort, _ = write_stmaps(rig, camera.name, map_dir)
            written += [undistort, redistort]
            lines += [
                "Read {", " inputs 0", f' file "{node}_plate.####.exr"', f" name {node}_plate",
                f" xpos {index * 150}", " ypos 100", "}",
                "Read {", " inputs 0", f' file "{undistort.resolve()}"', " raw true", f" name {node}_undistort_map",
                f" xpos {index * 150 + 100}", " ypos 100", "}",
                "STMap {", " inputs 2", " channels rgba", " uv rgb", f" name {node}_undistort",
                f" xpos {index * 150}", " ypos 200", "}",
                "Read {", " inputs 0", f' file "{redistort.resolve()}"', " raw true", f" name {node}_redistort_map",
                f" xpos {index * 150 + 100}", " ypos 300", "}",
                "STMap {", " inputs 2", " channels rgba", " uv rgb", f" name {node}_redistort",
                f" xpos {index * 150}", " ypos 400", "}",
            ]
    notes = []
    if rig.points is not None:
        notes.append("sparse points are not written to Nuke (export USD for a point cloud)")
    if written:
        notes.append(f"ST-maps of {len(written) // 2} camera(s) written to {map_dir}; the plate Read nodes "
                     "name a placeholder file to replace")
    atomic_write_text(out, "\n".join(lines) + "\n")
    return ExportResult((out, *written), tuple(conversions), tuple(notes))


# -- reading: the Camera3 nodes (camcal's and Nuke's own, static or keyed) ----------------


def _blocks(text: str) -> list[str]:
    """Bodies of the Camera3 / Camera2 / Camera nodes."""
    bodies = []
    for match in re.finditer(r"^Camera[23]? \{", text, flags=re.M):
        depth, position = 1, match.end()
        while depth and position < len(text):
            depth += {"{": 1, "}": -1}.get(text[position], 0)
            position += 1
        if depth:
            raise CamcalError("unbalanced braces in a Camera node")
        bodies.append(text[match.end():position - 1])
    return bodies


def _knob_text(body: str, name: str) -> str | None:
    match = re.search(rf"^\s*{name} (.+)$", body, flags=re.M)
    return None if match is None else match.group(1).strip()


def _float(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CamcalError(f"{where}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise CamcalError(f"{where} is not finite")
    return value


def _vector(text: str | None, where: str) -> tuple[np.ndarray | dict[int, np.ndarray], bool]:
    """A 3-vector knob: constant, or {curve x<f> v ...} per axis -> (values per frame, animated)."""
    if text is None:
        return np.zeros(3), False
    if "curve" not in text:
        values = text.strip("{}").split()
        if len(values) != 3:
            raise CamcalError(f"{where} must hold 3 numbers")
        return np.array([_float(v, where) for v in values]), False
    curves = re.findall(r"\{curve ([^{}]*)\}", text)
    if len(curves) != 3:
        raise CamcalError(f"{where}: expected a curve per axis")
    keyed: dict[int, np.ndarray] = {}
    for axis, curve in enumerate(curves):
        frame = None
        for token in curve.split():
            if token.startswith("x"):
                frame = int(_float(token[1:], where))
                continue
            if frame is None:
                raise CamcalError(f"{where}: a key without a frame")
            keyed.setdefault(frame, np.zeros(3))[axis] = _float(token, where)
            frame += 1
    return keyed, True


def load(path: Path) -> ImportResult:
    """Read the Camera3 nodes of a script (see the module docstring)."""
    check_file_size(path, FILE_BYTES, "Nuke script")
    text = path.read_text(errors="replace")
    bodies = _blocks(text)
    if not bodies:
        raise CamcalError("no Camera3 node in the script")
    cameras, conversions, animated = [], [], []
    for body in bodies:
        node = _knob_text(body, "name") or f"Camera{len(cameras) + 1}"
        where = f"camera node {node}"
        width, height = _knob_text(body, "image_width"), _knob_text(body, "image_height")
        if width is None or height is None:
            raise CamcalError(f"{where} has no image_width / image_height knobs (Nuke cameras hold no image size)")
        size = (int(_float(width, where)), int(_float(height, where)))
        focal = _float(_knob_text(body, "focal") or "50", f"{where} focal")
        haperture = _float(_knob_text(body, "haperture") or "24.576", f"{where} haperture")
        if focal <= 0 or haperture <= 0:
            raise CamcalError(f"{where}: focal and haperture must be positive")
        win = (_knob_text(body, "win_translate") or "{0 0}").strip("{}").split()
        K = _K_from_nuke(focal, haperture, [_float(v, f"{where} win_translate") for v in win], size)
        model = (_knob_text(body, "lens_model") or '"none"').strip('"')
        params = {}
        for item in (_knob_text(body, "lens_params") or '""').strip('"').split():
            key, _, value = item.partition("=")
            params[key] = _float(value, f"{where} lens_params")
        centre_text = (_knob_text(body, "lens_center") or '""').strip('"').split()
        centre = tuple(_float(v, f"{where} lens_center") for v in centre_text) or None
        order = (_knob_text(body, "rot_order") or "ZXY").lower()
        if sorted(order) != ["x", "y", "z"]:
            raise CamcalError(f"{where}: unknown rot_order {order!r}")
        translate, moving_t = _vector(_knob_text(body, "translate"), f"{where} translate")
        rotate, moving_r = _vector(_knob_text(body, "rotate"), f"{where} rotate")
        name = (_knob_text(body, "camera_name") or node).strip('"')
        try:
            distortion = Distortion(model, params, centre)
            if moving_t or moving_r:
                keys = sorted(translate if moving_t else rotate)
                poses = {f: _pose_order((translate[f] if moving_t else translate), (rotate[f] if moving_r else rotate),
                                        order) for f in keys}
                animated.append(poses)
                R, c = poses[keys[0]]
            else:
                R, c = _pose_order(translate, rotate, order)
                animated.append(None)
            cameras.append(Camera(name, size, K, distortion, R, c))
        except CamcalError as error:
            raise CamcalError(f"{where}: {error}") from None
        conversions.append(LensConversion(name, "Nuke Camera3", distortion.model, True))
    if all(a is None for a in animated):
        return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions))
    return ImportResult(_moving(cameras, animated), tuple(conversions), ("frames from the keyed cameras",))


def _pose_order(translate: np.ndarray, rotate: np.ndarray, order: str) -> tuple[np.ndarray, np.ndarray]:
    M = Rotation.from_euler(order, rotate, degrees=True).as_matrix()
    return _D @ M.T @ _D, _D @ translate


def _moving(cameras: list[Camera], animated: list) -> Rig:
    """A moving rig: the first camera's keys give the frames, every camera keeps its pose relative to it."""
    reference = animated[0]
    if reference is None or any(a is not None and sorted(a) != sorted(reference) for a in animated):
        raise CamcalError("the cameras are keyed on different frames")
    frames, rig_cameras = [], []
    first = sorted(reference)[0]
    for index in sorted(reference):
        R, c = reference[index]
        frames.append(Frame(index, R, c))
    R0, c0 = reference[first]
    for camera, poses in zip(cameras, animated):
        R, c = poses[first] if poses is not None else (camera.R, camera.c)
        rig_cameras.append(Camera(camera.name, camera.image_size, camera.K, camera.distortion, R @ R0.T, R0 @ (c - c0)))
    return Rig(tuple(rig_cameras), units="unknown", frames=tuple(frames))
