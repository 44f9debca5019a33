"""``camcal calibrate dlt | board | profile``: one camera from 3D-2D points, a rig from board images, or a lens
profile from board images at several lens states."""

from __future__ import annotations

import argparse

from camcal.cli.options import (cache_options, corner_cache, handler, image_size, image_size_option, loss_option,
                                named_option, only_with, out_option, report_option, verb_group)
from camcal.cli.summary import report_result, summary_of

__all__ = ["register"]

#: ``calibrate board --model`` choices besides ``auto`` and ``<model>+spline`` (camcal.geometry.zhang.MODELS, written
#: here so that ``--help`` does not import the solver; tests/cli check the two agree).
_BOARD_MODELS = ("none", "division", "polynomial", "kannala-brandt", "opencv", "opencv-rational", "opencv-thin-prism",
                 "kannala-brandt-thin-prism")
#: 3DEqualizer's LDPK models (camcal.model.tde4.TDE4_MODELS), fitted directly; no correction field.
_TDE4_MODELS = ("3de-classic", "3de4-radial-deg4", "3de4-anamorphic-deg4", "3de4-fisheye-deg8")


def register(parser: argparse.ArgumentParser) -> None:
    """``dlt``, ``board`` and ``profile`` under ``camcal calibrate``."""
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
                       + _TDE4_MODELS + ("auto",), metavar="MODEL",
                       help="lens model: " + ", ".join(_BOARD_MODELS) + ", any of them with a correction field "
                       "(MODEL+spline, e.g. kannala-brandt+spline: a smooth B-spline displacement over the image "
                       "after the model, one camera, without --intrinsics), or auto; kannala-brandt is OpenCV's "
                       "fisheye model, opencv-rational and opencv-thin-prism its 8- and 12-coefficient models, "
                       "kannala-brandt-thin-prism COLMAP's RAD_TAN_THIN_PRISM_FISHEYE (six radial terms, "
                       "tangential, thin prism); " + ", ".join(_TDE4_MODELS) + " are 3DEqualizer's LDPK models "
                       "(one camera, fitted in their own distorted-to-undistorted direction); division estimates fx and fy (its aspect = fx / fy); auto "
                       "(default) ranks every model by views held out (each one's leave-one-view-out error estimated "
                       "from its one fit; --thorough: fold by fold) and keeps the simplest within 1 %% of the best")
    board.add_argument("--board-shape", default="auto", metavar="SHAPE",
                       choices=("auto", "flat") + tuple(f"{d}{p}" for d in ("2", "3", "4", "6", "free")
                                                        for p in ("", "+plane")),
                       help="the board's shape (one camera): flat, a smooth surface z(x, y) of degree 2, 3, 4 or 6 "
                       "or free (every corner's height), +plane: the corners' displacement in the board's plane too "
                       "(e.g. 4+plane), fitted with the lens (a printed board bows, twists and stretches), or auto "
                       "(default): with --model "
                       "auto, a surface only where it beats the flat board on views held out in turn; with "
                       "--intrinsics RIG whose board has a fitted surface, that surface is held)")
    board.add_argument("--thorough", action="store_true",
                       help="with --model auto (the lens model and the board shape): rank by views held out in turn, fold by fold, "
                       "and also rank a correction field and every lens model again on the board surface taken "
                       "(dozens of fits; default: off, each candidate's held-out error estimated from its one fit, "
                       "about the cost of a few single-model fits), e.g. --model auto --thorough")
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
    cache_options(board)
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
    only_with(board, "--thorough", "--model auto", lambda args: args.model == "auto")
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
    _register_profile(verbs)


def _register_profile(verbs) -> None:
    """``calibrate profile``: its options."""
    profile = verbs.add_parser("profile", help="a lens profile over focal length and focus distance from board "
                               "images at several lens states (zoom, focus)")
    profile.add_argument("--board", required=True, metavar="SPEC",
                         help="the board every state's images show (as calibrate board: chessboard:WxH:SQUARE or "
                         "charuco:...)")
    named_option(profile, "--state", "FOCALmm@FOCUSm=GLOB|RIG", "a lens state and its board images, e.g. "
                 "24mm@1.2m='grids/24_1.2/*.jpg' (focus in m, cm or mm, or inf; repeated or several entries), or "
                 "a one-camera rig calibrated at that state (24mm@1.2m=cal24.rig.json); at least 2 states, or "
                 "--states-from")
    profile.add_argument("--states-from", nargs=2, action="append", metavar=("SOURCE", "PATH"),
                         help="the states and their images instead of --state: folders DIR (a sub-folder per state "
                         "named like --state, 24mm@1.2m, or with _ for @, 24mm_1.2m), exif GLOB (the images grouped "
                         "by the focal length and focus distance their EXIF records: FocalLength, SubjectDistance), "
                         "or csv FILE (columns image,focal_mm,focus_m; images relative to the CSV); at least 3 "
                         "images per state")
    profile.add_argument("--model", default="polynomial", metavar="MODEL",
                         choices=_BOARD_MODELS + _TDE4_MODELS + ("auto",),
                         help="the one lens model of every state, one of calibrate board's (default: polynomial, "
                         "k1 k2; auto ranks the models by views held out once, on the state of the shortest focal "
                         "length, and fits the winner at every state: ranking at every state is too slow)")
    profile.add_argument("--holdout", metavar="FRAMES",
                         help="each state's frames left out of its fit and reported as held-out RMS (as calibrate "
                         "board)")
    profile.add_argument("--suggest", action="store_true",
                         help="print the lens state to shoot next: where the profile's worst projection sigma over "
                         "the focal x focus range is largest")
    cache_options(profile)
    profile.add_argument("--force", action="store_true",
                         help="keep a state whose calibration fails calibrate board's quality gate")
    out_option(profile, "FILE.profile.json", "the lens profile to write")
    handler(profile, _profile, [
        "# a zoom at three focal lengths, focused at 1.2 m, and at infinity",
        "camcal calibrate profile --board chessboard:9x6:0.03 --state 24mm@1.2m='grids/24_1.2/*.jpg' "
        "--state 35mm@1.2m='grids/35_1.2/*.jpg' --state 70mm@1.2m='grids/70_1.2/*.jpg' "
        "--state 35mm@inf='grids/35_inf/*.jpg' --out lens.profile.json --suggest",
        "# the same states from folders named after them (grids/24mm@1.2m/, grids/35mm_inf/, ...)",
        "camcal calibrate profile --board chessboard:9x6:0.03 --states-from folders grids --out lens.profile.json",
        "# the images' lens states from their EXIF, or from a CSV (image,focal_mm,focus_m)",
        "camcal calibrate profile --board chessboard:9x6:0.03 --states-from exif 'grids/*.jpg' --out lens.profile.json",
        "camcal calibrate profile --board chessboard:9x6:0.03 --states-from csv states.csv --out lens.profile.json",
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
    from camcal.api.board import calibrate_board

    result = calibrate_board(
        args.camera, args.board, model=args.model, board_shape=args.board_shape, thorough=args.thorough,
        units=args.units, every=args.every,
        timestamps=args.timestamps, time_tolerance_s=args.time_tolerance, intrinsics=args.intrinsics,
        refine_intrinsics=args.refine_intrinsics, holdout=args.holdout, max_views=args.max_views, loss=args.loss,
        loss_scale=args.loss_scale, workers=args.workers, scheduler=args.scheduler,
        cache=corner_cache(args), force=args.force, suggest=args.suggest,
        out=args.out, report=args.report, suggest_preview=args.suggest_preview, log=print)
    for line in result.lines():
        print(line)
    out = summary_of(args)
    if result.quality_problems:
        out.warn("written with --force although " + "; ".join(result.quality_problems))
    out.figures(**result.figures())
    for path, kind in result.files:
        out.wrote(args.out if kind == "rig" else path, kind)
    return 3 if result.quality_problems else 0


def _profile(args: argparse.Namespace) -> int:
    """Calibrate the lens at each state (focal length and focus distance) from its board images, as calibrate
    board does, with one lens model for all; then fit each parameter (fx, fy, cx, cy and the lens model's) as a
    low-order polynomial surface over the focal length and 1 / focus distance (so focus is sampled toward
    infinity), its degrees chosen by leaving one state out in turn, its sigma propagated from each state's
    calibration and widened where the held-out states miss by more. States that every smooth surface misses by
    more than 5 sigma are named. The profile file holds every state and every surface; camcal lens makes a camera
    at any state from it. The states and their images come from --state, or from folder names, the images' EXIF
    or a CSV (--states-from).
    """
    from camcal.api.profile import calibrate_profile
    from camcal.base.errors import CamcalError

    sources = args.states_from or []
    if len(sources) > 1:
        raise CamcalError(f"--states-from: give one source, got {len(sources)} ({', '.join(s for s, _ in sources)})")
    result = calibrate_profile(args.state or None, args.board, states_from=tuple(sources[0]) if sources else None,
                               model=args.model, holdout=args.holdout,
                               cache=corner_cache(args), force=args.force,
                               suggest=args.suggest, out=args.out, log=print)
    report_result(args, result)
    return 0
