"""Time `camcal calibrate board` on the real stereo pairs against OpenCV's pipeline.

OpenCV's pipeline on the same images: findChessboardCorners + cornerSubPix per
image, calibrateCamera per camera, stereoCalibrate (CALIB_FIX_INTRINSIC).
Prints ``name: ours X, peer Y, ratio Y/X`` (seconds) and the RMS of both.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from camcal.cli import main
from camcal.rig import Rig

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stereo_chessboard"
PATTERN = (9, 6)


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


def ours(out: Path) -> float:
    """RMS of `camcal calibrate board` (joint refinement, OpenCV distortion model)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = main([
            "calibrate", "board", "--board", "chessboard:9x6:1", "--units", "squares", "--model", "opencv",
            "--camera", f"left={DATA}/left*.jpg", "--camera", f"right={DATA}/right*.jpg", "--out", str(out),
        ])
    if code:
        raise SystemExit(f"camcal calibrate board failed with exit code {code}")
    cameras = Rig.load(out).cameras
    counts = [c.quality["n_points"] for c in cameras]
    return float(np.sqrt(sum(c.quality["rms_px"] ** 2 * n for c, n in zip(cameras, counts)) / sum(counts)))


def main_bench() -> int:
    if not DATA.is_dir():
        print(f"skipped: real images not found at {DATA}", file=sys.stderr)
        return 0
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        rms_ours = ours(Path(folder) / "stereo.rig.json")
        t_ours = time.perf_counter() - start
    start = time.perf_counter()
    rms_peer = opencv_pipeline()
    t_peer = time.perf_counter() - start
    print(f"calibrate board, 25 stereo pairs (s): ours {t_ours:.2f}, peer {t_peer:.2f}, ratio {t_peer / t_ours:.2f}")
    print(f"stereo RMS reprojection error (px): ours {rms_ours:.4f}, peer {rms_peer:.4f}, ratio {rms_peer / rms_ours:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_bench())
