"""Leave-one-view-out held-out error of a board calibration from its one fit on every view (no refit).

``model="auto"`` ranks lens models by views held out (:mod:`camcal.geometry.zhang_rank`). Refitting a model once
per fold costs a fit per fold; this module estimates every view's held-out error from the single fit on all views,
as the one Gauss-Newton step of the problem without that view taken from the full solution (the first-order
deletion formula of least squares, Cook & Weisberg 1982, chapter 3, applied to a whole view as in the grouped
jackknife of :mod:`camcal.geometry.view_jackknife`).

In camcal's parameters (the free intrinsics of every camera and each non-reference camera's pose: the global
``a``; one board pose per view ``p_f``), with ``r = projected - detected`` at the solution and its Jacobian split
per view into ``A_f`` (global columns) and ``B_f`` (the view's own pose), the view's pose is eliminated by the
projector ``P_f = I - B_f (B_f^T B_f)^-1 B_f^T`` (the Schur complement of the sparse bundle, Triggs et al. 2000):

    S_f = A_f^T P_f A_f,   g_f = A_f^T P_f r_f,   S = sum_f S_f,   sum_f g_f = 0 at the solution.

Without view ``f`` one Gauss-Newton step moves the global parameters by ``delta_f = (S - S_f)^-1 g_f`` (every other
view's pose re-solved with them); view ``f`` is then posed again with those intrinsics held, to first order
``e_f = P_f (r_f + A_f delta_f)``: its held-out residuals. The estimate is exact for a model linear in its
parameters and, for a camera calibration whose views each move the intrinsics little, agrees with the refit to
well within the noise the ranking compares (the test measures it). A view the fit left out (an outlier image) is
posed with the full fit's intrinsics: it was held out already.

References
----------
Cook, R. D. & Weisberg, S. (1982). Residuals and Influence in Regression. Chapman & Hall (case deletion).
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle Adjustment - A Modern Synthesis
(the reduced camera system).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.board_shape import BoardShapeFit
from camcal.geometry.spline_fit import pose_view
from camcal.geometry.view_jackknife import board_jacobian
from camcal.geometry.zhang_fit import posed_residuals
from camcal.geometry.zhang_result import CalibrationResult
from camcal.geometry.zhang_starts import INTRINSICS, MODELS
from camcal.model.rig import Camera

__all__ = ["leave_one_view_out", "leave_one_view_out_on_shape"]


def _observed_ids(detection: Detection, points: NDArray[np.float64]) -> NDArray[np.int64]:
    """The board ids of the corners of ``detection`` a fit kept (``points``, a subset of its corners in order)."""
    index = {tuple(xy): k for k, xy in enumerate(np.asarray(detection.corners_px, dtype=np.float64))}
    try:
        return np.asarray(detection.ids)[[index[tuple(xy)] for xy in points]]
    except KeyError:
        raise CamcalError(f"{detection.image}: the fit's corners are not the detection's") from None


def leave_one_view_out(board: Board, result: CalibrationResult, model: str, names: Sequence[str],
                       views: Sequence[Mapping[int, Detection]]) -> dict[tuple[int, int], float]:
    """Every view's leave-one-view-out held-out error, ``sum |r|^2`` in px^2, from the fit ``result`` on all of
    ``views`` (module docstring).

    Parameters
    ----------
    board : Board
        The flat board the fit used.
    result : CalibrationResult
        The fit of ``model`` on every view of ``views`` (a scoring fit will do: no covariance is used).
    model : str
        A name of :data:`~camcal.geometry.zhang_starts.MODELS`.
    names : sequence of str
        The cameras, in the order of ``views`` and of ``result.rig.cameras``.
    views : sequence of mapping of int to Detection
        Per camera, its views by frame (the fit's training views).

    Returns
    -------
    dict of (camera index, frame) to float
        The held-out ``sum |r|^2`` of each view, all of a frame's cameras left out together (a frame's board pose
        is shared by the cameras that saw it).

    Raises
    ------
    CamcalError
        A view the fit left out cannot be posed, or the estimate is not finite.
    """
    cameras = result.rig.cameras
    free = ("f", "cx", "cy") if model == "division" else INTRINSICS
    lenses = [(camera.K, camera.distortion, free + MODELS[model]) for camera in cameras]
    sensor_R = np.array([camera.R for camera in cameras])
    sensor_t = np.array([-camera.R @ camera.c for camera in cameras])
    frame_of = {(names.index(name), image): f for name, image in result.images
                for f, d in views[names.index(name)].items() if d.image == image}
    poses = {f: (R, t) for f, R, t in result.board_poses}
    kept_frames = sorted({f for f in frame_of.values()})
    if any(f not in poses for f in kept_frames):  # a fit without board poses (OpenCV's): each view posed again
        poses = {}
        for (j, image), f in frame_of.items():
            rvec, tvec, _ = pose_view(board, cameras[j].K, cameras[j].distortion, views[j][f])
            R_j, t_j = sensor_R[j], sensor_t[j]
            R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
            poses[f] = (R_j.T @ R, R_j.T @ (np.ravel(tvec) - t_j))
    frame_index = {f: n for n, f in enumerate(kept_frames)}
    X, cam, frame, xy = [], [], [], []
    for n, (name, image) in enumerate(result.images):
        j = names.index(name)
        f = frame_of[(j, image)]
        points = result.points_px[result.image_of_point == n]
        X.append(board.object_points[_observed_ids(views[j][f], points)])
        cam.append(np.full(len(points), j))
        frame.append(np.full(len(points), frame_index[f]))
        xy.append(points)
    X, cam, frame, xy = (np.concatenate(a) for a in (X, cam, frame, xy))
    frame_R = np.array([poses[f][0] for f in kept_frames])
    frame_t = np.array([poses[f][1] for f in kept_frames])
    _, Jg, Jp, projected = board_jacobian(lenses, sensor_R, sensor_t, frame_R, frame_t, X, cam, frame)
    held = _deletion_errors(Jg, Jp, (projected - xy).ravel(), np.repeat(frame, 2), np.repeat(cam, 2))
    out = {(j, kept_frames[n]): value for (j, n), value in held.items()}
    for j, camera in enumerate(cameras):  # views the fit left out (outliers, not posable at the start)
        for f, detection in views[j].items():
            if (j, f) not in out:
                residuals = posed_residuals(board, camera, detection)
                out[(j, f)] = float(np.sum(residuals**2))
    if not all(np.isfinite(v) for v in out.values()):
        raise CamcalError("the leave-one-view-out estimate is not finite")
    return out


def _deletion_errors(Jg: NDArray, Jp: NDArray, r: NDArray, row_view: NDArray,
                     row_cam: NDArray) -> dict[tuple[int, int], float]:
    """``sum |e_f|^2`` of each camera's rows of each view ``f`` left out (module docstring): ``Jg`` the global
    columns (2N, G), ``Jp`` (2N, 6) each row's derivative by its own view's pose, ``r`` (2N,) the residuals at the
    solution, ``row_view`` / ``row_cam`` each row's view index and camera."""
    Jg = Jg / np.maximum(np.linalg.norm(Jg, axis=0), 1e-300)  # Jacobi scaling: coefficients span 1e8
    reduced = []
    for n in np.unique(row_view):
        rows = row_view == n
        A, r_f = Jg[rows], r[rows]
        Q = np.linalg.qr(Jp[rows])[0]  # P_f v = v - Q Q^T v
        reduced.append((int(n), rows, A - Q @ (Q.T @ A), r_f - Q @ (Q.T @ r_f)))
    S = sum(PA.T @ PA for _, _, PA, _ in reduced)
    G = sum(PA.T @ Pr for _, _, PA, Pr in reduced)  # zero at a solution; else the step starts from a linearisation
    # directions no view constrains (a gauge the poses hold) carries no gradient: a ridge far below every
    # constrained direction's curvature (unit columns) gives the minimum-norm step without an SVD per view
    ridge = 1e-10 * np.eye(len(S))
    out: dict[tuple[int, int], float] = {}
    for n, rows, PA, Pr in reduced:
        delta = np.linalg.solve(S - PA.T @ PA + ridge, PA.T @ Pr - G)
        e = Pr + PA @ delta
        for j in np.unique(row_cam[rows]):
            out[(int(j), n)] = float(np.sum(e[row_cam[rows] == j] ** 2))
    return out


def leave_one_view_out_on_shape(board: Board, fit: BoardShapeFit, refine: Sequence[str],
                                views: Mapping[int, Detection]) -> dict[int, float]:
    """Every view's leave-one-view-out held-out error (``sum |r|^2``, px^2) of a board-surface fit
    (:func:`camcal.geometry.board_shape.fit_board_shape` on ``views``, refining the distortion parameters
    ``refine``), each view posed against the fitted surface, by the one-step deletion of the module docstring.

    The global parameters are ``fx, fy, cx, cy`` (an ``aspect`` the fit held tied to ``fx / fy`` follows them),
    ``refine`` and the surface's Legendre coefficients (heights of total degree 2 and more; every in-plane term
    but the shift: the rigid and similarity parts the poses hold are left to the least-squares minimum norm);
    each view's pose is ``(rvec, tvec)`` of ``cam_from_board``. A view the fit left out is posed against the
    fitted surface with the fitted lens.
    """
    shape, K0, lens0 = fit.shape, np.asarray(fit.K, dtype=np.float64), fit.distortion
    tie_aspect = "aspect" in lens0.params and "aspect" not in refine
    frames = sorted(fit.views)
    ids = [fit.views[f].ids for f in frames]
    corner = np.concatenate(ids)
    view_of = np.repeat(np.arange(len(frames)), [len(i) for i in ids])
    points = shape.points(board)[corner]
    xy = np.concatenate([fit.views[f].corners_px for f in frames])
    rvec = np.array([np.ravel(fit.poses[f][0]) for f in frames])
    tvec = np.array([np.ravel(fit.poses[f][1]) for f in frames])

    def project(K: NDArray, lens, P: NDArray, rv: NDArray, tv: NDArray) -> NDArray:
        R = np.stack([cv2.Rodrigues(v)[0] for v in rv])[view_of]
        return lens.project_rays(np.einsum("nij,nj->ni", R, P) + tv[view_of], K)

    def lens_moved(name: str, h: float):
        K, values = K0.copy(), dict(lens0.params)
        if name in INTRINSICS:
            K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[name]] += h
            if tie_aspect:
                values["aspect"] = K[0, 0] / K[1, 1]
        else:
            values[name] += h
        return K, type(lens0)(lens0.model, values, lens0.center)

    q0 = project(K0, lens0, points, rvec, tvec)
    columns = []
    for name in (*INTRINSICS, *refine):
        value = abs(K0[0, 0]) if name in INTRINSICS else abs(lens0.params[name])
        h = 1e-6 * max(value, 1.0) if name in INTRINSICS else (1e-6 * value if value else 1e-9)
        columns.append(((project(*lens_moved(name, h), points, rvec, tvec)
                         - project(*lens_moved(name, -h), points, rvec, tvec)) / (2.0 * h)).ravel())
    # the surface by the chain rule: d q / d X_board = (d q / d X_cam) R, three central differences of every corner
    R = np.stack([cv2.Rodrigues(v)[0] for v in rvec])[view_of]
    X = np.einsum("nij,nj->ni", R, points) + tvec[view_of]
    G = np.empty((len(X), 2, 3))
    for axis in range(3):
        h = 1e-6 * np.maximum(1.0, np.abs(X[:, axis]))
        plus, minus = X.copy(), X.copy()
        plus[:, axis] += h
        minus[:, axis] -= h
        G[:, :, axis] = (lens0.project_rays(plus, K0) - lens0.project_rays(minus, K0)) / (2.0 * h[:, None])
    M = G @ R
    flat_xy = np.asarray(board.object_points[:, :2], dtype=np.float64)
    unit = {"centre": shape.centre, "half_size": shape.half_size}
    for term in sorted(shape.coefficients):
        if sum(term) >= 2:
            dz = type(shape)(shape.degree, {term: 1.0}, **unit).heights(flat_xy)[corner]
            columns.append((M[:, :, 2] * dz[:, None]).ravel())
    for term in sorted(shape.in_plane):
        for axis in (0, 1):
            if sum(term) >= 1:
                shift = type(shape)(shape.degree, {}, **unit, in_plane={term: (1.0 - axis, float(axis))})
                d = shift.displacements(flat_xy)[corner]
                columns.append((M[:, :, 0] * d[:, 0, None] + M[:, :, 1] * d[:, 1, None]).ravel())
    Jg = np.column_stack(columns)
    Jp = np.empty((2 * len(X), 6))
    for axis in range(6):
        h = 1e-6 * (1.0 if axis < 3 else max(float(np.median(np.linalg.norm(tvec, axis=1))), 1e-3))
        e = np.zeros((len(frames), 3))
        e[:, axis % 3] = h
        plus = (rvec + e, tvec) if axis < 3 else (rvec, tvec + e)
        minus = (rvec - e, tvec) if axis < 3 else (rvec, tvec - e)
        Jp[:, axis] = ((project(K0, lens0, points, *plus) - project(K0, lens0, points, *minus)) / (2.0 * h)).ravel()
    row_view = np.repeat(view_of, 2)
    held = _deletion_errors(Jg, Jp, (q0 - xy).ravel(), row_view, np.zeros_like(row_view))
    out = {frames[n]: value for (_, n), value in held.items()}
    camera = Camera("held", next(iter(views.values())).image_size, K0, lens0, np.eye(3), np.zeros(3))
    for f, detection in views.items():
        if f not in out:
            out[f] = float(np.sum(posed_residuals(board, camera, detection, shape.points(board)) ** 2))
    if not all(np.isfinite(v) for v in out.values()):
        raise CamcalError("the leave-one-view-out estimate is not finite")
    return out
