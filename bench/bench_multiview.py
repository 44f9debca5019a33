"""Benchmark: camcal's N-camera board calibration vs OpenCV 5's cv2.calibrateMultiview.

Scene (same for both, made here): three 1280x800 cameras 0.15 m apart,
slightly toed in, an OpenCV lens (k1 -0.2, k2 0.05), principal points off
centre; a 9x6 chessboard (40 mm squares) at 24 random poses 0.9-1.8 m away;
a camera sees a pose only when every corner is inside its frame; corners
get Gaussian noise of 0.2 px. Both calibrate the opencv model from the same
corners. Errors against the truth: worst focal length and principal point
error over the cameras (px), worst relative rotation (deg) and baseline
(%) error of cameras 1 and 2 against camera 0, and the time.

Prints ``name: ours X, peer Y, ratio Y/X``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from camcal.geometry.board import Detection, parse_board
from camcal.model.camera import rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.geometry.zhang import calibrate_board
from camcal.model.rig import Camera

SIZE = (1280, 800)
SIGMA_PX = 0.2
N_POSES = 24


def truth_cameras() -> list[Camera]:
    lens = Distortion("opencv", {"k1": -0.2, "k2": 0.05, "p1": 0.0, "p2": 0.0, "k3": 0.0})
    cameras = []
    for i in range(3):
        R = Rotation.from_euler("y", (1 - i) * 3.0, degrees=True).as_matrix()
        K = [[1000.0 + 10 * i, 0.0, 652.0 + 5 * i], [0.0, 1000.0 + 10 * i, 391.0 - 4 * i], [0.0, 0.0, 1.0]]
        cameras.append(Camera(f"cam{i}", SIZE, K, lens, R, [0.15 * i, 0.0, 0.0]))
    return cameras


def observations(cameras, board, rng):
    """Per pose, each camera's noisy corners (None when the board is not wholly in its frame)."""
    obj = board.object_points
    poses = []
    while len(poses) < N_POSES:
        centre = np.array([0.15, 0.0, 0.0]) + rng.uniform([-0.4, -0.3, 0.9], [0.4, 0.3, 1.8])
        R_board = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3), degrees=True).as_matrix()
        X = (obj - obj.mean(axis=0)) @ R_board.T + centre
        views = []
        for camera in cameras:
            x = camera.project(X)
            inside = np.all(np.isfinite(x)) and np.all((x > 5) & (x < np.array(SIZE) - 6))
            views.append(x + rng.normal(0.0, SIGMA_PX, x.shape) if inside else None)
        if sum(view is not None for view in views) >= 2:
            poses.append(views)
    return poses


def errors(cameras_true, Ks, Rs, cs) -> dict[str, float]:
    """Worst errors against the truth; Rs, cs are poses relative to camera 0."""
    ref = cameras_true[0]
    out = {"focal_px": 0.0, "principal_point_px": 0.0, "rotation_deg": 0.0, "baseline_pct": 0.0}
    for i, true in enumerate(cameras_true):
        out["focal_px"] = max(out["focal_px"], abs(Ks[i][0, 0] - true.K[0, 0]), abs(Ks[i][1, 1] - true.K[1, 1]))
        out["principal_point_px"] = max(out["principal_point_px"], float(np.abs(Ks[i][:2, 2] - true.K[:2, 2]).max()))
        if i == 0:
            continue
        R_true = true.R @ ref.R.T
        out["rotation_deg"] = max(out["rotation_deg"], rotation_angle_deg(Rs[i] @ R_true.T))
        baseline_true = np.linalg.norm(ref.R @ (true.c - ref.c))
        out["baseline_pct"] = max(out["baseline_pct"], 100 * abs(np.linalg.norm(cs[i]) / baseline_true - 1))
    return out


def ours(cameras, board, poses):
    detections = {camera.name: [] for camera in cameras}
    ids = np.arange(board.n_corners)
    for k, views in enumerate(poses):
        for camera, view in zip(cameras, views):
            if view is not None:
                detections[camera.name].append(Detection(f"{camera.name}_{k:02d}.png", SIZE, ids, view, "sb"))
    start = time.perf_counter()
    rig = calibrate_board(board, detections, model="opencv").rig
    seconds = time.perf_counter() - start
    ref = rig.cameras[0]
    return ([c.K for c in rig.cameras], [c.R @ ref.R.T for c in rig.cameras],
            [ref.R @ (c.c - ref.c) for c in rig.cameras], seconds)


def peer(cameras, board, poses):
    obj = np.asarray(board.object_points, np.float32)
    mask = np.array([[view is not None for view in (p[i] for p in poses)] for i in range(len(cameras))], np.uint8)
    blank = np.zeros((board.n_corners, 2), np.float32)
    image_points = [[(p[i] if p[i] is not None else blank).astype(np.float32) for p in poses] for i in range(len(cameras))]
    start = time.perf_counter()
    _, Ks, _, rvecs, tvecs = cv2.calibrateMultiview([obj] * len(poses), image_points, [SIZE] * len(cameras), mask,
                                                    np.zeros(len(cameras), np.uint8), None, None, None, None)
    seconds = time.perf_counter() - start
    Rs = [cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0] for r in rvecs]
    cs = [-R.T @ np.asarray(t, np.float64).reshape(3) for R, t in zip(Rs, tvecs)]  # camera i's centre in camera 0
    return Ks, Rs, cs, seconds


def main() -> None:
    cameras = truth_cameras()
    board = parse_board("chessboard:9x6:0.04")
    poses = observations(cameras, board, np.random.default_rng(5))
    K_o, R_o, c_o, t_o = ours(cameras, board, poses)
    K_p, R_p, c_p, t_p = peer(cameras, board, poses)
    mine, theirs = errors(cameras, K_o, R_o, c_o), errors(cameras, K_p, R_p, c_p)
    seen = sum(v is not None for p in poses for v in p)
    print(f"{N_POSES} board poses, {seen} camera views, corner noise {SIGMA_PX} px")
    for name in mine:
        print(f"multiview {name} error (worst camera): ours {mine[name]:.4g}, peer {theirs[name]:.4g}, "
              f"ratio {theirs[name] / max(mine[name], 1e-12):.3g}")
    print(f"multiview time s: ours {t_o:.3f}, peer {t_p:.3f}, ratio {t_p / t_o:.3g}")


if __name__ == "__main__":
    main()
