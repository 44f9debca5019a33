"""``camcal undistort``: undistorted images of a rig camera and the rig of the new pinhole camera."""

from __future__ import annotations

import argparse

from camcal.cli.options import (camera_option, every_option, handler, max_fov_option, out_option, rig_argument,
                                sigma_options, undistort_mode_options)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal undistort``."""
    rig_argument(parser)
    camera_option(parser)
    parser.add_argument("images", nargs="+", metavar="IMAGES|VIDEO",
                        help="image files, or videos (frame k of clip.mp4 written as clip_00000k.png)")
    every_option(parser)
    undistort_mode_options(parser, "crop: no black borders; keep: every source pixel kept (bigger canvas); "
                           "overscan: canvas --overscan times the plate (default: crop)")
    max_fov_option(parser, "crop / keep: widest full angle about the axis the pinhole output holds "
                   "(default: 120 for a kannala-brandt fisheye, no cap for the other lenses)")
    out_option(parser, "DIR")
    sigma_options(parser, "DIR/sigma.exr, pixel for pixel with the undistorted images: the projection sigma "
                  "(plate pixels) of the plate pixel each one samples")
    handler(parser, _undistort)


def _undistort(args: argparse.Namespace) -> int:
    """Undistort images with one remap per image; writes them under their own names and DIR/undistorted.rig.json
    with the new K and distortion none. Videos are streamed, one frame at a time (--every N: frames 0, N, 2N...).
    """
    from camcal.api.undistortion import undistort

    result = undistort(args.rig, args.camera, args.images, args.out, every=args.every, mode=args.mode,
                       overscan=args.overscan, max_fov_deg=args.max_fov, sigma=args.sigma, distance=args.distance)
    for line in result.lines():
        print(line)
    out = summary_of(args)
    out.figures(**result.figures())
    out.wrote(result.rig_path, "rig", say=False)
    out.wrote_each(result.images, "image")
    if result.sigma_path is not None:
        out.wrote(result.sigma_path, "sigma")
    return 0
