"""Starts for the rolling-shutter bundle adjustment that need none: centres and points linear in the rotations.

:func:`linear_start` gives, for known frame rotations and a readout time,
the centres and points that best fit the observations in the least-squares
sense of the linear constraints (no start, no local minimum), which
:mod:`camcal.geometry.rolling_shutter_ba` adjusts from when the solve's own
poses sit in another minimum; :func:`schur_blocks` and :func:`schur_solve`
eliminate the points from normal equations (Triggs et al. 2000, section
6.1), which both use.

References
----------
Kahl, F. & Hartley, R. (2008). Multiple-View Geometry Under the L-infinity
Norm. IEEE TPAMI 30(9) (structure and motion with known rotations).
Meingast, M., Geyer, C. & Sastry, S. (2005). Geometric Models of
Rolling-Shutter Cameras. OMNIVIS.
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment: A Modern Synthesis. Vision Algorithms: Theory and Practice.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix, csr_matrix, hstack
from scipy.spatial.transform import Rotation

from camcal.geometry.rolling_shutter import camera_velocities

__all__ = ["linear_start", "schur_blocks", "schur_solve"]


def linear_start(focal: NDArray[np.float64], centre: NDArray[np.float64], rotations: NDArray[np.float64],
                 times: NDArray[np.float64], frame_of: NDArray[np.intp], point_of: NDArray[np.intp],
                 pixels: NDArray[np.float64], tau: NDArray[np.float64], n_points: int, iterations: int = 3
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The frames' centres and the points that best fit the observations given the rotations and each
    observation's read-out time ``tau`` (s): linear least squares, no start needed.

    With the rotations known, the rolling-shutter model is linear in the centres and points: observation ``i`` of
    point ``X_j`` in frame ``k``, on the ray ``m_i`` (unit, camera axes), gives ``[m_i]_x R_k(tau_i) (X_j - c_k -
    tau_i v_k) = 0``, ``R_k(tau) = exp(tau [omega_k]_x) R_k`` (``omega_k`` from the rotations) and ``v_k = sum_l
    D_kl c_l`` linear in the centres (:func:`camcal.geometry.rolling_shutter.camera_velocities`); with known
    rotations the rest of structure from motion is linear (Kahl & Hartley 2008, section 4; Meingast et al. 2005 for
    the rolling shutter). Each constraint is divided by the point's depth (from the previous pass; 1 in the first)
    so that it weighs its angular error; the first frame's centre is the origin and the scale is fixed by
    ``|c| = 1``: the centres are the eigenvector of the smallest eigenvalue of the points' Schur complement (Triggs
    et al. 2000, section 6.1), the points then solved for, and both turned so the points lie in front.

    Parameters
    ----------
    focal, centre : ndarray, shape (P, 2)
        Each observation's focal lengths and principal point (pixels).
    rotations : ndarray, shape (N, 3, 3)
        The frames' world -> camera rotations (held).
    times : ndarray, shape (N,)
        The frames' times (s), increasing.
    frame_of, point_of : ndarray of int, shape (P,)
        Each observation's frame and point (every point seen from at least two places).
    pixels : ndarray, shape (P, 2)
        The observations in pinhole pixels.
    tau : ndarray, shape (P,)
        Each observation's read-out time from its frame's (s).
    n_points : int
        The points' number.
    iterations : int
        Passes, each weighted by the previous one's depths.

    Returns
    -------
    centres : ndarray, shape (N, 3)
    points : ndarray, shape (n_points, 3)

    Raises
    ------
    numpy.linalg.LinAlgError
        A point the rays do not fix (its normal block singular).
    """
    n_frames, n = len(rotations), len(pixels)
    identity = np.broadcast_to(np.eye(3), (n_frames, 3, 3))
    probes = [camera_velocities(identity, np.outer(np.eye(n_frames)[frame], [1.0, 0.0, 0.0]), times)[1][:, 0]
              for frame in range(n_frames)]
    velocity_of = np.array(probes).T  # v = velocity_of @ c
    omega, _ = camera_velocities(rotations, np.zeros((n_frames, 3)), times)
    row_rotation = np.einsum("nij,njk->nik", Rotation.from_rotvec(tau[:, None] * omega[frame_of]).as_matrix(),
                             rotations[frame_of])
    ray = np.c_[(pixels - centre) / focal, np.ones(n)]
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    cross = np.zeros((n, 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -ray[:, 2], ray[:, 1], -ray[:, 0]
    constraint = np.einsum("nij,njk->nik", cross - cross.transpose(0, 2, 1), row_rotation)
    weight_of = np.zeros((n, n_frames))  # c_k + tau v_k = sum_l weight_of[i, l] c_l
    weight_of[np.arange(n), frame_of] = 1.0
    weight_of += tau[:, None] * velocity_of[frame_of]
    obs, frame = np.nonzero(weight_of)
    rows = 3 * np.arange(n)[:, None] + np.arange(3)
    weights = np.ones(n)
    for _ in range(iterations):
        weighted = constraint * weights[:, None, None]
        points_part = coo_matrix((weighted.ravel(), (np.repeat(rows.ravel(), 3),
                                                     np.tile(3 * point_of[:, None] + np.arange(3), 3).ravel())),
                                 shape=(3 * n, 3 * n_points))
        centres_part = coo_matrix(((-weighted[obs] * weight_of[obs, frame][:, None, None]).ravel(),
                                   (np.repeat(rows[obs].ravel(), 3),
                                    np.tile(3 * frame[:, None] + np.arange(3), 3).ravel())),
                                  shape=(3 * n, 3 * n_frames)).tocsc()[:, 3:]  # the first centre is the origin
        A = hstack([centres_part, points_part]).tocsc()
        cameras, coupling, points_inverse = schur_blocks((A.T @ A).tocsc(), 3 * n_points)
        reduced = cameras - (points_inverse.T @ coupling.T).T @ coupling.T
        centres = np.r_[np.zeros(3), np.linalg.eigh(reduced)[1][:, 0]]
        points = -(points_inverse @ (coupling.T @ centres[3:]))
        c, X = centres.reshape(-1, 3), points.reshape(-1, 3)
        depth = np.einsum("nij,nj->ni", row_rotation, X[point_of] - weight_of @ c)[:, 2]
        if np.median(depth) < 0:
            c, X, depth = -c, -X, -depth
        weights = 1.0 / np.maximum(depth, 1e-3 * np.median(depth))
    return c, X


def schur_blocks(A, n_points: int) -> tuple[NDArray[np.float64], NDArray[np.float64], csr_matrix]:
    """``A``'s camera block and camera-point block (dense) and the inverses of its 3 x 3 point blocks (sparse)."""
    n_camera = A.shape[0] - n_points
    A = A.tocsr()
    cameras = A[:n_camera, :n_camera].toarray()
    coupling = A[:n_camera, n_camera:].toarray()
    points = A[n_camera:, n_camera:].tocoo()
    same = points.row // 3 == points.col // 3
    blocks = np.zeros((n_points // 3, 3, 3))
    blocks[points.row[same] // 3, points.row[same] % 3, points.col[same] % 3] = points.data[same]
    inverse = np.linalg.inv(blocks)
    index = np.arange(n_points).reshape(-1, 3)
    rows, cols = np.repeat(index, 3, axis=1).ravel(), np.tile(index, (1, 3)).ravel()
    return cameras, coupling, coo_matrix((inverse.ravel(), (rows, cols)), shape=(n_points, n_points)).tocsr()


def schur_solve(A, b: NDArray[np.float64], n_points: int) -> NDArray[np.float64]:
    """``A^-1 b`` with the points (the last ``n_points`` unknowns, block diagonal in 3 x 3) eliminated: the
    cameras from ``S = B - E C^-1 E^T``, then the points (Triggs et al. 2000, section 6.1)."""
    n_camera = A.shape[0] - n_points
    cameras, coupling, points_inverse = schur_blocks(A, n_points)
    reduced = cameras - (points_inverse.T @ coupling.T).T @ coupling.T
    camera_step = np.linalg.solve(reduced, b[:n_camera] - coupling @ (points_inverse @ b[n_camera:]))
    return np.r_[camera_step, points_inverse @ (b[n_camera:] - coupling.T @ camera_step)]
