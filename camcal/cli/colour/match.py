"""``camcal colour match``: one camera's colours matched to another's (stereo pair or chart)."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import handler, named_option, out_option, output_folder, report_option, rig_argument
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour match``."""
    rig_argument(parser, "a calibrated *.rig.json holding both cameras", nargs="?")
    named_option(parser, "--images", "NAME=IMG", "one image per camera, target first")
    parser.add_argument("--rectified", action="store_true", help="the images are rectified already")
    named_option(parser, "--fits", "NAME=FIT.colour.json",
                 "characterisations (linearisation; the target's gives XYZ for Delta E)")
    named_option(parser, "--patches", "NAME=FILE.csv",
                 "chart route: each camera's patch CSV of the same chart, target first")
    named_option(parser, "--test-patches", "NAME=FILE.csv", "chart route: independent patches per camera")
    parser.add_argument("--encoding", default="linear", metavar="NAME",
                        help="image encoding of cameras without a fit: linear or a transfer function "
                             "(sRGB, ITU-R BT.709, ARRI LogC3...; default: linear)")
    parser.add_argument("--model", default="matrix3x3",
                        help="matrix3x3 | root-polynomial:D | polynomial:N | lut3d[:N] (default: matrix3x3)")
    parser.add_argument("--robust", choices=("lmeds-irls", "irls", "none"), default=None,
                        help="robust fitting (default: lmeds-irls for images, none for charts)")
    out_option(parser, "MATCH.colour.json", "match file to write")
    report_option(parser, "difference images and Delta E maps (or chart plots)")
    handler(parser, _match, [
        "camcal colour match board.rig.json --images left=left.png right=right.png --out match.colour.json",
        "camcal colour match --fits left=left.colour.json right=right.colour.json --patches "
        "left=left.csv right=right.csv --out match.colour.json",
    ])


def _match(args: argparse.Namespace) -> int:
    """Fit a colour transform from camera B's linear RGB to camera A's. Image route: a stereo pair (--images A=IMG
    --images B=IMG; the first camera is the target A), rectified with the rig's calibration unless
    --rectified; SGBM disparity with a left-right check picks reliable, unoccluded, unsaturated pixels, the
    fit is robust (LMedS + IRLS) and judged by CIEDE2000 on held-out image tiles. Chart route: --fits and
    --patches for both cameras (same chart): both go to XYZ, the residual camera-to-camera CIEDE2000 is
    reported. Writes a *.colour.json of kind match.
    """
    from camcal.colour.match.models import parse_match_model
    from camcal.io.colourfile import load_fit, save_colour_file
    from camcal.pipelines.colour import match_image_files, match_patch_files
    from camcal.base.atomic import final_path
    from camcal.report.colour_match import write_report

    parse_match_model(args.model)
    images, patches = args.images, args.patches
    fits = {name: load_fit(path) for name, path in args.fits.items()}
    if images and patches:
        raise CamcalError("give --images (image route) or --patches (chart route), not both")
    if images:
        rig = None
        if args.rig:
            from camcal.model.rig import Rig

            rig = Rig.load(args.rig)
        result = match_image_files(images, rig=rig, rectified=args.rectified, fits=fits, encoding=args.encoding,
                                   model=args.model, robust=args.robust or "lmeds-irls")
        counts = result.correspondences.counts
        print(f"correspondences: {counts['valid']} of {counts['total']} pixels kept (disparity {counts['disparity']}, "
              f"left-right consistent {counts['consistent']}, away from depth edges {counts['smooth']})")
    elif patches:
        fits = {name: fits[name] for name in patches if name in fits} | fits
        result = match_patch_files(fits, patches, test_patches=args.test_patches,
                                   model=args.model, robust=args.robust or "none")
    else:
        raise CamcalError("nothing to match: give --images NAME=IMG twice, or --fits and --patches for two cameras")
    print(result.match.summary())
    out = summary_of(args)
    out.figures(model=args.model, evaluation=result.match.evaluation,
                correspondences=dict(result.correspondences.counts) if images else None)
    with output_folder(args.report) as report_dir:
        reports = [] if report_dir is None else write_report(result, report_dir)
        out.wrote(save_colour_file(result.match, args.out), "colour match")
    if args.report:
        out.report([final_path(path, report_dir, args.report) for path in reports], args.report)
    return 0
