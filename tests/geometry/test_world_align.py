"""The world of a reconstruction from constraints: a known similarity removed is recovered exactly."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import parse_board
from camcal.geometry.world_align import (Similarity, ground_plane_RANSAC, mean_camera_up, plane_normal_covariance,
                                         point_under, triangulate_corners, world_from_board, world_from_constraints)
from camcal.model.camera import look_at


def _set(rng):
    """The set's truth: 300 points on the ground z = 0, 120 on two boxes, 5 cameras 1.6 above the ground; the
    first stands over the origin looking down +y."""
    ground = np.column_stack([rng.uniform(-4, 4, (300, 2)), np.zeros(300)])
    boxes = np.concatenate([rng.uniform([1, 2, 0.1], [2, 3, 1.0], (60, 3)), rng.uniform([-2, 3, 0.2], [-1, 4, 0.8], (60, 3))])
    centres = [np.array([0.0, 0.0, 1.6])] + [np.array([x, -1.0, 1.5 + 0.1 * x]) for x in (-2.0, -1.0, 1.0, 2.0)]
    rotations = [look_at(centres[0], [0.0, 5.0, 0.4])] + [look_at(c, [0.0, 3.0, 0.5]) for c in centres[1:]]
    return np.concatenate([ground, boxes]), np.array(centres), np.array(rotations)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_known_similarity_removed_is_recovered_exactly_from_the_constraints(seed):
    rng = np.random.default_rng(seed)
    X, centres, rotations = _set(rng)
    truth = Similarity(float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(), rng.normal(0, 3, 3))
    solved = truth.inverse()  # what structure from motion gives: the set in a world of its own
    X_s = solved.apply(X)
    c_s = solved.apply(centres)
    R_s = np.array([solved.pose(R, c)[0] for R, c in zip(rotations, centres)])
    plane = ground_plane_RANSAC(X_s, cameras=c_s, seed=seed)
    assert plane.inliers[:300].all() and not plane.inliers[300:].any()
    a, b = 7, 150  # two ground points: their distance in the set's metres
    distance = float(np.linalg.norm(X[a] - X[b]))
    origin = point_under(plane, c_s[0])  # the ground under the first camera: the set's origin
    S = world_from_constraints(plane.normal, R_s[0][2], origin, (X_s[a], X_s[b], distance))
    assert abs(S.s - truth.s) < 1e-9 * truth.s
    np.testing.assert_allclose(S.R, truth.R, atol=1e-9)
    np.testing.assert_allclose(S.t, truth.t, atol=1e-9 * (1 + np.linalg.norm(truth.t)))
    np.testing.assert_allclose(S.apply(X_s), X, atol=1e-9)
    for R, c, R_true, c_true in zip(R_s, c_s, rotations, centres):
        R_new, c_new = S.pose(R, c)
        np.testing.assert_allclose(R_new, R_true, atol=1e-9)
        np.testing.assert_allclose(c_new, c_true, atol=1e-9)


def test_the_mean_camera_up_of_level_cameras_is_the_world_up():
    rng = np.random.default_rng(3)
    X, centres, rotations = _set(rng)
    truth = Similarity(1.7, Rotation.random(random_state=3).as_matrix(), [1.0, -2.0, 0.5])
    solved = truth.inverse()
    R_s = [solved.pose(R, c)[0] for R, c in zip(rotations, centres)]
    # look_at keeps every camera's x axis level; their mean up lies in the vertical plane of the mean view:
    # on the truth's +z only for cameras that look level, so compare against the cameras' own mean
    expected = -np.mean([R[1] for R in rotations], axis=0)
    expected /= np.linalg.norm(expected)
    np.testing.assert_allclose(truth.R @ mean_camera_up(R_s), expected, atol=1e-12)
    level = [look_at(c, c + [np.cos(a), np.sin(a), 0.0]) for c, a in zip(centres, (0.1, 0.9, 2.0, 3.0, 4.2))]
    np.testing.assert_allclose(truth.R @ mean_camera_up([solved.pose(R, c)[0] for R, c in zip(level, centres)]),
                               [0.0, 0.0, 1.0], atol=1e-12)


def test_ransac_ground_is_the_same_for_the_same_seed_and_robust_to_clutter():
    rng = np.random.default_rng(4)
    X, centres, _ = _set(rng)
    noisy = X + rng.normal(0, 0.002, X.shape)
    a, b = ground_plane_RANSAC(noisy, cameras=centres, seed=5), ground_plane_RANSAC(noisy, cameras=centres, seed=5)
    assert np.array_equal(a.normal, b.normal) and a.offset == b.offset
    assert np.degrees(np.arccos(a.normal @ [0, 0, 1])) < 0.2 and abs(a.offset) < 0.01
    below = ground_plane_RANSAC(noisy, cameras=-centres, seed=5)  # cameras under the plane: the normal turns
    np.testing.assert_allclose(below.normal, -a.normal)


def test_the_ground_normal_sigma_is_the_spread_of_its_fits_over_noise_draws():
    """A 4 x 1 m floor of 150 points, 1 cm of noise across it, tilted: 2000 draws' normals scatter about the truth
    as plane_normal_covariance says, axis by axis (the long side tilts it 4x less), within 7 % (the sampling
    error of a variance from 2000 draws: 3 %); the ground plane carries its inliers' covariance."""
    rng = np.random.default_rng(7)
    turn = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    floor = np.column_stack([rng.uniform(-2, 2, 150), rng.uniform(-0.5, 0.5, 150), np.zeros(150)]) @ turn.T
    normal, u, v = turn[:, 2], turn[:, 0], turn[:, 1]
    draws = floor + rng.normal(0, 0.01, (2000, 150, 1)) * normal
    fitted = np.linalg.svd(draws - draws.mean(axis=1, keepdims=True), full_matrices=False)[2][:, -1]
    fitted *= np.sign(fitted @ normal)[:, None]
    predicted = np.mean([[u @ C @ u, v @ C @ v] for C in map(plane_normal_covariance, draws[:200])], axis=0)
    np.testing.assert_allclose(np.var(fitted @ np.column_stack([u, v]), axis=0), predicted, rtol=0.07)
    assert np.sqrt(predicted[1] / predicted[0]) > 3.5  # the short side: 4x
    X = draws[0]
    plane = ground_plane_RANSAC(X, seed=1)
    np.testing.assert_array_equal(plane.normal_covariance, plane_normal_covariance(X[plane.inliers]))
    assert plane.tilt_sigma_deg == np.degrees(np.sqrt(np.trace(plane.normal_covariance)))
    assert np.isnan(plane_normal_covariance(floor[:3])).all()  # three points: no spread to measure


def test_constraints_that_fix_nothing_are_one_clear_error():
    with pytest.raises(CamcalError, match="parallel to the up direction"):
        world_from_constraints([0, 0, 1], [0, 0, 2])
    with pytest.raises(CamcalError, match="same point"):
        world_from_constraints([0, 0, 1], [0, 1, 0], None, ([1, 2, 3], [1, 2, 3], 1.0))
    with pytest.raises(CamcalError, match="distance must be positive"):
        world_from_constraints([0, 0, 1], [0, 1, 0], None, ([1, 2, 3], [1, 2, 4], -1.0))
    with pytest.raises(CamcalError, match="at least 3 points"):
        ground_plane_RANSAC(np.zeros((2, 3)))
    with pytest.raises(CamcalError, match="no plane"):
        ground_plane_RANSAC(np.outer(np.arange(10.0), [1, 2, 3]))


def test_a_wall_with_more_points_than_the_floor_is_not_the_ground_given_the_cameras_up():
    rng = np.random.default_rng(6)
    floor = np.column_stack([rng.uniform(0, 8, (200, 2)), np.zeros(200)])
    wall = np.column_stack([rng.uniform(0, 8, 500), np.zeros(500), rng.uniform(0, 3, 500)])  # the wall y = 0
    X = np.concatenate([floor, wall])
    cameras = np.array([[4.0, 5.0, 1.6], [5.0, 6.0, 1.5]])
    assert abs(ground_plane_RANSAC(X, cameras=cameras).normal[1]) > 0.999  # the most points: the wall
    pitched = mean_camera_up([look_at(c, [4.0, 0.0, 0.4]) for c in cameras])  # cameras looking down at the wall
    assert 0.9 < pitched[2] < 0.99  # the hint leans towards the wall, far less than 45 deg
    plane = ground_plane_RANSAC(X, cameras=cameras, up_hint=pitched)
    np.testing.assert_allclose(plane.normal, [0.0, 0.0, 1.0], atol=1e-4)  # a wall point at the foot may pull
    assert plane.inliers[:200].all() and plane.inliers.sum() < 260  # the floor, and the wall's foot within reach


def _board_seen(seed):
    """A 9x6 board of 4 cm squares, printed side up, rotated and moved on the set's ground, and 4 cameras around
    it (the set's world); the set then moved into a world of its own (a random similarity), and each camera's
    view of the board's corners (exact normalised rays, some corners out of some views)."""
    rng = np.random.default_rng(seed)
    board = parse_board("chessboard:9x6:0.04")
    turn = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()
    # the board's x along its columns, its y along its rows, its z into its printed side: here the ground's -z
    board_to_set = turn @ np.diag([1.0, -1.0, -1.0])
    origin = np.array([rng.uniform(-1, 1), rng.uniform(2, 3), 0.0])
    corners = board.object_points @ board_to_set.T + origin
    centres = np.array([[x, -1.0, 1.5 + 0.1 * x] for x in (-2.0, -1.0, 1.0, 2.0)])
    rotations = np.array([look_at(c, origin + [0.1, 0.1, 0.0]) for c in centres])
    truth = Similarity(float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(),
                       rng.normal(0, 3, 3))
    solved = truth.inverse()
    poses = [solved.pose(R, c) for R, c in zip(rotations, centres)]
    R_s = np.array([R for R, _ in poses])
    t_s = np.array([-R @ c for R, c in poses])
    ids, rays = [], []
    for view, (R, c) in enumerate(zip(rotations, centres)):
        seen = np.arange(board.n_corners)[view::1] if view < 2 else np.arange(board.n_corners)[: 40 + view]
        x_cam = (corners[seen] - c) @ R.T
        ids.append(seen)
        rays.append(x_cam[:, :2] / x_cam[:, 2:])
    return board, board_to_set, origin, centres, rotations, R_s, t_s, ids, rays, solved


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_board_seen_by_the_solved_cameras_sets_the_world_exactly(seed):
    """Exact rays: the corners triangulate to the set's corners in the solve's world, and the board's world puts
    every camera where it stands relative to the board (the board's plane the ground, +z towards the cameras, its
    first corner the origin, its columns +x, its metres) to 1e-9."""
    board, board_to_set, origin, centres, rotations, R_s, t_s, ids, rays, solved = _board_seen(seed)
    seen, X = triangulate_corners(R_s, t_s, ids, rays)
    np.testing.assert_array_equal(seen, np.arange(board.n_corners))  # every corner is in two views at least
    np.testing.assert_allclose(X, solved.apply(board.object_points @ board_to_set.T + origin), atol=1e-9)
    fit = world_from_board(board.object_points, R_s, t_s, ids, rays)
    assert fit.n_corners == board.n_corners and fit.rms < 1e-9
    # the board's world: x along the columns, y = z x x on the ground, z up (the set's up here)
    axes = board_to_set @ np.diag([1.0, -1.0, -1.0])  # columns: the world's axes in the set
    assert abs(fit.similarity.s - 1.0 / solved.s) < 1e-9 / solved.s
    for R, c in zip(rotations, centres):
        R_new, c_new = fit.similarity.pose(*solved.pose(R, c))
        np.testing.assert_allclose(c_new, axes.T @ (c - origin), atol=1e-9)
        np.testing.assert_allclose(R_new, R @ axes, atol=1e-9)
        assert c_new[2] > 0


def test_a_board_corner_far_off_is_dropped_and_too_few_corners_are_one_error():
    board, board_to_set, origin, centres, rotations, R_s, t_s, ids, rays, solved = _board_seen(3)
    rays[0][ids[0] == 5] += 0.05  # a corner detected far off in one view (a wrong match)
    rays[1][ids[1] == 7] = np.nan  # a corner the lens model cannot unproject in another
    fit = world_from_board(board.object_points, R_s, t_s, ids, rays)
    assert fit.n_corners == board.n_corners - 1 and fit.rms < 1e-9
    axes = board_to_set @ np.diag([1.0, -1.0, -1.0])
    np.testing.assert_allclose(fit.similarity.pose(*solved.pose(rotations[0], centres[0]))[1],
                               axes.T @ (centres[0] - origin), atol=1e-9)
    with pytest.raises(CamcalError, match="3 corners not on one line"):
        world_from_board(board.object_points, R_s, t_s, [i[:9] for i in ids], [r[:9] for r in rays])
