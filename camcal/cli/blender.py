"""``camcal blender import``: a rig into a new .blend file (headless, with the add-on's importer)."""

from __future__ import annotations

import argparse

from camcal.cli.options import handler, rig_argument, verb_group
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """``camcal blender import RIG --blend OUT.blend``: a .blend with the rig in it."""
    verbs = verb_group(parser, "blender_verb")
    imp = verbs.add_parser("import", help="import a rig into a new .blend file (headless, with the add-on's importer)")
    rig_argument(imp, "the *.rig.json file")
    imp.add_argument("--blend", required=True, metavar="OUT.blend", help="the .blend file to write")
    imp.add_argument("--up-axis", choices=("Z", "Y", "-Y"), default="Z",
                     help="the rig's world axis that points up in Blender (default: Z)")
    imp.add_argument("--sensor-fit", choices=("AUTO", "HORIZONTAL", "VERTICAL"), default="AUTO",
                     help="Blender's sensor fit of the cameras: the larger image side (AUTO), the width or the height "
                     "(default: %(default)s)")
    imp.add_argument("--rectified", action="store_true", help="import the rectified cameras and plates")
    imp.add_argument("--no-plates", action="store_true", help="no camera background images")
    imp.add_argument("--plates", metavar="DIR", help="folder of <camera name>.<ext> plates")
    imp.add_argument("--no-points", action="store_true", help="skip the sparse point cloud")
    imp.add_argument("--no-stereo", action="store_true", help="no stereo / multi-view set-up")
    imp.add_argument("--no-distortion", action="store_true", help="no lens clips or distortion compositor")
    imp.add_argument("--overscan", type=float, default=1.1,
                     help="overscan of the render the distortion compositor uses (default: 1.1)")
    handler(imp, _import, [
        "camcal blender import board.rig.json --blend shot.blend",
        "camcal blender import rectified.rig.json --blend rig.blend --rectified --up-axis Y",
    ])


def _import(args: argparse.Namespace) -> int:
    """Import a camcal rig file into a new .blend file with the Blender add-on's importer, in a subprocess that
    runs the bpy module.
    """
    from camcal.blender_bridge import import_rig_to_blend
    from camcal.model.rig import Rig

    Rig.load(args.rig)  # a bad rig file fails here, in one line, before Blender starts
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
    out = summary_of(args)
    out.figures(rig=summary["rig"], cameras=list(summary["cameras"]), stereo_mode=summary["stereo_mode"],
                n_distorted_lenses=len(summary["clips"]))
    out.wrote(args.blend, "blend", say=False)
    for warning in summary["warnings"]:
        out.warn(warning)
    return 0
