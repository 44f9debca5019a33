"""Held-out RMS of camcal's default lens model (auto) against OpenCV's best model on real chessboard sets.

Every tool gets the same corners (OpenCV ``findChessboardCornersSB``, EXHAUSTIVE | ACCURACY) and the same
split (every 6th view held out); each held-out view is posed by PnP with the fitted intrinsics held (camcal's
``_posed_residuals``: the same LM pose fit for every tool). Prints ``name: ours X, peer Y, ratio Y/X``.

Usage: python bench/bench_lens_models.py DIR PATTERN COLUMNS ROWS [DIR PATTERN COLUMNS ROWS ...]
(default: ../shared/data/stereo_chessboard left*.jpg and right*.jpg, 9x6).
"""

import sys
from pathlib import Path

import cv2
import numpy as np

from camcal.geometry import zhang
from camcal.geometry.board import Board, Detection
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera


def sb_detections(folder: Path, pattern: str, board: Board) -> list[Detection]:
    out = []
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    for n, path in enumerate(sorted(folder.glob(pattern))):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCornersSB(gray, (board.columns, board.rows), flags=flags)
        if found:
            out.append(Detection(f"view{len(out):03d}.jpg", (gray.shape[1], gray.shape[0]),
                                 np.arange(board.n_corners), corners.reshape(-1, 2).astype(np.float64), "sb"))
    return out


def heldout(board, camera, views) -> float:
    r = np.concatenate([zhang._posed_residuals(board, camera, d) for d in views])
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def opencv_models(board, train, size):
    obj = [board.object_points[d.ids].astype(np.float32) for d in train]
    img = [d.corners_px.astype(np.float32).reshape(-1, 1, 2) for d in train]
    for name, flags in (("default", 0), ("rational", cv2.CALIB_RATIONAL_MODEL),
                        ("rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL)):
        try:
            _, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
            yield name, Camera("cv", size, K, Distortion.from_opencv_coefficients(dist.ravel()[:12 if flags else 5]),
                               np.eye(3), np.zeros(3))
        except (cv2.error, Exception) as error:  # noqa: BLE001 - a peer's failure is a row, not a stop
            print(f"  opencv {name}: failed ({error})")
    try:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        flags = zhang._fisheye_flags("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW")
        _, K, D, _, _ = cv2.fisheye.calibrate([o.reshape(1, -1, 3).astype(np.float64) for o in obj],
                                              [i.reshape(1, -1, 2).astype(np.float64) for i in img], size, None, None,
                                              flags=flags, criteria=crit)
        yield "fisheye", Camera("cv", size, K, Distortion("kannala-brandt", dict(zip(("k1", "k2", "k3", "k4"), D.ravel()))),
                                np.eye(3), np.zeros(3))
    except (cv2.error, Exception) as error:  # noqa: BLE001
        print(f"  opencv fisheye: failed ({error})")


def run(folder: Path, pattern: str, columns: int, rows: int) -> None:
    board = Board("chessboard", columns, rows, 1.0)
    views = sb_detections(folder, pattern, board)
    held = [d for n, d in enumerate(views) if n % 6 == 0]
    train = [d for n, d in enumerate(views) if n % 6]
    size = views[0].image_size
    result = zhang.calibrate_board(board, {"cam": views}, units="squares", holdout=set(range(0, len(views), 6)))
    ours = result.heldout_rms_px
    peers = {}
    for name, camera in opencv_models(board, train, size):
        try:
            peers[name] = heldout(board, camera, held)
        except Exception as error:  # noqa: BLE001
            print(f"  opencv {name}: held-out posing failed ({error})")
    best = min(peers, key=peers.get)
    label = f"{folder.name}/{pattern}"
    print(f"{label}: {len(views)} views ({len(held)} held out), camcal auto -> {result.model}")
    for score in result.model_ranking:
        print(f"  camcal {score.describe()}")
    for name, value in peers.items():
        print(f"  opencv {name}: {value:.4f} px held out")
    print(f"{label}: ours {ours:.4f}, peer {peers[best]:.4f} (opencv {best}), ratio {peers[best] / ours:.3f}")


if __name__ == "__main__":
    args = sys.argv[1:] or ["../shared/data/stereo_chessboard", "left*.jpg", "9", "6",
                            "../shared/data/stereo_chessboard", "right*.jpg", "9", "6"]
    for k in range(0, len(args), 4):
        run(Path(args[k]), args[k + 1], int(args[k + 2]), int(args[k + 3]))
