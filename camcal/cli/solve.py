"""``camcal solve``: cameras from image folders (pycolmap structure from motion + camcal's bundle adjustment)."""

from __future__ import annotations

import argparse
import math
import sys

from camcal.base.errors import CamcalError
from camcal.cli.options import every_option, expand_glob, handler, loss_option, named_option, out_option
from camcal.cli.summary import summary_of

__all__ = ["register"]

#: ``--uncertainty`` -> the jackknife's replicate method (camcal.geometry.jackknife.METHODS), None: covariance alone.
UNCERTAINTY = {"jackknife": "step", "jackknife-refit": "refit", "covariance": None}


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal solve``."""
    parser.add_argument("folders", nargs="+", metavar="IMAGES_DIR", help="image folder(s)")
    named_option(parser, "--camera", "NAME=GLOB|VIDEO", "a camera's images, e.g. left='*_L.png' right='*_R.png', "
                 "or its video (left=left.mp4: every --every-th frame, streamed into OUT/images; the k-th frames "
                 "kept pair up) (relative to IMAGES_DIR, or absolute; several entries or a repeated option)")
    every_option(parser)
    parser.add_argument("--frames", metavar="RANGE", help="plates given as IMAGES_DIR or --camera with a frame "
                        "placeholder (left.%%04d.exr, left.####.dpx): these frames (1001-1100, 1001-1100x2; all on disk "
                        "by default), every one must exist")
    named_option(parser, "--mask", "NAME=PATTERN", "a camera's matte sequence (left=mattes/left.%%04d.exr, the same "
                 "--frames; alpha, else the first channel): no feature is taken where it is white (moving actors, the sky)")
    parser.add_argument("--rig", metavar="KNOWN.rig.json",
                        help="hold the cameras' relative poses at this calibration (and take its units)")
    parser.add_argument("--model", choices=("auto", "division", "polynomial", "opencv", "none", "kannala-brandt"),
                        help="camcal lens model (refined as COLMAP DIVISION / OPENCV with p1 = p2 = 0 / OPENCV / "
                        "PINHOLE / OPENCV_FISHEYE: fx and fy apart, under the square-pixel prior fx - fy +- 1 %% "
                        "of f except with --principal-point refine; skew 0); auto (the default) chooses per camera "
                        "by held-out residual among "
                        "division, polynomial and opencv, never kannala-brandt: name it for a fisheye lens "
                        "(mapped with SIMPLE_RADIAL, then refined as OPENCV_FISHEYE)")
    parser.add_argument("--camera-model", help="COLMAP camera model to map with; alone, it is kept (no choice; "
                        "a model with one focal length then keeps fx = fy)")
    parser.add_argument("--principal-point", default="auto", choices=("auto", "refine", "centre"),
                        help="refine it under the sensor's prior, the image centre +- 2 %% of the diagonal (auto), "
                        "by the images alone (refine), or hold it at the centre")
    parser.add_argument("--prior", action="append", default=[], metavar="CAMERA.NAME=MEAN+-SIGMA",
                        help="a Gaussian prior on an intrinsic (f, fx, fy, aspect, cx, cy, lambda, k1, k2, p1, p2; "
                        "camcal's units and pixel convention), e.g. left.f=1200+-30; repeatable. The rig's "
                        "intrinsics and sigmas are then the posterior's")
    parser.add_argument("--uncertainty", default="jackknife", choices=tuple(UNCERTAINTY),
                        help="sigmas: the larger of the covariance and a delete-one-frame jackknife (one "
                        "Gauss-Newton step per frame or group of frames, at most 20), which sees errors an image's "
                        "features share; the same with a full bundle adjustment per group (jackknife-refit, "
                        "slower); or the covariance alone (too small on real features)")
    parser.add_argument("--features", type=int, default=8192, metavar="N", help="SIFT features per image (8192)")
    parser.add_argument("--guided-matching", action="store_true",
                        help="match each verified pair again along its epipolar geometry (more, longer tracks; "
                        "10-20 times the matching time on the CPU)")
    parser.add_argument("--matcher", default="exhaustive", choices=("exhaustive", "sequential"))
    parser.add_argument("--mapper", default="incremental", choices=("incremental", "global"))
    loss_option(parser, "robust loss of camcal's bundle adjustment (scale 1 px)")
    parser.add_argument("--no-refine", action="store_true", help="keep pycolmap's result, skip camcal's refinement")
    parser.add_argument("--compare-pycolmap", action="store_true",
                        help="also run plain pycolmap (SIMPLE_DIVISION, principal point refined) on the same images "
                        "into OUT/pycolmap and print its intrinsics beside camcal's")
    parser.add_argument("--seed", type=int, default=0,
                        help="seeds every random choice (COLMAP's RANSAC and mapper, the held-out points): the same "
                        "images and options give the same rig; recorded in its provenance (0)")
    parser.add_argument("--verbose", action="store_true",
                        help="also show COLMAP's own log lines on stderr (always written to OUT/colmap.log)")
    out_option(parser, "DIR")
    handler(parser, _solve)


def _solve(args: argparse.Namespace) -> int:
    """One folder per camera (or one folder of per-camera sub-folders, or --camera NAME=GLOB inside one folder);
    several cameras form a rig whose frames pair up by sorted order. Each camera's lens model is chosen by
    held-out residual; the principal point and the lens are refined under the sensor's Gaussian priors and the
    user's (--prior), and what the images do not determine is said with its sigma. Writes OUT/solve.rig.json, OUT/points.ply and the COLMAP model.
    """
    from pathlib import Path

    from camcal.geometry.bundle import parse_prior
    from camcal.geometry.selfcal import LENS_MODELS, MAPPING_MODELS
    from camcal.pipelines.solve import COLMAP_LOG, collect_images, solve_pycolmap_plain, solve_sfm
    from camcal.model.rig import Rig
    from camcal.io.sequence import is_sequence_pattern, sequence_paths

    folders = [Path(folder) for folder in args.folders]
    if args.camera:
        if len(folders) != 1:
            raise CamcalError(f"--camera NAME=GLOB selects images inside one folder: give exactly one, got {len(folders)}")
        if not folders[0].is_dir():
            raise CamcalError(f"image folder not found: {folders[0]}")
        images = {name: sequence_paths(folders[0] / pattern, args.frames) if is_sequence_pattern(pattern)
                  else [Path(f) for f in expand_glob("--camera", name, pattern, root=folders[0])]
                  for name, pattern in args.camera.items()}
    else:
        images = collect_images(folders, frames=args.frames)
    known_rig = Rig.load(args.rig) if args.rig else None
    if args.features < 100:
        raise CamcalError(f"--features must be at least 100, got {args.features}")
    # --model auto (or nothing): choose among LENS_MODELS; a named model: only it; --camera-model alone: keep it
    model = args.model or ("keep" if args.camera_model else "auto")
    lens_models = LENS_MODELS if model == "auto" else (None if model == "keep" else (model,))
    # COLMAP marks fisheye pairs without a focal prior as degenerate (no match survives): a fisheye maps with
    # SIMPLE_RADIAL and becomes kannala-brandt in the self-calibration (a fit of the lens, then the bundle)
    mapped = model in MAPPING_MODELS and model != "kannala-brandt"
    camera_model = args.camera_model or (MAPPING_MODELS[model] if mapped else "SIMPLE_RADIAL")
    result = solve_sfm(images, Path(args.out), camera_model=camera_model, matcher=args.matcher, mapper=args.mapper,
                       seed=args.seed, refine=not args.no_refine, known_rig=known_rig, loss=args.loss,
                       lens_models=lens_models, principal_point=args.principal_point, max_num_features=args.features,
                       jackknife=UNCERTAINTY[args.uncertainty], priors=tuple(parse_prior(text) for text in args.prior),
                       verbose=args.verbose, guided_matching=args.guided_matching, every=args.every,
                       masks={name: sequence_paths(pattern, args.frames) for name, pattern in (args.mask or {}).items()},
                       progress=lambda message: print(f"camcal solve: {message}", file=sys.stderr, flush=True))
    print(f"registered {result.n_registered} / {result.n_images} images"
          + (f" (not registered: {', '.join(result.unregistered)})" if result.unregistered else ""))
    per_camera = ", ".join(f"{name} {rms:.3f} px" for name, rms in result.per_camera_rms_px.items())
    print(f"RMS reprojection error: {result.rms_px:.3f} px ({per_camera}); {result.n_points} points")
    if result.bundle is not None:
        print(result.bundle.summary())
    if result.self_calibration is not None:
        print("\n".join(result.self_calibration.lines()))
    peer = (solve_pycolmap_plain(images, Path(args.out) / "pycolmap", seed=args.seed, verbose=args.verbose,
                                 every=args.every)
            if args.compare_pycolmap else None)
    for camera in result.rig.cameras:
        sigma = camera.quality.get("sigma", {})
        print(f"{camera.name}: {_intrinsics_line(camera, sigma)}"
              + (f"; heldout RMS {camera.quality['heldout_rms_px']:.3f} px" if "heldout_rms_px" in camera.quality else ""))
        if "rotation_deg" in sigma:
            print(f"{camera.name}: rig pose sigma rotation {sigma['rotation_deg']:.3g} deg, "
                  f"baseline {100 * sigma['baseline_rel']:.3g} %")
        if peer is not None and camera.name in peer.cameras:
            print(f"{camera.name} (plain pycolmap): {_intrinsics_line(peer.cameras[camera.name], {})}; "
                  f"RMS {peer.rms_px[camera.name]:.3f} px")
    print(f"wrote {Path(args.out) / 'solve.rig.json'}, {Path(args.out) / 'points.ply'} and the COLMAP model in "
          f"{result.reconstruction_dir} (COLMAP's log: {Path(args.out) / COLMAP_LOG})")
    out = summary_of(args)
    out.figures(n_images=result.n_images, n_registered=result.n_registered, unregistered=list(result.unregistered),
                rms_px=result.rms_px, per_camera_rms_px=dict(result.per_camera_rms_px), n_points=result.n_points,
                bundle=None if result.bundle is None else result.bundle.summary(),
                cameras={camera.name: dict(camera.quality) for camera in result.rig.cameras})
    if result.self_calibration is not None:
        calibration = result.self_calibration
        out.figures(lens_models=calibration.lens_models, heldout_rms_px_by_model=calibration.heldout_rms_px,
                    principal_point={d.camera: {"refined": d.refined, "determined": d.determined,
                                                "prior_sigma_px": d.prior_sigma_px if math.isfinite(d.prior_sigma_px) else None,
                                                "sigma_px": [v if math.isfinite(v) else None for v in d.sigma_px],
                                                "reason": d.reason} for d in calibration.principal_point},
                    uncertainty={"covariance_sigmas": calibration.covariance_sigmas,
                                 "jackknife_sigmas": calibration.jackknife_sigmas,
                                 "jackknife_groups": calibration.jackknife_groups,
                                 "jackknife_method": calibration.jackknife_method or None})
    if peer is not None:
        out.figures(pycolmap={name: {"K": camera.K, "distortion": camera.distortion.to_dict(),
                                     "rms_px": peer.rms_px.get(name)} for name, camera in peer.cameras.items()})
    out.wrote(Path(args.out) / "solve.rig.json", "rig", say=False)
    out.wrote(Path(args.out) / "points.ply", "points", say=False)
    out.wrote(result.reconstruction_dir, "colmap model", say=False)
    out.wrote(Path(args.out) / COLMAP_LOG, "log", say=False)
    return 0


def _intrinsics_line(camera, sigma) -> str:
    """``f 900.12 +- 0.04 px, principal point (646.0, 474.3) +- (0.01, 0.02) px, division lambda -1.2e-07``."""
    def pm(key: str, fmt: str) -> str:
        return f" +- {sigma[key]:{fmt}}" if key in sigma else ""
    K = camera.K
    focal = f"f {K[0, 0]:.2f}{pm('fx', '.2g')}" if K[0, 0] == K[1, 1] else \
        f"fx {K[0, 0]:.2f}{pm('fx', '.2g')}, fy {K[1, 1]:.2f}{pm('fy', '.2g')}"
    lens = ", ".join(f"{name} {value:.4g}{pm(name, '.2g')}" for name, value in camera.distortion.params.items())
    return (f"{focal} px, principal point ({K[0, 2]:.2f}{pm('cx', '.2g')}, {K[1, 2]:.2f}{pm('cy', '.2g')}) px, "
            f"{camera.distortion.model} {lens}")
