"""4K ST-map generation: camcal against OpenCV on the same lens.

- undistort map (for every undistorted pixel, the plate pixel to sample:
  the forward model): camcal's ``st_of_distorted_grid`` (the ST values,
  ready to write) against ``cv2.initUndistortRectifyMap`` (two float32 maps
  of pixel positions) with the same ``K`` and coefficients;
- redistort map (for every plate pixel, the undistorted pixel: the
  model's inverse): camcal's ``make_stmaps`` inverse against
  ``cv2.undistortPoints`` (20 iterations or 1e-12) on every plate pixel.

Each side runs ``REPEATS`` times (the slower inverse ``INVERSE_REPEATS``), interleaved; the best of each is kept
(the machine may be shared). Prints ``name: ours X s, peer Y s, ratio Y/X``
(above 1: camcal is faster) and camcal's map against OpenCV's in pixels.
"""

import time

import cv2
import numpy as np

from camcal.geometry.stmap import undistorted_grid, pixels_from_st, st_of_distorted_grid
from camcal.model.distortion import Distortion

SIZE = (3840, 2160)
REPEATS = 15
INVERSE_REPEATS = 2
PARAMS = {"k1": -0.15, "k2": 0.04, "p1": 0.0005, "p2": -0.0003, "k3": -0.004}
K = np.array([[2900.0, 0.0, 1925.3], [0.0, 2900.0, 1076.8], [0.0, 0.0, 1.0]])


def best_of(runs: dict, repeats: int = REPEATS) -> dict:
    """The best time of each named callable over ``repeats`` interleaved rounds, and its last result."""
    times = {name: np.inf for name in runs}
    results = {}
    for _ in range(repeats):
        for name, run in runs.items():
            start = time.perf_counter()
            results[name] = run()
            times[name] = min(times[name], time.perf_counter() - start)
    return {name: (times[name], results[name]) for name in runs}


def main() -> None:
    width, height = SIZE
    lens = Distortion("opencv", PARAMS)
    coefficients = np.array([PARAMS[name] for name in ("k1", "k2", "p1", "p2", "k3")])
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)

    forward = best_of({
        "ours": lambda: st_of_distorted_grid(lens, K, xs, ys, SIZE),
        "peer": lambda: cv2.initUndistortRectifyMap(K, coefficients, None, K, SIZE, cv2.CV_32FC1),
    })
    (ours, st), (peer, (map_x, map_y)) = forward["ours"], forward["peer"]
    x, y = pixels_from_st(st, SIZE)
    agree = np.hypot(x - map_x, y - map_y).max()
    print(f"undistort map {width}x{height} (forward model): ours {ours:.4f} s, "
          f"peer cv2.initUndistortRectifyMap {peer:.4f} s, ratio {peer / ours:.2f}; "
          f"maps agree to {agree:.1e} px")

    u, v = np.meshgrid(xs, ys)
    plate = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)
    inverse = best_of({
        "ours": lambda: undistorted_grid(lens, K, SIZE),
        "peer": lambda: cv2.undistortPoints(plate, K, coefficients, None, None, K, criteria),
    }, INVERSE_REPEATS)
    (ours, (x_u, y_u)), (peer, points) = inverse["ours"], inverse["peer"]
    points = points.reshape(height, width, 2)
    agree = np.hypot(x_u - points[..., 0], y_u - points[..., 1]).max()
    print(f"redistort map {width}x{height} (inverse model): ours {ours:.4f} s, "
          f"peer cv2.undistortPoints {peer:.4f} s, ratio {peer / ours:.2f}; maps agree to {agree:.1e} px")


if __name__ == "__main__":
    main()
