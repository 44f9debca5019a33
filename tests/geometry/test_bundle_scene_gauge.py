"""The scene gauge of a solve's covariance against repeated noisy solves of one scene (synthetic tracks)."""

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.geometry.bundle import BundleOptions, BundleState, bundle_adjust
from camcal.geometry.uncertainty import covariance_from_colmap, projection_covariance, scene_gauge_rotation
from camcal.model.colmap import camera_from_colmap
from camcal.synthetic import example_stereo_rig, orbit_rig_poses

sys.path.insert(0, str(Path(__file__).parent))
from rig_tracks import observe_points  # noqa: E402

NOISE_PX = 0.5


def scene(rng, n_frames=6, n_points=400):
    """A stereo rig orbiting random points (fixed per ``rng``): the truth, the rig poses and the tracks' points."""
    cameras = example_stereo_rig(image_size=(640, 480), f=450.0, lam=(-2.7e-7, -2.7e-7))
    poses = orbit_rig_poses(rng, n_frames, roll_deg=30.0)
    X = rng.uniform([1.0, 1.0, 0.0], [7.0, 7.0, 3.0], (n_points, 3))
    return cameras, poses, X


def noisy_state(cameras, poses, X, rng) -> BundleState:
    """The tracks of ``X`` with Gaussian noise of :data:`NOISE_PX`, started at the truth (SIMPLE_DIVISION)."""
    cams, frames, points, xys = observe_points(cameras, poses, X, rng, NOISE_PX)
    keep_point = np.bincount(points, minlength=len(X)) >= 3
    keep = keep_point[points]
    params = [np.r_[c.K[0, 0], c.K[0, 2] + 0.5, c.K[1, 2] + 0.5, c.distortion.params["lambda"] * c.K[0, 0] ** 2]
              for c in cameras]
    right = cameras[1]
    return BundleState(
        camera_names=tuple(c.name for c in cameras), models=("SIMPLE_DIVISION",) * len(cameras),
        image_sizes=tuple(c.image_size for c in cameras), params=tuple(params),
        sensor_R=np.array([np.eye(3), right.R]), sensor_t=np.array([np.zeros(3), -right.R @ right.c]),
        frame_R=np.array([R for R, _ in poses]), frame_t=np.array([-R @ c for R, c in poses]),
        frame_ids=tuple(range(len(poses))), points=X[keep_point], point_ids=tuple(range(int(keep_point.sum()))),
        obs_camera=cams[keep], obs_frame=frames[keep],
        obs_point=(np.cumsum(keep_point) - 1)[points[keep]], obs_xy=xys[keep])


def test_scene_gauge_covariance_matches_repeated_solves():
    """Over 24 noise draws of one scene, the true gauge turn (:func:`scene_gauge_rotation`) and the true
    projection error of rays at infinity in that gauge follow the covariance: their Mahalanobis distances
    average 3 (the gauge, chi-square with 3 degrees of freedom) and 2 (a pixel's error, 2 degrees)."""
    rng = np.random.default_rng(12)
    cameras, poses, X = scene(rng)
    true_R = np.array([R for R, _ in poses])
    gauge_d2, pixel_d2 = [], []
    pixels = np.array([[0.0, 0.0], [320.0, 240.0], [639.0, 479.0], [600.0, 40.0]])
    for _ in range(24):
        result = bundle_adjust(noisy_state(cameras, poses, X, rng), BundleOptions(refine_principal_point=True))
        names = list(result.covariance_names)
        assert names[-3:] == ["gauge.rx", "gauge.ry", "gauge.rz"]
        g = -Rotation.from_matrix(scene_gauge_rotation(true_R, result.state.frame_R)).as_rotvec()
        C = result.covariance[-3:, -3:]
        gauge_d2.append(g @ np.linalg.solve(C, g))
        state = result.state
        solved = [camera_from_colmap(name, model, size, params, np.eye(3), np.zeros(3)) for name, model, size, params
                  in zip(state.camera_names, state.models, state.image_sizes, state.params)]
        covariance = covariance_from_colmap(solved, state.models, state.params,
                                            [state.param_names(k) for k in range(2)], names, result.covariance, 0)
        assert covariance.names[-3:] == ("gauge_rx", "gauge_ry", "gauge_rz")
        G = scene_gauge_rotation(true_R, state.frame_R)
        rays = solved[0].distortion.rays_from_pixels(pixels, solved[0].K) @ G.T
        error = cameras[0].distortion.project_rays(rays, cameras[0].K) - pixels
        S = projection_covariance(solved[0], pixels, covariance=covariance)
        pixel_d2 += list(np.einsum("ni,nij,nj->n", error, np.linalg.inv(S), error))
    print(f"gauge: mean Mahalanobis^2 {np.mean(gauge_d2):.2f} (3 expected); pixels: {np.mean(pixel_d2):.2f} (2)")
    # 24 draws: the mean of chi2(3) / 3 has standard deviation sqrt(2 / 72) = 0.17, that of chi2(2) / 2 at most
    # sqrt(2 / 48) = 0.20 (the four pixels of a draw are correlated: counted as one); 4 of those either side
    assert 3 * (1 - 4 * 0.17) < np.mean(gauge_d2) < 3 * (1 + 4 * 0.17)
    assert 2 * (1 - 4 * 0.20) < np.mean(pixel_d2) < 2 * (1 + 4 * 0.20)
