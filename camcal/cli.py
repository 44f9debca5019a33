"""The ``camcal`` command: parses arguments and calls the library.

Every verb prints a short human summary, writes its outputs atomically and,
on a user's mistake, prints one line ``camcal: error: ...`` and exits with
code 2 (argparse does the same for malformed command lines).

Each verb group registers itself with a ``_register_<group>(subparsers)``
function that sets ``func`` on its parser; the handler receives the parsed
namespace and returns the exit code.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from camcal import __version__
from camcal.errors import CamcalError

__all__ = ["main", "build_parser"]

EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every verb registered."""
    parser = argparse.ArgumentParser(
        prog="camcal",
        description="Geometric and colour camera calibration for VFX pipelines.",
    )
    parser.add_argument("--version", action="version", version=f"camcal {__version__}")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB")
    subparsers.required = True
    for register in _REGISTERS:
        register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CamcalError as error:
        print(f"camcal: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT


# --------------------------------------------------------------------------
# colour: characterisation (fit); export and match register here too.


def _register_colour(subparsers) -> None:
    """The ``colour`` group; its sub-verbs come from ``_COLOUR_VERBS``."""
    parser = subparsers.add_parser(
        "colour",
        help="colour characterisation: fit camera RGB to XYZ",
        description="Colour characterisation of a camera: charts, linearisation, models, Delta E.",
    )
    colour_verbs = parser.add_subparsers(dest="colour_verb", metavar="SUBVERB")
    colour_verbs.required = True
    for register in _COLOUR_VERBS:
        register(colour_verbs)


def _register_colour_fit(colour_verbs) -> None:
    parser = colour_verbs.add_parser(
        "fit",
        help="fit a characterisation from a chart photo or a patch CSV",
        description=(
            "Fit camera RGB to CIE XYZ (perfect white Y = 1) and judge it by CIEDE2000 on "
            "the training patches, by leave-one-out and on an independent patch set. "
            "Writes a versioned *.colour.json."
        ),
        epilog=(
            "Patch CSV header: R,G,B,X,Y,Z (camera RGB, reference XYZ under the scene "
            "illuminant, perfect white Y = 1), optional first column name. "
            "--model auto picks model, objective and regularisation by leave-one-out "
            "CIEDE2000 and says why."
        ),
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--chart", metavar="IMAGE", help="photo of a 24-patch ColorChecker")
    source.add_argument("--patches", metavar="FILE.csv", help="training patches (see below)")
    parser.add_argument("--reference", default="ColorChecker24 - After November 2014", metavar="NAME",
                        help="reference chart for --chart (colour-science name or cc24, cc24-2005, "
                             "babel, sg; default: %(default)s)")
    parser.add_argument("--corners", metavar="X,Y,...",
                        help="manual chart corners instead of detection: 8 numbers, top-left (dark "
                             "skin), top-right, bottom-right, bottom-left of the patch grid")
    parser.add_argument("--keep-clipped", action="store_true", help="keep patches flagged clipped")
    parser.add_argument("--model", default="auto",
                        help="auto | matrix3x3[:white-preserving] | polynomial:N | root-polynomial:D "
                             "| rbf[:KERNEL] (default: auto)")
    parser.add_argument("--objective", choices=("xyz", "de2000"), default=None,
                        help="least squares in XYZ or CIEDE2000 (default: xyz; auto tries both)")
    parser.add_argument("--regularisation", type=float, default=0.0, metavar="LAMBDA",
                        help="ridge lambda on the non-linear terms of a named model (auto picks its own)")
    parser.add_argument("--linearise", default=None, metavar="KIND",
                        help="none | gamma-offset | lut1d | named:FUNCTION (e.g. named:sRGB); "
                             "default: lut1d for --chart, none for --patches")
    parser.add_argument("--illuminant", default="D50", metavar="WHITE",
                        help="white the reference XYZ are relative to: CIE name or x,y "
                             "(default: D50, the ColorChecker data's own; with --chart, another "
                             "white adapts the chart's data to it with CAT02)")
    parser.add_argument("--target-white", default=None, metavar="WHITE",
                        help="white of the output XYZ (default: the training white)")
    parser.add_argument("--adaptation", choices=("CAT02", "Bradford"), default="CAT02",
                        help="chromatic adaptation to the target white (default: %(default)s)")
    parser.add_argument("--test-patches", metavar="FILE.csv",
                        help="independent patches, same encoding and white as the training ones")
    parser.add_argument("--camera", default=None, help="camera name recorded in the file")
    parser.add_argument("--out", required=True, metavar="FIT.colour.json", help="fit file to write")
    parser.add_argument("--report", metavar="DIR", help="write per-patch tables and plots here")
    parser.set_defaults(func=_colour_fit)


def _parse_corners(text: str):
    try:
        values = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise CamcalError(f"--corners: expected 8 numbers, got {text!r}") from None
    if len(values) != 8:
        raise CamcalError(f"--corners: expected 8 numbers, got {len(values)}")
    return [values[i : i + 2] for i in range(0, 8, 2)]


def _colour_fit(args: argparse.Namespace) -> int:
    from camcal.colour.characterise import characterise, patches_from_chart, write_report
    from camcal.colour.patches import read_patch_csv

    reference = None
    if args.chart:
        corners = _parse_corners(args.corners) if args.corners else None
        found = patches_from_chart(args.chart, args.reference, corners=corners,
                                   keep_clipped=args.keep_clipped, illuminant=args.illuminant)
        train = found.patches
        reference = found.reference.name
        excluded = f" (dropped clipped: {', '.join(found.excluded)})" if found.excluded else ""
        print(f"chart found by {found.detection.method}: {len(train)} / "
              f"{len(found.reference.patch_names)} patches used{excluded}")
        noisy = [n for n, flag in zip(found.reference.patch_names, found.samples.noisy) if flag]
        if noisy:
            print(f"flagged noisy (kept): {', '.join(noisy)}")
        linearise = args.linearise or "lut1d"
        white = args.illuminant
    else:
        if args.corners:
            raise CamcalError("--corners applies to --chart only")
        train = read_patch_csv(args.patches)
        print(f"read {len(train)} patches from {args.patches}")
        linearise = args.linearise or "none"
        white = args.illuminant
    test = read_patch_csv(args.test_patches) if args.test_patches else None
    outcome = characterise(
        train, white=white, model=args.model, objective=args.objective,
        regularisation=args.regularisation, linearise=linearise,
        test=test, target_white=args.target_white, adaptation=args.adaptation,
        camera=args.camera, reference=reference, source=args.chart or args.patches,
    )
    print(outcome.summary())
    path = outcome.fit.save(args.out)
    print(f"wrote {path}")
    if args.report:
        files = write_report(args.report, outcome, title=args.camera or "")
        print(f"report: {len(files)} files in {args.report}")
    return 0


_COLOUR_VERBS: list = [_register_colour_fit]


# One entry per verb group; keep this list the only place verbs are wired in.
_REGISTERS: list = [_register_colour]
