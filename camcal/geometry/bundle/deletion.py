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

The frames' influences on the projection sigma
(:mod:`camcal.geometry.bundle.influences`) are the same steps with the
directions the rows kept leave free chosen as the whole problem would
(:meth:`FrameDeletion.step` returns a basis of them).

References
----------
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals
of Statistics 9.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.bundle.covariance import is_free_block, point_schur_terms, point_schur_vector
from camcal.geometry.bundle.prior import resolve_priors
from camcal.geometry.bundle.solve import bundle_adjust
from camcal.geometry.bundle.state import BundleOptions, BundleState, model_layout

__all__ = ["DeletionUnsupported", "FrameDeletion", "LinearisedBundle", "linearise", "apply_step",
           "one_step_replicates", "prior_sums", "split_priors"]

#: eigenvalues of the Jacobi-scaled reduced system below this share of the largest are its null space (the gauge).
_NULL_RATIO = 1e-11
#: a point's 3x3 block with ``lambda_min`` below this share of ``lambda_max`` is left free along that direction.
_POINT_NULL_RATIO = 1e-10
#: a replicate's points' Schur terms are the full ones with those of the points the group touches taken out and put
#: back without it when they are fewer than this share of the points (two sums over them against one over every
#: point); else they are summed again over every point.
_UPDATE_BELOW = 0.5


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


def _pseudo_solve(S: NDArray[np.float64], b: NDArray[np.float64], singular: bool,
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``S^+ b`` for a symmetric positive semi-definite ``S`` and a basis of ``S``'s null space (columns):
    Cholesky unless ``singular`` or it fails, else eigen. ``b``: one right side, or several (columns).

    ``singular``: ``S`` is known to have a null space (the group held a gauge
    frame). Cholesky would not reliably refuse it: the Jacobi-scaled
    pivot of a null direction is rounding (1e-16 to 1e-13), on either side
    of any threshold, and where it passes the step gains a null-space
    component of ``b``'s rounding over that pivot, a different one per run
    (the baseline direction's jackknife sigma moved by 1e-4 relative when
    the solution moved by 1e-11). The eigen-decomposition drops it. The
    null space: the columns with nothing on the diagonal and the
    eigenvectors dropped (Jacobi scaling undone).
    """
    import scipy.linalg  # noqa: PLC0415

    out = np.zeros_like(b)
    d = np.diag(S).copy()
    used = d > 0
    null = np.eye(len(b))[:, ~used]
    if not np.any(used):
        return out, null
    scale = 1.0 / np.sqrt(d[used])
    scaled = S[np.ix_(used, used)] * np.outer(scale, scale)
    column = (-1,) + (1,) * (b.ndim - 1)  # a vector per row, against one right side or several
    row_scale = scale.reshape(column)
    rhs = b[used] * row_scale
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
        x = vectors[:, keep] @ ((vectors[:, keep].T @ rhs) / values[keep].reshape(column))
        dropped = np.zeros((len(b), int(np.sum(~keep))))
        dropped[used] = scale[:, None] * vectors[:, ~keep]
        null = np.hstack([null, dropped])
    out[used] = x * row_scale
    return out, null


@dataclasses.dataclass
class LinearisedBundle:
    """A bundle adjustment linearised at its solution (Ceres' Jacobian and residuals, the loss applied).

    Attributes
    ----------
    blocks : list
        The free parameter blocks in column order (``kind``: camera, sensor, frame or point; ``index``: its
        position in the state; ``columns``: its slice; ``free``: a camera's free COLMAP parameters, a frame's
        free translation axes).
    J_c : scipy.sparse.csr_matrix
        The Jacobian's camera, rig and frame columns (rows x columns).
    point_rows : ndarray, shape (rows, 3)
        Each row's derivative by its point (zero where it has no free point).
    r : ndarray
        The residuals.
    row_frame, row_point : ndarray of int
        Each row's frame and point (-1: none, e.g. a prior's row).
    n_points : int
        Free points.
    n_frames : int
        Frames in the state.
    gauge : list of int
        Frame positions that hold the gauge (constant, or with a held translation axis).
    """

    blocks: list[_Block]
    J_c: object
    point_rows: NDArray[np.float64]
    r: NDArray[np.float64]
    row_frame: NDArray[np.int64]
    row_point: NDArray[np.int64]
    n_points: int
    n_frames: int
    gauge: list[int]


def linearise(state: BundleState, options: BundleOptions, colmap, problem) -> LinearisedBundle:
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
    return LinearisedBundle(blocks, J[:, :n_c].tocsr(), point_rows, r, row_frame, row_point, n_points,
                            len(state.frame_R), gauge)


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


def _sums(system: LinearisedBundle, rows: NDArray[np.int64]) -> _Sums:
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


class FrameDeletion:
    """The one-step moves of a linearised bundle adjustment without groups of frames (module docstring).

    Every sum over the rows kept is the full one less the sum over the rows that go (the group's, and those of
    the points left with fewer than two observations): a few frames' worth, however long the plate. The points'
    Schur terms are then summed again over the points the group touches (their 3x3 blocks changed), the full
    ones of those points taken out, unless they are most of the points (a short plate, long tracks): then over
    every point.

    Parameters
    ----------
    system : LinearisedBundle
        The problem at its solution (:func:`linearise`).
    """

    def __init__(self, system: LinearisedBundle) -> None:
        self.system = system
        self._full = _sums(system, np.arange(len(system.r)))
        self._full_root = _point_inverses(self._full.H_pp)[1]

    @functools.cached_property
    def _full_terms(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return _point_terms(self._full, self._full_root)

    @functools.cached_property
    def reduced(self) -> NDArray[np.float64]:
        """``S``: the reduced system of every row on the camera, rig and frame columns (points eliminated)."""
        return self._full.AtA - self._full_terms[0]

    def step(self, group: NDArray[np.int64], group_gradient: bool = False,
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The move of the camera, rig and frame columns without the frames ``group`` and a basis (columns) of
        the directions the rows kept leave free: the group's frame poses, and the gauge where the group held
        it (the step has no component along them).

        ``group_gradient``: the move the rows that go make, ``(J_(g)^T J_(g))^+ J_g^T r_g``, without the step
        of the whole problem's gradient at its solution (its solver's tolerance, the same for every group):
        the Woodbury form's move (:mod:`camcal.geometry.bundle.influences`)."""
        S, b, b_group, singular = self._reduced(group, step=not group_gradient, own=group_gradient)
        delta, free = _pseudo_solve(S, b_group if group_gradient else b, singular)
        return -delta, free

    def moves(self, group: NDArray[np.int64], step_priors: tuple[NDArray[np.float64], NDArray[np.float64]],
              own_priors: tuple[NDArray[np.float64], NDArray[np.float64]],
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`step`'s two moves without the frames ``group`` from one set of sums, on a system of
        observations alone (:func:`split_priors`): the replicate's step with the priors' normal equations
        ``step_priors`` added, the group's own move (``group_gradient``) with ``own_priors``, and the basis of
        the directions the rows kept leave free (of the latter).

        Every group keeps the priors' rows, so each problem is the observations' reduced system plus its priors'
        sums: two problems that differ only in their priors (the self-calibration's replicates and its fit)
        share the sums over the group. The same priors for both: one factorisation solves both.
        """
        S, b, b_group, singular = self._reduced(group, step=True, own=True)
        if step_priors is own_priors:
            both, free = _pseudo_solve(S + own_priors[0], np.column_stack([b + own_priors[1], b_group]), singular)
            return -both[:, 0], -both[:, 1], free
        step = _pseudo_solve(S + step_priors[0], b + step_priors[1], singular)[0]
        own, free = _pseudo_solve(S + own_priors[0], b_group, singular)
        return -step, -own, free

    def _reduced(self, group: NDArray[np.int64], step: bool, own: bool,
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None, bool]:
        """The reduced system without the frames ``group``, the right sides of its step (``step``) and of the
        group's own move (``own``; :meth:`step`), and whether the group held the gauge."""
        system, full = self.system, self._full
        deleted = np.isin(system.row_frame, group)
        counts = np.bincount(system.row_point[~deleted & (system.row_point >= 0)], minlength=system.n_points) // 2
        kept = ~deleted & ((system.row_point < 0) | (counts[np.maximum(system.row_point, 0)] >= 2))
        gone = _sums(system, np.flatnonzero(~kept))
        sums = full - gone
        # a point with no row left: its sums cancel to rounding, not to 0
        sums.H_pp[counts < 2] = 0.0
        sums.b_p[counts < 2] = 0.0
        _, root = _point_inverses(sums.H_pp)
        touched = np.unique(system.row_point[~kept & (system.row_point >= 0)])
        if len(touched) < _UPDATE_BELOW * system.n_points:
            before, after = _point_terms(full, self._full_root, touched), _point_terms(sums, root, touched)
            terms = self._full_terms[0] - before[0] + after[0]
            vector = self._full_terms[1] - before[1] + after[1]
        else:
            terms, vector = _point_terms(sums, root)
        S = sums.AtA - terms
        b = sums.Atr - vector if step else None
        # the points' 3x3 blocks without the group, their gradient the group's
        b_group = -(gone.Atr - point_schur_vector(sums.H_pc, root, gone.b_p * (counts >= 2)[:, None])) if own else None
        # a frame left with no rows: its terms cancel to rounding, not to 0
        rows_left = np.bincount(system.row_frame[kept & (system.row_frame >= 0)], minlength=system.n_frames)
        for block in system.blocks:
            if block.kind == "frame" and rows_left[block.index] == 0:
                S[block.columns, :] = S[:, block.columns] = 0.0
                for right in (b, b_group):
                    if right is not None:
                        right[block.columns] = 0.0
        return S, b, b_group, bool(np.isin(group, system.gauge).any())


def _observed(system: LinearisedBundle) -> NDArray[np.bool_]:
    """The rows of an observation (of a frame or a point); the others are priors on the intrinsics."""
    return (system.row_frame >= 0) | (system.row_point >= 0)


def split_priors(system: LinearisedBundle,
                 ) -> tuple[LinearisedBundle, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """The system's observations' rows alone, and the normal equations ``(P^T P, P^T r)`` of its other rows
    (priors on the intrinsics: of no frame and no point, kept by every group) on its camera, rig and frame
    columns (:meth:`FrameDeletion.moves`)."""
    observed = _observed(system)
    rows, P = np.flatnonzero(observed), system.J_c[np.flatnonzero(~observed)]
    alone = dataclasses.replace(system, J_c=system.J_c[rows], point_rows=system.point_rows[rows], r=system.r[rows],
                                row_frame=system.row_frame[rows], row_point=system.row_point[rows])
    return alone, ((P.T @ P).toarray(), P.T @ system.r[~observed])


def prior_sums(state: BundleState, system: LinearisedBundle, options: BundleOptions, other: BundleOptions,
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The normal equations ``(P^T P, P^T r)`` of the priors ``other`` puts on the problem that ``system``
    linearises with ``options`` (:func:`split_priors`' second part for ``other``, without building its problem).

    Each prior is a row ``w (a . x - mean)`` with ``w = s / sigma`` on one camera's parameters
    (:mod:`camcal.geometry.bundle.prior`): ``s``, the noise both problems weigh their priors with (it is the
    observations'), is read from ``system``'s own prior rows, and ``other``'s rows are made with it. None when
    those rows are not the priors ``options`` resolves to, row by row (then ``other``'s problem is to be
    linearised on its own).
    """
    columns = {}
    for block in system.blocks:
        if block.kind == "camera":
            columns.update({(block.index, i): block.columns.start + k for k, i in enumerate(block.free)})
    free = {camera: {i for c, i in columns if c == camera} for camera, _ in columns}

    def rows(specs: BundleOptions) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Each prior's row for ``w = 1``, its ``a . x - mean`` and its sigma."""
        priors = resolve_priors(state, specs.priors, specs.default_priors, free)[0]
        unit = np.zeros((len(priors), system.J_c.shape[1]))
        for k, prior in enumerate(priors):
            for i, coefficient in zip(prior.indices, prior.coefficients):
                if (prior.camera, i) in columns:
                    unit[k, columns[prior.camera, i]] = coefficient
        offsets = np.array([prior.value(state.params[prior.camera]) - prior.mean for prior in priors])
        return unit, offsets, np.array([prior.sigma for prior in priors])

    observed = _observed(system)
    P, r = system.J_c[np.flatnonzero(~observed)].toarray(), system.r[~observed]
    unit, offsets, sigmas = rows(options)
    if len(P) != len(unit) or len(P) == 0:
        return None
    weights = np.sum(P * unit, axis=1) / np.sum(unit * unit, axis=1)
    noise = weights * sigmas
    if not (np.allclose(noise, noise[0], rtol=1e-12, atol=0)
            and np.allclose(P, weights[:, None] * unit, rtol=1e-12, atol=0)
            and np.allclose(r, weights * offsets, rtol=1e-9, atol=1e-12 * max(np.abs(r).max(), 1.0))):
        return None
    unit, offsets, sigmas = rows(other)
    Q = (noise[0] / sigmas)[:, None] * unit
    return Q.T @ Q, Q.T @ ((noise[0] / sigmas) * offsets)


def apply_step(state: BundleState, blocks: list[_Block], delta: NDArray[np.float64]) -> BundleState:
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
        system = linearise(state, options, colmap, problem)
        deletion = FrameDeletion(system)
        out.append([apply_step(state, system.blocks, deletion.step(group)[0]) for group in groups])

    bundle_adjust(state, dataclasses.replace(options, max_iterations=0, compute_sigmas=False), inspect=inspect)
    return out[0]
