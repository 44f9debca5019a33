"""camcal's corners against OpenCV SB's on real chessboard sets: held-out RMS, views held out.

Per set: every image where both camcal's ``detect_board`` (as ``calibrate board`` runs it) and
``cv2.findChessboardCornersSB`` (EXHAUSTIVE | ACCURACY) find the whole board; every 6th of those views
held out. Rows:

- camcal: ``calibrate_board`` (model auto, the default) on camcal's corners, held out on camcal's corners;
- camcal on SB corners: the same call on SB's corners (the model's share of the gain, without the corners');
- OpenCV: ``calibrateCamera`` (default, rational, rational + thin prism) and ``cv2.fisheye.calibrate`` on
  SB's corners, each held-out view posed by PnP with the intrinsics held (``zhang._posed_residuals``), on SB's
  corners; the best of them printed as the peer.

Each pipeline is measured on its own corners: the held-out RMS is what a user of that pipeline sees (corner
noise + model error). Also printed: RMS distance between the two detectors' corners.

Usage: python bench/bench_real_corners.py DIR PATTERN COLUMNS ROWS [DIR PATTERN COLUMNS ROWS ...]
(default: the /work/data sets of issue 27).
"""

import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from camcal.geometry import zhang
from camcal.geometry.board import Board, Detection, detect_board

sys.path.insert(0, str(Path(__file__).parent))
from bench_lens_models import heldout, opencv_models  # noqa: E402

SB_FLAGS = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
DEFAULT_SETS = ["/work/data/udacity_gopro", "GOPR*.jpg", "8", "6",
                "/work/data/udacity_dashcam", "calibration*.jpg", "9", "6",
                "/work/data/xinning_fisheye", "*.jpg", "6", "9",
                "/work/data/sourishg_fisheye_stereo", "left*.jpg", "9", "6",
                "/work/data/sourishg_stereo", "left*.jpg", "9", "6"]


def both_detections(folder: Path, pattern: str, board: Board):
    """camcal's and SB's detections on the images where both find the board (the most common size only)."""
    pairs, t_ours, t_sb = [], 0.0, 0.0
    for path in sorted(folder.glob(pattern)):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        t = time.perf_counter()
        ours = detect_board(board, gray, path.name)
        t_ours += time.perf_counter() - t
        t = time.perf_counter()
        found, corners = cv2.findChessboardCornersSB(gray, (board.columns, board.rows), flags=SB_FLAGS)
        t_sb += time.perf_counter() - t
        if ours is None or not found:
            print(f"  {path.name}: camcal {'found' if ours else 'missed'}, SB {'found' if found else 'missed'}")
            continue
        sb = Detection(path.name, ours.image_size, np.arange(board.n_corners), corners.reshape(-1, 2).astype(np.float64), "sb")
        pairs.append((ours, sb))
    sizes = [o.image_size for o, _ in pairs]
    size = max(set(sizes), key=sizes.count)
    pairs = [p for p in pairs if p[0].image_size == size]
    renamed = [tuple(dataclasses.replace(d, image=f"view{n:03d}.jpg") for d in p) for n, p in enumerate(pairs)]
    return [p[0] for p in renamed], [p[1] for p in renamed], t_ours, t_sb


def corner_distance(ours, sb) -> float:
    """RMS distance between the two detectors' corners, matched by nearest neighbour (labelling may differ)."""
    d = []
    for a, b in zip(ours, sb):
        gap = np.linalg.norm(a.corners_px[:, None] - b.corners_px[None], axis=2).min(axis=1)
        d.append(gap)
    return float(np.sqrt(np.mean(np.concatenate(d) ** 2)))


def run(folder: Path, pattern: str, columns: int, rows: int) -> None:
    board = Board("chessboard", columns, rows, 1.0)
    ours, sb, t_ours, t_sb = both_detections(folder, pattern, board)
    holdout = set(range(0, len(ours), 6))
    label = f"{folder.name}/{pattern} ({ours[0].image_size[0]}x{ours[0].image_size[1]}, {len(ours)} views, "
    label += f"{len(holdout)} held out)"
    ours_result = zhang.calibrate_board(board, {"cam": ours}, units="squares", holdout=holdout)
    sb_result = zhang.calibrate_board(board, {"cam": sb}, units="squares", holdout=holdout)
    train = [d for n, d in enumerate(sb) if n not in holdout]
    held = [d for n, d in enumerate(sb) if n in holdout]
    peers = {}
    for name, camera in opencv_models(board, train, sb[0].image_size):
        try:
            peers[name] = heldout(board, camera, held)
        except Exception as error:  # noqa: BLE001 - a peer's failure is a row, not a stop
            print(f"  opencv {name}: held-out posing failed ({error})")
    best = min(peers, key=peers.get)
    print(f"{label}: camcal vs SB corners {corner_distance(ours, sb):.3f} px RMS apart; detection "
          f"{t_ours:.1f} s vs SB {t_sb:.1f} s")
    print(f"  camcal (auto -> {ours_result.model}) on camcal's corners: {ours_result.heldout_rms_px:.4f} px held out")
    print(f"  camcal (auto -> {sb_result.model}) on SB's corners:     {sb_result.heldout_rms_px:.4f} px held out")
    for name, value in peers.items():
        print(f"  opencv {name} on SB's corners: {value:.4f} px held out")
    print(f"  => ours / OpenCV best ({best}) {ours_result.heldout_rms_px / peers[best]:.3f}; corner gain "
          f"(camcal corners / SB corners, camcal's fit) {ours_result.heldout_rms_px / sb_result.heldout_rms_px:.3f}",
          flush=True)


if __name__ == "__main__":
    args = sys.argv[1:] or DEFAULT_SETS
    for k in range(0, len(args), 4):
        run(Path(args[k]), args[k + 1], int(args[k + 2]), int(args[k + 3]))
