"""``camcal rectify``: 2 or N views onto one image plane (calibrated, N-view refined, or Hartley from matches)."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import (every_option, expand_glob, handler, max_fov_option, named_option, only_with,
                                out_option, output_folder, report_option, rig_argument, sigma_options)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal rectify``."""
    rig_argument(parser, "a calibrated *.rig.json")
    parser.add_argument("--method", choices=("camera", "hartley"), default="camera",
                        help="camera: rotate the calibrated cameras onto one plane; hartley: homographies from "
                        "point matches alone (Hartley 1999) (default: %(default)s)")
    parser.add_argument("--refine", action="store_true", help="camera method: refine on matches (Nozick 2011)")
    only_with(parser, "--refine", "--method camera", lambda args: args.method == "camera")
    named_option(parser, "--images", "NAME=GLOB|VIDEO", "images per camera, e.g. left='L/*.png' right='R/*.png', "
                 "or a video per camera (left=L.mp4: streamed, frame k written as L_00000k.png) (several entries or "
                 "a repeated option; globs absolute or relative)")
    every_option(parser)
    parser.add_argument("--matches", metavar="FILE.csv", help="point matches in original pixels")
    parser.add_argument("--alpha", type=float, default=0.0,
                        help="0: only pixels all views see (default); 1: every source pixel")
    max_fov_option(parser, "widest full angle about the rectified viewing direction the pinhole rectified images "
                   "hold (default: 120 when a camera has a kannala-brandt fisheye, no cap otherwise)")
    out_option(parser, "FILE.rig.json", "the rectified rig")
    parser.add_argument("--write", metavar="DIR", help="write rectified images to DIR/<camera>/")
    report_option(parser, "write DIR/rectification.json with the figures and the page DIR/index.html (with --sigma: "
                  "heat maps of the sigma maps with a colour bar, worst and median values)")
    sigma_options(parser, "per pair of consecutive cameras A-B, A-B_vertical_sigma.exr (the sigma of the vertical "
                  "disparity, rectified pixels) and with --distance A-B_depth_sigma.exr (the sigma of the depth at "
                  "that distance, rig units), pixel for pixel with A's rectified images, into the --write DIR (or "
                  "the --report DIR); --method camera only")
    handler(parser, _rectify, [
        "camcal rectify board.rig.json --images left='L/*.png' right='R/*.png' --write rectified "
        "--out rectified.rig.json",
        "camcal rectify board.rig.json --method hartley --matches matches.csv --out hartley.rig.json",
        "camcal rectify board.rig.json --out rectified.rig.json --report rectified --sigma --distance 2",
    ])


def _rectify(args: argparse.Namespace) -> int:
    """Rectify a rig's cameras onto one image plane and store per camera rectification {H, K_rect, image_size}, H
    mapping UNDISTORTED original pixels to rectified pixels. --method camera uses the calibration (with
    --refine: the N-view refinement of Nozick 2011 on matches); --method hartley uses only point matches
    (Hartley 1999). Matches come from --matches (CSV camera_a,u_a,v_a,camera_b,u_b,v_b) or from SIFT on the
    first image of each --images sequence (of a video: its frame 0).
    """
    import os

    from camcal.base.atomic import final_path
    from camcal.geometry.rectify import RectifyWarper, rectify
    from camcal.io.matches import read_matches_csv
    from camcal.io.video import is_video, video_info
    from camcal.pipelines.rectify import match_image_files, write_rectified
    from camcal.base.jsonfile import write_json
    from camcal.model.rig import Rig

    if not 0.0 <= args.alpha <= 1.0:
        raise CamcalError(f"--alpha must be in [0, 1], got {args.alpha}")
    if args.write and not args.images:
        raise CamcalError("--write needs --images NAME=GLOB for the cameras to rectify")
    if args.sigma and not (args.write or args.report):
        raise CamcalError("--sigma needs --write DIR or --report DIR for its EXRs")
    if args.sigma and (args.method != "camera" or args.refine):
        raise CamcalError("--sigma needs --method camera without --refine (a rotation of the calibrated cameras)")
    rig = Rig.load(args.rig)
    for name in args.images:
        rig.camera(name)
    if args.every < 1:
        raise CamcalError(f"--every must be 1 or more, got {args.every}")
    images = {name: [pattern] if is_video(pattern) else expand_glob("--images", name, pattern)
              for name, pattern in args.images.items()}
    for name, pattern in args.images.items():
        if is_video(pattern):
            video_info(pattern)  # decodable, before anything is computed or written
    names = list(images) if len(images) >= 2 else None
    if args.matches:
        matches = read_matches_csv(args.matches)
    elif images and (args.method == "hartley" or args.refine):
        matches = match_image_files(rig, {name: files[0] for name, files in images.items()})
    else:
        matches = None
    method = {"camera": "Nozick 2011" if args.refine else "camera", "hartley": "Hartley 1999"}[args.method]
    result = rectify(rig, method, matches, names, args.alpha, args.max_fov)
    pairs = []
    if args.sigma:
        from camcal.geometry.rectify.sigma import rectified_pair_sigma

        pairs = [rectified_pair_sigma(result.rig.camera(a), result.rig.camera(b), args.distance, units=rig.units)
                 for a, b in zip(result.names, result.names[1:])]
    written, sigma_files = [], []
    with output_folder(args.write) as write_dir, output_folder(args.report) as report_dir:
        if write_dir is not None:
            warper = RectifyWarper(result.rig)
            for name in result.names:
                written += write_rectified(warper, name, images.get(name, []), write_dir, args.every)
        links = {}
        if pairs:
            from camcal.io.stmap import write_sigma_map

            sigma_dir, final_dir = (write_dir, args.write) if write_dir is not None else (report_dir, args.report)
            for pair in pairs:
                for kind, values in (("vertical", pair.vertical_px), ("depth", pair.depth)):
                    if values is None:  # depth at infinity
                        continue
                    path = write_sigma_map(sigma_dir / f"{pair.first}-{pair.second}_{kind}_sigma.exr", values)
                    sigma_files.append(path)
                    if args.report:
                        links[pair.first, pair.second, kind] = os.path.relpath(final_path(path, sigma_dir, final_dir),
                                                                               args.report)
        reports = []
        if report_dir is not None:
            from camcal.report.rectification import write_report

            write_json(report_dir / "rectification.json", result.to_report())
            reports = [report_dir / "rectification.json", *write_report(result, report_dir, pairs, links)]
        result.rig.save(args.out)
    written = [final_path(path, write_dir, args.write) for path in written]
    if sigma_files:
        sigma_files = [final_path(path, sigma_dir, final_dir) for path in sigma_files]
    print(result.summary())
    for pair in pairs:
        print(pair.describe())
    out = summary_of(args)
    out.figures(**result.to_report())
    if pairs:
        out.figures(sigma=[pair.to_dict() for pair in pairs])
    out.wrote_each(written, "image")
    if written:
        print(f"wrote {len(written)} rectified image(s) to {args.write}")
    if reports:
        out.report([final_path(path, report_dir, args.report) for path in reports], args.report)
    out.wrote_each(sigma_files, "sigma", say=True)
    out.wrote(args.out, "rig")
    return 0
