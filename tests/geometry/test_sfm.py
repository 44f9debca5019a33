"""pycolmap SfM -> camcal Rig, against a rendered scene with known cameras."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.geometry.camera import look_at
from camcal.geometry.distortion import Distortion
from camcal.geometry.sfm import solve_sfm
from camcal.io.ply import read_points_ply, write_points_ply
from camcal.rig import Camera, Rig
from camcal.synthetic import procedural_texture, render_planes, room_corner_planes

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
BASELINE = 0.3


def render_stereo_sequence(root, n_frames=7):
    """A stereo rig (baseline 0.3 m along its x axis) moving through a textured room corner."""
    rng = np.random.default_rng(0)
    textures = tuple(procedural_texture(rng) for _ in range(3))
    lens = Distortion("polynomial", {"k1": -0.05, "k2": 0.0})
    truth = {}
    for i in range(n_frames):
        centre = np.array([5.5 - 0.4 * i, 4.0 + 0.3 * i, 1.6 + 0.05 * i])
        R = look_at(centre, [1.5 + 0.1 * i, 1.5, 1.0])
        for name, offset in (("left", 0.0), ("right", BASELINE)):
            camera = Camera(name, (640, 480), K, lens, R, centre + R[0] * offset)
            (root / name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / name / f"{i:04d}.png"), render_planes(camera, room_corner_planes(), textures))
            truth[name, i] = camera
    return truth


def similarity(source, target):
    """Umeyama (1991): s, R, t minimising |target - (s R source + t)|."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    u, d, vt = np.linalg.svd(cov)
    sign = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    R = u @ sign @ vt
    scale = np.trace(np.diag(d) @ sign) / np.mean(np.sum((source - mu_s) ** 2, axis=1))
    return scale, R, mu_t - scale * R @ mu_s


@pytest.mark.slow
def test_stereo_sequence_recovers_known_rig(tmp_path):
    truth = render_stereo_sequence(tmp_path / "in")
    result = solve_sfm({"left": tmp_path / "in/left", "right": tmp_path / "in/right"}, tmp_path / "out")
    assert result.n_registered == result.n_images == 14 and not result.unregistered
    assert result.rms_px < 0.5
    rig = Rig.load(tmp_path / "out/sfm.rig.json")
    for camera in rig.cameras:
        assert abs(camera.K[0, 0] / 500.0 - 1) < 0.005
    solved = {(name, frame.index): rig.camera_at_frame(name, frame.index) for frame in rig.frames for name in frame.images}
    keys = sorted(solved)
    s, R_align, t = similarity(np.array([solved[k].c for k in keys]), np.array([truth[k].c for k in keys]))
    scene_size = 8.0
    for key in keys:
        centre = s * R_align @ solved[key].c + t
        assert np.linalg.norm(centre - truth[key].c) < 0.005 * scene_size
        relative = truth[key].R @ (solved[key].R @ R_align.T).T
        angle = np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1)))
        assert angle < 0.1
    # the rig constraint: one baseline, along the left camera's x axis
    right = rig.camera("right")
    direction = right.c / np.linalg.norm(right.c)
    assert np.degrees(np.arccos(np.clip(direction @ [1.0, 0.0, 0.0], -1, 1))) < 0.1
    # the PLY holds the sparse points with their track lengths
    points = read_points_ply(tmp_path / "out" / rig.points)
    assert len(points) == result.n_points and points["track_length"].min() >= 2


def test_ply_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    xyz, colours, tracks = rng.normal(size=(50, 3)), rng.integers(0, 256, (50, 3)), rng.integers(2, 9, 50)
    points = read_points_ply(write_points_ply(tmp_path / "p.ply", xyz, colours, tracks))
    assert np.array_equal(np.column_stack([points["x"], points["y"], points["z"]]), xyz)
    assert np.array_equal(np.column_stack([points["red"], points["green"], points["blue"]]), colours)
    assert np.array_equal(points["track_length"], tracks)


def test_bad_inputs(tmp_path):
    with pytest.raises(CamcalError, match="image folder not found"):
        solve_sfm({"a": tmp_path / "nope"}, tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CamcalError, match="no images"):
        solve_sfm({"a": tmp_path / "empty"}, tmp_path / "out")
    with pytest.raises(CamcalError, match="unknown matcher"):
        solve_sfm({"a": tmp_path / "empty"}, tmp_path / "out", matcher="magic")


def test_solve_cli_help_and_bad_input(tmp_path):
    help_run = subprocess.run([sys.executable, "-m", "camcal", "solve", "--help"], capture_output=True, text=True)
    assert help_run.returncode == 0 and "usage: camcal solve" in help_run.stdout
    bad = subprocess.run([sys.executable, "-m", "camcal", "solve", str(tmp_path / "nope"), "--out", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "image folder not found" in bad.stderr
    assert not (tmp_path / "o" / "sfm.rig.json").exists()
