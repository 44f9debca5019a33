"""camcal's bundle adjustment against pycolmap's (Ceres) on the same reconstruction, and against truth."""

import dataclasses

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.geometry.bundle import (
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
    stages = []
    result = bundle_adjust(state, options, progress=lambda done, total: stages.append((done, total)))
    assert stages == [(0, 2), (1, 2), (2, 2)]  # built, solved, covariance
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
    from camcal.geometry.bundle import _project  # the projection under test against pycolmap above

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
