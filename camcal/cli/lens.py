"""``camcal lens``: a camera at a lens state of a lens profile, or a lens per frame from lens metadata."""

from __future__ import annotations

import argparse

from camcal.cli.options import handler, out_option
from camcal.cli.summary import report_result

__all__ = ["register"]


def _focus(text: str) -> float:
    """A focus distance in m, or ``inf``."""
    return float("inf") if text.strip().lower() in ("inf", "infinity") else float(text)


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal lens``."""
    parser.add_argument("profile", metavar="PROFILE", help="a *.profile.json (camcal calibrate profile)")
    parser.add_argument("--focal", type=float, metavar="MM",
                        help="the focal length in mm (with --encoders: the zoom encoder, 0-1, wide to tele)")
    parser.add_argument("--focus", type=_focus, metavar="M",
                        help="the focus distance in m, or inf (with --encoders: the focus encoder, 0-1, far to near)")
    parser.add_argument("--metadata", metavar="FILE.csv",
                        help="instead of --focal/--focus: each frame's lens state, a CSV with the header "
                        "frame,focal_mm,focus_m (or frame,focal,focus with --encoders); the rig gets a lens per "
                        "frame")
    parser.add_argument("--encoders", action="store_true",
                        help="the values are lens encoder readings from 0 to 1 as OpenTrackIO normalises them, "
                        "mapped through the profile's calibrated ranges: zoom from the shortest focal length (0) "
                        "to the longest (1), linearly; focus from the farthest (0) to the nearest (1), linearly in "
                        "1 / distance")
    parser.add_argument("--extrapolate", action="store_true",
                        help="allow lens states outside the calibrated range (default: refused); the output says "
                        "which")
    parser.add_argument("--name", default="camera", help="the camera's name in the rig (default: camera)")
    out_option(parser, "FILE.rig.json", "the rig file to write")
    handler(parser, _lens, [
        "# a camera at 32 mm focused at 2.5 m",
        "camcal lens lens.profile.json --focal 32 --focus 2.5 --out cam.rig.json",
        "# a lens per frame from the lens metadata of a shot",
        "camcal lens lens.profile.json --metadata shot_lens.csv --out shot.rig.json",
    ])


def _lens(args: argparse.Namespace) -> int:
    """Make a one-camera rig from a lens profile at a lens state (focal length in mm, focus distance in m), or
    with a lens per frame from a metadata CSV (frames without motion: R = I, c = 0; the rig's camera is the first
    frame's lens). States outside the calibrated focal and focus range are refused unless --extrapolate. The
    camera's sigmas are the profile's at that state.
    """
    from camcal.api.lens import lens_rig

    result = lens_rig(args.profile, args.focal, args.focus, metadata=args.metadata, encoders=args.encoders,
                      extrapolate=args.extrapolate, name=args.name, out=args.out)
    report_result(args, result)
    return 0
