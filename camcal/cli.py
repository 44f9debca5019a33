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


def _calibrate_board(args: argparse.Namespace) -> int:
    import glob

    import numpy as np

    from camcal.geometry.board import detect_in_images, parse_board
    from camcal.geometry.zhang import calibrate_board, write_report

    board = parse_board(args.board)
    cameras: dict[str, list[str]] = {}
    for entry in args.camera:
        name, sep, pattern = entry.partition("=")
        if not sep or not name or not pattern:
            raise CamcalError(f"--camera must be NAME=GLOB (e.g. left='shots/left*.jpg'), got {entry!r}")
        if name in cameras:
            raise CamcalError(f"camera {name!r} given twice")
        files = sorted(glob.glob(pattern))
        if not files:
            raise CamcalError(f"camera {name!r}: no image matches {pattern!r}")
        cameras[name] = files
    detections = {}
    for name, files in cameras.items():
        report = detect_in_images(board, files, progress=f"detecting {name}")
        print(f"{name}: {report.summary()}")
        detections[name] = report.detections
    result = calibrate_board(board, detections, model=args.model, units=args.units)
    result.rig.save(args.out)
    print(result.summary())
    if result.outliers:
        print("dropped as outliers: " + ", ".join(image for _, image in result.outliers))
    for camera in result.rig.cameras:
        K, sigma = camera.K, camera.quality["sigma"]
        line = (
            f"{camera.name}: fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  "
            f"principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f}) +/- ({sigma['cx']:.2f}, {sigma['cy']:.2f}) px  "
            f"RMS {camera.quality['rms_px']:.3f} px"
        )
        if "baseline" in sigma:
            line += f"  baseline {float(np.linalg.norm(camera.c)):.4f} +/- {sigma['baseline']:.4f} {result.rig.units}"
        print(line)
    print(f"wrote {args.out}")
    if args.report:
        for path in write_report(result, args.report):
            print(f"wrote {path}")
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
    board = verbs.add_parser(
        "board",
        help="one camera or an N-camera rig from chessboard / ChArUco images (joint refinement)",
        description="Detect the board in every image, calibrate each camera with OpenCV, then refine "
        "all intrinsics, distortion and camera poses jointly. Views of several cameras are matched by "
        "the frame number in their file names; the first camera is the reference (R = I, c = 0).",
    )
    board.add_argument(
        "--board", required=True, metavar="SPEC",
        help="chessboard:WxH:SQUARE (inner corners) or charuco:DICT:WxH:SQUARE:MARKER (squares)",
    )
    board.add_argument(
        "--camera", required=True, action="append", metavar="NAME=GLOB",
        help="a camera and its images, e.g. left='shots/left*.jpg' (repeat for every camera)",
    )
    board.add_argument("--model", default="polynomial", choices=("polynomial", "division", "opencv"),
                       help="distortion model (default: polynomial)")
    board.add_argument("--units", default="m", help="unit of the square size, stored in the rig (default: m)")
    board.add_argument("--out", required=True, metavar="FILE.rig.json")
    board.add_argument("--report", metavar="DIR", help="write PNG plots: residuals, per-image RMS, coverage")
    board.set_defaults(func=_calibrate_board)


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
_REGISTERS: list = [_register_rig, _register_calibrate, _register_demo]
