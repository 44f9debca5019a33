"""``camcal batch``: undistort, rectify and colour-correct a plate sequence, one Dask task per frame."""

from __future__ import annotations

import argparse

from camcal.cli.options import (after_parsing, camera_option, deprecated_option, handler, only_with, out_option,
                                rig_argument, undistort_mode_options)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal batch``."""
    rig_argument(parser)
    camera_option(parser)
    parser.add_argument("--images", dest="in_pattern", metavar="PATTERN",
                        help="input frames, e.g. 'plates/left.%%04d.exr' (required)")
    deprecated_option(parser, "--in", "--images", dest="in_pattern", metavar="PATTERN")
    after_parsing(parser, _images_given)
    parser.add_argument("--frames", required=True, metavar="RANGE", help="e.g. 1001-1240, 1001-1240x2, 1,5,10-12")
    out_option(parser, "PATTERN", "output frames, e.g. 'out/left.%%04d.exr'")
    geometry = parser.add_mutually_exclusive_group()
    geometry.add_argument("--undistort", action="store_true", help="undistort (see `camcal undistort`)")
    geometry.add_argument("--rectify", action="store_true", help="rectify with the camera's rectification")
    undistort_mode_options(parser, "how --undistort chooses the new camera (default: crop)", "--undistort",
                           lambda args: args.undistort)
    parser.add_argument("--colour", metavar="FIT.colour.json", help="apply a characterisation (camera RGB -> "
                        "--colour-space, through the OCIO processor of its exported transform)")
    parser.add_argument("--colour-space", default=None, choices=("ACES2065-1", "ACEScg", "lin Rec.709", "CIE XYZ"),
                        help="output space of --colour (default: ACES2065-1; CIE XYZ is the fit's own XYZ)")
    only_with(parser, "--colour-space", "--colour", lambda args: args.colour is not None, default="ACES2065-1")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="use a running Dask scheduler (its workers must see the input and output folders)")
    where.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: one per core)")
    parser.add_argument("--resume", action="store_true", help="skip frames already complete and unchanged")
    parser.add_argument("--retries", type=int, default=2, metavar="N", help="retries of a failed frame (default: 2)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    handler(parser, _batch, [
        "camcal batch board.rig.json --camera left --images 'plates/left.%04d.exr' --frames "
        "1001-1240 --out 'out/left.%04d.exr' --undistort",
        "camcal batch board.rig.json --camera left --images 'plates/left.%04d.exr' --frames "
        "1001-1240 --out 'out/left.%04d.exr' --colour left.colour.json --colour-space ACEScg --workers 4",
    ])



def _images_given(parser, args: argparse.Namespace) -> None:
    """``--images`` is required (an option rather than required=True, so the deprecated ``--in`` also counts)."""
    if args.in_pattern is None:
        parser.error("the following arguments are required: --images")

def _batch(args: argparse.Namespace) -> int:
    """Process frames of a sequence, one Dask task per frame, on a local cluster (--workers) or an existing
    scheduler (--scheduler). Maps and the colour step are built once per worker. Outputs keep the inputs'
    format, bit depth and (EXR) metadata, are written atomically, and a failed frame is retried, then
    reported by number.

    Exit status: 0 all frames written, 1 some frames failed (listed), 2 bad input.
    """
    from camcal.base.frame_ranges import parse_frames
    from camcal.pipelines.batch import make_job, run_batch

    geometry = "undistort" if args.undistort else "rectify" if args.rectify else None
    job = make_job(args.rig, args.camera, args.in_pattern, args.out, geometry, args.colour, args.mode, args.overscan,
                   colour_space=args.colour_space)
    frames = parse_frames(args.frames)
    report = run_batch(job, frames, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                       retries=args.retries, progress=not args.quiet)
    print(report.summary())
    out = summary_of(args)
    out.figures(n_frames=len(report.frames), n_written=len(report.written), skipped=list(report.skipped),
                failed={failure.frame: failure.message for failure in report.failed},
                seconds=report.seconds, n_workers=report.n_workers)
    out.wrote_each((frame.output for frame in report.written), "frame")
    return 0 if report.ok else 1
