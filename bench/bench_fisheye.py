"""Kannala-Brandt (fisheye) point mappings and undistortion maps against OpenCV's fisheye module.

On one wide lens (1920x1080, about 190 degrees across the diagonal), in the
same run:

- ``undistort points``: :meth:`Distortion.undistort` on every pixel of the
  frame against ``cv2.fisheye.undistortPoints`` (criteria 20 iterations,
  1e-12), with the largest round-trip error of each (distort the result
  again with camcal's exact forward model, only where OpenCV's inverse is
  defined: theta_d < pi / 2, rays in front of the camera);
- ``project rays``: :meth:`Distortion.project_rays` against
  ``cv2.fisheye.projectPoints`` on one million rays;
- ``undistort maps``: :func:`camcal.geometry.undistort.make_undistorter`
  (crop, 120-degree default field of view) against
  ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` +
  ``cv2.fisheye.initUndistortRectifyMap`` (the plain OpenCV recipe).

Prints ``name: ours X, peer Y, ratio Y/X``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from camcal.model.distortion import Distortion
from camcal.geometry.undistort import make_undistorter
from camcal.model.rig import Camera

SIZE = (1920, 1080)
K = np.array([[560.0, 0.0, 962.4], [0.0, 558.7, 537.9], [0.0, 0.0, 1.0]])
LENS = Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021})
D = np.array([LENS.params[k] for k in ("k1", "k2", "k3", "k4")])


def best_of(function, repeats=3):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> None:
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=np.float64), np.arange(SIZE[1], dtype=np.float64))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    ours_t, ours = best_of(lambda: LENS.undistort(pixels, K))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)
    peer_t, peer = best_of(lambda: cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2), K, D, P=K,
                                                                criteria=criteria).reshape(-1, 2))
    theta_d = np.hypot(*((pixels - K[:2, 2]) / np.diag(K)[:2]).T)
    usable = np.all(np.isfinite(ours), axis=1) & (theta_d < 0.5 * np.pi)
    ours_rt = np.abs(LENS.distort(ours[usable], K) - pixels[usable]).max()
    peer_rt = np.abs(LENS.distort(peer[usable], K) - pixels[usable]).max()
    print(f"undistort points ({len(pixels)} px, {usable.sum()} in front): ours {ours_t:.3f} s, "
          f"peer {peer_t:.3f} s, ratio {peer_t / ours_t:.2f}; round trip ours {ours_rt:.1e} px, "
          f"peer {peer_rt:.1e} px")

    rng = np.random.default_rng(0)
    rays = rng.normal(size=(1_000_000, 3))
    rays[:, 2] = np.abs(rays[:, 2]) + 0.05
    ours_t, ours = best_of(lambda: LENS.project_rays(rays, K))
    peer_t, peer = best_of(lambda: cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0])
    print(f"project rays (1e6): ours {ours_t:.3f} s, peer {peer_t:.3f} s, ratio {peer_t / ours_t:.2f}; "
          f"max difference {np.abs(ours - peer.reshape(-1, 2)).max():.1e} px")

    camera = Camera("fish", SIZE, K, LENS, np.eye(3), np.zeros(3))

    def opencv_recipe():
        K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, SIZE, np.eye(3), balance=0.0)
        return cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K_new, SIZE, cv2.CV_32FC1)

    ours_t, _ = best_of(lambda: make_undistorter(camera, "crop"))
    peer_t, _ = best_of(opencv_recipe)
    print(f"undistort maps {SIZE[0]}x{SIZE[1]} (crop): ours {ours_t:.3f} s, peer {peer_t:.3f} s, "
          f"ratio {peer_t / ours_t:.2f}")


if __name__ == "__main__":
    main()
