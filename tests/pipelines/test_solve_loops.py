"""Loop closure of ``solve --matcher sequential``: a rendered shot that comes back to its start drifts less with it."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.model.camera import look_at, similarity_Umeyama1991
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from camcal.pipelines.solve import solve_sfm
from camcal.pipelines.solve_loops import keyframe_times
from camcal.synthetic import orbit_set_planes, procedural_texture, render_rig_poses

WIDTH, HEIGHT, FOCAL = 384, 216, 300.0


def _orbit_plate(root, n_frames):
    """A camera circling the set once (radius 2.8 m, looking at its boxes, rising and falling 0.3 m), its last frame
    one step before its first: grey noise of 6 levels on every frame. The true centres and rotations."""
    rng = np.random.default_rng(0)
    planes = orbit_set_planes(rng)
    textures = tuple(procedural_texture(rng) for _ in planes)
    centre = np.array([4.0, 4.0, 0.8])
    poses = []
    for i in range(n_frames):
        angle = 2 * np.pi * i / n_frames
        position = centre + [2.8 * np.cos(angle), 2.8 * np.sin(angle), 0.9 + 0.3 * np.sin(2 * angle)]
        poses.append((look_at(position, centre + [0.3 * np.sin(3 * angle), 0.3 * np.cos(2 * angle), 0.0]), position))
    camera = Camera("plate", (WIDTH, HEIGHT), np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2],
                                                        [0, 0, 1.0]]),
                    Distortion("polynomial", {"k1": -0.05, "k2": 0.0}), np.eye(3), np.zeros(3))
    render_rig_poses(root, (camera,), poses, planes, textures, 6.0, rng)
    return np.array([c for _, c in poses]), np.array([R for R, _ in poses])


def _loop_drift(result, centres, rotations):
    """After a similarity fit of every solved centre to the truth: how far the last frame's position relative to the
    first is from the truth's, in % of the path, and the same for its rotation, in degrees."""
    frames = sorted(result.rig.frames, key=lambda frame: frame.index)
    assert [frame.index for frame in frames] == list(range(len(centres)))
    solved = np.array([frame.c for frame in frames])
    s, R, t = similarity_Umeyama1991(solved, centres)
    aligned = s * solved @ R.T + t
    path = np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()
    position = np.linalg.norm((aligned[-1] - aligned[0]) - (centres[-1] - centres[0])) / path * 100
    relative = (frames[-1].R @ frames[0].R.T).T @ (rotations[-1] @ rotations[0].T)
    return position, np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1.0, 1.0)))


@pytest.mark.slow
def test_a_shot_that_returns_to_its_start_drifts_less_with_loop_closure(tmp_path):
    """60 frames at 384 x 216, 256 features each, matched by frame order (window 10): without loop closure the end
    drifts from the start; with it the revisit is found, verified, and the drift is at most half. The fast siblings
    are the retrieval tests on synthetic descriptors (tests/geometry/test_retrieval.py)."""
    centres, rotations = _orbit_plate(tmp_path / "in", 60)
    drift = {}
    for loops in ("off", "auto"):
        result = solve_sfm({"plate": tmp_path / "in" / "plate"}, tmp_path / loops, matcher="sequential",
                           max_num_features=256, refine=False, loops=loops)
        assert result.n_registered == 60
        drift[loops] = _loop_drift(result, centres, rotations)
        closure = [note for note in result.notes if note.startswith("loop closure:")]
        assert closure == [] if loops == "off" else len(closure) == 1, result.notes
    verified = int(closure[0].split(", ")[-1].split()[0])
    assert verified >= 1, closure
    assert drift["auto"][0] <= 0.5 * drift["off"][0], drift
    assert drift["auto"][1] <= 0.5 * drift["off"][1], drift


def test_keyframes_are_every_step_th_frame_of_each_camera():
    names = [f"{camera}/{k:04d}.png" for camera in ("left", "right") for k in range(7)]
    assert keyframe_times(names, 3) == {f"{camera}/{k:04d}.png": k for camera in ("left", "right") for k in (0, 3, 6)}


def test_loops_without_the_sequential_matcher_is_a_usage_error_and_an_unknown_mode_an_error(tmp_path, capsys):
    assert main(["solve", str(tmp_path), "--loops", "off", "--out", str(tmp_path / "out")]) == 2
    assert "--loops has no effect without --matcher sequential" in capsys.readouterr().err
    with pytest.raises(CamcalError, match="unknown loop closure 'sometimes', expected one of: auto, off"):
        solve_sfm({"plate": tmp_path}, tmp_path / "out", matcher="sequential", loops="sometimes")
    assert not (tmp_path / "out").exists()
