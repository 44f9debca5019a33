"""``camcal solve``: cameras from image folders (pycolmap structure from motion + camcal's bundle adjustment)."""

from __future__ import annotations

import argparse

from camcal.api.reconstruction import UNCERTAINTY
from camcal.cli.options import every_option, handler, loss_option, named_option, only_with, out_option
from camcal.cli.summary import report_result

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal solve``."""
    parser.add_argument("folders", nargs="+", metavar="IMAGES_DIR", help="image folder(s)")
    named_option(parser, "--images", "NAME=GLOB|VIDEO", "a camera's images, e.g. left='*_L.png' right='*_R.png', "
                 "or its video (left=left.mp4: every --every-th frame, streamed into OUT/images; the k-th frames "
                 "kept pair up) (relative to IMAGES_DIR, or absolute; several entries or a repeated option; "
                 "default: one camera per folder)", dest="camera", old="--camera")
    every_option(parser)
    parser.add_argument("--frames", metavar="RANGE", help="plates given as IMAGES_DIR or --images with a frame "
                        "placeholder (left.%%04d.exr, left.####.dpx): these frames (1001-1100, 1001-1100x2; all on disk "
                        "by default), every one must exist")
    only_with(parser, "--frames", "a frame placeholder in IMAGES_DIR or --images (left.%04d.exr)", _plates_given)
    named_option(parser, "--mask", "NAME=PATTERN", "a camera's matte sequence (left=mattes/left.%%04d.exr, the same "
                 "--frames; alpha, else the first channel): no feature is taken where it is white (moving actors, the sky)")
    parser.add_argument("--rig", metavar="KNOWN.rig.json",
                        help="hold the cameras' relative poses at this calibration (and take its units)")
    parser.add_argument("--intrinsics", metavar="GRID.rig.json",
                        help="take each camera's lens from this grid calibration (calibrate board; by camera name, or "
                        "its one camera for a one-camera solve) instead of choosing one: a plate of the grid's size "
                        "takes it as is, one of the same aspect at another size takes K scaled (said); another "
                        "aspect or a crop is an error naming both sizes; a rig with a lens per frame (a zoom or a "
                        "refocus, from camcal lens --metadata) holds each plate frame at the lens of the frame of "
                        "its number (the last number in its file name; fixed only, one camera) and the solved rig "
                        "carries those lenses")
    parser.add_argument("--intrinsics-mode", choices=("fixed", "prior"),
                        help="hold the grid's lens (fixed) or refine it under a Gaussian prior of the grid's sigmas "
                        "(prior; the move is said in sigmas) (default: fixed)")
    only_with(parser, "--intrinsics-mode", "--intrinsics", lambda args: args.intrinsics is not None, default="fixed")
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
                        "by the images alone (refine), or hold it at the centre (default: %(default)s)")
    parser.add_argument("--prior", action="append", default=[], metavar="CAMERA.NAME=MEAN+-SIGMA",
                        help="a Gaussian prior on an intrinsic (f, fx, fy, aspect, cx, cy, lambda, k1, k2, p1, p2; "
                        "camcal's units and pixel convention), e.g. left.f=1200+-30; repeatable. The rig's "
                        "intrinsics and sigmas are then the posterior's")
    parser.add_argument("--uncertainty", default="jackknife", choices=tuple(UNCERTAINTY),
                        help="sigmas: the larger of the covariance and a delete-one-frame jackknife (one "
                        "Gauss-Newton step per frame or group of frames, at most 20), which sees errors an image's "
                        "features share; the same with a full bundle adjustment per group (jackknife-refit, "
                        "slower); or the covariance alone (too small on real features) (default: %(default)s)")
    parser.add_argument("--features", type=int, default=8192, metavar="N",
                        help="SIFT features per image (default: %(default)s)")
    parser.add_argument("--guided-matching", action="store_true",
                        help="match each verified pair again along its epipolar geometry (more, longer tracks; "
                        "10-20 times the matching time on the CPU)")
    parser.add_argument("--matcher", default="exhaustive", choices=("exhaustive", "sequential"),
                        help="COLMAP's pair matching: every pair, or neighbours in file order (video, long "
                        "sequences) (default: %(default)s)")
    parser.add_argument("--loops", choices=("auto", "off"),
                        help="with --matcher sequential, loop closure for shots that revisit: every second frame "
                        "gets a global descriptor (VLAD over a vocabulary of the plate's own SIFT features), frames "
                        "further apart than the matching window that look alike are matched too and kept if COLMAP's "
                        "geometric verification holds them; the pairs added and verified are printed "
                        "(default: auto)")
    only_with(parser, "--loops", "--matcher sequential", lambda args: args.matcher == "sequential", default="auto")
    parser.add_argument("--tracks", default="auto", choices=("auto", "refine", "detected"),
                        help="the observations camcal's bundle adjustment takes: each aligned to its track's middle "
                        "observation by an affine patch alignment (refine: a detected SIFT position moves with the "
                        "viewpoint, and on a pan the focal length absorbs it), or the keypoints as detected; auto "
                        "refines with --matcher sequential (default: %(default)s)")
    parser.add_argument("--mapper", default="incremental", choices=("incremental", "global"),
                        help="COLMAP's incremental or global mapper (default: %(default)s)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="extract and match the features on this Dask cluster: one task per image, then one per "
                       "block of 100 image pairs matched and verified (its workers must see the images and the "
                       "folder OUT is in); each image's features and each block's matches are kept in "
                       "OUT/.camcal-features until the solve ends, so a rerun of a killed solve does only what it "
                       "had not finished; the features, matches and rig are the same as in this process, the "
                       "mapping stays here (default: in this process, the extraction on every core, the matching on one "
                       "thread, so that two runs give the same cameras)")
    where.add_argument("--workers", type=int, metavar="N",
                       help="the same on a local Dask cluster of N worker processes: the matching in parallel, each block "
                       "on one thread (default: no Dask)")
    parser.add_argument("--require-all", action="store_true",
                        help="an image that cannot be registered is an error (nothing written); by default each is "
                        "named by its frame number in one line and the solve goes on")
    parser.add_argument("--up", choices=("ground", "cameras"),
                        help="after the solve, turn the world so that +z is up: the normal of the ground plane "
                        "(RANSAC on the sparse points) or the cameras' mean up; the first camera then looks down +y "
                        "(default: the solve's own axes)")
    parser.add_argument("--origin", metavar="POINT",
                        help="the point that becomes the origin: ground (the ground plane under the first camera), "
                        "a point's row in points.ply (12) or coordinates in the solve's world (--origin=0.5:-1.2:3) "
                        "(default: the solve's own origin)")
    parser.add_argument("--scale", metavar="A,B=DIST",
                        help="two points (rows of points.ply or x:y:z coordinates) and their known distance, e.g. "
                        "12,40=1.5: the world is scaled to it (default: the solve's own scale, units arbitrary)")
    parser.add_argument("--world-board", metavar="SPEC",
                        help="a board lying in the set, chessboard:WxH:SQUARE or charuco:DICT:WxH:SQUARE:MARKER (as "
                        "calibrate board's --board), found in up to 24 of the solved frames and triangulated: its "
                        "plane becomes the ground (+z towards the cameras), its first inner corner the origin, its "
                        "columns +x, its squares the scale; instead of --up, --origin and --scale (default: none)")
    parser.add_argument("--units", metavar="NAME",
                        help="the unit of --scale's distance or of --world-board's squares, recorded in the rig "
                        "(default: m)")
    only_with(parser, "--units", "--scale or --world-board",
              lambda args: args.scale is not None or args.world_board is not None)
    parser.add_argument("--readout-ms", metavar="MS|typical|estimate",
                        help="the camera's rolling-shutter readout time, top row to bottom row, in ms (typical: 30, a "
                        "consumer camera's): after the solve, each frame's points are moved by the camera's motion "
                        "during the readout (its speed and turn from the neighbouring frames), the largest move is "
                        "stored per frame in the rig and frames above --readout-flag-px are named; estimate: the "
                        "readout is estimated from the solved plate by a rolling-shutter bundle adjustment, stored "
                        "with its standard deviation and used for the check, or said to be undetermined where the "
                        "camera moves straight or sideways at a constant speed (default: no check, a global "
                        "shutter)")
    parser.add_argument("--readout-flag-px", type=float, metavar="PX",
                        help="flag frames whose points move more than this during the readout (default: 1.0)")
    only_with(parser, "--readout-flag-px", "--readout-ms", lambda args: args.readout_ms is not None, default=1.0)
    parser.add_argument("--fps", type=float, metavar="FPS",
                        help="the plate's frame rate, which times the frames for the rolling-shutter check "
                        "(default: a movie's own, else 24)")
    only_with(parser, "--fps", "--readout-ms", lambda args: args.readout_ms is not None)
    loss_option(parser, "robust loss of camcal's bundle adjustment (scale 1 px; default: %(default)s)")
    parser.add_argument("--no-refine", action="store_true", help="keep pycolmap's result, skip camcal's refinement")
    parser.add_argument("--compare-pycolmap", action="store_true",
                        help="also run plain pycolmap (SIMPLE_DIVISION, principal point refined) on the same images "
                        "into OUT/pycolmap and print its intrinsics beside camcal's")
    parser.add_argument("--seed", type=int, default=0,
                        help="seeds every random choice (COLMAP's RANSAC and mapper, the held-out points): the same "
                        "images and options give the same rig; recorded in its provenance (default: %(default)s)")
    parser.add_argument("--verbose", action="store_true",
                        help="also show COLMAP's own log lines on stderr (always written to OUT/colmap.log)")
    out_option(parser, "DIR", "the folder to write: solve.rig.json, points.ply, the COLMAP model and colmap.log")
    handler(parser, _solve, [
        "# one folder per camera",
        "camcal solve images/left images/right --out solve",
        "# two cameras' images in one folder, a fisheye lens, the relative pose of a board calibration",
        "camcal solve shots --images left='*_L.jpg' right='*_R.jpg' --model kannala-brandt --rig "
        "board.rig.json --out solve",
        "# a plate with the lens of the day's grid held, every frame required, the world set on the ground",
        "camcal solve plates/shot.%04d.exr --frames 1001-1240 --matcher sequential --intrinsics grid.rig.json "
        "--require-all --up ground --origin ground --scale 12,40=1.5 --out solve",
        "# a zoom, each frame held at its lens (shot.rig.json: camcal lens PROFILE --metadata lens.csv)",
        "camcal solve plates/shot.%04d.exr --frames 1001-1240 --matcher sequential --intrinsics shot.rig.json "
        "--out solve",
        "# a handheld shot that comes back to where it started, matched by frame order, no loop closure",
        "camcal solve plates/walk.%04d.png --matcher sequential --loops off --out solve",
        "# driving footage from a phone: frames whose motion during a 30 ms readout moves points over 2 px flagged",
        "camcal solve drive/frame.%06d.png --matcher sequential --intrinsics phone.rig.json --readout-ms 30 "
        "--readout-flag-px 2 --fps 30 --out solve",
        "# a handheld phone plate that pans and tilts: its readout estimated from the plate, frames checked with it",
        "camcal solve walk/frame.%04d.png --matcher sequential --intrinsics phone.rig.json --readout-ms estimate "
        "--fps 30 --out solve",
        "# a long plate's features extracted and matched on a Dask cluster (rerun the same command after a crash to "
        "resume)",
        "camcal solve plates/shot.%04d.exr --frames 1001-1960 --matcher sequential --scheduler tcp://farm:8786 "
        "--out solve",
        "# the world set on a 9x6 chessboard of 4 cm squares lying on the set's floor",
        "camcal solve plates/shot.%04d.exr --frames 1001-1240 --matcher sequential --world-board chessboard:9x6:0.04 "
        "--out solve",
    ])


def _plates_given(args: argparse.Namespace) -> bool:
    """Whether an image folder or an --images entry is a plate (has a frame placeholder)."""
    from camcal.io.sequence import is_sequence_pattern

    return any(map(is_sequence_pattern, [*args.folders, *(args.camera or {}).values()]))


def _solve(args: argparse.Namespace) -> int:
    """One folder per camera (or one folder of per-camera sub-folders, or --images NAME=GLOB inside one folder);
    several cameras form a rig whose frames pair up by sorted order. Each camera's lens model is chosen by
    held-out residual; the principal point and the lens are refined under the sensor's Gaussian priors and the
    user's (--prior), and what the images do not determine is said with its sigma; or the lens of a grid
    calibration is held (--intrinsics). Frames that cannot be registered are named by number. The world can be set
    after the solve (--up, --origin, --scale, or --world-board). Writes OUT/solve.rig.json, OUT/points.ply and the
    COLMAP model.
    """
    from camcal.api.reconstruction import solve

    result = solve(args.folders, args.out, images=args.camera, every=args.every, frames=args.frames, masks=args.mask,
                   rig=args.rig, model=args.model,
                   camera_model=args.camera_model, principal_point=args.principal_point, priors=args.prior,
                   uncertainty=args.uncertainty, features=args.features, guided_matching=args.guided_matching,
                   matcher=args.matcher, loops=args.loops, tracks=args.tracks, mapper=args.mapper, loss=args.loss,
                   refine=not args.no_refine, compare_pycolmap=args.compare_pycolmap, intrinsics=args.intrinsics,
                   intrinsics_mode=args.intrinsics_mode, require_all=args.require_all, up=args.up, origin=args.origin,
                   scale=args.scale, units=args.units, world_board=args.world_board, readout_ms=args.readout_ms,
                   readout_flag_px=args.readout_flag_px, fps=args.fps, seed=args.seed,
                   scheduler=args.scheduler, workers=args.workers, verbose=args.verbose)
    report_result(args, result, say=False)
    return 0
