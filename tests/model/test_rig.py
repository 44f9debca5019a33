"""The rig file: round trip, validation messages, atomic save, projection."""

import dataclasses
import json
import os

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Frame, Lens, Rectification, Rig, make_provenance
from camcal.model.rig_frames import ShutterCheck
from camcal.synthetic import example_camera, points_in_view


#: The left camera's lens at frame 1002: zoomed in, the principal point drifted, less barrel distortion.
ZOOMED = Lens([[1800.0, 0.0, 962.25], [0.0, 1800.0, 537.5], [0.0, 0.0, 1.0]],
              Distortion("division", {"lambda": -0.6e-7}, center=(962.25, 537.5)), focal_mm=42.5, focus_m=3.0)


def stereo_rig() -> Rig:
    left = example_camera("left", distortion=Distortion("division", {"lambda": -1.2e-7}, center=(959.5, 539.5)))
    right = example_camera(
        "right",
        centre=(0.665, -5.99, 1.41),
        fy=1500.0,
        distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 1e-4, "p2": 0.0, "k3": 0.0}),
    )
    H = np.array([[1.01, 0.002, -3.0], [-0.001, 0.99, 2.5], [1e-6, 0.0, 1.0]])
    right = Camera(
        **{**right.__dict__, "rectification": Rectification(H, right.K, (1920, 1080)), "sensor_width_mm": 36.0,
           "quality": {"rms_px": 0.21, "n_views": 18, "sigma": {"fx": 0.31, "baseline_m": 1e-4}}}
    )
    frames = (
        Frame(1001, np.eye(3), [0.0, 0.0, 0.0], {"left": "left/1001.jpg", "right": "right/1001.jpg"}),
        Frame(1002, look_at([0, 0, 0], [0.3, 1.0, 0.0], up=[0, 0, -1]).T @ look_at([0, 0, 0], [0, 1.0, 0], up=[0, 0, -1]), [0.1, 0.2, 0.0],
              lenses={"left": ZOOMED}),
    )
    return Rig((left, right), units="m", frames=frames, points="points.ply", provenance=make_provenance("test", seed=3))


def test_round_trip_exact(tmp_path):
    rig = stereo_rig()
    path = rig.save(tmp_path / "a.rig.json")
    loaded = Rig.load(path)
    assert loaded == rig
    assert loaded.to_json() == path.read_text()
    assert Rig.from_dict(json.loads(path.read_text())) == rig
    # floats survive bit for bit
    assert np.array_equal(loaded.camera("right").rectification.H, rig.camera("right").rectification.H)


def test_save_is_atomic_and_leaves_nothing_on_failure(tmp_path):
    rig = stereo_rig()
    path = rig.save(tmp_path / "a.rig.json")
    before = path.read_text()
    broken = Rig((example_camera("x"),), provenance={"tool": "t", "method": "m", "created": "now", "bad": float("nan")})
    with pytest.raises(ValueError):
        broken.save(path)
    assert path.read_text() == before
    assert sorted(os.listdir(tmp_path)) == ["a.rig.json"]


def test_project_matches_P_without_distortion_and_applies_distortion():
    camera = stereo_rig().camera("left")
    X = points_in_view(camera, 50, np.random.default_rng(1))
    homogeneous = np.hstack([X, np.ones((50, 1))]) @ camera.P.T
    ideal = homogeneous[:, :2] / homogeneous[:, 2:]
    assert np.allclose(camera.distortion.undistort(camera.project(X), camera.K), ideal, atol=1e-9)
    assert np.abs(camera.project(X) - ideal).max() > 1.0  # the lens really distorts


def test_camera_at_frame_composes_rig_pose():
    rig = stereo_rig()
    frame = rig.frames[1]
    camera = rig.camera("right")
    world = rig.camera_at_frame("right", 1002)
    X_world = np.random.default_rng(2).normal(size=(10, 3)) + [0, 5, 0]
    X_rig = (X_world - frame.c) @ frame.R.T
    assert np.allclose(world.project(X_world), camera.project(X_rig), atol=1e-9)
    with pytest.raises(CamcalError, match="no frame 7"):
        rig.camera_at_frame("right", 7)


def test_camera_at_frame_takes_the_frames_lens():
    rig = stereo_rig()
    left = rig.camera("left")
    X_world = np.random.default_rng(3).normal(scale=0.3, size=(20, 3)) + [0, 6, 0]
    for index, lens in ((1001, None), (1002, ZOOMED)):
        frame = next(f for f in rig.frames if f.index == index)
        at_frame = rig.camera_at_frame("left", index)
        K, distortion = (left.K, left.distortion) if lens is None else (lens.K, lens.distortion)
        # the truth, composed by hand: world -> rig -> camera, pinhole with the frame's K, then its distortion
        X_camera = ((X_world - frame.c) @ frame.R.T - left.c) @ left.R.T
        ideal = X_camera[:, :2] / X_camera[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
        assert np.allclose(at_frame.project(X_world), distortion.distort(ideal, K), atol=1e-9)
    assert np.array_equal(rig.camera_at_frame("left", 1002).K, ZOOMED.K)
    assert rig.camera_at_frame("left", 1002).distortion == ZOOMED.distortion
    assert np.array_equal(rig.camera_at_frame("right", 1002).K, rig.camera("right").K)  # no lens for it: its own


def test_lens_state_is_optional_and_round_trips():
    bare = Lens(ZOOMED.K, ZOOMED.distortion)
    assert bare.to_dict().keys() == {"K", "distortion"}
    assert Lens.from_dict(ZOOMED.to_dict()) == ZOOMED and Lens.from_dict(bare.to_dict()) == bare
    assert ZOOMED.to_dict()["focal_mm"] == 42.5 and ZOOMED.to_dict()["focus_m"] == 3.0


def test_rolling_shutter_checks_round_trip_and_bad_ones_are_named():
    rig = stereo_rig()
    frames = (dataclasses.replace(rig.frames[0], rolling_shutter={"left": ShutterCheck(3.25, True),
                                                                  "right": ShutterCheck(0.5, False)}),
              *rig.frames[1:])
    checked = dataclasses.replace(rig, frames=frames)
    again = Rig.from_dict(json.loads(json.dumps(checked.to_dict())))
    assert again == checked and again.frames[0].rolling_shutter["left"].displacement_px == 3.25
    assert "rolling_shutter" not in again.frames[1].to_dict()
    data = checked.to_dict()
    data["frames"][0]["rolling_shutter"]["left"]["displacement_px"] = -1.0
    with pytest.raises(CamcalError, match=r"rolling_shutter\['left'\]: displacement_px must be a number >= 0"):
        Rig.from_dict(data)
    data["frames"][0]["rolling_shutter"] = {"middle": {"displacement_px": 1.0, "flagged": False}}
    with pytest.raises(CamcalError, match="rolling-shutter check of unknown camera"):
        Rig.from_dict(data)


def test_rig_show_counts_frames_with_a_lens():
    assert "2 frame(s) (per-frame lens on 1 frames)" in stereo_rig().summary()
    static = Rig((example_camera("x"),))
    assert "per-frame lens" not in static.summary()


def edit(data, path, value):
    """Set (or with value=KeyError, delete) a nested key of a rig dict."""
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


BAD = [
    (("format",), "camcal.lens", "format must be 'camcal.rig'"),
    (("version",), 2, "unsupported rig version 2"),
    (("cameras", 0, "K"), KeyError, r"cameras\[0\] \('left'\): camera is missing key 'K'"),
    (("cameras", 1, "R"), [[1, 0, 0], [0, 1, 0], [0, 0.1, 1]], r"cameras\[1\] \('right'\): R is not orthonormal"),
    (("cameras", 1, "R"), [[-1, 0, 0], [0, 1, 0], [0, 0, 1]], "reflection"),
    (("cameras", 0, "K"), [[1000, 0, 960], [3, 1000, 540], [0, 0, 1]], "K must be upper triangular"),
    (("cameras", 0, "K"), [[1000, 0, 960], [0, 1000, 540], [0, 0, 2]], r"K\[2\]\[2\] must be 1"),
    (("cameras", 0, "K"), [[-1000, 0, 960], [0, 1000, 540], [0, 0, 1]], "positive fx and fy"),
    (("cameras", 0, "K"), [[1000, 0], [0, 1000]], "K must have shape 3x3"),
    (("cameras", 0, "image_size"), [1920], "image_size must be"),
    (("cameras", 0, "distortion", "model"), "fisheye", "unknown distortion model 'fisheye'"),
    (("cameras", 0, "lens"), {}, "unknown key"),
    (("cameras", 1, "name"), "left", "camera names must be unique"),
    (("cameras", 1, "quality", "rms_px"), "low", "quality.rms_px must be a number"),
    (("cameras", 1, "rectification", "H"), [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "rectification.H is singular"),
    (("frames", 0, "images", "middle"), "m.jpg", "unknown camera"),
    (("frames", 1, "index"), 1001, "frame indices must be unique"),
    (("cameras",), [], "at least one camera"),
    (("frames", 1, "lenses", "middle"), ZOOMED.to_dict(), "frame 1002 has a lens for unknown camera 'middle'"),
    (("frames", 1, "lenses", "left", "distortion"), {"model": "polynomial", "params": {"k1": 0.1, "k2": 0.0}},
     "frame 1002 lens of 'left' has distortion model 'polynomial', the camera has 'division'"),
    (("frames", 1, "lenses", "left", "K"), [[1e7, 0, 960], [0, 1e7, 540], [0, 0, 1]],
     "frame 1002 lens of 'left': K: fx = 10000000.0 is not a plausible focal length"),
    (("frames", 1, "lenses", "left", "K"), [[1800, 0, 960], [0, 0, 540], [0, 0, 1]], r"frames\[1\]: lenses\['left'\]: K must have positive"),
    (("frames", 1, "lenses", "left", "focal_mm"), -35.0, "focal_mm must be a positive number"),
    (("frames", 1, "lenses", "left", "zoom"), 2.0, "lens has unknown key"),
    (("frames", 1, "lenses"), [1], "lenses must be an object"),
]


@pytest.mark.parametrize("path, value, message", BAD, ids=[m for _, _, m in BAD])
def test_validation_names_the_bad_field(tmp_path, path, value, message):
    data = edit(stereo_rig().to_dict(), path, value)
    file = tmp_path / "bad.rig.json"
    file.write_text(json.dumps(data))
    with pytest.raises(CamcalError, match=message) as info:
        Rig.load(file)
    assert str(file) in str(info.value) and "\n" not in str(info.value)


def test_provenance_is_optional_and_filled_with_unknown(tmp_path):
    data = stereo_rig().to_dict()
    del data["provenance"]
    (tmp_path / "typed.rig.json").write_text(json.dumps(data))
    rig = Rig.load(tmp_path / "typed.rig.json")
    assert dict(rig.provenance) == {"tool": "unknown", "method": "unknown", "created": "unknown"}
    partial = edit(stereo_rig().to_dict(), ("provenance",), {"tool": "Kalibr"})
    assert dict(Rig.from_dict(partial).provenance) == {"tool": "Kalibr", "method": "unknown", "created": "unknown"}
    assert Rig.from_dict(rig.to_dict()) == rig


def test_non_finite_values_in_memory_are_named():
    data = edit(stereo_rig().to_dict(), ("cameras", 0, "c"), [0, float("nan"), 0])
    with pytest.raises(CamcalError, match=r"cameras\[0\] \('left'\): c contains NaN"):
        Rig.from_dict(data)


def test_malformed_files(tmp_path):
    with pytest.raises(CamcalError, match="rig file not found"):
        Rig.load(tmp_path / "missing.rig.json")
    broken = tmp_path / "broken.rig.json"
    broken.write_text('{"format": "camcal.rig", ')
    with pytest.raises(CamcalError, match="not valid JSON"):
        Rig.load(broken)
    nan = tmp_path / "nan.rig.json"
    nan.write_text(stereo_rig().to_json().replace('"c": [0.6,', '"c": [NaN,', 1))
    with pytest.raises(CamcalError, match="non-finite number NaN"):
        Rig.load(nan)


def test_inputs_are_copied_not_aliased():
    K = example_camera().K.copy()
    camera = Camera("a", (1920, 1080), K, Distortion.none(), np.eye(3), np.zeros(3))
    K[0, 0] = 5.0
    assert camera.K[0, 0] != 5.0
    with pytest.raises(ValueError):
        camera.K[0, 0] = 1.0


def test_with_camera_replaces_a_camera_and_its_frame_lenses():
    rig = stereo_rig()
    assert rig.lens_frames("left") == (1002,) and rig.lens_frames("right") == ()
    left = dataclasses.replace(rig.camera("left"), distortion=Distortion("division", {"lambda": 0.0}))
    wider = Lens(ZOOMED.K, Distortion("division", {"lambda": 0.0}), focal_mm=20.0)
    new = rig.with_camera(left, {1001: wider}, units="cm")
    assert new.units == "cm" and new.camera("left") == left and new.camera("right") == rig.camera("right")
    assert new.lens_frames("left") == (1001,) and new.frames[0].lenses["left"] == wider
    assert [f.images for f in new.frames] == [f.images for f in rig.frames]
    assert rig.with_camera(rig.camera("left")).lens_frames("left") == ()
    with pytest.raises(CamcalError, match="no frame 7"):
        rig.with_camera(left, {7: wider})
    with pytest.raises(CamcalError, match="distortion model 'polynomial', the camera has 'division'"):
        rig.with_camera(left, {1001: Lens(ZOOMED.K, Distortion("polynomial", {"k1": 0.1, "k2": 0.0}))})
