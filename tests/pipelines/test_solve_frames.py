"""``solve`` on a plate, frame by frame: the same cameras twice, frames that cannot be registered named, no parallax."""

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from camcal.pipelines.solve import solve_sfm
from camcal.synthetic import procedural_texture, render_planes, render_stereo_sequence, room_corner_planes

ROOT = Path(__file__).resolve().parents[2]
WIDTH, HEIGHT = 256, 192
FOCAL = 500.0 * WIDTH / 640
K = ((FOCAL, 0.0, (WIDTH - 1) / 2), (0.0, FOCAL, (HEIGHT - 1) / 2), (0.0, 0.0, 1.0))


def _plate(folder, n_frames, blank=()):
    """The rendered plate ``folder/plate.1001.png``...; the frames in ``blank`` flat grey (nothing to match)."""
    render_stereo_sequence(folder.parent / "rendered", n_frames=n_frames, image_size=(WIDTH, HEIGHT), K=K)
    folder.mkdir()
    for k in range(n_frames):
        image = cv2.imread(str(folder.parent / "rendered" / "left" / f"{k:04d}.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(folder / f"plate.{1001 + k}.png"), np.full_like(image, 128) if 1001 + k in blank else image)


def _masked(path):
    """The rig file with its creation time masked."""
    data = json.loads(path.read_text())
    data["provenance"].pop("created")
    return json.dumps(data, sort_keys=True)


def _solve_twice(tmp_path, options):
    """The same plate solved by two processes (Python's string hashing seeded apart, COLMAP's threads scheduled
    apart): the two rig files with their creation time masked, and the two point files."""
    _plate(tmp_path / "plate", 4)
    for out, hash_seed in (("a", "1"), ("b", "2")):
        env = dict(os.environ, PYTHONHASHSEED=hash_seed,
                   PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        subprocess.run([sys.executable, "-m", "camcal", "solve", "plate/plate.%04d.png", "--matcher", "sequential",
                        "--features", "512", *options, "--out", out], cwd=tmp_path, env=env, check=True,
                       capture_output=True)
    return ([_masked(tmp_path / out / "solve.rig.json") for out in "ab"],
            [(tmp_path / out / "points.ply").read_bytes() for out in "ab"])


def test_the_same_plate_and_command_twice_give_the_same_cameras_bit_for_bit(tmp_path):
    """One lens model, the covariance's sigmas: the rig files equal byte for byte once the creation time is
    masked, the points too (the slow sibling runs the default lens choice and jackknife)."""
    rigs, points = _solve_twice(tmp_path, ["--model", "polynomial", "--uncertainty", "covariance"])
    assert rigs[0] == rigs[1] and points[0] == points[1]


@pytest.mark.slow
def test_the_default_solve_twice_gives_the_same_cameras_bit_for_bit(tmp_path):
    """The lens model chosen on held-out points, the delete-one-frame jackknife: still the same bytes."""
    rigs, points = _solve_twice(tmp_path, [])
    assert rigs[0] == rigs[1] and points[0] == points[1]


def test_frames_that_cannot_be_registered_are_named_by_number_and_refused_with_require_all(tmp_path, capsys):
    _plate(tmp_path / "plates", 5, blank=(1003,))
    command = ["solve", str(tmp_path / "plates" / "plate.%04d.png"), "--features", "512", "--no-refine"]
    assert main(command + ["--out", str(tmp_path / "out")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:2] == ["registered 4 / 5 images", "not registered: plate frames 1003 (1 of 5)"]
    assert main(command + ["--require-all", "--out", str(tmp_path / "strict")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("camcal solve: ")]
    assert err == ["camcal: error: not registered: plate frames 1003 (1 of 5) (--require-all)"]
    assert not (tmp_path / "strict").exists()


def test_a_plate_without_parallax_is_one_line_saying_so(tmp_path):
    """A nodal pan (the camera turns about its centre): every pair fits a rotation alone; COLMAP's mapper makes a
    model of it all the same (focal 328 px for 200), camcal says why it cannot be solved and writes nothing."""
    rng = np.random.default_rng(0)
    planes = room_corner_planes()
    textures = tuple(procedural_texture(rng) for _ in planes)
    (tmp_path / "pan").mkdir()
    centre = np.array([5.5, 4.0, 1.6])
    for k in range(4):
        target = centre + [np.cos(3.6 + 0.08 * k), np.sin(3.6 + 0.08 * k), -0.15]
        camera = Camera("pan", (WIDTH, HEIGHT), np.array(K), Distortion.none(), look_at(centre, target), centre)
        cv2.imwrite(str(tmp_path / "pan" / f"pan.{1001 + k}.png"), render_planes(camera, planes, textures))
    with pytest.raises(CamcalError, match=r"too little parallax in the 4 images: the camera turns"):
        solve_sfm({"pan": tmp_path / "pan"}, tmp_path / "out", max_num_features=512, refine=False)
    assert not (tmp_path / "out").exists()
