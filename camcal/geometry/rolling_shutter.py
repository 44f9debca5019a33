"""Rolling shutter: how far the camera's motion during the sensor's readout moves a frame's image.

A rolling-shutter sensor exposes its rows one after another: row ``y`` of a
frame of ``H`` rows is taken at

    tau(y) = T_r (y / (H - 1) - 1/2)

around the frame's time (its middle row), ``T_r`` the readout time (top row
to bottom row). A camera moving with angular velocity ``omega`` (rad/s, in
the camera's axes) and linear velocity ``v`` (world units/s) sees a point
``X`` at camera coordinates ``x = R (X - c)`` move as

    dx/dt = omega x x - R v

(``R(t) = exp(t [omega]_x) R``, ``c(t) = c + t v``), and its pinhole image
``u = K (x / z)`` as

    du/dt = K_2x2 ((dx/dt)_xy z - x_xy (dx/dt)_z) / z^2.

To first order in ``T_r`` the rolling shutter then moves the point's image by

    delta(X) = du/dt * tau(y)

from where a global shutter at the frame's time puts it: the error a
global-shutter solve leaves in that frame. Per frame the largest
``|delta|`` over its points (the top and bottom rows move most; the
rotation's part does not depend on depth, the translation's falls as
``1 / z``) is compared with a threshold in pixels.

The velocities come from the solved neighbouring frames (central
differences of the poses over their times; second-order one-sided at the ends):
``omega = log(R_next R_prev^T) / (t_next - t_prev)``.

References
----------
Meingast, M., Geyer, C. & Sastry, S. (2005). Geometric Models of
Rolling-Shutter Cameras. OMNIVIS (the row-time projection model).
Hedborg, J., Forssen, P.-E., Felsberg, M. & Ringaby, E. (2012). Rolling
Shutter Bundle Adjustment. CVPR (constant velocity over a frame's readout).
Richardson, L. F. (1911). The approximate arithmetical solution by finite
differences of physical problems. Phil. Trans. R. Soc. A 210 (the
extrapolation of :func:`camera_velocities`' fourth order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError

__all__ = ["ShutterFrame", "camera_velocities", "image_velocities", "readout_displacements", "rolling_shutter_frames"]


@dataclass(frozen=True)
class ShutterFrame:
    """The rolling shutter's effect on one frame.

    Attributes
    ----------
    displacement_px : float
        The largest image displacement of the frame's points between their
        row's time and the frame's time (0 without points).
    rotation_deg_per_s, speed : float
        The camera's angular speed (deg/s) and linear speed (world units/s) at the frame.
    flagged : bool
        ``displacement_px`` above the threshold.
    """

    displacement_px: float
    rotation_deg_per_s: float
    speed: float
    flagged: bool


def camera_velocities(rotations: ArrayLike, centres: ArrayLike, times: ArrayLike, *, order: int = 2
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each frame's angular velocity (camera axes, rad/s) and linear velocity (world units/s) from its neighbours.

    Parameters
    ----------
    rotations : array_like, shape (N, 3, 3)
        World -> camera rotation of each frame, in time order.
    centres : array_like, shape (N, 3)
        Camera centres in world coordinates.
    times : array_like, shape (N,)
        Each frame's time in seconds, strictly increasing.
    order : {2, 4}
        4: at a frame whose two neighbours on each side lie at ``+-h`` and ``+-2h``, the Richardson
        extrapolation ``(4 D(h) - D(2h)) / 3`` of the central differences over them (``D(h) = log(R(t + h)
        R(t - h)^T) / 2h`` is even in ``h``: the ``h^2`` term cancels, leaving an error of order ``h^4``;
        Richardson 1911); elsewhere the second-order ones.

    Returns
    -------
    omega, velocity : ndarray, shape (N, 3)
        ``omega = log(R_b R_a^T) / (t_b - t_a)`` and ``(c_b - c_a) / (t_b - t_a)``
        with ``a, b`` the frame's neighbours; zero for a single frame. At an end
        ``e`` with its next two frames ``1, 2`` at ``h_1, h_2`` from it, the
        second-order one-sided difference ``w_1 d_1 + w_2 d_2``,
        ``w_1 = h_2 / (h_1 (h_2 - h_1))``, ``w_2 = -h_1 / (h_2 (h_2 - h_1))``,
        ``d_i = log(R_i R_e^T)`` or ``c_i - c_e`` (exact for constant velocity, like
        the central one, whose error on a turning camera it matches to
        ``O(dt^2)``); with two frames the first-order one.
    """
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if not (len(R) == len(c) == len(t)):
        raise CamcalError(f"rotations, centres and times differ in length ({len(R)}, {len(c)}, {len(t)})")
    if np.any(np.diff(t) <= 0):
        raise CamcalError("frame times must increase strictly")
    if order not in (2, 4):
        raise CamcalError(f"the velocities' order must be 2 or 4, got {order}")
    n = len(t)
    omega, velocity = np.zeros((n, 3)), np.zeros((n, 3))
    if n < 2:
        return omega, velocity
    before = np.maximum(np.arange(n) - 1, 0)
    after = np.minimum(np.arange(n) + 1, n - 1)
    dt = t[after] - t[before]
    relative = np.einsum("nij,nkj->nik", R[after], R[before])  # R_b R_a^T
    omega = Rotation.from_matrix(relative).as_rotvec() / dt[:, None]
    velocity = (c[after] - c[before]) / dt[:, None]
    if n >= 3:
        for end, near, far in ((0, 1, 2), (n - 1, n - 2, n - 3)):
            h1, h2 = t[near] - t[end], t[far] - t[end]
            w1, w2 = h2 / (h1 * (h2 - h1)), -h1 / (h2 * (h2 - h1))
            turns = Rotation.from_matrix(R[[near, far]] @ R[end].T).as_rotvec()
            omega[end] = w1 * turns[0] + w2 * turns[1]
            velocity[end] = w1 * (c[near] - c[end]) + w2 * (c[far] - c[end])
    if order == 4 and n >= 5:
        middle = np.arange(2, n - 2)
        h = t[middle + 1] - t[middle]
        even = np.isclose(t[middle] - t[middle - 1], h) & np.isclose(t[middle + 2] - t[middle + 1], h) & np.isclose(
            t[middle - 1] - t[middle - 2], h)
        middle = middle[even]
        wide = np.einsum("nij,nkj->nik", R[middle + 2], R[middle - 2])
        omega_wide = Rotation.from_matrix(wide).as_rotvec() / (t[middle + 2] - t[middle - 2])[:, None]
        velocity_wide = (c[middle + 2] - c[middle - 2]) / (t[middle + 2] - t[middle - 2])[:, None]
        omega[middle] = (4.0 * omega[middle] - omega_wide) / 3.0
        velocity[middle] = (4.0 * velocity[middle] - velocity_wide) / 3.0
    return omega, velocity


def image_velocities(K: ArrayLike, R: ArrayLike, c: ArrayLike, omega: ArrayLike, velocity: ArrayLike,
                     points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pinhole pixels of ``points`` and their velocities (px/s) under the camera's motion.

    Returns
    -------
    pixels, pixel_velocity : ndarray, shape (N, 2)
        ``K (x / z)`` and ``K_2x2 (dx_xy z - x_xy dz) / z^2`` with ``dx = omega x x - R v`` (module notes);
        NaN for points at or behind the camera plane.
    """
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x = (X - np.asarray(c, dtype=np.float64)) @ R.T
    dx = np.cross(np.asarray(omega, dtype=np.float64), x) - R @ np.asarray(velocity, dtype=np.float64)
    z = np.where(x[:, 2] > 0, x[:, 2], np.nan)[:, None]
    normalised = x[:, :2] / z
    rate = (dx[:, :2] * z - x[:, :2] * dx[:, 2:3]) / z ** 2
    return normalised @ K[:2, :2].T + K[:2, 2], rate @ K[:2, :2].T


def readout_displacements(K: ArrayLike, height: int, R: ArrayLike, c: ArrayLike, omega: ArrayLike,
                          velocity: ArrayLike, points: ArrayLike, readout_s: float) -> NDArray[np.float64]:
    """Each point's image displacement (px, shape (N, 2)) between its row's time and the frame's (module notes).

    ``delta = du/dt * tau(y)``, ``tau(y) = T_r (y / (H - 1) - 1/2)``, ``y`` the point's global-shutter row.
    """
    pixels, rate = image_velocities(K, R, c, omega, velocity, points)
    tau = readout_s * (pixels[:, 1:2] / max(int(height) - 1, 1) - 0.5)
    return rate * tau


def rolling_shutter_frames(K: ArrayLike | Sequence[ArrayLike], height: int, rotations: ArrayLike, centres: ArrayLike,
                           times: ArrayLike, points: Sequence[ArrayLike], readout_s: float,
                           threshold_px: float) -> list[ShutterFrame]:
    """The rolling shutter's displacement of each frame's points and whether it passes ``threshold_px``.

    Parameters
    ----------
    K : array_like, shape (3, 3) or (N, 3, 3)
        The intrinsics (one for every frame, or one per frame).
    height : int
        Image rows.
    rotations, centres, times
        The frames' poses and times (:func:`camera_velocities`).
    points : sequence of array_like, shape (M_i, 3)
        The world points each frame sees (its observations' 3D points).
    readout_s : float
        The sensor's readout time, top row to bottom row, in seconds.
    threshold_px : float
        A frame is flagged when its largest displacement exceeds this.

    Returns
    -------
    list of ShutterFrame
        In the frames' order; points at or behind a camera are left out.
    """
    if not np.isfinite(readout_s) or readout_s < 0:
        raise CamcalError(f"the readout time must be 0 or more seconds, got {readout_s}")
    if not np.isfinite(threshold_px) or threshold_px <= 0:
        raise CamcalError(f"the rolling-shutter threshold must be a positive number of pixels, got {threshold_px}")
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    if len(points) != len(rotations):
        raise CamcalError(f"{len(rotations)} frames but points for {len(points)}")
    Ks = np.broadcast_to(np.asarray(K, dtype=np.float64), (len(rotations), 3, 3))
    omega, velocity = camera_velocities(rotations, centres, times)
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    frames = []
    for k in range(len(rotations)):
        delta = readout_displacements(Ks[k], height, rotations[k], centres[k], omega[k], velocity[k], points[k],
                                      readout_s)
        size = np.linalg.norm(delta, axis=1)
        size = size[np.isfinite(size)]
        largest = float(size.max()) if size.size else 0.0
        frames.append(ShutterFrame(largest, float(np.degrees(np.linalg.norm(omega[k]))),
                                   float(np.linalg.norm(velocity[k])), largest > threshold_px))
    return frames
