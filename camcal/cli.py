"""The ``camcal`` command: parses arguments and calls the library.

Every verb prints a short human summary and writes its outputs atomically.

Errors, for every verb and every input:

- a user's mistake (:class:`~camcal.base.errors.CamcalError`, an ``OSError`` on a
  path the user gave, a file that does not decode) prints one line
  ``camcal: error: ...`` on stderr and exits with code 2 (argparse does the
  same for malformed command lines);
- an internal error (a bug in camcal) prints one line naming the verb and
  "run with --debug for the traceback" and exits with code 1;
- ``--debug`` (before or after the verb) shows the full traceback instead.

Options that name cameras take ``NAME=VALUE`` entries (:class:`NamedValues`):
``--images left=A right=B`` is the same as ``--images left=A --images
right=B``; a name given twice, an entry without ``=`` or a glob that matches
nothing is one error line naming the option and the entry. Globs may be
absolute or relative (:func:`expand_glob`).

``--json`` (every verb) prints one versioned JSON object on stdout instead
of the human summary (which then goes to stderr)::

    {"format": "camcal.summary", "version": 1, "camcal": "0.x",
     "verb": "rectify", "exit_code": 0,
     "figures": {...the summary's numbers, named with their units...},
     "files": [{"path": "out/rect.rig.json", "kind": "rig"}, ...],
     "warnings": [...]}

and on an error ``{"...", "exit_code": 2, "error": "the one line"}``.
Handlers record figures and files on :func:`summary_of(args)
<summary_of>` (:class:`VerbSummary`).

Each verb group registers itself with a ``_register_<group>(subparsers)``
function that sets ``func`` on its parser; the handler receives the parsed
namespace and returns the exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import json
import math
import os
import sys
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from camcal import __version__
from camcal.base.errors import CamcalError

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL",
    "SUMMARY_FORMAT",
    "SUMMARY_VERSION",
    "NamedValues",
    "VerbSummary",
    "build_parser",
    "expand_glob",
    "main",
    "summary_of",
]

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
SUMMARY_FORMAT = "camcal.summary"
SUMMARY_VERSION = 1


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every verb registered.

    Every leaf verb gets ``--json`` and ``--debug`` here, so a verb a module
    registers has them without asking.
    """
    parser = argparse.ArgumentParser(
        prog="camcal",
        description="Geometric and colour camera calibration for VFX pipelines.",
        epilog="Exit status: 0 done, 1 internal error (or a verb's own partial failure), 2 bad input.",
    )
    parser.add_argument("--version", action="version", version=f"camcal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB")
    subparsers.required = True
    for register in _REGISTERS:
        register(subparsers)
    for path, leaf in _leaf_parsers(parser, ()):
        leaf.add_argument("--json", action="store_true",
                          help="print the summary's figures and written files as one JSON object on stdout")
        leaf.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                          help="show the traceback of an internal error")
        leaf.set_defaults(_verb=" ".join(path))
    return parser


def _leaf_parsers(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    """``(verb path, parser)`` of every leaf verb below ``parser``."""
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not actions:
        yield path, parser
        return
    for name, sub in actions[0].choices.items():
        yield from _leaf_parsers(sub, path + (name,))


# -- errors, --debug and --json ------------------------------------------------------


@dataclass
class VerbSummary:
    """What a verb reports: its figures and the files it wrote (``--json``).

    Handlers fill it with :meth:`figures` and :meth:`wrote`; :func:`main`
    prints it as one JSON object when ``--json`` is given.
    """

    verb: str
    data: dict[str, Any] = field(default_factory=dict)
    files: list[dict[str, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def figures(self, **values: Any) -> None:
        """Record figures (numbers with their units in their names: ``rms_px``)."""
        self.data.update(values)

    def wrote(self, path: str | os.PathLike, kind: str = "file", say: bool = True) -> None:
        """Record a written file; ``say`` also prints ``wrote PATH``."""
        self.files.append({"path": str(path), "kind": kind})
        if say:
            print(f"wrote {path}")

    def warn(self, message: str) -> None:
        """Record and print a warning."""
        self.warnings.append(message)
        print(f"warning: {message}")

    def to_dict(self, exit_code: int, error: str | None = None) -> dict[str, Any]:
        """The versioned JSON object (see the module docstring)."""
        out: dict[str, Any] = {
            "format": SUMMARY_FORMAT, "version": SUMMARY_VERSION, "camcal": __version__,
            "verb": self.verb, "exit_code": exit_code,
            "figures": self.data, "files": self.files, "warnings": self.warnings,
        }
        if error is not None:
            out["error"] = error
        return out


def summary_of(args: argparse.Namespace) -> VerbSummary:
    """The :class:`VerbSummary` of this run (made by :func:`main`)."""
    summary = getattr(args, "_summary", None)
    if summary is None:  # a handler called without main(), e.g. from a test
        summary = VerbSummary(getattr(args, "_verb", "camcal"))
        args._summary = summary
    return summary


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, paths and tuples as JSON."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _user_error(error: BaseException) -> str | None:
    """The one line for a user's mistake, or None for an internal error."""
    if isinstance(error, CamcalError):
        return str(error)
    if isinstance(error, OSError) and error.filename is not None:
        reason = error.strerror or error.__class__.__name__
        return f"{error.filename}: {reason}"
    if isinstance(error, UnicodeDecodeError):
        return f"a file is not text in the expected encoding ({error.reason} at byte {error.start})"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    debug = "--debug" in argv
    want_json = "--json" in argv
    summary = VerbSummary(next((a for a in argv if not a.startswith("-")), "camcal"))
    stdout = sys.stdout
    code = EXIT_BAD_INPUT
    error_line = None
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as exit_:  # --help, --version, or argparse's own usage error (exit 2)
            if want_json and exit_.code not in (0, None):
                print(json.dumps(summary.to_dict(int(exit_.code), "malformed command line (see stderr)")), file=stdout)
            raise
        debug, want_json = bool(getattr(args, "debug", False)), bool(getattr(args, "json", False))
        summary.verb = args._verb
        args._summary = summary
        with contextlib.redirect_stdout(sys.stderr) if want_json else contextlib.nullcontext():
            code = int(args.func(args) or 0)
    except KeyboardInterrupt:
        error_line, code = "interrupted", 130
        print("camcal: interrupted", file=sys.stderr)
    except Exception as error:  # noqa: BLE001 - the one place every error becomes one line
        user = _user_error(error)
        if debug:
            traceback.print_exc()
        if user is not None:
            error_line, code = user, EXIT_BAD_INPUT
            print(f"camcal: error: {user}", file=sys.stderr)
        else:
            error_line, code = f"internal error in `camcal {summary.verb}`: {error.__class__.__name__}: {error}", EXIT_INTERNAL
            hint = "" if debug else " (run with --debug for the traceback)"
            print(f"camcal: {error_line}{hint}", file=sys.stderr)
    if want_json:
        text = json.dumps(summary.to_dict(code, error_line), default=_json_default, allow_nan=False)
        print(text, file=stdout)
    return code


# -- NAME=VALUE options ----------------------------------------------------------------


def _name_value(entry: str, option: str, form: str) -> tuple[str, str]:
    """Split a ``NAME=VALUE`` option value, or fail naming the option."""
    name, sep, value = entry.partition("=")
    if not sep or not name or not value:
        raise CamcalError(f"{option}: expected {form}, got {entry!r}")
    return name, value


class NamedValues(argparse.Action):
    """A ``NAME=VALUE`` option: repeatable and multi-valued mean the same.

    ``--images left=A right=B`` and ``--images left=A --images right=B`` both
    give ``{"left": "A", "right": "B"}`` (in order). A name given twice or an
    entry without ``=`` raises :class:`CamcalError` naming the option and the
    entry. The default is an empty dict.
    """

    def __init__(self, option_strings, dest, nargs=None, default=None, **kwargs) -> None:
        super().__init__(option_strings, dest, nargs="+", default={}, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        current = dict(getattr(namespace, self.dest, None) or {})
        form = self.metavar if isinstance(self.metavar, str) else "NAME=VALUE"
        for entry in values:
            name, value = _name_value(entry, option_string, form)
            if name in current:
                raise CamcalError(f"{option_string} {entry}: name {name!r} given twice")
            current[name] = value
        setattr(namespace, self.dest, current)


def expand_glob(option: str, name: str, pattern: str, root: str | os.PathLike | None = None,
                what: str = "image") -> list[str]:
    """The files a glob matches, sorted; absolute or relative (to ``root``, else the cwd).

    Raises
    ------
    CamcalError
        ``"--images left=L/*.png: no image matches"`` when nothing matches.
    """
    full = os.path.join(os.fspath(root), os.path.expanduser(pattern)) if root else os.path.expanduser(pattern)
    files = sorted(path for path in glob.glob(full) if os.path.isfile(path))
    if not files:
        where = f" (in {root})" if root and not os.path.isabs(pattern) else ""
        raise CamcalError(f"{option} {name}={pattern}: no {what} matches{where}")
    return files


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


def _image_size(value: Sequence[int]) -> tuple[int, int]:
    width, height = value
    if width <= 0 or height <= 0:
        raise CamcalError(f"--image-size must be two positive integers, got {width} {height}")
    return width, height


# -- camcal rig ---------------------------------------------------------------------


def _rig_show(args: argparse.Namespace) -> int:
    from camcal.model.rig import Rig

    rig = Rig.load(args.rig)
    print(rig.summary())
    summary_of(args).figures(rig=rig.to_dict())
    return 0


def _register_rig(subparsers) -> None:
    rig = subparsers.add_parser("rig", help="inspect rig files; export them to and import them from other tools")
    verbs = rig.add_subparsers(dest="rig_verb", metavar="VERB")
    verbs.required = True
    show = verbs.add_parser("show", help="print a readable summary of a rig file")
    show.add_argument("rig", metavar="FILE", help="a *.rig.json file")
    show.set_defaults(func=_rig_show)
    _register_rig_interchange(verbs)


def _register_rig_interchange(verbs) -> None:
    from camcal.io.interchange import FORMATS

    export = verbs.add_parser(
        "export", help="write a rig for another tool (OpenCV, Kalibr, COLMAP, USD, Nuke)",
        description="Write RIG as FORMAT. opencv: .yaml/.yml/.xml FileStorage (one camera or a stereo pair); "
        "kalibr: camchain.yaml; colmap: a directory with cameras.txt, images.txt, points3D.txt; usd: "
        ".usda/.usdc/.usd; nuke: .nk. A lens or skew the format cannot hold is fitted with the nearest "
        "model it holds and the max pixel residual is printed; exact conversions say so.")
    export.add_argument("rig", metavar="RIG", help="a *.rig.json file")
    export.add_argument("--to", required=True, choices=FORMATS, metavar="FORMAT", help=f"one of: {', '.join(FORMATS)}")
    export.add_argument("out", metavar="OUT", help="the file (a directory for colmap) to write")
    export.add_argument("--camera", action="append", metavar="NAME", help="export only this camera (repeatable)")
    export.add_argument("--stmaps", action="store_true",
                        help="usd: also write each lens' ST-maps beside the stage and reference them from its camera")
    export.set_defaults(func=_rig_export)
    imp = verbs.add_parser(
        "import", help="read another tool's camera file as a rig",
        description="Read FILE (a directory for colmap) written by FORMAT's tool and write a camcal rig.")
    imp.add_argument("file", metavar="FILE", help="the other tool's file")
    imp.add_argument("--from", dest="fmt", required=True, choices=FORMATS, metavar="FORMAT",
                     help=f"one of: {', '.join(FORMATS)}")
    imp.add_argument("--out", required=True, metavar="RIG.rig.json", help="the rig file to write")
    imp.add_argument("--image-size", nargs=2, type=int, metavar=("W", "H"),
                     help="usd: the image size of cameras that carry none (USD cameras not written by camcal)")
    imp.set_defaults(func=_rig_import)


def _print_conversions(args: argparse.Namespace, result) -> None:
    import dataclasses

    for conversion in result.conversions:
        print(conversion.describe())
    for note in result.notes:
        print(f"note: {note}")
    summary_of(args).figures(conversions=[dataclasses.asdict(c) for c in result.conversions], notes=list(result.notes))


def _rig_export(args: argparse.Namespace) -> int:
    from pathlib import Path

    from camcal.io.interchange import export_rig
    from camcal.model.rig import Rig

    result = export_rig(Rig.load(args.rig), args.to, args.out, cameras=args.camera, rig_path=args.rig,
                        stmaps=args.stmaps)
    _print_conversions(args, result)
    for path in result.paths:
        summary_of(args).wrote(path, args.to if path == Path(args.out) or path.parent == Path(args.out) else "stmap")
    return 0


def _rig_import(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    from camcal.io.interchange import import_rig
    from camcal.io.ply import write_points_ply
    from camcal.model.rig import make_provenance

    result = import_rig(args.file, args.fmt,
                        image_size=None if args.image_size is None else _image_size(args.image_size))
    rig = dataclasses.replace(result.rig, provenance=make_provenance("import", format=args.fmt, source=str(args.file)))
    _print_conversions(args, result)
    out = summary_of(args)
    if result.points_xyz is not None:
        points = Path(args.out).with_name(Path(args.out).name.removesuffix(".json").removesuffix(".rig") + ".points.ply")
        out.wrote(write_points_ply(points, result.points_xyz, result.points_rgb), "points")
        rig = dataclasses.replace(rig, points=points.name)
    out.figures(n_cameras=len(rig.cameras), n_frames=len(rig.frames))
    out.wrote(rig.save(args.out), "rig")
    return 0


# -- camcal calibrate ----------------------------------------------------------------


def _calibrate_dlt(args: argparse.Namespace) -> int:
    from camcal.geometry.dlt import calibrate_dlt
    from camcal.io.points_csv import read_correspondences
    from camcal.model.rig import Rig, make_provenance

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
    out = summary_of(args)
    out.figures(rms_px=result.rms_px, worst_px=result.worst_px, n_points=len(X), K=K, sigma=sigma, c=result.c)
    out.wrote(args.out, "rig")
    return 0


def _parse_holdout(text: str, frames: list[int]) -> set[int]:
    """``--holdout``: frame numbers and ranges (``21-25,3``, as :func:`camcal.base.frames.parse_frames`) or a
    fraction of the frames (``0.2``, evenly spaced)."""
    import re

    from camcal.base.frames import parse_frames

    text = text.strip()
    if re.fullmatch(r"0?\.\d+", text):
        fraction = float(text)
        count = max(1, round(fraction * len(frames)))
        step = len(frames) / count
        return {frames[min(len(frames) - 1, int((k + 0.5) * step))] for k in range(count)}
    try:
        return set(parse_frames(text))
    except CamcalError as error:
        raise CamcalError(f"bad --holdout {text!r} ({error}): expected frame numbers and ranges (21-25,3) "
                          "or a fraction (0.2)") from None


def _calibrate_board(args: argparse.Namespace) -> int:
    import os

    import numpy as np

    from camcal.geometry.board import default_cache_dir, detect_in_images, frame_number, parse_board
    from camcal.geometry.zhang import calibrate_board, quality_problems
    from camcal.base.progress import Progress
    from camcal.report.calibration import write_report

    board = parse_board(args.board)
    if not args.camera:
        raise CamcalError("--camera: give at least one camera, e.g. --camera left='shots/left*.jpg'")
    cameras = {name: expand_glob("--camera", name, pattern) for name, pattern in args.camera.items()}
    detections = {}
    for name, files in cameras.items():
        report = detect_in_images(board, files, progress=Progress(len(files), f"detecting {name}", "images").report,
                                  workers=args.workers or os.cpu_count() or 1,
                                  cache=None if args.no_cache else (args.cache or default_cache_dir()))
        print(f"{name}: {report.summary()}")
        detections[name] = report.detections
    holdout: set[int] = set()
    if args.holdout:
        frames = sorted({frame_number(d.image) for views in detections.values() for d in views})
        holdout = _parse_holdout(args.holdout, frames)
    result = calibrate_board(board, detections, model=args.model, units=args.units, loss=args.loss,
                             loss_scale=args.loss_scale, holdout=holdout)
    problems = quality_problems(result)
    if problems and not args.force:
        raise CamcalError("calibration refused, its own figures show it broken: " + "; ".join(problems)
                          + " (--force writes it anyway)")
    result.rig.save(args.out)
    for note in result.notes:
        print(note)
    if result.model_heldout_rms_px:
        scores = ", ".join(f"{model} {rms:.4f} px" for model, rms in result.model_heldout_rms_px.items())
        print(f"model auto: RMS on every 4th training frame, held out to choose: {scores}; chose {result.model}")
    if result.relabelled:
        print("relabelled by a half turn (symmetric board) to agree with the rig: "
              + ", ".join(image for _, image in result.relabelled))
    if result.dropped:
        print("dropped (no corner labelling agrees with the rig): " + ", ".join(image for _, image in result.dropped))
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
        if camera.quality.get("heldout_rms_px") is not None:
            line += f" (held-out {camera.quality['heldout_rms_px']:.3f} px)"
        if "baseline_rel" in sigma:
            baseline = float(np.linalg.norm(camera.c))
            line += (f"  baseline {baseline:.4f} +/- {sigma['baseline_rel'] * baseline:.4f} {result.rig.units}"
                     f"  rotation +/- {sigma['rotation_deg']:.3f} deg")
        print(line)
    out = summary_of(args)
    if problems:
        out.warn("written with --force although " + "; ".join(problems))
    out.figures(
        summary=result.summary(), outliers=[image for _, image in result.outliers],
        detections={name: len(found) for name, found in detections.items()},
        cameras={camera.name: {"K": camera.K, "distortion": camera.distortion.to_dict(), "c": camera.c,
                               "quality": camera.quality.to_dict()} for camera in result.rig.cameras},
        model=result.model, heldout_rms_px=result.heldout_rms_px, model_heldout_rms_px=dict(result.model_heldout_rms_px),
        relabelled=[image for _, image in result.relabelled], dropped=[image for _, image in result.dropped],
        quality_problems=problems,
    )
    out.wrote(args.out, "rig")
    if args.report:
        for path in write_report(result, args.report):
            out.wrote(path, "report")
    return 3 if problems else 0


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
        "--camera", required=True, action=NamedValues, metavar="NAME=GLOB",
        help="a camera and its images, e.g. left='shots/left*.jpg' right='shots/right*.jpg' "
        "(several entries or a repeated option; globs absolute or relative)",
    )
    board.add_argument("--model", default="polynomial", choices=("polynomial", "division", "opencv", "kannala-brandt", "auto"),
                       help="distortion model; kannala-brandt is OpenCV's fisheye model; auto: the lowest RMS on "
                       "every 4th training frame held out (default: polynomial)")
    board.add_argument("--holdout", metavar="FRAMES",
                       help="frames left out of the fit and reported as held-out RMS (PnP, intrinsics held): "
                       "numbers and ranges (21-25) or a fraction (0.2)")
    board.add_argument("--loss", default="trivial", choices=("trivial", "huber", "soft_l1", "cauchy"),
                       help="robust loss on each corner (Ceres; default: trivial)")
    board.add_argument("--loss-scale", type=float, default=1.0, metavar="PX", help="scale of the loss (default: 1 px)")
    board.add_argument("--workers", type=int, default=None, metavar="N",
                       help="images detected at once (threads; default: the CPU count)")
    board.add_argument("--cache", metavar="DIR",
                       help="corner cache directory, keyed by image content and detector settings "
                       "(default: $XDG_CACHE_HOME/camcal/corners)")
    board.add_argument("--no-cache", action="store_true", help="detect again, do not read or write the cache")
    board.add_argument("--force", action="store_true",
                       help="write a rig that fails the quality gate (principal point outside the image, RMS over "
                       "1.5 px, sigma fx over 5 %%) and exit 3 instead of refusing it")
    board.add_argument("--units", default="m", help="unit of the square size, stored in the rig (default: m)")
    board.add_argument("--out", required=True, metavar="FILE.rig.json")
    board.add_argument("--report", metavar="DIR", help="write PNG plots: residuals, per-image RMS, coverage")
    board.set_defaults(func=_calibrate_board)


# -- camcal solve --------------------------------------------------------------------


def _solve(args: argparse.Namespace) -> int:
    from pathlib import Path

    from camcal.geometry.sfm import LENS_MODELS, MODELS, collect_images, solve_pycolmap_plain, solve_sfm
    from camcal.model.rig import Rig

    folders = [Path(folder) for folder in args.folders]
    if args.camera:
        if len(folders) != 1:
            raise CamcalError(f"--camera NAME=GLOB selects images inside one folder: give exactly one, got {len(folders)}")
        if not folders[0].is_dir():
            raise CamcalError(f"image folder not found: {folders[0]}")
        images = {name: [Path(f) for f in expand_glob("--camera", name, pattern, root=folders[0])]
                  for name, pattern in args.camera.items()}
    else:
        images = collect_images(folders)
    known_rig = Rig.load(args.rig) if args.rig else None
    if args.features < 100:
        raise CamcalError(f"--features must be at least 100, got {args.features}")
    # --model auto (or nothing): choose among LENS_MODELS; a named model: only it; --camera-model alone: keep it
    model = args.model or ("keep" if args.camera_model else "auto")
    lens_models = LENS_MODELS if model == "auto" else (None if model == "keep" else (model,))
    # COLMAP marks fisheye pairs without a focal prior as degenerate (no match survives): a fisheye maps with
    # SIMPLE_RADIAL and becomes kannala-brandt in the self-calibration (a fit of the lens, then the bundle)
    mapped = model in MODELS and model != "kannala-brandt"
    camera_model = args.camera_model or (MODELS[model] if mapped else "SIMPLE_RADIAL")
    result = solve_sfm(images, Path(args.out), camera_model=camera_model, matcher=args.matcher, mapper=args.mapper,
                       seed=args.seed, refine=not args.no_refine, known_rig=known_rig, loss=args.loss,
                       lens_models=lens_models, principal_point=args.principal_point, max_num_features=args.features,
                       jackknife=args.uncertainty == "jackknife",
                       progress=lambda message: print(f"camcal solve: {message}", file=sys.stderr, flush=True))
    print(f"registered {result.n_registered} / {result.n_images} images"
          + (f" (not registered: {', '.join(result.unregistered)})" if result.unregistered else ""))
    per_camera = ", ".join(f"{name} {rms:.3f} px" for name, rms in result.per_camera_rms_px.items())
    print(f"RMS reprojection error: {result.rms_px:.3f} px ({per_camera}); {result.n_points} points")
    if result.bundle is not None:
        print(result.bundle.summary())
    if result.self_calibration is not None:
        print("\n".join(result.self_calibration.lines()))
    peer = solve_pycolmap_plain(images, Path(args.out) / "pycolmap", seed=args.seed) if args.compare_pycolmap else None
    for camera in result.rig.cameras:
        sigma = camera.quality.get("sigma", {})
        print(f"{camera.name}: {_intrinsics_line(camera, sigma)}"
              + (f"; heldout RMS {camera.quality['heldout_rms_px']:.3f} px" if "heldout_rms_px" in camera.quality else ""))
        if "rotation_deg" in sigma:
            print(f"{camera.name}: rig pose sigma rotation {sigma['rotation_deg']:.3g} deg, "
                  f"baseline {100 * sigma['baseline_rel']:.3g} %")
        if peer is not None and camera.name in peer.cameras:
            print(f"{camera.name} (plain pycolmap): {_intrinsics_line(peer.cameras[camera.name], {})}; "
                  f"RMS {peer.rms_px[camera.name]:.3f} px")
    print(f"wrote {Path(args.out) / 'solve.rig.json'}, {Path(args.out) / 'points.ply'} and the COLMAP model in {result.reconstruction_dir}")
    out = summary_of(args)
    out.figures(n_images=result.n_images, n_registered=result.n_registered, unregistered=list(result.unregistered),
                rms_px=result.rms_px, per_camera_rms_px=dict(result.per_camera_rms_px), n_points=result.n_points,
                bundle=None if result.bundle is None else result.bundle.summary(),
                cameras={camera.name: dict(camera.quality) for camera in result.rig.cameras})
    if result.self_calibration is not None:
        calibration = result.self_calibration
        out.figures(lens_models=calibration.lens_models, heldout_rms_px_by_model=calibration.heldout_rms_px,
                    principal_point={d.camera: {"refined": d.refined, "limit_px": d.limit_px,
                                                "sigma_px": [v if math.isfinite(v) else None for v in d.sigma_px],
                                                "reason": d.reason} for d in calibration.principal_point},
                    uncertainty={"covariance_sigmas": calibration.covariance_sigmas,
                                 "jackknife_sigmas": calibration.jackknife_sigmas,
                                 "jackknife_groups": calibration.jackknife_groups})
    if peer is not None:
        out.figures(pycolmap={name: {"K": camera.K, "distortion": camera.distortion.to_dict(),
                                     "rms_px": peer.rms_px.get(name)} for name, camera in peer.cameras.items()})
    out.wrote(Path(args.out) / "solve.rig.json", "rig", say=False)
    out.wrote(Path(args.out) / "points.ply", "points", say=False)
    out.wrote(result.reconstruction_dir, "colmap model", say=False)
    return 0


def _intrinsics_line(camera, sigma) -> str:
    """``f 900.12 +- 0.04 px, principal point (646.0, 474.3) +- (0.01, 0.02) px, division lambda -1.2e-07``."""
    def pm(key: str, fmt: str) -> str:
        return f" +- {sigma[key]:{fmt}}" if key in sigma else ""
    K = camera.K
    focal = f"f {K[0, 0]:.2f}{pm('fx', '.2g')}" if K[0, 0] == K[1, 1] else \
        f"fx {K[0, 0]:.2f}{pm('fx', '.2g')}, fy {K[1, 1]:.2f}{pm('fy', '.2g')}"
    lens = ", ".join(f"{name} {value:.4g}{pm(name, '.2g')}" for name, value in camera.distortion.params.items())
    return (f"{focal} px, principal point ({K[0, 2]:.2f}{pm('cx', '.2g')}, {K[1, 2]:.2f}{pm('cy', '.2g')}) px, "
            f"{camera.distortion.model} {lens}")


def _register_solve(subparsers) -> None:
    solve = subparsers.add_parser(
        "solve",
        help="cameras from images: pycolmap structure from motion + camcal bundle adjustment",
        description="One folder per camera (or one folder of per-camera sub-folders, or --camera NAME=GLOB "
        "inside one folder); several cameras form a rig whose frames pair up by sorted order. "
        "Each camera's lens model is chosen by held-out residual and the principal point is refined "
        "where its sigma says the views determine it (both printed). "
        "Writes OUT/solve.rig.json, OUT/points.ply and the COLMAP model.",
    )
    solve.add_argument("folders", nargs="+", metavar="IMAGES_DIR", help="image folder(s)")
    solve.add_argument("--camera", action=NamedValues, metavar="NAME=GLOB",
                       help="a camera's images, e.g. left='*_L.png' right='*_R.png' (relative to "
                       "IMAGES_DIR, or absolute; several entries or a repeated option)")
    solve.add_argument("--rig", metavar="KNOWN.rig.json",
                       help="hold the cameras' relative poses at this calibration (and take its units)")
    solve.add_argument("--model", choices=("auto", "division", "polynomial", "opencv", "none", "kannala-brandt"),
                       help="camcal lens model (COLMAP SIMPLE_DIVISION / RADIAL / OPENCV / SIMPLE_PINHOLE / "
                       "OPENCV_FISHEYE); auto (the default) chooses per camera by held-out residual among "
                       "division, polynomial and opencv, never kannala-brandt: name it for a fisheye lens "
                       "(mapped with SIMPLE_RADIAL, then refined as OPENCV_FISHEYE)")
    solve.add_argument("--camera-model", help="COLMAP camera model to map with; alone, it is kept (no choice)")
    solve.add_argument("--principal-point", default="auto", choices=("auto", "refine", "centre"),
                       help="refine it where its sigma says the views determine it (auto), always, or never")
    solve.add_argument("--uncertainty", default="jackknife", choices=("jackknife", "covariance"),
                       help="sigmas: the larger of the covariance and a delete-one-frame jackknife (one more "
                       "refinement per frame, at most 20), which sees errors an image's features share; "
                       "or the covariance alone (faster, too small on real features)")
    solve.add_argument("--features", type=int, default=8192, metavar="N", help="SIFT features per image (8192)")
    solve.add_argument("--matcher", default="exhaustive", choices=("exhaustive", "sequential"))
    solve.add_argument("--mapper", default="incremental", choices=("incremental", "global"))
    solve.add_argument("--loss", default="trivial", choices=("trivial", "huber", "soft_l1", "cauchy"),
                       help="robust loss of camcal's bundle adjustment (scale 1 px)")
    solve.add_argument("--no-refine", action="store_true", help="keep pycolmap's result, skip camcal's refinement")
    solve.add_argument("--compare-pycolmap", action="store_true",
                       help="also run plain pycolmap (SIMPLE_DIVISION, principal point refined) on the same images "
                       "into OUT/pycolmap and print its intrinsics beside camcal's")
    solve.add_argument("--seed", type=int, default=0)
    solve.add_argument("--out", required=True, metavar="DIR")
    solve.set_defaults(func=_solve)


# -- camcal demo ---------------------------------------------------------------------


def _demo(args: argparse.Namespace) -> int:
    import dataclasses

    from camcal.demo import FULL, run_demo

    config = dataclasses.replace(FULL, seed=args.seed)
    if args.stages:
        config = dataclasses.replace(config, stages=tuple(s.strip() for s in args.stages.split(",")))
    report = run_demo(args.out, config)
    print(report.table())
    out = summary_of(args)
    for label, path in report.outputs:
        print(f"wrote {path} ({label})")
        out.wrote(path, label, say=False)
    print(f"report: {report.report}")
    out.wrote(report.report, "report", say=False)
    out.figures(rows=[{"stage": row.stage, "quantity": row.quantity, "true": row.true, "recovered": row.recovered,
                       "error": row.error, "tolerance": row.tolerance, "unit": row.unit, "ok": row.ok,
                       "source": row.source} for row in report.rows],
                seconds=dict(report.seconds), n_failed=len(report.failed))
    print("time per stage: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in report.seconds))
    if report.failed:
        print(f"outside tolerance: {', '.join(row.quantity for row in report.failed)}", file=sys.stderr)
        return 1
    print(f"all {len(report.rows)} recovered values within tolerance")
    return 0


def _register_demo(subparsers) -> None:
    from camcal.demo import STAGES

    demo = subparsers.add_parser(
        "demo",
        help="the whole pipeline on a stereo rig it renders with Blender, with an HTML report",
        description="Render a known stereo rig with Blender (Cycles, CPU), run camcal's verbs on the images, "
        "print recovered vs true values with their tolerances and write DIR/report.html. "
        "Exits 1 when a value is outside its tolerance.",
    )
    demo.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    demo.add_argument("--stages", metavar="A,B,...",
                      help="run only these stages (of: " + ", ".join(s.name for s in STAGES) + ")")
    demo.set_defaults(func=_demo)


# -- camcal distortion ---------------------------------------------------------------


def _pattern(value: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise CamcalError(f"--pattern must look like 9x6 (inner corners), got {value!r}") from None
    if cols < 2 or rows < 2:
        raise CamcalError(f"--pattern needs at least 2x2 inner corners, got {value!r}")
    return cols, rows


def _distortion_fit(args: argparse.Namespace) -> int:
    import cv2

    from pathlib import Path

    from camcal.geometry.plumbline import fit_plumbline, lines_from_images, read_lines
    from camcal.io.frames import imread
    from camcal.base.jsonfile import write_json

    if bool(args.images) == bool(args.lines):
        raise CamcalError("give either IMAGES or --lines LINES.json (not both)")
    if args.lines:
        lines = read_lines(args.lines)
        skipped: list[str] = []
    else:
        images = []
        for path in args.images:
            images.append(imread(path, cv2.IMREAD_GRAYSCALE))
        pattern = _pattern(args.pattern) if args.pattern else None
        lines, skipped_index = lines_from_images(images, pattern)
        skipped = [args.images[i] for i in skipped_index]
        what = "board" if pattern else "long straight edges"
        print(f"{what} found in {len(images) - len(skipped)} / {len(images)} images"
              + (f" (skipped: {', '.join(skipped)})" if skipped else ""))
    result = fit_plumbline(lines, args.model, fit_center=args.fit_centre)
    write_json(args.out, result.to_dict())
    if args.report:
        write_json(Path(args.report) / "plumbline_report.json", {
            **result.to_dict(),
            "strand_hayman": {
                "distortion": result.initial.distortion.to_dict(),
                "lambda_per_line": result.initial.lambda_per_line.tolist(),
                "weights": result.initial.weights.tolist(),
            },
            "rms_before_px": result.rms_before_px.tolist(),
            "rms_after_px": result.rms_after_px.tolist(),
        })
    params = ", ".join(f"{k} {v:.6g}" for k, v in result.distortion.params.items())
    centre = result.distortion.center or tuple(result.K[:2, 2])
    print(f"{result.distortion.model}: {params} about ({centre[0]:.2f}, {centre[1]:.2f}) px")
    out = summary_of(args)
    out.figures(distortion=result.distortion.to_dict(), straightness_rms_before_px=result.straightness_rms_before_px,
                straightness_rms_px=result.straightness_rms_px, worst_line_rms_px=float(result.rms_after_px.max()),
                n_lines=result.n_lines, n_points=result.n_points, skipped=skipped)
    out.wrote(args.out, "lens", say=False)
    if args.report:
        out.wrote(Path(args.report) / "plumbline_report.json", "report", say=False)
    print(f"straightness RMS: {result.straightness_rms_before_px:.3f} px before, "
          f"{result.straightness_rms_px:.3f} px after (worst line {result.rms_after_px.max():.3f} px, "
          f"{result.n_lines} lines, {result.n_points} points)")

# -- camcal rectify ------------------------------------------------------------------


def _rectify(args: argparse.Namespace) -> int:
    from camcal.geometry.rectify import RectifyWarper, match_images, read_matches_csv, rectify
    from camcal.base.jsonfile import write_json
    from camcal.model.rig import Rig

    if not 0.0 <= args.alpha <= 1.0:
        raise CamcalError(f"--alpha must be in [0, 1], got {args.alpha}")
    if args.write and not args.images:
        raise CamcalError("--write needs --images NAME=GLOB for the cameras to rectify")
    rig = Rig.load(args.rig)
    for name in args.images:
        rig.camera(name)
    images = {name: expand_glob("--images", name, pattern) for name, pattern in args.images.items()}
    names = list(images) if len(images) >= 2 else None
    if args.matches:
        matches = read_matches_csv(args.matches)
    elif images and (args.method == "hartley" or args.refine):
        matches = match_images(rig, {name: files[0] for name, files in images.items()})
    else:
        matches = None
    method = {"camera": "Nozick 2011" if args.refine else "camera", "hartley": "Hartley 1999"}[args.method]
    result = rectify(rig, method, matches, names, args.alpha, args.max_fov)
    written = []
    if args.write:
        warper = RectifyWarper(result.rig)
        for name in result.names:
            written += warper.write(name, images.get(name, []), args.write)
    result.rig.save(args.out)
    print(result.summary())
    out = summary_of(args)
    out.figures(**result.to_report())
    for path in written:
        out.wrote(path, "image", say=False)
    if written:
        print(f"wrote {len(written)} rectified image(s) to {args.write}")
    if args.report:
        out.wrote(write_json(f"{args.report}/rectification.json", result.to_report()), "report")
    out.wrote(args.out, "rig")
    return 0


def _register_distortion(subparsers) -> None:
    distortion = subparsers.add_parser("distortion", help="lens distortion from straight lines")
    verbs = distortion.add_subparsers(dest="distortion_verb", metavar="VERB")
    verbs.required = True
    fit = verbs.add_parser(
        "fit",
        help="plumb-line fit (Strand & Hayman, refined by Devernay & Faugeras)",
        description="Fit a division or polynomial lens model so that straight lines become straight. "
        "Lines come from chessboard rows/columns (--pattern), from long edges in IMAGES, or from "
        'LINES.json: {"image_size": [W, H], "lines": [[[x, y], ...], ...]}.',
    )
    fit.add_argument("images", nargs="*", metavar="IMAGES", help="images of one camera")
    fit.add_argument("--lines", metavar="LINES.json", help="line points instead of images")
    fit.add_argument("--pattern", metavar="COLSxROWS", help="chessboard inner corners, e.g. 9x6 (default: edges)")
    fit.add_argument("--model", choices=("division", "polynomial"), default="division")
    fit.add_argument("--fit-centre", action="store_true", help="fit the distortion centre too")
    fit.add_argument("--out", required=True, metavar="lens.json")
    fit.add_argument("--report", metavar="DIR", help="write per-line figures to DIR/plumbline_report.json")
    fit.set_defaults(func=_distortion_fit)


# -- camcal undistort / stmap ------------------------------------------------------------


def _undistort(args: argparse.Namespace) -> int:
    from camcal.geometry.undistort import undistort_images
    from camcal.model.rig import Rig

    rig = Rig.load(args.rig)
    rig_path, written = undistort_images(rig, args.camera, args.images, args.out, args.mode, args.overscan,
                                         args.max_fov)
    camera = Rig.load(rig_path).camera(args.camera)
    width, height = camera.image_size
    print(f"undistorted {len(written)} image(s) of {args.camera!r} ({args.mode}): {width}x{height} px, "
          f"fx {camera.K[0, 0]:.3f} fy {camera.K[1, 1]:.3f} principal point ({camera.K[0, 2]:.2f}, {camera.K[1, 2]:.2f})")
    print(f"wrote {rig_path} and {len(written)} image(s) in {args.out}")
    out = summary_of(args)
    out.figures(camera=args.camera, mode=args.mode, image_size=[width, height], K=camera.K)
    out.wrote(rig_path, "rig", say=False)
    for path in written:
        out.wrote(path, "image", say=False)
    return 0


def _register_undistort(subparsers) -> None:
    undistort = subparsers.add_parser(
        "undistort",
        help="undistort images of a rig camera",
        description="Undistort images with one remap per image; writes them under their own names "
        "and DIR/undistorted.rig.json with the new K and distortion none.",
    )
    undistort.add_argument("rig", metavar="RIG", help="a *.rig.json file")
    undistort.add_argument("--camera", required=True, metavar="NAME")
    undistort.add_argument("images", nargs="+", metavar="IMAGES")
    undistort.add_argument("--mode", choices=("crop", "keep", "overscan"), default="crop",
                           help="crop: no black borders; keep: every source pixel kept (bigger canvas); "
                           "overscan: canvas --overscan times the plate (default: crop)")
    undistort.add_argument("--overscan", type=float, default=1.1, help="canvas factor for --mode overscan")
    undistort.add_argument("--max-fov", type=float, metavar="DEG",
                           help="crop / keep: widest full angle about the axis the pinhole output holds "
                           "(default: 120 for a kannala-brandt fisheye, no cap for the other lenses)")
    undistort.add_argument("--out", required=True, metavar="DIR")
    undistort.set_defaults(func=_undistort)


def _stmap(args: argparse.Namespace) -> int:
    from camcal.geometry.stmap import write_stmaps
    from camcal.model.rig import Rig

    paths = write_stmaps(Rig.load(args.rig), args.camera, args.out, args.overscan)
    print(f"ST-maps of {args.camera!r} with overscan {args.overscan:g}")
    out = summary_of(args)
    out.figures(camera=args.camera, overscan=args.overscan)
    for path in paths:
        out.wrote(path, "stmap" if str(path).endswith(".exr") else "rig")
    return 0


def _register_stmap(subparsers) -> None:
    stmap = subparsers.add_parser(
        "stmap",
        help="undistort/redistort ST-maps (EXR) for comp packages",
        description="Write NAME_undistort.exr and NAME_redistort.exr (R = (x + 0.5) / W, "
        "G = 1 - (y + 0.5) / H of the pixel to sample) and the undistorted rig.",
    )
    stmap.add_argument("rig", metavar="RIG", help="a *.rig.json file")
    stmap.add_argument("--camera", required=True, metavar="NAME")
    stmap.add_argument("--overscan", type=float, default=1.1, help="undistorted canvas factor (default 1.1)")
    stmap.add_argument("--out", required=True, metavar="DIR")
    stmap.set_defaults(func=_stmap)


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
    parser.add_argument("--images", action=NamedValues, metavar="NAME=GLOB",
                        help="images per camera, e.g. left='L/*.png' right='R/*.png' "
                        "(several entries or a repeated option; globs absolute or relative)")
    parser.add_argument("--matches", metavar="FILE.csv", help="point matches in original pixels")
    parser.add_argument("--alpha", type=float, default=0.0,
                        help="0: only pixels all views see (default); 1: every source pixel")
    parser.add_argument("--max-fov", type=float, metavar="DEG",
                        help="widest full angle about the rectified viewing direction the pinhole rectified images "
                        "hold (default: 120 when a camera has a kannala-brandt fisheye, no cap otherwise)")
    parser.add_argument("--out", required=True, metavar="FILE.rig.json", help="the rectified rig")
    parser.add_argument("--write", metavar="DIR", help="write rectified images to DIR/<camera>/")
    parser.add_argument("--report", metavar="DIR", help="write DIR/rectification.json with the figures")
    parser.set_defaults(func=_rectify)


# --------------------------------------------------------------------------
# batch: plate sequences, locally or on a Dask cluster


def _batch(args: argparse.Namespace) -> int:
    from camcal.base.frames import parse_frames
    from camcal.batch import make_job, run_batch

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
    for frame in report.written:
        out.wrote(frame.output, "frame", say=False)
    return 0 if report.ok else 1


def _register_batch(subparsers) -> None:
    parser = subparsers.add_parser(
        "batch",
        help="undistort / rectify / colour-correct a plate sequence on Dask",
        description="Process frames of a sequence, one Dask task per frame, on a local cluster "
        "(--workers) or an existing scheduler (--scheduler). Maps and the colour step are built "
        "once per worker. Outputs keep the inputs' format, bit depth and (EXR) metadata, are "
        "written atomically, and a failed frame is retried, then reported by number.",
        epilog="Exit status: 0 all frames written, 1 some frames failed (listed), 2 bad input.",
    )
    parser.add_argument("rig", metavar="RIG", help="a *.rig.json file")
    parser.add_argument("--camera", required=True, metavar="NAME")
    parser.add_argument("--in", dest="in_pattern", required=True, metavar="PATTERN",
                        help="input frames, e.g. 'plates/left.%%04d.exr'")
    parser.add_argument("--frames", required=True, metavar="RANGE", help="e.g. 1001-1240, 1001-1240x2, 1,5,10-12")
    parser.add_argument("--out", required=True, metavar="PATTERN", help="output frames, e.g. 'out/left.%%04d.exr'")
    geometry = parser.add_mutually_exclusive_group()
    geometry.add_argument("--undistort", action="store_true", help="undistort (see `camcal undistort`)")
    geometry.add_argument("--rectify", action="store_true", help="rectify with the camera's rectification")
    parser.add_argument("--mode", choices=("crop", "keep", "overscan"), default="crop",
                        help="how --undistort chooses the new camera (default: crop)")
    parser.add_argument("--overscan", type=float, default=1.1, help="canvas factor for --mode overscan")
    parser.add_argument("--colour", metavar="FIT.colour.json", help="apply a characterisation (camera RGB -> "
                        "--colour-space, through the OCIO processor of its exported transform)")
    parser.add_argument("--colour-space", default="ACES2065-1",
                        choices=("ACES2065-1", "ACEScg", "lin Rec.709", "CIE XYZ"),
                        help="output space of --colour (default: %(default)s; CIE XYZ is the fit's own XYZ)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="use a running Dask scheduler")
    where.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: one per core)")
    parser.add_argument("--resume", action="store_true", help="skip frames already complete and unchanged")
    parser.add_argument("--retries", type=int, default=2, metavar="N", help="retries of a failed frame (default: 2)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.set_defaults(func=_batch)


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
    source.add_argument("--chart", metavar="IMAGE", help="photo of a 24-patch ColorChecker (PNG/TIFF/JPEG/EXR, or "
                                                          "raw: DNG, CR2, NEF, ARW... read as linear camera RGB)")
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
    _register_for_illuminant(parser)
    parser.set_defaults(func=_colour_fit)


def _register_for_illuminant(parser) -> None:
    """``colour fit --for-illuminant B --sensitivities SSF``: a fit for another light."""
    group = parser.add_argument_group(
        "another illuminant",
        "fit for the light B the camera will be used under, from a chart shot under --illuminant A: the "
        "spectral route (ACES P-2013-001: training reflectances through the sensitivities under B) vs the "
        "chart fit white-balanced and adapted with CAT02 / Bradford, each with each model under --model auto; the "
        "pair with the lowest RMS CIEDE2000 on validation "
        "reflectances is written (its camera name gets ' (B)', so one OCIO input space per illuminant). "
        "The chart RGB must be linear (raw or --linearise none).")
    group.add_argument("--for-illuminant", metavar="B", help="CIE illuminant name the fit is for (A, D50, FL2...)")
    group.add_argument("--sensitivities", metavar="SSF", help="*.ssf.json or measured CSV (colour sensitivities)")
    group.add_argument("--training-reflectances", default="rawtoaces 190", metavar="SET",
                       help="spectral route training set (default: %(default)s)")
    group.add_argument("--validation-reflectances", default="Munsell validation", metavar="SET",
                       help="reflectances the routes are compared on (default: %(default)s)")
    group.add_argument("--plausible-cameras", type=int, default=0, metavar="N",
                       help="compare over N cameras drawn from the sensitivities' uncertainty (default: 0, "
                            "the curves themselves)")


def _colour_fit_for_illuminant(args: argparse.Namespace, train, reference, linearise: str) -> int:
    from dataclasses import replace

    from camcal.colour.illuminant import characterise_for_illuminant
    from camcal.colour.ssf import load_sensitivities
    from camcal.io.raw import is_raw, raw_metadata

    if not args.sensitivities:
        raise CamcalError("--for-illuminant needs --sensitivities SSF (from 'camcal colour sensitivities')")
    if linearise != "none":
        raise CamcalError(f"--for-illuminant needs linear camera RGB (--linearise none, raw input), got {linearise!r}")
    if args.test_patches or args.target_white:
        raise CamcalError("--for-illuminant judges on validation reflectances under B: drop --test-patches / --target-white")
    if args.plausible_cameras < 0:
        raise CamcalError(f"--plausible-cameras must be >= 0, got {args.plausible_cameras}")
    sens = load_sensitivities(args.sensitivities)
    camera = f"{args.camera} ({args.for_illuminant})" if args.camera else None
    outcome = characterise_for_illuminant(
        train, sens, illuminant=args.illuminant, for_illuminant=args.for_illuminant, model=args.model,
        training_set=args.training_reflectances, validation_set=args.validation_reflectances,
        n_cameras=args.plausible_cameras, camera=camera, reference=reference,
        source=args.chart or args.patches)
    print(outcome.summary())
    fit = outcome.fit
    if args.chart and is_raw(args.chart):
        fit = replace(fit, capture=raw_metadata(args.chart).to_dict())
    out = summary_of(args)
    out.figures(for_illuminant=args.for_illuminant, route=outcome.picked, model=fit.model.label,
                n_train=len(train), reason=outcome.reason, validation_reflectances=args.validation_reflectances,
                delta_E2000_validation={score.route: score.to_dict() for score in outcome.scores})
    out.wrote(fit.save(args.out), "colour fit")
    return 0


def _parse_corners(text: str):
    try:
        values = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise CamcalError(f"--corners: expected 8 numbers, got {text!r}") from None
    if len(values) != 8:
        raise CamcalError(f"--corners: expected 8 numbers, got {len(values)}")
    return [values[i : i + 2] for i in range(0, 8, 2)]


def _colour_fit(args: argparse.Namespace) -> int:
    import dataclasses

    from camcal.colour.characterise import characterise, patches_from_chart
    from camcal.colour.patches import read_patch_csv
    from camcal.io.raw import is_raw, raw_metadata
    from camcal.report.characterisation import write_report

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
        linearise = args.linearise or ("none" if args.for_illuminant or is_raw(args.chart) else "lut1d")
        white = args.illuminant
    else:
        if args.corners:
            raise CamcalError("--corners applies to --chart only")
        train = read_patch_csv(args.patches)
        print(f"read {len(train)} patches from {args.patches}")
        linearise = args.linearise or "none"
        white = args.illuminant
    if args.for_illuminant:
        return _colour_fit_for_illuminant(args, train, reference, linearise)
    if args.sensitivities:
        raise CamcalError("--sensitivities is used with --for-illuminant B")
    test = read_patch_csv(args.test_patches) if args.test_patches else None
    outcome = characterise(
        train, white=white, model=args.model, objective=args.objective,
        regularisation=args.regularisation, linearise=linearise,
        test=test, target_white=args.target_white, adaptation=args.adaptation,
        camera=args.camera, reference=reference, source=args.chart or args.patches,
    )
    print(outcome.summary())
    fit = outcome.fit
    if args.chart and is_raw(args.chart):
        fit = dataclasses.replace(fit, capture=raw_metadata(args.chart).to_dict())
    out = summary_of(args)
    stats = {name: None if value is None else dataclasses.asdict(value) for name, value in (
        ("train", outcome.result.stats_train), ("loo", outcome.result.stats_loo), ("test", outcome.result.stats_test))}
    out.figures(model=outcome.result.model.label, linearisation=outcome.fit.linearisation.label,
                selection=None if outcome.selection is None else outcome.selection.reason,
                n_train=len(train), delta_E2000=stats)
    out.wrote(fit.save(args.out), "colour fit")
    if args.report:
        files = write_report(outcome, args.report, title=args.camera or "")
        for file in files:
            out.wrote(file, "report", say=False)
        print(f"report: {len(files)} files in {args.report}")
    return 0


def _register_colour_export(colour_verbs) -> None:
    parser = colour_verbs.add_parser(
        "export",
        help="export fits as OCIO colour spaces (config + CLF) and ICC camera profiles",
        description=(
            "Export characterisations (*.colour.json) as input colour spaces 'camcal <camera>' "
            "(family Input/camcal) of an OpenColorIO config, and/or as an ICC camera profile. "
            "Matrix fits are exact; other models are baked (log-chromaticity shaper + 3D LUT; ICC v4: "
            "float D2B0/D2B1 plus a 16-bit A2B0) with the bake error checked over the chart gamut and "
            "plausible surface colours."
        ),
        epilog=(
            "--base: 'camcal' (camcal's small ACES config, ocio_configs/camcal_base.ocio), an "
            "ocio:// built-in (default: ocio://studio-config-latest, which needs OCIO 2.6; "
            "Blender 5.0 links OCIO 2.4: use 'camcal' or ocio://studio-config-v2.2.0_aces-v1.3_ocio-v2.4 "
            "there) or a .ocio file with an aces_interchange role."
        ),
    )
    parser.add_argument("fits", nargs="+", metavar="FIT.colour.json", help="characterisation files")
    parser.add_argument("--camera-name", metavar="NAME",
                        help="camera name (one fit only; default: the fit's camera, else the file name)")
    parser.add_argument("--ocio", metavar="OUTDIR", help="write OUTDIR/config.ocio and OUTDIR/luts/*.clf")
    parser.add_argument("--base", default="ocio://studio-config-latest", metavar="CONFIG",
                        help="config to add the spaces to (default: %(default)s; see below)")
    parser.add_argument("--cat", choices=("Bradford", "CAT02"), default="Bradford",
                        help="adaptation from the fit's white to the ACES white (default: %(default)s)")
    parser.add_argument("--icc", metavar="OUT.icc", help="write an ICC camera profile (one fit only)")
    parser.add_argument("--icc-version", type=int, choices=(4, 2), default=4,
                        help="ICC profile version: 4 (ICC.1:2010, default) or 2 (ICC.1:2001-04)")
    parser.add_argument("--max-bake-error", type=float, default=0.2, metavar="DE",
                        help="largest CIEDE2000 a baked LUT may add over the chart gamut and plausible surface "
                        "colours (default: %(default)s)")
    parser.set_defaults(func=_colour_export)


def _colour_export(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    from camcal.colour.fitfile import ColourFit, load_colour_file

    if not args.ocio and not args.icc:
        raise CamcalError("nothing to write: give --ocio OUTDIR and/or --icc OUT.icc")
    if args.camera_name and len(args.fits) > 1:
        raise CamcalError(f"--camera-name needs exactly one fit, got {len(args.fits)}")
    if args.icc and len(args.fits) > 1:
        raise CamcalError(f"--icc writes one profile: give one fit, got {len(args.fits)}")
    if not (args.max_bake_error > 0):
        raise CamcalError(f"--max-bake-error must be > 0, got {args.max_bake_error}")
    out = summary_of(args)
    fits, matches = [], []
    for path in args.fits:
        fit = load_colour_file(path)
        if not isinstance(fit, ColourFit):
            matches.append(fit)
            continue
        name = args.camera_name or fit.camera or Path(path).name.removesuffix(".json").removesuffix(".colour")
        fits.append((name, fit))
    if args.icc and not fits:
        raise CamcalError("--icc needs a characterisation (kind characterisation); a camera match has no ICC profile")
    profile = None
    if args.icc:
        from camcal.colour.export_icc import icc_profile_from_fit, write_icc

        profile = icc_profile_from_fit(fits[0][1], fits[0][0], version=args.icc_version,
                                       max_delta_E=args.max_bake_error)
    if args.ocio:
        from camcal.colour.export_ocio import export_ocio

        result = export_ocio(fits, args.ocio, base=args.base, cat=args.cat, max_delta_E=args.max_bake_error,
                             matches=matches)
        for space in result.spaces:
            print(space.summary())
        print(f"wrote {result.config_path} (base {result.base}, {len(fits)} camera space(s), {len(matches)} match Look(s))")
        out.figures(base=result.base, n_matches=len(matches), spaces=[{
            "name": space.name, "camera": space.camera, "model": space.model, "kind": space.kind,
            "lut_size": space.lut_size, "clf": space.clf, "linearisation_error": space.linearisation_error,
            "bake_error_delta_E2000": None if space.bake_error is None else dataclasses.asdict(space.bake_error),
        } for space in result.spaces])
        out.wrote(result.config_path, "ocio config", say=False)
        for space in result.spaces:
            if space.clf:
                out.wrote(Path(args.ocio) / space.clf, "clf", say=False)
    if profile is not None:
        write_icc(profile, args.icc)
        print(f"wrote {args.icc} (ICC v{profile.version}, {profile.summary()})")
        out.figures(icc={"version": profile.version, "kind": profile.kind, "bake_error_delta_E2000":
                         None if profile.kind == "matrix-trc" else dataclasses.asdict(profile.bake_error),
                         "float_clut_size": profile.float_clut_size, "float_bake_error_delta_E2000":
                         None if profile.float_bake_error is None else dataclasses.asdict(profile.float_bake_error)})
        out.wrote(args.icc, "icc", say=False)
    return 0


def _register_colour_match(colour_verbs) -> None:
    parser = colour_verbs.add_parser(
        "match",
        help="match one camera's colours to another's (stereo pair or chart)",
        description=(
            "Fit a colour transform from camera B's linear RGB to camera A's. Image route: a "
            "stereo pair (--images A=IMG --images B=IMG; the first camera is the target A), "
            "rectified with the rig's calibration unless --rectified; SGBM disparity with a "
            "left-right check picks reliable, unoccluded, unsaturated pixels, the fit is robust "
            "(LMedS + IRLS) and judged by CIEDE2000 on held-out image tiles. Chart route: "
            "--fits and --patches for both cameras (same chart): both go to XYZ, the residual "
            "camera-to-camera CIEDE2000 is reported. Writes a *.colour.json of kind match."
        ),
    )
    parser.add_argument("rig", nargs="?", metavar="RIG", help="a calibrated *.rig.json holding both cameras")
    parser.add_argument("--images", action=NamedValues, metavar="NAME=IMG",
                        help="one image per camera, target first")
    parser.add_argument("--rectified", action="store_true", help="the images are rectified already")
    parser.add_argument("--fits", action=NamedValues, metavar="NAME=FIT.colour.json",
                        help="characterisations (linearisation; the target's gives XYZ for Delta E)")
    parser.add_argument("--patches", action=NamedValues, metavar="NAME=FILE.csv",
                        help="chart route: each camera's patch CSV of the same chart, target first")
    parser.add_argument("--test-patches", action=NamedValues, metavar="NAME=FILE.csv",
                        help="chart route: independent patches per camera")
    parser.add_argument("--encoding", default="linear", metavar="NAME",
                        help="image encoding of cameras without a fit: linear or a transfer function "
                             "(sRGB, ITU-R BT.709, ARRI LogC3...; default: linear)")
    parser.add_argument("--model", default="matrix3x3",
                        help="matrix3x3 | root-polynomial:D | polynomial:N | lut3d[:N] (default: matrix3x3)")
    parser.add_argument("--robust", choices=("lmeds-irls", "irls", "none"), default=None,
                        help="robust fitting (default: lmeds-irls for images, none for charts)")
    parser.add_argument("--out", required=True, metavar="MATCH.colour.json", help="match file to write")
    parser.add_argument("--report", metavar="DIR", help="difference images and Delta E maps (or chart plots)")
    parser.set_defaults(func=_colour_match)


def _colour_match(args: argparse.Namespace) -> int:
    from camcal.colour.fitfile import load_fit
    from camcal.colour.match import match_image_files, match_patch_files
    from camcal.colour.match_models import parse_match_model
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
    out.wrote(result.match.save(args.out), "colour match")
    if args.report:
        files = write_report(result, args.report)
        for file in files:
            out.wrote(file, "report", say=False)
        print(f"report: {len(files)} files in {args.report}")
    return 0


def _register_colour_sensitivities(colour_verbs) -> None:
    parser = colour_verbs.add_parser(
        "sensitivities",
        help="estimate (or load measured) camera spectral sensitivities: *.ssf.json + CSV",
        description=(
            "Estimate a camera's spectral sensitivities from chart captures (linear images: raw or "
            "linear TIFF/EXR) and/or spectral patch CSVs, each under a known illuminant, with "
            "positivity, smoothness and the regularisation chosen by K-fold cross-validation; "
            "or read measured curves (--measured). Writes *.ssf.json and *.ssf.csv and prints the "
            "Vora-Trussell mu-factor and the Luther-Ives deviation."
        ),
        epilog=(
            "ILLUMINANT: a colour-science SDS_ILLUMINANTS name (D65, A, FL2, LED-B3...) or a CSV "
            "wavelength,value. Spectral patch CSV header: name,R,G,B,<nm>,<nm>,... (linear camera "
            "RGB then reflectance samples). Measured CSV: wavelength,R,G,B[,sigma_R,sigma_G,sigma_B]."
        ),
    )
    parser.add_argument("--chart", nargs="+", action="extend", metavar="ILLUMINANT=IMAGE", default=[],
                        help="a linear photo of a ColorChecker 24 under ILLUMINANT (repeatable)")
    parser.add_argument("--patches", nargs="+", action="extend", metavar="ILLUMINANT=FILE.csv", default=[],
                        help="patches with reflectance spectra under ILLUMINANT (repeatable)")
    parser.add_argument("--measured", metavar="FILE.csv", help="measured sensitivities instead of an estimate")
    parser.add_argument("--chart-spectra", default="BabelColor Average", metavar="NAME",
                        help="reflectances of the chart's patches: BabelColor Average, ColorChecker N Ohta "
                             "or ISO 17321-1 (default: %(default)s)")
    parser.add_argument("--wavelengths", default="400,700,10", metavar="START,END,STEP",
                        help="estimation grid in nm (default: %(default)s)")
    parser.add_argument("--camera", default=None, help="camera name recorded in the file")
    parser.add_argument("--compare", metavar="SSF", help="reference curves (*.ssf.json or CSV): print the "
                                                         "relative RMS error and both mu-factors")
    parser.add_argument("--out", required=True, metavar="CAMERA.ssf.json", help="file to write (+ .ssf.csv)")
    parser.add_argument("--report", metavar="DIR", help="plot with 95 %% bands (sensitivities.png)")
    parser.set_defaults(func=_colour_sensitivities)


def _colour_sensitivities(args: argparse.Namespace) -> int:
    import numpy as np

    from camcal.colour.ssf import (capture_from_chart, estimate_from_captures, load_sensitivities,
                                   plot_sensitivities, read_sensitivities_csv, read_spectral_patch_csv,
                                   relative_rms_error, write_sensitivities)

    try:
        start, end, step = (float(v) for v in args.wavelengths.split(","))
    except ValueError:
        raise CamcalError(f"--wavelengths: expected START,END,STEP in nm, got {args.wavelengths!r}") from None
    if not (0 < step and start + 2 * step <= end):
        raise CamcalError(f"--wavelengths: need START < END with at least 3 steps, got {args.wavelengths!r}")
    wavelengths = np.arange(start, end + step / 2, step)
    reference = load_sensitivities(args.compare) if args.compare else None
    if args.measured:
        if args.chart or args.patches:
            raise CamcalError("give --measured, or captures (--chart / --patches), not both")
        sens = read_sensitivities_csv(args.measured, args.camera)
    else:
        captures = []
        for entry in args.chart:
            illuminant, path = _name_value(entry, "--chart", "ILLUMINANT=IMAGE")
            captures.append(capture_from_chart(path, illuminant, wavelengths, reflectances=args.chart_spectra))
        for entry in args.patches:
            illuminant, path = _name_value(entry, "--patches", "ILLUMINANT=FILE.csv")
            captures.append(read_spectral_patch_csv(path, illuminant, wavelengths))
        if not captures:
            raise CamcalError("nothing to estimate from: give --chart ILLUMINANT=IMAGE, --patches "
                              "ILLUMINANT=FILE.csv or --measured FILE.csv")
        for cap in captures:
            print(f"{cap.source}: {len(cap.names)} patches under {cap.illuminant_name}")
        sens = estimate_from_captures(captures, wavelengths, camera=args.camera)
    print(sens.summary())
    out = summary_of(args)
    out.figures(source=sens.source, wavelengths_nm=[float(sens.wavelengths[0]), float(sens.wavelengths[-1]),
                                                    float(sens.wavelengths[1] - sens.wavelengths[0])],
                **sens.quality(), estimation=sens.estimation)
    if reference is not None:
        per_channel, overall = relative_rms_error(sens.values, reference.resampled(sens.wavelengths).values)
        print(f"vs {args.compare}: relative RMS error R {100 * per_channel[0]:.1f} %, G {100 * per_channel[1]:.1f} %, "
              f"B {100 * per_channel[2]:.1f} % (overall {100 * overall:.1f} %); mu-factor {sens.mu_factor():.4f} "
              f"vs {reference.mu_factor():.4f}")
        out.figures(compare={"reference": args.compare, "relative_rms_error": [float(v) for v in per_channel],
                             "relative_rms_error_overall": overall, "mu_factor": reference.mu_factor()})
    json_path, csv_path = write_sensitivities(args.out, sens)
    out.wrote(json_path, "sensitivities")
    out.wrote(csv_path, "sensitivities csv")
    if args.report:
        from pathlib import Path

        path = plot_sensitivities(Path(args.report) / "sensitivities.png", sens, reference, title=args.camera or "")
        out.wrote(path, "report", say=False)
        print(f"report: {path}")
    return 0


_COLOUR_VERBS: list = [_register_colour_fit, _register_colour_export, _register_colour_match,
                       _register_colour_sensitivities]


# One entry per verb group; keep this list the only place verbs are wired in.
_REGISTERS: list = [
    _register_rig,
    _register_calibrate,
    _register_distortion,
    _register_undistort,
    _register_stmap,
    _register_rectify,
    _register_solve,
    _register_blender,
    _register_colour,
    _register_batch,
    _register_demo,
]
