"""Nuke's lens nodes: ``LensDistortion2`` with a 3DEqualizer preset and the LDPK node of the same model, written and read.

The nodes and their knobs are described in :mod:`camcal.io.nuke` (the
script's format). A lens that changes over a shot (a rig with per-frame
lenses, :attr:`camcal.model.rig.Frame.lenses`) keys every knob that
carries the lens state once per frame (focal length, film back, lens
centre offset, pixel aspect, the model's parameters), in the syntax of
:func:`camcal.io.nuke_knobs.animated_knob`; the preset, the image format
and the model are the same on every frame.

References
----------
Foundry, Nuke reference guide: LensDistortion
(learn.foundry.com/nuke/content/reference_guide/transform_nodes/lensdistortion.html).
Science-D-Visions, 3DEqualizer4 "Export Nuke LD_3DE4 Lens Distortion Node" and "Export Nuke LensDistortion
Node" scripts; Lens Distortion Plugin Kit 2.0.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.io.nuke_knobs import animated_knob, blocks, keyed_knob, knob_text, number, parse_number, value_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from camcal.model.tde4 import BUILTIN_PARAMETERS, FILMBACK_KEYS, LDPK_MODEL_NAMES, LDPK_PARAMETERS, LdpkCamera

__all__ = ["format_knob", "ldpk_node_class", "lens_nodes", "lens_nodes_of", "node_lenses"]

#: A lens read from a node at one frame (None: the node is not keyed): ``K`` and the distortion.
_NodeLenses = dict[int | None, tuple[NDArray[np.float64], Distortion]]

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


def format_knob(camera: Camera) -> str:
    """Nuke's ``format`` of the camera's image: ``"W H 0 0 W H pixel_aspect WxH"`` (pixel aspect ``fy / fx``)."""
    width, height = camera.image_size
    aspect = camera.K[1, 1] / camera.K[0, 0]
    return f'"{width} {height} 0 0 {width} {height} {number(aspect)} {width}x{height}"'


def _knob_values(camera: Camera, haperture_mm: float) -> tuple[dict[str, list[float]], dict[str, float]]:
    """The LensDistortion node's lens knobs and the LDPK node's of one camera (a 3DE lens), unkeyed."""
    lens = camera.distortion
    builtin = LdpkCamera.from_camera_matrix(camera.K, camera.image_size, haperture_mm / 10.0)
    values = {p.key: lens.params.get(p.key, p.default) for p in LDPK_PARAMETERS[lens.model]}
    half_diagonal = 0.5 * math.hypot(builtin.filmback_width_cm, builtin.filmback_height_cm)
    distortion: dict[str, list[float]] = {
        "focal": [builtin.focal_length_cm * 10.0],
        "sensorSize": [builtin.filmback_width_cm * 10.0, builtin.filmback_height_cm * 10.0],
        "centre": [builtin.lens_center_offset_x_cm / half_diagonal, builtin.lens_center_offset_y_cm / half_diagonal],
    }
    for key, knob in _LD_KNOBS[lens.model].items():
        name = knob if isinstance(knob, str) else knob[0]
        distortion.setdefault(name, []).append(values[key])
    ldpk = {**builtin.builtin_parameters(), **{_nukify(p.ldpk_name): values[p.key] for p in LDPK_PARAMETERS[lens.model]}}
    return distortion, ldpk


def lens_nodes(lenses: Sequence[Camera], frames: Sequence[int] | None, node: str, haperture_mm: float,
               index: int) -> list[str]:
    """The LensDistortion and LDPK nodes of a camera whose lens is one of the 3DE models.

    Parameters
    ----------
    lenses : sequence of Camera
        One camera (``frames`` None: constant knobs) or the camera at each
        of ``frames`` (one key per frame on every lens knob); one 3DE model.
    frames : sequence of int or None
    node : str
        The Camera3's node name: the nodes are ``<node>_lens`` and ``<node>_ldpk``.
    haperture_mm : float
        The film back width (the Camera3's ``haperture``).
    index : int
        The camera's column in the node graph.
    """
    first = lenses[0]
    model = first.distortion.model
    per_frame = [_knob_values(camera, haperture_mm) for camera in lenses]

    def knob(table: int, name: str) -> str:
        values = np.array([entry[table][name] for entry in per_frame], dtype=np.float64)
        if frames is not None:
            return animated_knob(values, frames)
        row = np.ravel(values[0])
        return animated_knob(row[0] if len(row) == 1 else row, None)

    lines = ["LensDistortion2 {", " inputs 0", f' distortionModelPreset "3DEqualizer/{LDPK_MODEL_NAMES[model]}"',
             *(f" {k} {v}" for k, v in _LD_SETUP[model]), " distortionDomain Rectilinear",
             " normalisationType Diagonal", " distortionScalingType Format",
             f" distortionScalingFormat {format_knob(first)}", " output Undistort",
             *(f" {name} {knob(0, name)}" for name in per_frame[0][0]),
             f" name {node}_lens", f" xpos {index * 150}", " ypos 500", "}"]
    lines += [f"{ldpk_node_class(model)} {{", " inputs 0", " direction undistort",
              *(f" {name} {knob(1, name)}" for name in BUILTIN_PARAMETERS),
              " field_of_view_xa_unit 0", " field_of_view_ya_unit 0", " field_of_view_xb_unit 1",
              " field_of_view_yb_unit 1",
              *(f" {name} {knob(1, name)}" for name in per_frame[0][1] if name not in BUILTIN_PARAMETERS),
              f" name {node}_ldpk", f" xpos {index * 150}", " ypos 600", "}"]
    return lines


def _tde_lens(model: str, params: dict[str, float], image_size: tuple[int, int]) -> Distortion:
    return Distortion(model, {**params, FILMBACK_KEYS[0]: float(image_size[0]), FILMBACK_KEYS[1]: float(image_size[1])})


def _frames_of(knobs: Sequence[NDArray[np.float64] | dict[int, NDArray[np.float64]]]) -> list[int | None]:
    """The frames any of the knobs is keyed on, sorted ([None]: none is keyed)."""
    keyed = sorted({frame for knob in knobs if isinstance(knob, dict) for frame in knob})
    return list(keyed) or [None]


def _lenses_from_ldpk(body: str, model: str, image_size: tuple[int, int], where: str) -> _NodeLenses:
    """``K`` and the lens of an LDPK node at each keyed frame (built-ins ``tde4_*`` in cm, parameters by 3DE name)."""
    builtins = [keyed_knob(_required(body, name, where), 1, f"{where} {name}") for name in BUILTIN_PARAMETERS]
    params = {p.key: keyed_knob(knob_text(body, _nukify(p.ldpk_name)), 1, f"{where} {p.ldpk_name}", p.default)
              for p in LDPK_PARAMETERS[model]}
    out: _NodeLenses = {}
    for frame in _frames_of([*builtins, *params.values()]):
        builtin = LdpkCamera(*(float(value_at(knob, frame, where)[0]) for knob in builtins))
        values = {key: float(value_at(knob, frame, where)[0]) for key, knob in params.items()}
        out[frame] = (builtin.camera_matrix(image_size), _tde_lens(model, values, image_size))
    return out


def _lenses_from_lens_distortion(body: str, image_size: tuple[int, int] | None,
                                 where: str) -> tuple[_NodeLenses, tuple[int, int]]:
    """``K`` and the lens at each keyed frame, and the image size, of a LensDistortion node with a 3DE preset."""
    preset = (knob_text(body, "distortionModelPreset") or "").strip('"')
    names = {f"3DEqualizer/{name}": model for model, name in LDPK_MODEL_NAMES.items()}
    if preset not in names:
        raise CamcalError(f"{where}: model preset {preset!r} is not one of 3DEqualizer's: {', '.join(names)}")
    model = names[preset]
    fmt = (knob_text(body, "distortionScalingFormat") or "").strip('"').split()
    pixel_aspect = 1.0
    if len(fmt) >= 7:
        image_size = (int(parse_number(fmt[0], where)), int(parse_number(fmt[1], where)))
        pixel_aspect = parse_number(fmt[6], f"{where} distortionScalingFormat")
    if image_size is None:
        raise CamcalError(f"{where}: no distortionScalingFormat and no image size to normalise the lens on")
    focal = keyed_knob(_required(body, "focal", where), 1, f"{where} focal")
    sensor = keyed_knob(_required(body, "sensorSize", where), 2, f"{where} sensorSize")
    centre = keyed_knob(knob_text(body, "centre"), 2, f"{where} centre", (0.0, 0.0))
    knobs: dict[str, tuple[NDArray[np.float64] | dict[int, NDArray[np.float64]], int]] = {}
    for key, knob in _LD_KNOBS[model].items():
        name, position = (knob, 0) if isinstance(knob, str) else knob
        size = 2 if name == "anamorphicScale" else 1
        text = knob_text(body, name)
        if text is not None:
            knobs[key] = (keyed_knob(text, size, f"{where} {name}"), position)
    defaults = {p.key: p.default for p in LDPK_PARAMETERS[model]}
    out: _NodeLenses = {}
    for frame in _frames_of([focal, sensor, centre, *(knob for knob, _ in knobs.values())]):
        width_mm, height_mm = value_at(sensor, frame, where)
        half_diagonal = 0.5 * math.hypot(width_mm, height_mm)
        offset = value_at(centre, frame, where) * half_diagonal
        builtin = LdpkCamera(float(value_at(focal, frame, where)[0]), float(width_mm), float(height_mm),
                             float(offset[0]), float(offset[1]), pixel_aspect)
        params = {**defaults, **{key: float(value_at(knob, frame, where)[position])
                                 for key, (knob, position) in knobs.items()}}
        out[frame] = (builtin.camera_matrix(image_size), _tde_lens(model, params, image_size))
    return out, image_size


def _required(body: str, name: str, where: str) -> str:
    text = knob_text(body, name)
    if text is None:
        raise CamcalError(f"{where} has no {name} knob")
    return text


def lens_nodes_of(text: str) -> dict[str, tuple[str, str]]:
    """Node name -> (class, body) of the LensDistortion nodes with a 3DEqualizer preset and the LDPK nodes."""
    ldpk = {ldpk_node_class(model): model for model in LDPK_MODEL_NAMES}
    found = {}
    for cls, body in blocks(text, "|".join([*ldpk, "LensDistortion2?"])):
        if cls.startswith("LensDistortion") and "3DEqualizer/" not in (knob_text(body, "distortionModelPreset") or ""):
            continue
        found[(knob_text(body, "name") or f"{cls}{len(found) + 1}").strip('"')] = (cls, body)
    return found


def node_lenses(cls: str, body: str, image_size: tuple[int, int] | None,
                where: str) -> tuple[_NodeLenses, tuple[int, int]]:
    """``K`` and the lens at each keyed frame (``{None: ...}`` unkeyed), and the image size, of a lens node."""
    models = {ldpk_node_class(model): model for model in LDPK_MODEL_NAMES}
    if cls in models:
        if image_size is None:
            raise CamcalError(f"{where}: no image size (no camcal knobs, no Root format) to normalise the lens on")
        return _lenses_from_ldpk(body, models[cls], image_size, where), image_size
    return _lenses_from_lens_distortion(body, image_size, where)
