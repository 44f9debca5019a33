"""The rig file's JSON Schema: published as docs/rig.schema.json, agrees with the loader, used by `rig show --validate`."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.base.schema import schema_errors
from camcal.cli import main
from camcal.model.distortion import MODEL_PARAMS, Distortion
from camcal.model.quality import ParameterCovariance, Quality
from camcal.model.rig import Camera, Frame, Lens, Rectification, Rig, make_provenance
from camcal.model.rig_frames import ShutterCheck
from camcal.model.rig_schema import RIG_SCHEMA, rig_schema_json, validate_rig_dict
from camcal.model.spline import SplineField

ROOT = Path(__file__).resolve().parents[2]
#: Lens models whose parameters take any number (the 3DE models need a film back: their own tests cover them).
CORE_MODELS = ("none", "polynomial", "opencv", "division", "kannala-brandt", "kannala-brandt-thin-prism")
SIZE = (640, 480)


def _K(fx=700.0, fy=698.0, cx=321.5, cy=238.0, skew=0.0):
    return [[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]


def _rotation(angle_deg):
    a = np.radians(angle_deg)
    return [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]


def full_rig() -> Rig:
    """A rig with every optional part the file holds: each lens model, a correction field, rectification,
    quality with sigmas and covariance, frames with images and per-frame lenses, points and a board shape in the
    provenance."""
    cameras = []
    for index, model in enumerate(CORE_MODELS):
        required, optional = MODEL_PARAMS[model]
        params = {name: 1e-3 * (k + 1) for k, name in enumerate(required + optional)}
        if model == "division":
            params = {"lambda": -2e-7, "aspect": 1.01}
        center = (322.0, 240.5) if model == "division" else None
        correction = SplineField(SIZE, np.full((4, 5, 2), 0.01)) if model == "polynomial" else None
        cameras.append(Camera(
            f"cam{index}", SIZE, _K(skew=0.1 * index), Distortion(model, params, center, correction),
            _rotation(3.0 * index), [0.1 * index, 0.0, 0.0], sensor_width_mm=36.0 if index == 0 else None,
            rectification=Rectification(np.eye(3), _K(), SIZE) if index == 1 else None,
            quality=Quality(rms_px=0.2, worst_px=0.8, heldout_rms_px=0.25, n_views=12, n_observations=600,
                            n_outliers=0, sigma={"fx": 0.4, "k1": 1e-4, "rotation_deg": 0.01},
                            worst_projection_sigma_px=0.1,
                            covariance=ParameterCovariance(("fx", "cx"), ((0.16, 0.01), (0.01, 0.09))))))
    zoomed = {"cam3": Lens(_K(fx=760.0, fy=758.0), Distortion("division", {"lambda": -1e-7}), 50.0, 2.5),
              "cam2": Lens(_K(cx=318.0), cameras[2].distortion)}
    frames = (Frame(0, np.eye(3), [0.0, 0.0, 0.0], {"cam0": "a.png"}),
              Frame(1, _rotation(5.0), [0.0, 0.1, 0.0], lenses=zoomed,
                    rolling_shutter={"cam0": ShutterCheck(2.5, True)}))
    shape = {"surface": "legendre", "degree": 2, "centre": [4.0, 2.5], "half_size": [4.0, 2.5],
             "coefficients": [[2, 0, 0.01], [1, 1, -0.02]], "in_plane": [[2, 0, 0.001, 0.0]]}
    return Rig(tuple(cameras), units="m", frames=frames, points="points.ply",
               provenance=make_provenance("test", board_shape=shape))


def test_published_schema_is_the_one_camcal_checks_against():
    """docs/rig.schema.json is generated: `python -m camcal.model.rig_schema > docs/rig.schema.json`."""
    assert (ROOT / "docs" / "rig.schema.json").read_text() == rig_schema_json()


def test_every_part_camcal_writes_conforms():
    data = full_rig().to_dict()
    assert validate_rig_dict(json.loads(json.dumps(data))) == []
    assert Rig.from_dict(data) == full_rig()


def _set(data, path, value):
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value


_DELETE = object()
# each breaks the file's structure: the schema and the loader must both refuse it, and the schema says where
BROKEN = [
    (("format",), "camcal.rigs", "/format"),
    (("version",), 2, "/version"),
    (("cameras",), [], "/cameras"),
    (("points",), "", "/points"),
    (("units",), 3, "/units"),
    (("extra",), 1, "unknown key 'extra'"),
    (("cameras", 0, "K", 1, 0), 0.5, "/cameras/0/K/1/0"),
    (("cameras", 0, "K", 2, 2), 2.0, "/cameras/0/K/2/2"),
    (("cameras", 0, "K", 0, 0), -700.0, "/cameras/0/K/0/0"),
    (("cameras", 0, "K", 2), [0.0, 0.0], "/cameras/0/K/2"),
    (("cameras", 0, "image_size"), [640.5, 480], "/cameras/0/image_size/0"),
    (("cameras", 0, "image_size"), [True, 480], "/cameras/0/image_size/0"),
    (("cameras", 0, "R", 0), [1.0, 0.0], "/cameras/0/R/0"),
    (("cameras", 0, "c"), [0.0, "x", 0.0], "/cameras/0/c/1"),
    (("cameras", 0, "name"), "", "/cameras/0/name"),
    (("cameras", 0, "colour"), "red", "unknown key 'colour'"),
    (("cameras", 0, "distortion"), {"model": "fisheye", "params": {}}, "/cameras/0/distortion"),
    (("cameras", 2, "distortion", "params", "k9"), 0.1, "unknown key 'k9'"),
    (("cameras", 2, "distortion", "params", "k1"), _DELETE, "missing key 'k1'"),
    (("cameras", 2, "distortion", "center"), [1.0, 2.0], "unknown key 'center'"),
    (("cameras", 3, "distortion", "params", "aspect"), 0.0, "/cameras/3/distortion/params/aspect"),
    (("cameras", 1, "rectification", "H"), [[1.0]], "/cameras/1/rectification/H"),
    (("cameras", 0, "quality", "n_views"), -1, "/cameras/0/quality/n_views"),
    (("cameras", 0, "quality", "sigma", "fx"), -0.4, "/cameras/0/quality/sigma/fx"),
    (("cameras", 0, "quality", "rms"), 0.2, "unknown key 'rms'"),
    (("cameras", 0, "sensor_width_mm"), 0, "/cameras/0/sensor_width_mm"),
    (("frames", 0, "index"), "first", "/frames/0/index"),
    (("frames", 0, "images", "cam0"), 3, "/frames/0/images/cam0"),
    (("frames", 1, "lenses", "cam3", "K", 1, 1), 0.0, "/frames/1/lenses/cam3/K/1/1"),
    (("frames", 1, "lenses", "cam3", "focus_m"), 0.0, "/frames/1/lenses/cam3/focus_m"),
    (("frames", 1, "lenses", "cam3", "distortion"), _DELETE, "missing key 'distortion'"),
    (("frames", 1, "lenses", "cam3", "iris"), 2.8, "unknown key 'iris'"),
]


@pytest.mark.parametrize("path, value, where", BROKEN, ids=[w for *_, w in BROKEN])
def test_schema_and_loader_refuse_the_same_broken_files(path, value, where):
    data = full_rig().to_dict()
    _set(data, path, value)
    errors = validate_rig_dict(data)
    assert errors and any(where in error for error in errors), errors
    with pytest.raises(CamcalError):
        Rig.from_dict(data)


def test_what_json_schema_cannot_say_the_loader_still_refuses():
    """A reflection instead of a rotation has the schema's shape; the loader's own checks refuse it."""
    data = full_rig().to_dict()
    data["cameras"][0]["R"] = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    assert validate_rig_dict(data) == []
    with pytest.raises(CamcalError, match="reflection"):
        Rig.from_dict(data)


def test_older_files_the_loader_reads_conform():
    """A hand-typed rig (no provenance, frames, points, quality; params of 'none' left out) and older quality keys."""
    data = {"format": "camcal.rig", "version": 1,
            "cameras": [{"name": "a", "image_size": [640, 480], "K": [[700, 0, 320], [0, 700, 240], [0, 0, 1]],
                         "distortion": {"model": "none"}, "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "c": [0, 0, 0],
                         "quality": {"n_points": 40, "sigma": {"f": 0.5}}}]}
    assert validate_rig_dict(data) == []
    Rig.from_dict(data)


def test_validator_follows_json_schema_semantics():
    assert schema_errors(0.0, {"const": 0}) == []  # 0 and 0.0 are the same JSON number
    assert schema_errors(True, {"type": "integer"}) != []  # a boolean is not a number
    assert schema_errors(2.0, {"type": "integer"}) == []
    assert schema_errors(2.5, {"type": "integer"}) != []
    assert schema_errors(float("nan"), {"type": "number"}) != []
    one_of = {"oneOf": [{"type": "string"}, {"type": "number", "minimum": 0}]}
    assert schema_errors(3, one_of) == [] and schema_errors(-3, one_of) == ["/: -3 is less than the minimum 0"]
    assert schema_errors(3, {"oneOf": [{"type": "number"}, {"minimum": 0}]}) == [
        "/: matches 2 of the alternatives, expected exactly one"]
    assert schema_errors({"a/b": "x"}, {"additionalProperties": {"type": "number"}}) == [
        "/a~1b: expected number, got 'x'"]


def test_validator_refuses_keywords_it_does_not_implement():
    with pytest.raises(CamcalError, match="pattern"):
        schema_errors("x", {"type": "string", "pattern": "^x$"})
    with pytest.raises(CamcalError, match=r"\$defs"):
        schema_errors(1, {"$ref": "#/$defs/missing"})


def test_schema_holds_every_lens_model():
    branches = RIG_SCHEMA["$defs"]["distortion"]["oneOf"]
    assert [b["properties"]["model"]["const"] for b in branches] == list(MODEL_PARAMS)
    for branch, (required, optional) in zip(branches, MODEL_PARAMS.values()):
        assert set(branch["properties"]["params"]["properties"]) == set(required + optional)


def test_rig_schema_uses_only_supported_keywords():
    """Validating every part runs every keyword of the schema through the validator without refusal."""
    assert RIG_SCHEMA["$schema"].endswith("2020-12/schema")
    schema_errors(full_rig().to_dict(), RIG_SCHEMA)


def test_rig_show_validate(tmp_path, capsys):
    good = full_rig().save(tmp_path / "good.rig.json")
    assert main(["rig", "show", "--validate", str(good)]) == 0
    out = capsys.readouterr().out
    assert "valid (conforms to docs/rig.schema.json and loads)" in out and "cam0" in out
    data = copy.deepcopy(full_rig().to_dict())
    data["cameras"][0]["K"][1][0] = 0.5
    data["cameras"][0]["colour"] = "red"
    bad = tmp_path / "bad.rig.json"
    bad.write_text(json.dumps(data))
    assert main(["rig", "show", "--validate", str(bad)]) == 2
    captured = capsys.readouterr()
    error_lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(error_lines) == 1 and "/cameras/0/K/1/0" in error_lines[0] and "'colour'" in error_lines[0]
    assert "valid" not in captured.out
    # without --validate the loader's first complaint is what the user sees, as before
    assert main(["rig", "show", str(bad)]) == 2


@pytest.mark.parametrize("model", [m for m in MODEL_PARAMS if m not in CORE_MODELS])
def test_film_back_lenses_conform(model):
    """The 3DE lens models (parameters plus the film back in pixels) written by camcal pass the schema."""
    params = {"filmback_width_px": float(SIZE[0]), "filmback_height_px": float(SIZE[1])}
    camera = Camera("cam", SIZE, _K(), Distortion(model, params), np.eye(3), [0.0, 0.0, 0.0])
    assert validate_rig_dict(Rig((camera,)).to_dict()) == []
