"""The command reference (``docs/commands.md``), generated from the argparse parsers.

``python -m camcal.cli.docs > docs/commands.md`` writes it: every verb's
``--help`` page, in the order of ``camcal --help``, at a fixed width so the
file does not depend on the terminal it is generated in. A test checks that
the committed file is what this prints, so the reference cannot drift from
the command line.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator

from camcal.cli.app import build_parser

__all__ = ["HELP_WIDTH", "command_reference", "help_pages"]

#: Columns the help pages are wrapped at in the reference.
HELP_WIDTH = 100


def help_pages() -> Iterator[tuple[str, str]]:
    """``(command, help text)`` of ``camcal`` and of every verb and verb group below it, depth first."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_WIDTH)  # argparse's formatter reads the width from the environment
    try:
        yield from _walk(build_parser())
    finally:
        if previous is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = previous


def _walk(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str]]:
    yield parser.prog, parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _walk(sub)


def command_reference() -> str:
    """The Markdown text of ``docs/commands.md``."""
    pages = list(help_pages())
    lines = [
        "# Command reference",
        "",
        "Every `camcal` command's `--help`, generated from the command line itself",
        "(`python -m camcal.cli.docs > docs/commands.md`; a test checks this file is current).",
        "",
    ]
    lines += [f"- [`{command}`](#{_anchor(command)})" for command, _ in pages]
    for command, text in pages:
        lines += ["", f"## {command}", "", "```text", text.rstrip(), "```"]
    return "\n".join(lines) + "\n"


def _anchor(command: str) -> str:
    """GitHub's anchor of a ``## command`` heading: lower case, spaces to hyphens."""
    return command.lower().replace(" ", "-")


if __name__ == "__main__":
    print(command_reference(), end="")
