"""Rig-aware bundle adjustment: camcal's refinement after a pycolmap seed.

The state (:class:`BundleState`) is what structure from motion gives:
physical cameras with intrinsics shared over all frames, one
``sensor_from_rig`` pose per camera shared over all frames (a stereo rig
moved around; the first camera is the rig's reference), one
``rig_from_world`` pose per frame, sparse 3D points and their observations;
optionally chessboard corners as *known* 3D points on a board whose pose in
the world is unknown (:class:`BoardObservations`), which also fixes the
scale. Every pose maps ``X_to = R X_from + t`` (COLMAP's ``Rigid3d``).

Intrinsics live in COLMAP's parameter vectors (focal, principal point,
extra), so that a refinement of the same reconstruction with the same model
and loss minimises exactly the cost that ``pycolmap.bundle_adjustment``
minimises; projection goes through camcal's own models
(:func:`camcal.io.colmap.camera_from_colmap`, exact to 1e-8 px).

The cost is Ceres' ``1/2 sum_i rho(|r_i|^2)`` over the 2-vector residual of
each observation, with Ceres' losses (scale ``a``)::

    trivial  rho(s) = s
    huber    rho(s) = s              if s <= a^2,   2 a sqrt(s) - a^2 otherwise
    soft_l1  rho(s) = 2 a^2 (sqrt(1 + s / a^2) - 1)
    cauchy   rho(s) = a^2 log(1 + s / a^2)

It is minimised by Levenberg-Marquardt (Marquardt's diagonal damping, Nielsen's
update of the damping) on the reweighted residuals ``sqrt(rho'(s_i)) r_i`` and
Jacobian rows ``sqrt(rho'(s_i)) J_i`` (Triggs et al. 2000, section 4.3, without
the second-order correction, as Ceres does for losses with ``rho'' <= 0``), with a finite-difference Jacobian evaluated by
column groups that share no residual (Curtis, Powell & Reid 1974) and each
step solved exactly on the reduced camera system: the points are eliminated
by their 3x3 blocks (Schur complement), the rest solved by Cholesky. The gauge is fixed by holding the first frame's
pose and, when nothing else sets the scale (a rig held at a known
calibration, or a board), the largest coordinate of the second frame's
translation (as COLMAP's ``TWO_CAMS_FROM_WORLD``).

Uncertainty: ``Sigma = sigma^2 S^-1`` with ``S`` the Schur complement of the
points in ``J^T J`` (points marginalised) and ``sigma^2 = 2 cost / (m - n)``
(Triggs et al. 2000, section 6; Hartley & Zisserman 2004, section 5.2).

References
----------
Curtis, A. R., Powell, M. J. D. & Reid, J. K. (1974). On the estimation of
sparse Jacobian matrices. IMA J. Appl. Math. 13, 117-119.
Nielsen, H. B. (1999). Damping parameter in Marquardt's method. IMM-REP-1999-05.
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Agarwal, S., Mierle, K. et al. Ceres Solver: loss functions
(``ceres/loss_function.h``).
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from camcal.errors import CamcalError
from camcal.io.colmap import camera_from_colmap

__all__ = [
    "LOSSES",
    "BoardObservations",
    "BundleOptions",
    "BundleResult",
    "BundleState",
    "bundle_adjust",
    "robust_cost",
    "state_from_reconstruction",
    "state_to_reconstruction",
    "hold_rig",
    "attach_board",
]

LOSSES = ("trivial", "huber", "soft_l1", "cauchy")

# Indices of (focal, principal point) in COLMAP's parameter vectors; the rest is "extra".
_FOCAL_PP: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "SIMPLE_PINHOLE": ((0,), (1, 2)),
    "PINHOLE": ((0, 1), (2, 3)),
    "SIMPLE_RADIAL": ((0,), (1, 2)),
    "RADIAL": ((0,), (1, 2)),
    "OPENCV": ((0, 1), (2, 3)),
    "FULL_OPENCV": ((0, 1), (2, 3)),
    "SIMPLE_DIVISION": ((0,), (1, 2)),
}
_PARAM_NAMES: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_DIVISION": ("f", "cx", "cy", "k"),
}


@dataclass(frozen=True)
class BoardObservations:
    """Chessboard corners seen in the SfM images: known 3D points on a board.

    Attributes
    ----------
    object_points : ndarray, shape (M, 3)
        Corners in the board's frame, in the board's units (they set the
        reconstruction's scale).
    camera, frame : ndarray of int, shape (N,)
        Camera index and frame position (into :attr:`BundleState.frame_R`)
        of each observation.
    corner : ndarray of int, shape (N,)
        Index into ``object_points``.
    xy : ndarray, shape (N, 2)
        Observed pixels (camcal convention: top-left pixel centre at 0, 0).
    """

    object_points: NDArray[np.float64]
    camera: NDArray[np.int64]
    frame: NDArray[np.int64]
    corner: NDArray[np.int64]
    xy: NDArray[np.float64]


@dataclass(frozen=True)
class BundleState:
    """Cameras, rig, frames, points and observations of a reconstruction.

    Attributes
    ----------
    camera_names : tuple of str
    models : tuple of str
        COLMAP model name per camera.
    image_sizes : tuple of (int, int)
    params : tuple of ndarray
        COLMAP parameter vector per camera (COLMAP's pixel convention).
    sensor_R, sensor_t : ndarray, shapes (C, 3, 3), (C, 3)
        ``sensor_from_rig`` per camera; camera 0 is the reference (identity).
    frame_R, frame_t : ndarray, shapes (F, 3, 3), (F, 3)
        ``rig_from_world`` per frame.
    frame_ids : tuple of int
        The frames' ids in their source (COLMAP frame ids).
    points : ndarray, shape (P, 3)
    point_ids : tuple of int
    obs_camera, obs_frame, obs_point : ndarray of int, shape (N,)
    obs_xy : ndarray, shape (N, 2)
        Observed pixels, camcal convention.
    board : BoardObservations or None
    board_R, board_t : ndarray or None
        ``world_from_board`` when a board is present.
    """

    camera_names: tuple[str, ...]
    models: tuple[str, ...]
    image_sizes: tuple[tuple[int, int], ...]
    params: tuple[NDArray[np.float64], ...]
    sensor_R: NDArray[np.float64]
    sensor_t: NDArray[np.float64]
    frame_R: NDArray[np.float64]
    frame_t: NDArray[np.float64]
    frame_ids: tuple[int, ...]
    points: NDArray[np.float64]
    point_ids: tuple[int, ...]
    obs_camera: NDArray[np.int64]
    obs_frame: NDArray[np.int64]
    obs_point: NDArray[np.int64]
    obs_xy: NDArray[np.float64]
    board: BoardObservations | None = None
    board_R: NDArray[np.float64] | None = None
    board_t: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        for model in self.models:
            if model not in _FOCAL_PP:
                raise CamcalError(
                    f"bundle adjustment supports the COLMAP models {', '.join(_FOCAL_PP)}, not {model!r}"
                )
        if len(self.obs_xy) == 0:
            raise CamcalError("bundle adjustment needs observations; the reconstruction has none")
        if not np.all(np.isfinite(self.obs_xy)) or not np.all(np.isfinite(self.points)):
            raise CamcalError("bundle adjustment input has NaN or infinite observations or points")

    def scaled(self, factor: float) -> BundleState:
        """The same reconstruction with the world scaled by ``factor`` (translations and points)."""
        return dataclasses.replace(
            self, sensor_t=self.sensor_t * factor, frame_t=self.frame_t * factor, points=self.points * factor,
            board_t=None if self.board_t is None else self.board_t * factor,
        )

    def param_names(self, camera: int) -> tuple[str, ...]:
        """COLMAP's names of camera ``camera``'s parameters."""
        return _PARAM_NAMES[self.models[camera]]


@dataclass(frozen=True)
class BundleOptions:
    """What to refine and how (COLMAP's ``BundleAdjustmentOptions`` names)."""

    refine_focal_length: bool = True
    refine_principal_point: bool = False
    refine_extra_params: bool = True
    refine_sensor_from_rig: bool = True
    refine_points3D: bool = True
    loss: str = "trivial"
    loss_scale: float = 1.0
    max_iterations: int = 200
    tolerance: float = 1e-10

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise CamcalError(f"unknown loss {self.loss!r}, expected one of: {', '.join(LOSSES)}")
        if not self.loss_scale > 0:
            raise CamcalError(f"loss scale must be positive, got {self.loss_scale!r}")


@dataclass(frozen=True)
class BundleResult:
    """The refined state and what the refinement measured.

    Attributes
    ----------
    state : BundleState
    initial_cost, final_cost : float
        Ceres' cost ``1/2 sum rho(|r|^2)`` before and after.
    rms_before_px, rms_after_px : dict of str to float
        Plain reprojection RMS per camera (and ``"board"`` when present).
    sigmas : dict of str to float
        One-sigma of each free intrinsic (``camera.f``...) and of each
        refined rig pose (``camera.rotation_deg``, ``camera.baseline_direction_deg``,
        ``camera.baseline_rel``), points marginalised.
    n_iterations : int
    n_residuals, n_parameters : int
    """

    state: BundleState
    initial_cost: float
    final_cost: float
    rms_before_px: dict[str, float]
    rms_after_px: dict[str, float]
    sigmas: dict[str, float] = field(default_factory=dict)
    n_iterations: int = 0
    n_residuals: int = 0
    n_parameters: int = 0

    def summary(self) -> str:
        """Per-camera RMS before -> after and the cost."""
        rows = [f"  {name}: {self.rms_before_px[name]:.4f} -> {self.rms_after_px[name]:.4f} px" for name in self.rms_after_px]
        return "\n".join(
            [f"bundle adjustment: cost {self.initial_cost:.6g} -> {self.final_cost:.6g} "
             f"({self.n_iterations} evaluations, {self.n_residuals} residuals, {self.n_parameters} unknowns)"] + rows
        )


def _rho(s: NDArray[np.float64], loss: str, a: float) -> NDArray[np.float64]:
    """Ceres' loss ``rho(s)`` of the squared residual norm ``s`` (module docstring)."""
    if loss == "trivial":
        return s
    b = a * a
    if loss == "huber":
        return np.where(s <= b, s, 2.0 * a * np.sqrt(s) - b)
    if loss == "soft_l1":
        return 2.0 * b * (np.sqrt(1.0 + s / b) - 1.0)
    return b * np.log1p(s / b)


def _rho_derivative(s: NDArray[np.float64], loss: str, a: float) -> NDArray[np.float64]:
    """``rho'(s)`` of :func:`_rho`."""
    if loss == "trivial":
        return np.ones_like(s)
    b = a * a
    if loss == "huber":
        return np.where(s <= b, 1.0, a / np.sqrt(np.maximum(s, b)))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + s / b)
    return 1.0 / (1.0 + s / b)


def robust_cost(residuals: ArrayLike, loss: str = "trivial", scale: float = 1.0) -> float:
    """Ceres' cost ``1/2 sum_i rho(|r_i|^2)`` of 2-vector residuals (N, 2)."""
    r = np.asarray(residuals, dtype=np.float64).reshape(-1, 2)
    return 0.5 * float(np.sum(_rho(np.sum(r * r, axis=1), loss, scale)))


def _project(state: BundleState, camera: NDArray, frame: NDArray, X: NDArray) -> NDArray[np.float64]:
    """Pixels (camcal convention) of world points X (N, 3) seen by camera[i] at frame[i]."""
    Xr = np.einsum("nij,nj->ni", state.frame_R[frame], X) + state.frame_t[frame]
    Xc = np.einsum("nij,nj->ni", state.sensor_R[camera], Xr) + state.sensor_t[camera]
    out = np.empty((len(X), 2))
    for index, name in enumerate(state.camera_names):
        mask = camera == index
        if not np.any(mask):
            continue
        lens = camera_from_colmap(name, state.models[index], state.image_sizes[index], state.params[index],
                                  np.eye(3), np.zeros(3))
        ideal = Xc[mask, :2] / Xc[mask, 2:3] @ lens.K[:2, :2].T + lens.K[:2, 2]
        out[mask] = lens.distortion.distort(ideal, lens.K)
    return out


def _residuals(state: BundleState) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Reprojection residuals (N, 2) of the points and (B, 2) of the board corners."""
    scene = _project(state, state.obs_camera, state.obs_frame, state.points[state.obs_point]) - state.obs_xy
    if state.board is None:
        return scene, None
    corners = state.board.object_points[state.board.corner] @ state.board_R.T + state.board_t
    return scene, _project(state, state.board.camera, state.board.frame, corners) - state.board.xy


def _measure(state: BundleState, options: BundleOptions) -> tuple[float, dict[str, float]]:
    """Ceres' cost of a state and its plain reprojection RMS per camera (and ``"board"``)."""
    scene, board = _residuals(state)
    rms = {}
    for index, name in enumerate(state.camera_names):
        r = scene[state.obs_camera == index]
        if len(r):
            rms[name] = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    if board is not None:
        rms["board"] = float(np.sqrt(np.mean(np.sum(board * board, axis=1))))
    both = scene if board is None else np.vstack([scene, board])
    return robust_cost(both, options.loss, options.loss_scale), rms


class _Layout:
    """Where each unknown lives in the parameter vector, and the gauge.

    Blocks, in order: free intrinsics per camera; ``sensor_from_rig``
    (rotation-vector increment, translation) of cameras 1..C-1 when refined;
    ``rig_from_world`` of every frame (frame 0 held when the points move, and
    one translation coordinate of frame 1 when nothing else sets the scale);
    the board pose; the points when refined.
    """

    def __init__(self, state: BundleState, options: BundleOptions):
        self.state = state
        self.options = options
        self.intrinsic_index: list[NDArray[np.int64]] = []
        for model in state.models:
            focal, pp = _FOCAL_PP[model]
            extra = tuple(range(len(_PARAM_NAMES[model])))[len(focal) + len(pp):]
            chosen = (focal if options.refine_focal_length else ()) + (pp if options.refine_principal_point else ()) \
                + (extra if options.refine_extra_params else ())
            self.intrinsic_index.append(np.array(sorted(chosen), dtype=np.int64))
        n_cameras, n_frames = len(state.camera_names), len(state.frame_R)
        offset = 0
        self.intrinsic_offset = []
        for index in self.intrinsic_index:
            self.intrinsic_offset.append(offset)
            offset += len(index)
        self.sensor_offset = {}
        if options.refine_sensor_from_rig:
            for camera in range(1, n_cameras):
                self.sensor_offset[camera] = offset
                offset += 6
        # gauge: frame 0 held when the points move; the scale by one translation coordinate
        scale_free = options.refine_points3D and state.board is None and (
            options.refine_sensor_from_rig or n_cameras == 1)
        self.frame_offset: dict[int, tuple[int, NDArray[np.int64]]] = {}
        for frame in range(n_frames):
            if frame == 0 and options.refine_points3D:
                continue
            free = np.arange(6)
            if frame == 1 and scale_free:
                held = 3 + int(np.argmax(np.abs(state.frame_t[1] - state.frame_t[0])))
                free = free[free != held]
            self.frame_offset[frame] = (offset, free)
            offset += len(free)
        if scale_free and n_frames < 2:
            raise CamcalError("bundle adjustment needs at least 2 frames (or a known rig or a board) to fix the scale")
        self.board_offset = None
        if state.board is not None:
            self.board_offset = offset
            offset += 6
        self.point_offset = offset
        if options.refine_points3D:
            offset += 3 * len(state.points)
        self.size = offset
        self.pattern = self._sparsity().tocsc()
        self.groups = self._column_groups()

    def _column_groups(self) -> list[NDArray[np.int64]]:
        """Columns that share no residual row, by block structure (one camera, frame or point per row)."""
        groups: list[list[int]] = []
        for k in range(max((len(index) for index in self.intrinsic_index), default=0)):
            groups.append([self.intrinsic_offset[c] + k for c, index in enumerate(self.intrinsic_index) if k < len(index)])
        for k in range(6):
            groups.append([o + k for o in self.sensor_offset.values()])
            groups.append([o + k for o, free in self.frame_offset.values() if k < len(free)])
            if self.board_offset is not None:
                groups.append([self.board_offset + k])
        if self.options.refine_points3D:
            for k in range(3):
                groups.append(list(self.point_offset + 3 * np.arange(len(self.state.points)) + k))
        return [np.array(group, dtype=np.int64) for group in groups if group]

    def unpack(self, x: NDArray[np.float64]) -> BundleState:
        s = self.state
        params = []
        for camera, index in enumerate(self.intrinsic_index):
            p = s.params[camera].copy()
            p[index] = x[self.intrinsic_offset[camera]:self.intrinsic_offset[camera] + len(index)]
            params.append(p)
        sensor_R, sensor_t = s.sensor_R.copy(), s.sensor_t.copy()
        for camera, o in self.sensor_offset.items():
            sensor_R[camera] = Rotation.from_rotvec(x[o:o + 3]).as_matrix() @ s.sensor_R[camera]
            sensor_t[camera] = x[o + 3:o + 6]
        frame_R, frame_t = s.frame_R.copy(), s.frame_t.copy()
        for frame, (o, free) in self.frame_offset.items():
            six = np.concatenate([np.zeros(3), s.frame_t[frame]])
            six[free] = x[o:o + len(free)]
            frame_R[frame] = Rotation.from_rotvec(six[:3]).as_matrix() @ s.frame_R[frame]
            frame_t[frame] = six[3:]
        board_R, board_t = s.board_R, s.board_t
        if self.board_offset is not None:
            o = self.board_offset
            board_R = Rotation.from_rotvec(x[o:o + 3]).as_matrix() @ s.board_R
            board_t = x[o + 3:o + 6].copy()
        points = x[self.point_offset:].reshape(-1, 3).copy() if self.options.refine_points3D else s.points
        return dataclasses.replace(s, params=tuple(params), sensor_R=sensor_R, sensor_t=sensor_t, frame_R=frame_R,
                                   frame_t=frame_t, points=points, board_R=board_R, board_t=board_t)

    def initial(self) -> NDArray[np.float64]:
        s = self.state
        x = np.zeros(self.size)
        for camera, index in enumerate(self.intrinsic_index):
            x[self.intrinsic_offset[camera]:self.intrinsic_offset[camera] + len(index)] = s.params[camera][index]
        for camera, o in self.sensor_offset.items():
            x[o + 3:o + 6] = s.sensor_t[camera]
        for frame, (o, free) in self.frame_offset.items():
            x[o:o + len(free)] = np.concatenate([np.zeros(3), s.frame_t[frame]])[free]
        if self.board_offset is not None:
            x[self.board_offset + 3:self.board_offset + 6] = s.board_t
        if self.options.refine_points3D:
            x[self.point_offset:] = s.points.ravel()
        return x

    def _sparsity(self) -> scipy.sparse.csr_matrix:
        """Which unknowns each residual row depends on."""
        s = self.state
        rows: list[NDArray] = []
        cols: list[NDArray] = []

        def observation_columns(camera: NDArray, frame: NDArray, first_row: int, extra: list[NDArray]) -> None:
            n = len(camera)
            row_of = first_row + np.arange(n)
            blocks: list[tuple[NDArray, NDArray]] = []
            for c, index in enumerate(self.intrinsic_index):
                sel = np.flatnonzero(camera == c)
                for k in range(len(index)):
                    blocks.append((sel, np.full(len(sel), self.intrinsic_offset[c] + k)))
            for c, o in self.sensor_offset.items():
                sel = np.flatnonzero(camera == c)
                for k in range(6):
                    blocks.append((sel, np.full(len(sel), o + k)))
            for f, (o, free) in self.frame_offset.items():
                sel = np.flatnonzero(frame == f)
                for k in range(len(free)):
                    blocks.append((sel, np.full(len(sel), o + k)))
            for sel_cols in extra:
                for k in range(sel_cols.shape[1]):
                    blocks.append((np.arange(n), sel_cols[:, k]))
            for sel, col in blocks:
                for axis in (0, 1):
                    rows.append(2 * row_of[sel] + axis)
                    cols.append(col)

        point_cols = []
        if self.options.refine_points3D:
            point_cols.append(self.point_offset + 3 * s.obs_point[:, None] + np.arange(3))
        observation_columns(s.obs_camera, s.obs_frame, 0, point_cols)
        n_rows = 2 * len(s.obs_xy)
        if s.board is not None:
            board_cols = [np.tile(self.board_offset + np.arange(6), (len(s.board.xy), 1))]
            observation_columns(s.board.camera, s.board.frame, len(s.obs_xy), board_cols)
            n_rows += 2 * len(s.board.xy)
        r, c = np.concatenate(rows), np.concatenate(cols)
        return scipy.sparse.csr_matrix((np.ones(len(r)), (r, c)), shape=(n_rows, self.size))


def bundle_adjust(state: BundleState, options: BundleOptions = BundleOptions(), verbose: bool = True) -> BundleResult:
    """Refine a reconstruction: shared intrinsics, shared rig, frames, points, board.

    Parameters
    ----------
    state : BundleState
        The seed (e.g. :func:`state_from_reconstruction` of a pycolmap model).
    options : BundleOptions
        What is refined, the loss, the tolerances.
    verbose : bool
        Print the cost before and after on stderr.

    Returns
    -------
    BundleResult
        Never ends above the seed's cost (only steps that lower it are taken).
    """
    layout = _Layout(state, options)

    def fun(x: NDArray[np.float64]) -> NDArray[np.float64]:
        scene, board = _residuals(layout.unpack(x))
        blocks = scene if board is None else np.vstack([scene, board])
        return np.nan_to_num(blocks, nan=1e6).ravel()

    x0 = layout.initial()
    initial_cost, rms_before = _measure(state, options)
    if verbose:
        print(f"camcal bundle: {len(x0)} unknowns, {len(state.obs_xy)} observations, cost {initial_cost:.6g}",
              file=sys.stderr, flush=True)
    x, r, J, n_iterations = _levenberg_marquardt(fun, x0, layout, options)
    refined = layout.unpack(x)
    final_cost, rms_after = _measure(refined, options)
    result = BundleResult(
        state=refined, initial_cost=initial_cost, final_cost=final_cost,
        rms_before_px=rms_before, rms_after_px=rms_after,
        sigmas=_sigmas(layout, x, r, J), n_iterations=n_iterations, n_residuals=len(r), n_parameters=len(x0),
    )
    if verbose:
        print(result.summary(), file=sys.stderr, flush=True)
    return result


def _jacobian(fun, x: NDArray[np.float64], r: NDArray[np.float64], layout: _Layout) -> scipy.sparse.csc_matrix:
    """Forward differences, one evaluation per group of columns that share no residual."""
    pattern = layout.pattern
    step = 1.5e-8 * np.maximum(1.0, np.abs(x))
    rows, cols, values = [], [], []
    for group in layout.groups:
        shifted = x.copy()
        shifted[group] += step[group]
        difference = fun(shifted) - r
        sub = pattern[:, group]
        column = np.repeat(group, np.diff(sub.indptr))
        rows.append(sub.indices)
        cols.append(column)
        values.append(difference[sub.indices] / step[column])
    return scipy.sparse.csc_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=pattern.shape)


def _normal_equations(J: scipy.sparse.csc_matrix, layout: _Layout):
    """``J^T J`` split into the camera block (dense), the cross block and the points' 3x3 blocks."""
    p = layout.point_offset
    A, B = J[:, :p], J[:, p:]
    H_aa = (A.T @ A).toarray()
    if B.shape[1] == 0:
        return H_aa, None, None
    BtB = (B.T @ B).tocsr()
    first = 3 * np.arange(B.shape[1] // 3)
    H_bb = np.empty((len(first), 3, 3))
    for k in range(3):
        for j in range(3):
            H_bb[:, k, j] = np.asarray(BtB[first + k, first + j]).ravel()
    return H_aa, (A.T @ B).tocsr(), H_bb


def _reduced(H_aa, H_ab, H_bb_inverse):
    """Schur complement ``H_aa - H_ab H_bb^-1 H_ba`` with ``H_bb^-1`` block-diagonal (points)."""
    n = len(H_bb_inverse)
    inverse = scipy.sparse.bsr_matrix((H_bb_inverse, np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n))
    W = (H_ab @ inverse).tocsr()
    return H_aa - (W @ H_ab.T).toarray(), W


def _solve_step(H_aa, H_ab, H_bb, g, mu: float, p: int) -> NDArray[np.float64]:
    """Solve ``(H + mu diag(H)) dx = -g`` with the points eliminated."""
    damped_aa = H_aa + mu * np.diag(np.maximum(np.diag(H_aa), 1e-6))
    if H_bb is None:
        return np.linalg.solve(damped_aa, -g)
    D_b = np.maximum(np.diagonal(H_bb, axis1=1, axis2=2), 1e-6)
    inverse = np.linalg.inv(H_bb + mu * D_b[:, :, None] * np.eye(3))
    S, W = _reduced(damped_aa, H_ab, inverse)
    g_a, g_b = g[:p], g[p:]
    dx_a = np.linalg.solve(S, -(g_a - W @ g_b))
    dx_b = np.einsum("nij,nj->ni", inverse, (-g_b - H_ab.T @ dx_a).reshape(-1, 3)).ravel()
    return np.concatenate([dx_a, dx_b])


def _reweighted(r: NDArray[np.float64], J, options: BundleOptions):
    """Cost ``1/2 sum rho``, and residuals and Jacobian scaled by ``sqrt(rho'(s))`` per 2-vector."""
    s = np.sum(r.reshape(-1, 2) ** 2, axis=1)
    cost = 0.5 * float(np.sum(_rho(s, options.loss, options.loss_scale)))
    if options.loss == "trivial":
        return cost, r, J
    weight = np.repeat(np.sqrt(_rho_derivative(s, options.loss, options.loss_scale)), 2)
    return cost, r * weight, None if J is None else scipy.sparse.diags(weight) @ J


def _levenberg_marquardt(fun, x0: NDArray[np.float64], layout: _Layout, options: BundleOptions):
    """Levenberg-Marquardt, Nielsen's damping update; stops when the relative decrease falls below tolerance."""
    x, r = x0.copy(), fun(x0)
    cost, r_w, J_w = _reweighted(r, _jacobian(fun, x, r, layout), options)
    mu, nu = 1e-4, 2.0
    iterations = 0
    while iterations < options.max_iterations and mu < 1e16:
        iterations += 1
        H_aa, H_ab, H_bb = _normal_equations(J_w, layout)
        g = J_w.T @ r_w
        try:
            dx = _solve_step(H_aa, H_ab, H_bb, g, mu, layout.point_offset)
        except np.linalg.LinAlgError:
            mu, nu = mu * nu, nu * 2
            continue
        r_new = fun(x + dx)
        cost_new = _reweighted(r_new, None, options)[0]
        predicted = -float(g @ dx) - 0.5 * float(np.sum((J_w @ dx) ** 2))
        if not (cost_new < cost and predicted > 0):
            mu, nu = mu * nu, nu * 2
            continue
        decrease = cost - cost_new
        mu *= max(1.0 / 3.0, 1.0 - (2.0 * decrease / predicted - 1.0) ** 3)
        nu = 2.0
        x, r = x + dx, r_new
        cost, r_w, J_w = _reweighted(r, _jacobian(fun, x, r, layout), options)
        if decrease < options.tolerance * cost:
            break
    return x, r_w, J_w, iterations


def _sigmas(layout: _Layout, x: NDArray[np.float64], r: NDArray[np.float64], J) -> dict[str, float]:
    """One-sigma of the intrinsics and rig poses, points marginalised (Schur complement)."""
    m, n = J.shape
    if m <= n:
        return {}
    sigma2 = float(r @ r) / (m - n)
    H_aa, H_ab, H_bb = _normal_equations(J, layout)
    try:
        if H_bb is not None:
            H_aa, _ = _reduced(H_aa, H_ab, np.linalg.pinv(H_bb))
        covariance = sigma2 * np.linalg.inv(H_aa)
    except np.linalg.LinAlgError:
        return {}
    state = layout.state
    sigmas: dict[str, float] = {}
    for camera, index in enumerate(layout.intrinsic_index):
        names = state.param_names(camera)
        for k, param in enumerate(index):
            o = layout.intrinsic_offset[camera] + k
            sigmas[f"{state.camera_names[camera]}.{names[param]}"] = float(np.sqrt(max(covariance[o, o], 0.0)))
    for camera, o in layout.sensor_offset.items():
        block = covariance[o:o + 6, o:o + 6]
        t = x[o + 3:o + 6]
        length = float(np.linalg.norm(t))
        across = np.eye(3) - np.outer(t, t) / max(length * length, 1e-300)
        along = t / max(length, 1e-300)
        name = state.camera_names[camera]
        sigmas[f"{name}.rotation_deg"] = float(np.degrees(np.sqrt(max(np.trace(block[:3, :3]), 0.0))))
        sigmas[f"{name}.baseline_direction_deg"] = float(
            np.degrees(np.sqrt(max(np.trace(across @ block[3:, 3:] @ across), 0.0)) / max(length, 1e-300)))
        sigmas[f"{name}.baseline_rel"] = float(np.sqrt(max(along @ block[3:, 3:] @ along, 0.0)) / max(length, 1e-300))
    return sigmas


def hold_rig(state: BundleState, cam_from_reference: dict[str, tuple[ArrayLike, ArrayLike]]) -> BundleState:
    """Put a known rig calibration into the state, rescaling the reconstruction to its units.

    Parameters
    ----------
    state : BundleState
    cam_from_reference : dict of str to (R, t)
        Each non-reference camera's pose relative to the reference camera
        (``X_cam = R X_ref + t``), e.g. from ``calibrate board``.

    Returns
    -------
    BundleState
        Scaled so that the seed's baselines match the known ones (median
        ratio), with ``sensor_from_rig`` replaced by the known poses; refine
        it with ``BundleOptions(refine_sensor_from_rig=False)``.
    """
    ratios = []
    sensor_R, sensor_t = state.sensor_R.copy(), state.sensor_t.copy()
    for name, (R, t) in cam_from_reference.items():
        if name not in state.camera_names:
            raise CamcalError(f"known rig camera {name!r} is not among the solved cameras: {', '.join(state.camera_names)}")
        index = state.camera_names.index(name)
        if index == 0:
            continue
        seed = np.linalg.norm(state.sensor_t[index])
        if seed <= 0:
            raise CamcalError(f"camera {name!r} sits at the reference camera's centre: no baseline to scale by")
        ratios.append(np.linalg.norm(np.asarray(t, dtype=np.float64)) / seed)
        sensor_R[index] = np.asarray(R, dtype=np.float64)
        sensor_t[index] = np.asarray(t, dtype=np.float64)
    if not ratios:
        raise CamcalError("the known rig has no camera besides the reference: nothing to hold")
    scaled = state.scaled(float(np.median(ratios)))
    return dataclasses.replace(scaled, sensor_R=sensor_R, sensor_t=sensor_t)


def _camera_from_world(state: BundleState, camera: int, frame: int) -> tuple[NDArray, NDArray]:
    R = state.sensor_R[camera] @ state.frame_R[frame]
    return R, state.sensor_R[camera] @ state.frame_t[frame] + state.sensor_t[camera]


def attach_board(state: BundleState, board: BoardObservations) -> BundleState:
    """Add chessboard observations, scaling the reconstruction to the board's units.

    Each view with 4+ corners gives ``cam_from_board`` by PnP (OpenCV, on
    undistorted pixels). The camera centres in board units against the same
    centres in the reconstruction give the scale (median ratio of pairwise
    distances); ``world_from_board`` is the chordal mean of the per-view
    estimates (rotation projected onto SO(3) by SVD), its translation the mean.

    Raises
    ------
    CamcalError
        Fewer than two views of the board from distinct places.
    """
    import cv2  # noqa: PLC0415

    views = sorted({(int(c), int(f)) for c, f in zip(board.camera, board.frame)})
    centres_board, centres_world, poses = [], [], []
    for camera, frame in views:
        mask = (board.camera == camera) & (board.frame == frame)
        if mask.sum() < 4:
            continue
        lens = camera_from_colmap(state.camera_names[camera], state.models[camera], state.image_sizes[camera],
                                  state.params[camera], np.eye(3), np.zeros(3))
        ideal = lens.distortion.undistort(board.xy[mask], lens.K)
        ok, rvec, tvec = cv2.solvePnP(board.object_points[board.corner[mask]], ideal, lens.K, None)
        if not ok:
            continue
        R_cb, t_cb = Rotation.from_rotvec(rvec.ravel()).as_matrix(), tvec.ravel()
        R_cw, t_cw = _camera_from_world(state, camera, frame)
        centres_board.append(-R_cb.T @ t_cb)
        centres_world.append(-R_cw.T @ t_cw)
        poses.append((R_cw, t_cw, R_cb, t_cb))
    if len(poses) < 2:
        raise CamcalError(f"the board is seen (4+ corners) in {len(poses)} view(s): need 2 or more to set its scale")
    cb, cw = np.array(centres_board), np.array(centres_world)
    i, j = np.triu_indices(len(cb), 1)
    world_distance = np.linalg.norm(cw[i] - cw[j], axis=1)
    distinct = world_distance > 1e-9 * max(1.0, float(np.abs(cw).max()))
    if not np.any(distinct):
        raise CamcalError("every view of the board is taken from the same place: its scale is not determined")
    scale = float(np.median(np.linalg.norm(cb[i] - cb[j], axis=1)[distinct] / world_distance[distinct]))
    scaled = state.scaled(scale)
    rotations, translations = [], []
    for R_cw, t_cw, R_cb, t_cb in poses:
        rotations.append(R_cw.T @ R_cb)
        translations.append(R_cw.T @ (t_cb - scale * t_cw))
    u, _, vt = np.linalg.svd(np.sum(rotations, axis=0))
    board_R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return dataclasses.replace(scaled, board=board, board_R=board_R, board_t=np.mean(translations, axis=0))


def state_from_reconstruction(reconstruction, camera_names: dict[int, str] | None = None) -> BundleState:
    """A :class:`BundleState` from a pycolmap ``Reconstruction`` with one rig.

    ``camera_names`` maps COLMAP camera ids to names (default ``camera<id>``);
    the rig's reference sensor becomes camera 0. Pixels move from COLMAP's
    convention (pixel centre 0.5) to camcal's (0).
    """
    import pycolmap  # noqa: PLC0415 - heavy dependency, only here

    if reconstruction.num_rigs() != 1:
        raise CamcalError(f"expected one rig in the reconstruction, got {reconstruction.num_rigs()}")
    rig = next(iter(reconstruction.rigs.values()))
    ref = rig.ref_sensor_id.id
    camera_ids = [ref] + sorted(cid for cid in reconstruction.cameras if cid != ref)
    names = camera_names or {cid: f"camera{cid}" for cid in camera_ids}
    sensor_R = np.repeat(np.eye(3)[None], len(camera_ids), axis=0)
    sensor_t = np.zeros((len(camera_ids), 3))
    for index, cid in enumerate(camera_ids[1:], start=1):
        pose = rig.sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid))
        sensor_R[index], sensor_t[index] = pose.rotation.matrix(), pose.translation
    frame_ids = sorted(reconstruction.reg_frame_ids())
    frame_pos = {fid: k for k, fid in enumerate(frame_ids)}
    frame_R = np.array([reconstruction.frame(fid).rig_from_world.rotation.matrix() for fid in frame_ids])
    frame_t = np.array([reconstruction.frame(fid).rig_from_world.translation for fid in frame_ids])
    point_ids = sorted(reconstruction.points3D)
    point_pos = {pid: k for k, pid in enumerate(point_ids)}
    camera_pos = {cid: k for k, cid in enumerate(camera_ids)}
    cams, frames, pts, xys = [], [], [], []
    for image in reconstruction.images.values():
        if not image.has_pose or image.frame_id not in frame_pos:
            continue
        for p in image.points2D:
            if p.has_point3D():
                cams.append(camera_pos[image.camera_id])
                frames.append(frame_pos[image.frame_id])
                pts.append(point_pos[p.point3D_id])
                xys.append(p.xy)
    cameras = [reconstruction.cameras[cid] for cid in camera_ids]
    return BundleState(
        camera_names=tuple(names[cid] for cid in camera_ids),
        models=tuple(c.model.name for c in cameras),
        image_sizes=tuple((c.width, c.height) for c in cameras),
        params=tuple(np.array(c.params, dtype=np.float64) for c in cameras),
        sensor_R=sensor_R, sensor_t=sensor_t, frame_R=frame_R, frame_t=frame_t, frame_ids=tuple(frame_ids),
        points=np.array([reconstruction.points3D[pid].xyz for pid in point_ids]).reshape(-1, 3),
        point_ids=tuple(point_ids),
        obs_camera=np.array(cams, dtype=np.int64), obs_frame=np.array(frames, dtype=np.int64),
        obs_point=np.array(pts, dtype=np.int64), obs_xy=np.array(xys, dtype=np.float64).reshape(-1, 2) - 0.5,
    )


def state_to_reconstruction(state: BundleState, reconstruction) -> None:
    """Write a refined state back into the pycolmap ``Reconstruction`` it came from (in place)."""
    import pycolmap  # noqa: PLC0415

    rig = next(iter(reconstruction.rigs.values()))
    camera_ids = [rig.ref_sensor_id.id] + sorted(cid for cid in reconstruction.cameras if cid != rig.ref_sensor_id.id)
    for index, cid in enumerate(camera_ids):
        reconstruction.cameras[cid].params = state.params[index]
        if index:
            rig.set_sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid),
                                    pycolmap.Rigid3d(pycolmap.Rotation3d(state.sensor_R[index]), state.sensor_t[index]))
    for k, fid in enumerate(state.frame_ids):
        reconstruction.frame(fid).rig_from_world = pycolmap.Rigid3d(
            pycolmap.Rotation3d(state.frame_R[k]), state.frame_t[k])
    for k, pid in enumerate(state.point_ids):
        reconstruction.points3D[pid].xyz = state.points[k]
