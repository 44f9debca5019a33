"""Help lint: every option of every verb has help stating its default, and every verb's help ends with examples that
parse with the verb's own parser."""

import argparse
import shlex

import pytest

from camcal.cli import build_parser
from camcal.cli.app import leaf_parsers

PARSER = build_parser()
LEAVES = {" ".join(path): leaf for path, leaf in leaf_parsers(PARSER)}


def _no_default(value) -> bool:
    """None, False, SUPPRESS, an empty list or dict (by identity and type: 0 is a default to state)."""
    return value is None or value is False or value is argparse.SUPPRESS or (type(value) in (list, dict) and not value)


def _options(leaf: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options and positionals a user sees (not --help, not a hidden former spelling)."""
    return [action for action in leaf._actions
            if not isinstance(action, argparse._HelpAction) and action.help is not argparse.SUPPRESS]


def _stated(default) -> tuple[str, ...]:
    """The ways a default may be written: 1.1, 0.2, 1 (for 1.0), D50."""
    if isinstance(default, float):
        return (str(default), f"{default:g}")
    return (str(default),)


def examples(leaf: argparse.ArgumentParser) -> list[str]:
    """The command lines of the verb's ``examples:`` section (a line may continue a quoted ``camcal`` line)."""
    epilog = leaf.epilog or ""
    _, found, section = epilog.rpartition("examples:\n")
    assert found, "no examples section"
    return [line.strip() for line in section.splitlines() if line.strip().startswith("camcal ")]


def test_every_leaf_verb_is_linted():
    assert len(LEAVES) >= 18 and {"calibrate board", "undistort", "colour export", "rig import"} <= set(LEAVES)


@pytest.mark.parametrize("verb", LEAVES)
def test_every_option_has_help_with_its_default(verb):
    leaf = LEAVES[verb]
    formatter = leaf._get_formatter()
    problems = []
    for action in _options(leaf):
        name = "/".join(action.option_strings) or action.dest
        if not (action.help and action.help.strip()):
            problems.append(f"{name}: no help")
        elif not (_no_default(action.default) or isinstance(action, argparse._StoreTrueAction)):
            text = formatter._expand_help(action)
            if not ("default" in text and any(value in text for value in _stated(action.default))):
                problems.append(f"{name}: default {action.default!r} not stated in {text!r}")
    assert problems == [], f"camcal {verb}"


@pytest.mark.parametrize("verb", LEAVES)
def test_help_ends_with_examples_that_parse(verb, capsys):
    leaf = LEAVES[verb]
    lines = examples(leaf)
    assert lines, f"camcal {verb}: an empty examples section"
    help_text = leaf.format_help()
    assert help_text.rstrip().splitlines()[-1].strip().startswith("camcal "), "examples are not the end of the help"
    for line in lines:
        argv = shlex.split(line)
        assert argv[: 1 + len(verb.split())] == ["camcal", *verb.split()], line
        args = PARSER.parse_args(argv[1:])  # parsed only: the handler does not run
        assert args._verb == verb and not getattr(args, "_deprecated", None), line
    assert capsys.readouterr().err == ""  # no deprecation note: examples use today's spellings
