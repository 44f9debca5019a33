"""Rig-aware bundle adjustment on Ceres: camcal's one nonlinear calibration engine.

The state (:class:`BundleState`) is what structure from motion or a board
calibration gives: physical cameras with intrinsics shared over all frames,
one ``sensor_from_rig`` pose per camera shared over all frames (a rig moved
around; the first camera is the rig's reference), one ``rig_from_world``
pose per frame, sparse 3D points and their observations; optionally
chessboard corners as *known* 3D points (:class:`BoardObservations`). With a
board the board's frame is the world (``world_from_board`` is the identity):
its corners are constant points, which fix the gauge and the scale. Every
pose maps ``X_to = R X_from + t`` (COLMAP's ``Rigid3d``).

The refinement is pycolmap's Ceres bundle adjuster
(``create_default_ceres_bundle_adjuster``, COLMAP's reprojection costs on
rigs and frames, Ceres' sparse Schur solvers): the state becomes a pycolmap
``Reconstruction`` (cameras, one rig, frames, images, points with tracks),
board corners are added as constant points, and camcal only chooses what is
held. The adjuster's problem is solved with the adjuster's own solver options
through pyceres (``pyceres.solve``), which adds a per-iteration progress
callback (pycolmap's binding of the options has no ``callbacks``). Intrinsics are COLMAP parameter vectors (any model that
:func:`camcal.io.colmap.camera_from_colmap` maps exactly, named by COLMAP's
``params_info``), so the cost is exactly the one ``pycolmap.bundle_adjustment``
minimises; single parameters can be held (``BundleOptions.fixed_params``,
e.g. the tangential terms of ``OPENCV`` for camcal's radial-only
``polynomial`` model) by a Ceres ``SubsetManifold`` on the camera's block.

The cost is Ceres' ``1/2 sum_i rho(|r_i|^2)`` over the 2-vector residual of
each observation, with Ceres' losses (scale ``a``)::

    trivial  rho(s) = s
    huber    rho(s) = s              if s <= a^2,   2 a sqrt(s) - a^2 otherwise
    soft_l1  rho(s) = 2 a^2 (sqrt(1 + s / a^2) - 1)
    cauchy   rho(s) = a^2 log(1 + s / a^2)

Gauge: with a board, its constant corners; without one, when the points
move, COLMAP's ``TWO_CAMS_FROM_WORLD`` gauge if nothing sets the scale, or
the first frame's pose held when a rig held at a known calibration sets it.

Uncertainty: ``Sigma = sigma^2 (J^T J)^-1`` restricted to the intrinsics
and the rig poses, frames and points marginalised (:func:`marginal_covariance`:
Ceres' Jacobian of the adjuster's own problem, the points eliminated by the
Schur complement of their 3x3 blocks, a point seen along nearly parallel rays
left out of the covariance instead of making it singular), with
``sigma^2 = 2 cost / (m - n)``, ``n`` the free unknowns (Triggs et al. 2000,
section 6; Hartley & Zisserman 2004, section 5.2). Rotations are in Ceres' quaternion
tangent space ``q' = [cos|d|, sin|d| d / |d|] q``, i.e. a rotation vector
``2 d`` applied on the left; these sigmas measure the sampling noise of the
observations, not model error.

References
----------
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR (COLMAP).
Agarwal, S., Mierle, K. et al. Ceres Solver: loss functions, manifolds,
covariance estimation.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.camera import chordal_mean_rotation, pixels_from_colmap, pixels_to_colmap
from camcal.io.colmap import camera_from_colmap

__all__ = [
    "LOSSES",
    "BoardObservations",
    "BundleOptions",
    "BundleResult",
    "BundleState",
    "bundle_adjust",
    "residuals",
    "robust_cost",
    "state_from_reconstruction",
    "state_to_reconstruction",
    "hold_rig",
    "attach_board",
    "marginal_covariance",
    "ceres_covariance",
    "MIN_POINT_SINGULAR_RATIO",
]

LOSSES = ("trivial", "huber", "soft_l1", "cauchy")

#: A free 3D point whose Jacobian has ``sigma_min < MIN_POINT_SINGULAR_RATIO x sigma_max`` (its depth
#: is not determined to the rounding of the Jacobian) is left out of the covariance, not of the fit
#: (:func:`marginal_covariance`).
MIN_POINT_SINGULAR_RATIO = 1e-10
#: Points whose 3x3 information block has ``lambda_min`` below this share of ``lambda_max`` are eliminated
#: through the SVD of their own Jacobian rows instead of the normal equations (:func:`marginal_covariance`).
_NORMAL_EQUATIONS_MIN_RATIO = 1e-10


@functools.lru_cache(maxsize=None)
def _model_layout(model: str) -> tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    """COLMAP's parameter names and the indices of focal, principal point and extra parameters."""
    import pycolmap  # noqa: PLC0415 - heavy dependency, only here and in sfm.py

    model_id = getattr(pycolmap.CameraModelId, model, None)
    if model_id is None or model in ("INVALID",):
        raise CamcalError(f"unknown COLMAP camera model {model!r}")
    camera = pycolmap.Camera.create_from_model_id(0, model_id, 1.0, 2, 2)
    names = tuple(name.strip() for name in camera.params_info.split(","))
    return (names, tuple(camera.focal_length_idxs()), tuple(camera.principal_point_idxs()),
            tuple(camera.extra_params_idxs()))


@dataclass(frozen=True)
class BoardObservations:
    """Chessboard corners seen in the images: known 3D points on a board.

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
        The frames' ids in their source (COLMAP frame ids, or frame numbers).
    points : ndarray, shape (P, 3)
    point_ids : tuple of int
    obs_camera, obs_frame, obs_point : ndarray of int, shape (N,)
    obs_xy : ndarray, shape (N, 2)
        Observed pixels, camcal convention.
    board : BoardObservations or None
    board_R, board_t : ndarray or None
        ``world_from_board`` when a board is present (the identity once
        :func:`attach_board` has moved the world onto the board).
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
        for model, params in zip(self.models, self.params):
            names = _model_layout(model)[0]
            if len(params) != len(names):
                raise CamcalError(f"COLMAP model {model} takes {len(names)} parameters, got {len(params)}")
        if len(self.obs_xy) == 0 and (self.board is None or len(self.board.xy) == 0):
            raise CamcalError("bundle adjustment needs observations; the reconstruction has none")
        finite = np.all(np.isfinite(self.obs_xy)) and np.all(np.isfinite(self.points))
        if self.board is not None:
            finite = finite and np.all(np.isfinite(self.board.xy)) and np.all(np.isfinite(self.board.object_points))
        if not finite:
            raise CamcalError("bundle adjustment input has NaN or infinite observations or points")

    def scaled(self, factor: float) -> BundleState:
        """The same reconstruction with the world scaled by ``factor`` (translations and points)."""
        return dataclasses.replace(
            self, sensor_t=self.sensor_t * factor, frame_t=self.frame_t * factor, points=self.points * factor,
            board_t=None if self.board_t is None else self.board_t * factor,
        )

    def subset(self, keep_point: NDArray[np.bool_], keep_obs: NDArray[np.bool_] | None = None) -> BundleState:
        """The state restricted to the points ``keep_point`` and their observations (those in ``keep_obs`` too)."""
        kept = keep_point[self.obs_point] if keep_obs is None else keep_obs & keep_point[self.obs_point]
        index = np.cumsum(keep_point) - 1
        return dataclasses.replace(
            self, points=self.points[keep_point],
            point_ids=tuple(int(i) for i, k in zip(self.point_ids, keep_point) if k),
            obs_camera=self.obs_camera[kept], obs_frame=self.obs_frame[kept],
            obs_point=index[self.obs_point[kept]], obs_xy=self.obs_xy[kept],
        )

    def param_names(self, camera: int) -> tuple[str, ...]:
        """COLMAP's names of camera ``camera``'s parameters."""
        return _model_layout(self.models[camera])[0]


@dataclass(frozen=True)
class BundleOptions:
    """What to refine and how (COLMAP's ``BundleAdjustmentOptions`` names).

    Attributes
    ----------
    refine_focal_length, refine_principal_point, refine_extra_params : bool
        Which intrinsics move (every camera).
    refine_sensor_from_rig : bool
        Whether the cameras' poses in the rig move.
    refine_points3D : bool
        Whether the scene points move (board corners never do).
    loss, loss_scale : str, float
        Ceres loss on each 2-vector residual (module docstring), scale in px.
    max_iterations : int
        Ceres iterations (0 evaluates the start only).
    tolerance : float
        Ceres' function tolerance: stop when the cost falls by less than
        ``tolerance x cost`` in an iteration.
    fixed_params : mapping of str to tuple of str
        Camera name -> COLMAP parameter names held at their start values
        (e.g. ``{"left": ("p1", "p2")}``).
    constant_intrinsics : tuple of str
        Cameras whose intrinsics are all held.
    compute_sigmas : bool
        Estimate the covariance of the intrinsics and the rig poses.
    """

    refine_focal_length: bool = True
    refine_principal_point: bool = False
    refine_extra_params: bool = True
    refine_sensor_from_rig: bool = True
    refine_points3D: bool = True
    loss: str = "trivial"
    loss_scale: float = 1.0
    max_iterations: int = 200
    tolerance: float = 1e-10
    fixed_params: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    constant_intrinsics: tuple[str, ...] = ()
    compute_sigmas: bool = True

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise CamcalError(f"unknown loss {self.loss!r}, expected one of: {', '.join(LOSSES)}")
        if not self.loss_scale > 0:
            raise CamcalError(f"loss scale must be positive, got {self.loss_scale!r}")
        if self.max_iterations < 0:
            raise CamcalError(f"max_iterations must be 0 or more, got {self.max_iterations!r}")


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
        ``camera.baseline_rel``), frames and points marginalised.
    n_iterations : int
        Ceres iterations taken.
    n_residuals, n_parameters : int
        Scalar residuals and free (tangent-space) unknowns.
    covariance : ndarray, shape (P, P)
        ``sigma^2 (J^T J)^-1`` of the quantities in :attr:`covariance_names`
        (empty when not estimated).
    covariance_names : tuple of str
        ``camera.<COLMAP parameter>`` for the free intrinsics, then
        ``camera.rx, .ry, .rz`` (rotation vector applied on the left of
        ``sensor_from_rig``, radians) and ``camera.tx, .ty, .tz`` for each
        refined rig pose.
    n_points_out_of_covariance : int
        Scene points left out of the covariance (not of the fit): seen
        along parallel rays to the rounding of the Jacobian, their depth is
        not determined (:data:`MIN_POINT_SINGULAR_RATIO`); the sigmas are
        then conservative.
    termination : str
        Ceres' termination message.
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
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    covariance_names: tuple[str, ...] = ()
    n_points_out_of_covariance: int = 0
    termination: str = ""

    def summary(self) -> str:
        """Per-camera RMS before -> after and the cost."""
        rows = [f"  {name}: {self.rms_before_px[name]:.4f} -> {self.rms_after_px[name]:.4f} px" for name in self.rms_after_px]
        if self.n_points_out_of_covariance:
            rows.append(f"  {self.n_points_out_of_covariance} point(s) seen along nearly parallel rays left out of "
                        "the sigmas (not of the fit)")
        return "\n".join(
            [f"bundle adjustment (Ceres): cost {self.initial_cost:.6g} -> {self.final_cost:.6g} "
             f"({self.n_iterations} iterations, {self.n_residuals} residuals, {self.n_parameters} unknowns)"] + rows
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
        out[mask] = lens.project(Xc[mask])
    return out


def residuals(state: BundleState) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Reprojection residuals ``projected - observed`` (N, 2) of the points and (B, 2) of the board corners."""
    scene = _project(state, state.obs_camera, state.obs_frame, state.points[state.obs_point]) - state.obs_xy
    if state.board is None:
        return scene, None
    corners = state.board.object_points[state.board.corner] @ state.board_R.T + state.board_t
    return scene, _project(state, state.board.camera, state.board.frame, corners) - state.board.xy


def _rms(state: BundleState) -> dict[str, float]:
    """Plain reprojection RMS per camera (scene points) and ``"board"``."""
    scene, board = residuals(state)
    rms = {}
    for index, name in enumerate(state.camera_names):
        r = scene[state.obs_camera == index]
        if len(r):
            rms[name] = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    if board is not None and len(board):
        rms["board"] = float(np.sqrt(np.mean(np.sum(board * board, axis=1))))
    return rms


@dataclass
class _Colmap:
    """The pycolmap reconstruction of a state and where each part of the state went."""

    reconstruction: object
    camera_ids: list[int]
    frame_ids: dict[int, int]  # frame position -> COLMAP frame id (frames with images only)
    point_ids: list[int]  # scene points, in state order
    board_point_ids: list[int]


def _rigid(pycolmap, R: NDArray, t: NDArray):
    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(R, dtype=np.float64)), np.asarray(t, dtype=np.float64))


def _to_colmap(state: BundleState) -> _Colmap:
    """A pycolmap ``Reconstruction`` holding the state: one rig, a frame per state frame, constant board corners."""
    import pycolmap  # noqa: PLC0415

    reconstruction = pycolmap.Reconstruction()
    camera_ids = list(range(1, len(state.camera_names) + 1))
    for index, cid in enumerate(camera_ids):
        width, height = state.image_sizes[index]
        reconstruction.add_camera(pycolmap.Camera(
            camera_id=cid, model=getattr(pycolmap.CameraModelId, state.models[index]), width=int(width),
            height=int(height), params=np.asarray(state.params[index], dtype=np.float64)))
    rig = pycolmap.Rig(rig_id=1)
    rig.add_ref_sensor(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_ids[0]))
    for index, cid in enumerate(camera_ids[1:], start=1):
        rig.add_sensor(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid),
                       _rigid(pycolmap, state.sensor_R[index], state.sensor_t[index]))
    reconstruction.add_rig(rig)

    # every observation, scene points first, then board corners: one image per (camera, frame)
    board = state.board
    n_scene = len(state.obs_xy)
    cameras = state.obs_camera if board is None else np.concatenate([state.obs_camera, board.camera])
    frames = state.obs_frame if board is None else np.concatenate([state.obs_frame, board.frame])
    xy = state.obs_xy if board is None else np.vstack([state.obs_xy, board.xy])
    key = cameras.astype(np.int64) * len(state.frame_R) + frames
    order = np.argsort(key, kind="stable")
    keys, first = np.unique(key[order], return_index=True)
    point2D_index = np.empty(len(key), dtype=np.int64)
    point2D_index[order] = np.arange(len(key)) - np.repeat(first, np.diff(np.r_[first, len(key)]))
    image_of_key = {int(k): n + 1 for n, k in enumerate(keys)}
    image_id = np.array([image_of_key[int(k)] for k in key], dtype=np.int64) if len(key) else np.zeros(0, np.int64)

    frame_ids: dict[int, int] = {}
    frame_images: dict[int, list] = {}
    images = []
    bounds = np.r_[first, len(key)]
    for n, k in enumerate(keys):
        camera, frame = divmod(int(k), len(state.frame_R))
        rows = order[bounds[n]:bounds[n + 1]]
        image = pycolmap.Image(name=f"{state.camera_names[camera]}/{frame}", keypoints=pixels_to_colmap(xy[rows]),
                               camera_id=camera_ids[camera], image_id=n + 1)
        frame_ids.setdefault(frame, len(frame_ids) + 1)
        image.frame_id = frame_ids[frame]
        images.append(image)
        frame_images.setdefault(frame, []).append(image)
    for frame, fid in frame_ids.items():
        colmap_frame = pycolmap.Frame(frame_id=fid, rig_id=1,
                                      rig_from_world=_rigid(pycolmap, state.frame_R[frame], state.frame_t[frame]))
        for image in frame_images[frame]:
            colmap_frame.add_data_id(image.data_id)
        reconstruction.add_frame(colmap_frame)
    for image in images:
        reconstruction.add_image(image)
    for fid in frame_ids.values():
        reconstruction.register_frame(fid)

    def add_points(xyz: NDArray, which: NDArray, rows: NDArray) -> list[int]:
        by_point = np.argsort(which, kind="stable")
        starts = np.searchsorted(which[by_point], np.arange(len(xyz) + 1))
        ids = []
        for p in range(len(xyz)):
            members = rows[by_point[starts[p]:starts[p + 1]]]
            track = pycolmap.Track([pycolmap.TrackElement(int(image_id[m]), int(point2D_index[m])) for m in members])
            ids.append(reconstruction.add_point3D(xyz[p], track) if len(members) else -1)
        return ids

    point_ids = add_points(state.points, state.obs_point, np.arange(n_scene))
    board_point_ids = []
    if board is not None:
        corners = board.object_points @ state.board_R.T + state.board_t
        board_point_ids = add_points(corners, board.corner, n_scene + np.arange(len(board.xy)))
    return _Colmap(reconstruction, camera_ids, frame_ids, point_ids, board_point_ids)


def _from_colmap(state: BundleState, colmap: _Colmap) -> BundleState:
    """The state with the refined values of its reconstruction."""
    import pycolmap  # noqa: PLC0415

    reconstruction = colmap.reconstruction
    rig = reconstruction.rig(1)
    params = tuple(np.array(reconstruction.cameras[cid].params, dtype=np.float64) for cid in colmap.camera_ids)
    sensor_R, sensor_t = state.sensor_R.copy(), state.sensor_t.copy()
    for index, cid in enumerate(colmap.camera_ids[1:], start=1):
        pose = rig.sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid))
        sensor_R[index], sensor_t[index] = pose.rotation.matrix(), pose.translation
    frame_R, frame_t = state.frame_R.copy(), state.frame_t.copy()
    for frame, fid in colmap.frame_ids.items():
        pose = reconstruction.frame(fid).rig_from_world
        frame_R[frame], frame_t[frame] = pose.rotation.matrix(), pose.translation
    points = state.points.copy()
    for p, pid in enumerate(colmap.point_ids):
        if pid >= 0:
            points[p] = reconstruction.points3D[pid].xyz
    return dataclasses.replace(state, params=params, sensor_R=sensor_R, sensor_t=sensor_t, frame_R=frame_R,
                               frame_t=frame_t, points=points)


def _held_indices(state: BundleState, camera: int, options: BundleOptions) -> list[int]:
    """Indices of camera ``camera``'s COLMAP parameters that do not move."""
    names, focal, pp, extra = _model_layout(state.models[camera])
    name = state.camera_names[camera]
    if name in options.constant_intrinsics:
        return list(range(len(names)))
    held = set()
    for refined, index in ((options.refine_focal_length, focal), (options.refine_principal_point, pp),
                           (options.refine_extra_params, extra)):
        if not refined:
            held.update(index)
    for param in options.fixed_params.get(name, ()):
        if param not in names:
            raise CamcalError(f"camera {name!r} ({state.models[camera]}) has no parameter {param!r}; "
                              f"it has: {', '.join(names)}")
        held.add(names.index(param))
    return sorted(held)


def bundle_adjust(state: BundleState, options: BundleOptions = BundleOptions(),
                  progress: Callable[[int, int], None] | None = None) -> BundleResult:
    """Refine a reconstruction on Ceres: shared intrinsics, shared rig, frames, points, board.

    Parameters
    ----------
    state : BundleState
        The seed (e.g. :func:`state_from_reconstruction` of a pycolmap model,
        or board views from :mod:`camcal.geometry.zhang`).
    options : BundleOptions
        What is refined, the loss, the tolerances.
    progress : callable, optional
        Called as ``progress(done, total)`` with ``total =
        options.max_iterations`` (+ 1 with ``options.compute_sigmas``):
        after each Ceres iteration (``done`` = the iteration, 0 for the
        start; a pyceres ``IterationCallback``), with ``done =
        max_iterations`` once Ceres has stopped (converged early or not),
        and with ``done = total`` once the covariance is computed. An
        exception it raises stops the solve and propagates. Nothing is
        printed; :meth:`BundleResult.summary` describes the run.

    Returns
    -------
    BundleResult

    Raises
    ------
    CamcalError
        Unknown parameter names, or a gauge that cannot be fixed (fewer than
        two frames and nothing else that sets the scale).
    """
    import pycolmap  # noqa: PLC0415
    import pyceres  # noqa: PLC0415 - the Ceres problem behind pycolmap's adjuster

    colmap = _to_colmap(state)
    reconstruction = colmap.reconstruction
    ba = pycolmap.BundleAdjustmentOptions(
        print_summary=False, refine_focal_length=options.refine_focal_length,
        refine_principal_point=options.refine_principal_point, refine_extra_params=options.refine_extra_params,
        refine_sensor_from_rig=options.refine_sensor_from_rig, refine_points3D=options.refine_points3D,
    )
    ba.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, options.loss.upper())
    ba.ceres.loss_function_scale = options.loss_scale
    solver = ba.ceres.solver_options
    solver.function_tolerance = options.tolerance
    solver.gradient_tolerance = 1e-12
    solver.parameter_tolerance = 1e-12
    solver.max_num_iterations = options.max_iterations
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.images:
        config.add_image(image_id)
    for pid in colmap.board_point_ids:
        if pid >= 0:
            config.add_constant_point(pid)
    if not options.refine_points3D:
        for pid in colmap.point_ids:
            if pid >= 0:
                config.add_constant_point(pid)
    # the gauge (module docstring)
    if options.refine_points3D and len(state.obs_xy) > 0 and state.board is None:
        scale_free = options.refine_sensor_from_rig or len(state.camera_names) == 1
        if scale_free:
            if len(colmap.frame_ids) < 2:
                raise CamcalError("bundle adjustment needs at least 2 frames (or a known rig or a board) to fix the scale")
            config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
        else:
            config.set_constant_rig_from_world_pose(colmap.frame_ids[min(colmap.frame_ids)])
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(ba, config, reconstruction)
    problem = adjuster.problem
    for index, cid in enumerate(colmap.camera_ids):
        block = reconstruction.cameras[cid].params
        if not problem.has_parameter_block(block):
            continue
        held = _held_indices(state, index, options)
        if len(held) == len(block):
            problem.set_parameter_block_constant(block)
        elif held:
            problem.set_manifold(block, pyceres.SubsetManifold(len(block), held))

    rms_before = _rms(state)
    # the adjuster's own solve, with pyceres' solver options: pycolmap's binding of them has no callbacks
    solver_options = _pyceres_solver_options(ba.ceres.create_solver_options(config, problem))
    total = options.max_iterations + int(options.compute_sigmas)
    if progress is not None:
        solver_options.callbacks = [_iteration_callback(progress, total)]
    summary = pyceres.SolverSummary()
    pyceres.solve(solver_options, problem, summary)
    if progress is not None:
        progress(options.max_iterations, total)
    refined = _from_colmap(state, colmap)
    covariance, covariance_names, sigmas, n_left_out = np.zeros((0, 0)), (), {}, 0
    if options.compute_sigmas:
        covariance, covariance_names, n_left_out = _covariance(state, options, colmap, problem, summary)
        sigmas = _sigmas(refined, covariance, covariance_names)
        if progress is not None:
            progress(total, total)
    return BundleResult(
        state=refined, initial_cost=float(summary.initial_cost), final_cost=float(summary.final_cost),
        rms_before_px=rms_before, rms_after_px=_rms(refined), sigmas=sigmas,
        # Ceres counts its iteration 0 (the start) as a successful step
        n_iterations=int(summary.num_successful_steps + summary.num_unsuccessful_steps) - 1,
        n_residuals=int(summary.num_residuals), n_parameters=int(summary.num_effective_parameters_reduced),
        covariance=covariance, covariance_names=covariance_names, n_points_out_of_covariance=n_left_out,
        termination=str(summary.message),
    )


def _pyceres_solver_options(colmap_options):
    """pycolmap's Ceres solver options (its own pyceres binding) as pyceres' ``SolverOptions``, field by field."""
    import pyceres  # noqa: PLC0415

    converted = pyceres.SolverOptions()
    for key, value in colmap_options.todict().items():
        kind = type(getattr(converted, key))
        if hasattr(kind, "__members__"):  # the two bindings' enums differ as types, not in their names
            value = kind.__members__[value.name]
        setattr(converted, key, value)
    return converted


def _iteration_callback(progress: Callable[[int, int], None], total: int):
    """A pyceres ``IterationCallback`` that reports ``progress(iteration, total)`` and lets Ceres go on."""
    import pyceres  # noqa: PLC0415

    class IterationProgress(pyceres.IterationCallback):
        def __call__(self, summary) -> object:
            progress(int(summary.iteration), total)
            return pyceres.CallbackReturnType.SOLVER_CONTINUE

    return IterationProgress()


def _is_free(problem, block: NDArray[np.float64]) -> bool:
    """Whether ``block`` is a parameter block of the Ceres ``problem`` that the solve moves."""
    return problem.has_parameter_block(block) and not problem.is_parameter_block_constant(block)


def _covariance(state: BundleState, options: BundleOptions, colmap: _Colmap, problem,
                summary) -> tuple[NDArray[np.float64], tuple[str, ...], int]:
    """``sigma^2 (J^T J)^-1`` of the free intrinsics and rig poses, its names and the points left out of it.

    Empty (and 0) when there is nothing to estimate, no redundancy, or the
    reduced normal equations are singular (:func:`marginal_covariance`).
    """
    reconstruction = colmap.reconstruction
    blocks, names, scales = [], [], []
    for index, cid in enumerate(colmap.camera_ids):
        block = reconstruction.cameras[cid].params
        if not _is_free(problem, block):
            continue
        all_names = state.param_names(index)
        held = set(_held_indices(state, index, options))
        free = [k for k in range(len(all_names)) if k not in held]
        blocks.append(block)
        names.extend(f"{state.camera_names[index]}.{all_names[k]}" for k in free)
        scales.extend([1.0] * len(free))
    rig = reconstruction.rig(1)
    sensors = {sensor.id: pose for sensor, pose in rig.non_ref_sensors.items()}
    for index, cid in enumerate(colmap.camera_ids[1:], start=1):
        block = sensors[cid].params  # (qx, qy, qz, qw, tx, ty, tz), tangent (rotation, translation)
        if not _is_free(problem, block):
            continue
        camera = state.camera_names[index]
        blocks.append(block)
        names += [f"{camera}.{axis}" for axis in ("rx", "ry", "rz", "tx", "ty", "tz")]
        scales += [2.0, 2.0, 2.0, 1.0, 1.0, 1.0]  # Ceres' quaternion tangent d is half the rotation vector
    dof = summary.num_residuals - summary.num_effective_parameters_reduced
    if not blocks or dof <= 0:
        return np.zeros((0, 0)), (), 0
    inverse, n_left_out = marginal_covariance(problem, reconstruction, blocks)
    if inverse.size == 0:
        return np.zeros((0, 0)), (), n_left_out
    sigma2 = 2.0 * float(summary.final_cost) / dof
    scale = np.asarray(scales)
    return sigma2 * inverse * np.outer(scale, scale), tuple(names), n_left_out


def ceres_covariance(problem, blocks: list[NDArray[np.float64]], num_threads: int = 2) -> NDArray[np.float64] | None:
    """``(J^T J)^-1`` of some parameter blocks by Ceres' own ``Covariance`` (sparse QR of the whole Jacobian).

    The reference :func:`marginal_covariance` is checked against (tests,
    ``bench/bench_sfm.py``); ``None`` where Ceres finds the Jacobian rank
    deficient (one point seen along parallel rays is enough).

    Parameters
    ----------
    problem : pyceres.Problem
        A solved problem.
    blocks : list of ndarray
        Its free parameter blocks, in the order of the result (tangent space).
    num_threads : int
        Ceres' threads.
    """
    import pyceres  # noqa: PLC0415

    options = pyceres.CovarianceOptions()
    options.algorithm_type = pyceres.CovarianceAlgorithmType.SPARSE_QR
    options.num_threads = num_threads
    covariance = pyceres.Covariance(options)
    if not covariance.compute([(a, b) for i, a in enumerate(blocks) for b in blocks[i:]], problem):
        return None
    sizes = [problem.parameter_block_tangent_size(b) for b in blocks]
    offsets = np.r_[0, np.cumsum(sizes)]
    out = np.zeros((offsets[-1], offsets[-1]))
    for i, a in enumerate(blocks):
        for j in range(i, len(blocks)):
            part = np.asarray(covariance.get_covariance_block_tangent_space(a, blocks[j], problem)).reshape(sizes[i], sizes[j])
            out[offsets[i]:offsets[i + 1], offsets[j]:offsets[j + 1]] = part
            out[offsets[j]:offsets[j + 1], offsets[i]:offsets[i + 1]] = part.T
    return out


def marginal_covariance(problem, reconstruction, blocks: list[NDArray[np.float64]],
                        min_point_singular_ratio: float = MIN_POINT_SINGULAR_RATIO,
                        ) -> tuple[NDArray[np.float64], int]:
    """``(J^T J)^-1`` of some parameter blocks of a COLMAP bundle adjustment, all other unknowns marginalised.

    Parameters
    ----------
    problem : pyceres.Problem
        The problem of a pycolmap Ceres bundle adjuster (e.g.
        ``create_default_ceres_bundle_adjuster(...).problem``), at its solution.
    reconstruction : pycolmap.Reconstruction
        The reconstruction that problem refines: its cameras, rig sensor
        poses, frame poses and 3D points are the problem's parameter blocks.
    blocks : list of ndarray
        The free parameter blocks wanted (e.g. camera ``params``, a rig
        sensor pose's ``params``), in the order of the result.
    min_point_singular_ratio : float
        A free 3D point whose own Jacobian rows ``J_p`` (2k x 3) have
        ``sigma_min < ratio x sigma_max`` is left out of the covariance.

    Returns
    -------
    covariance : ndarray, shape (n, n)
        In the blocks' tangent spaces (Ceres' manifolds; held coordinates of
        a ``SubsetManifold`` omitted), in the order of ``blocks``; shape
        (0, 0) when the reduced normal equations are singular (a gauge or a
        parameter the data do not fix).
    n_points_left_out : int
        Free 3D points left out as singular.

    Raises
    ------
    RuntimeError
        The problem has parameter blocks that are not part of the
        reconstruction (their columns would be missed).

    Notes
    -----
    With ``J = [J_c J_p]`` (``c``: the wanted blocks, then the frames and
    any other free block; ``p``: the 3D points), each residual involves one
    point, so ``H_pp = J_p^T J_p`` is block diagonal with 3x3 blocks and the
    points are eliminated exactly by the Schur complement (Triggs et al.
    2000, section 6.1)::

        S = J_c^T J_c - sum_p H_cp H_pp^-1 H_pc,      Cov(c) = S^-1

    the ``c`` block of ``(J^T J)^-1``, which Ceres' ``Covariance`` computes
    from a rank-revealing QR of the whole ``J``. A point seen along nearly
    parallel rays (a tiny triangulation angle) has a nearly null depth
    direction: that QR then declares the whole Jacobian rank deficient and
    gives no covariance at all, and ``H_pp^-1`` from the normal equations
    loses the small eigenvalue to rounding (``eps lambda_max``). So a point
    with ``lambda_min < 1e-10 lambda_max`` is eliminated from the SVD of
    its own rows instead, ``J_p = U s V^T``: ``H_cp H_pp^-1 H_pc = (J_c^T
    U)(U^T J_c)``, exact while ``s_min`` stands above the rounding of
    ``J_p``. Below ``min_point_singular_ratio`` its depth is not determined
    at all and the point is left out of the covariance with its
    observations -- it stays in the fit -- which can only enlarge
    ``Cov(c)``. ``S`` is factored by Cholesky after Jacobi scaling
    (``D^-1/2 S D^-1/2``, ``D = diag S``); a pivot below 1e-14 (Ceres'
    ``min_reciprocal_condition_number``) means singular.
    """
    import scipy.linalg  # noqa: PLC0415
    import scipy.sparse  # noqa: PLC0415

    J, n_wanted, n_camera = _jacobian(problem, reconstruction, blocks)
    n_points = (J.shape[1] - n_camera) // 3

    # the 3x3 information block of each point, from the rows (residuals) that see it
    Jp = J[:, n_camera:].tocoo()
    row_point = np.full(J.shape[0], -1, dtype=np.int64)
    row_point[Jp.row] = Jp.col // 3
    A = np.zeros((J.shape[0], 3))
    A[Jp.row, Jp.col % 3] = Jp.data
    seen = row_point >= 0
    H_pp = np.empty((n_points, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            H_pp[:, i, j] = H_pp[:, j, i] = np.bincount(row_point[seen], A[seen, i] * A[seen, j], minlength=n_points)
    eigenvalues, eigenvectors = np.linalg.eigh(H_pp)
    by_normal_equations = eigenvalues[:, 0] > _NORMAL_EQUATIONS_MIN_RATIO * eigenvalues[:, 2]
    # the others through the SVD of their own rows J_p = U s V^T: H_cp H_pp^-1 H_pc = (J_c^T U)(U^T J_c)
    order = np.argsort(row_point, kind="stable")
    starts = np.searchsorted(row_point[order], np.arange(n_points + 1))
    left_out = np.zeros(n_points + 1, dtype=bool)  # the last entry: rows without a free point
    projections = []
    for p in np.flatnonzero(~by_normal_equations):
        rows = order[starts[p]:starts[p + 1]]
        U, singular, _ = np.linalg.svd(A[rows], full_matrices=False)
        if len(singular) < 3 or not singular[2] > min_point_singular_ratio * singular[0]:
            left_out[p] = True
        else:
            projections.append(J[rows, :n_camera].T @ U)
    kept = J[~left_out[row_point]]
    J_c = kept[:, :n_camera]
    S = (J_c.T @ J_c).toarray()
    for JcU in projections:
        S -= JcU @ JcU.T
    if n_points:
        inverse_eigen = np.where(by_normal_equations[:, None], 1.0 / np.where(by_normal_equations[:, None], eigenvalues, 1.0), 0.0)
        H_pp_inverse = scipy.sparse.bsr_matrix(
            (np.einsum("pij,pj,pkj->pik", eigenvectors, inverse_eigen, eigenvectors), np.arange(n_points),
             np.arange(n_points + 1)), shape=(3 * n_points, 3 * n_points))
        H_pc = (kept[:, n_camera:].T @ J_c).tocsr()
        S -= (H_pc.T @ (H_pp_inverse @ H_pc)).toarray()
    n_left_out = int(left_out.sum())

    d = np.sqrt(np.diag(S))
    if not np.all(d > 0):
        return np.zeros((0, 0)), n_left_out
    try:
        factor = scipy.linalg.cholesky(S / np.outer(d, d), lower=True)
    except np.linalg.LinAlgError:
        return np.zeros((0, 0)), n_left_out
    if np.min(np.diag(factor)) ** 2 < 1e-14:
        return np.zeros((0, 0)), n_left_out
    unit = np.zeros((n_camera, n_wanted))
    unit[np.arange(n_wanted), np.arange(n_wanted)] = 1.0
    scaled = scipy.linalg.cho_solve((factor, True), unit)[:n_wanted]
    covariance = scaled / np.outer(d[:n_wanted], d[:n_wanted])
    return 0.5 * (covariance + covariance.T), n_left_out


def _jacobian(problem, reconstruction, blocks: list[NDArray[np.float64]]):
    """Ceres' Jacobian (SciPy CSR, loss applied) of a COLMAP problem, columns: ``blocks``, other free blocks, points.

    Returns the matrix, the columns of ``blocks`` and the columns before the
    points (:func:`marginal_covariance`).
    """
    import pyceres  # noqa: PLC0415 - the Ceres problem behind pycolmap's adjuster
    import scipy.sparse  # noqa: PLC0415

    candidates = [camera.params for camera in reconstruction.cameras.values()]
    candidates += [pose.params for rig in reconstruction.rigs.values() for pose in rig.non_ref_sensors.values()]
    candidates += [frame.rig_from_world.params for frame in reconstruction.frames.values() if frame.has_pose]
    others = [block for block in candidates if problem.has_parameter_block(block)]
    points = [point.xyz for point in reconstruction.points3D.values() if problem.has_parameter_block(point.xyz)]
    if len(others) + len(points) != problem.num_parameter_blocks():
        raise RuntimeError(f"the problem has {problem.num_parameter_blocks()} parameter blocks, the reconstruction "
                           f"{len(others) + len(points)}: not a plain COLMAP bundle adjustment")
    wanted = {block.ctypes.data for block in blocks}  # pycolmap hands a new view of the same memory each time
    rest = [block for block in others if _is_free(problem, block) and block.ctypes.data not in wanted]
    evaluate = pyceres.EvaluateOptions()
    evaluate.set_parameter_blocks(list(blocks) + rest + [block for block in points if _is_free(problem, block)])
    evaluate.num_threads = 2
    crs = problem.evaluate_jacobian(evaluate)
    J = scipy.sparse.csr_matrix((np.asarray(crs.values), np.asarray(crs.cols), np.asarray(crs.rows)),
                                shape=(crs.num_rows, crs.num_cols))
    n_wanted = sum(problem.parameter_block_tangent_size(block) for block in blocks)
    return J, n_wanted, n_wanted + sum(problem.parameter_block_tangent_size(block) for block in rest)


def _sigmas(state: BundleState, covariance: NDArray[np.float64], names: tuple[str, ...]) -> dict[str, float]:
    """One-sigma of each intrinsic and of each rig pose's rotation, baseline direction and length."""
    if not len(names):
        return {}
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    out = {name: float(value) for name, value in zip(names, sigma) if name.rsplit(".", 1)[1] not in
           ("rx", "ry", "rz", "tx", "ty", "tz")}
    for index, camera in enumerate(state.camera_names):
        if f"{camera}.rx" not in names:
            continue
        o = names.index(f"{camera}.rx")
        rotation, translation = covariance[o:o + 3, o:o + 3], covariance[o + 3:o + 6, o + 3:o + 6]
        t = state.sensor_t[index]
        length = max(float(np.linalg.norm(t)), 1e-300)
        along = t / length
        across = np.eye(3) - np.outer(along, along)
        out[f"{camera}.rotation_deg"] = float(np.degrees(np.sqrt(max(np.trace(rotation), 0.0))))
        out[f"{camera}.baseline_direction_deg"] = float(
            np.degrees(np.sqrt(max(np.trace(across @ translation @ across), 0.0)) / length))
        out[f"{camera}.baseline_rel"] = float(np.sqrt(max(along @ translation @ along, 0.0)) / length)
    return out


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
    """Add chessboard observations and move the world onto the board (its frame, its units).

    Each view with 4+ corners gives ``cam_from_board`` by PnP (OpenCV, on
    undistorted pixels). The camera centres in board units against the same
    centres in the reconstruction give the scale (median ratio of pairwise
    distances); ``world_from_board`` is the chordal mean of the per-view
    estimates (:func:`camcal.model.camera.chordal_mean_rotation`), its
    translation the mean. The state is then re-expressed in the board's frame
    (``X_board = R^T (X_world - t)``, ``rig_from_board = rig_from_world
    world_from_board``), so that the board's constant corners fix the gauge.

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
    board_R = chordal_mean_rotation(rotations)
    board_t = np.mean(translations, axis=0)
    # the board's frame becomes the world
    return dataclasses.replace(
        scaled, board=board, board_R=np.eye(3), board_t=np.zeros(3),
        frame_R=scaled.frame_R @ board_R, frame_t=scaled.frame_R @ board_t + scaled.frame_t,
        points=(scaled.points - board_t) @ board_R,
    )


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
        obs_point=np.array(pts, dtype=np.int64), obs_xy=pixels_from_colmap(np.array(xys, dtype=np.float64).reshape(-1, 2)),
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
