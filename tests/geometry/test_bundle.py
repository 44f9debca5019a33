"""camcal's bundle adjustment against pycolmap's (Ceres) on the same reconstruction, and against truth."""

import dataclasses

import numpy as np
import pytest
import scipy.linalg

import camcal.geometry.bundle.covariance as covariance_module
import camcal.geometry.bundle.solve as solve_module
from camcal.base.errors import CamcalError
from camcal.geometry.bundle import (
    WARM_START_RADIUS,
    BoardObservations,
    BundleOptions,
    attach_board,
    bundle_adjust,
    hold_rig,
    robust_cost,
    state_from_reconstruction,
    state_to_reconstruction,
)

pycolmap = pytest.importorskip("pycolmap")

SIGMA_PX = 0.5


def synthetic(model="SIMPLE_RADIAL", params=(500.0, 320.0, 240.0, -0.05), frames=8, points=300, seed=0):
    """A 2-camera rig at ``frames`` positions (pycolmap's synthetic scene), exact, then a noisy seed."""
    options = pycolmap.SyntheticDatasetOptions(
        num_rigs=1, num_cameras_per_rig=2, num_frames_per_rig=frames, num_points3D=points,
        camera_width=640, camera_height=480, camera_model_id=getattr(pycolmap.CameraModelId, model),
        camera_params=list(params), sensor_from_rig_translation_stddev=0.3,
    )
    pycolmap.set_random_seed(seed)
    truth = pycolmap.synthesize_dataset(options)
    seed_model = pycolmap.Reconstruction(truth)
    rng = np.random.default_rng(seed)
    for image in seed_model.images.values():
        for point in image.points2D:
            point.xy = point.xy + rng.normal(0.0, SIGMA_PX, 2)
    for point in seed_model.points3D.values():
        point.xyz = point.xyz + rng.normal(0.0, 0.02, 3)
    for camera in seed_model.cameras.values():
        camera.params = camera.params * np.r_[1.02, np.ones(len(camera.params) - 1)]
    return truth, seed_model


def pycolmap_refine(reconstruction, options: BundleOptions):
    ba = pycolmap.BundleAdjustmentOptions(
        print_summary=False, refine_focal_length=options.refine_focal_length,
        refine_principal_point=options.refine_principal_point, refine_extra_params=options.refine_extra_params,
        refine_sensor_from_rig=options.refine_sensor_from_rig,
    )
    ba.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, options.loss.upper())
    ba.ceres.loss_function_scale = options.loss_scale
    solver = ba.ceres.solver_options
    solver.function_tolerance, solver.gradient_tolerance, solver.parameter_tolerance = 0.0, 1e-14, 1e-14
    solver.max_num_iterations = 500
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.reg_image_ids():
        config.add_image(image_id)
    return pycolmap.create_default_bundle_adjuster(ba, config, reconstruction).solve().ceres_summary


@pytest.mark.parametrize(
    "model, params, options",
    [
        ("SIMPLE_RADIAL", (500.0, 320.0, 240.0, -0.05), BundleOptions()),
        ("RADIAL", (480.0, 318.0, 244.0, -0.08, 0.02), BundleOptions(loss="huber", loss_scale=1.0,
                                                                   refine_principal_point=True)),
        ("SIMPLE_DIVISION", (520.0, 320.0, 240.0, -0.06), BundleOptions(loss="cauchy", loss_scale=2.0)),
        ("OPENCV", (500.0, 505.0, 321.0, 239.0, -0.05, 0.01, 1e-3, -1e-3), BundleOptions(loss="soft_l1")),
    ],
)
def test_reaches_pycolmap_cost(model, params, options):
    _, seed_model = synthetic(model, params)
    state = state_from_reconstruction(seed_model)
    calls = []
    result = bundle_adjust(state, options, progress=lambda done, total: calls.append((done, total)))
    # one call per Ceres iteration (0: the start), then the solve's share done, then the covariance
    total = options.max_iterations + 1
    assert all(t == total for _, t in calls)
    done = [d for d, _ in calls]
    assert done[:-2] == list(range(len(done) - 2)) and done[-2:] == [options.max_iterations, total]
    assert len(done) - 2 == result.n_iterations + 1 and result.n_iterations > 2
    peer = pycolmap_refine(seed_model, options)
    # the same starting cost: camcal's projection and loss are COLMAP's
    assert result.initial_cost == pytest.approx(peer.initial_cost, rel=1e-9)
    assert result.final_cost <= result.initial_cost
    assert abs(result.final_cost - peer.final_cost) / peer.final_cost < 1e-6
    # camcal's cost of pycolmap's solution is pycolmap's final cost
    peer_result = bundle_adjust(state_from_reconstruction(seed_model), dataclasses.replace(options, max_iterations=0))
    assert peer_result.initial_cost == pytest.approx(peer.final_cost, rel=1e-9)


def test_state_round_trips_through_reconstruction():
    _, seed_model = synthetic(points=80, frames=4)
    state = state_from_reconstruction(seed_model)
    moved = dataclasses.replace(state, points=state.points + 1.0, params=tuple(p * 1.01 for p in state.params),
                                frame_t=state.frame_t * 2.0)
    state_to_reconstruction(moved, seed_model)
    back = state_from_reconstruction(seed_model)
    assert np.allclose(back.points, moved.points, atol=1e-12)
    assert np.allclose(back.frame_t, moved.frame_t, atol=1e-12)
    assert np.allclose(back.frame_R, moved.frame_R, atol=1e-12)
    assert all(np.allclose(a, b, rtol=1e-12) for a, b in zip(back.params, moved.params))


def test_robust_cost_is_ceres_loss():
    r = np.array([[0.5, 0.0], [3.0, 4.0]])  # s = 0.25, 25
    assert robust_cost(r) == pytest.approx(0.5 * (0.25 + 25))
    assert robust_cost(r, "huber", 1.0) == pytest.approx(0.5 * (0.25 + 2 * 5 - 1))
    assert robust_cost(r, "cauchy", 2.0) == pytest.approx(0.5 * 4 * (np.log1p(0.25 / 4) + np.log1p(25 / 4)))
    assert robust_cost(r, "soft_l1", 1.0) == pytest.approx(0.5 * 2 * ((np.sqrt(1.25) - 1) + (np.sqrt(26) - 1)))


def test_focal_error_within_its_sigma():
    truth, seed_model = synthetic(frames=10, points=400, seed=3)
    result = bundle_adjust(state_from_reconstruction(seed_model), BundleOptions())
    true_state = state_from_reconstruction(truth)
    for index, name in enumerate(result.state.camera_names):
        error = result.state.params[index][0] - true_state.params[index][0]
        sigma = result.sigmas[f"{name}.f"]
        assert 0 < sigma < 5.0
        assert abs(error) < 4 * sigma
    # per-camera RMS close to the noise: 2D noise of sigma 0.5 px per axis
    for name, rms in result.rms_after_px.items():
        assert rms == pytest.approx(SIGMA_PX * np.sqrt(2), rel=0.1)
        assert rms < result.rms_before_px[name]


def _true_sensor(truth_state):
    return {truth_state.camera_names[1]: (truth_state.sensor_R[1], truth_state.sensor_t[1])}


def test_rig_held_at_known_calibration_sets_scale():
    truth, seed_model = synthetic(seed=1)
    true_state = state_from_reconstruction(truth)
    # the seed in an arbitrary scale, with a slightly wrong rig
    seed_state = state_from_reconstruction(seed_model).scaled(0.37)
    seed_state = dataclasses.replace(seed_state, sensor_t=seed_state.sensor_t * [[1.0], [1.03]])
    held = hold_rig(seed_state, _true_sensor(true_state))
    result = bundle_adjust(held, BundleOptions(refine_sensor_from_rig=False))
    assert np.array_equal(result.state.sensor_t, held.sensor_t)
    # metric again: the frames' centres match the truth after a rigid alignment (no scale)
    centres = np.array([-R.T @ t for R, t in zip(result.state.frame_R, result.state.frame_t)])
    true_centres = np.array([-R.T @ t for R, t in zip(true_state.frame_R, true_state.frame_t)])
    spread = np.linalg.norm(true_centres - true_centres.mean(0), axis=1).mean()
    scale = np.linalg.norm(centres - centres.mean(0), axis=1).mean() / spread
    assert scale == pytest.approx(1.0, abs=0.01)


def test_board_observations_set_metric_scale():
    truth, seed_model = synthetic(seed=2, frames=8)
    true_state = state_from_reconstruction(truth)
    # a 9 x 6 board of 0.1 units placed among the points, seen from every frame by camera 0
    corners = np.array([[i * 0.1, j * 0.1, 0.0] for j in range(6) for i in range(9)])
    centre = true_state.points.mean(0)
    board_R = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))[0]
    board_R *= np.linalg.det(board_R)
    world = corners @ board_R.T + centre
    cameras, frames, ids, xys = [], [], [], []
    from camcal.geometry.bundle.state import _project  # the projection under test against pycolmap above

    rng = np.random.default_rng(5)
    for frame in range(len(true_state.frame_R)):
        for camera in (0, 1):
            xy = _project(true_state, np.full(len(world), camera), np.full(len(world), frame), world)
            inside = (xy[:, 0] > 0) & (xy[:, 0] < 639) & (xy[:, 1] > 0) & (xy[:, 1] < 479)
            n = int(inside.sum())
            cameras += [camera] * n
            frames += [frame] * n
            ids += list(np.flatnonzero(inside))
            xys.append(xy[inside] + rng.normal(0, SIGMA_PX, (n, 2)))
    board = BoardObservations(corners, np.array(cameras), np.array(frames), np.array(ids), np.vstack(xys))
    assert len(board.xy) > 200
    seed_state = state_from_reconstruction(seed_model).scaled(2.5)
    with_board = attach_board(seed_state, board)
    result = bundle_adjust(with_board, BundleOptions())
    baseline = np.linalg.norm(result.state.sensor_t[1])
    true_baseline = np.linalg.norm(true_state.sensor_t[1])
    assert baseline == pytest.approx(true_baseline, rel=0.01)
    assert "board" in result.rms_after_px and result.rms_after_px["board"] < 1.0


def test_bad_inputs():
    _, seed_model = synthetic(points=50, frames=3)
    state = state_from_reconstruction(seed_model)
    with pytest.raises(CamcalError, match="unknown loss"):
        BundleOptions(loss="tukey")
    with pytest.raises(CamcalError, match="trust region radius must be positive"):
        BundleOptions(trust_region_radius=0.0)
    with pytest.raises(CamcalError, match="NaN"):
        dataclasses.replace(state, obs_xy=np.full_like(state.obs_xy, np.nan))
    with pytest.raises(CamcalError, match="not among the solved cameras"):
        hold_rig(state, {"nobody": (np.eye(3), np.ones(3))})
    with pytest.raises(CamcalError, match="need 2 or more"):
        attach_board(state, BoardObservations(np.zeros((4, 3)), np.zeros(2, int), np.zeros(2, int),
                                              np.arange(2), np.zeros((2, 2))))


def test_fixed_params_and_constant_intrinsics_are_held():
    """Single COLMAP parameters held by a Ceres SubsetManifold stay exactly put; the others move."""
    _, seed_model = synthetic("OPENCV", (500.0, 505.0, 321.0, 239.0, -0.05, 0.01, 1e-3, -1e-3), points=150)
    state = state_from_reconstruction(seed_model)
    names = state.camera_names
    result = bundle_adjust(state, BundleOptions(fixed_params={names[0]: ("p1", "p2")}, constant_intrinsics=(names[1],)))
    before, after = state.params, result.state.params
    assert np.array_equal(after[0][6:8], before[0][6:8]) and not np.allclose(after[0][:2], before[0][:2])
    assert np.array_equal(after[1], before[1])
    assert f"{names[0]}.p1" not in result.sigmas and f"{names[0]}.fx" in result.sigmas
    assert not any(key.startswith(f"{names[1]}.f") for key in result.sigmas)
    with pytest.raises(CamcalError, match="has no parameter 'k9'"):
        bundle_adjust(state, BundleOptions(fixed_params={names[0]: ("k9",)}))


def capture_covariance(monkeypatch, dense_reference=True):
    """Run two references beside camcal's covariance on the same problem: Ceres' own ``Covariance`` (sparse
    QR of the whole Jacobian, the engine's former method) and ``(J^T J)^-1 = R^-1 R^-T`` from the dense QR
    of the whole column-scaled Jacobian (Householder: accurate to ~eps / rcond, rcond estimated by
    ``min |R_ii| / max |R_ii|``; the normal equations are never formed).

    Returns a list that receives, per covariance, ``(camcal's (covariance, n left out), Ceres' covariance or
    None if Ceres finds the Jacobian rank deficient, (the QR's covariance, its rcond) or None, the tangent
    sizes)``.
    """
    calls = []
    ours = covariance_module.marginal_covariance

    def with_references(problem, reconstruction, blocks, *args, **kwargs):
        mine = ours(problem, reconstruction, blocks, *args, **kwargs)
        full = covariance_module.ceres_covariance(problem, blocks)
        sizes = [problem.parameter_block_tangent_size(b) for b in blocks]
        offsets = np.r_[0, np.cumsum(sizes)]
        dense = None
        if dense_reference:
            J = covariance_module._jacobian(problem, reconstruction, blocks)[0].toarray()
            norms = np.linalg.norm(J, axis=0)
            R = scipy.linalg.qr(J / norms, mode="r")[0][:J.shape[1]]
            R_inverse = scipy.linalg.solve_triangular(R, np.eye(len(R)))[:offsets[-1]]
            diagonal = np.abs(np.diag(R))
            dense = (R_inverse @ R_inverse.T / np.outer(norms[:offsets[-1]], norms[:offsets[-1]]),
                     float(diagonal.min() / diagonal.max()))
        calls.append((mine, full, dense, sizes))
        return mine

    monkeypatch.setattr(solve_module, "marginal_covariance", with_references)
    return calls


def correlation_error(a, b):
    """Largest difference of two covariances in units of ``sqrt(b_ii b_jj)``."""
    scale = np.sqrt(np.diag(b))
    return float(np.max(np.abs(a - b) / np.outer(scale, scale)))


@pytest.mark.parametrize(
    "model, params, options",
    [
        ("SIMPLE_RADIAL", (500.0, 320.0, 240.0, -0.05), BundleOptions()),  # points marginalised, rig free
        ("OPENCV", (500.0, 505.0, 321.0, 239.0, -0.05, 0.01, 1e-3, -1e-3),  # SubsetManifold, robust loss
         BundleOptions(refine_principal_point=True, loss="huber", fixed_params={"camera1": ("p1", "p2")})),
        ("SIMPLE_DIVISION", (520.0, 320.0, 240.0, -0.06), BundleOptions(refine_points3D=False)),  # no points
    ],
)
def test_covariance_equals_ceres_on_a_well_conditioned_problem(monkeypatch, model, params, options):
    """camcal's Schur-complement covariance is Ceres' (sparse QR of the whole Jacobian) to 1e-6."""
    calls = capture_covariance(monkeypatch)
    _, seed_model = synthetic(model, params, frames=6, points=200, seed=7)
    result = bundle_adjust(state_from_reconstruction(seed_model), options)
    (mine, n_left_out), ceres, dense, sizes = calls[0]
    assert n_left_out == 0 and result.n_points_out_of_covariance == 0
    assert ceres is not None and mine.shape == ceres.shape == (sum(sizes), sum(sizes))
    assert correlation_error(mine, ceres) < 1e-6 and correlation_error(dense[0], ceres) < 1e-6
    # sigma^2 = 2 cost / (m - n) with n the free unknowns (constant blocks not counted)
    state = result.state
    if not options.refine_points3D:
        frames, free_intrinsics = len(state.frame_R), sum(len(p) for p in state.params) - 2 * 2  # cx, cy held
        assert result.n_parameters == free_intrinsics + 6 + 6 * frames
    sigma2 = 2 * result.final_cost / (result.n_residuals - result.n_parameters)
    # the intrinsics and rig poses; without a board the scene gauge follows them, from the frames' blocks
    # (their covariance is tested against repeated solves in test_bundle_scene_gauge.py)
    n = sum(not name.startswith("gauge.") for name in result.covariance_names)
    assert result.covariance_names[n:] == (("gauge.rx", "gauge.ry", "gauge.rz") if options.refine_points3D else ())
    scales = np.array([2.0 if name[-2:] in ("rx", "ry", "rz") else 1.0 for name in result.covariance_names[:n]])
    assert np.allclose(result.covariance[:n, :n], sigma2 * ceres[:n, :n] * np.outer(scales, scales), rtol=1e-6,
                       atol=0)


def with_far_points(state, truth, distances, rng):
    """``state`` plus one scene point per distance along camera 0's axis at frame 0 (triangulated under
    ~baseline / distance), observed with ``SIGMA_PX`` noise wherever it lands in the images."""
    centre = -truth.frame_R[0].T @ truth.frame_t[0]
    points, cams, frames, ids, xys = [], [], [], [], []
    from camcal.geometry.bundle.state import _project  # the projection tested against pycolmap above

    for k, distance in enumerate(distances):
        direction = truth.frame_R[0].T @ np.array([0.04 * k, 0.03, 1.0])
        X = centre + distance * direction / np.linalg.norm(direction)
        for frame in range(len(truth.frame_R)):
            for camera in range(len(truth.camera_names)):
                depth = (truth.sensor_R[camera] @ (truth.frame_R[frame] @ X + truth.frame_t[frame]) + truth.sensor_t[camera])[2]
                xy = _project(truth, np.array([camera]), np.array([frame]), X[None])[0]
                if depth > 0 and 0 < xy[0] < 639 and 0 < xy[1] < 479:
                    cams.append(camera)
                    frames.append(frame)
                    ids.append(len(state.points) + k)
                    xys.append(xy + rng.normal(0.0, SIGMA_PX, 2))
        points.append(X)
    assert len(set(ids)) == len(distances) and len(ids) >= 2 * len(distances)
    return dataclasses.replace(
        state, points=np.vstack([state.points, points]),
        point_ids=state.point_ids + tuple(max(state.point_ids) + 1 + np.arange(len(distances))),
        obs_camera=np.r_[state.obs_camera, cams], obs_frame=np.r_[state.obs_frame, frames],
        obs_point=np.r_[state.obs_point, ids], obs_xy=np.vstack([state.obs_xy, xys]),
    )


def test_sigmas_survive_points_seen_along_nearly_parallel_rays(monkeypatch):
    """Three points out of 400 seen from 1000-1700 scene units away (the scene is 2 units across, the frames
    a few units apart: triangulated under ~0.1 deg, then pushed further by the noise) make Ceres' Covariance
    declare the whole Jacobian rank deficient: no sigma at all. camcal's is the exact (J^T J)^-1 of the
    whole problem (dense SVD) with those points in it."""
    truth, seed_model = synthetic(frames=6, points=150, seed=3)
    state = state_from_reconstruction(seed_model)
    calls = capture_covariance(monkeypatch)
    far = with_far_points(state, state_from_reconstruction(truth), (1000.0, 1300.0, 1700.0), np.random.default_rng(1))
    result = bundle_adjust(far, BundleOptions())
    (mine, n_left_out), ceres, (dense, rcond), _ = calls[0]
    assert ceres is None  # the reproduction: Ceres' QR finds the Jacobian rank deficient
    assert n_left_out == result.n_points_out_of_covariance == 0
    assert rcond > 1e-11  # the dense reference holds to ~eps / rcond
    assert correlation_error(mine, dense) < 1e-6
    assert all(np.isfinite(value) and value > 0 for value in result.sigmas.values()) and len(result.sigmas) == 7


def test_points_of_undetermined_depth_are_left_out_of_the_covariance_only(monkeypatch):
    """Three points out of 400 at 1e12-1e14 units (parallel rays to the rounding of the Jacobian): Ceres'
    Covariance gives nothing; camcal leaves them out of the covariance (not of the fit), says so, and gives
    the sigmas of the scene without them."""
    truth, seed_model = synthetic(frames=10, points=400, seed=3)
    state = state_from_reconstruction(seed_model)
    clean = bundle_adjust(state, BundleOptions())
    calls = capture_covariance(monkeypatch, dense_reference=False)
    far = with_far_points(state, state_from_reconstruction(truth), (1e12, 1e13, 1e14), np.random.default_rng(8))
    result = bundle_adjust(far, BundleOptions())
    (_, n_left_out), ceres, _, _ = calls[0]
    assert ceres is None
    assert n_left_out == result.n_points_out_of_covariance == 3
    assert "3 point(s) seen along nearly parallel rays" in result.summary()
    assert set(result.sigmas) == set(clean.sigmas)
    for name, sigma in clean.sigmas.items():
        # the far points' 18 observations barely move the fit and its cost: the same sigmas to a percent
        assert result.sigmas[name] == pytest.approx(sigma, rel=0.01), name
    # they stay in the fit: refined like the others
    assert np.all(np.any(result.state.points[-3:] != far.points[-3:], axis=1))


def test_progress_reports_iterations_and_its_exceptions_stop_the_solve():
    _, seed_model = synthetic(points=100, frames=4)
    state = state_from_reconstruction(seed_model)
    calls = []
    result = bundle_adjust(state, BundleOptions(max_iterations=3, tolerance=0.0, compute_sigmas=False),
                           progress=lambda done, total: calls.append((done, total)))
    assert result.n_iterations == 3 and calls == [(0, 3), (1, 3), (2, 3), (3, 3), (3, 3)]

    def interrupt(done, total):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        bundle_adjust(state, BundleOptions(), progress=interrupt)


def test_ceres_warnings_stay_out_of_the_output(monkeypatch):
    """Ceres warns of rejected steps through pyceres' own glog (``Linear solver failure``): the adjuster's solve runs
    with that glog at ERROR, and the level is back where it was afterwards."""
    import pyceres

    levels = []
    solve = pyceres.solve

    def solve_recording_the_level(*args):
        levels.append(pyceres.logging.minloglevel)
        return solve(*args)

    monkeypatch.setattr(pyceres, "solve", solve_recording_the_level)
    _, seed_model = synthetic(frames=3, points=60, seed=5)
    before = pyceres.logging.minloglevel
    bundle_adjust(state_from_reconstruction(seed_model), BundleOptions(compute_sigmas=False))
    assert levels and all(level >= 2 for level in levels)
    assert pyceres.logging.minloglevel == before


def test_a_warm_start_reaches_the_solution_in_fewer_iterations_with_a_wide_trust_region():
    _, seed_model = synthetic(model="OPENCV", params=(500.0, 505.0, 321.0, 239.0, -0.05, 0.01, 1e-3, -1e-3), points=200)
    options = BundleOptions(refine_principal_point=True, compute_sigmas=False)
    solved = bundle_adjust(state_from_reconstruction(seed_model), options).state
    # a solved model refined again from a little off its solution (as a lens model converted, or a prior added)
    start = dataclasses.replace(solved, params=tuple(p * (1.0 + 1e-3 * np.arange(1, len(p) + 1) / len(p))
                                                     for p in solved.params))
    converged = bundle_adjust(start, dataclasses.replace(options, tolerance=0.0, max_iterations=500)).state
    cold = bundle_adjust(start, options)
    warm = bundle_adjust(start, dataclasses.replace(options, trust_region_radius=WARM_START_RADIUS))

    def distance(state) -> float:
        return max(float(np.abs(state.params[0] - converged.params[0]).max()),
                   float(np.abs(state.frame_t - converged.frame_t).max()))

    assert warm.n_iterations < cold.n_iterations
    assert warm.final_cost <= cold.final_cost
    # the default radius stops short along the weakly determined directions (k2, the principal point)
    assert distance(warm.state) <= distance(cold.state)
    assert distance(warm.state) < 1e-3
