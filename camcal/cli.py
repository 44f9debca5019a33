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


# -- camcal rectify ------------------------------------------------------------------


def _parse_images(entries: Sequence[str]) -> dict[str, list[str]]:
    import glob

    images: dict[str, list[str]] = {}
    for entry in entries:
        name, sep, pattern = entry.partition("=")
        if not sep or not name or not pattern:
            raise CamcalError(f"--images takes NAME=GLOB, got {entry!r}")
        images[name] = sorted(glob.glob(pattern))
    return images


def _rectify(args: argparse.Namespace) -> int:
    from camcal.geometry.rectify import RectifyWarper, match_images, read_matches_csv, rectify
    from camcal.io.jsonfile import write_json
    from camcal.rig import Rig

    if not 0.0 <= args.alpha <= 1.0:
        raise CamcalError(f"--alpha must be in [0, 1], got {args.alpha}")
    if args.write and not args.images:
        raise CamcalError("--write needs --images NAME=GLOB for the cameras to rectify")
    rig = Rig.load(args.rig)
    images = _parse_images(args.images or [])
    for name, files in images.items():
        rig.camera(name)
        if not files:
            raise CamcalError(f"--images {name}=...: no file matches")
    names = list(images) if len(images) >= 2 else None
    if args.matches:
        matches = read_matches_csv(args.matches)
    elif images and (args.method == "hartley" or args.refine):
        matches = match_images(rig, {name: files[0] for name, files in images.items()})
    else:
        matches = None
    method = {"camera": "Nozick 2011" if args.refine else "camera", "hartley": "Hartley 1999"}[args.method]
    result = rectify(rig, method, matches, names, args.alpha)
    written = []
    if args.write:
        warper = RectifyWarper(result.rig)
        for name in result.names:
            written += warper.write(name, images.get(name, []), args.write)
    result.rig.save(args.out)
    print(result.summary())
    if written:
        print(f"wrote {len(written)} rectified image(s) to {args.write}")
    if args.report:
        report = write_json(f"{args.report}/rectification.json", result.to_report())
        print(f"wrote {report}")
    print(f"wrote {args.out}")
    return 0


def _register_rectify(subparsers) -> None:
    parser = subparsers.add_parser(
        "rectify",
        help="rectify 2 or N views (calibrated, N-view refined, or Hartley from matches)",
        description="Rectify a rig's cameras onto one image plane and store per camera "
        "rectification {H, K_rect, image_size}, H mapping UNDISTORTED original pixels to "
        "rectified pixels. --method camera uses the calibration (with --refine: the N-view "
        "refinement of Nozick 2011 on matches); --method hartley uses only point matches "
        "(Hartley 1999). Matches come from --matches (CSV camera_a,u_a,v_a,camera_b,u_b,v_b) "
        "or from SIFT on the first image of each --images sequence.",
    )
    parser.add_argument("rig", metavar="RIG", help="a calibrated *.rig.json")
    parser.add_argument("--method", choices=("camera", "hartley"), default="camera")
    parser.add_argument("--refine", action="store_true", help="camera method: refine on matches (Nozick 2011)")
    parser.add_argument("--images", nargs="+", metavar="NAME=GLOB", help="images per camera, e.g. left='L/*.png'")
    parser.add_argument("--matches", metavar="FILE.csv", help="point matches in original pixels")
    parser.add_argument("--alpha", type=float, default=0.0,
                        help="0: only pixels all views see (default); 1: every source pixel")
    parser.add_argument("--out", required=True, metavar="FILE.rig.json", help="the rectified rig")
    parser.add_argument("--write", metavar="DIR", help="write rectified images to DIR/<camera>/")
    parser.add_argument("--report", metavar="DIR", help="write DIR/rectification.json with the figures")
    parser.set_defaults(func=_rectify)


# One entry per verb group; keep this list the only place verbs are wired in.
_REGISTERS: list = [_register_rig, _register_calibrate, _register_demo, _register_rectify]
