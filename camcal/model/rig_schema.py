"""The JSON Schema of the rig file (``*.rig.json``), built from the data model it describes.

:data:`RIG_SCHEMA` is what ``docs/rig.schema.json`` holds (``python -m
camcal.model.rig_schema`` prints it; a test checks the committed file equals
it) and what ``camcal rig show --validate`` checks a file against
(:func:`validate_rig_dict`). The lens models and their parameter names come
from :data:`camcal.model.distortion.MODEL_PARAMS`, the quality keys from
:class:`camcal.model.quality.Quality`, so the schema follows the model.

The schema says what a file's structure must be: keys, types, array shapes,
the lens model's parameters, ``K``'s zeros and one. What JSON Schema cannot
say, :meth:`camcal.model.rig.Rig.from_dict` checks on load: ``R`` orthonormal
with determinant +1, a plausible focal length and principal point, camera
names unique, frames naming cameras of the rig (their lenses of the camera's
distortion model, with a plausible K on its image), image sizes within the pixel
cap, a covariance symmetric with one row per name.
"""

from __future__ import annotations

import json
import os
from dataclasses import fields
from typing import Any

from camcal.base.errors import CamcalError
from camcal.base.jsonfile import read_json
from camcal.base.schema import schema_errors
from camcal.model.distortion import MODEL_PARAMS
from camcal.model.quality import INTRINSIC_SIGMAS, POSE_SIGMAS, Quality
from camcal.model.rig import RIG_FORMAT, RIG_VERSION, Rig
from camcal.model.spline import MAX_KNOTS, MIN_KNOTS

__all__ = ["RIG_SCHEMA", "RIG_SCHEMA_ID", "load_validated", "rig_schema_json", "validate_rig_dict"]

#: Where the schema is published in the repository.
RIG_SCHEMA_ID = "docs/rig.schema.json"

_NUMBER = {"type": "number"}
_VECTOR3 = {"type": "array", "items": _NUMBER, "minItems": 3, "maxItems": 3}
_MATRIX3 = {"type": "array", "items": _VECTOR3, "minItems": 3, "maxItems": 3}
_POINT2 = {"type": "array", "items": _NUMBER, "minItems": 2, "maxItems": 2}
_COUNT = {"type": "integer", "minimum": 0}
_NON_NEGATIVE = {"type": "number", "minimum": 0}


def _row(*items: dict) -> dict:
    return {"type": "array", "prefixItems": list(items), "minItems": len(items), "maxItems": len(items)}


def _distortion_model(model: str) -> dict:
    required, optional = MODEL_PARAMS[model]
    properties: dict[str, Any] = {
        "model": {"const": model},
        "params": {
            "type": "object",
            "properties": {name: _NUMBER for name in required + optional},
            "required": list(required),
            "additionalProperties": False,
        },
        "correction": {"$ref": "#/$defs/spline_field"},
    }
    if model == "division":
        properties["params"]["properties"]["aspect"] = {"type": "number", "exclusiveMinimum": 0}
        properties["center"] = dict(_POINT2, description="Distortion centre (x, y) in pixels; absent: the principal point.")
    out = {"type": "object", "properties": properties, "required": ["model", "params"] if required else ["model"],
           "additionalProperties": False}
    if not required:
        out["description"] = f"'{model}': no parameters (params may be left out)."
    else:
        out["description"] = f"'{model}': parameters {', '.join(required)}" + (
            f", optionally {', '.join(optional)}" if optional else "") + "."
    return out


def _quality() -> dict:
    names = [item.name for item in fields(Quality)]
    properties: dict[str, Any] = {}
    for name in names:
        if name == "sigma":
            properties[name] = {
                "type": "object",
                "description": ("One-sigma uncertainties (sampling noise, not model error): "
                                f"{', '.join(INTRINSIC_SIGMAS)} in pixels, each distortion parameter under its "
                                f"name, and the pose relative to the reference camera ({', '.join(POSE_SIGMAS)})."),
                "additionalProperties": _NON_NEGATIVE,
            }
        elif name == "covariance":
            properties[name] = {
                "type": "object",
                "description": "Covariance of the camera's parameters: one row per name, symmetric.",
                "properties": {
                    "names": {"type": "array", "items": {"type": "string", "minLength": 1}},
                    "matrix": {"type": "array", "items": {"type": "array", "items": _NUMBER}},
                },
                "required": ["names", "matrix"],
                "additionalProperties": False,
            }
        elif name.startswith("n_"):
            properties[name] = _COUNT
        else:
            properties[name] = _NON_NEGATIVE
    properties["n_points"] = dict(_COUNT, deprecated=True, description="Older name of n_observations.")
    return {"type": "object", "description": "Fit quality; every key optional, units in the names.",
            "properties": properties, "additionalProperties": False}


def _build() -> dict:
    image_size = _row({"type": "integer", "minimum": 1}, {"type": "integer", "minimum": 1})
    image_size["description"] = "[width, height] in pixels."
    K = _row(
        _row({"type": "number", "exclusiveMinimum": 0}, _NUMBER, _NUMBER),
        _row({"const": 0}, {"type": "number", "exclusiveMinimum": 0}, _NUMBER),
        _row({"const": 0}, {"const": 0}, {"const": 1}),
    )
    K["description"] = "[[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels; pixel (0, 0) is the centre of the top-left pixel."
    defs = {
        "image_size": image_size,
        "K": K,
        "rotation": dict(_MATRIX3, description="Rotation matrix (orthonormal, determinant +1), world (or rig) to camera."),
        "centre": dict(_VECTOR3, description="Camera or rig centre in the rig's units."),
        "distortion": {"oneOf": [_distortion_model(model) for model in MODEL_PARAMS],
                       "description": "Maps undistorted pixels to distorted ones."},
        "spline_field": {
            "type": "object",
            "description": "A smooth correction after the lens model: cubic B-spline knot displacements in pixels.",
            "properties": {
                "image_size": {"$ref": "#/$defs/image_size"},
                "coefficients": {"type": "array", "minItems": MIN_KNOTS, "maxItems": MAX_KNOTS,
                                 "items": {"type": "array", "minItems": MIN_KNOTS, "maxItems": MAX_KNOTS,
                                           "items": _POINT2}},
            },
            "required": ["image_size", "coefficients"],
            "additionalProperties": False,
        },
        "rectification": {
            "type": "object",
            "description": "H maps undistorted pixels of the camera to pixels of the rectified camera K_rect.",
            "properties": {"H": _MATRIX3, "K_rect": {"$ref": "#/$defs/K"}, "image_size": {"$ref": "#/$defs/image_size"}},
            "required": ["H", "K_rect", "image_size"],
            "additionalProperties": False,
        },
        "quality": _quality(),
        "camera": {
            "type": "object",
            "properties": {
                "name": {"type": "string", "minLength": 1},
                "image_size": {"$ref": "#/$defs/image_size"},
                "K": {"$ref": "#/$defs/K"},
                "distortion": {"$ref": "#/$defs/distortion"},
                "R": {"$ref": "#/$defs/rotation"},
                "c": {"$ref": "#/$defs/centre"},
                "sensor_width_mm": {"type": "number", "exclusiveMinimum": 0},
                "rectification": {"$ref": "#/$defs/rectification"},
                "quality": {"$ref": "#/$defs/quality"},
            },
            "required": ["name", "image_size", "K", "distortion", "R", "c"],
            "additionalProperties": False,
        },
        "frame": {
            "type": "object",
            "description": "The rig's pose at one frame (rig_from_world as R, c); cameras' R, c are then cam_from_rig.",
            "properties": {
                "index": {"type": "integer"},
                "R": {"$ref": "#/$defs/rotation"},
                "c": {"$ref": "#/$defs/centre"},
                "images": {"type": "object", "additionalProperties": {"type": "string"},
                           "description": "Camera name -> the image it took at this frame."},
                "lenses": {"type": "object", "additionalProperties": {"$ref": "#/$defs/lens"},
                           "description": "Camera name -> its lens at this frame (a zoom, a refocus); "
                                          "cameras absent keep their own."},
                "rolling_shutter": {"type": "object", "additionalProperties": {"$ref": "#/$defs/shutter_check"},
                                    "description": "Camera name -> the rolling shutter's effect at this frame "
                                                   "(a solve given a readout time)."},
            },
            "required": ["index", "R", "c"],
            "additionalProperties": False,
        },
        "shutter_check": {
            "type": "object",
            "description": ("The largest image displacement (px) of a frame's points between their row's readout "
                            "time and the frame's time, and whether it passed the solve's threshold."),
            "properties": {
                "displacement_px": {"type": "number", "minimum": 0},
                "flagged": {"type": "boolean"},
            },
            "required": ["displacement_px", "flagged"],
            "additionalProperties": False,
        },
        "lens": {
            "type": "object",
            "description": ("A camera's lens at one frame: K and distortion (the camera's model) in pixels of the "
                            "camera's image; focal_mm and focus_m record the lens state, no mapping uses them."),
            "properties": {
                "K": {"$ref": "#/$defs/K"},
                "distortion": {"$ref": "#/$defs/distortion"},
                "focal_mm": {"type": "number", "exclusiveMinimum": 0, "description": "Focal length setting in mm."},
                "focus_m": {"type": "number", "exclusiveMinimum": 0, "description": "Focus distance in m."},
            },
            "required": ["K", "distortion"],
            "additionalProperties": False,
        },
        "board_shape": {
            "type": "object",
            "description": "The calibration board's surface: Legendre coefficients over the corner extent.",
            "properties": {
                "surface": {"const": "legendre"},
                "degree": {"type": "integer", "minimum": 0},
                "centre": _POINT2,
                "half_size": _POINT2,
                "coefficients": {"type": "array", "items": _row({"type": "integer"}, {"type": "integer"}, _NUMBER)},
                "in_plane": {"type": "array",
                             "items": _row({"type": "integer"}, {"type": "integer"}, _NUMBER, _NUMBER)},
            },
            "required": ["surface", "degree", "centre", "half_size", "coefficients"],
            "additionalProperties": False,
        },
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": RIG_SCHEMA_ID,
        "title": "camcal rig file (*.rig.json)",
        "description": ("Cameras x ~ K [R | -R c] X in one coordinate frame, optionally moving over frames. "
                        "Lengths in 'units', angles as rotation matrices. See docs/rig.md."),
        "type": "object",
        "properties": {
            "format": {"const": RIG_FORMAT},
            "version": {"const": RIG_VERSION},
            "units": {"type": "string", "minLength": 1, "default": "m"},
            "cameras": {"type": "array", "items": {"$ref": "#/$defs/camera"}, "minItems": 1},
            "frames": {"type": "array", "items": {"$ref": "#/$defs/frame"}, "default": []},
            "points": {"type": ["string", "null"], "minLength": 1,
                       "description": "A PLY of sparse points beside the rig file, or null."},
            "provenance": {
                "type": "object",
                "description": "Who made the rig and how; free-form beyond these keys ('unknown' when absent).",
                "properties": {"tool": {"type": "string"}, "method": {"type": "string"},
                               "created": {"type": "string"}, "board_shape": {"$ref": "#/$defs/board_shape"}},
            },
        },
        "required": ["format", "version", "cameras"],
        "additionalProperties": False,
        "$defs": defs,
    }


#: The rig file's JSON Schema (draft 2020-12), as ``docs/rig.schema.json`` publishes it.
RIG_SCHEMA: dict = _build()


def rig_schema_json() -> str:
    """:data:`RIG_SCHEMA` as the text of ``docs/rig.schema.json`` (two-space indent, a final newline)."""
    return json.dumps(RIG_SCHEMA, indent=2) + "\n"


def validate_rig_dict(data: Any) -> list[str]:
    """The ways a parsed rig file breaks :data:`RIG_SCHEMA` (empty when it conforms).

    Examples
    --------
    >>> validate_rig_dict({"format": "camcal.rig", "version": 1, "cameras": []})
    ['/cameras: expected at least 1 item(s), got 0']
    """
    return schema_errors(data, RIG_SCHEMA)


def load_validated(path: str | os.PathLike) -> Rig:
    """Read a rig file, check it against :data:`RIG_SCHEMA`, then load it (:meth:`Rig.from_dict`'s checks).

    Raises
    ------
    CamcalError
        One line starting with the file name: every schema violation (up to
        five, then how many more), or the first check of the data model that
        fails.
    """
    data = read_json(path, "rig file")
    errors = validate_rig_dict(data)
    if errors:
        shown = "; ".join(errors[:5]) + (f"; and {len(errors) - 5} more" if len(errors) > 5 else "")
        raise CamcalError(f"{path}: does not conform to the rig file schema ({RIG_SCHEMA_ID}): {shown}")
    try:
        return Rig.from_dict(data)
    except CamcalError as error:
        raise CamcalError(f"{path}: conforms to the schema but {error}") from None


if __name__ == "__main__":
    print(rig_schema_json(), end="")
