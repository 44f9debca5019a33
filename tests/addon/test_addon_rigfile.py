"""Reading and checking rig files in the add-on (no bpy)."""

import json

import numpy as np
import pytest

from addon_helpers import camera_dict, frame, rotation, write_rig
from addon_helpers import addon  # noqa: F401  (fixtures)

K = [[800.0, 0.0, 640.2], [0.0, 790.0, 355.7], [0.0, 0.0, 1.0]]


def test_reads_cameras_frames_points_with_relative_paths(addon, tmp_path):
    R = rotation(0.1, -0.2, 0.3)
    frames = [frame(3, R, (1, 2, 3), {"left": "plates/left_0003.png", "right": "right_0003.png"}), frame(4)]
    path = write_rig(
        tmp_path / "stereo.rig.json",
        [camera_dict("left", (1280, 720), K, R), camera_dict("right", (1280, 720), K, R, c=(0.1, 0, 0))],
        frames=frames,
        points="stereo_points.ply",
    )
    rig = addon.rigfile.load_rig(path)
    assert rig.name == "stereo"
    assert [c.name for c in rig.cameras] == ["left", "right"]
    cam = rig.camera("left")
    assert cam.K == tuple(tuple(r) for r in K)
    assert np.allclose(cam.R, R, atol=0, rtol=0)
    assert cam.distortion.model == "none"
    assert cam.distortion.center == (640.2, 355.7)  # defaults to the principal point
    assert rig.points == str(tmp_path / "stereo_points.ply")
    first = rig.frames[0]
    assert first.index == 3 and first.c == (1.0, 2.0, 3.0) and np.allclose(first.R, R, atol=0, rtol=0)
    assert first.images == {"left": str(tmp_path / "plates" / "left_0003.png"),
                            "right": str(tmp_path / "right_0003.png")}
    assert rig.frames[1].images == {}
    with pytest.raises(KeyError, match="cameras: left, right"):
        rig.camera("centre")


def test_polynomial_centre_is_the_principal_point(addon, tmp_path):
    K = [[800.0, 0.0, 640.5], [0.0, 800.0, 360.25], [0.0, 0.0, 1.0]]
    dist = {"model": "polynomial", "params": {"k1": -0.1, "k2": 0.01}}
    path = write_rig(tmp_path / "p.rig.json", [camera_dict("a", (1280, 720), K, distortion=dist)])
    d = addon.rigfile.load_rig(path).cameras[0].distortion
    assert d.model == "polynomial" and d.center == (640.5, 360.25) and d.params == {"k1": -0.1, "k2": 0.01}


def test_double_precision_survives(addon, tmp_path):
    fx = 1234.5678901234567
    path = write_rig(tmp_path / "a.rig.json", [camera_dict("a", (100, 80), [[fx, 0, 49.5], [0, fx, 39.5], [0, 0, 1]])])
    assert addon.rigfile.load_rig(path).cameras[0].K[0][0] == fx


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda r: r.update(format="other"), "format: expected 'camcal.rig'"),
        (lambda r: r.update(version=7), "version: unsupported 7"),
        (lambda r: r.update(cameras=[]), "cameras: the rig has no cameras"),
        (lambda r: r["cameras"][0].pop("K"), r"cameras\[0\] \(a\): missing key 'K'"),
        (lambda r: r["cameras"][0].update(K=[[1, 0], [0, 1]]), r"\.K: expected a 3x3 matrix"),
        (lambda r: r["cameras"][0].update(K=[[100, 0, 5], [1, 100, 5], [0, 0, 1]]), "upper-triangular"),
        (lambda r: r["cameras"][0].update(K=[[-100, 0, 5], [0, 100, 5], [0, 0, 1]]), "focal lengths must be positive"),
        (lambda r: r["cameras"][0].update(R=[[1, 0, 0], [0, 1, 0], [0, 0, 1.1]]), "R: not orthonormal"),
        (lambda r: r["cameras"][0].update(R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "R: a reflection"),
        (lambda r: r["cameras"][0].update(c=[0, float("nan"), 0]), "c: expected 3 finite numbers"),
        (lambda r: r["cameras"][0].update(image_size=[0, 10]), "image_size: must be positive"),
        (lambda r: r["cameras"][0].update(distortion={"model": "poly"}), "unknown model 'poly', expected one of"),
        (lambda r: r["cameras"][0].update(distortion={"model": "division", "params": {}}), "needs 'lambda'"),
        (lambda r: r["cameras"][0].update(distortion={"model": "polynomial", "params": {"k1": 0.1}}), "needs 'k2'"),
        (lambda r: r["cameras"].append(dict(r["cameras"][0])), "duplicate camera name 'a'"),
        (lambda r: r.update(frames=[{"R": np.eye(3).tolist(), "c": [0, 0, 0]}]), r"frames\[0\]: missing key 'index'"),
        (lambda r: r.update(frames=[frame(0, images={"b": "b.png"})]), r"frames\[0\] \(index 0\)\.images: unknown camera 'b'"),
        (lambda r: r.update(frames=[frame(0, images={"a": 3})]), r"\.images\.a: expected a path"),
        (lambda r: r.update(frames=[frame(0), frame(0)]), "duplicate frame index 0"),
        (lambda r: r.update(frames=[frame(0, R=np.diag([1, 1, -1.0]))]), r"\(index 0\)\.R: a reflection"),
        (lambda r: r.update(points=5), "points: expected a PLY path or null"),
        (lambda r: r.update(frames=[frame(0, lenses={"b": {"K": [[120, 0, 50], [0, 120, 40], [0, 0, 1]], "distortion": {"model": "none"}}})]), r"\(index 0\)\.lenses\.b: unknown camera 'b'"),
        (lambda r: r.update(frames=[frame(0, lenses={"a": {"K": [[120, 0, 50], [0, 120, 40], [0, 0, 1]],
                                                              "distortion": {"model": "division", "params": {"lambda": 0.1}}}})]),
         r"lenses\.a\.distortion\.model: 'division', but the camera's lens is 'none'"),
        (lambda r: r.update(frames=[frame(0, lenses={"a": {"K": [[120, 0, 50], [0, 120, 40], [0, 0, 1]]}})]),
         r"lenses\.a: missing key 'distortion'"),
        (lambda r: r.update(frames=[frame(0, lenses={"a": {**{"K": [[120, 0, 50], [0, 120, 40], [0, 0, 1]], "distortion": {"model": "none"}}, "focal_mm": -3}})]), r"lenses\.a\.focal_mm: expected a positive"),
        (lambda r: r.update(frames=[frame(0, lenses={"a": {**{"K": [[120, 0, 50], [0, 120, 40], [0, 0, 1]], "distortion": {"model": "none"}}, "K": [[0, 0, 50], [0, 120, 40], [0, 0, 1]]}})]),
         r"lenses\.a\.K: focal lengths must be positive"),
    ],
)
def test_bad_fields_are_named(addon, tmp_path, mutate, message):
    rig = {"format": "camcal.rig", "version": 1,
           "cameras": [camera_dict("a", (100, 80), [[100, 0, 50], [0, 100, 40], [0, 0, 1]])]}
    mutate(rig)
    path = tmp_path / "bad.rig.json"
    path.write_text(json.dumps(rig))
    with pytest.raises(addon.rigfile.RigFileError, match=message):
        addon.rigfile.load_rig(path)


def test_unreadable_and_malformed_files(addon, tmp_path):
    with pytest.raises(addon.rigfile.RigFileError, match="cannot read rig file"):
        addon.rigfile.load_rig(tmp_path / "missing.rig.json")
    bad = tmp_path / "broken.rig.json"
    bad.write_text("{not json")
    with pytest.raises(addon.rigfile.RigFileError, match="not valid JSON"):
        addon.rigfile.load_rig(bad)


def test_per_frame_lenses_read_as_camcal_writes_them(addon, tmp_path):
    """A rig camcal saves with a lens on some frames reads back in the add-on to the last bit."""
    from camcal.model.distortion import Distortion
    from camcal.model.rig import Camera, Frame, Lens, Rig

    camera = Camera("a", (1280, 720), K, Distortion("division", {"lambda": -1e-7}), np.eye(3), [0.0, 0.0, 0.0])
    zoomed = Lens([[1012.25, 0.0, 641.0], [0.0, 1000.5, 356.0], [0.0, 0.0, 1.0]],
                  Distortion("division", {"lambda": -0.5e-7}), focal_mm=35.0)
    frames = (Frame(1, np.eye(3), [0.0, 0.0, 0.0]), Frame(2, np.eye(3), [0.0, 0.0, 0.1], lenses={"a": zoomed}))
    path = Rig((camera,), frames=frames).save(tmp_path / "zoom.rig.json")
    rig = addon.rigfile.load_rig(path)
    assert rig.frames[0].lenses == {}
    lens = rig.frames[1].lenses["a"]
    assert lens.K == tuple(map(tuple, zoomed.K.tolist()))
    assert lens.distortion.model == "division" and lens.distortion.params == {"lambda": -0.5e-7}
    assert lens.distortion.center == (641.0, 356.0)  # the frame's principal point, not the camera's
    assert lens.focal_mm == 35.0 and lens.focus_m is None
