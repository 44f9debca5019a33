"""Frames chosen for the solve by coverage (camcal.geometry.view_selection) on the capture volume's geometry.

Corners are the true projections of the board plus Gaussian noise (sigma 0.15 px per axis), in every view where the
rendered volume would show the board whole; a solve on the chosen frames is compared with the solve on all frames,
parameter by parameter within the chosen solve's own covariance, and the frames left out are its held-out views.
"""

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.geometry.board import Detection, parse_board
from camcal.geometry.view_selection import select_frames, tilt_bin
from camcal.geometry.zhang import calibrate_board
from capture_volume import board_origin_pose, board_seen, make_volume, true_corners

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided"
NOISE_PX = 0.15


def noisy_detections(n_cameras, n_frames, seed=11):
    board = parse_board(SPEC)
    volume = make_volume(n_cameras, n_frames, radius=0.85)
    rng = np.random.default_rng(seed)
    detections = {c.name: [] for c in volume.cameras}
    for f in range(n_frames):
        R_wb, t_wb = board_origin_pose(board, volume.board_R[f], volume.board_t[f])
        for camera in volume.cameras:
            if board_seen(board, camera, R_wb, t_wb):
                x = true_corners(board, camera, R_wb, t_wb) + rng.normal(0, NOISE_PX, (board.n_corners, 2))
                detections[camera.name].append(Detection(f"{camera.name}_{f:04d}.png", camera.image_size,
                                                         np.arange(board.n_corners), x, "charuco"))
    return board, volume, detections


def test_tilt_bins():
    assert tilt_bin(np.eye(3)) == 0 and tilt_bin(np.diag([1.0, -1.0, -1.0])) == 0  # facing, either side
    assert tilt_bin(Rotation.from_euler("y", 25, degrees=True).as_matrix()) in range(1, 5)
    assert tilt_bin(Rotation.from_euler("x", 50, degrees=True).as_matrix()) in range(5, 9)
    sides = {tilt_bin(Rotation.from_euler(axis, sign * 25, degrees=True).as_matrix())
             for axis in "xy" for sign in (-1, 1)}
    assert sides == {1, 2, 3, 4}


def test_selection_is_deterministic_and_keeps_every_camera_and_pair():
    board, volume, detections = noisy_detections(6, 90)
    chosen = select_frames(board, detections, 24, seed=0)
    assert chosen == select_frames(board, detections, 24, seed=0) and len(chosen) == 24
    assert not set(select_frames(board, detections, 24, exclude=chosen)) & set(chosen)
    frames_of = {name: {int(d.image[-8:-4]) for d in views} for name, views in detections.items()}
    for name, frames in frames_of.items():
        assert len(frames & set(chosen)) >= min(6, len(frames)), name
    for a in frames_of:  # every pair that shares frames shares chosen ones (up to three)
        for b in frames_of:
            shared = frames_of[a] & frames_of[b]
            if a < b and shared:
                assert len(shared & set(chosen)) >= min(3, len(shared)), (a, b)
    # coverage beats the same number of evenly spaced frames: more (camera, cell) items seen
    def cells(frames):
        return len({(name, int(x // 80), int(y // 80)) for name, views in detections.items() for d in views
                    if int(d.image[-8:-4]) in frames for x, y in d.corners_px})
    even = set(np.linspace(0, 89, 24).astype(int).tolist())
    print(f"\n(camera, 80 px cell) items: chosen {cells(set(chosen))}, evenly spaced {cells(even)}, "
          f"all {cells(set(range(90)))}")
    assert cells(set(chosen)) > cells(even)


@pytest.mark.slow
def test_subset_solve_matches_the_full_solve_within_its_sigma():
    board, volume, detections = noisy_detections(6, 120)
    start = time.perf_counter()
    full = calibrate_board(board, detections, model="none")
    full_s = time.perf_counter() - start
    frames = {int(d.image[-8:-4]) for views in detections.values() for d in views}
    start = time.perf_counter()
    chosen = set(select_frames(board, detections, 30))
    subset = calibrate_board(board, detections, model="none", holdout=frames - chosen)
    subset_s = time.perf_counter() - start
    names = list(subset.parameter_names)
    worst = 0.0
    for mine, theirs in zip(subset.rig.cameras[1:], full.rig.cameras[1:]):
        # cam_from_reference: rotation vector on the left and translation t = -R c, as the covariance names them
        dr = Rotation.from_matrix(mine.R @ theirs.R.T).as_rotvec()
        dt = -mine.R @ mine.c + theirs.R @ theirs.c
        index = [names.index(f"{mine.name}.{p}") for p in ("rx", "ry", "rz", "tx", "ty", "tz")]
        delta = np.concatenate([dr, dt])
        d2 = float(delta @ np.linalg.solve(subset.covariance[np.ix_(index, index)], delta))
        worst = max(worst, d2)
        assert d2 < 22.5, (mine.name, d2)  # chi-square, 6 dof, 99.9 %
    for mine, theirs in zip(subset.rig.cameras, full.rig.cameras):
        sigma = mine.quality["sigma"]
        for p, (r, c) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
            assert abs(mine.K[r, c] - theirs.K[r, c]) < 4 * sigma[p], (mine.name, p)
    # the RMS of a corner's 2D noise left by a pose fitted to it: 6 parameters from 2n coordinates per view
    floor = NOISE_PX * np.sqrt(2) * np.sqrt(1 - 6 / (2 * board.n_corners))
    print(f"\nsubset of {len(chosen)} / {len(frames)} frames: solve {subset_s:.1f} s (with {len(frames) - len(chosen)} "
          f"held-out frames posed) vs all frames {full_s:.1f} s; worst pose Mahalanobis^2 {worst:.2f} (6 dof); "
          f"held-out RMS {subset.heldout_rms_px:.4f} px, training {subset.rms_px:.4f} px, full {full.rms_px:.4f} px, "
          f"noise {floor:.4f} px")
    assert 0.9 * floor < subset.heldout_rms_px < 1.1 * floor
    assert len(subset.images) < 0.4 * len(full.images)
