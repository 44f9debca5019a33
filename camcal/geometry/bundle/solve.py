"""The bundle adjustment itself: the state as a pycolmap problem, solved by Ceres through pyceres.

The refinement is pycolmap's Ceres bundle adjuster
(``create_default_ceres_bundle_adjuster``, COLMAP's reprojection costs on
rigs and frames, Ceres' sparse Schur solvers): the state becomes a pycolmap
``Reconstruction`` (cameras, one rig, frames, images, points with tracks),
board corners are added as constant points, and camcal only chooses what is
held. The adjuster's problem is solved with the adjuster's own solver options
through pyceres (``pyceres.solve``), which adds a per-iteration progress
callback (pycolmap's binding of the options has no ``callbacks``). The cost
is exactly the one ``pycolmap.bundle_adjustment`` minimises; single
parameters can be held (``BundleOptions.fixed_params``, e.g. the tangential
terms of ``OPENCV`` for camcal's radial-only ``polynomial`` model) by a
Ceres ``SubsetManifold`` on the camera's block.

Gauge: with a board, its constant corners; without one, when the points
move, COLMAP's ``TWO_CAMS_FROM_WORLD`` gauge if nothing sets the scale, or
the first frame's pose held when a rig held at a known calibration sets it.
The covariance carries the board gauge (mrcal's mean of the board poses,
:func:`_gauge_rows`) or, without a board, the scene gauge: the common turn
of the camera frame over the frames once the world's turn is taken out
(:func:`camcal.geometry.uncertainty.scene_gauge_rows`), which does not
depend on how the solve fixed its own gauge.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import glog_level
from camcal.geometry.bundle.covariance import is_free_block, marginal_covariance
from camcal.geometry.bundle.prior import Prior, posterior_sigma, prior_weights, resolve_priors
from camcal.geometry.bundle.state import BundleOptions, BundleResult, BundleState, model_layout, residuals
from camcal.geometry.uncertainty import scene_gauge_rows
from camcal.model.camera import pixels_to_colmap

__all__ = ["DENSE_SCHUR_MAX_FRAMES", "bundle_adjust", "with_covariance"]

#: the priors are weighed again with the solved noise when the start's estimate was off by more than this factor.
_NOISE_RATIO = 1.5
#: up to this many frames the reduced camera system is solved dense (Ceres' ``DENSE_SCHUR``) where pycolmap's
#: adjuster takes ``SPARSE_SCHUR`` (above 50 images): a plate's points are seen by 16-60 frames each, so the
#: system of 6 parameters per frame is nearly full within a band of frames and the sparse solver's block
#: bookkeeping costs more than the dense Cholesky factorisation it saves (rendered 240-frame plates: -19 % CPU
#: per iteration, 120 frames: -10 %, the same solution to 1e-15; not measured beyond 240 frames).
DENSE_SCHUR_MAX_FRAMES = 300


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
    pycolmap = require("pycolmap")

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
    pycolmap = require("pycolmap")

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
    names, focal, pp, extra = model_layout(state.models[camera])
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
                  progress: Callable[[int, int], None] | None = None,
                  inspect: Callable[[object, _Colmap], None] | None = None) -> BundleResult:
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
    inspect : callable, optional
        Called as ``inspect(problem, colmap)`` once Ceres has stopped, with
        the Ceres problem at the solution and the reconstruction it refines
        (:mod:`camcal.geometry.bundle.deletion` reads its Jacobian).

    Returns
    -------
    BundleResult

    Raises
    ------
    CamcalError
        Unknown parameter names, or a gauge that cannot be fixed (fewer than
        two frames and nothing else that sets the scale).
    """
    pycolmap = require("pycolmap")
    pyceres = require("pyceres")

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
    solver.initial_trust_region_radius = options.trust_region_radius
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

    free = {index: set(range(len(reconstruction.cameras[cid].params))) - set(_held_indices(state, index, options))
            for index, cid in enumerate(colmap.camera_ids)
            if is_free_block(problem, reconstruction.cameras[cid].params)}
    priors, unused = resolve_priors(state, options.priors, options.default_priors, free)
    noise = options.prior_noise_px if options.prior_noise_px is not None else _noise_px(state)
    costs = [_prior_cost(prior, weight, len(reconstruction.cameras[colmap.camera_ids[prior.camera]].params))
             for prior, weight in zip(priors, prior_weights(priors, noise))]
    for cost in costs:
        problem.add_residual_block(cost, None, [reconstruction.cameras[colmap.camera_ids[cost.prior.camera]].params])

    rms_before = _rms(state)
    # the adjuster's own solve, with pyceres' solver options: pycolmap's binding of them has no callbacks
    solver_options = _pyceres_solver_options(ba.ceres.create_solver_options(config, problem))
    # one thread: Ceres' threads add into the reduced system in the order they finish, and the solution
    # then differs from run to run in its last digits (frame poses by 1e-6 on a rendered stereo sequence)
    solver_options.num_threads = 1
    if (solver_options.linear_solver_type == pyceres.LinearSolverType.SPARSE_SCHUR
            and len(colmap.frame_ids) <= DENSE_SCHUR_MAX_FRAMES):
        solver_options.linear_solver_type = pyceres.LinearSolverType.DENSE_SCHUR
    total = options.max_iterations + int(options.compute_sigmas)
    if progress is not None:
        solver_options.callbacks = [_iteration_callback(progress, total)]
    summary = pyceres.SolverSummary()
    with glog_level(pyceres):  # Ceres' warnings of rejected steps are the solver's own business
        pyceres.solve(solver_options, problem, summary)
    # Ceres counts its iteration 0 (the start) as a successful step
    iterations = int(summary.num_successful_steps + summary.num_unsuccessful_steps) - 1
    initial_cost = float(summary.initial_cost)
    solved = np.sqrt(_image_sigma2(colmap, summary, costs))
    if (costs and options.prior_noise_px is None and options.reweigh_priors and solved > 0
            and abs(np.log(noise / solved)) > np.log(_NOISE_RATIO)):
        # the start's residuals misjudged the noise that weighs the priors: solve again with the solved noise
        for cost in costs:
            cost.weight = solved / cost.prior.sigma
        summary = pyceres.SolverSummary()
        with glog_level(pyceres):
            pyceres.solve(solver_options, problem, summary)
        iterations += int(summary.num_successful_steps + summary.num_unsuccessful_steps) - 1
        solved = np.sqrt(_image_sigma2(colmap, summary, costs))
    if inspect is not None:
        inspect(problem, colmap)
    if progress is not None:
        progress(options.max_iterations, total)
    refined = _from_colmap(state, colmap)
    result = BundleResult(
        state=refined, initial_cost=initial_cost, final_cost=float(summary.final_cost),
        rms_before_px=rms_before, rms_after_px=_rms(refined), n_iterations=iterations,
        n_residuals=int(summary.num_residuals), n_parameters=int(summary.num_effective_parameters_reduced),
        termination=str(summary.message), priors=priors, prior_posterior_sigmas=tuple(float("nan") for _ in priors),
        unused_priors=unused, noise_px=float(solved),
    )
    if options.compute_sigmas:
        result = with_covariance(result, *_covariance(state, options, colmap, problem, summary, costs))
        if progress is not None:
            progress(total, total)
    return result


def with_covariance(result: BundleResult, covariance: NDArray[np.float64], names: tuple[str, ...],
                    n_points_left_out: int) -> BundleResult:
    """``result`` with the covariance ``covariance`` of the quantities ``names`` (:attr:`BundleResult.covariance`),
    its sigmas and its priors' posterior sigmas (:func:`~camcal.geometry.bundle.prior.posterior_sigma`)."""
    state = result.state
    posterior = tuple(posterior_sigma(prior, covariance, names, state.param_names(prior.camera),
                                      state.camera_names[prior.camera]) if len(names) else float("nan")
                      for prior in result.priors)
    return dataclasses.replace(result, covariance=covariance, covariance_names=names,
                               n_points_out_of_covariance=n_points_left_out, sigmas=_sigmas(state, covariance, names),
                               prior_posterior_sigmas=posterior)


def _pyceres_solver_options(colmap_options):
    """pycolmap's Ceres solver options (its own pyceres binding) as pyceres' ``SolverOptions``, field by field."""
    pyceres = require("pyceres")

    converted = pyceres.SolverOptions()
    for key, value in colmap_options.todict().items():
        kind = type(getattr(converted, key))
        if hasattr(kind, "__members__"):  # the two bindings' enums differ as types, not in their names
            value = kind.__members__[value.name]
        setattr(converted, key, value)
    return converted


def _iteration_callback(progress: Callable[[int, int], None], total: int):
    """A pyceres ``IterationCallback`` that reports ``progress(iteration, total)`` and lets Ceres go on."""
    pyceres = require("pyceres")

    class IterationProgress(pyceres.IterationCallback):
        def __call__(self, summary) -> object:
            progress(int(summary.iteration), total)
            return pyceres.CallbackReturnType.SOLVER_CONTINUE

    return IterationProgress()


def _noise_px(state: BundleState) -> float:
    """Per-axis reprojection noise of the state, robustly: the median residual norm over ``sqrt(2 ln 2)`` (Rayleigh)."""
    scene, board = residuals(state)
    r = scene if board is None else np.vstack([scene, board])
    norms = np.linalg.norm(r, axis=1)
    norms = norms[np.isfinite(norms)]
    return max(float(np.median(norms)) / np.sqrt(2.0 * np.log(2.0)), 1e-3) if len(norms) else 1.0


def _image_sigma2(colmap: _Colmap, summary, costs: list) -> float:
    """Per-axis noise variance of the images' residuals at the solution (priors' residuals left out); NaN without redundancy."""
    dof = summary.num_residuals - len(costs) - summary.num_effective_parameters_reduced
    if dof <= 0:
        return float("nan")
    cameras = colmap.reconstruction.cameras
    prior_cost = 0.5 * sum(cost.residual(np.asarray(cameras[colmap.camera_ids[cost.prior.camera]].params)) ** 2
                           for cost in costs)
    return 2.0 * max(float(summary.final_cost) - prior_cost, 0.0) / dof


def _prior_cost(prior: Prior, weight: float, size: int):
    """A pyceres cost ``w (a . x - mean)`` on one camera's parameter block of ``size`` parameters."""
    pyceres = require("pyceres")

    class PriorCost(pyceres.CostFunction):
        def __init__(self) -> None:
            super().__init__()
            self.prior, self.weight = prior, weight
            self.row = np.zeros(size)
            self.row[list(prior.indices)] = prior.coefficients
            self.set_num_residuals(1)
            self.set_parameter_block_sizes([size])

        def residual(self, params: NDArray[np.float64]) -> float:
            return self.weight * (float(self.row @ params) - self.prior.mean)

        def Evaluate(self, parameters, residuals, jacobians) -> bool:  # noqa: N802 - pyceres' name
            residuals[0] = self.residual(parameters[0])
            if jacobians is not None and jacobians[0] is not None:
                jacobians[0][:] = self.weight * self.row
            return True

    return PriorCost()


def _covariance(state: BundleState, options: BundleOptions, colmap: _Colmap, problem,
                summary, costs: list) -> tuple[NDArray[np.float64], tuple[str, ...], int]:
    """``sigma^2 (J^T J)^-1`` of the free intrinsics and rig poses, its names and the points left out of it.

    Empty (and 0) when there is nothing to estimate, no redundancy, or the
    reduced normal equations are singular (:func:`marginal_covariance`).
    ``sigma^2`` comes from the images' residuals alone; the priors' rows
    are re-weighed to ``sigma / sigma_prior`` first, so that the result is
    ``(J_img^T J_img / sigma^2 + sum a a^T / sigma_prior^2)^-1``, the
    posterior covariance (:mod:`~camcal.geometry.bundle.prior`).
    """
    reconstruction = colmap.reconstruction
    blocks, names, scales = [], [], []
    for index, cid in enumerate(colmap.camera_ids):
        block = reconstruction.cameras[cid].params
        if not is_free_block(problem, block):
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
        if not is_free_block(problem, block):
            continue
        camera = state.camera_names[index]
        blocks.append(block)
        names += [f"{camera}.{axis}" for axis in ("rx", "ry", "rz", "tx", "ty", "tz")]
        scales += [2.0, 2.0, 2.0, 1.0, 1.0, 1.0]  # Ceres' quaternion tangent d is half the rotation vector
    sigma2 = _image_sigma2(colmap, summary, costs)
    if not blocks or np.isnan(sigma2):
        return np.zeros((0, 0)), (), 0
    if sigma2 > 0:
        for cost in costs:
            cost.weight = np.sqrt(sigma2) / cost.prior.sigma
    frames = _board_frames(state, colmap, problem)
    scene = [] if frames or not options.refine_points3D else _scene_frames(colmap, problem)
    scene_rows = scene_gauge_rows([R for _, R, _ in scene]) if scene else None
    extra = [block for block, _ in frames] + ([block for block, _, free in scene if free] if scene_rows is not None
                                                 else [])
    # one thread: the priors are Python cost functions (on more threads the Jacobian's evaluation waits on
    # the GIL forever), and threads that sum in the order they finish would make two runs differ
    inverse, n_left_out = marginal_covariance(problem, reconstruction, blocks + extra, num_threads=1)
    if inverse.size == 0:
        return np.zeros((0, 0)), (), n_left_out
    B = np.diag(scales)
    if frames:
        B = np.vstack([np.hstack([B, np.zeros((len(names), inverse.shape[0] - len(names)))]),
                       _gauge_rows(len(names), [t for _, t in frames])])
        names += list(GAUGE_NAMES)
    elif scene_rows is not None:
        rows = np.zeros((3, inverse.shape[0]))
        o = len(names)
        for i, (block, _, free) in enumerate(scene):
            if free:  # Ceres' quaternion tangent first (half the rotation vector), then the translation's
                rows[:, o:o + 3] = 2.0 * scene_rows[:, 3 * i:3 * i + 3]
                o += problem.parameter_block_tangent_size(block)
        B = np.vstack([np.hstack([B, np.zeros((len(names), inverse.shape[0] - len(names)))]), rows])
        names += list(GAUGE_NAMES[:3])
    return sigma2 * (B @ inverse @ B.T), tuple(names), n_left_out


#: Names of the board gauge in :attr:`BundleResult.covariance_names` (:func:`_gauge_rows`).
GAUGE_NAMES = ("gauge.rx", "gauge.ry", "gauge.rz", "gauge.tx", "gauge.ty", "gauge.tz")


def _board_frames(state: BundleState, colmap: _Colmap, problem) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``(params block, translation)`` of every free ``rig_from_board`` frame pose (board problems only)."""
    if state.board is None:
        return []
    out = []
    for _, fid in sorted(colmap.frame_ids.items()):
        pose = colmap.reconstruction.frame(fid).rig_from_world
        if is_free_block(problem, pose.params):
            out.append((pose.params, np.array(pose.translation, dtype=np.float64)))
    return out


def _scene_frames(colmap: _Colmap, problem) -> list[tuple[NDArray[np.float64], NDArray[np.float64], bool]]:
    """``(params block, rotation, free)`` of every frame pose ``rig_from_world`` of a problem without a board.

    The scene gauge (:func:`camcal.geometry.uncertainty.scene_gauge_rows`) of
    the frames' rotations: the frames the solve holds to fix its gauge
    (COLMAP's ``TWO_CAMS_FROM_WORLD`` holds the first) enter with no perturbation."""
    out = []
    for _, fid in sorted(colmap.frame_ids.items()):
        pose = colmap.reconstruction.frame(fid).rig_from_world
        if problem.has_parameter_block(pose.params):
            out.append((pose.params, pose.rotation.matrix(), is_free_block(problem, pose.params)))
    return out


def _gauge_rows(n_before: int, translations: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """The 6 rows mapping the frames' tangent perturbations to the board gauge ``(delta_bar, epsilon)``.

    Notes
    -----
    mrcal's projection uncertainty (Kogan, mrcal 2.x, "projection
    uncertainty") moves a point of the reference frame through every board
    frame and back with the perturbed poses and averages:
    ``p' = mean_i T_i' T_i^-1 p``, ``T_i = rig_from_board_i``. With Ceres'
    perturbations ``R_i' = exp(delta_i) R_i`` (``delta_i = 2 d_i``, ``d_i``
    the quaternion tangent) and ``t_i' = t_i + tau_i``, to first order
    ``p' = p + delta_bar x p + epsilon`` with ``delta_bar = mean_i delta_i``
    and ``epsilon = mean_i (tau_i + t_i x delta_i)``: a 6-vector whose
    covariance with the intrinsics and rig poses is all the projection
    uncertainty needs (:mod:`camcal.geometry.uncertainty`).
    """
    n = len(translations)
    rows = np.zeros((6, n_before + 6 * n))
    for i, t in enumerate(translations):
        o = n_before + 6 * i
        rows[:3, o:o + 3] = 2.0 * np.eye(3) / n
        rows[3:, o:o + 3] = 2.0 * np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]]) / n
        rows[3:, o + 3:o + 6] = np.eye(3) / n
    return rows



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
