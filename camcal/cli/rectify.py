"""``camcal rectify``: 2 or N views onto one image plane (calibrated, N-view refined, or Hartley from matches)."""

from __future__ import annotations

import argparse

from camcal.cli.options import (every_option, handler, max_fov_option, named_option, out_option, report_option,
                                rig_argument, sigma_options)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal rectify``."""
    rig_argument(parser, "a calibrated *.rig.json")
    parser.add_argument("--method", choices=("camera", "hartley"), default="camera")
    parser.add_argument("--refine", action="store_true", help="camera method: refine on matches (Nozick 2011)")
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
    handler(parser, _rectify)


def _rectify(args: argparse.Namespace) -> int:
    """Rectify a rig's cameras onto one image plane and store per camera rectification {H, K_rect, image_size}, H
    mapping UNDISTORTED original pixels to rectified pixels. --method camera uses the calibration (with
    --refine: the N-view refinement of Nozick 2011 on matches); --method hartley uses only point matches
    (Hartley 1999). Matches come from --matches (CSV camera_a,u_a,v_a,camera_b,u_b,v_b) or from SIFT on the
    first image of each --images sequence (of a video: its frame 0).
    """
    from camcal.api.rectification import rectify

    result = rectify(args.rig, method=args.method, refine=args.refine, images=args.images, every=args.every,
                     matches=args.matches, alpha=args.alpha, max_fov_deg=args.max_fov, out=args.out, write=args.write,
                     report=args.report, sigma=args.sigma, distance=args.distance)
    for line in result.lines():
        print(line)
    out = summary_of(args)
    out.figures(**result.figures())
    out.wrote_each(result.images, "image")
    if result.images:
        print(f"wrote {len(result.images)} rectified image(s) to {args.write}")
    if result.report_files:
        out.report(list(result.report_files), args.report)
    out.wrote_each(result.sigma_files, "sigma", say=True)
    out.wrote(args.out, "rig")
    return 0
