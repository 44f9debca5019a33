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


def _register_blender(subparsers) -> None:
    """``camcal blender import RIG --blend OUT.blend``: a .blend with the rig in it."""
    blender = subparsers.add_parser(
        "blender", help="Blender hand-off (needs the bpy module: camcal[blender])"
    )
    verbs = blender.add_subparsers(dest="blender_verb", metavar="VERB")
    verbs.required = True
    imp = verbs.add_parser(
        "import",
        help="import a rig into a new .blend file (headless, with the add-on's importer)",
        description="Import a camcal rig file into a new .blend file with the Blender "
        "add-on's importer, in a subprocess that runs the bpy module.",
    )
    imp.add_argument("rig", metavar="RIG", help="the *.rig.json file")
    imp.add_argument("--blend", required=True, metavar="OUT.blend", help="the .blend file to write")
    imp.add_argument("--up-axis", choices=("Z", "Y", "-Y"), default="Z",
                     help="the rig's world axis that points up in Blender (default: Z)")
    imp.add_argument("--sensor-fit", choices=("AUTO", "HORIZONTAL", "VERTICAL"), default="AUTO")
    imp.add_argument("--rectified", action="store_true", help="import the rectified cameras and plates")
    imp.add_argument("--no-plates", action="store_true", help="no camera background images")
    imp.add_argument("--plates", metavar="DIR", help="folder of <camera name>.<ext> plates")
    imp.add_argument("--no-points", action="store_true", help="skip the sparse point cloud")
    imp.add_argument("--no-stereo", action="store_true", help="no stereo / multi-view set-up")
    imp.add_argument("--no-distortion", action="store_true", help="no lens clips or distortion compositor")
    imp.add_argument("--overscan", type=float, default=1.1,
                     help="overscan of the render the distortion compositor uses (default: 1.1)")
    imp.set_defaults(func=_blender_import)


def _blender_import(args: argparse.Namespace) -> int:
    from camcal.blender_bridge import import_rig_to_blend

    summary = import_rig_to_blend(
        args.rig,
        args.blend,
        up_axis=args.up_axis,
        sensor_fit=args.sensor_fit,
        use_rectified=args.rectified,
        import_plates=not args.no_plates,
        plate_directory=args.plates,
        import_points=not args.no_points,
        stereo=not args.no_stereo,
        distortion=not args.no_distortion,
        compositor=not args.no_distortion,
        overscan=args.overscan,
    )
    cams = ", ".join(summary["cameras"])
    print(f"imported rig {summary['rig']!r} into {args.blend}: {len(summary['cameras'])} camera(s) "
          f"({cams}), stereo: {summary['stereo_mode'].lower()}, "
          f"distorted lenses: {len(summary['clips'])}")
    for warning in summary["warnings"]:
        print(f"warning: {warning}")
    return 0


# One entry per verb group; keep this list the only place verbs are wired in.
_REGISTERS: list = [_register_blender]
