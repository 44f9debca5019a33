"""The options several verbs share, written once: NAME=VALUE camera specs and globs, rig, out, report, holdout.

A verb module adds a shared option with the function named after it
(``out_option(parser, "FILE.rig.json")``), so one option is spelled, typed
and checked the same in every verb that has it. Every parser is a
:class:`CamcalParser`: a usage error is one line naming the verb plus a
``--help`` hint (:class:`UsageError`), checks added with :func:`after_parsing`
run once the verb's options are parsed (:func:`only_with`: a flag that has
no effect without another is an error), and :func:`deprecated_option` keeps
a former spelling working with a one-line note.
"""

from __future__ import annotations

import argparse
import inspect
import sys
from collections.abc import Callable, Sequence

from camcal.base.atomic import output_folder
from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import parse_holdout
from camcal.base.globs import expand_glob

__all__ = [
    "ADAPTATION",
    "ADAPTATIONS",
    "LOSSES",
    "OVERSCAN",
    "CamcalParser",
    "HelpFormatter",
    "NamedValues",
    "UsageError",
    "adaptation_option",
    "after_parsing",
    "cache_options",
    "camera_label_option",
    "corner_cache",
    "camera_option",
    "deprecated_option",
    "distance_option",
    "every_option",
    "expand_glob",
    "handler",
    "images_option",
    "image_size",
    "image_size_option",
    "loss_option",
    "max_fov_option",
    "name_value",
    "named_option",
    "note_deprecated",
    "only_with",
    "out_option",
    "output_folder",
    "parse_holdout",
    "report_option",
    "rig_argument",
    "sigma_options",
    "undistort_mode_options",
    "verb_group",
]

#: Robust losses of the bundle adjustments (Ceres' names).
LOSSES = ("trivial", "huber", "soft_l1", "cauchy")


class UsageError(CamcalError):
    """A malformed command line: ``str()`` is the reason, ``prog`` the verb's ``camcal ...`` (None: unknown).

    :func:`camcal.cli.main` prints it as ``camcal <verb>: error: <reason>``
    and ``see 'camcal <verb> --help'`` and exits 2; with ``--json`` the
    summary's ``error`` holds the reason.
    """

    def __init__(self, reason: str, prog: str | None = None) -> None:
        super().__init__(reason)
        self.prog = prog


class HelpFormatter(argparse.HelpFormatter):
    """argparse's, filling the description and epilog paragraph by paragraph.

    The ``examples:`` paragraph and tables (a paragraph with columns, two
    spaces in a row) are kept line by line.
    """

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        fill = super()._fill_text
        return "\n\n".join(paragraph if paragraph.startswith("examples:") or "  " in paragraph
                           else fill(paragraph, width, indent) for paragraph in text.split("\n\n"))


class CamcalParser(argparse.ArgumentParser):
    """argparse's parser, with a one-line :class:`UsageError` instead of the usage dump, and checks after parsing.

    ``error`` raises :class:`UsageError` (argparse calls it for a missing or
    malformed option); ``parse_known_args`` runs the checks
    :func:`after_parsing` added on this parser, in order, on its namespace
    (a verb's subparser parses into a namespace of its own, so a check sees
    that verb's options). Sub-verbs' parsers are of the same class. With
    ``loose_files`` set to an attribute name, the arguments left over that
    are not options are put there (a list) instead of being unrecognised.
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self.checks: list[Callable[[CamcalParser, argparse.Namespace], None]] = []
        self.loose_files: str | None = None

    def error(self, message: str):
        raise UsageError(message, self.prog)

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        if self.loose_files is not None:  # (not beside an unknown option: "--bogus 3" is one mistake)
            claimed = [] if any(arg.startswith("-") for arg in extras) else extras
            setattr(namespace, self.loose_files, claimed)
            extras = [] if claimed else extras
        for check in self.checks:
            check(self, namespace)
        return namespace, extras

    def parse_args(self, args=None, namespace=None):
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:  # named after the leaf verb, not the top-level parser that collects them
            verb = getattr(namespace, "_verb", None)
            prog = f"{self.prog} {verb}" if verb else self.prog
            raise UsageError(f"unrecognized arguments: {' '.join(extras)}", prog)
        return namespace


def after_parsing(parser: argparse.ArgumentParser, check: Callable[[CamcalParser, argparse.Namespace], None]) -> None:
    """Run ``check(parser, namespace)`` once ``parser`` has parsed its options (it may fill values or raise)."""
    parser.checks.append(check)


def _action(parser: argparse.ArgumentParser, option: str) -> argparse.Action:
    return next(a for a in parser._actions if option in a.option_strings)


def only_with(parser: argparse.ArgumentParser, option: str, needs: str, holds: Callable[[argparse.Namespace], bool],
              default=None) -> None:
    """``option`` has no effect unless ``needs`` holds: given without it, a usage error naming both.

    ``option`` must be added with a default of ``None`` (or ``False`` for a
    flag), so that giving it is seen; ``default`` is then filled in when it
    is not given (state it in the option's help).
    """
    dest = _action(parser, option).dest

    def check(parser: CamcalParser, namespace: argparse.Namespace) -> None:
        value = getattr(namespace, dest)
        if value is None or value is False:
            if default is not None:
                setattr(namespace, dest, default)
        elif not holds(namespace):
            parser.error(f"{option} has no effect without {needs}")

    after_parsing(parser, check)


def deprecated_option(parser: argparse.ArgumentParser, old: str, new: str, **kwargs) -> None:
    """``old``, a former spelling of the option ``new``: still accepted, hidden from ``--help``.

    ``kwargs`` are ``new``'s (same ``dest``, action and type). Each use
    prints one line ``camcal <verb>: warning: OLD is deprecated, use NEW``
    on stderr; :func:`camcal.cli.main` also lists it in the ``--json``
    summary's warnings.
    """
    action = kwargs.pop("action", "store")
    base = parser._registry_get("action", action, action)

    class Deprecated(base):
        def __call__(self, parser, namespace, values, option_string=None) -> None:
            note_deprecated(parser, namespace, f"{option_string} is deprecated, use {new}")
            super().__call__(parser, namespace, values, option_string)

    parser.add_argument(old, action=Deprecated, help=argparse.SUPPRESS, **kwargs)


def note_deprecated(parser: argparse.ArgumentParser, namespace: argparse.Namespace, note: str) -> None:
    """Print ``camcal <verb>: warning: <note>`` once on stderr; :func:`camcal.cli.main` puts it in the summary."""
    if note not in getattr(namespace, "_deprecated", ()):
        print(f"{parser.prog}: warning: {note}", file=sys.stderr)
        namespace._deprecated = [*getattr(namespace, "_deprecated", ()), note]


def images_option(parser: argparse.ArgumentParser, metavar: str, help: str, required: bool = True) -> None:
    """``--images FILE ...``: a one-camera verb's input files (repeatable; the former positional files still work).

    Files given without ``--images`` are added to them with a deprecation
    note; ``required``: a usage error when there are none.
    """
    parser.add_argument("--images", nargs="+", action="extend", default=[], metavar=metavar, help=help)
    parser.loose_files = "_loose_files"

    def merge(parser: CamcalParser, namespace: argparse.Namespace) -> None:
        positional = namespace.__dict__.pop("_loose_files")
        if positional:
            note_deprecated(parser, namespace, "image files without --images are deprecated, use --images FILE ...")
            namespace.images = [*namespace.images, *positional]
        if required and not namespace.images:
            parser.error("the following arguments are required: --images")

    after_parsing(parser, merge)


def handler(parser: argparse.ArgumentParser, run, examples: Sequence[str], notes: Sequence[str] = ()) -> None:
    """``run`` handles the verb (parsed namespace in, exit code out); its docstring is the verb's ``--help``.

    The docstring's first paragraph is printed before the options (the
    description), the rest after them (the epilog), then ``notes`` (more
    paragraphs, e.g. a table), so the help says what the function that runs
    the verb does, in its words. The help ends with ``examples``: command
    lines (``camcal <verb> ...``, parsed by the help lint test) and
    ``# comment`` lines above them.
    """
    description, _, epilog = inspect.cleandoc(run.__doc__ or "").partition("\n\n")
    parser.set_defaults(func=run)
    parser.description = description or None
    section = "examples:\n" + "\n".join(f"  {line}" for line in examples)
    parser.epilog = "\n\n".join(filter(None, [epilog, *notes, section]))


def verb_group(parser: argparse.ArgumentParser, dest: str, metavar: str = "VERB"):
    """The sub-verbs of a verb group (``camcal rig show``); one of them is required."""
    verbs = parser.add_subparsers(dest=dest, metavar=metavar)
    verbs.required = True
    return verbs


# -- NAME=VALUE options and globs --------------------------------------------------------


def name_value(entry: str, option: str, form: str) -> tuple[str, str]:
    """Split a ``NAME=VALUE`` option value, or fail naming the option."""
    name, sep, value = entry.partition("=")
    if not sep or not name or not value:
        raise CamcalError(f"{option}: expected {form}, got {entry!r}")
    if not entry.isprintable():
        raise CamcalError(f"{option}: {entry!r} holds a control character (a newline?)")
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
        prog = getattr(parser, "prog", None)
        for entry in values:
            try:
                name, value = name_value(entry, option_string, form)
            except CamcalError as error:
                raise UsageError(str(error), prog) from None
            if name in current:
                raise UsageError(f"{option_string} {entry}: name {name!r} given twice", prog)
            current[name] = value
        setattr(namespace, self.dest, current)


def named_option(parser, option: str, metavar: str, help: str, required: bool = False, dest: str | None = None,
                 old: str | None = None) -> None:
    """A :class:`NamedValues` option such as ``--images NAME=GLOB``; ``old``: its former spelling, deprecated."""
    dest = dest or option.lstrip("-").replace("-", "_")
    parser.add_argument(option, dest=dest, required=required and old is None, action=NamedValues, metavar=metavar,
                        help=help)
    if old is None:
        return
    deprecated_option(parser, old, option, dest=dest, action=NamedValues, metavar=metavar)
    if required:
        def given(parser: CamcalParser, namespace: argparse.Namespace) -> None:
            if not getattr(namespace, dest):
                parser.error(f"the following arguments are required: {option}")

        after_parsing(parser, given)


# -- rigs, cameras, files written --------------------------------------------------------


def rig_argument(parser, help: str = "a *.rig.json file", metavar: str = "RIG", **kwargs) -> None:
    """The positional rig file (``RIG``)."""
    parser.add_argument("rig", metavar=metavar, help=help, **kwargs)


def camera_option(parser) -> None:
    """``--camera NAME``: the one rig camera a verb works on."""
    parser.add_argument("--camera", required=True, metavar="NAME", help="the rig camera to use (its name in RIG)")


def camera_label_option(parser, help: str = "camera name recorded in the file (default: none)") -> None:
    """``--camera-name NAME``: the camera name a colour verb records in its file (``--camera``: deprecated)."""
    parser.add_argument("--camera-name", dest="camera", default=None, metavar="NAME", help=help)
    deprecated_option(parser, "--camera", "--camera-name", dest="camera", metavar="NAME")


def out_option(parser, metavar: str, help: str) -> None:
    """``--out``: the file or folder a verb writes (required)."""
    parser.add_argument("--out", required=True, metavar=metavar, help=help)


def report_option(parser, help: str) -> None:
    """``--report DIR``: figures and plots beside the result."""
    parser.add_argument("--report", metavar="DIR", help=help)


def image_size_option(parser, help: str | None = None, required: bool = False) -> None:
    """``--image-size W H`` (checked with :func:`image_size`)."""
    parser.add_argument("--image-size", required=required, nargs=2, type=int, metavar=("W", "H"), help=help)


def image_size(value: Sequence[int]) -> tuple[int, int]:
    """``--image-size W H`` as ``(width, height)``, both positive."""
    width, height = value
    if width <= 0 or height <= 0:
        raise CamcalError(f"--image-size must be two positive integers, got {width} {height}")
    return width, height


#: ``--overscan``'s default: the canvas of an undistorted plate, as a factor of the plate.
OVERSCAN = 1.1


def undistort_mode_options(parser, mode_help: str, needs: str | None = None,
                           holds: Callable[[argparse.Namespace], bool] | None = None) -> None:
    """``--mode crop|keep|overscan`` and ``--overscan`` (only with ``--mode overscan``): the new pinhole camera.

    ``needs`` / ``holds``: ``--mode`` has no effect without ``needs`` (:func:`only_with`).
    """
    parser.add_argument("--mode", choices=("crop", "keep", "overscan"), default=None if needs else "crop",
                        help=mode_help)
    if needs:
        only_with(parser, "--mode", needs, holds, default="crop")
    parser.add_argument("--overscan", type=float, default=None, metavar="FACTOR",
                        help=f"with --mode overscan: the canvas as a factor of the plate (default: {OVERSCAN})")
    only_with(parser, "--overscan", "--mode overscan", lambda args: args.mode == "overscan", default=OVERSCAN)


def distance_option(parser) -> None:
    """``--distance D``: where along the rays projection uncertainty is taken (rig units; default infinity)."""
    parser.add_argument("--distance", type=_positive_float, default=None, metavar="D",
                        help="distance along the rays in the rig's units (default: infinity)")


def sigma_options(parser, what: str) -> None:
    """``--sigma`` (a projection-sigma EXR beside the outputs) and its ``--distance``."""
    parser.add_argument("--sigma", action="store_true", help=f"also write {what}")
    distance_option(parser)
    only_with(parser, "--distance", "--sigma", lambda args: args.sigma)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


#: Chromatic adaptation transforms (von Kries, colour-science's names) and the one default every verb uses:
#: Bradford, as OpenColorIO's ACES configs and ICC profiles (ICC.1:2010, Annex E) adapt.
ADAPTATIONS = ("Bradford", "CAT02")
ADAPTATION = "Bradford"


def adaptation_option(parser, what: str, needs: str, holds: Callable[[argparse.Namespace], bool],
                      dest: str = "adaptation", old: str | None = None) -> None:
    """``--adaptation Bradford|CAT02``: the chromatic adaptation ``what``, only with ``needs`` (:func:`only_with`).

    ``old``: a former spelling, deprecated (:func:`deprecated_option`).
    """
    parser.add_argument("--adaptation", dest=dest, choices=ADAPTATIONS, default=None,
                        help=f"chromatic adaptation {what}: {' or '.join(ADAPTATIONS)} (default: {ADAPTATION})")
    if old is not None:
        deprecated_option(parser, old, "--adaptation", dest=dest, choices=ADAPTATIONS)
    only_with(parser, "--adaptation", needs, holds, default=ADAPTATION)


def max_fov_option(parser, help: str) -> None:
    """``--max-fov DEG``: the widest angle a pinhole output holds."""
    parser.add_argument("--max-fov", type=float, metavar="DEG", help=help)


def every_option(parser) -> None:
    """``--every N``: of a video given for a camera's images, every N-th frame (0, N, 2N...)."""
    parser.add_argument("--every", type=int, default=1, metavar="N",
                        help="videos (.mp4 .mov .avi .mkv, streamed): every N-th frame (frames 0, N, 2N...; default 1)")


def cache_options(parser) -> None:
    """``--cache DIR`` / ``--no-cache``: the corner cache of the board-detecting verbs (read by :func:`corner_cache`)."""
    parser.add_argument("--cache", metavar="DIR",
                        help="corner cache directory, keyed by image content and detector settings "
                        "(default: $XDG_CACHE_HOME/camcal/corners)")
    parser.add_argument("--no-cache", action="store_true", help="detect again, do not read or write the cache")


def corner_cache(args) -> str | bool:
    """The API's ``cache`` argument from :func:`cache_options`: False, a directory, or True (the default one)."""
    return False if args.no_cache else (args.cache or True)


def loss_option(parser, help: str) -> None:
    """``--loss``: the robust loss of a bundle adjustment (:data:`LOSSES`)."""
    parser.add_argument("--loss", default="trivial", choices=LOSSES, help=help)
