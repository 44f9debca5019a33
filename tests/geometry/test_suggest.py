"""Capture guidance: the suggested next board view against a random one of the same board."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import detect_board
from camcal.geometry.suggest import expected_worst_sigma, pose_views, suggest_views
from camcal.geometry.zhang import calibrate_board
from tests.geometry.test_uncertainty import BOARD, board_texture, posed, render_view, rendered_scene


def random_pose(camera, rng):
    """A board pose drawn as :func:`rendered_scene` draws its views (all corners inside the frame)."""
    centred = BOARD.object_points.mean(axis=0)
    while True:
        R = Rotation.from_euler("xyz", rng.uniform(-40, 40, 3) * [1, 1, 0.5], degrees=True).as_matrix()
        depth = rng.uniform(0.35, 0.6)
        t = np.array([rng.uniform(-0.35, 0.35), rng.uniform(-0.25, 0.25), 1.0]) * depth - R @ centred
        q = camera.distortion.project_rays(BOARD.object_points @ R.T + t, camera.K)
        if np.all((q > 12) & (q < np.array(camera.image_size) - 12)):
            return R, t


def scene(seed, n_views=8):
    truth, detections, poses = rendered_scene(seed, n_views, rendered=False)
    camera = calibrate_board(BOARD, {"cam": detections}, model="division").rig.cameras[0]
    return camera, [posed(camera, d, R, t) for d, (R, t) in zip(detections, poses)]


@pytest.mark.parametrize("n_scenes", [pytest.param(20, marks=pytest.mark.slow), 5])
def test_suggested_view_beats_a_random_one(n_scenes):
    """Must-show: over 20 seeded scenes of 8 views (synthetic corners, 0.1 px noise), the suggested view lowers
    the expected worst projection sigma more than a random extra view of the same board in >= 80 % of them
    (the fast run: the first 5 scenes, the same rule)."""
    wins, gains = 0, []
    for seed in range(200, 200 + n_scenes):
        camera, poses = scene(seed)
        rng = np.random.default_rng(seed)
        suggested = suggest_views(camera, BOARD.object_points, poses)[0]
        now = camera.quality["worst_projection_sigma_px"]
        random = expected_worst_sigma(camera, BOARD.object_points, poses, [random_pose(camera, rng)])
        assert suggested.worst_sigma_px == pytest.approx(
            expected_worst_sigma(camera, BOARD.object_points, poses, [(suggested.R, suggested.t)]), rel=1e-9)
        wins += suggested.worst_sigma_px < random
        gains.append(((now - suggested.worst_sigma_px) / now, (now - random) / now))
    gains = np.array(gains)
    print(f"suggested beats random in {wins}/{n_scenes} scenes; worst sigma lowered by {100 * np.median(gains[:, 0]):.0f} % "
          f"(suggested) vs {100 * np.median(gains[:, 1]):.0f} % (random), medians")
    assert wins >= 0.8 * n_scenes


def test_shot_list_lowers_the_sigma_step_by_step():
    camera, poses = scene(230)
    shots = suggest_views(camera, BOARD.object_points, poses, n=3)
    sigmas = [camera.quality["worst_projection_sigma_px"]] + [shot.worst_sigma_px for shot in shots]
    assert np.all(np.diff(sigmas) < 0)
    width, height = camera.image_size
    for shot in shots:
        assert np.all((shot.corners_px > 0) & (shot.corners_px < [width - 1, height - 1]))
        assert "worst sigma" in shot.describe()


def test_no_covariance_is_one_line():
    camera, poses = scene(231)
    bare = camera.__class__(camera.name, camera.image_size, camera.K, camera.distortion, camera.R, camera.c)
    with pytest.raises(CamcalError, match="worst projection sigma"):
        suggest_views(bare, BOARD.object_points, poses)


def _recalibrated_worst(truth, detections, R, t, rng, texture):
    """Render the board at ``(R, t)`` through the true camera, detect it, add it and recalibrate: the new
    detections and the recalibrated camera's worst projection sigma (None when the board is not found whole)."""
    image = render_view(truth, R, t, rng, texture)
    found = detect_board(BOARD, image, f"cam_{len(detections):03d}.png")
    if found is None or len(found.ids) != BOARD.n_corners:
        return detections, None
    detections = detections + [found]
    camera = calibrate_board(BOARD, {"cam": detections}, model="division").rig.cameras[0]
    return detections, camera


def images_to_target(seed, n_start=5, n_suggested=5, max_random=15, size=(320, 240)):
    """One rendered scene: from ``n_start`` views, five suggested views one at a time (each from the current
    recalibration), then from the same start random views until their recalibrated worst sigma reaches the
    suggested list's. Returns (suggested images, random images needed, or max_random + 1 when not reached)."""
    truth, detections, _ = rendered_scene(seed, n_start, size)
    texture = board_texture()
    rng = np.random.default_rng(7000 + seed)
    camera = calibrate_board(BOARD, {"cam": detections}, model="division").rig.cameras[0]
    start, suggested = list(detections), 0
    while suggested < n_suggested:
        shot = suggest_views(camera, BOARD.object_points, pose_views(camera, BOARD.object_points, detections))[0]
        # the suggestion is in the estimated camera's frame: render it through the truth (what a user would shoot)
        detections, found = _recalibrated_worst(truth, detections, shot.R, shot.t, rng, texture)
        if found is None:
            break
        camera, suggested = found, suggested + 1
    target = camera.quality["worst_projection_sigma_px"]
    detections, n_random = start, 0
    while n_random <= max_random:
        R, t = random_pose(truth, rng)
        detections, found = _recalibrated_worst(truth, detections, R, t, rng, texture)
        if found is None:
            continue
        n_random += 1
        if found.quality["worst_projection_sigma_px"] <= target:
            return suggested, n_random, target
    return suggested, max_random + 1, target


@pytest.mark.slow
def test_five_suggested_views_reach_a_target_with_fewer_images_than_random():
    """Must-show, with recalibrations on rendered corners: the worst sigma five suggested views reach (each one
    rendered, detected and recalibrated in turn) needs more random views of the same board, in >= 80 % of 10
    seeded scenes, and in total.

    Measured (320x240, 5 start views): seeds 300-309 fewer in 9/10 (5 vs 5, 11, 6, 12, 15 and five not reached
    in 15, counted 16; 50 vs 129 images in all). Developed on seeds 400-409: 10/10, 50 vs 133; held out 500-509: 10/10,
    50 vs 129. Before the candidates were turned in their plane (:data:`camcal.geometry.suggest.ROLL_DEG`):
    5/10 on seeds 300-309, the design effect 1 -> 3.8 after one suggested view of seed 300."""
    rows = [images_to_target(seed) for seed in range(300, 310)]
    for seed, (suggested, random, target) in zip(range(300, 310), rows):
        print(f"seed {seed}: target worst sigma {target:.3f} px reached by {suggested} suggested, "
              f"{random if random <= 15 else '> 15'} random images")
    suggested, random = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    print(f"images to the target: suggested {suggested.sum()} in all, random {random.sum()} in all "
          f"(median {np.median(suggested):.0f} vs {np.median(random):.0f}); fewer in {np.sum(suggested < random)}/10")
    assert np.sum(suggested < random) >= 8 and suggested.sum() < random.sum()
