"""``camcal stmap``: undistort / redistort ST-maps (EXR) of a rig camera for comp packages."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import camera_option, handler, out_option, report_option, rig_argument, sigma_options
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal stmap``."""
    rig_argument(parser)
    camera_option(parser)
    parser.add_argument("--overscan", type=float, default=1.1, help="undistorted canvas factor (default 1.1)")
    out_option(parser, "DIR", "the folder to write NAME_undistort.exr and NAME_redistort.exr into")
    sigma_options(parser, "NAME_sigma.exr (plate-sized, with the redistort map) and NAME_undistort_sigma.exr "
                  "(with the undistort map): the projection sigma in plate pixels")
    report_option(parser, "with --sigma, write DIR/sigma_NAME.png and DIR/undistort_sigma_NAME.png: the sigma maps "
                  "as heat maps with a colour bar")
    handler(parser, _stmap, [
        "camcal stmap board.rig.json --camera left --out stmaps",
        "camcal stmap board.rig.json --camera left --overscan 1.2 --out stmaps --sigma --report stmaps/report",
    ])


def _stmap(args: argparse.Namespace) -> int:
    """Write NAME_undistort.exr and NAME_redistort.exr (R = (x + 0.5) / W, G = 1 - (y + 0.5) / H of the pixel to
    sample) and the undistorted rig.
    """
    from camcal.base.atomic import final_path
    from camcal.cli.options import output_folder
    from camcal.io.stmap import read_sigma_map, write_stmap_sigmas, write_stmaps
    from camcal.model.rig import Rig

    if args.report and not args.sigma:
        raise CamcalError("--report draws the sigma maps: give --sigma too")
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
        if args.report:
            from camcal.report.sigma import plot_sigma_map

            where = "at infinity" if args.distance is None else f"at distance {args.distance:g}"
            with output_folder(args.report) as report_dir:
                plots = [plot_sigma_map(read_sigma_map(path), report_dir / f"{kind}_{args.camera}.png",
                                        f"{args.camera}: projection sigma {where} ({what})")
                         for (path, _), kind, what in zip(sigmas, ("sigma", "undistort_sigma"),
                                                          ("plate", "undistorted canvas"))]
            out.wrote_each([final_path(path, report_dir, args.report) for path in plots], "report", say=True)
    return 0
