"""The bundle adjustment's data: the state, the options, the result, the cost and the gauge's anchors.

The state (:class:`BundleState`) is what structure from motion or a board
calibration gives: physical cameras with intrinsics shared over all frames,
one ``sensor_from_rig`` pose per camera shared over all frames (a rig moved
around; the first camera is the rig's reference), one ``rig_from_world``
pose per frame, sparse 3D points and their observations; optionally
chessboard corners as *known* 3D points (:class:`BoardObservations`). With a
board the board's frame is the world (``world_from_board`` is the identity):
its corners are constant points, which fix the gauge and the scale. Every
pose maps ``X_to = R X_from + t`` (COLMAP's ``Rigid3d``). Intrinsics are
COLMAP parameter vectors (:func:`model_layout` names them).

The cost is Ceres' ``1/2 sum_i rho(|r_i|^2)`` over the 2-vector residual of
each observation, with Ceres' losses (scale ``a``)::

    trivial  rho(s) = s
    huber    rho(s) = s              if s <= a^2,   2 a sqrt(s) - a^2 otherwise
    soft_l1  rho(s) = 2 a^2 (sqrt(1 + s / a^2) - 1)
    cauchy   rho(s) = a^2 log(1 + s / a^2)
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.bundle.prior import Prior, PriorSpec, undetermined
from camcal.model.colmap import camera_from_colmap
from camcal.model.camera import chordal_mean_rotation

__all__ = [
    "LOSSES",
    "WARM_START_RADIUS",
    "BoardObservations",
    "BundleOptions",
    "BundleResult",
    "BundleState",
    "attach_board",
    "hold_rig",
    "model_layout",
    "residuals",
    "robust_cost",
]

LOSSES = ("trivial", "huber", "soft_l1", "cauchy")
#: :attr:`BundleOptions.trust_region_radius` for a start near the solution: Gauss-Newton steps from the first
#: iteration (the self-calibration of a rendered 60-frame plate: 10-14 iterations per refinement down to 2-3, the
#: same cameras to 4e-6 of the path and 3e-5 px, sigmas to 1e-6 of themselves, the cost a little lower).
WARM_START_RADIUS = 1e12


@functools.lru_cache(maxsize=None)
def model_layout(model: str) -> tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    """COLMAP's parameter names and the indices of focal, principal point and extra parameters."""
    pycolmap = require("pycolmap")

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
            names = model_layout(model)[0]
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
        return model_layout(self.models[camera])[0]


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
    trust_region_radius : float
        Ceres' initial trust region radius. Levenberg-Marquardt damps each
        step by its inverse on the Jacobi-scaled normal equations and widens
        the radius about 3 times per successful step, so a direction the
        data barely fix (``fx - fy`` on a critical motion) is approached
        over 10-14 iterations from Ceres' default 1e4 (a rendered 60-frame
        plate), which suits a start far from the solution. A
        start already near it (a solved model refined again) takes
        Gauss-Newton steps from the first iteration with a large radius
        (:data:`WARM_START_RADIUS`); a step that raises the cost is
        rejected and the radius shrunk, as for any radius (Madsen, Nielsen
        & Tingleff 2004, Methods for Non-Linear Least Squares Problems,
        section 3.2).
    fixed_params : mapping of str to tuple of str
        Camera name -> COLMAP parameter names held at their start values
        (e.g. ``{"left": ("p1", "p2")}``).
    constant_intrinsics : tuple of str
        Cameras whose intrinsics are all held.
    compute_sigmas : bool
        Estimate the covariance of the intrinsics and the rig poses.
    priors : tuple of PriorSpec
        Gaussian priors on intrinsics (:mod:`~camcal.geometry.bundle.prior`);
        the estimate is then the posterior's mode and the sigmas the posterior's.
    default_priors : bool
        Also put the sensor's default priors on every free intrinsic
        (:func:`~camcal.geometry.bundle.prior.default_specs`) that no given
        prior names.
    prior_noise_px : float or None
        Reprojection noise (px per axis) that weighs the priors against the
        images in the fit; None: from the start's median residual. The
        covariance re-weighs them with the solved noise.
    reweigh_priors : bool
        With ``prior_noise_px`` None, solve again with the solved noise when
        the start's estimate was off by more than 1.5 times (each solve costs
        Ceres' preprocessing of the whole problem again). False for a fit
        whose priors need only be weighed roughly: one that only finds the
        outliers.
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
    trust_region_radius: float = 1e4
    fixed_params: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    constant_intrinsics: tuple[str, ...] = ()
    compute_sigmas: bool = True
    priors: tuple[PriorSpec, ...] = ()
    default_priors: bool = False
    prior_noise_px: float | None = None
    reweigh_priors: bool = True

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise CamcalError(f"unknown loss {self.loss!r}, expected one of: {', '.join(LOSSES)}")
        if not self.loss_scale > 0:
            raise CamcalError(f"loss scale must be positive, got {self.loss_scale!r}")
        if self.max_iterations < 0:
            raise CamcalError(f"max_iterations must be 0 or more, got {self.max_iterations!r}")
        if not self.trust_region_radius > 0:
            raise CamcalError(f"trust region radius must be positive, got {self.trust_region_radius!r}")


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
        refined rig pose; with a board, then ``gauge.rx .. gauge.tz``: the
        mean perturbation of the board poses (rotation vector, then
        translation, in the reference camera's frame), which projection
        uncertainty needs (mrcal's gauge; ``solve._gauge_rows``).
    n_points_out_of_covariance : int
        Scene points left out of the covariance (not of the fit): seen
        along parallel rays to the rounding of the Jacobian, their depth is
        not determined (:data:`MIN_POINT_SINGULAR_RATIO`); the sigmas are
        then conservative.
    termination : str
        Ceres' termination message.
    priors : tuple of Prior
        The priors in the problem (their residuals are part of the costs).
    prior_posterior_sigmas : tuple of float
        Posterior sigma of each prior's quantity, in its spec's units (NaN
        without a covariance).
    unused_priors : tuple of PriorSpec
        Given priors on an intrinsic the camera's model does not have.
    noise_px : float
        The images' per-axis reprojection noise at the solution (residuals
        over their degrees of freedom, the priors' left out), which weighs
        the priors in the covariance; NaN without redundancy.
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
    priors: tuple[Prior, ...] = ()
    prior_posterior_sigmas: tuple[float, ...] = ()
    unused_priors: tuple[PriorSpec, ...] = ()
    noise_px: float = float("nan")

    def summary(self) -> str:
        """Per-camera RMS before -> after and the cost."""
        rows = [f"  {name}: {self.rms_before_px[name]:.4f} -> {self.rms_after_px[name]:.4f} px" for name in self.rms_after_px]
        if self.priors:
            rows.append(f"  {len(self.priors)} Gaussian prior(s) on intrinsics in the cost; the sigmas are the posterior's")
        rows += [f"  {line}" for line in undetermined(self.priors, self.prior_posterior_sigmas)]
        rows += [f"  prior on {spec.label} not used: camera {spec.camera!r} has no such parameter in its lens model"
                 for spec in self.unused_priors]
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
