"""``camcal stmap``: undistort / redistort ST-maps (EXR) of a rig camera for comp packages."""

from __future__ import annotations

import argparse

from camcal.cli.options import camera_option, handler, out_option, rig_argument, sigma_options
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal stmap``."""
    rig_argument(parser)
    camera_option(parser)
    parser.add_argument("--overscan", type=float, default=1.1, help="undistorted canvas factor (default 1.1)")
    out_option(parser, "DIR")
    sigma_options(parser, "NAME_sigma.exr (plate-sized, with the redistort map) and NAME_undistort_sigma.exr "
                  "(with the undistort map): the projection sigma in plate pixels")
    handler(parser, _stmap)


def _stmap(args: argparse.Namespace) -> int:
    """Write NAME_undistort.exr and NAME_redistort.exr (R = (x + 0.5) / W, G = 1 - (y + 0.5) / H of the pixel to
    sample) and the undistorted rig.
    """
    from camcal.io.stmap import write_stmap_sigmas, write_stmaps
    from camcal.model.rig import Rig

    rig = Rig.load(args.rig)
    paths = write_stmaps(rig, args.camera, args.out, args.overscan)
    print(f"ST-maps of {args.camera!r} with overscan {args.overscan:g}")
    out = summary_of(args)
    out.figures(camera=args.camera, overscan=args.overscan)
    for path in paths:
        out.wrote(path, "stmap" if str(path).endswith(".exr") else "rig")
    if args.sigma:
        sigmas = write_stmap_sigmas(rig, args.camera, args.out, args.overscan, args.distance)
        (_, plate), (_, undistorted) = sigmas
        print(f"plate: {plate.describe()}")
        print(f"undistorted canvas: {undistorted.describe()}")
        out.figures(sigma=plate.to_dict(), undistort_sigma=undistorted.to_dict())
        for path, _ in sigmas:
            out.wrote(path, "sigma")
    return 0
