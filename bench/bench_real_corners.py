"""camcal's corners against OpenCV SB's on real chessboard sets: held-out RMS, views held out.

Per set: every image where both camcal's ``detect_board`` (as ``calibrate board`` runs it) and
``cv2.findChessboardCornersSB`` (EXHAUSTIVE | ACCURACY) find the whole board; every 6th of those views
held out. Three detectors' corners: camcal's, SB's, and SB's refined by OpenCV's ``cornerSubPix`` (Forstner's
gradient orthogonality, a third estimator: :func:`subpix_refined`). Pipelines, each trained on its own corners:

- camcal default: ``calibrate_board`` (model auto, board shape auto) on camcal's corners, each held-out view
  posed against its board (flat or the fitted surface) with the intrinsics held;
- OpenCV on SB's corners and on SB + cornerSubPix's: ``calibrateCamera`` (default, rational, rational + thin
  prism), ``cv2.fisheye.calibrate`` (posed by LM with the intrinsics held, ``zhang_fit.posed_residuals``) and
  ``calibrateCameraRO`` (rational, + thin prism: the board's points refined; posed by ``solvePnP`` +
  ``solvePnPRefineLM`` against the board it estimated);
- mrcal on SB's corners: OPENCV8 and splined stereographic fits, flat and with its board warp
  (``bench_lens_models.mrcal_models``, skipped with a line where Debian's mrcal is absent);
- the same OpenCV and mrcal fits on camcal's corners (the models compared on the same corners, without the
  corners' gain).

Every pipeline is held out on the *same* evaluation corners, three times: on each detector's (each held-out
view's corners put in the fit's own labelling by nearest neighbour); the best of the peers' fits is the peer.
No detector is the truth on real images: a pipeline whose corners carry an error the others' do not is favoured
on its own corners, so the ratio is printed for all three (on rendered boards, where the truth is known,
camcal's corners have 0.26 x SB's error: ``bench_corners.py``).

``--floor`` adds what these corners allow (``bench_lens_models.floor`` on camcal's corners: the held-out views'
own noise for camcal's pick on a ``free+plane`` board fitted with them) beside 0.97 x the best peer fitted on
the same corners.

``--all-splits`` runs the 6 splits (views ``n % 6 == k`` held out) and prints, per evaluation corners, each
pipeline fixed over the splits and scored on every view, each held out once (:func:`pooled`).

Usage: python bench/bench_real_corners.py [--floor] [--all-splits] DIR PATTERN COLUMNS ROWS [DIR PATTERN COLUMNS ROWS ...]
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
from bench_lens_models import (floor, mrcal_models, mrcal_seed, opencv_held_out_rms, opencv_models,  # noqa: E402
                               posed_rms, release_object_fit)

SB_FLAGS = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
DEFAULT_SETS = ["/work/data/udacity_gopro", "GOPR*.jpg", "8", "6",
                "/work/data/udacity_dashcam", "calibration*.jpg", "9", "6",
                "/work/data/xinning_fisheye", "*.jpg", "6", "9",
                "/work/data/sourishg_fisheye_stereo", "left*.jpg", "9", "6",
                "/work/data/sourishg_stereo", "left*.jpg", "9", "6"]


def subpix_refined(gray: np.ndarray, corners: np.ndarray, board: Board) -> np.ndarray:
    """OpenCV's own saddle-point refinement of SB's corners: ``cornerSubPix`` (Forstner's gradient orthogonality),
    half-window 0.4 x the board's smallest square in the image, 2-11 px (11: OpenCV's tutorial window)."""
    grid = corners.reshape(board.rows, board.columns, 2)
    square = min(np.linalg.norm(np.diff(grid, axis=axis), axis=2).min() for axis in (0, 1))
    half = int(np.clip(round(0.4 * square), 2, 11))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    return cv2.cornerSubPix(gray, corners.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1),
                            crit).reshape(-1, 2).astype(np.float64)


def detections(folder: Path, pattern: str, board: Board):
    """camcal's, SB's and SB + cornerSubPix's detections on the images where camcal and SB find the board (the
    most common size only), and the seconds camcal and SB took."""
    triples, t_ours, t_sb = [], 0.0, 0.0
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
        corners = corners.reshape(-1, 2).astype(np.float64)
        sb = Detection(path.name, ours.image_size, np.arange(board.n_corners), corners, "sb")
        triples.append((ours, sb, dataclasses.replace(sb, corners_px=subpix_refined(gray, corners, board))))
    sizes = [t[0].image_size for t in triples]
    size = max(set(sizes), key=sizes.count)
    triples = [t for t in triples if t[0].image_size == size]
    renamed = [[dataclasses.replace(d, image=f"view{n:03d}.jpg") for d in t] for n, t in enumerate(triples)]
    return [t[0] for t in renamed], [t[1] for t in renamed], [t[2] for t in renamed], t_ours, t_sb


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
    for name, flags in (("RO rational", cv2.CALIB_RATIONAL_MODEL),
                        ("RO rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL)):
        try:
            _, K, dist, points = release_object_fit(board, train, size, flags)
            yield name, K, dist, points
        except cv2.error as error:
            print(f"  opencv {name}: failed ({str(error).strip().splitlines()[-1]})")


def peer_fits(board, train, held_sets: dict, with_mrcal: bool) -> dict:
    """Held-out RMS of OpenCV's fits (and mrcal's) of ``train`` on each of ``held_sets`` (views in the order of
    ``train``'s detector): ``{(fit, evaluation corners): px}``."""
    size = train[0].image_size
    out, cameras = {}, {}
    for name, camera in opencv_models(board, train, size):
        cameras[name] = camera
        for corners, held in held_sets.items():
            try:
                out[(f"opencv {name}", corners)] = posed_rms(board, camera, held)
            except Exception as error:  # noqa: BLE001 - a peer's failure is a row, not a stop
                print(f"  opencv {name}: held-out posing failed ({error})")
    for name, K, dist, points in release_object_fits(board, train, size):
        for corners, held in held_sets.items():
            out[(f"opencv {name}", corners)] = opencv_held_out_rms(points, held, K, dist)
    if with_mrcal and cameras:
        seed = mrcal_seed(cameras, size)
        for corners, held in held_sets.items():
            for name, _, held_rms in mrcal_models(board, train, held, size, *seed):
                out[(f"mrcal {name}", corners)] = held_rms
    return out


def run(folder: Path, pattern: str, columns: int, rows: int, with_mrcal: bool = True, with_floor: bool = False,
        split: int = 0, found=None) -> dict:
    board = Board("chessboard", columns, rows, 1.0)
    ours, sb, subpix, t_ours, t_sb = found or detections(folder, pattern, board)
    holdout = {n for n in range(len(ours)) if n % 6 == split}
    label = f"{folder.name}/{pattern} ({ours[0].image_size[0]}x{ours[0].image_size[1]}, {len(ours)} views, "
    label += f"{len(holdout)} held out" + (f", split {split})" if split else ")")
    print(f"{label}: camcal's corners {corner_distance(ours, sb):.3f} px RMS from SB's, "
          f"{corner_distance(ours, subpix):.3f} from SB + cornerSubPix's (SB's from those {corner_distance(sb, subpix):.3f}); "
          f"detection {t_ours:.1f} s vs SB {t_sb:.1f} s", flush=True)
    held = {"camcal's": [d for n, d in enumerate(ours) if n in holdout],
            "SB's": [d for n, d in enumerate(sb) if n in holdout],
            "cornerSubPix's": [d for n, d in enumerate(subpix) if n in holdout]}
    in_order = {detector: {corners: relabelled(views, held[detector]) for corners, views in held.items()}
                for detector in held}
    rows_out = {}
    result = zhang.calibrate_board(board, {"cam": ours}, units="squares", holdout=holdout)
    camera = result.rig.cameras[0]
    points = None if result.board_shape is None else result.board_shape.points(board)
    shape = "flat board" if result.board_shape is None else result.board_shape.describe(board)
    for corners, views in in_order["camcal's"].items():
        rows_out[("camcal default", corners)] = posed_rms(board, camera, views, points)
    own = rows_out[("camcal default", "camcal's")]
    print(f"  camcal default on camcal's corners: {result.model}, {shape}; held out {own:.4f} px on its own corners "
          f"(calibrate_board's figure {result.heldout_rms_px:.4f})")
    trained_on = {"camcal's": (ours, "camcal's corners"), "SB's": (sb, "SB's corners"),
                  "cornerSubPix's": (subpix, "SB + cornerSubPix's corners")}
    for detector, (views, train_label) in trained_on.items():
        train = [d for n, d in enumerate(views) if n not in holdout]
        fits = peer_fits(board, train, in_order[detector], with_mrcal and detector != "cornerSubPix's")
        rows_out.update({(f"{name} on {train_label}", corners): v for (name, corners), v in fits.items()})
    ratios = {}
    for corners in held:
        peers = {k[0]: v for k, v in rows_out.items() if k[1] == corners and k[0] != "camcal default"}
        for name, value in peers.items():
            print(f"  {name}, held out on {corners} corners: {value:.4f} px")
        best = min(peers, key=peers.get)
        ours_rms = rows_out[("camcal default", corners)]
        ratios[corners] = ours_rms / peers[best]
        print(f"  => held out on {corners} corners: camcal default {ours_rms:.4f}, best peer {peers[best]:.4f} "
              f"({best}), ratio {ratios[corners]:.3f}", flush=True)
    if with_floor:
        _, _, noise_held = floor(board, ours, held["camcal's"], result.model)
        same = min(v for k, v in rows_out.items() if k[1] == "camcal's" and k[0].endswith("on camcal's corners"))
        print(f"  floor on camcal's corners: the held-out views' own noise {noise_held:.4f} px "
              f"(bench_lens_models.floor, {result.model}); 0.97 x the best peer on the same corners {0.97 * same:.4f}")
    return {"set": label, "heldout": rows_out, "n_corners": sum(len(d.ids) for d in held["camcal's"]),
            **{f"ratio on {k} corners": v for k, v in ratios.items()}}


def pooled(runs: list[dict]) -> None:
    """Each pipeline fixed over the 6 splits, its RMS over every view (each held out once), per evaluation corners:
    camcal's default over the best such peer, of every training, of the peers trained on SB's corners (their own
    pipeline), and of those trained on camcal's (the models on the same corners)."""
    n = np.array([r["n_corners"] for r in runs], dtype=np.float64)
    keys = set.intersection(*(set(r["heldout"]) for r in runs))
    rms = {k: float(np.sqrt(np.sum([r["heldout"][k] ** 2 for r in runs] * n) / n.sum())) for k in keys}
    for corners in ("camcal's", "SB's", "cornerSubPix's"):
        ours = rms[("camcal default", corners)]
        line = f"  every view held out once, on {corners} corners: camcal default {ours:.4f} px"
        for which, test in (("any training", lambda name: True), ("on SB's corners", lambda name: name.endswith("on SB's corners")),
                            ("on camcal's corners", lambda name: name.endswith("on camcal's corners"))):
            peers = {k[0]: v for k, v in rms.items() if k[1] == corners and k[0] != "camcal default" and test(k[0])}
            if peers:
                best = min(peers, key=peers.get)
                line += f"; best peer {which} {peers[best]:.4f} ({best}): ratio {ours / peers[best]:.3f}"
        print(line, flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    with_floor, all_splits = "--floor" in args, "--all-splits" in args
    args = [a for a in args if a not in ("--floor", "--all-splits")] or DEFAULT_SETS
    for k in range(0, len(args), 4):
        folder, pattern, columns, rows = Path(args[k]), args[k + 1], int(args[k + 2]), int(args[k + 3])
        if not all_splits:
            run(folder, pattern, columns, rows, with_floor=with_floor)
            continue
        found = detections(folder, pattern, Board("chessboard", columns, rows, 1.0))
        pooled([run(folder, pattern, columns, rows, with_floor=with_floor, split=split, found=found) for split in range(6)])
