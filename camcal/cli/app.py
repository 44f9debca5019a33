"""The ``camcal`` parser (verbs wired in from :data:`VERBS`) and :func:`main`: errors, ``--debug``, ``--json``."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
import traceback
from collections.abc import Iterable, Sequence

from camcal import __version__
from camcal.base.errors import CamcalError
from camcal.base.extras import missing_extra
from camcal.base.native_log import OPENCV_LOG_ERROR, set_opencv_log_level
from camcal.cli.options import CamcalParser, UsageError
from camcal.cli.summary import EXIT_BAD_INPUT, EXIT_INTERNAL, VerbSummary

__all__ = ["VERBS", "build_parser", "leaf_parsers", "main"]

#: verb -> (its module under camcal.cli, its line in ``camcal --help``). The only place verbs are wired in;
#: a verb's module is imported only when that verb runs (or all of them, for :func:`build_parser` ``()``).
VERBS: dict[str, tuple[str, str]] = {
    "rig": ("rig", "inspect rig files; export them to and import them from other tools"),
    "calibrate": ("calibrate", "calibrate cameras from targets or correspondences"),
    "lens": ("lens", "a camera at any focal length and focus distance of a lens profile, or per frame"),
    "distortion": ("distortion", "lens distortion from straight lines"),
    "undistort": ("undistort", "undistort images of a rig camera"),
    "stmap": ("stmap", "undistort/redistort ST-maps (EXR) for comp packages"),
    "sigma": ("sigma", "per-pixel projection uncertainty (EXR) of a calibrated camera"),
    "rectify": ("rectify", "rectify 2 or N views (calibrated, N-view refined, or Hartley from matches)"),
    "solve": ("solve", "cameras from images: pycolmap structure from motion + camcal bundle adjustment"),
    "blender": ("blender", "Blender hand-off (needs the bpy module: camcal[blender])"),
    "colour": ("colour", "colour characterisation: fit camera RGB to XYZ"),
    "batch": ("batch", "undistort / rectify / colour-correct a plate sequence on Dask"),
    "demo": ("demo", "the whole pipeline on a stereo rig it renders with Blender, with an HTML report"),
}


def build_parser(verbs: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser; ``verbs`` (default: every verb) get their options, the others only their name.

    Each verb's module fills its parser with ``register(parser)`` and sets
    ``func`` (the handler: parsed namespace in, exit code out) on every leaf.
    Every leaf verb gets ``--json`` and ``--debug`` here, so a verb a module
    registers has them without asking.
    """
    wanted = set(VERBS if verbs is None else verbs)
    parser = CamcalParser(
        prog="camcal",
        description="Geometric and colour camera calibration for VFX pipelines.",
        epilog="Exit status: 0 done, 1 internal error (or a verb's own partial failure), 2 bad input.",
    )
    parser.add_argument("--version", action="version", version=f"camcal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB")
    subparsers.required = True
    for name, (module, help_line) in VERBS.items():
        verb = subparsers.add_parser(name, help=help_line)
        if name not in wanted:
            continue
        importlib.import_module(f"camcal.cli.{module}").register(verb)
        for path, leaf in leaf_parsers(verb, (name,)):
            leaf.add_argument("--json", action="store_true",
                              help="print the summary's figures and written files as one JSON object on stdout")
            leaf.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                              help="show the traceback of an internal error")
            leaf.set_defaults(_verb=" ".join(path))
    return parser


def leaf_parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """``(verb path, parser)`` of every leaf verb below ``parser``."""
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not actions:
        yield path, parser
        return
    for name, sub in actions[0].choices.items():
        yield from leaf_parsers(sub, path + (name,))


def _user_error(error: BaseException, verb: str) -> str | None:
    """The one line for a user's mistake (or a missing extra), or None for an internal error."""
    missing = missing_extra(error)
    if missing is not None:
        return missing.line(f"camcal {verb}")
    if isinstance(error, CamcalError):
        return str(error)
    if isinstance(error, OSError) and error.filename is not None:
        reason = error.strerror or error.__class__.__name__
        return f"{error.filename}: {reason}"
    if isinstance(error, UnicodeDecodeError):
        return f"a file is not text in the expected encoding ({error.reason} at byte {error.start})"
    return None


def _quiet_opencv() -> None:
    """No OpenCV log line below ERROR (its ``[ WARN:0@0.4] ... imread_`` would precede camcal's own message).

    ``OPENCV_LOG_LEVEL`` is read at OpenCV's first log line (a user's own
    setting is kept); when ``cv2`` is imported already, its level is set.
    """
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and os.environ["OPENCV_LOG_LEVEL"] == "ERROR":
        set_opencv_log_level(cv2, OPENCV_LOG_ERROR)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code.

    A malformed command line returns 2 after two lines on stderr,
    ``camcal <verb>: error: <reason>`` and ``see 'camcal <verb> --help'``
    (``--json``: the summary's ``error`` is the reason); ``--help`` and
    ``--version`` exit through ``SystemExit(0)`` as argparse does.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    _quiet_opencv()
    verb = next((a for a in argv if not a.startswith("-")), None)  # the top level has no option with a value
    parser = build_parser([verb] if verb in VERBS else [])
    debug = "--debug" in argv
    want_json = "--json" in argv
    summary = VerbSummary(verb or "camcal")
    stdout = sys.stdout
    code = EXIT_BAD_INPUT
    error_line = None
    try:
        args = parser.parse_args(argv)
        debug, want_json = bool(getattr(args, "debug", False)), bool(getattr(args, "json", False))
        summary.verb = args._verb
        summary.warnings.extend(getattr(args, "_deprecated", ()))
        args._summary = summary
        with contextlib.redirect_stdout(sys.stderr) if want_json else contextlib.nullcontext():
            code = int(args.func(args) or 0)
    except KeyboardInterrupt:
        error_line, code = "interrupted", 130
        print("camcal: interrupted", file=sys.stderr)
    except UsageError as error:
        prog = error.prog or f"camcal {summary.verb}"
        summary.verb = prog.removeprefix("camcal").strip() or "camcal"
        error_line, code = str(error), EXIT_BAD_INPUT
        print(f"{prog}: error: {error}\nsee '{prog} --help'", file=sys.stderr)
    except Exception as error:  # noqa: BLE001 - the one place every error becomes one line
        user = _user_error(error, summary.verb)
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
        print(summary.to_json(code, error_line), file=stdout)
    return code
