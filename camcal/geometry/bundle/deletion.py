"""The bundle adjustment without some frames, to first order: one Gauss-Newton step from the full solution.

The delete-one-frame jackknife (:mod:`camcal.geometry.jackknife`) needs the
solution of the problem without each frame (or group of frames). A full
refit per group costs a whole bundle adjustment each; from the full
solution ``theta`` the replicate is, to first order, one Gauss-Newton step
on the problem without the group's residuals::

    theta_(g) = theta - (J_(g)^T J_(g))^+ J_(g)^T r_(g)

with ``J_(g)``, ``r_(g)`` the Jacobian and residuals of the remaining
observations at ``theta`` (Ceres' own, the loss applied), the deleted
frames' poses and the points left with fewer than two observations out
(as :func:`camcal.geometry.jackknife.without_frames` drops them). The
points are eliminated by the Schur complement of their 3x3 blocks (Triggs
et al. 2000, section 6.1), so each replicate costs a sparse product and a
dense factorisation of the cameras' and frames' reduced system, not a
nonlinear solve. Deleting one of the two frames that fix the gauge leaves
the remaining system singular along the gauge (rotation, translation,
scale): the reduced system is then solved by its pseudo-inverse, which
moves the intrinsics and the rig rotation -- gauge invariants -- exactly as
any other gauge choice would. This is the one-step jackknife (Efron & Stein
1981 call the linearised version the infinitesimal jackknife); it differs
from the full refit by the curvature of the problem over one frame's
influence, small where the jackknife itself is meaningful.

The same deletion gives each frame's influence without a solve per frame
(:func:`frame_influences`): by the Woodbury identity the step above is
``H^-1 J_k^T (I - H_kk)^-1 r_k`` with ``H = J^T J`` of the whole problem
and ``H_kk = J_k H^-1 J_k^T`` the frame's block of the hat matrix, the
delete-one-cluster form of MacKinnon & White's (1985) jackknife
covariance (Bell & McCaffrey 2002 call it CR3). It is taken over every
free column, the frames' poses included, so that the scene gauge's turn
(:func:`camcal.geometry.uncertainty.scene_gauge_rows`) moves with the
intrinsics in each replicate. ``I - H_kk`` is singular along what only the
frame fixes (its own pose, points it alone sees), where its residuals are
zero: the Moore-Penrose inverse drops those directions (Pustejovsky &
Tipton 2018). The points are eliminated from ``H_kk`` too: with ``D = I -
P_k V^+ P_k^T`` (block diagonal, one block per point) and ``E =
D^(+1/2) X_k F`` (``X_k`` the frame's rows with the points eliminated, ``F
F^T = S^+``), ``(I - H_kk)^+ = D^(+1/2) (I - E E^T)^+ D^(+1/2)``, one eigen-decomposition
per frame over the columns the frame touches (its intrinsics, rig and the frames that share its points:
a few hundred on a long plate, whatever its length).

References
----------
MacKinnon, J. G. & White, H. (1985). Some heteroskedasticity-consistent
covariance matrix estimators with improved finite sample properties.
Journal of Econometrics 29.
Bell, R. M. & McCaffrey, D. F. (2002). Bias reduction in standard errors
for linear regression with multi-stage samples. Survey Methodology 28.
Pustejovsky, J. E. & Tipton, E. (2018). Small-sample methods for
cluster-robust variance estimation and hypothesis testing in fixed effects
models. Journal of Business & Economic Statistics 36.
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals
of Statistics 9.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.bundle.covariance import is_free_block, point_schur_terms
from camcal.geometry.bundle.solve import bundle_adjust
from camcal.geometry.bundle.state import BundleOptions, BundleState, model_layout
from camcal.geometry.uncertainty import scene_gauge_rows

__all__ = ["DeletionUnsupported", "FrameInfluences", "frame_influences", "one_step_replicates"]

#: eigenvalues of the Jacobi-scaled reduced system below this share of the largest are its null space (the gauge).
_NULL_RATIO = 1e-11
#: a point's 3x3 block with ``lambda_min`` below this share of ``lambda_max`` is left free along that direction.
_POINT_NULL_RATIO = 1e-10
#: a replicate's points' Schur terms are the full ones with those of the points the group touches taken out and put
#: back without it when they are fewer than this share of the points (two sums over them against one over every
#: point); else they are summed again over every point.
_UPDATE_BELOW = 0.5
#: a leverage (a hat matrix eigenvalue) within this of 1: the cluster's residuals are zero along it.
_LEVERAGE_NULL = 1e-8


class DeletionUnsupported(CamcalError):
    """The problem has a shape the one-step replicates do not handle (a board, constant points...): refit instead."""


@dataclasses.dataclass
class _Block:
    kind: str  # "camera", "sensor", "frame", "point"
    index: int  # camera, frame or point position in the state
    columns: slice
    free: tuple[int, ...] = ()  # camera: the free COLMAP parameters; frame: the free translation axes


def _free_params(state: BundleState, camera: int, options: BundleOptions) -> tuple[int, ...]:
    """The COLMAP parameters of camera ``camera`` the options leave free (:class:`BundleOptions`)."""
    names, focal, pp, extra = model_layout(state.models[camera])
    name = state.camera_names[camera]
    if name in options.constant_intrinsics:
        return ()
    held = set(options.fixed_params.get(name, ()))
    held = {names.index(param) for param in held if param in names}
    for refined, index in ((options.refine_focal_length, focal), (options.refine_principal_point, pp),
                           (options.refine_extra_params, extra)):
        if not refined:
            held.update(index)
    return tuple(k for k in range(len(names)) if k not in held)


def _gauge_axis(state: BundleState, colmap, problem) -> int:
    """The translation axis COLMAP's ``TWO_CAMS_FROM_WORLD`` gauge holds on its second frame.

    COLMAP holds the first frame (in image order) and, on the next frame, the
    axis of the largest component of ``frame1_from_world frame2_from_world^-1``'s
    translation.
    """
    fixed = [frame for frame, fid in colmap.frame_ids.items()
             if not is_free_block(problem, colmap.reconstruction.frame(fid).rig_from_world.params)]
    if len(fixed) != 1:
        raise DeletionUnsupported(f"expected one constant frame in the gauge, found {len(fixed)}")
    f1 = fixed[0]
    partial = [frame for frame, fid in colmap.frame_ids.items()
               if problem.parameter_block_tangent_size(colmap.reconstruction.frame(fid).rig_from_world.params) == 5]
    if len(partial) != 1:
        return -1
    f2 = partial[0]
    baseline = state.frame_t[f1] - state.frame_R[f1] @ state.frame_R[f2].T @ state.frame_t[f2]
    return int(np.argmax(np.abs(baseline)))


def _layout(state: BundleState, options: BundleOptions, colmap, problem) -> tuple[list[_Block], list, int]:
    """The free parameter blocks in column order: cameras, rig sensors, frames, then points."""
    reconstruction = colmap.reconstruction
    blocks, arrays, start = [], [], 0

    def add(kind: str, index: int, array, free: tuple[int, ...] = ()) -> None:
        nonlocal start
        size = problem.parameter_block_tangent_size(array)
        blocks.append(_Block(kind, index, slice(start, start + size), free))
        arrays.append(array)
        start += size

    for index, cid in enumerate(colmap.camera_ids):
        array = reconstruction.cameras[cid].params
        if is_free_block(problem, array):
            free = _free_params(state, index, options)
            if len(free) != problem.parameter_block_tangent_size(array):
                raise DeletionUnsupported(f"camera {state.camera_names[index]!r}: {len(free)} free parameters "
                                          f"expected, Ceres has {problem.parameter_block_tangent_size(array)}")
            add("camera", index, array, free)
    sensors = {sensor.id: pose for sensor, pose in reconstruction.rig(1).non_ref_sensors.items()}
    for index, cid in enumerate(colmap.camera_ids[1:], start=1):
        if is_free_block(problem, sensors[cid].params):
            add("sensor", index, sensors[cid].params)
    axis = _gauge_axis(state, colmap, problem) if options.refine_sensor_from_rig or len(state.camera_names) == 1 else -1
    for frame, fid in sorted(colmap.frame_ids.items()):
        array = reconstruction.frame(fid).rig_from_world.params
        if is_free_block(problem, array):
            free = (0, 1, 2) if problem.parameter_block_tangent_size(array) == 6 else \
                tuple(k for k in range(3) if k != axis)
            if axis < 0 and len(free) != 3:
                raise DeletionUnsupported("a frame pose with a partial manifold outside the gauge")
            add("frame", frame, array, free)
    n_cameras = start
    for p, pid in enumerate(colmap.point_ids):
        if pid >= 0 and is_free_block(problem, reconstruction.points3D[pid].xyz):
            add("point", p, reconstruction.points3D[pid].xyz)
    if start == n_cameras:
        raise DeletionUnsupported("no free points")
    return blocks, arrays, n_cameras


def _pseudo_solve(S: NDArray[np.float64], b: NDArray[np.float64], singular: bool) -> NDArray[np.float64]:
    """``S^+ b`` for a symmetric positive semi-definite ``S``: Cholesky unless ``singular`` or it fails, else eigen.

    ``singular``: ``S`` is known to have a null space (the group held a gauge
    frame). Cholesky would not reliably refuse it: the Jacobi-scaled
    pivot of a null direction is rounding (1e-16 to 1e-13), on either side
    of any threshold, and where it passes the step gains a null-space
    component of ``b``'s rounding over that pivot, a different one per run
    (the baseline direction's jackknife sigma moved by 1e-4 relative when
    the solution moved by 1e-11). The eigen-decomposition drops it.
    """
    import scipy.linalg  # noqa: PLC0415

    out = np.zeros_like(b)
    d = np.diag(S).copy()
    used = d > 0
    if not np.any(used):
        return out
    scale = 1.0 / np.sqrt(d[used])
    scaled = S[np.ix_(used, used)] * np.outer(scale, scale)
    rhs = b[used] * scale
    try:
        if singular:
            raise np.linalg.LinAlgError("a gauge frame left out")
        factor = scipy.linalg.cholesky(scaled, lower=True)
        if np.min(np.diag(factor)) ** 2 < 1e-14:
            raise np.linalg.LinAlgError("nearly singular")
        x = scipy.linalg.cho_solve((factor, True), rhs)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(scaled)
        keep = values > _NULL_RATIO * values[-1]
        x = vectors[:, keep] @ ((vectors[:, keep].T @ rhs) / values[keep])
    out[used] = x * scale
    return out


@dataclasses.dataclass
class _System:
    """The linearised problem at the solution: the Jacobian split into its camera / rig / frame columns and its
    points' (3 per row), the residuals, and each row's frame and point (-1: none, e.g. a prior's row)."""

    blocks: list[_Block]
    J_c: object  # scipy.sparse.csr_matrix, rows x camera/rig/frame columns
    point_rows: NDArray[np.float64]  # rows x 3: the row's derivative by its point
    r: NDArray[np.float64]
    row_frame: NDArray[np.int64]
    row_point: NDArray[np.int64]
    n_points: int
    gauge: list[int]  # frame positions that hold the gauge (constant, or a held translation axis)


def _system(state: BundleState, options: BundleOptions, colmap, problem) -> _System:
    """The problem's Jacobian and residuals at ``state`` (Ceres' own, the loss applied), rows assigned to frames."""
    pyceres = require("pyceres")
    import scipy.sparse  # noqa: PLC0415

    if state.board is not None or not options.refine_points3D:
        raise DeletionUnsupported("a board or constant points")
    blocks, arrays, n_c = _layout(state, options, colmap, problem)
    evaluate = pyceres.EvaluateOptions()
    evaluate.set_parameter_blocks(arrays)
    evaluate.num_threads = 1
    crs = problem.evaluate_jacobian(evaluate)
    J = scipy.sparse.csr_matrix((np.asarray(crs.values), np.asarray(crs.cols), np.asarray(crs.rows)),
                                shape=(crs.num_rows, crs.num_cols))
    r = np.asarray(problem.evaluate_residuals(evaluate), dtype=np.float64)
    n_rows, n_points = J.shape[0], (J.shape[1] - n_c) // 3

    # each row's frame and point, from the columns it touches
    column_frame = np.full(J.shape[1], -1, dtype=np.int64)
    column_point = np.full(J.shape[1], -1, dtype=np.int64)
    n_point_blocks = 0
    for block in blocks:
        if block.kind == "frame":
            column_frame[block.columns] = block.index
        elif block.kind == "point":
            column_point[block.columns] = n_point_blocks
            n_point_blocks += 1
    entry_row = np.repeat(np.arange(n_rows), np.diff(J.indptr))
    row_frame = np.full(n_rows, -1, dtype=np.int64)
    row_point = np.full(n_rows, -1, dtype=np.int64)
    on_frame, on_point = column_frame[J.indices] >= 0, column_point[J.indices] >= 0
    row_frame[entry_row[on_frame]] = column_frame[J.indices[on_frame]]
    row_point[entry_row[on_point]] = column_point[J.indices[on_point]]
    orphans = (row_frame < 0) & (row_point >= 0)
    if np.any(orphans):
        held = sorted(set(colmap.frame_ids) - {block.index for block in blocks if block.kind == "frame"})
        if len(held) != 1:
            raise DeletionUnsupported(f"observations of {len(held)} constant frames")
        row_frame[orphans] = held[0]
    observed = np.bincount(state.obs_frame, minlength=len(state.frame_R))
    assigned = np.bincount(row_frame[row_frame >= 0], minlength=len(state.frame_R))
    if not np.array_equal(assigned, 2 * observed):
        raise DeletionUnsupported("the Jacobian's rows do not match the observations frame by frame")

    # the point columns of every row (3 per row, zero where the row has no free point)
    Jp = J[:, n_c:].tocoo()
    point_rows = np.zeros((n_rows, 3))
    point_rows[Jp.row, Jp.col % 3] = Jp.data
    # the gauge frames: held constant, or with a held translation axis; without one, S is singular
    gauge = [frame for frame in colmap.frame_ids if not any(block.kind == "frame" and block.index == frame
                                                             and len(block.free) == 3 for block in blocks)]
    return _System(blocks, J[:, :n_c].tocsr(), point_rows, r, row_frame, row_point, n_points, gauge)


@dataclasses.dataclass
class _Sums:
    """The normal equations over some rows before the points are eliminated: ``A^T A`` and ``A^T r`` on the
    camera / rig / frame columns, each point's 3x3 block ``V = P^T P`` and ``P^T r``, and ``H_pc`` (each
    point's 3 rows of ``P^T A``, sparse)."""

    AtA: NDArray[np.float64]
    Atr: NDArray[np.float64]
    H_pp: NDArray[np.float64]
    b_p: NDArray[np.float64]
    H_pc: object  # scipy.sparse.csr_matrix, 3 n_points x columns

    def __sub__(self, other: _Sums) -> _Sums:
        return _Sums(self.AtA - other.AtA, self.Atr - other.Atr, self.H_pp - other.H_pp, self.b_p - other.b_p,
                     (self.H_pc - other.H_pc).tocsr())


def _sums(system: _System, rows: NDArray[np.int64]) -> _Sums:
    """:class:`_Sums` over the rows ``rows`` of the system."""
    import scipy.sparse  # noqa: PLC0415

    n_points = system.n_points
    A, rk, P, pk = system.J_c[rows], system.r[rows], system.point_rows[rows], system.row_point[rows]
    seen = pk >= 0
    H_pp = np.zeros((n_points, 3, 3))
    b_p = np.zeros((n_points, 3))
    for i in range(3):
        b_p[:, i] = np.bincount(pk[seen], P[seen, i] * rk[seen], minlength=n_points)
        for j in range(i, 3):
            H_pp[:, i, j] = H_pp[:, j, i] = np.bincount(pk[seen], P[seen, i] * P[seen, j], minlength=n_points)
    # H_pc: each row's point block (3 entries) times its camera row, summed per point
    rows_of = np.flatnonzero(seen)
    W = scipy.sparse.csr_matrix((P[rows_of].ravel(), (np.repeat(3 * pk[rows_of], 3) + np.tile(np.arange(3), len(rows_of)),
                                                      np.repeat(rows_of, 3))), shape=(3 * n_points, len(rows)))
    return _Sums((A.T @ A).toarray(), A.T @ rk, H_pp, b_p, (W @ A).tocsr())


def _point_inverses(H_pp: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each point's ``V^+`` and ``R`` with ``R R^T = V^+`` (eigenvalues below :data:`_POINT_NULL_RATIO` of its
    largest are null: a point left free along that direction, or not seen at all)."""
    values, vectors = np.linalg.eigh(H_pp)
    used = values > _POINT_NULL_RATIO * np.maximum(values[:, 2:], 1e-300)
    inverse_values = np.where(used, 1.0 / np.where(values > 0, values, 1.0), 0.0)
    return (np.einsum("pij,pj,pkj->pik", vectors, inverse_values, vectors),
            vectors * np.sqrt(inverse_values)[:, None, :])


def _point_terms(sums: _Sums, root: NDArray[np.float64], points: NDArray[np.int64] | None = None,
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Schur terms ``H_cp V^+ H_pc``, ``H_cp V^+ b_p`` of the points ``points`` (all by default), by dense
    products (:func:`camcal.geometry.bundle.covariance.point_schur_terms`)."""
    if points is None:
        return point_schur_terms(sums.H_pc, root, sums.b_p)
    return point_schur_terms(sums.H_pc[(3 * points[:, None] + np.arange(3)).ravel()], root[points], sums.b_p[points])


def _point_elimination(system: _System):
    """The points' 3x3 inverses ``V^+``, ``G = V^+ W`` and the reduced system ``S``, ``b`` over every row (Schur
    complement of the points, Triggs et al. 2000, section 6.1), ``S = A^T A - W^T G`` as a sparse product
    (:func:`_influences` depends on its rounding: its leverages near 1 are inverted)."""
    import scipy.sparse  # noqa: PLC0415

    n_points = system.n_points
    sums = _sums(system, np.arange(len(system.r)))
    H_inv, _ = _point_inverses(sums.H_pp)
    S, b, G = sums.AtA, sums.Atr, None
    if n_points:
        G = (scipy.sparse.bsr_matrix((H_inv, np.arange(n_points), np.arange(n_points + 1)),
                                     shape=(3 * n_points, 3 * n_points)) @ sums.H_pc).tocsr()
        S = S - (sums.H_pc.T @ G).toarray()
        b = b - G.T @ sums.b_p.ravel()
    return H_inv, G, S, b


def _steps(state: BundleState, options: BundleOptions, colmap, problem,
           groups: list[NDArray[np.int64]]) -> list[BundleState]:
    """The one-step replicate of ``state`` without each group of frames (module docstring).

    Every sum over the rows kept is the full one less the sum over the rows that go (the group's, and those of
    the points left with fewer than two observations): a few frames' worth, however long the plate. The points'
    Schur terms are then summed again over the points the group touches (their 3x3 blocks changed), the full
    ones of those points taken out, unless they are most of the points (a short plate, long tracks): then over
    every point.
    """
    system = _system(state, options, colmap, problem)
    full = _sums(system, np.arange(len(system.r)))
    _, full_root = _point_inverses(full.H_pp)
    full_terms = None
    replicates = []
    for group in groups:
        deleted = np.isin(system.row_frame, group)
        counts = np.bincount(system.row_point[~deleted & (system.row_point >= 0)], minlength=system.n_points) // 2
        kept = ~deleted & ((system.row_point < 0) | (counts[np.maximum(system.row_point, 0)] >= 2))
        sums = full - _sums(system, np.flatnonzero(~kept))
        # a point with no row left: its sums cancel to rounding, not to 0
        sums.H_pp[counts < 2] = 0.0
        sums.b_p[counts < 2] = 0.0
        _, root = _point_inverses(sums.H_pp)
        touched = np.unique(system.row_point[~kept & (system.row_point >= 0)])
        if len(touched) < _UPDATE_BELOW * system.n_points:
            if full_terms is None:
                full_terms = _point_terms(full, full_root)
            before, after = _point_terms(full, full_root, touched), _point_terms(sums, root, touched)
            terms, vector = full_terms[0] - before[0] + after[0], full_terms[1] - before[1] + after[1]
        else:
            terms, vector = _point_terms(sums, root)
        S, b = sums.AtA - terms, sums.Atr - vector
        # a frame left with no rows: its terms cancel to rounding, not to 0
        rows_left = np.bincount(system.row_frame[kept & (system.row_frame >= 0)], minlength=len(state.frame_R))
        for block in system.blocks:
            if block.kind == "frame" and rows_left[block.index] == 0:
                S[block.columns, :] = S[:, block.columns] = b[block.columns] = 0.0
        delta_c = -_pseudo_solve(S, b, singular=bool(np.isin(group, system.gauge).any()))
        replicates.append(_apply(state, system.blocks, delta_c))
    return replicates


def _inverse_factor(S: NDArray[np.float64]) -> NDArray[np.float64]:
    """``F`` with ``F F^T = S^+`` for a symmetric positive semi-definite ``S`` (Jacobi-scaled eigen-decomposition,
    null directions dropped as :func:`_pseudo_solve` drops them)."""
    d = np.diag(S).copy()
    scale = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 0.0)
    values, vectors = np.linalg.eigh(S * np.outer(scale, scale))
    keep = values > _NULL_RATIO * values[-1]
    return scale[:, None] * vectors[:, keep] / np.sqrt(values[keep])


def _pinv_sqrt(blocks: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(B^+)^(1/2)`` of each symmetric positive semi-definite block ``B`` (shape (n, c, c)); eigenvalues
    below :data:`_LEVERAGE_NULL` of the largest are null."""
    values, vectors = np.linalg.eigh(blocks)
    used = values > _LEVERAGE_NULL * np.maximum(values[:, -1:], 1e-300)
    return np.einsum("nij,nj,nkj->nik", vectors, np.where(used, 1.0 / np.sqrt(np.where(used, values, 1.0)), 0.0),
                     vectors)


def _influences(system: _System) -> list[NDArray[np.float64]]:
    """Each frame's influence on the camera, rig and frame columns (:func:`frame_influences`)."""
    import scipy.sparse  # noqa: PLC0415

    n_rows, n_c = system.J_c.shape
    H_inv, G, S, _ = _point_elimination(system)
    F = _inverse_factor(S)
    S_plus = F @ F.T
    P, pk = system.point_rows, system.row_point
    seen = pk >= 0
    # A - P V^+ W row by row (each row with its point eliminated), one frame at a time and only on the columns it
    # touches (the intrinsics, the rig, the frames that share its points): dense over every row and column it
    # would be observations x (cameras + frames), and each frame's products (cameras + frames)^2
    G_rows = None if G is None else scipy.sparse.csr_matrix(
        (P[seen].ravel(), (np.repeat(np.flatnonzero(seen), 3), (3 * pk[seen, None] + np.arange(3)).ravel())),
        shape=(n_rows, G.shape[0]))
    out, roots = [], {}
    for frame in np.unique(system.row_frame[system.row_frame >= 0]):
        rows = np.flatnonzero(system.row_frame == frame)
        key = np.where(pk[rows] >= 0, pk[rows], -1 - np.arange(len(rows)))  # a row without a point: its own block
        rows = rows[np.argsort(key, kind="stable")]
        key = np.sort(key, kind="stable")
        _, starts, counts = np.unique(key, return_index=True, return_counts=True)
        X_sparse = system.J_c[rows]
        if G_rows is not None:
            X_sparse = (X_sparse - G_rows[rows] @ G).tocsr()
        columns = np.flatnonzero(np.bincount(X_sparse.indices, minlength=n_c))  # np.unique without its sort
        X, z = X_sparse[:, columns].toarray(), system.r[rows].copy()
        # D^(+1/2), D = I - P_k V^+ P_k^T: block diagonal, one block per point (its rows in this frame)
        for c in np.unique(counts):
            at = starts[counts == c, None] + np.arange(c)  # (n, c) positions in rows
            Pb = P[rows[at]]
            points = pk[rows[at[:, 0]]]
            D = np.eye(c) - np.einsum("nci,nij,ndj->ncd", Pb, H_inv[np.maximum(points, 0)], Pb) * (points >= 0)[:, None, None]
            root = _pinv_sqrt(D)
            X[at] = np.einsum("ncd,ndq->ncq", root, X[at])
            z[at] = np.einsum("ncd,nd->nc", root, z[at])
        # (I - H_kk)^+ = D^(+1/2) (I - E E^T)^+ D^(+1/2), E = D^(+1/2) X_k F. E E^T = X Q X^T with Q = S^+ on the
        # frame's columns: any R with R R^T = Q gives E' = X R with E's left singular vectors and singular values
        # (the nonzero ones; zero ones add nothing below), so the (columns x columns) eigen-decomposition is of
        # E'^T E' = R^T (X^T X) R over the frame's columns alone. By its eigenvectors V (eigenvalues s^2), E''s left
        # singular vectors are E' V / s: u = z + E' V diag(w) V^T E'^T z, w = 1 / (1 - s^2), or -1 / s^2 where
        # 1 - s^2 is null; only X^T u is wanted (:func:`_leverage_corrected`)
        key = columns.tobytes()
        if key not in roots:  # frames of a closed set all touch every column: one root serves them
            roots = {key: _psd_root(S_plus[np.ix_(columns, columns)])}
        out.append(S_plus[:, columns] @ _leverage_corrected(X, z, roots[key]))
    return out


def _leverage_corrected(X: NDArray[np.float64], z: NDArray[np.float64], R: NDArray[np.float64]) -> NDArray[np.float64]:
    """``X^T u``, ``u = z + E V diag(w) V^T E^T z`` of :func:`_influences` (``E = X R``), without ``E``.

    With ``M = X^T X`` and ``y = X^T z``: ``E^T E = R^T M R``, ``E^T z = R^T y`` and ``X^T u = y + M R h``,
    ``h = V diag(w) V^T R^T y``: one product over the frame's rows (``M``, where ``E`` and ``E^T E`` took two),
    the rest on the frame's columns. ``h`` needs the eigenvectors of ``K = R^T M R`` only where ``1 - s^2`` is
    null (``w = -1 / s^2``; a few: the frame's own pose): elsewhere ``V diag(1 / (1 - s^2)) V^T`` is the inverse
    of ``I - K`` there, solved by Cholesky of ``I - K + N N^T`` (``N`` those few eigenvectors, which the added
    term lifts to ``2 - s^2``). On a plate whose frames all share points (every column in every frame) this
    replaces a full eigen-decomposition and two products over the frame's rows per frame, each growing with the
    cube of the frame count (the eigenpairs of an interval alone: LAPACK's ``syevr``, Dhillon, I. S. & Parlett,
    B. N. (2004). Multiple representations to compute orthogonal eigenvectors of symmetric tridiagonal matrices.
    Linear Algebra and its Applications 387).
    """
    import scipy.linalg  # noqa: PLC0415

    M = scipy.linalg.blas.dsyrk(1.0, X.T)  # upper triangle of X^T X (X.T: Fortran order, no copy)
    M = np.triu(M) + np.triu(M, 1).T
    y = X.T @ z
    K = R.T @ M @ R
    K = 0.5 * (K + K.T)
    g = R.T @ y
    squares, N = scipy.linalg.eigh(K, subset_by_value=(1.0 - _LEVERAGE_NULL, np.inf), driver="evr")
    along = N.T @ g
    try:
        factor = scipy.linalg.cho_factor(np.eye(len(K)) - K + N @ N.T, lower=True)
        h = scipy.linalg.cho_solve(factor, g - N @ along) - N @ (along / squares)
    except np.linalg.LinAlgError:  # a leverage at the threshold's rounding: every eigenpair, as the weights say
        squares, V = np.linalg.eigh(K)
        gap = 1.0 - squares
        kept = gap > _LEVERAGE_NULL
        h = V @ (np.where(kept, 1.0 / np.where(kept, gap, 1.0), -1.0 / np.where(kept, 1.0, squares)) * (V.T @ g))
    return y + M @ (R @ h)


def _psd_root(Q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R`` with ``R R^T = Q`` for a symmetric positive semi-definite ``Q`` (its eigen-decomposition, rounding's
    negative eigenvalues as 0)."""
    values, vectors = np.linalg.eigh(Q)
    return vectors * np.sqrt(np.clip(values, 0.0, None))


def _apply(state: BundleState, blocks: list[_Block], delta: NDArray[np.float64]) -> BundleState:
    """The state moved by a tangent-space step of its cameras, rig sensors and frames (Ceres' manifolds)."""
    params = [p.copy() for p in state.params]
    sensor_R, sensor_t = state.sensor_R.copy(), state.sensor_t.copy()
    frame_R, frame_t = state.frame_R.copy(), state.frame_t.copy()
    for block in blocks:
        if block.kind == "point":
            continue
        d = delta[block.columns]
        if block.kind == "camera":
            params[block.index][list(block.free)] += d
            continue
        # Ceres' EigenQuaternionManifold: q' = [sin|d| d/|d|, cos|d|] q, a rotation vector 2 d applied on the left
        rotation = Rotation.from_rotvec(2.0 * d[:3]).as_matrix()
        if block.kind == "sensor":
            sensor_R[block.index] = rotation @ sensor_R[block.index]
            sensor_t[block.index] = sensor_t[block.index] + d[3:]
        else:
            frame_R[block.index] = rotation @ frame_R[block.index]
            frame_t[block.index, list(block.free)] += d[3:]
    return dataclasses.replace(state, params=tuple(params), sensor_R=sensor_R, sensor_t=sensor_t, frame_R=frame_R,
                               frame_t=frame_t)


def one_step_replicates(state: BundleState, options: BundleOptions,
                        groups: list[NDArray[np.int64]]) -> list[BundleState]:
    """The solution without each group of frames, by one Gauss-Newton step from ``state`` (module docstring).

    Parameters
    ----------
    state : BundleState
        A converged bundle adjustment (every frame).
    options : BundleOptions
        The options it was solved with (what is free, the loss).
    groups : list of ndarray of int
        Frame positions left out together, one replicate per entry.

    Returns
    -------
    list of BundleState
        One per group: the intrinsics, rig and frame poses moved by the step
        (points as in ``state``).

    Raises
    ------
    DeletionUnsupported
        A board, constant points, or a gauge other than COLMAP's two frames
        or one held frame: use full refits.
    """
    out: list[list[BundleState]] = []

    def inspect(problem, colmap) -> None:
        out.append(_steps(state, options, colmap, problem, groups))

    bundle_adjust(state, dataclasses.replace(options, max_iterations=0, compute_sigmas=False), inspect=inspect)
    return out[0]



@dataclasses.dataclass(frozen=True)
class FrameInfluences:
    """Each frame's influence on a bundle adjustment's intrinsics, rig poses and scene gauge.

    Attributes
    ----------
    names : tuple of str
        :attr:`camcal.geometry.bundle.BundleResult.covariance_names`' names
        (``CAMERA.f``..., ``CAMERA.rx``..., ``gauge.rx``...; rotations as
        rotation vectors).
    values : ndarray, shape (n_frames, len(names))
        ``theta_(k) - theta`` of each frame ``k``: the solution without its
        observations, to first order (:func:`frame_influences`).
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]


def frame_influences(state: BundleState, options: BundleOptions) -> FrameInfluences:
    """How much leaving out each frame moves the solution, the scene gauge included (module docstring).

    Raises
    ------
    DeletionUnsupported
        As :func:`one_step_replicates`.
    """
    out: list[FrameInfluences] = []

    def inspect(problem, colmap) -> None:
        system = _system(state, options, colmap, problem)
        influences = _influences(system)
        names, columns, scales = [], [], []
        for block in system.blocks:
            if block.kind == "camera":
                param_names = state.param_names(block.index)
                names += [f"{state.camera_names[block.index]}.{param_names[k]}" for k in block.free]
                scales += [1.0] * len(block.free)
            elif block.kind == "sensor":
                names += [f"{state.camera_names[block.index]}.{axis}" for axis in ("rx", "ry", "rz", "tx", "ty", "tz")]
                scales += [2.0, 2.0, 2.0, 1.0, 1.0, 1.0]  # Ceres' quaternion tangent is half the rotation vector
            else:
                continue
            columns += list(range(block.columns.start, block.columns.stop))
        B = np.zeros((len(names), system.J_c.shape[1]))
        B[np.arange(len(names)), columns] = scales
        frames = sorted(colmap.frame_ids.items())
        rows = scene_gauge_rows([colmap.reconstruction.frame(fid).rig_from_world.rotation.matrix() for _, fid in frames])
        if rows is not None:  # the scene gauge of the frames' turns, held frames unperturbed (as the covariance's)
            gauge = np.zeros((3, B.shape[1]))
            for i, (frame, _) in enumerate(frames):
                for block in system.blocks:
                    if block.kind == "frame" and block.index == frame:
                        gauge[:, block.columns.start:block.columns.start + 3] = 2.0 * rows[:, 3 * i:3 * i + 3]
            B = np.vstack([B, gauge])
            names += ["gauge.rx", "gauge.ry", "gauge.rz"]
        out.append(FrameInfluences(tuple(names), np.array([B @ g for g in influences])))

    bundle_adjust(state, dataclasses.replace(options, max_iterations=0, compute_sigmas=False), inspect=inspect)
    return out[0]
