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


def _image_size(value: Sequence[int]) -> tuple[int, int]:
    width, height = value
    if width <= 0 or height <= 0:
        raise CamcalError(f"--image-size must be two positive integers, got {width} {height}")
    return width, height


# -- camcal rig ---------------------------------------------------------------------


def _rig_show(args: argparse.Namespace) -> int:
    from camcal.rig import Rig

    print(Rig.load(args.rig).summary())
    return 0


def _register_rig(subparsers) -> None:
    rig = subparsers.add_parser("rig", help="inspect rig files")
    verbs = rig.add_subparsers(dest="rig_verb", metavar="VERB")
    verbs.required = True
    show = verbs.add_parser("show", help="print a readable summary of a rig file")
    show.add_argument("rig", metavar="FILE", help="a *.rig.json file")
    show.set_defaults(func=_rig_show)


# -- camcal calibrate ----------------------------------------------------------------


def _calibrate_dlt(args: argparse.Namespace) -> int:
    from camcal.geometry.dlt import calibrate_dlt
    from camcal.io.points_csv import read_correspondences
    from camcal.rig import Rig, make_provenance

    image_size = _image_size(args.image_size)
    X, x = read_correspondences(args.points)
    result = calibrate_dlt(X, x)
    rig = Rig(
        (result.to_camera(args.name, image_size),),
        provenance=make_provenance("dlt", points=str(args.points)),
    )
    rig.save(args.out)
    K, sigma = result.K, result.sigmas
    print(
        f"RMS reprojection error: {result.rms_px:.3f} px "
        f"(worst {result.worst_px:.3f} px, {len(X)} points)"
    )
    print(
        f"fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  "
        f"principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f}) px  skew {K[0, 1]:.3g}"
    )
    print(f"camera centre ({result.c[0]:.4f}, {result.c[1]:.4f}, {result.c[2]:.4f})")
    print(f"wrote {args.out}")
    return 0


def _register_calibrate(subparsers) -> None:
    calibrate = subparsers.add_parser("calibrate", help="calibrate cameras from targets or correspondences")
    verbs = calibrate.add_subparsers(dest="calibrate_verb", metavar="METHOD")
    verbs.required = True
    dlt = verbs.add_parser(
        "dlt",
        help="one camera from 3D-2D correspondences (normalised DLT + LM)",
        description="Calibrate one camera from n >= 6 non-coplanar 3D points and their pixels. "
        "The CSV has the header X,Y,Z,u,v; pixel (0, 0) is the centre of the top-left pixel.",
    )
    dlt.add_argument("--points", required=True, metavar="FILE.csv", help="correspondences X,Y,Z,u,v")
    dlt.add_argument("--image-size", required=True, nargs=2, type=int, metavar=("W", "H"))
    dlt.add_argument("--name", default="camera", help="camera name in the rig (default: camera)")
    dlt.add_argument("--out", required=True, metavar="FILE.rig.json")
    dlt.set_defaults(func=_calibrate_dlt)


# -- camcal solve --------------------------------------------------------------------


def _solve(args: argparse.Namespace) -> int:
    from pathlib import Path

    from camcal.geometry.sfm import solve_sfm

    folders = {Path(folder).name: Path(folder) for folder in args.folders}
    if len(folders) != len(args.folders):
        raise CamcalError("image folders must have distinct names (they name the cameras)")
    result = solve_sfm(folders, Path(args.out), camera_model=args.camera_model, matcher=args.matcher,
                       mapper=args.mapper, seed=args.seed)
    print(f"registered {result.n_registered} / {result.n_images} images"
          + (f" (not registered: {', '.join(result.unregistered)})" if result.unregistered else ""))
    per_camera = ", ".join(f"{name} {rms:.3f} px" for name, rms in result.per_camera_rms_px.items())
    print(f"RMS reprojection error: {result.rms_px:.3f} px ({per_camera}); {result.n_points} points")
    print(f"wrote {Path(args.out) / 'sfm.rig.json'}, {Path(args.out) / 'points.ply'} and the COLMAP model in {result.reconstruction_dir}")
    return 0


def _register_solve(subparsers) -> None:
    solve = subparsers.add_parser(
        "solve",
        help="cameras from images: pycolmap structure from motion",
        description="One folder per camera; several folders form a rig whose frames are matched by file name. "
        "Writes OUT/sfm.rig.json, OUT/points.ply and the COLMAP model.",
    )
    solve.add_argument("folders", nargs="+", metavar="DIR", help="image folder(s), one per camera")
    solve.add_argument("--out", required=True, metavar="DIR")
    solve.add_argument("--camera-model", default="SIMPLE_RADIAL", help="COLMAP camera model (default: SIMPLE_RADIAL)")
    solve.add_argument("--matcher", default="exhaustive", choices=("exhaustive", "sequential"))
    solve.add_argument("--mapper", default="incremental", choices=("incremental", "global"))
    solve.add_argument("--seed", type=int, default=0)
    solve.set_defaults(func=_solve)


# -- camcal demo ---------------------------------------------------------------------


def _demo(args: argparse.Namespace) -> int:
    from camcal.demo import run_demo

    report = run_demo(args.out, seed=args.seed)
    print(report.table())
    for path in report.outputs:
        print(f"wrote {path}")
    failed = [row.quantity for row in report.rows if not row.ok]
    if failed:
        print(f"outside tolerance: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def _register_demo(subparsers) -> None:
    demo = subparsers.add_parser("demo", help="run the pipeline on synthetic data with known truth")
    demo.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    demo.set_defaults(func=_demo)


# One entry per verb group; keep this list the only place verbs are wired in.
_REGISTERS: list = [_register_rig, _register_calibrate, _register_solve, _register_demo, _register_blender]
