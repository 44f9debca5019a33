"""The refinement's Ceres solves and its outlier rejection, against peers on the same input."""

import dataclasses
import re

import numpy as np
import pytest

import camcal.geometry.bundle.solve as solve_module
from camcal.geometry.bundle import BundleOptions, bundle_adjust, residuals, state_from_reconstruction
from camcal.geometry.sfm import reject_outliers

pycolmap = pytest.importorskip("pycolmap")


def noisy_scene(seed=0, sigma_px=0.5, n_outliers=12, offset_px=8.0):
    """pycolmap's synthetic scene with Gaussian feature noise and ``n_outliers`` observations moved by ``offset_px``."""
    options = pycolmap.SyntheticDatasetOptions(
        num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=8, num_points3D=200, camera_width=640,
        camera_height=480, camera_model_id=pycolmap.CameraModelId.SIMPLE_RADIAL,
        camera_params=[500.0, 320.0, 240.0, -0.05])
    pycolmap.set_random_seed(seed)
    scene = pycolmap.synthesize_dataset(options)
    rng = np.random.default_rng(seed)
    for image in scene.images.values():
        for point in image.points2D:
            point.xy = point.xy + rng.normal(0.0, sigma_px, 2)
    long_tracks = [pid for pid, point in scene.points3D.items() if point.track.length() >= 4]
    for pid in rng.choice(long_tracks, n_outliers, replace=False):
        element = scene.points3D[int(pid)].track.elements[0]
        point = scene.images[element.image_id].points2D[element.point2D_idx]
        point.xy = point.xy + offset_px * np.array([0.6, 0.8])
    return scene


def test_outliers_are_the_observations_beyond_four_sigma_of_each_observations_own_projection():
    scene = noisy_scene()
    # the peer: pycolmap's projection of every observation, one by one
    errors = {}
    for image_id, image in scene.images.items():
        for index, point in enumerate(image.points2D):
            if point.has_point3D():
                projected = image.project_point(scene.points3D[point.point3D_id].xyz)
                errors[image_id, index] = (point.point3D_id, float(np.linalg.norm(point.xy - projected)))
    threshold = 4.0 * np.median([e for _, e in errors.values()]) / np.sqrt(2.0 * np.log(2.0))
    bad: dict[int, int] = {}
    for pid, e in errors.values():
        bad[pid] = bad.get(pid, 0) + (e > threshold)
    # COLMAP's filter deletes a point whose track would keep fewer than two observations
    expected = sum(scene.points3D[pid].track.length() if scene.points3D[pid].track.length() - n < 2 else n
                   for pid, n in bad.items() if n)
    assert expected >= 12

    message = reject_outliers(scene)

    dropped, total, said = re.match(r"dropped (\d+) of (\d+) observations beyond ([\d.]+) px", message).groups()
    assert (int(dropped), int(total)) == (expected, len(errors))
    assert float(said) == pytest.approx(threshold, abs=5e-4)
    for image in scene.images.values():
        for point in image.points2D:
            if point.has_point3D():
                projected = image.project_point(scene.points3D[point.point3D_id].xyz)
                assert np.linalg.norm(point.xy - projected) <= threshold


def test_solved_noise_is_the_images_residual_over_its_degrees_of_freedom():
    scene = noisy_scene(n_outliers=0)
    state = state_from_reconstruction(scene)
    result = bundle_adjust(state, BundleOptions(refine_principal_point=True, default_priors=True, compute_sigmas=False))
    assert len(result.priors) > 0
    scene_residuals, _ = residuals(result.state)
    dof = result.n_residuals - len(result.priors) - result.n_parameters
    assert result.noise_px == pytest.approx(np.sqrt(np.sum(scene_residuals ** 2) / dof), rel=1e-6)
    assert 0.4 < result.noise_px < 0.6  # the 0.5 px noise put in


def test_a_fit_that_does_not_reweigh_its_priors_solves_once(monkeypatch):
    scene = noisy_scene(n_outliers=0)
    state = state_from_reconstruction(scene)
    options = BundleOptions(refine_principal_point=True, default_priors=True, compute_sigmas=False)
    # a start whose median residual misjudges the noise by far more than 1.5 times
    state.points[:] += np.random.default_rng(1).normal(0.0, 0.05, state.points.shape)
    calls = []
    solve = solve_module.require("pyceres").solve
    monkeypatch.setattr(solve_module.require("pyceres"), "solve", lambda *args: calls.append(1) or solve(*args))
    both = bundle_adjust(state, options)
    assert len(calls) == 2
    once = bundle_adjust(state, BundleOptions(refine_principal_point=True, default_priors=True, compute_sigmas=False,
                                              reweigh_priors=False))
    assert len(calls) == 3
    # its priors stay weighed by the start's median residual, as if that noise had been given
    given = bundle_adjust(state, BundleOptions(refine_principal_point=True, default_priors=True, compute_sigmas=False,
                                               prior_noise_px=solve_module._noise_px(state)))
    np.testing.assert_array_equal(once.state.params[0], given.state.params[0])
    assert np.abs(once.state.params[0] - both.state.params[0]).max() > 1e-3  # the re-weighing mattered here


def test_dense_and_sparse_schur_reach_the_same_solution_on_a_long_sequence(monkeypatch):
    """Above 50 images pycolmap takes the sparse Schur solver; camcal solves its reduced camera system dense."""
    options = pycolmap.SyntheticDatasetOptions(
        num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=60, num_points3D=150, camera_width=640,
        camera_height=480, camera_model_id=pycolmap.CameraModelId.SIMPLE_RADIAL,
        camera_params=[500.0, 320.0, 240.0, -0.05])
    pycolmap.set_random_seed(3)
    scene = pycolmap.synthesize_dataset(options)
    rng = np.random.default_rng(3)
    for image in scene.images.values():
        for point in image.points2D:
            point.xy = point.xy + rng.normal(0.0, 0.5, 2)
    state = state_from_reconstruction(scene)
    used = []
    pyceres = solve_module.require("pyceres")
    solve = pyceres.solve
    monkeypatch.setattr(pyceres, "solve", lambda o, p, s: (solve(o, p, s), used.append(s.linear_solver_type_used)))
    fit = BundleOptions(compute_sigmas=False)
    dense = bundle_adjust(state, fit)
    monkeypatch.setattr(solve_module, "DENSE_SCHUR_MAX_FRAMES", 59)
    sparse = bundle_adjust(state, fit)
    assert used == [pyceres.LinearSolverType.DENSE_SCHUR, pyceres.LinearSolverType.SPARSE_SCHUR]
    np.testing.assert_allclose(dense.state.params[0], sparse.state.params[0], rtol=1e-9)
    np.testing.assert_allclose(dense.state.frame_t, sparse.state.frame_t, atol=1e-9)
    assert dense.final_cost == pytest.approx(sparse.final_cost, rel=1e-10)


def test_the_pre_rejection_fit_stops_early_and_the_solve_after_it_converges_fully(tmp_path, monkeypatch):
    """The fit that frees the mapper's principal point before the outlier rejection stops at
    ``PRE_REJECTION_TOLERANCE``, every fit after it at camcal's default; the early stop leaves its cost within
    1e-5 of the converged fit's (a 5-frame rendered stereo solve)."""
    import camcal.geometry.selfcal as selfcal
    import camcal.pipelines.solve as pipeline
    from camcal.pipelines.solve import PRE_REJECTION_TOLERANCE, solve_sfm
    from camcal.synthetic import render_stereo_sequence

    fits = []

    def spy(module):
        inner = module.bundle_adjust

        def bundle_adjust(state, options=BundleOptions(), **kwargs):
            result = inner(state, options, **kwargs)
            fits.append((state, options, result))
            return result
        monkeypatch.setattr(module, "bundle_adjust", bundle_adjust)

    spy(pipeline)
    spy(selfcal)
    width, height = 256, 192
    focal = 500.0 * width / 640
    render_stereo_sequence(tmp_path / "in", n_frames=5, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    solve_sfm({"left": tmp_path / "in/left", "right": tmp_path / "in/right"}, tmp_path / "out", max_num_features=512)
    (state, options, pre), rest = fits[0], fits[1:]
    assert options.tolerance == PRE_REJECTION_TOLERANCE > BundleOptions().tolerance and not options.compute_sigmas
    assert rest and all(o.tolerance in (BundleOptions().tolerance, selfcal.LENS_CHOICE_TOLERANCE) for _, o, _ in rest)
    assert rest[-1][1].tolerance == BundleOptions().tolerance
    converged = bundle_adjust(state, dataclasses.replace(options, tolerance=BundleOptions().tolerance))
    assert converged.final_cost <= pre.final_cost <= converged.final_cost * (1 + 1e-5)
