"""pycolmap SfM -> camcal Rig, against a rendered scene with known cameras."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from camcal.cli import main
from camcal.base.errors import CamcalError
from camcal.model.camera import rotation_angle_deg, similarity_Umeyama1991
from camcal.pipelines.solve import COLMAP_LOG, collect_images, solve_sfm
from camcal.io.ply import read_points_ply, write_points_ply
from camcal.model.rig import Rig
from camcal.synthetic import render_stereo_sequence

BASELINE = 0.3


@pytest.mark.slow
def test_stereo_sequence_recovers_known_rig(tmp_path, capsys):
    truth = render_stereo_sequence(tmp_path / "in")
    result = solve_sfm({"left": tmp_path / "in/left", "right": tmp_path / "in/right"}, tmp_path / "out")
    assert result.n_registered == result.n_images == 14 and not result.unregistered
    assert result.rms_px < 0.5
    rig = Rig.load(tmp_path / "out/solve.rig.json")
    for camera in rig.cameras:
        assert abs(camera.K[0, 0] / 500.0 - 1) < 0.005
    solved = {(name, frame.index): rig.camera_at_frame(name, frame.index) for frame in rig.frames for name in frame.images}
    keys = sorted(solved)
    s, R_align, t = similarity_Umeyama1991(np.array([solved[k].c for k in keys]), np.array([truth[k].c for k in keys]))
    scene_size = 8.0
    for key in keys:
        centre = s * R_align @ solved[key].c + t
        assert np.linalg.norm(centre - truth[key].c) < 0.005 * scene_size
        assert rotation_angle_deg(truth[key].R @ (solved[key].R @ R_align.T).T) < 0.1
    # the rig constraint: one baseline, along the left camera's x axis
    right = rig.camera("right")
    direction = right.c / np.linalg.norm(right.c)
    assert np.degrees(np.arccos(np.clip(direction @ [1.0, 0.0, 0.0], -1, 1))) < 0.1
    # the PLY holds the sparse points with their track lengths
    points = read_points_ply(tmp_path / "out" / rig.points)
    assert len(points) == result.n_points and points["track_length"].min() >= 2
    # camcal's refinement never ends above its pycolmap seed, and reports per-camera figures
    assert result.bundle is not None and result.bundle.final_cost <= result.bundle.initial_cost
    assert set(result.bundle.rms_after_px) == {"left", "right"}
    assert 0 < rig.camera("left").quality["sigma"]["fx"] < 5.0
    # sigmas: the larger of the covariance and the frame jackknife (one group per frame here)
    calibration = result.self_calibration
    assert calibration.jackknife_groups == len(rig.frames)
    for key, value in result.bundle.sigmas.items():
        assert value == max(calibration.covariance_sigmas.get(key, 0.0), calibration.jackknife_sigmas.get(key, 0.0))
    # frames point at the user's images
    assert (tmp_path / "out" / rig.frames[0].images["left"]).resolve() == (tmp_path / "in/left/0000.png").resolve()

    # the same images with the rig held at a known (board) calibration: metric units, exact baseline
    known = Rig((truth["left", 0], truth["right", 0]), units="m")
    known.save(tmp_path / "known.rig.json")
    capsys.readouterr()
    code = main(["solve", str(tmp_path / "in"), "--rig", str(tmp_path / "known.rig.json"), "--out", str(tmp_path / "metric"),
                 "--json", "--uncertainty", "covariance"])
    assert code == 0
    metric = Rig.load(tmp_path / "metric/solve.rig.json")
    summary = json.loads(capsys.readouterr().out)  # --json: one object on stdout
    assert summary["verb"] == "solve" and summary["figures"]["n_registered"] == len(metric.frames) * 2
    assert summary["figures"]["uncertainty"]["jackknife_groups"] == 0
    assert summary["figures"]["uncertainty"]["covariance_sigmas"]["left.fx"] == pytest.approx(
        metric.camera("left").quality["sigma"]["fx"])
    assert {"path": str(tmp_path / "metric" / "solve.rig.json"), "kind": "rig"} in summary["files"]
    assert summary["figures"]["per_camera_rms_px"]["left"] == pytest.approx(metric.camera("left").quality["rms_px"])
    assert metric.units == "m"
    assert np.linalg.norm(metric.camera("right").c) == pytest.approx(BASELINE, rel=1e-9)
    centres = np.array([metric.camera_at_frame("left", frame.index).c for frame in metric.frames])
    true_centres = np.array([truth["left", i].c for i in range(len(centres))])
    assert np.linalg.norm(centres[-1] - centres[0]) == pytest.approx(np.linalg.norm(true_centres[-1] - true_centres[0]), rel=0.005)


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


def test_collect_images_by_folder_subfolder_and_glob(tmp_path):
    for name in ("a_L.png", "a_R.png", "b_L.png", "b_R.png", "notes.txt"):
        (tmp_path / "flat").mkdir(exist_ok=True)
        (tmp_path / "flat" / name).write_bytes(b"")
    by_glob = collect_images([tmp_path / "flat"], {"left": "*_L.png", "right": "*_R.png"})
    assert [p.name for p in by_glob["left"]] == ["a_L.png", "b_L.png"] and len(by_glob["right"]) == 2
    for camera in ("left", "right"):
        (tmp_path / "rig" / camera).mkdir(parents=True)
        (tmp_path / "rig" / camera / "0001.png").write_bytes(b"")
    assert list(collect_images([tmp_path / "rig"])) == ["left", "right"]
    assert list(collect_images([tmp_path / "rig" / "left"])) == ["left"]
    with pytest.raises(CamcalError, match="no images"):
        collect_images([tmp_path / "flat"], {"left": "*.jpg"})
    with pytest.raises(CamcalError, match="exactly one"):
        collect_images([tmp_path / "flat", tmp_path / "rig"], {"left": "*.png"})


def test_solve_cli_help_and_bad_input(tmp_path):
    help_run = subprocess.run([sys.executable, "-m", "camcal", "solve", "--help"], capture_output=True, text=True)
    assert help_run.returncode == 0 and "usage: camcal solve" in help_run.stdout and "jackknife-refit" in help_run.stdout
    bad = subprocess.run([sys.executable, "-m", "camcal", "solve", str(tmp_path / "nope"), "--out", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "image folder not found" in bad.stderr
    assert not (tmp_path / "o" / "solve.rig.json").exists()


GLOG_LINE = re.compile(r"^[IWEF]\d{8} ")


def _numbers(value, path=""):
    """Every leaf of a rig file's JSON, by its path; the creation time left out (it is the clock's)."""
    if isinstance(value, dict):
        for key, item in value.items():
            if key != "created":
                yield from _numbers(item, f"{path}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _numbers(item, f"{path}[{index}]")
    else:
        yield path, value


def _solve_twice(tmp_path, width: int, max_num_features: int) -> None:
    """Solve a rendered 5-position stereo sequence ``width`` px wide twice, the first time in its own process:
    only camcal's lines on stderr (COLMAP's in the log), and the two rig files equal to 1e-9 relative.

    COLMAP's extraction threads and pycolmap's Ceres threads are the sources of difference this
    guards against (the images' ids in finishing order, sums in finishing order)."""
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(tmp_path / "in", n_frames=5, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    script = (
        "import sys\n"
        "from camcal.pipelines.solve import solve_sfm\n"
        f"solve_sfm({{'left': {str(tmp_path / 'in/left')!r}, 'right': {str(tmp_path / 'in/right')!r}}}, "
        f"{str(tmp_path / 'first')!r}, max_num_features={max_num_features}, "
        "progress=lambda m: print(f'camcal solve: {m}', file=sys.stderr, flush=True))\n"
    )
    first = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    lines = first.stderr.splitlines()
    assert lines and all(line.startswith("camcal solve: ") for line in lines), lines[:5]
    assert not any(GLOG_LINE.match(line) or "Linear solver failure" in line for line in lines)
    log = (tmp_path / "first" / COLMAP_LOG).read_text()
    assert any(GLOG_LINE.match(line) for line in log.splitlines())  # COLMAP's own lines are in the log
    solve_sfm({"left": tmp_path / "in/left", "right": tmp_path / "in/right"}, tmp_path / "second",
              max_num_features=max_num_features)
    a = dict(_numbers(json.loads((tmp_path / "first/solve.rig.json").read_text())))
    b = dict(_numbers(json.loads((tmp_path / "second/solve.rig.json").read_text())))
    assert a[".provenance.seed"] == 0 and set(a) == set(b)
    assert any(".sigma." in key for key in a)  # the jackknife's and the covariance's sigmas are compared too
    differing = {key: (a[key], b[key]) for key in a if a[key] != b[key]}
    for key, (x, y) in differing.items():
        assert isinstance(x, float) and abs(x - y) <= 1e-9 * max(abs(x), abs(y)), (key, x, y)


def test_solve_twice_on_a_small_scene_gives_the_same_rig(tmp_path):
    _solve_twice(tmp_path, width=256, max_num_features=512)


@pytest.mark.slow
def test_solve_twice_gives_the_same_rig_and_only_camcal_writes_to_stderr(tmp_path):
    _solve_twice(tmp_path, width=640, max_num_features=2048)


@pytest.mark.slow
def test_solve_twice_on_real_stereo_pairs_gives_the_same_rig(tmp_path, shared_data):
    """Six of OpenCV's real stereo pairs (a chessboard on a desk, 640x480): the two rig files equal to 1e-9,
    and a default ``camcal solve`` on them (its own process) writes only camcal's lines to stderr."""
    folder = shared_data / "stereo_chessboard"
    folders = {name: [folder / f"{name}{index:02d}.jpg" for index in range(1, 7)] for name in ("left", "right")}
    for name, paths in folders.items():
        (tmp_path / "in" / name).mkdir(parents=True)
        for path in paths:
            (tmp_path / "in" / name / path.name).symlink_to(path)
    first = subprocess.run([sys.executable, "-m", "camcal", "solve", str(tmp_path / "in/left"), str(tmp_path / "in/right"),
                            "--out", str(tmp_path / "first")], capture_output=True, text=True, check=True)
    lines = first.stderr.splitlines()
    assert lines and all(line.startswith("camcal solve: ") for line in lines), lines[:5]
    assert any(GLOG_LINE.match(line) for line in (tmp_path / "first" / COLMAP_LOG).read_text().splitlines())
    solve_sfm({name: tmp_path / "in" / name for name in folders}, tmp_path / "second")
    a = dict(_numbers(json.loads((tmp_path / "first/solve.rig.json").read_text())))
    b = dict(_numbers(json.loads((tmp_path / "second/solve.rig.json").read_text())))
    assert set(a) == set(b) and any(".sigma." in key for key in a)
    for key in a:
        assert a[key] == b[key] or abs(a[key] - b[key]) <= 1e-9 * max(abs(a[key]), abs(b[key])), (key, a[key], b[key])
