"""Structure from motion and bundle adjustment: camcal against plain pycolmap.

1. ``camcal solve`` (pycolmap seed + rig constraint + camcal's
   self-calibration: lens model by held-out residual, principal point by
   its sigma) against plain pycolmap (SIMPLE_DIVISION per folder, then
   ``bundle_adjustment`` with ``refine_principal_point``) on the same
   rendered stereo rig (principal points 5-8 px off-centre, focal 1 %
   apart, a division lens): wall time, errors against the truth, RMS.
2. camcal's bundle adjustment against ``pycolmap.bundle_adjustment`` (Ceres)
   on the same noisy reconstruction (pycolmap's synthetic rig): time and
   final cost; camcal with and without a per-iteration progress callback.
3. The covariance of the intrinsics and the rig pose on that problem:
   camcal's ``marginal_covariance`` against Ceres' ``Covariance`` (sparse QR,
   the engine's former method) on the same solved Ceres problem: time and
   agreement.

Prints ``name: ours X, peer Y, ratio Y/X``. ``--frames N`` renders fewer
rig positions (default 12).
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap

from camcal.geometry.bundle import (BundleOptions, bundle_adjust, ceres_covariance, marginal_covariance,
                                   state_from_reconstruction)
from camcal.model.camera import rotation_angle_deg
from camcal.pipelines.solve import solve_pycolmap_plain, solve_sfm
from camcal.synthetic import example_stereo_rig, render_rig_orbit


def _errors(camera, truth) -> tuple[float, float, float]:
    """Focal error (%), worst principal point error (px), lambda error (%) of a camera against the truth."""
    lam = camera.distortion.params.get("lambda", 0.0) if camera.distortion.model == "division" else np.nan
    return (100 * abs(camera.K[0, 0] / truth.K[0, 0] - 1), float(np.max(np.abs(camera.K[:2, 2] - truth.K[:2, 2]))),
            100 * abs(lam / truth.distortion.params["lambda"] - 1))


def bench_solve(frames: int) -> None:
    """``camcal solve`` (self-calibration) against plain pycolmap on the rendered must-show rig."""
    cameras = example_stereo_rig()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        render_rig_orbit(root / "in", cameras, n_frames=frames)
        folders = {camera.name: root / "in" / camera.name for camera in cameras}
        start = time.perf_counter()
        result = solve_sfm(folders, root / "camcal")
        ours = time.perf_counter() - start
        start = time.perf_counter()
        peer = solve_pycolmap_plain(folders, root / "plain")
        theirs = time.perf_counter() - start
    print(f"solve time (s, {2 * frames} images, peer without the lens-model choice): ours {ours:.1f}, "
          f"peer {theirs:.1f}, ratio {theirs / ours:.2f}")
    for truth in cameras:
        mine, other = _errors(result.rig.camera(truth.name), truth), _errors(peer.cameras[truth.name], truth)
        for label, a, b in zip(("focal error (%)", "principal point error (px)", "lambda error (%)"), mine, other):
            print(f"solve {truth.name} {label}: ours {a:.4f}, peer {b:.4f}, ratio {b / max(a, 1e-12):.2f}")
        rms, peer_rms = result.per_camera_rms_px[truth.name], peer.rms_px[truth.name]
        print(f"solve {truth.name} RMS reprojection (px): ours {rms:.3f}, peer {peer_rms:.3f}, ratio {peer_rms / rms:.2f}")
    true_rotation = cameras[1].R @ cameras[0].R.T
    ours_deg = rotation_angle_deg(result.rig.camera("right").R @ true_rotation.T)
    peer_deg = float(np.median([rotation_angle_deg(R @ true_rotation.T) for R in peer.right_from_left["right"]]))
    print(f"solve rig rotation error (deg; peer: median per frame, no rig): ours {ours_deg:.4f}, peer {peer_deg:.4f}, "
          f"ratio {peer_deg / ours_deg:.2f}")


def _noisy_rig_reconstruction():
    """pycolmap's synthetic 2-camera rig at 20 positions, 2000 points, 0.5 px noise, points moved 0.02."""
    options = pycolmap.SyntheticDatasetOptions(
        num_rigs=1, num_cameras_per_rig=2, num_frames_per_rig=20, num_points3D=2000,
        camera_width=1280, camera_height=960, camera_params=[1000.0, 640.0, 480.0, -0.05],
    )
    pycolmap.set_random_seed(0)
    reconstruction = pycolmap.synthesize_dataset(options)
    rng = np.random.default_rng(0)
    for image in reconstruction.images.values():
        for point in image.points2D:
            point.xy = point.xy + rng.normal(0.0, 0.5, 2)
    for point in reconstruction.points3D.values():
        point.xyz = point.xyz + rng.normal(0.0, 0.02, 3)
    return reconstruction


def bench_bundle() -> None:
    reconstruction = _noisy_rig_reconstruction()
    state = state_from_reconstruction(reconstruction)
    start = time.perf_counter()
    result = bundle_adjust(state, BundleOptions(compute_sigmas=False))
    ours = time.perf_counter() - start
    start = time.perf_counter()
    with_sigmas = bundle_adjust(state, BundleOptions())
    ours_sigmas = time.perf_counter() - start
    ba = pycolmap.BundleAdjustmentOptions(print_summary=False)
    solver = ba.ceres.solver_options
    solver.function_tolerance, solver.gradient_tolerance, solver.parameter_tolerance = 0.0, 1e-14, 1e-14
    solver.max_num_iterations = 200
    peer_model = pycolmap.Reconstruction(reconstruction)
    start = time.perf_counter()
    pycolmap.bundle_adjustment(peer_model, ba)
    peer = time.perf_counter() - start
    # the peer's final cost, evaluated by the same Ceres cost (no iterations)
    peer_cost = bundle_adjust(state_from_reconstruction(peer_model), BundleOptions(max_iterations=0, compute_sigmas=False)).initial_cost
    print(f"bundle adjustment time (s, {len(state.obs_xy)} observations): ours {ours:.2f}, "
          f"peer (pycolmap.bundle_adjustment) {peer:.2f}, ratio {peer / ours:.3f}")
    print(f"bundle adjustment + covariance time (s): ours {ours_sigmas:.2f}, peer (BA only) {peer:.2f}, "
          f"ratio {peer / ours_sigmas:.3f}")
    print(f"bundle adjustment final cost: ours {result.final_cost:.9g}, peer {peer_cost:.9g}, "
          f"ratio {peer_cost / result.final_cost:.9f} (with sigmas {with_sigmas.final_cost:.9g})")
    # the progress callback's cost: best of 3 interleaved runs each (the machine is shared)
    calls, times = [], {"with": [], "without": []}
    for _ in range(3):
        for kind in times:
            start = time.perf_counter()
            with_progress = bundle_adjust(state, BundleOptions(compute_sigmas=False),
                                          progress=(lambda *args: calls.append(args)) if kind == "with" else None)
            times[kind].append(time.perf_counter() - start)
    best, best_without = min(times["with"]), min(times["without"])
    print(f"bundle adjustment time with per-iteration progress (s, best of 3, {len(calls) // 3} calls a run): "
          f"ours {best:.2f}, ours without progress {best_without:.2f}, ratio {best_without / best:.3f} "
          f"(final cost {with_progress.final_cost:.9g})")


def bench_covariance() -> None:
    """Intrinsics and rig-pose covariance on the solved problem: camcal's marginalisation against Ceres' QR."""
    reconstruction = _noisy_rig_reconstruction()
    ba = pycolmap.BundleAdjustmentOptions(print_summary=False)
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(ba, config, reconstruction)
    adjuster.solve()
    problem = adjuster.problem
    blocks = [camera.params for camera in reconstruction.cameras.values()]
    blocks += [pose.params for rig in reconstruction.rigs.values() for pose in rig.non_ref_sensors.values()]
    blocks = [b for b in blocks if problem.has_parameter_block(b) and not problem.is_parameter_block_constant(b)]
    ours_times, peer_times = [], []
    for _ in range(3):  # best of 3 interleaved runs each (the machine is shared)
        start = time.perf_counter()
        ours, _ = marginal_covariance(problem, reconstruction, blocks)
        ours_times.append(time.perf_counter() - start)
        start = time.perf_counter()
        peer = ceres_covariance(problem, blocks)
        peer_times.append(time.perf_counter() - start)
    ours_time, peer_time = min(ours_times), min(peer_times)
    scale = np.sqrt(np.diag(peer))
    agreement = float(np.max(np.abs(ours - peer) / np.outer(scale, scale)))
    print(f"covariance time (s, best of 3, intrinsics + rig pose, {problem.num_residuals()} residuals): ours {ours_time:.3f}, "
          f"peer (Ceres Covariance, sparse QR) {peer_time:.3f}, ratio {peer_time / ours_time:.2f} "
          f"(largest difference {agreement:.1e} of sqrt(C_ii C_jj))")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--bundle-only", action="store_true", help="skip the structure-from-motion comparison")
    args = parser.parse_args()
    bench_bundle()
    bench_covariance()
    if not args.bundle_only:
        bench_solve(args.frames)


if __name__ == "__main__":
    main()
