"""The options several verbs share, written once: NAME=VALUE camera specs and globs, rig, out, report, holdout.

A verb module adds a shared option with the function named after it
(``out_option(parser, "FILE.rig.json")``), so one option is spelled, typed
and checked the same in every verb that has it.
"""

from __future__ import annotations

import argparse
import inspect
from collections.abc import Sequence

from camcal.base.atomic import output_folder
from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import parse_holdout
from camcal.base.globs import expand_glob

__all__ = [
    "LOSSES",
    "NamedValues",
    "camera_label_option",
    "camera_option",
    "distance_option",
    "every_option",
    "expand_glob",
    "handler",
    "image_size",
    "image_size_option",
    "loss_option",
    "max_fov_option",
    "name_value",
    "named_option",
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


def handler(parser: argparse.ArgumentParser, run) -> None:
    """``run`` handles the verb (parsed namespace in, exit code out); its docstring is the verb's ``--help``.

    The docstring's first paragraph is printed before the options (the
    description), the rest after them (the epilog), so the help says what
    the function that runs the verb does, in its words.
    """
    description, _, epilog = inspect.cleandoc(run.__doc__ or "").partition("\n\n")
    parser.set_defaults(func=run)
    parser.description = description or None
    parser.epilog = epilog or None


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
        for entry in values:
            name, value = name_value(entry, option_string, form)
            if name in current:
                raise CamcalError(f"{option_string} {entry}: name {name!r} given twice")
            current[name] = value
        setattr(namespace, self.dest, current)


def named_option(parser, option: str, metavar: str, help: str, required: bool = False) -> None:
    """A :class:`NamedValues` option such as ``--camera NAME=GLOB``."""
    parser.add_argument(option, required=required, action=NamedValues, metavar=metavar, help=help)


# -- rigs, cameras, files written --------------------------------------------------------


def rig_argument(parser, help: str = "a *.rig.json file", metavar: str = "RIG", **kwargs) -> None:
    """The positional rig file (``RIG``)."""
    parser.add_argument("rig", metavar=metavar, help=help, **kwargs)


def camera_option(parser) -> None:
    """``--camera NAME``: the one rig camera a verb works on."""
    parser.add_argument("--camera", required=True, metavar="NAME")


def camera_label_option(parser) -> None:
    """``--camera NAME``: the camera name a colour verb records in its file."""
    parser.add_argument("--camera", default=None, help="camera name recorded in the file")


def out_option(parser, metavar: str, help: str | None = None) -> None:
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


def undistort_mode_options(parser, mode_help: str) -> None:
    """``--mode crop|keep|overscan`` and ``--overscan``: the pinhole camera an undistortion makes."""
    parser.add_argument("--mode", choices=("crop", "keep", "overscan"), default="crop", help=mode_help)
    parser.add_argument("--overscan", type=float, default=1.1, help="canvas factor for --mode overscan")


def distance_option(parser) -> None:
    """``--distance D``: where along the rays projection uncertainty is taken (rig units; default infinity)."""
    parser.add_argument("--distance", type=_positive_float, default=None, metavar="D",
                        help="distance along the rays in the rig's units (default: infinity)")


def sigma_options(parser, what: str) -> None:
    """``--sigma`` (a projection-sigma EXR beside the outputs) and its ``--distance``."""
    parser.add_argument("--sigma", action="store_true", help=f"also write {what}")
    distance_option(parser)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def max_fov_option(parser, help: str) -> None:
    """``--max-fov DEG``: the widest angle a pinhole output holds."""
    parser.add_argument("--max-fov", type=float, metavar="DEG", help=help)


def every_option(parser) -> None:
    """``--every N``: of a video given for a camera's images, every N-th frame (0, N, 2N...)."""
    parser.add_argument("--every", type=int, default=1, metavar="N",
                        help="videos (.mp4 .mov .avi .mkv, streamed): every N-th frame (frames 0, N, 2N...; default 1)")


def loss_option(parser, help: str) -> None:
    """``--loss``: the robust loss of a bundle adjustment (:data:`LOSSES`)."""
    parser.add_argument("--loss", default="trivial", choices=LOSSES, help=help)
