"""Rectifying a 4096x2160 stereo pair: camcal's one-remap maps vs OpenCV's.

Both sides build the per-camera maps (undistortion + rectification in one
resampling) and remap one 8-bit RGB image per camera. camcal:
``rectify_calibrated`` + :class:`RectifyWarper` (``build_maps`` +
``cv2.remap``); OpenCV: ``cv2.stereoRectify`` + ``cv2.initUndistortRectifyMap``
(float maps) + ``cv2.remap``, on the same calibration.

Prints ``name: ours X, peer Y, ratio Y/X`` (seconds, best of 3).
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from camcal.model.distortion import Distortion
from camcal.geometry.rectify import RectifyWarper, rectify_calibrated
from camcal.model.rig import Camera, Rig

SIZE = (4096, 2160)
REPEATS = 3


def make_rig() -> tuple[Rig, list[tuple[np.ndarray, np.ndarray]]]:
    params = {"k1": -0.08, "k2": 0.02, "p1": 2e-4, "p2": -1e-4, "k3": 0.0}
    K = np.array([[3200.0, 0.0, 2050.0], [0.0, 3195.0, 1075.0], [0.0, 0.0, 1.0]])
    R_right = Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix()
    cameras = (
        Camera("left", SIZE, K, Distortion("opencv", params), np.eye(3), np.zeros(3)),
        Camera("right", SIZE, K, Distortion("opencv", params), R_right, np.array([0.12, 0.001, 0.0])),
    )
    D = np.array([params[k] for k in ("k1", "k2", "p1", "p2", "k3")])
    return Rig(cameras), [(K, D), (K, D)]


def best_of(function) -> float:
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    rig, opencv = make_rig()
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (SIZE[1], SIZE[0], 3), dtype=np.uint8) for _ in range(2)]
    result = rectify_calibrated(rig, alpha=0.0)

    def ours() -> None:
        warper = RectifyWarper(result.rig)
        for name, image in zip(("left", "right"), images):
            warper.warp(name, image)

    left, right = rig.cameras
    R = right.R  # right_from_left, the left camera at the origin
    T = -R @ right.c
    (K1, D1), (K2, D2) = opencv
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), alpha=0.0)  # OpenCV 5: 3x1, not 1-D

    def peer() -> None:
        for (K, D, Rr, P), image in zip(((K1, D1, R1, P1), (K2, D2, R2, P2)), images):
            map_x, map_y = cv2.initUndistortRectifyMap(K, D, Rr, P, SIZE, cv2.CV_32FC1)
            cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    ours_s, peer_s = best_of(ours), best_of(peer)
    print(f"rectify 4096x2160 stereo pair (build maps + remap): ours {ours_s:.3f} s, "
          f"peer {peer_s:.3f} s, ratio {peer_s / ours_s:.3f}")

    warper = RectifyWarper(result.rig)
    for name in ("left", "right"):
        warper.maps(name)

    def ours_cached() -> None:
        for name, image in zip(("left", "right"), images):
            warper.warp(name, image)

    maps = [cv2.initUndistortRectifyMap(K, D, Rr, P, SIZE, cv2.CV_32FC1)
            for K, D, Rr, P in ((K1, D1, R1, P1), (K2, D2, R2, P2))]

    def peer_cached() -> None:
        for (map_x, map_y), image in zip(maps, images):
            cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    ours_s, peer_s = best_of(ours_cached), best_of(peer_cached)
    print(f"remap a 4096x2160 stereo pair with cached maps: ours {ours_s:.3f} s, "
          f"peer {peer_s:.3f} s, ratio {peer_s / ours_s:.3f}")


if __name__ == "__main__":
    main()
