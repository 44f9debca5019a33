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

4. A real scene with a known calibration: openMVG's Sceaux castle (11
   photographs, 2832 x 2128, ``K.txt``: f = 2905.88 px), found in
   ``$CAMCAL_SCEAUX_DIR`` or ``/work/data/sceaux`` (skipped with the reason
   otherwise; ``git clone https://github.com/openMVG/ImageDataset_SceauxCastle``
   and point the variable at its ``images`` folder): ``solve`` against the
   plain pycolmap pipeline on the same images in the same run, wall time and
   focal error against openMVG's calibration.

5. Real scenes with a measured calibration: Strecha et al.'s dense MVS
   benchmark (fountain-P11, Herz-Jesus-P8, entry-P10, castle-P19; 3072 x
   2048, ground-truth K, R, t per image), found in ``$CAMCAL_STRECHA_DIR``
   or ``/work/data/strecha`` (``<scene>/images/*.jpg`` and
   ``<scene>/gt_dense_cameras/*.jpg.camera``; openMVG's
   SfM_quality_evaluation repository holds a copy; skipped with the reason
   otherwise): ``solve`` against plain pycolmap, wall time, focal (fx, fy)
   and principal point errors, and the mean and largest error of the
   relative rotation of every pair of registered images. Then the
   aspect ``fy / fx`` the same images give with the laser-scanned poses
   held (:func:`_aspect_with_poses_held`): what the data say once the
   near-critical planar motion (Sturm 1997) cannot trade fy for a
   vertical stretch of the scene.

   Measured (one run, machine loaded 2-4; focal errors fx / fy %, ours
   against plain pycolmap's one f; mean of |fx|, |fy|): every scene's
   motion found near-critical for the aspect (a 1 % change of fx - fy
   moves the images by 0.055 / 0.049 / 0.044 / 0.043 px RMS, below the
   features' 0.1 px: square pixels held, the prior's spread of fx - fy
   carried to every parameter that re-adjusts with it). fountain -0.07 /
   -0.24 against -0.07 / -0.23 (mean 0.152 against 0.150), Herz-Jesus
   -0.03 / -0.20 against -0.04 / -0.21 (0.110 against 0.125), entry +0.01
   / -0.16 against +0.03 / -0.14 (0.085 both), castle -0.04 / -0.21
   against -0.05 / -0.22 (0.123 against 0.132; 0.136 in the run before:
   the peer's own spread); solve / plain time 0.81 / 0.62 / 0.49 / 0.57,
   0.62 over the four. Within 2 sigma: fountain 2 / 4 (fx 4.2 sigma:
   -0.068 %, where plain pycolmap is -0.065 %; cx 2.3), Herz-Jesus 4 / 4,
   entry 4 / 4 (cx 1.7; 5.5 sigma before the spread was carried), castle
   3 / 4 (cx 2.8).
   Before the aspect was held (98ca6c9, fx and fy apart under the 1 %
   prior) the means were 0.245 / 0.106 / 0.100 / 0.241 % and fy's error
   1.2-4.1 sigma. With the laser-scanned poses held our tracks
   give fy / fx 1.0007, 1.0016, 1.0026, 1.0017 (truth 1.0017): the aspect is
   what near-planar motion leaves to small systematic errors of the
   features, beyond the covariance.

Prints ``name: ours X, peer Y, ratio Y/X``. ``--frames N`` renders fewer
rig positions (default 12); ``--real-only`` runs only the real scenes,
``--strecha SCENE`` (repeatable) only those of Strecha's.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap
from scipy.optimize import least_squares

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


SCEAUX_DIRS = (os.environ.get("CAMCAL_SCEAUX_DIR", ""), "/work/data/sceaux")
#: openMVG's calibration of the Sceaux castle photographs (images/K.txt of openMVG/ImageDataset_SceauxCastle).
SCEAUX_FOCAL_PX = 2905.88


def bench_real_scene() -> None:
    """``solve`` against plain pycolmap on openMVG's Sceaux castle: time and focal error against openMVG's K."""
    folder = next((Path(p) for p in SCEAUX_DIRS if p and any(Path(p).glob("*.JPG"))), None)
    if folder is None:
        print(f"real scene: skipped, no Sceaux castle images (*.JPG) in {' or '.join(p for p in SCEAUX_DIRS if p)}; "
              "set CAMCAL_SCEAUX_DIR")
        return
    focal = SCEAUX_FOCAL_PX
    if (folder / "K.txt").is_file():
        focal = float((folder / "K.txt").read_text().split()[0])
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        start = time.perf_counter()
        peer = solve_pycolmap_plain({"sceaux": folder}, root / "plain")
        theirs = time.perf_counter() - start
        start = time.perf_counter()
        result = solve_sfm({"sceaux": folder}, root / "camcal")
        ours = time.perf_counter() - start
    n = len(list(folder.glob("*.JPG")))
    print(f"real scene (Sceaux castle, {n} photographs) solve time (s): ours {ours:.1f}, peer (plain pycolmap) "
          f"{theirs:.1f}, ratio {theirs / ours:.2f} (solve / plain {ours / theirs:.2f})")
    mine, other = result.rig.camera("sceaux").K[0, 0], peer.cameras["sceaux"].K[0, 0]
    a, b = 100 * abs(mine / focal - 1), 100 * abs(other / focal - 1)
    print(f"real scene focal error (%, openMVG's f = {focal:g} px): ours {a:.3f} (f {mine:.1f}), "
          f"peer {b:.3f} (f {other:.1f}), ratio {b / max(a, 1e-12):.2f}; registered ours {result.n_registered}, "
          f"peer {peer.n_registered}")


STRECHA_DIRS = (os.environ.get("CAMCAL_STRECHA_DIR", ""), "/work/data/strecha")
STRECHA_SCENES = ("fountain-P11", "Herz-Jesus-P8", "entry-P10", "castle-P19")


def _strecha_camera(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K, the rotation world -> camera and the centre of one Strecha ``.camera`` file (K; 0 0 0; R camera -> world;
    centre; size)."""
    rows = np.array([float(v) for v in path.read_text().split()])
    return rows[:9].reshape(3, 3), rows[12:21].reshape(3, 3).T, rows[21:24]


def _rotation_errors(estimated: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> np.ndarray:
    """Angle (deg) between the estimated and the true relative rotation of every pair of images in both."""
    names = sorted(set(estimated) & set(truth))
    return np.array([rotation_angle_deg((estimated[b] @ estimated[a].T) @ (truth[b] @ truth[a].T).T)
                     for i, a in enumerate(names) for b in names[i + 1:]])


def _aspect_with_poses_held(model_dir: Path, images: list[Path], truth: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                            K_true: np.ndarray) -> str:
    """fy / fx of the solve's tracks with every image's pose held at the ground truth (one line, for the report).

    Planar motion with the camera's y axis along the common rotation axis is
    critical for an unknown aspect: stretching the scene along the axis by
    ``s`` and dividing ``fy`` by ``s`` leaves every projection unchanged
    (Sturm, P. (1997). Critical Motion Sequences for Monocular
    Self-Calibration and Uncalibrated Euclidean Reconstruction. CVPR).
    Strecha's cameras move in a plane, tilted and rolled by +-2-10 degrees.
    With the laser-scanned poses held there is no such freedom: the
    intrinsics (fx, fy, cx, cy and a one-term division lens in normalised
    coordinates) are fitted by variable projection, every point
    re-triangulated (DLT, then Gauss-Newton with the poses held) for each
    trial K. Observations more than ``max(3 median, 1 px)`` off at the true
    K are left out.
    """
    reconstruction = pycolmap.Reconstruction(str(model_dir))
    ids = sorted(i for i, image in reconstruction.images.items() if image.has_pose)
    index = {i: k for k, i in enumerate(ids)}
    rotations, translations = [], []
    for i in ids:  # staged as <k>.<suffix>: the k-th image in sorted order
        _, R, centre = truth[images[int(Path(reconstruction.images[i].name).stem)].name]
        rotations.append(R)
        translations.append(-R @ centre)
    Rs, ts = np.array(rotations), np.array(translations)
    observed, cam, pt = [], [], []
    for p, point in enumerate(reconstruction.points3D.values()):
        for element in point.track.elements:
            observed.append(np.asarray(reconstruction.images[element.image_id].points2D[element.point2D_idx].xy) - 0.5)
            cam.append(index[element.image_id])
            pt.append(p)
    observed, cam, pt = np.array(observed), np.array(cam), np.array(pt)
    n_points = int(pt.max()) + 1
    P = np.concatenate([Rs, ts[:, :, None]], axis=2)[cam]

    def residuals(theta: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy, k = theta
        xn = np.stack([(observed[:, 0] - cx) / fx, (observed[:, 1] - cy) / fy], axis=1)
        xn = xn / (1 + k * np.sum(xn * xn, axis=1))[:, None]
        rows = (xn[:, 0, None] * P[:, 2] - P[:, 0], xn[:, 1, None] * P[:, 2] - P[:, 1])
        M = np.zeros((n_points, 4, 4))
        for row in rows:
            np.add.at(M, pt, row[:, :, None] * row[:, None, :])
        X = np.linalg.eigh(M)[1][:, :, 0]
        X = X[:, :3] / X[:, 3:]
        for _ in range(5):
            Y = np.einsum("mij,mj->mi", Rs[cam], X[pt]) + ts[cam]
            r = Y[:, :2] / Y[:, 2:] - xn
            J = (Rs[cam][:, :2] - (Y[:, :2] / Y[:, 2:])[:, :, None] * Rs[cam][:, 2:3]) / Y[:, 2, None, None]
            H, g = np.zeros((n_points, 3, 3)), np.zeros((n_points, 3))
            np.add.at(H, pt, np.einsum("mki,mkj->mij", J, J))
            np.add.at(g, pt, np.einsum("mki,mk->mi", J, r))
            X = X - np.linalg.solve(H, g[:, :, None])[:, :, 0]
        Y = np.einsum("mij,mj->mi", Rs[cam], X[pt]) + ts[cam]
        return (Y[:, :2] / Y[:, 2:] - xn) * theta[:2]

    start = np.array([K_true[0, 0], K_true[1, 1], K_true[0, 2], K_true[1, 2], 0.0])
    error = np.hypot(*residuals(start).T)
    keep = error < max(3 * np.median(error), 1.0)
    fits = {}
    for label, expand in (("apart", lambda x: x), ("fx = fy", lambda x: np.concatenate([x[:1], x]))):
        x0 = start if label == "apart" else start[1:]
        fit = least_squares(lambda x: residuals(expand(x))[keep].ravel(), x0, diff_step=1e-7,
                            x_scale=np.where(x0 == 0, 1e-9, np.abs(x0) * 1e-4))
        covariance = 2 * fit.cost / (fit.fun.size - x0.size) * np.linalg.inv(fit.jac.T @ fit.jac)
        fits[label] = (expand(fit.x), covariance, float(np.sqrt(np.mean(fit.fun ** 2))))
    (fx, fy, *_), covariance, rms = fits["apart"]
    gradient = np.array([-fy / fx ** 2, 1 / fx])
    sigma = float(np.sqrt(gradient @ covariance[:2, :2] @ gradient))
    return (f"fy / fx {fy / fx:.5f} +- {sigma:.5f} (truth {K_true[1, 1] / K_true[0, 0]:.5f}; fx error "
            f"{100 * (fx / K_true[0, 0] - 1):+.3f} %, fy error {100 * (fy / K_true[1, 1] - 1):+.3f} %), RMS {rms:.4f} px "
            f"against {fits['fx = fy'][2]:.4f} px with fx = fy ({keep.sum()} of {keep.size} observations)")


def bench_strecha(scenes: tuple[str, ...] = STRECHA_SCENES) -> None:
    """``solve`` against plain pycolmap on Strecha's scenes: time, intrinsics and relative rotations vs the truth."""
    root = next((Path(p) for p in STRECHA_DIRS if p and (Path(p) / scenes[0] / "gt_dense_cameras").is_dir()), None)
    if root is None:
        print(f"Strecha scenes: skipped, no {scenes[0]}/gt_dense_cameras in "
              f"{' or '.join(p for p in STRECHA_DIRS if p)}; set CAMCAL_STRECHA_DIR")
        return
    totals = {"ours": 0.0, "peer": 0.0}
    for scene in scenes:
        folder = root / scene / "images"
        images = sorted(folder.glob("*.jpg"))
        truth = {path.name: _strecha_camera(root / scene / "gt_dense_cameras" / f"{path.name}.camera") for path in images}
        K_true = next(iter(truth.values()))[0]
        for path in images:  # both runs read the files from the page cache
            path.read_bytes()
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            peer = solve_pycolmap_plain({"cam": folder}, Path(tmp) / "plain")
            theirs = time.perf_counter() - start
            start = time.perf_counter()
            result = solve_sfm({"cam": folder}, Path(tmp) / "camcal")
            ours = time.perf_counter() - start
            held = _aspect_with_poses_held(result.reconstruction_dir, images, truth, K_true)
        totals["ours"] += ours
        totals["peer"] += theirs
        camera = result.rig.camera("cam")
        rotations = {Path(frame.images["cam"]).name: camera.R @ frame.R for frame in result.rig.frames}
        peer_rotations = {Path(name).name: R for name, R in peer.cam_from_world.items()}
        true_rotations = {name: R for name, (_, R, _) in truth.items()}
        print(f"Strecha {scene} ({len(images)} images) solve time (s): ours {ours:.1f}, peer (plain pycolmap) "
              f"{theirs:.1f}, ratio {theirs / ours:.2f} (solve / plain {ours / theirs:.2f}); registered ours "
              f"{result.n_registered}, peer {peer.n_registered}")
        for label, K in (("ours", camera.K), ("peer", peer.cameras["cam"].K)):
            fx, fy = 100 * (K[0, 0] / K_true[0, 0] - 1), 100 * (K[1, 1] / K_true[1, 1] - 1)
            pp = np.hypot(*(K[:2, 2] - K_true[:2, 2]))
            print(f"Strecha {scene} {label}: fx error {fx:+.3f} %, fy error {fy:+.3f} % (focal error, mean |fx|, |fy|: "
                  f"{(abs(fx) + abs(fy)) / 2:.3f} %), principal point error {pp:.2f} px "
                  f"({K[0, 2] - K_true[0, 2]:+.2f}, {K[1, 2] - K_true[1, 2]:+.2f})")
        if result.bundle is not None:
            sigma = camera.quality.sigma
            lens = result.self_calibration.lens_models["cam"] if result.self_calibration is not None else "-"
            entries = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
            ratios = {key: abs(camera.K[ij] - K_true[ij]) / sigma.get(key, np.nan) for key, ij in entries.items()}
            print(f"Strecha {scene} ours sigma (px): " + ", ".join(f"{key} {sigma.get(key, np.nan):.2f}" for key in entries)
                  + "; |error| / sigma: " + ", ".join(f"{key} {value:.2f}" for key, value in ratios.items())
                  + f" ({sum(value < 2 for value in ratios.values())} / 4 within 2 sigma); lens model {lens}")
            if result.self_calibration is not None:
                print(f"Strecha {scene} ours " + " | ".join(line for line in result.self_calibration.lines()
                                                              if line.startswith("aspect")))
        print(f"Strecha {scene} our tracks with the laser-scanned poses held: {held}")
        mine, other = _rotation_errors(rotations, true_rotations), _rotation_errors(peer_rotations, true_rotations)
        print(f"Strecha {scene} relative rotation error (deg, {len(mine)} / {len(other)} pairs): mean ours "
              f"{mine.mean():.4f}, peer {other.mean():.4f}, ratio {other.mean() / mine.mean():.2f}; largest ours "
              f"{mine.max():.4f}, peer {other.max():.4f}")
    print(f"Strecha scenes solve time (s, {len(scenes)} scenes): ours {totals['ours']:.1f}, peer {totals['peer']:.1f}, "
          f"ratio {totals['peer'] / totals['ours']:.2f} (solve / plain {totals['ours'] / totals['peer']:.2f})")


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


def bench_jackknife() -> None:
    """The delete-one-frame jackknife by one Gauss-Newton step per frame against full refits: time and sigmas."""
    from camcal.geometry.jackknife import frame_jackknife  # noqa: PLC0415

    options = BundleOptions(refine_principal_point=True)
    full = bundle_adjust(state_from_reconstruction(_noisy_rig_reconstruction()), options)
    start = time.perf_counter()
    step = frame_jackknife(full, options)
    ours = time.perf_counter() - start
    start = time.perf_counter()
    refit = frame_jackknife(full, options, method="refit")
    peer = time.perf_counter() - start
    ratios = {key: step.sigmas[key] / value for key, value in refit.sigmas.items() if value > 0}
    print(f"jackknife time (s, {step.n_groups} frames): ours (one step each) {ours:.2f}, full refits {peer:.2f}, "
          f"ratio {peer / ours:.1f}")
    print(f"jackknife sigma step / refit: min {min(ratios.values()):.3f}, max {max(ratios.values()):.3f} "
          f"({', '.join(f'{k} {v:.3f}' for k, v in ratios.items())})")


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
    parser.add_argument("--real-only", action="store_true", help="only the real scenes")
    parser.add_argument("--strecha", action="append", choices=STRECHA_SCENES, help="only these Strecha scenes")
    args = parser.parse_args()
    if args.strecha:
        bench_strecha(tuple(args.strecha))
        return
    if args.real_only:
        bench_real_scene()
        bench_strecha()
        return
    bench_real_scene()
    bench_strecha()
    bench_bundle()
    bench_jackknife()
    bench_covariance()
    if not args.bundle_only:
        bench_solve(args.frames)


if __name__ == "__main__":
    main()
