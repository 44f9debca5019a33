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
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--overscan", type=float, metavar="FACTOR",
                      help="overscan of the undistorted image as a factor of the plate (default 1.1): a border of "
                           "round((FACTOR - 1) W / 2) x round((FACTOR - 1) H / 2) pixels on each side")
    size.add_argument("--border", type=int, nargs="+", metavar="PX",
                      help="overscan as a border in pixels on each side: one number, or X Y")
    out_option(parser, "DIR", "the folder to write NAME_undistort.exr and NAME_redistort.exr into (a camera whose "
               "lens changes per frame: NAME_undistort.%%04d.exr ..., a pair per frame)")
    sigma_options(parser, "NAME_sigma.exr (plate-sized, with the redistort map) and NAME_undistort_sigma.exr "
                  "(with the undistort map): the projection sigma in plate pixels")
    report_option(parser, "with --sigma, write DIR/sigma_NAME.png and DIR/undistort_sigma_NAME.png: the sigma maps "
                  "as heat maps with a colour bar")
    handler(parser, _stmap, [
        "camcal stmap board.rig.json --camera left --out stmaps",
        "camcal stmap board.rig.json --camera left --overscan 1.2 --out stmaps --sigma --report stmaps/report",
    ])


def _stmap(args: argparse.Namespace) -> int:
    """Write NAME_undistort.exr and NAME_redistort.exr, 32-bit float: R = (x + 0.5) / W, G = 1 - (y + 0.5) / H of
    the pixel to sample, (x, y) with pixel (0, 0) at the centre of the top-left pixel and W x H the plate's size
    (the format of both images; values outside 0..1 reach into the overscan border). The undistort map's border is
    the EXR's data window beyond its plate-sized display window (Nuke's bounding box). Also the undistorted rig.
    A camera whose lens changes over the rig's frames (a zoom) gets a pair per frame, NAME_undistort.%04d.exr and
    NAME_redistort.%04d.exr, each of its frame's lens.
    """
    from camcal.base.atomic import final_path
    from camcal.cli.options import output_folder
    from camcal.geometry.stmap import DEFAULT_OVERSCAN, overscan_border
    from camcal.io.stmap import read_sigma_map, write_stmap_frames, write_stmap_sigmas, write_stmaps
    from camcal.model.rig import Rig

    if args.report and not args.sigma:
        raise CamcalError("--report draws the sigma maps: give --sigma too")
    if args.border is not None and len(args.border) > 2:
        raise CamcalError(f"--border takes one number or two (X Y), got {len(args.border)}")
    border = None if args.border is None else (args.border * 2)[:2]
    rig = Rig.load(args.rig)
    camera = rig.camera(args.camera)
    factor = DEFAULT_OVERSCAN if border is None and args.overscan is None else args.overscan
    bx, by = overscan_border(camera.image_size, factor, border)
    per_frame = bool(rig.lens_frames(args.camera))
    if per_frame and args.sigma:
        raise CamcalError(f"camera {args.camera!r}'s lens changes over the rig's frames: --sigma maps one lens")
    if per_frame:
        undistort, redistort, rig_path = write_stmap_frames(rig, args.camera, args.out, border=(bx, by))
        paths = [*undistort, *redistort, rig_path]
    else:
        paths = write_stmaps(rig, args.camera, args.out, border=(bx, by))
    width, height = camera.image_size
    print(f"ST-maps of {args.camera!r}: format {width}x{height}, overscan border {bx}x{by} px "
          f"(undistorted data window {width + 2 * bx}x{height + 2 * by})"
          + (f", one pair per frame for its {len(rig.frames)} frames (per-frame lens)" if per_frame else ""))
    out = summary_of(args)
    out.figures(camera=args.camera, overscan=args.overscan, border=[bx, by])
    for path in paths:
        out.wrote(path, "stmap" if str(path).endswith(".exr") else "rig")
    if args.sigma:
        sigmas = write_stmap_sigmas(rig, args.camera, args.out, distance=args.distance, border=(bx, by))
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
