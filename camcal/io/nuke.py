"""Nuke scripts (``.nk``): a Camera3 node per camera, its lens as LensDistortion and LDPK nodes and an STMap chain.

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

Lens, three ways, for every camera:

- the ST-maps (:mod:`camcal.io.stmap`), exact for every camcal lens, written
  beside the script, ``<script>_stmaps/<camera>_undistort.exr`` and
  ``..._redistort.exr``, in the chain ``Read (plate) -> STMap (undistort
  map) -> ... -> STMap (redistort map)``, each STMap taking its source on
  input 0 and the map on input 1 (cameras with a lens);
- a ``LensDistortion2`` node (plain Nuke, no plugin) with the 3DEqualizer
  preset of the lens' 3DE model (``distortionModelPreset
  "3DEqualizer/3DE4 Radial - Standard, Degree 4"`` ...), ``normalisationType
  Diagonal``, ``output Undistort``, ``focal`` and ``sensorSize`` in mm (the
  Camera3's), the lens-centre offset over the film back's half-diagonal as
  ``centre``, the image size and pixel aspect as ``distortionScalingFormat``
  and each 3DE parameter on the knob 3DEqualizer's own Nuke export puts it
  (``Distortion - Degree 2`` -> ``distortionNumerator0``, ``U - Degree 2`` ->
  ``distortionNumeratorT0``, ``Cx02 - Degree 2`` -> ``distortionNumeratorX00``,
  ``Lens Rotation`` -> ``anamorphicTwist``, ``Squeeze-X / -Y`` ->
  ``anamorphicScale``, ``Phi / B - Cylindric`` -> ``beamSplitterDirection /
  Bending``, ...);
- the LDPK node of the same model (``LD_3DE4_Anamorphic_Standard_Degree_4``
  ...: 3DE's names with ``+,:; _-`` runs as one underscore) with LDPK's
  built-in ``tde4_*`` knobs in cm (focal length, film back, lens-centre
  offset, pixel aspect) and the model parameters by their 3DE names.

A lens that is one of the four 3DE models goes into the lens nodes exactly;
any other is refitted to the nearest 3DE model
(:func:`camcal.io.conversion.refit_camera`, residual max / RMS over the
image and a 1.25 overscan border printed). The film back is ``haperture``
wide for all three, so the Camera3's focal length and film back are the
lens nodes'. (A refit to 3DE's fisheye, whose equisolid image takes the
focal length, fits the focal length too: its lens nodes carry their own.)
Reading takes each Camera3's lens from its camcal knobs; a Camera3 without
them (Nuke's own) from the LDPK node ``<node>_ldpk`` or LensDistortion node
``<node>_lens`` (the only one, with one camera); a script with lens nodes and
no Camera3 gives one camera per lens node (LDPK nodes first), at the origin.
Image sizes come from the camcal knobs, the LensDistortion node's format,
the Root's ``format`` or the ``image_size`` given to :func:`load`. No key per frame: a camcal camera has one lens.

No Nuke was available to check these files: the conventions above are the
ones Foundry documents for Camera3, STMap and LensDistortion (knob names)
and 3DEqualizer's Nuke export uses (the 3DE parameters' knobs); the tests
evaluate the written knobs with the LDPK models' documented formulas,
independently of camcal's model code.

References
----------
Foundry, Nuke reference guide: Camera, STMap, LensDistortion
(learn.foundry.com/nuke/content/reference_guide/transform_nodes/lensdistortion.html).
Science-D-Visions, 3DEqualizer4 "Export Nuke LD_3DE4 Lens Distortion Node"
and "Export Nuke LensDistortion Node" scripts; Lens Distortion Plugin Kit 2.0.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_write_text
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    FORMAT_FAMILIES,
    ExportResult,
    ImportResult,
    LensConversion,
    max_pixel_residual,
    nearest_family,
    refit_camera,
    select_cameras,
)
from camcal.model.rig import Camera, Frame, Rig
from camcal.model.tde4 import BUILTIN_PARAMETERS, FILMBACK_KEYS, LDPK_MODEL_NAMES, LDPK_PARAMETERS, LdpkCamera

__all__ = ["DEFAULT_HAPERTURE_MM", "ldpk_node_class", "nuke_intrinsics", "export", "load"]

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
             f" first_frame {frames[0] if frames else 1}", f" last_frame {frames[-1] if frames else 1}",
             f" format {_format_knob(chosen[0])}", "}"]
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
        family = nearest_family(camera.distortion, FORMAT_FAMILIES["nuke"])
        lens_camera, refit = refit_camera(camera, family)
        conversion = LensConversion(camera.name, source, f"Nuke Camera3 (+ ST-maps for the lens), lens nodes "
                                    f"{LDPK_MODEL_NAMES[family]}", exact,
                                    0.0 if exact else max_pixel_residual(camera, converted, lens=False),
                                    "one focal scale, no skew", refit)
        conversions.append(conversion)
        if frames:
            posed = [rig.camera_at_frame(camera.name, f) for f in frames]
            poses = [_transform(p.R, p.c) for p in posed]
            translate, rotate = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
        else:
            translate, rotate = _transform(camera.R, camera.c)
        intr = nuke_intrinsics(converted)
        lines += _lens_nodes(lens_camera, node, intr["haperture"], index)
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
    if any(abs(c.K[1, 1] / c.K[0, 0] - 1.0) > 1e-9 for c in chosen):
        notes.append("non-square pixels: the LensDistortion node holds the pixel aspect in its distortionScalingFormat "
                     "only (not checked in Nuke); the LDPK node (tde4_pixel_aspect) and the ST-maps hold the lens")
    if rig.points is not None:
        notes.append("sparse points are not written to Nuke (export USD for a point cloud)")
    if written:
        notes.append(f"ST-maps of {len(written) // 2} camera(s) written to {map_dir}; the plate Read nodes "
                     "name a placeholder file to replace")
    atomic_write_text(out, "\n".join(lines) + "\n")
    return ExportResult((out, *written), tuple(conversions), tuple(notes))


# -- the lens nodes: Nuke's LensDistortion (3DEqualizer preset) and the LDPK node of the same model ---------

#: LensDistortion's knob of each 3DE parameter (3DEqualizer's own Nuke export names them so): a knob name, or a
#: (knob, index) pair for the two-value ``anamorphicScale``.
_LD_KNOBS: Mapping[str, Mapping[str, str | tuple[str, int]]] = MappingProxyType({
    "3de-classic": {"distortion": "distortionNumerator0", "quartic_distortion": "distortionNumerator1",
                    "curvature_x": "distortionNumeratorX00", "curvature_y": "distortionNumeratorY00",
                    "anamorphic_squeeze": "anamorphicSqueeze"},
    "3de4-radial-deg4": {"c2": "distortionNumerator0", "c4": "distortionNumerator1",
                         "u2": "distortionNumeratorT0", "u4": "distortionNumeratorT1",
                         "v2": "distortionNumeratorU0", "v4": "distortionNumeratorU1",
                         "cylindric_direction_deg": "beamSplitterDirection", "cylindric_bending": "beamSplitterBending"},
    "3de4-anamorphic-deg4": {
        **{f"c{axis}{term}": f"distortionNumerator{axis.upper()}{index}"
           for axis in "xy" for term, index in (("02", "00"), ("22", "10"), ("04", "01"), ("24", "11"), ("44", "20"))},
        "lens_rotation_deg": "anamorphicTwist", "squeeze_x": ("anamorphicScale", 0), "squeeze_y": ("anamorphicScale", 1)},
    "3de4-fisheye-deg8": {"c2": "distortionNumerator0", "c4": "distortionNumerator1", "c6": "distortionNumerator2",
                          "c8": "distortionNumerator3"},
})

#: LensDistortion's set-up knobs of each model's preset, besides the preset itself.
_LD_SETUP: Mapping[str, tuple[tuple[str, str], ...]] = MappingProxyType({
    "3de-classic": (("distortionOrder", "{2 0}"),),
    "3de4-radial-deg4": (("lens", '"Beam Splitter"'), ("distortionModelType", '"Radial-Tangential/R-T Uncoupled"'),
                         ("distortionOrder", "{2 0}")),
    "3de4-anamorphic-deg4": (("lens", "Anamorphic"), ("distortionModelType", '"Radial Asymmetric"'),
                             ("distortionOrder", "{2 0}")),
    "3de4-fisheye-deg8": (("projection", '"Fisheye/Fisheye Equisolid"'), ("distortionOrder", "{4 0}")),
})


def _nukify(name: str) -> str:
    """A 3DE name as the LDPK node names it: runs of ``+,:; _-`` to one underscore, a leading digit escaped."""
    text = re.sub(r"[+,:; _-]+", "_", name.strip())
    return "_" + text if text[:1].isdigit() else text


def ldpk_node_class(model: str) -> str:
    """The LDPK node of a 3DE model, e.g. ``LD_3DE4_Anamorphic_Standard_Degree_4``."""
    return "LD" + _nukify(LDPK_MODEL_NAMES[model])


def _ldpk_camera(camera: Camera, haperture_mm: float) -> LdpkCamera:
    return LdpkCamera.from_camera_matrix(camera.K, camera.image_size, haperture_mm / 10.0)


def _format_knob(camera: Camera) -> str:
    width, height = camera.image_size
    aspect = camera.K[1, 1] / camera.K[0, 0]
    return f'"{width} {height} 0 0 {width} {height} {_number(aspect)} {width}x{height}"'


def _lens_nodes(camera: Camera, node: str, haperture_mm: float, index: int) -> list[str]:
    """The LensDistortion and LDPK nodes of ``camera``, whose lens is one of the 3DE models (see the module docstring)."""
    lens = camera.distortion
    builtin = _ldpk_camera(camera, haperture_mm)
    values = {p.key: lens.params.get(p.key, p.default) for p in LDPK_PARAMETERS[lens.model]}
    half_diagonal = 0.5 * math.hypot(builtin.filmback_width_cm, builtin.filmback_height_cm)
    knobs: dict[str, list[str]] = {}
    for key, knob in _LD_KNOBS[lens.model].items():
        name, position = (knob, None) if isinstance(knob, str) else knob
        knobs.setdefault(name, []).append(_number(values[key]))
    lines = ["LensDistortion2 {", " inputs 0", f' distortionModelPreset "3DEqualizer/{LDPK_MODEL_NAMES[lens.model]}"',
             *(f" {k} {v}" for k, v in _LD_SETUP[lens.model]), " distortionDomain Rectilinear",
             " normalisationType Diagonal", " distortionScalingType Format",
             f" distortionScalingFormat {_format_knob(camera)}", " output Undistort",
             f" focal {_number(builtin.focal_length_cm * 10.0)}",
             f" sensorSize {{{_number(builtin.filmback_width_cm * 10.0)} {_number(builtin.filmback_height_cm * 10.0)}}}",
             f" centre {{{_number(builtin.lens_center_offset_x_cm / half_diagonal)} "
             f"{_number(builtin.lens_center_offset_y_cm / half_diagonal)}}}",
             *(f" {k} {v[0] if len(v) == 1 else '{' + ' '.join(v) + '}'}" for k, v in knobs.items()),
             f" name {node}_lens", f" xpos {index * 150}", " ypos 500", "}"]
    lines += [f"{ldpk_node_class(lens.model)} {{", " inputs 0", " direction undistort",
              *(f" {name} {_number(value)}" for name, value in builtin.builtin_parameters().items()),
              " field_of_view_xa_unit 0", " field_of_view_ya_unit 0", " field_of_view_xb_unit 1",
              " field_of_view_yb_unit 1",
              *(f" {_nukify(p.ldpk_name)} {_number(values[p.key])}" for p in LDPK_PARAMETERS[lens.model]),
              f" name {node}_ldpk", f" xpos {index * 150}", " ypos 600", "}"]
    return lines


def _lens_from_ldpk(body: str, model: str, image_size: tuple[int, int], where: str) -> tuple[np.ndarray, Distortion]:
    """``K`` and the lens of an LDPK node (built-in ``tde4_*`` knobs in cm, the model's knobs by their 3DE names)."""
    builtin = LdpkCamera(*(_float(_required(body, name, where), f"{where} {name}") for name in BUILTIN_PARAMETERS))
    params = {p.key: _float(_knob_text(body, _nukify(p.ldpk_name)) or repr(p.default), f"{where} {p.ldpk_name}")
              for p in LDPK_PARAMETERS[model]}
    return builtin.camera_matrix(image_size), _tde_lens(model, params, image_size)


def _lens_from_lens_distortion(body: str, image_size: tuple[int, int] | None,
                               where: str) -> tuple[np.ndarray, Distortion, tuple[int, int]]:
    """``K``, the lens and the image size of a LensDistortion node with a 3DEqualizer preset."""
    preset = (_knob_text(body, "distortionModelPreset") or "").strip('"')
    names = {f"3DEqualizer/{name}": model for model, name in LDPK_MODEL_NAMES.items()}
    if preset not in names:
        raise CamcalError(f"{where}: model preset {preset!r} is not one of 3DEqualizer's: {', '.join(names)}")
    model = names[preset]
    fmt = (_knob_text(body, "distortionScalingFormat") or "").strip('"').split()
    pixel_aspect = 1.0
    if len(fmt) >= 7:
        image_size = (int(_float(fmt[0], where)), int(_float(fmt[1], where)))
        pixel_aspect = _float(fmt[6], f"{where} distortionScalingFormat")
    if image_size is None:
        raise CamcalError(f"{where}: no distortionScalingFormat and no image size to normalise the lens on")
    focal = _float(_required(body, "focal", where), f"{where} focal")
    sensor = [_float(v, f"{where} sensorSize") for v in _required(body, "sensorSize", where).strip("{}").split()]
    centre = [_float(v, f"{where} centre") for v in (_knob_text(body, "centre") or "{0 0}").strip("{}").split()]
    if len(sensor) != 2 or len(centre) != 2:
        raise CamcalError(f"{where}: sensorSize and centre hold two numbers each")
    half_diagonal = 0.5 * math.hypot(*sensor)
    builtin = LdpkCamera(focal, sensor[0], sensor[1], centre[0] * half_diagonal, centre[1] * half_diagonal,
                         pixel_aspect)
    params = {p.key: p.default for p in LDPK_PARAMETERS[model]}
    for key, knob in _LD_KNOBS[model].items():
        name, position = (knob, 0) if isinstance(knob, str) else knob
        values = (_knob_text(body, name) or "").strip("{}").split()
        if len(values) > position:
            params[key] = _float(values[position], f"{where} {name}")
    return builtin.camera_matrix(image_size), _tde_lens(model, params, image_size), image_size


def _tde_lens(model: str, params: dict[str, float], image_size: tuple[int, int]) -> Distortion:
    return Distortion(model, {**params, FILMBACK_KEYS[0]: float(image_size[0]), FILMBACK_KEYS[1]: float(image_size[1])})


def _required(body: str, name: str, where: str) -> str:
    text = _knob_text(body, name)
    if text is None:
        raise CamcalError(f"{where} has no {name} knob")
    return text


# -- reading: the Camera3 nodes (camcal's and Nuke's own, static or keyed) ----------------


def _blocks(text: str, classes: str = r"Camera[23]?") -> list[tuple[str, str]]:
    """``(class, body)`` of the nodes whose class matches ``classes`` (a regular expression)."""
    bodies = []
    for match in re.finditer(rf"^({classes}) \{{", text, flags=re.M):
        depth, position = 1, match.end()
        while depth and position < len(text):
            depth += {"{": 1, "}": -1}.get(text[position], 0)
            position += 1
        if depth:
            raise CamcalError(f"unbalanced braces in a {match.group(1)} node")
        bodies.append((match.group(1), text[match.end():position - 1]))
    return bodies


def _lens_nodes_of(text: str) -> dict[str, tuple[str, str]]:
    """Node name -> (class, body) of the LensDistortion nodes with a 3DEqualizer preset and the LDPK nodes."""
    ldpk = {ldpk_node_class(model): model for model in LDPK_MODEL_NAMES}
    found = {}
    for cls, body in _blocks(text, "|".join([*ldpk, "LensDistortion2?"])):
        if cls.startswith("LensDistortion") and "3DEqualizer/" not in (_knob_text(body, "distortionModelPreset") or ""):
            continue
        found[(_knob_text(body, "name") or f"{cls}{len(found) + 1}").strip('"')] = (cls, body)
    return found


def _root_size(text: str) -> tuple[int, int] | None:
    """The image size of the Root's format knob, if it has one."""
    root = _blocks(text, "Root")
    fmt = (_knob_text(root[0][1], "format") or "").strip('"').split() if root else []
    return (int(_float(fmt[0], "Root format")), int(_float(fmt[1], "Root format"))) if len(fmt) >= 2 else None


def _node_lens(cls: str, body: str, image_size: tuple[int, int] | None,
               where: str) -> tuple[np.ndarray, Distortion, tuple[int, int]]:
    """``K``, lens and image size of a lens node (LDPK first-class knobs, or LensDistortion's)."""
    models = {ldpk_node_class(model): model for model in LDPK_MODEL_NAMES}
    if cls in models:
        if image_size is None:
            raise CamcalError(f"{where}: no image size (no camcal knobs, no Root format) to normalise the lens on")
        K, lens = _lens_from_ldpk(body, models[cls], image_size, where)
        return K, lens, image_size
    return _lens_from_lens_distortion(body, image_size, where)


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


def load(path: Path, *, image_size: tuple[int, int] | None = None) -> ImportResult:
    """Read the Camera3 nodes of a script and their lens nodes (see the module docstring).

    ``image_size`` stands in for a Root format where the script has none
    (an LDPK node 3DEqualizer exported on its own).
    """
    check_file_size(path, FILE_BYTES, "Nuke script")
    text = path.read_text(errors="replace")
    bodies = [body for _, body in _blocks(text)]
    lens_nodes = _lens_nodes_of(text)
    root_size = _root_size(text) or image_size
    if not bodies:
        return _lens_only(lens_nodes, root_size)
    cameras, conversions, animated = [], [], []
    for body in bodies:
        node = _knob_text(body, "name") or f"Camera{len(cameras) + 1}"
        where = f"camera node {node}"
        width, height = _knob_text(body, "image_width"), _knob_text(body, "image_height")
        if (width is None or height is None) and root_size is None:
            raise CamcalError(f"{where} has no image_width / image_height knobs (Nuke cameras hold no image size)")
        size = root_size if width is None or height is None else (int(_float(width, where)), int(_float(height, where)))
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
        source = "Nuke Camera3"
        paired = [n for n in (f"{node}_ldpk", f"{node}_lens") if n in lens_nodes] or (
            list(lens_nodes)[:1] if len(bodies) == 1 else [])
        if _knob_text(body, "lens_model") is None and paired:
            cls, lens_body = lens_nodes[paired[0]]
            _, lens, _ = _node_lens(cls, lens_body, size, f"lens node {paired[0]}")
            model, params, centre, source = lens.model, dict(lens.params), None, f"Nuke {cls}"
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
        conversions.append(LensConversion(name, source, distortion.model, True))
    if all(a is None for a in animated):
        return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions))
    return ImportResult(_moving(cameras, animated), tuple(conversions), ("frames from the keyed cameras",))


def _lens_only(lens_nodes: dict[str, tuple[str, str]], root_size: tuple[int, int] | None) -> ImportResult:
    """A rig of the lens nodes alone (a script with no camera): one camera per lens, at the origin."""
    if not lens_nodes:
        raise CamcalError("no Camera3 node and no LensDistortion (3DEqualizer preset) or LDPK node in the script")
    chosen = {n: v for n, v in lens_nodes.items() if v[0].startswith("LD")} or lens_nodes
    cameras, conversions = [], []
    for name, (cls, body) in chosen.items():
        K, lens, size = _node_lens(cls, body, root_size, f"lens node {name}")
        try:
            cameras.append(Camera(name, size, K, lens, np.eye(3), np.zeros(3)))
        except CamcalError as error:
            raise CamcalError(f"lens node {name}: {error}") from None
        conversions.append(LensConversion(name, f"Nuke {cls}", lens.model, True))
    return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions),
                        ("no Camera3 node: one camera per lens node, at the origin",))


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
