"""Board calibration of a fisheye (Kannala-Brandt) lens: synthetic truth, cv2.fisheye.calibrate as the peer."""

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.cli import main
from camcal.geometry.board import Board, Detection
from camcal.model.distortion import Distortion
from camcal.geometry.zhang import calibrate_board
from camcal.geometry.zhang_starts import corners_in_front, fisheye_flags
from camcal.model.rig import Camera, Rig

BOARD = Board("chessboard", 12, 9, 0.04)
KB = ("k1", "k2", "k3", "k4")
#: about 180 degrees across the diagonal of a 1280 x 960 frame
TRUTH = Camera(
    "fish", (1280, 960),
    np.array([[402.0, 0.0, 646.3], [0.0, 400.5, 473.1], [0.0, 0.0, 1.0]]),
    Distortion("kannala-brandt", {"k1": 0.032, "k2": -0.011, "k3": 0.0036, "k4": -0.00052}),
    np.eye(3), np.zeros(3),
)


def board_views(camera, n_views, rng, sigma, max_angle_deg=70.0, max_corner_deg=None):
    """Boards spread over the field of view up to ``max_angle_deg`` off axis, tilted, seen whole.

    With ``max_corner_deg``, only boards whose every corner is within that angle of the axis.
    """
    centred = BOARD.object_points - BOARD.object_points.mean(axis=0)
    detections, poses = [], []
    while len(detections) < n_views:
        theta, phi = np.radians(rng.uniform(0.0, max_angle_deg)), rng.uniform(-np.pi, np.pi)
        direction = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        centre = direction * rng.uniform(0.3, 0.6)
        # face the camera, then tilt and roll
        face = Rotation.align_vectors([[0.0, 0.0, 1.0]], [direction])[0].inv()
        R = (face * Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 2], degrees=True)).as_matrix()
        X = centred @ R.T + centre
        off_axis = np.degrees(np.arccos(X[:, 2] / np.linalg.norm(X, axis=1)))
        if max_corner_deg is not None and off_axis.max() > max_corner_deg:
            continue
        pixels = camera.project(X)
        if not np.all((pixels > 3) & (pixels < np.array(camera.image_size) - 3)):
            continue
        noisy = pixels + rng.normal(0.0, sigma, pixels.shape)
        detections.append(Detection(f"fish_{len(detections):03d}.png", camera.image_size,
                                    np.arange(BOARD.n_corners), noisy, "synthetic"))
        poses.append(X)
    return detections, poses


def frame_error_px(camera, truth, max_angle_deg=180.0):
    """Largest distance between two cameras' projections of the rays of the truth's frame (pixel grid, 16 px)
    up to ``max_angle_deg`` off axis."""
    u, v = np.meshgrid(np.arange(0.0, truth.image_size[0], 16.0), np.arange(0.0, truth.image_size[1], 16.0))
    rays = truth.distortion.rays_from_pixels(np.column_stack([u.ravel(), v.ravel()]), truth.K)
    rays = rays[np.all(np.isfinite(rays), axis=1) & (rays[:, 2] >= np.cos(np.radians(max_angle_deg)))]
    return float(np.nanmax(np.linalg.norm(
        camera.distortion.project_rays(rays, camera.K) - truth.distortion.project_rays(rays, truth.K), axis=1)))


def opencv_fisheye(detections):
    object_points = [BOARD.object_points.reshape(1, -1, 3) for _ in detections]
    image_points = [d.corners_px.reshape(1, -1, 2) for d in detections]
    # OpenCV 4 keeps the fisheye flags in cv2.fisheye, OpenCV 5 in cv2
    flags = fisheye_flags("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW")
    rms, K, D, _, _ = cv2.fisheye.calibrate(object_points, image_points, TRUTH.image_size, None, None, flags=flags,
                                            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    return Camera("cv2", TRUTH.image_size, K, Distortion("kannala-brandt", dict(zip(KB, D.ravel()))), np.eye(3), np.zeros(3))


@pytest.mark.parametrize("sigma", [0.1, 0.3])
def test_recovers_kannala_brandt_to_the_noise_floor(sigma):
    rng = np.random.default_rng(11)
    detections, _ = board_views(TRUTH, 20, rng, sigma)
    result = calibrate_board(BOARD, {"fish": detections}, model="kannala-brandt")
    camera = result.rig.cameras[0]
    sig = camera.quality["sigma"]
    errors = {k: camera.distortion.params[k] - TRUTH.distortion.params[k] for k in KB}
    # each coefficient within 4 sigma of the truth, sigma from the covariance (sampling noise)
    for k in KB:
        assert abs(errors[k]) < 4.0 * sig[k], (k, errors[k], sig[k])
    assert abs(camera.K[0, 0] - TRUTH.K[0, 0]) < 4.0 * sig["fx"]
    assert np.all(np.abs(camera.K[:2, 2] - TRUTH.K[:2, 2]) < 4.0 * np.array([sig["cx"], sig["cy"]]))
    # and the sigmas scale with the noise: the noise floor, not a model error
    assert sig["k1"] < 0.05 * sigma
    # residuals at the noise floor: sqrt(2) sigma less the fitted degrees of freedom
    assert result.rms_px == pytest.approx(math.sqrt(2) * sigma, rel=0.1)
    # held out: the projection of every ray of the frame within the angle the boards covered (most rays
    # far from any board corner); beyond it the polynomial extrapolates (printed, not asserted)
    covered = np.degrees(np.arccos(np.min([TRUTH.distortion.rays_from_pixels(d.corners_px, TRUTH.K)[:, 2]
                                            for d in detections])))
    peer = opencv_fisheye(detections)
    ours, theirs = frame_error_px(camera, TRUTH, covered), frame_error_px(peer, TRUTH, covered)
    print(f"sigma {sigma} px: boards up to {covered:.1f} deg; frame error there ours {ours:.4f} px, "
          f"cv2.fisheye.calibrate {theirs:.4f} px; whole frame ours {frame_error_px(camera, TRUTH):.3f} px, "
          f"cv2 {frame_error_px(peer, TRUTH):.3f} px; "
          + ", ".join(f"{k} err {errors[k]:+.2e} (sigma {sig[k]:.2e}, cv2 err "
                      f"{peer.distortion.params[k] - TRUTH.distortion.params[k]:+.2e})" for k in KB))
    assert ours < 3.0 * sigma
    assert ours <= theirs * 1.05


def test_cli_calibrates_a_fisheye(tmp_path, capsys, monkeypatch):
    """``camcal calibrate board --model kannala-brandt``: the verb accepts the model and writes a fisheye rig."""
    # every corner below 80 degrees off axis: OpenCV's start converges for every view and no corner is left out,
    # on every machine (with a corner past 90 degrees, the start of that view runs off to infinity, in front of
    # or behind the camera by the last bits; the leaving out itself is tested on given poses below)
    detections, _ = board_views(TRUTH, 12, np.random.default_rng(12), 0.1, max_corner_deg=80.0)
    for d in detections:
        (tmp_path / d.image).write_bytes(b"")

    def fake_detect(board, paths, progress=None, **options):
        from camcal.geometry.board import DetectionReport

        return DetectionReport(tuple(detections), ())

    monkeypatch.setattr("camcal.pipelines.board.detect_in_images", fake_detect)
    out = tmp_path / "fish.rig.json"
    code = main(["calibrate", "board", "--board", BOARD.spec(), "--images", f"fish={tmp_path / 'fish_*.png'}",
                 "--model", "kannala-brandt", "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed
    assert "beyond 90 degrees" not in printed.out
    camera = Rig.load(out).cameras[0]
    assert camera.distortion.model == "kannala-brandt"
    assert frame_error_px(camera, TRUTH, 70.0) < 1.0


def test_corners_beyond_89_degrees_at_the_start_pose_are_left_out():
    """The decision itself, on given poses: view 1 of this scene reaches 91.5 degrees at one corner, the rest are
    below 80; that one corner is left out, the view is kept with the others, and the count says so."""
    detections, poses = board_views(TRUTH, 12, np.random.default_rng(12), 0.1)
    angles = [np.degrees(np.arccos(X[:, 2] / np.linalg.norm(X, axis=1))) for X in poses]
    assert np.sum(angles[1] > 89.0) == 1 and angles[1].max() > 91.0
    assert all(a.max() < 80.0 for i, a in enumerate(angles) if i != 1)
    centred = BOARD.object_points - BOARD.object_points.mean(axis=0)
    starts = {}
    for f, X in enumerate(poses):  # the true cam_from_board of each view, given as the start
        R = Rotation.align_vectors(X - X.mean(axis=0), centred)[0].as_matrix()
        starts[f] = (R, X.mean(axis=0) - BOARD.object_points.mean(axis=0) @ R.T)
        assert np.allclose(BOARD.object_points @ R.T + starts[f][1], X)
    kept, n_left_out = corners_in_front(BOARD, [dict(enumerate(detections))], [starts])
    assert n_left_out == 1
    assert sorted(kept[0]) == list(range(12))
    assert len(kept[0][1].ids) == BOARD.n_corners - 1
    assert np.argmax(angles[1]) not in kept[0][1].ids


def test_held_out_fisheye_views_at_the_noise_floor():
    """Views held out of the fit (posed by PnP, intrinsics held): RMS ~ sqrt(2) sigma, as in training."""
    detections, poses = board_views(TRUTH, 14, np.random.default_rng(12), 0.2)
    # view 1 reaches 91.5 degrees off axis: its corners behind the image plane are left out of its PnP
    assert np.min(poses[1][:, 2]) < 0
    result = calibrate_board(BOARD, {"fish": detections}, model="kannala-brandt", holdout={1, 5, 9})
    print(f"fisheye held-out RMS {result.heldout_rms_px:.3f} px, training {result.rms_px:.3f} px")
    assert result.rms_px == pytest.approx(math.sqrt(2) * 0.2, rel=0.1)
    assert result.heldout_rms_px == pytest.approx(math.sqrt(2) * 0.2, rel=0.2)


@pytest.mark.slow
def test_kannala_brandt_sigmas_cover_the_error():
    """Over 20 seeded scenes, |error| < 2 sigma for k1..k4, fx and the principal point in >= 85 % of cases."""
    inside = []
    for seed in range(20):
        detections, _ = board_views(TRUTH, 15, np.random.default_rng(100 + seed), 0.2)
        camera = calibrate_board(BOARD, {"fish": detections}, model="kannala-brandt").rig.cameras[0]
        sig = camera.quality["sigma"]
        for k in KB:
            inside.append(abs(camera.distortion.params[k] - TRUTH.distortion.params[k]) < 2.0 * sig[k])
        inside.append(abs(camera.K[0, 0] - TRUTH.K[0, 0]) < 2.0 * sig["fx"])
        inside.append(abs(camera.K[0, 2] - TRUTH.K[0, 2]) < 2.0 * sig["cx"])
        inside.append(abs(camera.K[1, 2] - TRUTH.K[1, 2]) < 2.0 * sig["cy"])
    print(f"within 2 sigma: {np.mean(inside):.1%} of {len(inside)}")
    assert np.mean(inside) >= 0.85


def test_fisheye_stereo_rig_against_truth():
    """Two fisheye cameras 0.12 m apart, turned 10 degrees: the joint refinement recovers the rig."""
    right = Camera(
        "right", (1280, 960),
        np.array([[398.0, 0.0, 634.8], [0.0, 397.1, 481.9], [0.0, 0.0, 1.0]]),
        Distortion("kannala-brandt", {"k1": 0.028, "k2": -0.009, "k3": 0.0031, "k4": -0.00047}),
        Rotation.from_euler("xyz", [1.0, -10.0, 0.5], degrees=True).as_matrix(), np.array([0.12, 0.004, -0.002]),
    )
    left = Camera("left", TRUTH.image_size, TRUTH.K, TRUTH.distortion, np.eye(3), np.zeros(3))
    rng = np.random.default_rng(21)
    detections = {"left": [], "right": []}
    centred = BOARD.object_points - BOARD.object_points.mean(axis=0)
    view = 0
    while view < 16:
        theta, phi = np.radians(rng.uniform(0.0, 60.0)), rng.uniform(-np.pi, np.pi)
        direction = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        face = Rotation.align_vectors([[0.0, 0.0, 1.0]], [direction])[0].inv()
        R = (face * Rotation.from_euler("xyz", rng.uniform(-30, 30, 3), degrees=True)).as_matrix()
        X = centred @ R.T + direction * rng.uniform(0.35, 0.6)
        pixels = [camera.project(X) for camera in (left, right)]
        if not all(np.all((p > 3) & (p < np.array(TRUTH.image_size) - 3)) for p in pixels):
            continue
        for camera, p in zip((left, right), pixels):
            detections[camera.name].append(Detection(f"{camera.name}_{view:03d}.png", camera.image_size,
                                                     np.arange(BOARD.n_corners), p + rng.normal(0, 0.1, p.shape),
                                                     "synthetic"))
        view += 1
    result = calibrate_board(BOARD, detections, model="kannala-brandt")
    got = result.rig.cameras[1]
    angle = np.degrees(Rotation.from_matrix(got.R @ right.R.T).magnitude())
    print(f"fisheye stereo: rotation error {angle:.4f} deg, baseline error "
          f"{abs(np.linalg.norm(got.c) - np.linalg.norm(right.c)) * 1e3:.3f} mm, RMS {result.rms_px:.3f} px")
    assert angle < 0.05
    assert abs(np.linalg.norm(got.c) / np.linalg.norm(right.c) - 1) < 0.005
    assert frame_error_px(got, right, 60.0) < 0.5
    assert result.rms_px == pytest.approx(math.sqrt(2) * 0.1, rel=0.1)
