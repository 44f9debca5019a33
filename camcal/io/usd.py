"""USD cameras for camcal rigs (usd-core, ``pxr``): Houdini, Maya, Nuke, Unreal and Blender read them.

Layout of the written stage (``.usda`` text, ``.usdc`` / ``.usd`` crate)::

    /rig                 Xform, the stage's default prim
    /rig/<camera>        UsdGeom.Camera per camera
    /rig/points          UsdGeom.Points: the rig's sparse points, with displayColor

Stage: ``upAxis = "Y"``, ``metersPerUnit`` from the rig's units (m, cm,
mm; others are written as metres and noted). USD's world is camcal's turned
half a turn about x, ``X_usd = D X_camcal`` with ``D = diag(1, -1, -1)``,
so that a camera at camcal's identity pose (looking down +z, y down) looks
down USD's -z with +y up, as a USD camera at identity does.

Camera (USD cameras look down -Z with +Y up, so the camera's local frame is
``D`` times OpenCV's): the local-to-world matrix (row vectors, as USD) has
rotation ``D R D`` and translation ``D c``. Intrinsics, with the aperture
``A_h`` the sensor width in mm (36 when the camera has none)::

    focalLength              = fx A_h / W
    horizontalAperture       = A_h
    verticalAperture         = focalLength H / fy
    horizontalApertureOffset = (W / 2 - 0.5 - cx) A_h / W
    verticalApertureOffset   = (cy - H / 2 + 0.5) A_v / H

so that USD's projection (``Gf.Camera`` frustum, NDC to pixels
``u = (x + 1) W / 2 - 0.5``, ``v = (1 - y) H / 2 - 0.5``) is camcal's
``K`` exactly. USD has no skew (dropped, residual reported) and no lens
model: the camcal lens (and ``K``, image size, camera-from-rig pose) is
kept in the camera's ``customData`` under ``camcal:*`` keys; renderers
ignore it, comp needs camcal's ST-maps (written and referenced there with
``stmaps=True``, ``camcal rig export --stmaps``). A moving rig writes one time
sample of the transform per frame (time code = frame number). A camera whose
lens changes over the frames (a zoom: :attr:`camcal.model.rig.Frame.lenses`)
gets a time sample per frame of ``focalLength``, both apertures and both
offsets as well (the default values are its own lens), and each frame's
exact ``K``, lens and lens state in ``customData`` ``camcal:lens_keys``;
reading gives the frames a lens where the samples differ from the first
frame's.

Reading: a camera camcal wrote gets its image size, exact ``K``, lens and
rig pose back from ``customData``. A plain USD camera (written by another
tool) holds no image size: :func:`load` takes it as ``image_size`` (``camcal
rig import --image-size W H``) and reads ``K`` from the attributes above
(the schema's fallback values where unauthored), with no lens. When the
aperture's aspect (``horizontalAperture / verticalAperture``) is not the
image's, the mapping above gives non-square pixels (``fx != fy``), as the
``Gf.Camera`` frustum does; a note says so, since renderers that conform
the aperture to the image (e.g. Hydra's fit policy) widen one side instead.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_path
from camcal.base.jsonfile import parse_json
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    ExportResult,
    ImportResult,
    LensConversion,
    max_pixel_residual,
    nearest_camera,
    select_cameras,
)
from camcal.io.ply import read_points_ply
from camcal.model.rig import Camera, Frame, Lens, Rig

__all__ = ["SUFFIXES", "METERS_PER_UNIT", "DEFAULT_APERTURE_MM", "usd_intrinsics", "export", "load"]

SUFFIXES = (".usda", ".usdc", ".usd")
#: Rig units USD's metersPerUnit can state.
METERS_PER_UNIT = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Horizontal aperture of cameras without ``sensor_width_mm`` (full frame).
DEFAULT_APERTURE_MM = 36.0

_D = np.diag([1.0, -1.0, -1.0])
#: The camera attributes that carry its intrinsics (sampled per frame where the lens changes).
_INTRINSICS = ("focalLength", "horizontalAperture", "verticalAperture", "horizontalApertureOffset",
               "verticalApertureOffset")
#: A per-frame lens's state kept in ``camcal:lens_keys``.
_LENS_STATE = ("focal_mm", "focus_m")
#: Below this, a projection difference is rounding, not a conversion.
_EXACT_PX = 1e-9


def usd_intrinsics(camera: Camera) -> dict[str, float]:
    """``focalLength``, apertures and aperture offsets that project like ``camera``'s K (see the module docstring)."""
    width, height = camera.image_size
    K = camera.K
    h_aperture = camera.sensor_width_mm or DEFAULT_APERTURE_MM
    focal = K[0, 0] * h_aperture / width
    v_aperture = focal * height / K[1, 1]
    return {
        "focalLength": focal,
        "horizontalAperture": h_aperture,
        "verticalAperture": v_aperture,
        "horizontalApertureOffset": (width / 2 - 0.5 - K[0, 2]) * h_aperture / width,
        "verticalApertureOffset": (K[1, 2] - height / 2 + 0.5) * v_aperture / height,
    }


def _K_from_usd(values: dict[str, float], image_size: tuple[int, int]) -> NDArray[np.float64]:
    width, height = image_size
    fx = values["focalLength"] * width / values["horizontalAperture"]
    fy = values["focalLength"] * height / values["verticalAperture"]
    cx = width / 2 - 0.5 - values["horizontalApertureOffset"] * width / values["horizontalAperture"]
    cy = height / 2 - 0.5 + values["verticalApertureOffset"] * height / values["verticalAperture"]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _matrix(R: NDArray[np.float64], c: NDArray[np.float64]):
    require("pxr")
    from pxr import Gf

    M = np.eye(4)
    M[:3, :3] = _D @ R @ _D
    M[3, :3] = _D @ c
    return Gf.Matrix4d(*M.ravel().tolist())


def _pose(matrix) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    M = np.array(matrix, dtype=np.float64).reshape(4, 4)
    if not np.all(np.isfinite(M)) or np.abs(M[:3, :3] @ M[:3, :3].T - np.eye(3)).max() > 1e-6:
        raise CamcalError("the camera's transform is not a rotation and a position (scaled, sheared or not finite)")
    U, _, Vt = np.linalg.svd(_D @ M[:3, :3] @ _D)
    return U @ Vt, _D @ M[3, :3]


def export(
    rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None, stmaps: bool = False
) -> ExportResult:
    """Write the rig as a USD stage (see the module docstring); with ``stmaps`` the lens ST-maps too.

    The maps go to ``<stage>_stmaps/<camera>_undistort.exr`` / ``_redistort.exr``
    (:func:`camcal.io.stmap.write_stmaps`) and the camera's customData
    ``camcal.stmap_undistort`` / ``camcal.stmap_redistort`` hold their paths
    relative to the stage; a camera whose lens changes per frame gets a pair
    per frame (:func:`camcal.io.stmap.write_stmap_frames`), its paths with
    ``%04d`` for the frame number.
    """
    require("pxr")
    from pxr import Sdf, Tf, Usd, UsdGeom, Vt

    from camcal.io.stmap import write_stmap_frames, write_stmaps

    if out.suffix.lower() not in SUFFIXES:
        raise CamcalError(f"a USD file must end in {', '.join(SUFFIXES)}, got {out.name!r}")
    notes = []
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    if rig.units not in METERS_PER_UNIT:
        notes.append(f"units {rig.units!r} are not a length USD knows: metersPerUnit written as 1 (metres)")
    UsdGeom.SetStageMetersPerUnit(stage, METERS_PER_UNIT.get(rig.units, 1.0))
    root = UsdGeom.Xform.Define(stage, "/rig")
    stage.SetDefaultPrim(root.GetPrim())
    stage.GetRootLayer().customLayerData = {"camcal:units": rig.units, "camcal:usd_from_camcal_world": "diag(1, -1, -1)"}
    if rig.frames:
        stage.SetStartTimeCode(min(f.index for f in rig.frames))
        stage.SetEndTimeCode(max(f.index for f in rig.frames))
    conversions, used, written = [], set(), []
    for camera in select_cameras(rig, cameras):
        converted, conversion = nearest_camera(camera, lambda d: True, "opencv", "UsdGeom.Camera (pinhole)")
        conversions.append(_float_attributes(camera, converted, conversion))
        name = Tf.MakeValidIdentifier(camera.name)
        if name in used or name == "points":
            raise CamcalError(f"camera names {camera.name!r} and another become the same USD prim name {name!r}")
        used.add(name)
        usd_camera = UsdGeom.Camera.Define(stage, f"/rig/{name}")
        for attribute, value in usd_intrinsics(converted).items():
            usd_camera.GetPrim().GetAttribute(attribute).Set(float(value))
        lens_keys = {}
        if rig.lens_frames(camera.name):  # a zoom: the intrinsics sampled per frame, each frame's lens in customData
            for frame in rig.frames:
                at = rig.camera_at_frame(camera.name, frame.index)
                at_converted, at_conversion = nearest_camera(at, lambda d: True, "opencv", "UsdGeom.Camera (pinhole)")
                at_conversion = _float_attributes(at, at_converted, at_conversion)
                if at_conversion.max_px > conversions[-1].max_px:
                    conversions[-1] = at_conversion
                for attribute, value in usd_intrinsics(at_converted).items():
                    usd_camera.GetPrim().GetAttribute(attribute).Set(float(value), Usd.TimeCode(frame.index))
                state = frame.lenses.get(camera.name)
                lens_keys[str(frame.index)] = {
                    "K": at_converted.K.tolist(), "distortion": at_converted.distortion.to_dict(),
                    **({} if state is None else {k: v for k, v in state.to_dict().items() if k in _LENS_STATE})}
        usd_camera.CreateProjectionAttr(UsdGeom.Tokens.perspective)
        op = usd_camera.AddTransformOp()
        if rig.frames:
            for frame in rig.frames:
                posed = rig.camera_at_frame(camera.name, frame.index)
                op.Set(_matrix(posed.R, posed.c), Usd.TimeCode(frame.index))
        else:
            op.Set(_matrix(camera.R, camera.c))
        custom = {} if camera.sensor_width_mm is None else {"sensor_width_mm": camera.sensor_width_mm}
        if stmaps and lens_keys:  # a pair of maps per frame: the paths with %04d for the frame number
            undistort_maps, redistort_maps, _ = write_stmap_frames(rig, camera.name, out.with_name(out.stem + "_stmaps"))
            written += [*undistort_maps, *redistort_maps]
            for key, path in (("stmap_undistort", undistort_maps[0]), ("stmap_redistort", redistort_maps[0])):
                sequence = path.with_name(path.name.replace(f".{rig.frames[0].index:04d}.", ".%04d."))
                custom[key] = Sdf.AssetPath(str(sequence.relative_to(out.parent)))
        elif stmaps and not camera.distortion.is_identity:
            undistort, redistort, _ = write_stmaps(rig, camera.name, out.with_name(out.stem + "_stmaps"))
            written += [undistort, redistort]
            custom["stmap_undistort"] = Sdf.AssetPath(str(undistort.relative_to(out.parent)))
            custom["stmap_redistort"] = Sdf.AssetPath(str(redistort.relative_to(out.parent)))
        usd_camera.GetPrim().SetCustomData({"camcal": {
            **custom,
            "name": camera.name,
            "image_size": Vt.IntArray(list(camera.image_size)),
            "K": json.dumps(converted.K.tolist()),
            "distortion": json.dumps(converted.distortion.to_dict()),
            "cam_from_rig": json.dumps({"R": camera.R.tolist(), "c": camera.c.tolist()}),
            **({"lens_keys": json.dumps(lens_keys)} if lens_keys else {}),
        }})
    if any(not camera.distortion.is_identity for camera in select_cameras(rig, cameras)):
        maps = ("its ST-maps are written beside the stage and referenced there" if stmaps
                else "`camcal stmap` (or --stmaps) makes the ST-maps to apply it in comp")
        notes.append(f"USD cameras have no lens distortion: renders are undistorted; the lens is in customData "
                     f"(camcal:distortion), {maps}")
    if rig.points is not None:
        if rig_path is None:
            notes.append(f"points {rig.points!r} not written: the rig file's folder is unknown")
        else:
            points = read_points_ply(rig_path.parent / rig.points)
            xyz = np.column_stack([points["x"], points["y"], points["z"]]) @ _D
            rgb = np.column_stack([points["red"], points["green"], points["blue"]]) / 255.0
            usd_points = UsdGeom.Points.Define(stage, "/rig/points")
            usd_points.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(xyz.astype(np.float32)))
            usd_points.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(Vt.Vec3fArray.FromNumpy(rgb.astype(np.float32)))
            usd_points.CreateWidthsAttr(Vt.FloatArray([0.01 / METERS_PER_UNIT.get(rig.units, 1.0)]))
            usd_points.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    with atomic_path(out) as tmp:
        if not stage.GetRootLayer().Export(str(tmp)):
            raise CamcalError(f"cannot write USD {out}")
    return ExportResult((out, *written), tuple(conversions), tuple(notes))


def _float32(values: dict[str, float]) -> dict[str, float]:
    return {name: float(np.float32(value)) for name, value in values.items()}


def _float_attributes(camera: Camera, converted: Camera, conversion: LensConversion) -> LensConversion:
    """The conversion as USD stores it: its camera attributes are 32-bit floats."""
    K = _K_from_usd(_float32(usd_intrinsics(converted)), converted.image_size)
    stored = Camera(camera.name, camera.image_size, K, converted.distortion, camera.R, camera.c)
    residual = max_pixel_residual(camera, stored, lens=False)
    if conversion.exact:
        exact = residual <= _EXACT_PX
        return LensConversion(camera.name, conversion.source, conversion.target, exact, 0.0 if exact else residual,
                              "32-bit float attributes")
    return LensConversion(camera.name, conversion.source, conversion.target, False, residual,
                          "no skew, 32-bit float attributes")


def _custom(prim, key: str, where: str):
    value = prim.GetCustomDataByKey(key)
    if value is None:
        return None
    if key == "camcal:image_size":
        try:
            return tuple(int(v) for v in value)
        except (TypeError, ValueError, OverflowError):
            raise CamcalError(f"{where}: customData {key} is not two integers, got {value!r:.80}") from None
    if not isinstance(value, str):
        raise CamcalError(f"{where}: customData {key} is not camcal's JSON")
    try:
        return parse_json(value)
    except CamcalError as error:
        raise CamcalError(f"{where}: customData {key} is not camcal's JSON ({error})") from None


def _reason(error: Exception) -> str:
    """The last clause of a pxr error, on one line."""
    try:
        return " ".join(str(error).split()).rsplit(" : ", 1)[-1].strip("' ")
    except UnicodeDecodeError:  # pxr's message quotes the file's bytes, which need not be UTF-8
        return "not UTF-8 text"


def load(path: Path, image_size: tuple[int, int] | None = None) -> ImportResult:
    """Read the UsdGeom.Camera prims of a stage as a rig (see the module docstring).

    Parameters
    ----------
    path : Path
    image_size : (int, int), optional
        Width and height in pixels of the cameras that carry no
        ``camcal:image_size`` (plain USD cameras); cameras camcal wrote keep
        their own.

    Raises
    ------
    CamcalError
        A camera without an image size when ``image_size`` is None, and the
        file errors of :func:`camcal.io.interchange.import_rig`.
    """
    require("pxr")
    from pxr import Sdf, Tf, Usd, UsdGeom

    check_file_size(path, FILE_BYTES, "USD file")
    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
        if layer is None:
            raise CamcalError("not a USD file")
        layer.Reload()  # a layer this process opened before may have been rewritten since
        stage = Usd.Stage.Open(layer)
    except Tf.ErrorException as error:
        raise CamcalError(f"not a USD file ({_reason(error)})") from None
    cameras, conversions, world_poses, prims, notes, lenses = [], [], [], [], [], []
    times = None
    try:
        for prim in stage.Traverse():
            if not prim.IsA(UsdGeom.Camera):
                continue
            where = f"camera {prim.GetPath()}"
            size = _custom(prim, "camcal:image_size", where)
            if size is None and image_size is None:
                raise CamcalError(f"{where} has no image size (no camcal customData; USD cameras hold none): "
                                  "give it with --image-size W H")
            values = _intrinsic_values(prim, Usd.TimeCode.Default(), where)
            if size is None:
                size = image_size
                aperture_aspect = values["horizontalAperture"] / values["verticalAperture"]
                if abs(aperture_aspect / (size[0] / size[1]) - 1.0) > 1e-3:
                    notes.append(f"{where}: aperture aspect {aperture_aspect:.4g} is not the image's "
                                 f"{size[0] / size[1]:.4g}: read as non-square pixels (fx / fy "
                                 f"{size[0] / size[1] / aperture_aspect:.4g}, the Gf.Camera frustum's mapping); a "
                                 "renderer that fits the aperture to the image sees square pixels and a wider view")
            K = _exact_K(prim, values, size, _custom(prim, "camcal:K", where))
            lens = _custom(prim, "camcal:distortion", where)
            distortion = Distortion.none() if lens is None else Distortion.from_dict(lens)
            keyed = _keyed_lenses(prim, size, distortion, where, Usd)
            lenses.append(keyed or None)
            if keyed:
                K, distortion = keyed[min(keyed)][:2]
            name = prim.GetCustomDataByKey("camcal:name") or prim.GetName()
            xformable = UsdGeom.Xformable(prim)
            samples = xformable.GetTimeSamples()
            if samples:
                times = samples if times is None else times
                if list(samples) != list(times):
                    raise CamcalError(f"{where}: its time samples differ from the other cameras'")
                poses = [_pose(xformable.ComputeLocalToWorldTransform(Usd.TimeCode(t))) for t in samples]
            else:
                poses = [_pose(xformable.ComputeLocalToWorldTransform(Usd.TimeCode.Default()))]
            world_poses.append(poses)
            prims.append(prim)
            width = prim.GetCustomDataByKey("camcal:sensor_width_mm")
            try:
                cameras.append(Camera(name, size, K, distortion, *poses[0], sensor_width_mm=width))
            except CamcalError as error:
                raise CamcalError(f"{where}: {error}") from None
            conversions.append(LensConversion(name, "UsdGeom.Camera", distortion.model, True))
    except Tf.ErrorException as error:  # e.g. an invalid xformOp name: pxr raises while computing the pose
        raise CamcalError(f"USD cannot read the stage ({_reason(error)})") from None
    if not cameras:
        raise CamcalError("no UsdGeom.Camera in the stage")
    units = stage.GetRootLayer().customLayerData.get("camcal:units")
    if units is None:
        meters = UsdGeom.GetStageMetersPerUnit(stage)
        units = next((u for u, m in METERS_PER_UNIT.items() if m == meters), "m")
    if not times and not any(lenses):
        return ImportResult(Rig(tuple(cameras), units=units), tuple(conversions), tuple(notes))
    rig = _moving_rig(prims, cameras, world_poses, times, units, lenses)
    keyed = sum(1 for keys in lenses if keys)
    return ImportResult(rig, tuple(conversions), (*notes, f"{len(rig.frames)} frames from the cameras' time samples",
                                                  *([f"per-frame lenses of {keyed} camera(s)"] if keyed else [])))


def _intrinsic_values(prim, time, where: str) -> dict[str, float]:
    """The camera's focal length, apertures and offsets at ``time``, checked."""
    values = {name: prim.GetAttribute(name).Get(time) for name in _INTRINSICS}
    if any(v is None or not np.isfinite(v) for v in values.values()):
        raise CamcalError(f"{where}: focal length or apertures missing or not finite")
    if values["focalLength"] <= 0 or values["horizontalAperture"] <= 0 or values["verticalAperture"] <= 0:
        raise CamcalError(f"{where}: focal length and apertures must be positive")
    return values


def _exact_K(prim, values: dict[str, float], size: tuple[int, int], exact_K) -> NDArray[np.float64]:
    """``K`` of the attributes' values, or camcal's exact ``K`` where the attributes are still what camcal wrote."""
    if exact_K is not None:
        exact_K = np.asarray(exact_K, dtype=np.float64)
        written = _float32(usd_intrinsics(Camera(prim.GetName(), size, exact_K, Distortion.none(), np.eye(3),
                                                 np.zeros(3), prim.GetCustomDataByKey("camcal:sensor_width_mm"))))
        if written == _float32(values):  # the camera was not edited since camcal wrote it: its exact K
            return exact_K
    return _K_from_usd(values, size)


def _keyed_lenses(prim, size: tuple[int, int], distortion: Distortion, where: str,
                  Usd) -> dict[int, tuple[NDArray[np.float64], Distortion, dict[str, float]]]:
    """Frame -> (``K``, lens, lens state) of a camera whose intrinsics have time samples (empty: none)."""
    times = sorted({t for name in _INTRINSICS for t in prim.GetAttribute(name).GetTimeSamples()})
    keys = _custom(prim, "camcal:lens_keys", where) or {}
    if not isinstance(keys, dict):
        raise CamcalError(f"{where}: customData camcal:lens_keys is not camcal's JSON object")
    out = {}
    for time in times:
        frame = int(round(time))
        entry = keys.get(str(frame)) or {}
        K = _exact_K(prim, _intrinsic_values(prim, Usd.TimeCode(time), f"{where} at {time:g}"), size, entry.get("K"))
        lens = distortion if "distortion" not in entry else Distortion.from_dict(entry["distortion"])
        out[frame] = (K, lens, {key: entry[key] for key in _LENS_STATE if key in entry})
    return out


def _moving_rig(prims, cameras, world_poses, times, units, lenses) -> Rig:
    """Frames from the first camera's world poses (or its intrinsics' samples), the cameras' per-frame lenses.

    Each camera keeps its pose in the rig (customData ``camcal:cam_from_rig``;
    a camera that does not move keeps its world pose, under frames at the
    origin); a frame gets a camera's lens where it differs from the camera's
    own (its first frame's).
    """
    if not times:
        indices = sorted({frame for keys in lenses if keys for frame in keys})
        frames = [Frame(index, np.eye(3), np.zeros(3)) for index in indices]
        return _with_lenses(Rig(tuple(cameras), units=units, frames=tuple(frames)), lenses)
    rig_cameras = []
    for prim, camera in zip(prims, cameras):
        relative = _custom(prim, "camcal:cam_from_rig", camera.name)
        if relative is None:
            raise CamcalError(f"camera {camera.name!r} moves but has no camcal:cam_from_rig in customData")
        rig_cameras.append(Camera(camera.name, camera.image_size, camera.K, camera.distortion,
                                  relative["R"], relative["c"], sensor_width_mm=camera.sensor_width_mm))
    reference = rig_cameras[0]
    frames = []
    for index, time in enumerate(times):
        R_world, c_world = world_poses[0][index]
        R_frame = reference.R.T @ R_world
        U, _, Vt = np.linalg.svd(R_frame)
        R_frame = U @ Vt
        frames.append(Frame(int(round(time)), R_frame, c_world - R_frame.T @ reference.c))
    return _with_lenses(Rig(tuple(rig_cameras), units=units, frames=tuple(frames)), lenses)


def _with_lenses(rig: Rig, lenses) -> Rig:
    """``rig`` with each camera's keyed lenses on its frames (every frame must have one)."""
    indices = [frame.index for frame in rig.frames]
    for camera, keyed in zip(rig.cameras, lenses):
        if not keyed:
            continue
        if sorted(keyed) != indices:
            raise CamcalError(f"camera {camera.name!r}: its intrinsics are sampled on {len(keyed)} frames, the shot "
                              f"has {len(indices)} (sample the lens and the transform on the same frames)")
        rig = rig.with_camera(camera, {
            frame: Lens(K, lens, state.get("focal_mm"), state.get("focus_m")) for frame, (K, lens, state) in keyed.items()
            if not (np.array_equal(K, camera.K) and lens == camera.distortion and not state)})
    return rig
