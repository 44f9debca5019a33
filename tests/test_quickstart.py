"""The README's quick start as a new user runs it: a fresh virtual environment, ``pip install`` and the commands as written.

The slow test makes a fresh venv, runs the README's install line (the block
whose skip note names this file) from the checkout, copies the shipped board
set as the README says (``cp -r tests/data/boards .``), runs the README's
quick start (the blocks tests/test_docs.py runs fast) with the venv's
``camcal`` and ``python``, and checks what it wrote: the rig loads, its RMS is
small, the camera the board set was rendered with comes back. Its fast
sibling checks the same text without installing: the install line names
extras pyproject.toml has, every ``camcal`` command parses with camcal's own
parser, every file and glob under ``boards/`` names files of the shipped set,
and that set is the one :func:`test_docs.write_board_set` renders.
"""

from __future__ import annotations

import glob
import re
import shlex
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import build_parser
from fresh_venv import make_venv, run
from test_docs import (BOARD_SET, ROOT, Block, check_quick_start_outputs, fenced_blocks, quick_start_blocks, run_block,
                       write_board_set)

README = ROOT / "README.md"
#: the README's instruction that puts the shipped board set where the quick start looks for it
COPY_BOARDS = "cp -r tests/data/boards ."


def install_block() -> Block:
    """The README's quick-start install line: the block whose skip note names this file."""
    [block] = [b for b in fenced_blocks(README) if b.kind == "skip" and Path(__file__).name in b.reason]
    return block


def _install_extras(block: Block) -> set[str]:
    """The extras of ``pip install ".[a,b]"``, the block's only command."""
    [line] = [line for line in block.text.splitlines() if line.strip() and not line.startswith("#")]
    argv = shlex.split(line, comments=True)
    assert argv[:2] == ["pip", "install"] and len(argv) == 3, line
    match = re.fullmatch(r"\.(?:\[(?P<extras>[\w,-]+)\])?", argv[2])
    assert match, f"{line}: installs something other than this checkout"
    return set(filter(None, (match["extras"] or "").split(",")))


def _distributions(extras: set[str]) -> set[str]:
    """The distributions pyproject.toml's dependencies and these extras install (camcal's own extras expanded)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names, pending = [*project["dependencies"]], list(extras)
    while pending:
        extra = pending.pop()
        assert extra in project["optional-dependencies"], f"pyproject.toml has no extra {extra!r}"
        for requirement in project["optional-dependencies"][extra]:
            if requirement.startswith("camcal["):
                pending += requirement[len("camcal["):requirement.index("]")].split(",")
            else:
                names.append(requirement)
    return {re.match(r"[\w.-]+", name)[0].lower() for name in names}


def _board_paths(blocks: list[Block]) -> set[str]:
    """Every ``boards/...`` path or glob the blocks name."""
    return {match for block in blocks for match in re.findall(r"boards/[\w*?.\[\]-]+", block.text)}


def test_readme_quick_start_names_what_the_install_and_the_shipped_boards_provide(capsys):
    # the install line: this checkout, with extras that exist; `calibrate board --model auto` ranks the
    # lens models with pycolmap's bundle adjustment, which the calibrate extra brings
    assert "pycolmap" in _distributions(_install_extras(install_block()))
    assert README.read_text().count(f"`{COPY_BOARDS}`") == 1
    assert (ROOT / shlex.split(COPY_BOARDS)[2]).is_dir()

    blocks = quick_start_blocks()
    parser = build_parser()
    commands = [line for block in blocks if block.language == "sh"
                for line in (shlex.split(text, comments=True) for text in block.text.splitlines()) if line]
    assert len(commands) >= 3 and all(argv[0] == "camcal" for argv in commands), commands
    for argv in commands:
        args = parser.parse_args(argv[1:])  # parsed only: the handler does not run
        assert not getattr(args, "_deprecated", None), argv
    assert capsys.readouterr().err == ""
    assert ["calibrate", "board"] == commands[0][1:3]

    shipped = sorted(path.name for path in BOARD_SET.glob("*.png"))
    named = _board_paths(blocks)
    assert named, "the quick start names no board image"
    for pattern in named:
        found = sorted(Path(path).name for path in glob.glob(str(BOARD_SET.parent / pattern)))
        assert found, f"{pattern}: no file of {BOARD_SET.relative_to(ROOT)}"
        if "*" in pattern:
            assert found == shipped, f"{pattern} misses some views"


def test_shipped_board_set_is_the_rendered_one(tmp_path):
    """tests/data/boards holds what write_board_set renders (seeded): the truth the quick-start tests compare with."""
    write_board_set(tmp_path)
    rendered = sorted(tmp_path.glob("*.png"))
    assert [p.name for p in rendered] == sorted(p.name for p in BOARD_SET.glob("*.png")) and len(rendered) == 7
    for path in rendered:
        shipped = cv2.imread(str(BOARD_SET / path.name), cv2.IMREAD_UNCHANGED)
        again = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert shipped.shape == again.shape == (480, 640)
        # an OpenCV or NumPy release may round a warped edge pixel differently, not move a corner
        difference = np.abs(shipped.astype(int) - again.astype(int))
        assert difference.max() <= 2 and np.mean(difference > 0) < 1e-3, path.name


@pytest.mark.slow
def test_readme_quick_start_in_a_fresh_venv(tmp_path):
    venv = make_venv(tmp_path / "venv")
    # the install line exactly as written, from the checkout as a clone's user runs it
    run(["bash", "-e", "-c", install_block().text], ROOT, venv.env, check=True)
    assert str(venv.path) in venv.camcal_location()

    work = tmp_path / "work"
    work.mkdir()
    (work / "tests").symlink_to(ROOT / "tests")  # `cp -r tests/data/boards .` as in the clone
    run(["bash", "-e", "-c", COPY_BOARDS], work, venv.env, check=True)
    (work / "tests").unlink()
    for block in quick_start_blocks():
        run_block(block, work, venv.env, python=venv.python)
    check_quick_start_outputs(work)
