"""Rolling-shutter plates with a known readout: points imaged on the row whose read-out time put them there.

A camera follows a smooth path (a handheld pan and tilt while walking, the
same pan while walking slowly, a sideways dolly, a forward drive); each point of a frame at time ``t_k`` is
imaged from the camera at ``t_k + T (y / (H - 1) - 1/2)``, ``y`` the row it
lands on (found by fixed-point iteration, the exact rolling-shutter image
of Meingast et al. 2005, not the first-order model the estimator fits).
The solve's answer is imitated by the true frame poses and points with a
small perturbation, or (:func:`global_shutter_solve`) by a global-shutter
bundle adjustment from there, which absorbs what it can of the shutter's
shear into the path and the points, as a solve does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.geometry.rolling_shutter_ba import _Model
from camcal.model.camera import look_at

WIDTH, HEIGHT, FOCAL = 640, 360, 500.0
K = np.array([[FOCAL, 0.0, 319.5], [0.0, FOCAL, 179.5], [0.0, 0.0, 1.0]])
_FORWARD = look_at(np.zeros(3), [0.0, 0.0, 1.0], up=(0.0, -1.0, 0.0))


@dataclass(frozen=True)
class Plate:
    """A synthetic plate: the perturbed solve (poses, points) and the observations (pinhole pixels, rows)."""

    rotations: np.ndarray
    centres: np.ndarray
    times: np.ndarray
    points: np.ndarray
    frame_of: np.ndarray
    point_of: np.ndarray
    pixels: np.ndarray
    rows: np.ndarray
    true_rotations: np.ndarray
    true_centres: np.ndarray
    true_points: np.ndarray

    def estimate_arguments(self) -> tuple:
        """The positional arguments of :func:`camcal.geometry.rolling_shutter_ba.estimate_readout`."""
        return (K, HEIGHT, self.rotations, self.centres, self.times, self.points, self.frame_of, self.point_of,
                self.pixels, self.rows)


def pose(t: np.ndarray | float, motion: str) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera rotations and centres at times ``t`` of a ``"turning"``, ``"shaking"``, ``"slow"``,
    ``"sideways"`` or ``"forward"`` path."""
    t = np.asarray(t, dtype=np.float64)
    zero = np.zeros_like(t)
    if motion == "slow":  # the turning walk at 0.3 times the pace (0.13 m/s): the same pan, a third of the parallax
        R, centres = pose(t, "turning")
        return R, 0.3 * centres
    if motion in ("turning", "shaking"):  # walking with a handheld pan (up to 75 deg/s), tilt and roll
        angles = np.stack([0.12 * np.sin(2 * np.pi * 1.1 * t), 0.35 * np.sin(2 * np.pi * 0.6 * t),
                           0.05 * np.sin(2 * np.pi * 0.9 * t)], -1)
        if motion == "shaking":  # and a hand's tremor at 3 Hz: the velocity changes much within a frame interval
            angles += np.stack([0.02 * np.sin(2 * np.pi * 3.0 * t + 1.0), 0.03 * np.sin(2 * np.pi * 2.7 * t),
                                zero], -1)
        centres = np.stack([0.4 * t, 0.03 * np.sin(2 * np.pi * 1.3 * t), 0.2 * t], -1)
    elif motion == "sideways":  # a dolly along the set at 1 m/s, no turn
        angles, centres = np.stack([zero] * 3, -1), np.stack([1.0 * t, zero, zero], -1)
    else:  # driving straight ahead at 3 m/s
        angles, centres = np.stack([zero] * 3, -1), np.stack([zero, zero, 3.0 * t], -1)
    return Rotation.from_rotvec(angles).as_matrix() @ _FORWARD, centres


def plate(readout_s: float, motion: str, seed: int, n_frames: int = 12, n_points: int = 100, fps: float = 30.0,
          noise_px: float = 0.5, lens=None) -> Plate:
    """A plate of ``motion`` read out in ``readout_s``; observations with Gaussian noise of ``noise_px``.

    ``lens``: a ``pycolmap.Camera`` whose distortion images the points (its pixel centres at 0.5, returned at 0);
    the returned ``pixels`` are then the distorted ones and ``rows`` the same rows. Without it, a pinhole ``K``.
    """
    rng = np.random.default_rng(seed)
    times = np.arange(n_frames) / fps
    X = rng.uniform([-6.0, -3.0, 5.0], [8.0, 3.0, 14.0], (n_points, 3))

    def image(x: np.ndarray) -> np.ndarray:
        if lens is None:
            return x[:, :2] / x[:, 2:] * FOCAL + K[:2, 2]
        return np.asarray(lens.img_from_cam(np.ascontiguousarray(x)), dtype=np.float64) - 0.5

    frame_of, point_of, pixels = [], [], []
    for k, t in enumerate(times):
        R, c = pose(t, motion)
        uv = image((X - c) @ R.T)
        for _ in range(20):
            R_row, c_row = pose(t + readout_s * (uv[:, 1] / (HEIGHT - 1) - 0.5), motion)
            x = np.einsum("nij,nj->ni", R_row, X - c_row)
            uv = image(x)
        seen = (x[:, 2] > 0) & np.all((uv >= 0) & (uv <= [WIDTH - 1, HEIGHT - 1]), axis=1)
        frame_of += [k] * int(seen.sum())
        point_of += list(np.flatnonzero(seen))
        pixels.append(uv[seen])
    pixels = np.concatenate(pixels) + rng.normal(0.0, noise_px, (len(frame_of), 2))
    R_true, c_true = pose(times, motion)
    rotations = Rotation.from_rotvec(rng.normal(0.0, 0.002, (n_frames, 3))).as_matrix() @ R_true
    return Plate(rotations, c_true + rng.normal(0.0, 0.01, c_true.shape), times,
                 X + rng.normal(0.0, 0.02, X.shape), np.array(frame_of), np.array(point_of), pixels,
                 pixels[:, 1].copy(), R_true, c_true, X)


def global_shutter_solve(synthetic: Plate) -> Plate:
    """``synthetic`` with its poses and points replaced by a global-shutter bundle adjustment's from them: every
    observation imaged from its frame's pose (the rolling-shutter adjustment's own Levenberg-Marquardt with the
    readout held at 0, the first frame's pose and one coordinate of the last centre held)."""
    seen, point_of = np.unique(synthetic.point_of, return_inverse=True)
    n = len(point_of)
    model = _Model(np.full((n, 2), FOCAL), np.broadcast_to(K[:2, 2], (n, 2)), synthetic.times, synthetic.frame_of,
                   point_of, synthetic.pixels, np.zeros(n))
    R, c, X = model.adjust(synthetic.rotations, synthetic.centres, synthetic.points[seen], 0.0, hold_readout=True,
                           jacobian=False).state()
    points = synthetic.points.copy()
    points[seen] = X
    return replace(synthetic, rotations=R, centres=c, points=points)
