"""camcal's corners against OpenCV SB's on real chessboard sets: held-out RMS, views held out.

Per set: every image where both camcal's ``detect_board`` (as ``calibrate board`` runs it) and
``cv2.findChessboardCornersSB`` (EXHAUSTIVE | ACCURACY) find the whole board; every 6th of those views
held out. Rows:

- camcal default: ``calibrate_board`` (model auto, board shape auto) trained on camcal's corners;
- camcal on SB's corners: the same call trained and held out on SB's corners (the corners' share of the gain);
- OpenCV on SB's corners: ``calibrateCamera`` (default, rational, rational + thin prism), ``cv2.fisheye.calibrate``
  (each held-out view posed by LM with the intrinsics held, ``zhang._posed_residuals``) and ``calibrateCameraRO``
  (rational, + thin prism: the board's points refined; posed by ``solvePnP`` + ``solvePnPRefineLM`` against the
  board it estimated), the best of them the peer.

Each pipeline trains on its own detector's corners, and every one is held out on the *same* evaluation corners,
twice: on camcal's and on SB's (each held-out view's corners put in the fit's own labelling by nearest neighbour).
Neither detector is the truth on real images: a pipeline whose corners carry a bias the other's do not is favoured
on its own evaluation corners, so the ratio is printed for both (on rendered boards, camcal's corners are 0.26 x
SB's error: ``bench_corners.py``). Also printed: RMS distance between the two detectors' corners.

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
from bench_lens_models import opencv_held_out_rms, opencv_models, posed_rms  # noqa: E402

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


def relabelled(views, like):
    """``views`` with each view's corners put in the order of the same view in ``like`` (nearest neighbour): a
    fit's board (refined or shaped) is attached to its detector's labels."""
    out = []
    for d, ref in zip(views, like):
        order = np.linalg.norm(ref.corners_px[:, None] - d.corners_px[None], axis=2).argmin(axis=1)
        out.append(dataclasses.replace(d, corners_px=d.corners_px[order]))
    return out


def release_object_fits(board, train, size):
    """(name, K, dist, refined board points) of OpenCV's ``calibrateCameraRO`` (rational, + thin prism)."""
    obj = [board.object_points[d.ids].astype(np.float32) for d in train]
    img = [d.corners_px.astype(np.float32).reshape(-1, 1, 2) for d in train]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    for name, flags in (("RO rational", cv2.CALIB_RATIONAL_MODEL),
                        ("RO rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL)):
        try:
            _, K, dist, _, _, points = cv2.calibrateCameraRO(obj, img, size, board.columns - 1, None, None,
                                                             flags=flags, criteria=crit)
            yield name, K, dist, points.reshape(-1, 3).astype(np.float64)
        except cv2.error as error:
            print(f"  opencv {name}: failed ({str(error).strip().splitlines()[-1]})")


def run(folder: Path, pattern: str, columns: int, rows: int) -> dict:
    board = Board("chessboard", columns, rows, 1.0)
    ours, sb, t_ours, t_sb = both_detections(folder, pattern, board)
    holdout = set(range(0, len(ours), 6))
    label = f"{folder.name}/{pattern} ({ours[0].image_size[0]}x{ours[0].image_size[1]}, {len(ours)} views, "
    label += f"{len(holdout)} held out)"
    print(f"{label}: camcal vs SB corners {corner_distance(ours, sb):.3f} px RMS apart; detection "
          f"{t_ours:.1f} s vs SB {t_sb:.1f} s", flush=True)
    held_ours = [d for n, d in enumerate(ours) if n in holdout]
    held_sb = [d for n, d in enumerate(sb) if n in holdout]
    # every pipeline trains on its own corners and is held out on each detector's corners (labels matched)
    evaluation = {"camcal's": (held_ours, relabelled(held_ours, held_sb)), "SB's": (relabelled(held_sb, held_ours), held_sb)}
    rows_out = {}
    for corners, (in_ours_order, _) in evaluation.items():
        mixed = [in_ours_order[sorted(holdout).index(n)] if n in holdout else d for n, d in enumerate(ours)]
        result = zhang.calibrate_board(board, {"cam": mixed}, units="squares", holdout=holdout)
        rows_out[("camcal default", corners)] = result.heldout_rms_px
        print(f"  camcal default (auto -> {result.model}) on camcal's corners, held out on {corners} corners: "
              f"{result.heldout_rms_px:.4f} px", flush=True)
    sb_result = zhang.calibrate_board(board, {"cam": sb}, units="squares", holdout=holdout)
    print(f"  camcal (auto -> {sb_result.model}) on SB's corners, held out on SB's corners: "
          f"{sb_result.heldout_rms_px:.4f} px (the corners' share of the gain)")
    train_sb = [d for n, d in enumerate(sb) if n not in holdout]
    for name, camera in opencv_models(board, train_sb, sb[0].image_size):
        for corners, (_, in_sb_order) in evaluation.items():
            try:
                rows_out[(f"opencv {name}", corners)] = posed_rms(board, camera, in_sb_order)
            except Exception as error:  # noqa: BLE001 - a peer's failure is a row, not a stop
                print(f"  opencv {name}: held-out posing failed ({error})")
    for name, K, dist, points in release_object_fits(board, train_sb, sb[0].image_size):
        for corners, (_, in_sb_order) in evaluation.items():
            rows_out[(f"opencv {name}", corners)] = opencv_held_out_rms(points, in_sb_order, K, dist)
    ratios = {}
    for corners in evaluation:
        peers = {k[0]: v for k, v in rows_out.items() if k[1] == corners and k[0] != "camcal default"}
        for name, value in peers.items():
            print(f"  {name} on SB's corners, held out on {corners} corners: {value:.4f} px")
        best = min(peers, key=peers.get)
        ratios[corners] = rows_out[("camcal default", corners)] / peers[best]
        print(f"  => held out on {corners} corners: camcal default {rows_out[('camcal default', corners)]:.4f}, "
              f"best peer {peers[best]:.4f} ({best}), ratio {ratios[corners]:.3f}", flush=True)
    return {"set": label, **{f"ratio on {k} corners": v for k, v in ratios.items()}}


if __name__ == "__main__":
    args = sys.argv[1:] or DEFAULT_SETS
    for k in range(0, len(args), 4):
        run(Path(args[k]), args[k + 1], int(args[k + 2]), int(args[k + 3]))
