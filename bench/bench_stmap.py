"""4K ST-map generation: camcal against OpenCV on the same lens.

- undistort map (for every undistorted pixel, the plate pixel to sample:
  the forward model): camcal's ``st_of_distorted_grid`` (the ST values,
  ready to write) against ``cv2.initUndistortRectifyMap`` (two float32 maps
  of pixel positions) with the same ``K`` and coefficients;
- redistort map (for every plate pixel, the undistorted pixel: the
  model's inverse): camcal's ``make_stmaps`` inverse against
  ``cv2.undistortPoints`` (20 iterations or 1e-12) on every plate pixel;
- a fisheye's undistort map (Kannala-Brandt) against
  ``cv2.fisheye.initUndistortRectifyMap``.

Each side runs ``REPEATS`` times (the slower inverse ``INVERSE_REPEATS``),
interleaved; the best of each is kept (the machine may be shared), wall
time and CPU time. Prints ``name: ours X s, peer Y s, ratio Y/X`` (above 1:
camcal is faster) and camcal's map against OpenCV's in pixels.
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
FISHEYE = {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}
K_FISHEYE = np.array([[1100.0, 0.0, 1925.3], [0.0, 1100.0, 1076.8], [0.0, 0.0, 1.0]])


def best_of(runs: dict, repeats: int = REPEATS) -> dict:
    """Per named callable over ``repeats`` interleaved rounds: (best wall time, best CPU time of all threads, result).

    The CPU time (``time.process_time``, every thread of the process) is the
    work done, which other load on a shared machine disturbs less than the
    wall time.
    """
    wall = {name: np.inf for name in runs}
    cpu = {name: np.inf for name in runs}
    results = {}
    for _ in range(repeats):
        for name, run in runs.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            results[name] = run()
            wall[name] = min(wall[name], time.perf_counter() - start)
            cpu[name] = min(cpu[name], time.process_time() - start_cpu)
    return {name: (wall[name], cpu[name], results[name]) for name in runs}


def line(name: str, peer_name: str, timings: dict, agree: float) -> str:
    """``name: ours X s (CPU x s), peer Y s (CPU y s), ratio Y/X (CPU y/x); maps agree to ... px``."""
    (ours, ours_cpu, _), (peer, peer_cpu, _) = timings["ours"], timings["peer"]
    return (f"{name}: ours {ours:.4f} s (CPU {ours_cpu:.4f} s), peer {peer_name} {peer:.4f} s (CPU {peer_cpu:.4f} s), "
            f"ratio {peer / ours:.2f} (CPU {peer_cpu / ours_cpu:.2f}); maps agree to {agree:.1e} px")


def main() -> None:
    width, height = SIZE
    lens = Distortion("opencv", PARAMS)
    coefficients = np.array([PARAMS[name] for name in ("k1", "k2", "p1", "p2", "k3")])
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)

    forward = best_of({
        "ours": lambda: st_of_distorted_grid(lens, K, xs, ys, SIZE),
        "peer": lambda: cv2.initUndistortRectifyMap(K, coefficients, None, K, SIZE, cv2.CV_32FC1),
    })
    st, (map_x, map_y) = forward["ours"][2], forward["peer"][2]
    x, y = pixels_from_st(st, SIZE)
    agree = np.hypot(x - map_x, y - map_y).max()
    print(line(f"undistort map {width}x{height} (opencv, forward)", "cv2.initUndistortRectifyMap", forward, agree))

    fisheye = Distortion("kannala-brandt", FISHEYE)
    fisheye_coefficients = np.array([FISHEYE[name] for name in ("k1", "k2", "k3", "k4")])
    forward = best_of({
        "ours": lambda: st_of_distorted_grid(fisheye, K_FISHEYE, xs, ys, SIZE),
        "peer": lambda: cv2.fisheye.initUndistortRectifyMap(K_FISHEYE, fisheye_coefficients, None, K_FISHEYE, SIZE,
                                                            cv2.CV_32FC1),
    })
    st, (map_x, map_y) = forward["ours"][2], forward["peer"][2]
    x, y = pixels_from_st(st, SIZE)
    agree = np.nanmax(np.hypot(x - map_x, y - map_y))
    print(line(f"fisheye undistort map {width}x{height} (kannala-brandt, forward)",
               "cv2.fisheye.initUndistortRectifyMap", forward, agree))

    u, v = np.meshgrid(xs, ys)
    plate = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)
    inverse = best_of({
        "ours": lambda: undistorted_grid(lens, K, SIZE),
        "peer": lambda: cv2.undistortPoints(plate, K, coefficients, None, None, K, criteria),
    }, INVERSE_REPEATS)
    (x_u, y_u), points = inverse["ours"][2], inverse["peer"][2].reshape(height, width, 2)
    agree = np.hypot(x_u - points[..., 0], y_u - points[..., 1]).max()
    print(line(f"redistort map {width}x{height} (opencv, inverse)", "cv2.undistortPoints", inverse, agree))


if __name__ == "__main__":
    main()
