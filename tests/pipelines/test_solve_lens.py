"""``solve --intrinsics``: the lens of a grid calibration, held or refined under its sigmas, on a rendered plate."""

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.geometry.board import Detection
from camcal.geometry.zhang import calibrate_board
from camcal.model.camera import chordal_mean_rotation, rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from camcal.model.rig_frames import Frame, Lens
from camcal.pipelines.solve import solve_sfm
from camcal.pipelines.solve_lens import grid_lens, scaled_camera
from camcal.synthetic import render_stereo_sequence
from tests.geometry.test_uncertainty import BOARD

WIDTH, HEIGHT = 256, 192
FOCAL = 500.0 * WIDTH / 640


def _plate(tmp_path, n_frames):
    """A rendered plate (the left camera of the rendered stereo sequence, 256 x 192, polynomial lens): its truth."""
    truth = render_stereo_sequence(tmp_path / "in", n_frames=n_frames, image_size=(WIDTH, HEIGHT),
                                   K=((FOCAL, 0.0, (WIDTH - 1) / 2), (0.0, FOCAL, (HEIGHT - 1) / 2), (0.0, 0.0, 1.0)))
    return [truth["left", k] for k in range(n_frames)]


def _grid_calibration(camera: Camera, size, seed=0, n_views=12, noise_px=0.15) -> Rig:
    """What ``calibrate board`` gives for ``camera``'s lens at ``size`` (same aspect): a board seen in
    ``n_views`` poses, its corners with Gaussian noise, the polynomial model fitted."""
    lens, _ = scaled_camera(dataclasses.replace(camera, R=np.eye(3), c=np.zeros(3)), size)
    rng = np.random.default_rng(seed)
    centred, views = BOARD.object_points.mean(axis=0), []
    while len(views) < n_views:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.5], degrees=True).as_matrix()
        depth = rng.uniform(0.35, 0.6)
        t = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), 1.0]) * depth - R @ centred
        q = lens.project(BOARD.object_points @ R.T + t)
        if np.all((q > 5) & (q < np.array(size) - 5)):
            views.append(Detection(f"grid_{len(views):03d}.png", size, np.arange(BOARD.n_corners),
                                   q + rng.normal(0.0, noise_px, q.shape), ""))
    return calibrate_board(BOARD, {"cam": views}, model="polynomial").rig


def _pose_errors(rig: Rig, truth: list[Camera]) -> tuple[float, float]:
    """RMS camera-centre error (m) and RMS rotation error (deg) over the frames after a similarity alignment:
    its rotation the chordal mean of the frames' ``R_true^T R`` (the centres of a short plate lie near a line,
    which leaves a rotation fitted to them alone free about it), then scale and shift by least squares."""
    solved = {frame.index: rig.camera_at_frame("left", frame.index) for frame in rig.frames}
    keys = sorted(solved)
    Q = chordal_mean_rotation([truth[k].R.T @ solved[k].R for k in keys])
    turned = np.array([Q @ solved[k].c for k in keys])
    target = np.array([truth[k].c for k in keys])
    d, e = turned - turned.mean(axis=0), target - target.mean(axis=0)
    s = float(np.sum(d * e) / np.sum(d * d))
    centres = float(np.sqrt(np.mean(np.sum((s * d - e) ** 2, axis=1))))
    rotations = float(np.sqrt(np.mean([rotation_angle_deg(truth[k].R @ (solved[k].R @ Q.T).T) ** 2 for k in keys])))
    return centres, rotations


def test_a_lens_at_another_size_of_the_same_aspect_projects_where_the_scaled_image_would():
    """u' = s (u + 0.5) - 0.5 for every point, polynomial and division lenses (the latter's lambda in px^-2)."""
    K = np.array([[800.0, 0.0, 515.3], [0.0, 805.0, 380.7], [0.0, 0.0, 1.0]])
    X = np.random.default_rng(0).uniform([-1, -0.7, 2], [1, 0.7, 4], (50, 3))
    for lens in (Distortion("polynomial", {"k1": -0.12, "k2": 0.03}),
                 Distortion("division", {"lambda": -2e-7}, center=(520.0, 377.0))):
        camera = Camera("cam", (1024, 768), K, lens, np.eye(3), np.zeros(3))
        assert scaled_camera(camera, (1024, 768)) == (camera, 1.0)
        for size, s in (((512, 384), 0.5), ((1536, 1152), 1.5)):
            scaled, factor = scaled_camera(camera, size)
            assert factor == s and scaled.image_size == size
            np.testing.assert_allclose(scaled.project(X), s * (camera.project(X) + 0.5) - 0.5, atol=1e-9)


@pytest.mark.parametrize("size", [(1024, 576), (1000, 768), (1023, 767)])
def test_a_plate_of_another_aspect_is_one_error_naming_both_sizes(size):
    camera = Camera("cam", (1024, 768), np.array([[800.0, 0, 511.5], [0, 800, 383.5], [0, 0, 1]]),
                    Distortion("polynomial", {"k1": -0.1, "k2": 0.0}), np.eye(3), np.zeros(3))
    with pytest.raises(CamcalError, match=rf"the plate is {size[0]}x{size[1]} but the grid's lens was calibrated at "
                                          r"1024x768: another aspect"):
        grid_lens(Rig((camera,)), {"plate": size})


def test_a_prior_needs_the_grid_s_sigmas_and_a_camera_it_has():
    camera = Camera("cam", (256, 192), np.array([[200.0, 0, 127.5], [0, 200, 95.5], [0, 0, 1]]),
                    Distortion("polynomial", {"k1": -0.1, "k2": 0.0}), np.eye(3), np.zeros(3))
    with pytest.raises(CamcalError, match="has no sigmas"):
        grid_lens(Rig((camera,)), {"plate": (256, 192)}, "prior")
    with pytest.raises(CamcalError, match="has no camera named 'right'"):
        grid_lens(Rig((camera, dataclasses.replace(camera, name="other", c=np.array([0.1, 0, 0])))),
                  {"cam": (256, 192), "right": (256, 192)})
    lens = grid_lens(Rig((camera,)), {"plate": (128, 96)})  # one camera each: the one, at half size, said
    assert lens.cameras["plate"].K[0, 0] == 100.0 and "K scaled x0.5 from its 256x192 to the plate's 128x96" in lens.lines[0]


def _zoom_rig(camera: Camera, frames) -> Rig:
    """``camera`` on a zoom: at each frame of ``frames`` a lens of its own (fx 5 % longer per frame, focal_mm with it)."""
    lenses = {}
    for k, index in enumerate(frames):
        K = camera.K.copy()
        K[0, 0] *= 1.05 ** k
        K[1, 1] *= 1.05 ** k
        lenses[index] = Lens(K, camera.distortion, focal_mm=24.0 * 1.05 ** k)
    rig = Rig((camera,), frames=tuple(Frame(index, np.eye(3), np.zeros(3)) for index in frames))
    return rig.with_camera(camera, lenses)


def test_solve_with_a_lens_per_frame_missing_plate_frames_writes_nothing(tmp_path, capsys):
    _plate(tmp_path, 2)  # left/0000.png, left/0001.png
    camera = Camera("cam", (WIDTH, HEIGHT), np.array([[FOCAL, 0, 127.5], [0, FOCAL, 95.5], [0, 0, 1]]),
                    Distortion.none(), np.eye(3), np.zeros(3))
    _zoom_rig(camera, [1, 2, 3]).save(tmp_path / "shot.rig.json")
    code = main(["solve", str(tmp_path / "in" / "left"), "--intrinsics", str(tmp_path / "shot.rig.json"),
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "shot.rig.json has no lens of camera 'cam' for plate frames 0 (it has frames 1-3)" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_solve_with_a_plate_the_grid_does_not_fit_writes_nothing(tmp_path, capsys):
    _plate(tmp_path, 2)
    grid = Camera("cam", (320, 200), np.array([[250.0, 0, 159.5], [0, 250, 99.5], [0, 0, 1]]), Distortion.none(),
                  np.eye(3), np.zeros(3))
    Rig((grid,)).save(tmp_path / "grid.rig.json")
    code = main(["solve", str(tmp_path / "in" / "left"), "--intrinsics", str(tmp_path / "grid.rig.json"),
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "the plate is 256x192 but the grid's lens was calibrated at 320x200" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_the_grid_lens_held_is_the_rig_s_lens_and_as_a_prior_stays_within_3_sigma(tmp_path):
    """A grid calibrated at twice the plate's size (K scaled on the way): held, the rig's camera is exactly the
    scaled grid lens; as a prior, no intrinsic moves from it by more than 3 of the grid's sigmas."""
    truth = _plate(tmp_path, 4)
    grid = _grid_calibration(truth[0], (2 * WIDTH, 2 * HEIGHT))
    held = solve_sfm({"left": tmp_path / "in" / "left"}, tmp_path / "held", max_num_features=512, intrinsics=grid)
    expected, _ = scaled_camera(grid.cameras[0], (WIDTH, HEIGHT))
    camera = held.rig.camera("left")
    assert np.array_equal(camera.K, expected.K) and camera.distortion == expected.distortion
    assert held.n_registered == 4 and held.rms_px < 0.3
    assert any("K scaled x0.5 from its 512x384 to the plate's 256x192" in note for note in held.notes)
    saved = json.loads((tmp_path / "held" / "solve.rig.json").read_text())
    assert saved["cameras"][0]["distortion"]["model"] == "polynomial"
    prior = solve_sfm({"left": tmp_path / "in" / "left"}, tmp_path / "prior", max_num_features=512, intrinsics=grid,
                      intrinsics_mode="prior")
    sigma = {key: value * (0.5 if key in ("fx", "fy", "cx", "cy") else 1.0)
             for key, value in grid.cameras[0].quality["sigma"].items()}  # at the plate's half size
    refined = prior.rig.camera("left")
    moves = {"fx": refined.K[0, 0] - expected.K[0, 0], "fy": refined.K[1, 1] - expected.K[1, 1],
             "cx": refined.K[0, 2] - expected.K[0, 2], "cy": refined.K[1, 2] - expected.K[1, 2],
             "k1": refined.distortion.params["k1"] - expected.distortion.params["k1"],
             "k2": refined.distortion.params["k2"] - expected.distortion.params["k2"]}
    assert any(abs(move) > 0 for move in moves.values())  # refined, not held
    for key, move in moves.items():
        assert abs(move) <= 3.0 * sigma[key], (key, move, sigma[key])
    assert any("the lens moved from the grid's by at most" in note for note in prior.notes)


@pytest.mark.slow
def test_the_lens_from_a_grid_calibration_is_no_worse_than_the_true_lens_held(tmp_path):
    """Camera centres and rotations over a 7-frame plate with the lens of a grid calibration (held, and as a prior)
    against the same with the true lens held: within the noise of so short a plate (twice, plus 1 mm and 0.02 deg;
    measured: centres 1.8, 1.9 and 3.0 mm RMS over a 3 m path, rotations 0.039, 0.033, 0.048 deg)."""
    truth = _plate(tmp_path, 7)
    true_lens = Rig((dataclasses.replace(truth[0], name="cam", R=np.eye(3), c=np.zeros(3)),))
    grid = _grid_calibration(truth[0], (WIDTH, HEIGHT), seed=1)
    errors = {}
    for label, intrinsics, mode in (("true", true_lens, "fixed"), ("grid", grid, "fixed"), ("prior", grid, "prior")):
        result = solve_sfm({"left": tmp_path / "in" / "left"}, tmp_path / label, max_num_features=1024,
                           intrinsics=intrinsics, intrinsics_mode=mode)
        assert result.n_registered == 7
        errors[label] = _pose_errors(result.rig, truth)
    for label in ("grid", "prior"):
        assert errors[label][0] <= 2.0 * errors["true"][0] + 1e-3, errors
        assert errors[label][1] <= 2.0 * errors["true"][1] + 0.02, errors


def test_rolling_shutter_displacements_in_the_rig_are_those_of_the_true_cameras(tmp_path):
    """``solve`` with a readout time: each frame's stored displacement is the one the true cameras give to the
    points the frame observes (the solve's points moved into the truth's world by the cameras' similarity), at
    the frame rate given; frames above the threshold are those flagged and named."""
    import pycolmap

    from camcal.geometry.rolling_shutter import rolling_shutter_frames
    from camcal.pipelines.solve_shutter import ShutterSpec

    truth = _plate(tmp_path, 4)
    lens = Rig(cameras=(dataclasses.replace(truth[0], name="cam", R=np.eye(3), c=np.zeros(3)),))
    result = solve_sfm({"left": tmp_path / "in" / "left"}, tmp_path / "out", max_num_features=512, intrinsics=lens,
                       rolling_shutter=ShutterSpec(readout_ms=400.0, threshold_px=5.1, fps=2.0))
    rig = result.rig
    solved = [rig.camera_at_frame("left", frame.index) for frame in rig.frames]
    Q = chordal_mean_rotation([t.R.T @ s.R for t, s in zip(truth, solved)])
    turned, target = np.array([Q @ s.c for s in solved]), np.array([t.c for t in truth])
    d, e = turned - turned.mean(axis=0), target - target.mean(axis=0)
    scale = float(np.sum(d * e) / np.sum(d * d))
    model = pycolmap.Reconstruction(result.reconstruction_dir)
    points = []
    for frame in rig.frames:
        image = model.find_image_with_name(f"left/{frame.index:06d}.png")
        xyz = np.array([model.points3D[p.point3D_id].xyz for p in image.points2D if p.has_point3D()])
        points.append(scale * (xyz @ Q.T - turned.mean(axis=0)) + target.mean(axis=0))
    expected = rolling_shutter_frames(truth[0].K, HEIGHT, [t.R for t in truth], [t.c for t in truth],
                                      np.arange(4) / 2.0, points, readout_s=0.4, threshold_px=5.1)
    stored = [frame.rolling_shutter["left"] for frame in rig.frames]
    for check, peer in zip(stored, expected):
        assert check.displacement_px == pytest.approx(peer.displacement_px, rel=0.02)
        assert check.flagged == (check.displacement_px > 5.1)
    flagged = [frame.index for frame, check in zip(rig.frames, stored) if check.flagged]
    assert 0 < len(flagged) < 4  # the threshold parts the frames (4.7-5.4 px)
    assert any(note.startswith("rolling shutter (readout 400 ms at 2 fps, threshold 5.1 px): flagged left frames "
                               f"{', '.join(map(str, flagged))} ({len(flagged)}); largest ") for note in result.notes)
    assert json.loads((tmp_path / "out" / "solve.rig.json").read_text())["provenance"]["rolling_shutter"] == {
        "readout_ms": 400.0, "fps": 2.0, "threshold_px": 5.1}
