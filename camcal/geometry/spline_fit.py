"""A parametric lens plus a smooth correction field (:class:`camcal.model.spline.SplineField`), fitted to board views.

The fit starts from a parametric calibration (K, the lens, every view posed with them) and refines
jointly the intrinsics ``fx, fy, cx, cy``, the lens's distortion parameters, every view's board pose
(rotation vector, translation) and the field's control displacements ``c``, minimising

    sum_corners |q0 + F(q0) - x|^2 + lambda sum |D2 c|^2 + mu sum |c|^2

with ``q0`` the parametric projection of the board corner and ``D2`` the second differences of the
control grid along x and along y (a thin-plate-like bending energy: an affine field costs nothing
there, the small ridge ``mu`` keeps that part, which K and the poses also hold, at its smallest).
Levenberg-Marquardt (Marquardt's scaling, normal equations) on the Jacobian assembled from
forward differences for the intrinsics, the lens and the poses (the six pose columns of every view
perturbed at once: a view's corners depend on its own pose only) and the exact, linear field columns.

``lambda`` and ``mu`` are per corner coordinate in pixels: with the default ``lambda = 1`` a bend of
1 px between neighbouring knots costs as much as one corner 1 px off. The grid defaults to knots
every ~1/7 of the image width (``nx = 10``) and as many per pixel vertically.

References
----------
Schöps, T., Larsson, V., Pollefeys, M. & Sattler, T. (2020). Why having 10,000 parameters in your
camera model is better than twelve. CVPR (dense B-spline camera models, fitted jointly with poses).
Rueckert, D. et al. (1999). Nonrigid registration using free-form deformations. IEEE TMI 18(8)
(tensor cubic B-spline displacement fields with a bending-energy penalty).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.optimize
import scipy.sparse
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.model.distortion import Distortion, capped_rays
from camcal.model.spline import SplineField

__all__ = ["levenberg_marquardt", "SplineFit", "fit_spline_lens", "grid_shape", "pose_view"]

#: Default control points across the image width.
DEFAULT_NX = 10
#: Default bending weight and ridge (per corner coordinate, pixels).
DEFAULT_BENDING = 1.0
DEFAULT_RIDGE = 1e-3
_FD_STEP = 1e-7
_OPTICAL_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SplineFit:
    """The fitted intrinsics, lens (with its field), board poses and training residuals."""

    K: NDArray[np.float64]
    distortion: Distortion
    poses: Mapping[int, tuple[NDArray[np.float64], NDArray[np.float64]]]
    residuals_px: NDArray[np.float64]
    rms_px: float


def grid_shape(image_size: tuple[int, int], nx: int = DEFAULT_NX) -> tuple[int, int]:
    """``(nx, ny)``: ``nx`` knots across, as many per pixel down (at least 4)."""
    W, H = image_size
    return nx, max(4, round(3 + (nx - 3) * (H - 1) / (W - 1)))


def pose_view(board: Board, K: NDArray, distortion: Distortion, detection: Detection,
              points: NDArray | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(rvec, tvec, residuals)`` of one view posed with the intrinsics held.

    OpenCV's ``solvePnP`` on the undistorted corners, then Levenberg-Marquardt over the six pose
    parameters of ``|project(K, d, R X + t) - x|^2`` with the lens's own projection. ``points``: the
    board's corners (N, 3) when the board is not flat (:meth:`camcal.geometry.board_shape.BoardShape.points`).
    A fisheye lens (:attr:`~camcal.model.distortion.Distortion.is_fisheye`) images rays only up to its
    :attr:`~camcal.model.distortion.Distortion.max_angle_rad` (where its ``theta_d(theta)`` turns over), so its
    image is a disc: a corner outside it is measured from the disc's rim, the projection of its ray turned back to
    that angle (:func:`~camcal.model.distortion.capped_rays`), the nearest point the lens can image, so that a lens
    fitted on views that did not reach as far out is scored by how far it misses, like any other model, and the
    pose sees a residual that changes with it. Otherwise the residuals are NaN for a corner the lens cannot project
    at the pose found (behind a pinhole camera; the fit itself counts such a corner as 1e6 px, so that it pushes
    the pose away).
    """
    X = np.asarray((board.object_points if points is None else points)[detection.ids], dtype=np.float64)
    ideal = distortion.undistort(detection.corners_px, K)
    front = np.all(np.isfinite(ideal), axis=1)
    if front.sum() < 4:
        raise CamcalError(f"{detection.image}: fewer than 4 corners have an undistorted image under the lens: "
                          "the view cannot be posed")
    ok, rvec, tvec = cv2.solvePnP(X[front], ideal[front], K, None)
    if not ok:
        raise CamcalError(f"{detection.image}: PnP failed")

    # a fisheye's rays turned back inside its range (the rim's projection is finite); no cap otherwise
    cap = distortion.max_angle_rad * (1.0 - 1e-9) if distortion.is_fisheye else None

    def offsets(pose: NDArray[np.float64]) -> NDArray[np.float64]:
        rays = capped_rays(X @ cv2.Rodrigues(pose[:3])[0].T + pose[3:], _OPTICAL_AXIS, cap)
        return distortion.project_rays(rays, K) - detection.corners_px

    solution = scipy.optimize.least_squares(lambda pose: np.nan_to_num(offsets(pose), nan=1e6).ravel(),
                                            np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm",
                                            x_scale="jac", xtol=1e-12, ftol=1e-12)
    return solution.x[:3], solution.x[3:], offsets(solution.x)


def _second_differences(ny: int, nx: int) -> scipy.sparse.csr_matrix:
    """Rows ``c[j, i-1] - 2 c[j, i] + c[j, i+1]`` and ``c[j-1, i] - 2 c[j, i] + c[j+1, i]`` on the raveled grid."""
    def d2(n: int) -> scipy.sparse.csr_matrix:
        return scipy.sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n))
    return scipy.sparse.vstack([scipy.sparse.kron(scipy.sparse.eye(ny), d2(nx)),
                                scipy.sparse.kron(d2(ny), scipy.sparse.eye(nx))]).tocsr()


def levenberg_marquardt(residuals, jacobian, start: NDArray[np.float64], max_iter: int = 60,
                         tol: float = 1e-10) -> NDArray[np.float64]:
    """Levenberg-Marquardt with Marquardt's scaling ``(J^T J + mu diag(J^T J)) dp = -J^T r`` (Marquardt 1963).

    Stops when a step lowers the cost by less than ``tol`` of it or after ``max_iter`` Jacobians.
    """
    p = start.copy()
    r = residuals(p)
    cost = float(r @ r)
    mu = 1e-3
    for _ in range(max_iter):
        J = jacobian(p)
        H = J.T @ J
        g = J.T @ r
        diag = np.maximum(np.diag(H), 1e-12)
        while True:
            try:
                step = np.linalg.solve(H + mu * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                step = np.full_like(p, np.nan)
            trial = p + step
            r_trial = residuals(trial) if np.all(np.isfinite(step)) else None
            cost_trial = float(r_trial @ r_trial) if r_trial is not None else np.inf
            if cost_trial < cost:
                break
            mu *= 10.0
            if mu > 1e12:
                return p
        gain = cost - cost_trial
        p, r, cost, mu = trial, r_trial, cost_trial, max(mu / 10.0, 1e-12)
        if gain <= tol * cost:
            break
    return p


def fit_spline_lens(board: Board, views: Mapping[int, Detection], K: NDArray, distortion: Distortion,
                    refine: Sequence[str], nx: int = DEFAULT_NX, bending: float = DEFAULT_BENDING,
                    ridge: float = DEFAULT_RIDGE, points: NDArray | None = None) -> SplineFit:
    """Fit the field on top of a calibrated parametric lens (see the module docstring).

    Parameters
    ----------
    board, views :
        The board and the training views (frame -> detection), all of one image size.
    K, distortion :
        The parametric calibration of those views (its field, if any, is replaced).
    refine :
        The distortion parameters refined with the field (the others are held).
    nx, bending, ridge :
        Knots across the image (:func:`grid_shape`), ``lambda`` and ``mu``.
    points :
        The board's corners (N, 3) when it is not flat (held; :mod:`camcal.geometry.board_shape`).
    """
    frames = sorted(views)
    size = next(iter(views.values())).image_size
    nx, ny = grid_shape(size, nx)
    base = Distortion(distortion.model, dict(distortion.params), distortion.center)
    field0 = SplineField.zeros(size, nx, ny)
    corners = board.object_points if points is None else points
    starts = [pose_view(board, K, base, views[f], corners) for f in frames]
    X = [np.asarray(corners[views[f].ids], dtype=np.float64) for f in frames]
    x = np.concatenate([views[f].corners_px for f in frames])
    counts = [len(v) for v in X]
    view_of = np.repeat(np.arange(len(frames)), counts)
    n_lens = 4 + len(refine)
    n_views = len(frames)
    m = nx * ny
    D2 = _second_differences(ny, nx)
    reg = scipy.sparse.vstack([np.sqrt(bending) * D2, np.sqrt(ridge) * scipy.sparse.eye(m)]).tocsr()

    def unpack(p: NDArray[np.float64]):
        Kp = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        lens = Distortion(base.model, {**base.params, **dict(zip(refine, p[4:n_lens]))}, base.center)
        poses = p[n_lens:n_lens + 6 * n_views].reshape(n_views, 6)
        c = p[n_lens + 6 * n_views:].reshape(m, 2)
        return Kp, lens, poses, c

    def parametric(p: NDArray[np.float64]) -> NDArray[np.float64]:
        Kp, lens, poses, _ = unpack(p)
        cam = np.concatenate([Xv @ cv2.Rodrigues(pose[:3])[0].T + pose[3:] for Xv, pose in zip(X, poses)])
        return lens.project_rays(cam, Kp)

    def residuals(p: NDArray[np.float64]) -> NDArray[np.float64]:
        q0 = parametric(p)
        c = unpack(p)[3]
        data = q0 + field0.basis_matrix(np.nan_to_num(q0)) @ c - x
        return np.concatenate([np.nan_to_num(data, nan=1e6).ravel(), (reg @ c).ravel()])

    def jacobian(p: NDArray[np.float64]) -> NDArray[np.float64]:
        Kp, _, _, c = unpack(p)
        q0 = parametric(p)
        basis = field0.basis_matrix(np.nan_to_num(q0))
        field = SplineField(size, c.reshape(ny, nx, 2))
        moved = q0 + basis @ c
        n_data = 2 * len(x)
        J = np.zeros((n_data + 2 * reg.shape[0], len(p)))
        steps = _FD_STEP * np.maximum(1.0, np.abs(p))
        for k in range(n_lens):  # the intrinsics and the lens: one column each
            dp = p.copy()
            dp[k] += steps[k]
            q = parametric(dp)
            J[:n_data, k] = ((q + field.evaluate(q)) - moved).ravel() / steps[k]
        for k in range(6):  # the k-th pose parameter of every view at once
            dp = p.copy()
            cols = n_lens + 6 * np.arange(n_views) + k
            dp[cols] += steps[cols]
            q = parametric(dp)
            delta = ((q + field.evaluate(q)) - moved) / steps[cols][view_of, None]
            J[2 * np.arange(len(x)), cols[view_of]] = delta[:, 0]
            J[2 * np.arange(len(x)) + 1, cols[view_of]] = delta[:, 1]
        dense_basis = basis.toarray()
        off = n_lens + 6 * n_views
        J[0:n_data:2, off::2] = dense_basis
        J[1:n_data:2, off + 1::2] = dense_basis
        dense_reg = reg.toarray()
        J[n_data::2, off::2] = dense_reg
        J[n_data + 1::2, off + 1::2] = dense_reg
        return J

    start = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [base.params[name] for name in refine],
                            np.concatenate([np.concatenate([r, t]) for r, t, _ in starts]), np.zeros(2 * m)])
    solution = levenberg_marquardt(residuals, jacobian, start)
    if not np.all(np.isfinite(solution)):
        raise CamcalError("the spline lens fit diverged (non-finite parameters)")
    fun = residuals(solution)
    Kp, lens, poses, c = unpack(solution)
    fitted = Distortion(lens.model, dict(lens.params), lens.center, correction=SplineField(size, c.reshape(ny, nx, 2)))
    data = fun[:2 * len(x)].reshape(-1, 2)
    if not np.all(np.abs(data) < 1e5):
        raise CamcalError("the spline lens fit left corners unprojected (rays outside the lens's range)")
    return SplineFit(K=Kp, distortion=fitted, poses={f: (pose[:3].copy(), pose[3:].copy()) for f, pose in zip(frames, poses)},
                     residuals_px=data, rms_px=float(np.sqrt(np.mean(np.sum(data * data, axis=1)))))
