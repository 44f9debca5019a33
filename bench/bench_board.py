"""`camcal calibrate board` on the real stereo pairs against OpenCV's pipeline and mrcal.

1. Time (best of 3 alternating runs): `camcal calibrate board` (both
   cameras, joint refinement, OpenCV's distortion model) without its corner
   cache, and again with the cache filled, against OpenCV's classic pipeline on the same images in the same
   run: findChessboardCorners + cornerSubPix per image, calibrateCamera per
   camera, stereoCalibrate (CALIB_FIX_INTRINSIC).
2. Accuracy on views the fit never saw: frames 01-20 train, 21-25 are held
   out; every method gets THE SAME corners (camcal's detections); each
   held-out view is posed by PnP with the fitted intrinsics held, and the
   RMS is the per-corner norm over both cameras' held-out corners (px).
   Peers: OpenCV calibrateCamera (k1, k2, p1, p2, k3) + solvePnP, and mrcal
   (``mrcal-calibrate-cameras``, LENSMODEL_OPENCV8, Debian's package, run
   as its command-line tool; skipped with the reason when absent) whose
   model is posed the same way (its OPENCV8 is OpenCV's rational model).
   camcal: ``model="auto"`` (chosen on every 4th training frame; frames
   21-25 never take part) and the ``opencv`` model (the same model as
   OpenCV's), one camera at a time.
   A last row compares each pipeline with its own corners.

Prints ``name: ours X, peer Y, ratio Y/X`` (seconds: larger ratio = we are
faster; held-out px: larger ratio = we are more accurate).
"""

from __future__ import annotations

import ast
import contextlib
import io
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from camcal.cli import main
from camcal.geometry.board import frame_number, parse_board
from camcal.pipelines.board import detect_in_images
from camcal.geometry.zhang import calibrate_board
from camcal.model.rig import Rig

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stereo_chessboard"
PATTERN = (9, 6)
BOARD = parse_board("chessboard:9x6:1")
TEST = set(range(21, 26))
SIDES = ("left", "right")


def opencv_pipeline() -> float:
    """RMS of OpenCV's stereo calibration (intrinsics fixed) on the pairs it detects in both images."""
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    points = {"left": {}, "right": {}}
    for side in points:
        for path in sorted(DATA.glob(f"{side}*.jpg")):
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            found, corners = cv2.findChessboardCorners(gray, PATTERN, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if found:
                points[side][path.stem[len(side):]] = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
            size = gray.shape[::-1]
    frames = sorted(set(points["left"]) & set(points["right"]))
    grid = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0 : PATTERN[0], 0 : PATTERN[1]].T.reshape(-1, 2)
    objects = [grid] * len(frames)
    left = [points["left"][f] for f in frames]
    right = [points["right"][f] for f in frames]
    _, K_l, d_l, _, _ = cv2.calibrateCamera(objects, left, size, None, None)
    _, K_r, d_r, _, _ = cv2.calibrateCamera(objects, right, size, None, None)
    rms = cv2.stereoCalibrate(objects, left, right, K_l, d_l, K_r, d_r, size, flags=cv2.CALIB_FIX_INTRINSIC)[0]
    return float(rms)


def ours(out: Path, cache: Path | None) -> float:
    """RMS of `camcal calibrate board` (joint refinement, OpenCV distortion model)."""
    caching = ["--cache", str(cache)] if cache else ["--no-cache"]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = main([
            "calibrate", "board", "--board", "chessboard:9x6:1", "--units", "squares", "--model", "opencv",
            "--images", f"left={DATA}/left*.jpg", "--images", f"right={DATA}/right*.jpg", "--out", str(out), *caching,
        ])
    if code:
        raise SystemExit(f"camcal calibrate board failed with exit code {code}")
    cameras = Rig.load(out).cameras
    counts = [c.quality["n_observations"] for c in cameras]
    return float(np.sqrt(sum(c.quality["rms_px"] ** 2 * n for c, n in zip(cameras, counts)) / sum(counts)))


def bench_time(repeats: int = 3) -> None:
    """Best of ``repeats`` alternating runs of each (the machine is shared: the minimum is the least disturbed)."""
    t_ours, t_peer = [], []
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(repeats):
            start = time.perf_counter()
            rms_ours = ours(Path(folder) / "cold.rig.json", None)
            t_ours.append(time.perf_counter() - start)
            start = time.perf_counter()
            rms_peer = opencv_pipeline()
            t_peer.append(time.perf_counter() - start)
        t_ours, t_peer = min(t_ours), min(t_peer)
        ours(Path(folder) / "fill.rig.json", Path(folder) / "cache")
        start = time.perf_counter()
        ours(Path(folder) / "warm.rig.json", Path(folder) / "cache")
        t_warm = time.perf_counter() - start
    print(f"calibrate board, 25 stereo pairs, no cache, best of {repeats} (s): ours {t_ours:.2f}, peer {t_peer:.2f}, ratio {t_peer / t_ours:.2f}")
    print(f"calibrate board, 25 stereo pairs, corners cached (s): ours {t_warm:.2f}, peer {t_peer:.2f}, "
          f"ratio {t_peer / t_warm:.2f}")
    with tempfile.TemporaryDirectory() as folder:
        command_ours = [sys.executable, "-m", "camcal", "calibrate", "board", "--board", "chessboard:9x6:1", "--units",
                        "squares", "--model", "opencv", "--images", f"left={DATA}/left*.jpg", "--images",
                        f"right={DATA}/right*.jpg", "--out", str(Path(folder) / "cli.rig.json"), "--no-cache"]
        command_peer = [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); import bench_board; "
                        "bench_board.opencv_pipeline()", str(Path(__file__).parent)]
        p_ours, p_peer = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            subprocess.run(command_ours, check=True, capture_output=True)
            p_ours.append(time.perf_counter() - start)
            start = time.perf_counter()
            subprocess.run(command_peer, check=True, capture_output=True)
            p_peer.append(time.perf_counter() - start)
    print(f"calibrate board as a fresh process (imports included), best of {repeats} (s): ours {min(p_ours):.2f}, "
          f"peer {min(p_peer):.2f}, ratio {min(p_peer) / min(p_ours):.2f}")
    print(f"stereo RMS reprojection error, training (px): ours {rms_ours:.4f}, peer {rms_peer:.4f}, "
          f"ratio {rms_peer / rms_ours:.2f}")


# -- held-out accuracy -------------------------------------------------------------------------


def _pnp_squared(K: np.ndarray, dist: np.ndarray, views) -> tuple[float, int]:
    """Sum of squared held-out residual norms and corner count, each view posed by PnP (intrinsics held)."""
    total, count = 0.0, 0
    for d in views:
        _, rvec, tvec = cv2.solvePnP(BOARD.object_points[d.ids], d.corners_px, K, dist)
        _, rvec, tvec = cv2.solvePnP(BOARD.object_points[d.ids], d.corners_px, K, dist, rvec, tvec, True)
        projected = cv2.projectPoints(BOARD.object_points[d.ids], rvec, tvec, K, dist)[0].reshape(-1, 2)
        total += float(np.sum((projected - d.corners_px) ** 2))
        count += len(projected)
    return total, count


def _split(detections):
    train = [d for d in detections if frame_number(d.image) not in TEST]
    return train, [d for d in detections if frame_number(d.image) in TEST]


def heldout_opencv(detections) -> tuple[float, float]:
    """Training and held-out RMS of calibrateCamera per camera (default model k1, k2, p1, p2, k3)."""
    held_sq, held_n, train_sq, train_n = 0.0, 0, 0.0, 0
    for side in SIDES:
        train, held = _split(detections[side])
        rms, K, dist, _, _ = cv2.calibrateCamera(
            [BOARD.object_points[d.ids].astype(np.float32) for d in train],
            [d.corners_px.astype(np.float32) for d in train], train[0].image_size, None, None)
        train_sq += rms**2 * sum(len(d.ids) for d in train)  # OpenCV's RMS is per corner norm
        train_n += sum(len(d.ids) for d in train)
        s, n = _pnp_squared(K, dist, held)
        held_sq, held_n = held_sq + s, held_n + n
    return float(np.sqrt(train_sq / train_n)), float(np.sqrt(held_sq / held_n))


def heldout_camcal(detections, model: str) -> tuple[float, float, str]:
    """Training and held-out RMS of camcal's calibration per camera; the models it used."""
    held_sq, held_n, train_sq, train_n, models = 0.0, 0, 0.0, 0, []
    for side in SIDES:
        result = calibrate_board(BOARD, {side: detections[side]}, model=model, holdout=TEST)
        n_held = sum(len(d.ids) for d in _split(detections[side])[1])
        held_sq += result.heldout_rms_px**2 * n_held
        held_n += n_held
        train_sq += result.rms_px**2 * len(result.residuals_px)
        train_n += len(result.residuals_px)
        models.append(result.model)
    return float(np.sqrt(train_sq / train_n)), float(np.sqrt(held_sq / held_n)), "/".join(models)


def heldout_mrcal(detections) -> tuple[float, float] | str:
    """Training and held-out RMS of mrcal (LENSMODEL_OPENCV8) per camera, or why it was skipped."""
    tool = shutil.which("mrcal-calibrate-cameras")
    if tool is None:
        return "mrcal-calibrate-cameras not installed (apt-get install mrcal)"
    held_sq, held_n, train_sq, train_n = 0.0, 0, 0.0, 0
    with tempfile.TemporaryDirectory() as folder:
        for side in SIDES:
            train, held = _split(detections[side])
            out = Path(folder) / side
            out.mkdir()
            corners = out / "corners.vnl"
            with corners.open("w") as f:
                f.write("# filename x y level\n")
                for d in train:
                    for x, y in d.corners_px[np.argsort(d.ids)]:
                        f.write(f"{d.image} {x:.6f} {y:.6f} 0\n")
            width, height = train[0].image_size
            run = subprocess.run(
                [tool, "--corners-cache", str(corners), "--lensmodel", "LENSMODEL_OPENCV8", "--focal", "500",
                 "--object-spacing", "1", "--object-width-n", str(PATTERN[0]), "--object-height-n", str(PATTERN[1]),
                 "--imagersize", str(width), str(height), "--outdir", str(out), f"{side}*.jpg"],
                capture_output=True, text=True, cwd=DATA)
            if run.returncode:
                return f"mrcal-calibrate-cameras failed: {run.stderr.strip().splitlines()[-1:]}"
            model = ast.literal_eval((out / "camera-0.cameramodel").read_text())
            intrinsics = np.asarray(model["intrinsics"], dtype=np.float64)
            K = np.array([[intrinsics[0], 0, intrinsics[2]], [0, intrinsics[1], intrinsics[3]], [0, 0, 1]])
            dist = intrinsics[4:]
            s, n = _pnp_squared(K, dist, train)  # training RMS with the poses re-fitted (mrcal also fits board warp)
            train_sq, train_n = train_sq + s, train_n + n
            s, n = _pnp_squared(K, dist, held)
            held_sq, held_n = held_sq + s, held_n + n
    return float(np.sqrt(train_sq / train_n)), float(np.sqrt(held_sq / held_n))


def heldout_own_corners(detections) -> tuple[float, float]:
    """Held-out RMS of each pipeline with its own corners: OpenCV's classic corners vs camcal's."""
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    theirs = {}
    for side in SIDES:
        views = []
        for d in detections[side]:
            gray = cv2.imread(str(DATA / d.image), cv2.IMREAD_GRAYSCALE)
            found, corners = cv2.findChessboardCorners(gray, PATTERN, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not found:
                continue
            corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
            # OpenCV's own order for this view, matched to camcal's labelling of the same corners
            order = np.argmin(np.linalg.norm(corners[:, None] - d.corners_px[None], axis=2), axis=0)
            views.append(type(d)(d.image, d.image_size, d.ids, corners[order], "classic"))
        theirs[side] = views
    return heldout_opencv(theirs)[1], heldout_camcal(detections, "auto")[1]


def bench_heldout() -> None:
    detections = {side: detect_in_images(BOARD, sorted(DATA.glob(f"{side}*.jpg")), workers=2).detections
                  for side in SIDES}
    cv_train, cv_held = heldout_opencv(detections)
    auto_train, auto_held, models = heldout_camcal(detections, "auto")
    same_train, same_held, _ = heldout_camcal(detections, "opencv")
    print(f"held-out RMS, frames 21-25, same corners (px): ours {auto_held:.4f} (model auto: {models}; "
          f"training {auto_train:.4f}), peer OpenCV {cv_held:.4f} (training {cv_train:.4f}), ratio {cv_held / auto_held:.3f}")
    print(f"held-out RMS, same corners, same model opencv (px): ours {same_held:.4f} (training {same_train:.4f}), "
          f"peer OpenCV {cv_held:.4f}, ratio {cv_held / same_held:.3f}")
    mrcal = heldout_mrcal(detections)
    if isinstance(mrcal, str):
        print(f"held-out RMS vs mrcal: skipped ({mrcal})")
    else:
        print(f"held-out RMS, same corners (px): ours {auto_held:.4f}, peer mrcal LENSMODEL_OPENCV8 {mrcal[1]:.4f} "
              f"(training {mrcal[0]:.4f}), ratio {mrcal[1] / auto_held:.3f}")
    own_cv, own_ours = heldout_own_corners(detections)
    print(f"held-out RMS, each pipeline with its own corners (px): ours {own_ours:.4f}, "
          f"peer OpenCV (findChessboardCorners + cornerSubPix 5x5) {own_cv:.4f}, ratio {own_cv / own_ours:.3f}")


def main_bench() -> int:
    if not DATA.is_dir():
        print(f"skipped: real images not found at {DATA}", file=sys.stderr)
        return 0
    bench_time()
    bench_heldout()
    return 0


if __name__ == "__main__":
    raise SystemExit(main_bench())
