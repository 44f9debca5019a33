"""What every verb reports: exit codes and the ``--json`` summary (:class:`VerbSummary`)."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from camcal import __version__

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL",
    "SUMMARY_FORMAT",
    "SUMMARY_VERSION",
    "VerbSummary",
    "report_result",
    "summary_of",
]

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
SUMMARY_FORMAT = "camcal.summary"
SUMMARY_VERSION = 1


@dataclass
class VerbSummary:
    """What a verb reports: its figures and the files it wrote (``--json``).

    Handlers fill it with :meth:`figures` and :meth:`wrote`; :func:`camcal.cli.main`
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

    def wrote_each(self, paths: Iterable[str | os.PathLike], kind: str, say: bool = False) -> None:
        """Record several written files of one kind (:meth:`wrote`, silent by default)."""
        for path in paths:
            self.wrote(path, kind, say)

    def report(self, files: list, directory: str | os.PathLike) -> None:
        """Record the files of a ``--report DIR`` and print ``report: N files in DIR``."""
        self.wrote_each(files, "report")
        print(f"report: {len(files)} files in {directory}")

    def warn(self, message: str) -> None:
        """Record and print a warning."""
        self.warnings.append(message)
        print(f"warning: {message}")

    def to_dict(self, exit_code: int, error: str | None = None) -> dict[str, Any]:
        """The versioned JSON object (see :mod:`camcal.cli`)."""
        out: dict[str, Any] = {
            "format": SUMMARY_FORMAT, "version": SUMMARY_VERSION, "camcal": __version__,
            "verb": self.verb, "exit_code": exit_code,
            "figures": self.data, "files": self.files, "warnings": self.warnings,
        }
        if error is not None:
            out["error"] = error
        return out

    def to_json(self, exit_code: int, error: str | None = None) -> str:
        """:meth:`to_dict` as one line of JSON (numpy values, paths and sets converted)."""
        return json.dumps(self.to_dict(exit_code, error), default=_json_default, allow_nan=False)


def summary_of(args: argparse.Namespace) -> VerbSummary:
    """The :class:`VerbSummary` of this run (made by :func:`camcal.cli.main`)."""
    summary = getattr(args, "_summary", None)
    if summary is None:  # a handler called without main(), e.g. from a test
        summary = VerbSummary(getattr(args, "_verb", "camcal"))
        args._summary = summary
    return summary


def report_result(args: argparse.Namespace, result: Any, *, say: bool = True) -> VerbSummary:
    """Print an API result's lines, record its figures and its ``files`` ((path, kind) pairs) in the summary.

    ``say`` also prints ``wrote PATH`` for each file (off where the result's own lines name them).
    """
    for line in result.lines():
        print(line)
    out = summary_of(args)
    out.figures(**result.figures())
    for path, kind in result.files:
        out.wrote(path, kind, say=say)
    return out


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, paths and tuples as JSON."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
