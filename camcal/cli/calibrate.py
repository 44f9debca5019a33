"""``camcal calibrate dlt | board``: one camera from 3D-2D points, or a rig from board images."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import (expand_glob, handler, image_size, image_size_option, loss_option, named_option,
                                only_with, out_option, output_folder, parse_holdout, report_option, verb_group)
from camcal.cli.summary import summary_of

__all__ = ["register"]

#: ``calibrate board --model`` choices besides ``auto`` and ``<model>+spline`` (camcal.geometry.zhang.MODELS, written
#: here so that ``--help`` does not import the solver; tests/cli check the two agree).
_BOARD_MODELS = ("none", "division", "polynomial", "kannala-brandt", "opencv", "opencv-rational", "opencv-thin-prism",
                 "kannala-brandt-thin-prism")


def register(parser: argparse.ArgumentParser) -> None:
    """``dlt`` and ``board`` under ``camcal calibrate``."""
    verbs = verb_group(parser, "calibrate_verb", "METHOD")
    dlt = verbs.add_parser("dlt", help="one camera from 3D-2D correspondences (normalised DLT + LM)")
    dlt.add_argument("--points", required=True, metavar="FILE.csv", help="correspondences X,Y,Z,u,v")
    image_size_option(dlt, "the image's width and height in pixels", required=True)
    dlt.add_argument("--name", default="camera", help="camera name in the rig (default: camera)")
    out_option(dlt, "FILE.rig.json", "the rig file to write")
    handler(dlt, _dlt, [
        "camcal calibrate dlt --points survey.csv --image-size 1920 1080 --name A --out A.rig.json",
    ])
    board = verbs.add_parser(
        "board", help="one camera or an N-camera rig from chessboard / ChArUco images (joint refinement)")
    board.add_argument(
        "--board", required=True, metavar="SPEC",
        help="chessboard:WxH:SQUARE[:two-sided] (inner corners) or "
        "charuco:DICT:WxH:SQUARE:MARKER[:inverted][:two-sided][:legacy] (squares); inverted = white markers on "
        "black, two-sided = the back printed as the mirror image (cameras behind the board see it mirrored), "
        "legacy = OpenCV's legacy ChArUco pattern",
    )
    named_option(board, "--images", "NAME=GLOB|VIDEO", "a camera and its images, e.g. left='shots/left*.jpg' "
                 "right='shots/right*.jpg', or its video (cam0=cam_0.mp4; .mp4 .mov .avi .mkv, frame k of the "
                 "video is frame number k, from 0) (several entries or a repeated option; globs absolute or "
                 "relative)", required=True, dest="camera", old="--camera")
    board.add_argument("--every", type=int, default=1, metavar="N",
                       help="videos: detect every N-th frame (frames 0, N, 2N...; default 1); with --timestamps, the "
                       "first camera's, and the other cameras' frames matched to them")
    board.add_argument("--timestamps", metavar="FILE.csv",
                       help="frame times, CSV with the header camera,frame,time (seconds, one clock for all; frame "
                       "k of a video is its k-th frame from 0, of images the number in the file name): each camera's "
                       "frames are matched to the first camera's nearest in time instead of by frame number, and "
                       "numbered like them; frames without a match are dropped (counted)")
    board.add_argument("--time-tolerance", type=float, metavar="S",
                       help="with --timestamps: the largest time difference of a match, in seconds (default: half "
                       "the first camera's frame period)")
    board.add_argument("--intrinsics", metavar="RIG",
                       help="a rig file holding every camera's K and lens (by name): held, only the poses are "
                       "solved (the lens model is the rig's)")
    board.add_argument("--refine-intrinsics", action="store_true",
                       help="with --intrinsics: start from them and refine them")
    board.add_argument("--model", default="auto", choices=_BOARD_MODELS + tuple(m + "+spline" for m in _BOARD_MODELS)
                       + ("auto",), metavar="MODEL",
                       help="lens model: " + ", ".join(_BOARD_MODELS) + ", any of them with a correction field "
                       "(MODEL+spline, e.g. kannala-brandt+spline: a smooth B-spline displacement over the image "
                       "after the model, one camera, without --intrinsics), or auto; kannala-brandt is OpenCV's "
                       "fisheye model, opencv-rational and opencv-thin-prism its 8- and 12-coefficient models, "
                       "kannala-brandt-thin-prism COLMAP's RAD_TAN_THIN_PRISM_FISHEYE (six radial terms, "
                       "tangential, thin prism); division estimates fx and fy (its aspect = fx / fy); auto "
                       "(default) ranks every model by views held out in turn and keeps the simplest within 1 %% "
                       "of the best")
    board.add_argument("--board-shape", default="auto", metavar="SHAPE",
                       choices=("auto", "flat") + tuple(f"{d}{p}" for d in ("2", "3", "4", "6", "free")
                                                        for p in ("", "+plane")),
                       help="the board's shape (one camera): flat, a smooth surface z(x, y) of degree 2, 3, 4 or 6 "
                       "or free (every corner's height), +plane: the corners' displacement in the board's plane too "
                       "(e.g. 4+plane), fitted with the lens (a printed board bows, twists and stretches), or auto "
                       "(default): with --model "
                       "auto, a surface only where it beats the flat board on views held out in turn; with "
                       "--intrinsics RIG whose board has a fitted surface, that surface is held)")
    board.add_argument("--holdout", metavar="FRAMES",
                       help="frames left out of the fit and reported as held-out RMS (PnP, intrinsics held): "
                       "numbers and ranges (21-25) or a fraction (0.2)")
    board.add_argument("--max-views", type=int, metavar="N",
                       help="solve on at most N frames (board positions), chosen for coverage of each camera's image "
                       "and board tilts and of frames shared by pairs of cameras; the other frames are held out and "
                       "reported as held-out RMS")
    loss_option(board, "robust loss on each corner (Ceres; default: trivial)")
    board.add_argument("--loss-scale", type=float, default=1.0, metavar="PX", help="scale of the loss (default: 1 px)")
    board.add_argument("--workers", type=int, default=None, metavar="N",
                       help="images or frames detected at once (threads, or Dask worker processes; default: the "
                       "CPU count)")
    board.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="detect video frames on this Dask cluster (its workers must see the videos); without "
                       "it, videos of 2000 frames or more (after --every) run on a local Dask cluster, fewer in threads")
    board.add_argument("--cache", metavar="DIR",
                       help="corner cache directory, keyed by image content and detector settings "
                       "(default: $XDG_CACHE_HOME/camcal/corners)")
    board.add_argument("--no-cache", action="store_true", help="detect again, do not read or write the cache")
    board.add_argument("--force", action="store_true",
                       help="write a rig that fails the quality gate (principal point outside the image, RMS over "
                       "1.5 px, sigma fx over 5 %%) and exit 3 instead of refusing it")
    board.add_argument("--units", default="m", help="unit of the square size, stored in the rig (default: m)")
    board.add_argument("--suggest", type=int, default=0, metavar="N",
                       help="propose the next N board poses that most lower the worst projection sigma of the "
                       "first camera (expected, from the views taken), drawn on a frame-sized preview PNG (default: 0, none)")
    board.add_argument("--suggest-preview", metavar="FILE.png",
                       help="where --suggest draws its shot list (default: OUT without .rig.json + .suggest.png)")
    only_with(board, "--suggest-preview", "--suggest N", lambda args: args.suggest > 0)
    out_option(board, "FILE.rig.json", "the rig file to write")
    report_option(board, "write PNG plots: residuals, per-image RMS, coverage, projection sigma heat maps")
    handler(board, _board, [
        "# a stereo pair: 9x6 inner corners, 40 mm squares",
        "camcal calibrate board --board chessboard:9x6:0.04 --images left='shots/left*.jpg' "
        "right='shots/right*.jpg' --out board.rig.json --report report",
        "# one camera from a video (every 10th frame) and a ChArUco board",
        "camcal calibrate board --board charuco:DICT_5X5_100:7x5:0.04:0.03 --images cam=take1.mp4 "
        "--every 10 --out cam.rig.json",
    ])


def _dlt(args: argparse.Namespace) -> int:
    """Calibrate one camera from n >= 6 non-coplanar 3D points and their pixels. The CSV has the header X,Y,Z,u,v;
    pixel (0, 0) is the centre of the top-left pixel.
    """
    from camcal.geometry.dlt import calibrate_dlt
    from camcal.io.points_csv import read_correspondences
    from camcal.model.rig import Rig, make_provenance

    size = image_size(args.image_size)
    X, x = read_correspondences(args.points)
    result = calibrate_dlt(X, x)
    rig = Rig(
        (result.to_camera(args.name, size),),
        provenance=make_provenance("dlt", points=str(args.points)),
    )
    rig.save(args.out)
    K, sigma = result.K, result.sigmas
    print(
        f"RMS reprojection error: {result.rms_px:.3f} px "
        f"(worst {result.worst_px:.3f} px, {len(X)} points)"
    )
    print(
        f"fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  "
        f"principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f}) px  skew {K[0, 1]:.3g}"
    )
    print(f"camera centre ({result.c[0]:.4f}, {result.c[1]:.4f}, {result.c[2]:.4f})")
    out = summary_of(args)
    out.figures(rms_px=result.rms_px, worst_px=result.worst_px, n_points=len(X), K=K, sigma=sigma, c=result.c)
    out.wrote(args.out, "rig")
    return 0


def _board(args: argparse.Namespace) -> int:
    """Detect the board in every image, calibrate each camera with OpenCV, then refine all intrinsics, distortion
    and camera poses jointly. Views of several cameras are matched by the frame number in their file names (of a
    video: frame k is its k-th frame), or by time (--timestamps); the first camera is the reference (R = I, c = 0).
    """
    import os

    import numpy as np

    from camcal.base.atomic import final_path
    from camcal.geometry.board import frame_number, parse_board
    from camcal.pipelines.board import default_cache_dir, detect_in_images, detect_in_video
    from camcal.pipelines.distributed import detect_in_videos, use_dask
    from camcal.geometry.zhang import calibrate_board, quality_problems
    from camcal.base.progress import Progress
    from camcal.io.video import is_video, video_info
    from camcal.model.rig import Rig
    from camcal.report.calibration import write_report

    board = parse_board(args.board)
    if not args.camera:
        raise CamcalError("--camera: give at least one camera, e.g. --camera left='shots/left*.jpg'")
    if args.every < 1:
        raise CamcalError(f"--every must be 1 or more, got {args.every}")
    if args.max_views is not None and args.max_views < 1:
        raise CamcalError(f"--max-views must be 1 or more, got {args.max_views}")
    if args.refine_intrinsics and not args.intrinsics:
        raise CamcalError("--refine-intrinsics needs --intrinsics RIG (the start)")
    if args.time_tolerance is not None and not args.timestamps:
        raise CamcalError("--time-tolerance needs --timestamps FILE.csv")
    if args.time_tolerance is not None and not (0 < args.time_tolerance < float("inf")):
        raise CamcalError(f"--time-tolerance must be a positive number of seconds, got {args.time_tolerance}")
    timestamps = None
    if args.timestamps:
        from camcal.io.timestamps import read_timestamps

        timestamps = read_timestamps(args.timestamps)
        timestamps.check_cameras(list(args.camera))
    intrinsics, board_shape = None, args.board_shape
    if args.intrinsics:
        given = Rig.load(args.intrinsics)
        intrinsics = {camera.name: camera for camera in given.cameras}
        if ("board_shape" in given.provenance and args.board_shape == "auto"
                and given.provenance.get("board") == board.spec()):
            from camcal.geometry.board_shape import BoardShape

            board_shape = BoardShape.from_dict(given.provenance["board_shape"])
            print(f"--intrinsics {args.intrinsics}: its board's surface is held ({board_shape.describe(board)})")
        missing = [name for name in args.camera if name not in intrinsics]
        if missing:
            raise CamcalError(f"--intrinsics {args.intrinsics}: no camera named {', '.join(missing)} "
                              f"(it has: {', '.join(intrinsics)})")
    videos = {name: value for name, value in args.camera.items() if is_video(value)}
    # every video decodable before any work; the containers' frame counts (estimates) size the progress
    frame_counts = {name: video_info(video).frame_count for name, video in videos.items()}
    cameras = {name: expand_glob("--camera", name, pattern) for name, pattern in args.camera.items()
               if name not in videos}
    workers = args.workers or os.cpu_count() or 1
    cache = None if args.no_cache else (args.cache or default_cache_dir())
    first = next(iter(args.camera))
    # by time, another camera's frames matching the first camera's 0, N, 2N... are not its own 0, N, 2N...
    every = {name: 1 if timestamps is not None and name != first else args.every for name in videos}
    detections, reports, on_dask = {}, {}, {}
    n_video_frames = sum(-(-frame_counts[name] // every[name]) for name in videos)
    if videos and use_dask(n_video_frames, args.scheduler):
        for step in sorted(set(every.values())):
            group = {name: path for name, path in videos.items() if every[name] == step}
            on_dask |= detect_in_videos(board, group, every=step, workers=args.workers, scheduler=args.scheduler,
                                        cache=cache, progress=Progress(n_video_frames, f"detecting {len(group)} "
                                                                       "camera(s) on Dask", "frames").report)
    for name in args.camera:
        if name in videos:
            total = max(1, -(-frame_counts[name] // every[name]))
            report = on_dask[name] if name in on_dask else detect_in_video(
                board, videos[name], every=every[name], workers=workers, cache=cache,
                progress=Progress(total, f"detecting {name}", "frames").report)
            skipped = [str(frame_number(label)) for label in report.skipped]
            text = f"{name}: board found in {len(report.detections)} / {report.n_images} frames of {videos[name]}"
            if skipped:
                text += f" (not in frames {', '.join(skipped[:12])}{', ...' if len(skipped) > 12 else ''})"
            print(text)
        else:
            files = cameras[name]
            report = detect_in_images(board, files, progress=Progress(len(files), f"detecting {name}", "images").report,
                                      workers=workers, cache=cache)
            print(f"{name}: {report.summary()}")
        reports[name] = report
        detections[name] = report.detections
    if timestamps is not None:
        from camcal.pipelines.board import synchronise_detections

        detections, sync, dropped = synchronise_detections(reports, timestamps, args.time_tolerance,
                                                           sources={name: str(path) for name, path in videos.items()},
                                                           every=args.every)
        print(f"synchronised by time ({args.timestamps}): views numbered by {sync.reference}'s frames, matched "
              f"within {1e3 * sync.tolerance_s:.3g} ms")
        for name in args.camera:
            offset = "" if name == sync.reference else f", {sync.offsets_s[name]:+.4f} s from {sync.reference}"
            print(f"  {name}: {len(detections[name])} views kept, {dropped[name]} dropped (no frame of "
                  f"{sync.reference} within the tolerance, or no time){offset}")
    holdout: set[int] = set()
    if args.holdout:
        frames = sorted({frame_number(d.image) for views in detections.values() for d in views})
        holdout = parse_holdout(args.holdout, frames)
    if args.max_views is not None:
        from camcal.geometry.view_selection import select_frames

        frames = {frame_number(d.image) for views in detections.values() for d in views} - holdout
        chosen = select_frames(board, detections, args.max_views, intrinsics=intrinsics, exclude=holdout)
        if len(chosen) < len(frames):
            print(f"solving on {len(chosen)} of {len(frames)} frames, chosen for coverage (--max-views); the other "
                  f"{len(frames) - len(chosen)} are held out")
            holdout |= frames - set(chosen)
    result = calibrate_board(board, detections, model=args.model, units=args.units, loss=args.loss,
                             loss_scale=args.loss_scale, holdout=holdout, intrinsics=intrinsics,
                             refine_intrinsics=args.refine_intrinsics, board_shape=board_shape)
    problems = quality_problems(result)
    if problems and not args.force:
        raise CamcalError("calibration refused, its own figures show it broken: " + "; ".join(problems)
                          + " (--force writes it anyway)")
    with output_folder(args.report) as report_dir:
        if report_dir is not None:
            from camcal.report.sigma import write_sigma_heatmaps

            sigma_maps = write_sigma_heatmaps(result.rig.cameras, report_dir)
            reports = write_report(result, report_dir, board, sigma_maps) + sigma_maps
        else:
            reports = []
        result.rig.save(args.out)
    reports = [final_path(path, report_dir, args.report) for path in reports]
    for note in result.notes:
        print(note)
    if result.model_ranking:
        print(f"model auto: views held out in turn, chose {result.model}")
        for score in result.model_ranking:
            print("  " + score.describe())
    if result.shape_ranking:
        print("board shape auto: views held out in turn (the same folds; the lenses ranked again on the surface taken)")
        for score in result.shape_ranking:
            print("  " + score.describe())
    if result.dropped:
        print("dropped (no corner labelling agrees with the rig): " + ", ".join(image for _, image in result.dropped))
    print(result.summary())
    if result.outliers:
        print("dropped as outliers: " + ", ".join(image for _, image in result.outliers))
    for camera in result.rig.cameras:
        K, sigma = camera.K, camera.quality["sigma"]
        line = (
            f"{camera.name}: fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  "
            f"principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f}) +/- ({sigma['cx']:.2f}, {sigma['cy']:.2f}) px  "
            f"RMS {camera.quality['rms_px']:.3f} px"
        )
        if camera.quality.get("heldout_rms_px") is not None:
            line += f" (held-out {camera.quality['heldout_rms_px']:.3f} px)"
        if "baseline_rel" in sigma:
            baseline = float(np.linalg.norm(camera.c))
            line += (f"  baseline {baseline:.4f} +/- {sigma['baseline_rel'] * baseline:.4f} {result.rig.units}"
                     f"  rotation +/- {sigma['rotation_deg']:.3f} deg")
        print(line)
    shots, preview = [], None
    if args.suggest > 0:
        from camcal.geometry.suggest import pose_views, suggest_views
        from camcal.report.calibration import write_suggestion_preview

        camera = result.rig.cameras[0]
        kept = {image for name, image in result.images if name == camera.name}
        views = [d for d in detections[camera.name] if d.image in kept]
        shots = suggest_views(camera, board.object_points, pose_views(camera, board.object_points, views),
                              args.suggest)
        out_path = str(args.out)
        preview = args.suggest_preview or (out_path[:-len(".rig.json")] if out_path.endswith(".rig.json")
                                           else out_path) + ".suggest.png"
        preview = write_suggestion_preview(camera, shots, preview)
        print(f"{camera.name}: worst projection sigma now {camera.quality['worst_projection_sigma_px']:.3g} px; "
              f"next views (preview {preview}):")
        for number, shot in enumerate(shots, start=1):
            print(f"  {number}. {shot.describe()}")
    out = summary_of(args)
    if problems:
        out.warn("written with --force although " + "; ".join(problems))
    out.figures(
        summary=result.summary(), outliers=[image for _, image in result.outliers],
        detections={name: len(found) for name, found in detections.items()},
        cameras={camera.name: {"K": camera.K, "distortion": camera.distortion.to_dict(), "c": camera.c,
                               "quality": camera.quality.to_dict()} for camera in result.rig.cameras},
        model=result.model, heldout_rms_px=result.heldout_rms_px, model_heldout_rms_px=dict(result.model_heldout_rms_px),
        model_ranking=[{"model": s.model, "rms_px": s.rms_px, "n_params": s.n_params, "reason": s.reason}
                       for s in result.model_ranking],
        relabelled=[image for _, image in result.relabelled], dropped=[image for _, image in result.dropped],
        board_shape=None if result.board_shape is None else result.board_shape.to_dict(),
        shape_ranking=[{"model": s.model, "rms_px": s.rms_px, "n_params": s.n_params, "reason": s.reason}
                       for s in result.shape_ranking],
        quality_problems=problems,
    )
    if timestamps is not None:
        out.figures(synchronisation={"reference": sync.reference, "tolerance_s": sync.tolerance_s,
                                     "offsets_s": dict(sync.offsets_s), "dropped": dropped})
    if shots:
        out.figures(suggested=[{"centre_px": shot.centre_px, "distance": shot.distance, "tilt_deg": list(shot.tilt_deg),
                                "R": shot.R, "t": shot.t, "worst_sigma_px": shot.worst_sigma_px} for shot in shots])
    out.wrote(args.out, "rig")
    if preview is not None:
        out.wrote(preview, "suggest")
    if args.report:
        out.wrote_each(reports, "report", say=True)
    return 3 if problems else 0
