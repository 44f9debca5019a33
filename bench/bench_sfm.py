"""Structure from motion and bundle adjustment: camcal against plain pycolmap.

1. ``camcal solve`` (pycolmap seed + rig constraint + camcal's bundle
   adjustment) against the plain pycolmap pipeline (extract, match,
   incremental mapping) on the same rendered stereo sequence: wall time,
   registered images, reprojection RMS.
2. camcal's bundle adjustment against ``pycolmap.bundle_adjustment`` (Ceres)
   on the same noisy reconstruction (pycolmap's synthetic rig): time and
   final cost.

Prints ``name: ours X, peer Y, ratio Y/X``. ``--frames N`` renders fewer
rig positions (default 7).
"""

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap

from camcal.geometry.bundle import BundleOptions, bundle_adjust, state_from_reconstruction
from camcal.geometry.sfm import collect_images, solve_sfm
from camcal.synthetic import render_stereo_sequence


def plain_pycolmap(images: Path, work: Path) -> tuple[float, int, float]:
    """extract -> match -> map, one camera per folder, as a user would script it."""
    database = work / "database.db"
    start = time.perf_counter()
    pycolmap.extract_features(database, images, camera_mode=pycolmap.CameraMode.PER_FOLDER,
                              device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    (work / "sparse").mkdir()
    models = pycolmap.incremental_mapping(database, images, work / "sparse")
    elapsed = time.perf_counter() - start
    best = max(models.values(), key=lambda r: r.num_reg_images())
    return elapsed, best.num_reg_images(), best.compute_mean_reprojection_error()


def bench_solve(frames: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        render_stereo_sequence(root / "in", n_frames=frames)
        start = time.perf_counter()
        result = solve_sfm(collect_images([root / "in"]), root / "camcal")
        ours = time.perf_counter() - start
        (root / "plain").mkdir()
        peer, registered, mean_error = plain_pycolmap(root / "in", root / "plain")
        shutil.rmtree(root / "plain")
    print(f"solve time (s, {2 * frames} images): ours {ours:.1f}, peer {peer:.1f}, ratio {peer / ours:.2f}")
    print(f"solve registered images: ours {result.n_registered}, peer {registered}, "
          f"ratio {registered / max(result.n_registered, 1):.2f}")
    print(f"solve reprojection error (px; ours RMS, peer mean): ours {result.rms_px:.3f}, peer {mean_error:.3f}, "
          f"ratio {mean_error / result.rms_px:.2f}")


def bench_bundle() -> None:
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
    state = state_from_reconstruction(reconstruction)
    start = time.perf_counter()
    result = bundle_adjust(state, BundleOptions(compute_sigmas=False), verbose=False)
    ours = time.perf_counter() - start
    start = time.perf_counter()
    with_sigmas = bundle_adjust(state, BundleOptions(), verbose=False)
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
    peer_cost = bundle_adjust(state_from_reconstruction(peer_model), BundleOptions(max_iterations=0, compute_sigmas=False),
                              verbose=False).initial_cost
    print(f"bundle adjustment time (s, {len(state.obs_xy)} observations): ours {ours:.2f}, "
          f"peer (pycolmap.bundle_adjustment) {peer:.2f}, ratio {peer / ours:.3f}")
    print(f"bundle adjustment + covariance time (s): ours {ours_sigmas:.2f}, peer (BA only) {peer:.2f}, "
          f"ratio {peer / ours_sigmas:.3f}")
    print(f"bundle adjustment final cost: ours {result.final_cost:.9g}, peer {peer_cost:.9g}, "
          f"ratio {peer_cost / result.final_cost:.9f} (with sigmas {with_sigmas.final_cost:.9g})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--bundle-only", action="store_true", help="skip the structure-from-motion comparison")
    args = parser.parse_args()
    bench_bundle()
    if not args.bundle_only:
        bench_solve(args.frames)


if __name__ == "__main__":
    main()
