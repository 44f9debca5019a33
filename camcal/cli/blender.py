"""``camcal blender import``: a rig into a new or an existing .blend file (headless, with the add-on's importer)."""

from __future__ import annotations

import argparse

from camcal.cli.options import after_parsing, handler, rig_argument, verb_group
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """``camcal blender import RIG --blend OUT.blend`` (or ``--into SCENE.blend``): a .blend with the rig in it."""
    verbs = verb_group(parser, "blender_verb")
    imp = verbs.add_parser("import", help="import a rig into a new or an existing .blend file (headless, with the "
                           "add-on's importer)")
    rig_argument(imp, "the *.rig.json file")
    imp.add_argument("--blend", metavar="OUT.blend",
                     help="the .blend file to write (default with --into: that file, updated in place)")
    imp.add_argument("--into", metavar="SCENE.blend",
                     help="an existing .blend file to add the rig to, in its active scene (default: a new, empty file)")
    imp.add_argument("--no-replace", action="store_true",
                     help="add a second collection when the scene already holds an import of this rig file "
                     "(default: replace that import in place)")
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
    after_parsing(imp, _blend_given)
    handler(imp, _import, [
        "camcal blender import board.rig.json --blend shot.blend",
        "camcal blender import rectified.rig.json --blend rig.blend --rectified --up-axis Y",
        "# add a solved plate to an existing scene (run it again after a new solve: the camera is updated in place)",
        "camcal blender import solve/solve.rig.json --into layout.blend",
        "# the same, written to a new file, the layout left as it is",
        "camcal blender import solve/solve.rig.json --into layout.blend --blend layout_tracked.blend",
    ])


def _blend_given(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--blend`` or ``--into`` names the file to write."""
    if args.blend is None and args.into is None:
        parser.error("give --blend OUT.blend (a new file) or --into SCENE.blend (an existing one)")


def _import(args: argparse.Namespace) -> int:
    """Import a camcal rig file into a new .blend file, or into an existing one (--into), with the Blender add-on's
    importer, in a subprocess that runs the bpy module.

    Importing a rig file the scene already holds replaces that import in place: the collection keeps its name and
    its parent collections, objects parented to the rig stay on it, the cameras take the new values (--no-replace
    adds a second collection instead).
    """
    from camcal.blender_bridge import import_rig_to_blend
    from camcal.model.rig import Rig

    Rig.load(args.rig)  # a bad rig file fails here, in one line, before Blender starts
    summary = import_rig_to_blend(
        args.rig,
        args.blend,
        into=args.into,
        replace=not args.no_replace,
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
    written = args.blend or args.into
    print(f"{'re-imported' if summary['replaced'] else 'imported'} rig {summary['rig']!r} into {written} "
          f"(scene {summary['scene']!r}, collection {summary['collection']!r}): {len(summary['cameras'])} camera(s) "
          f"({cams}), stereo: {summary['stereo_mode'].lower()}, "
          f"distorted lenses: {len(summary['clips'])}")
    out = summary_of(args)
    out.figures(rig=summary["rig"], cameras=list(summary["cameras"]), stereo_mode=summary["stereo_mode"],
                n_distorted_lenses=len(summary["clips"]), collection=summary["collection"],
                replaced=summary["replaced"])
    out.wrote(written, "blend", say=False)
    for warning in summary["warnings"]:
        out.warn(warning)
    return 0
