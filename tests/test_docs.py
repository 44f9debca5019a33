"""README.md and docs/: every command and snippet runs, the generated files are current, no internal words.

Fenced ``sh`` and ``python`` blocks run as a user would type them: the shell
ones with ``bash -e`` (``camcal`` on the PATH), the Python ones as scripts, in
order, in a folder holding the small board set shipped in tests/data/boards
(seven views :func:`write_board_set` renders through a known camera). An HTML
comment on the line before a block says how it runs:

- none: a fast test runs it (the README's quick start among them);
- ``<!-- docs-test: slow -->``: a slow test (colour fits, Blender), after the fast blocks;
- ``<!-- docs-test: demo -->``: a slow test after ``camcal demo`` (shell blocks from the folder above
  ``demo_out``, Python blocks in it);
- ``<!-- docs-test: skip (reason) -->``: not run, for the reason given.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli.docs import command_reference, help_pages
from camcal.model.rig import Rig
from camcal.synthetic_boards import board_homography, render_board_view
from user_text import internal_references

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUNNABLE = {"sh": "shell", "bash": "shell", "python": "python"}
NOT_RUN = {"json", "text"}  # data and help output, shown not run
MARKER = re.compile(r"<!-- docs-test: (?P<kind>\w+)(?P<reason>.*?)-->")

#: The board set the quick start runs on (what `write_board_set` writes) and its camera: what it must recover.
BOARD_SET = ROOT / "tests" / "data" / "boards"
BOARD = (9, 6, 0.03)  # inner corners, square size (m): `chessboard:9x6:0.03`
FOCAL_PX, CENTRE_PX, IMAGE_SIZE, LAMBDA = 700.0, (322.0, 236.0), (640, 480), -4e-7
#: (tilt, tilt axis, roll) in degrees of each view: tilts about varied axes determine the principal point.
#: Seven views: under eight, `--model auto` ranks the lens models but neither a board surface nor a correction
#: field (they need eight training views), which keeps the quick start fast.
VIEWS = ((35, 0, 0), (35, 90, 5), (35, 180, -5), (35, 270, 10), (25, 45, -10), (25, 135, 0), (25, 225, 15))


@dataclass(frozen=True)
class Block:
    """One fenced block of a document."""

    path: Path
    line: int
    language: str
    kind: str  # "fast", "slow", "demo" or "skip"
    reason: str
    text: str

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def fenced_blocks(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown file, with the docs-test marker of the line before each."""
    lines = path.read_text().splitlines()
    blocks, index = [], 0
    while index < len(lines):
        line = lines[index]
        if line.startswith("```"):
            language = line[3:].strip().split(" ")[0]
            end = next(i for i in range(index + 1, len(lines)) if lines[i].startswith("```"))
            before = next((lines[i] for i in range(index - 1, -1, -1) if lines[i].strip()), "")
            marker = MARKER.search(before)
            kind = marker["kind"] if marker else "fast"
            reason = marker["reason"].strip() if marker else ""
            blocks.append(Block(path, index + 1, language, kind, reason, "\n".join(lines[index + 1:end]) + "\n"))
            index = end
        index += 1
    return blocks


ALL_BLOCKS = [block for path in DOCUMENTS for block in fenced_blocks(path)]


def write_board_set(folder: Path) -> None:
    """Seven 640x480 views of a 9x6 chessboard through a division lens, rendered with exact corners (seeded)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    columns, rows, _ = BOARD
    for number, (tilt, axis, roll) in enumerate(VIEWS, start=1):
        H = board_homography(IMAGE_SIZE, columns, rows, 38.0, tilt_deg=tilt, tilt_axis_deg=axis, roll_deg=roll,
                             centre_px=CENTRE_PX, focal_px=FOCAL_PX)
        view = render_board_view(rng, IMAGE_SIZE, H, columns, rows, 0.7, distortion=LAMBDA,
                                 distortion_centre=CENTRE_PX, jpeg_quality=None)
        cv2.imwrite(str(folder / f"board{number:02d}.png"), view.image)


def _environment(bin_dir: Path) -> dict[str, str]:
    """``camcal`` on the PATH as this interpreter's ``python -m camcal``, this checkout importable."""
    bin_dir.mkdir(exist_ok=True)
    wrapper = bin_dir / "camcal"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m camcal "$@"\n')
    wrapper.chmod(0o755)
    env = dict(os.environ)
    env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def run_block(block: Block, folder: Path, env: dict[str, str], python: str | Path = sys.executable) -> None:
    """Run one block in ``folder`` (Python blocks with ``python``); a failure names the block and shows its output."""
    if RUNNABLE[block.language] == "shell":
        command = ["bash", "-e", "-o", "pipefail", "-c", block.text]
    else:
        script = folder / f"snippet_{block.path.stem}_{block.line}.py"
        script.write_text(block.text)
        command = [str(python), str(script)]
    run = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, f"{block.where} failed ({run.returncode}):\n{block.text}\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    assert "is deprecated, use" not in run.stderr, f"{block.where} uses a former option spelling:\n{run.stderr}"


def _runnable(path: Path, kinds: tuple[str, ...]) -> list[Block]:
    return [b for b in ALL_BLOCKS if b.path == path and b.kind in kinds and b.language in RUNNABLE]


def quick_start_blocks() -> list[Block]:
    """The README's blocks a fast test runs, in order: the quick start, on the board set in ``boards/``."""
    return _runnable(ROOT / "README.md", ("fast",))


@pytest.fixture(scope="module")
def quick_start(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """A folder with the board set where the README's fast blocks (the quick start) have run."""
    folder = tmp_path_factory.mktemp("quick_start")
    shutil.copytree(BOARD_SET, folder / "boards")
    env = _environment(tmp_path_factory.mktemp("bin"))
    for block in quick_start_blocks():
        run_block(block, folder, env)
    return folder, env


# -- the blocks ------------------------------------------------------------------------------


def test_readme_quick_start_recovers_the_board_sets_camera(quick_start):
    """The README's quick start as written, on the shipped board set: the camera it renders comes back."""
    check_quick_start_outputs(quick_start[0])


def check_quick_start_outputs(folder: Path) -> None:
    """What the README's quick start wrote in ``folder``: the board set's camera, every file it names."""
    camera = Rig.load(folder / "cam.rig.json").camera("cam")
    assert camera.K[0, 0] == pytest.approx(FOCAL_PX, rel=3e-3) and camera.K[1, 1] == pytest.approx(FOCAL_PX, rel=3e-3)
    assert np.hypot(*(camera.K[:2, 2] - CENTRE_PX)) < 1.0
    assert camera.quality["rms_px"] < 0.1
    # the lens it chose undoes the rendered one: a frame corner goes where the division lens put it
    corner = np.array([[5.0, 5.0]])
    centre = np.asarray(CENTRE_PX)
    radius2 = float(np.sum((corner - centre) ** 2))
    truth = centre + (corner - centre) / (1 + LAMBDA * radius2)
    assert np.abs(camera.distortion.undistort(corner, camera.K) - truth).max() < 0.5
    # the undistorted image, ST-maps, exports and the Python snippet's rig were all written
    assert (folder / "undistorted" / "board01.png").is_file()
    assert any((folder / "stmaps").iterdir())
    # the README's Python calls give the command's camera (same defaults, same inputs)
    python_rig = Rig.load(folder / "cam_python.rig.json").camera("cam")
    np.testing.assert_allclose(python_rig.K, camera.K, rtol=1e-9)
    assert python_rig.distortion.model == camera.distortion.model
    assert (folder / "undistorted_python" / "board01.png").is_file() and (folder / "cam_python.nk").is_file()


@pytest.mark.parametrize("path", [p for p in DOCUMENTS[1:] if _runnable(p, ("fast",))], ids=lambda p: p.name)
def test_docs_fast_blocks_run(path, quick_start, tmp_path):
    """docs/*.md blocks without a marker run after the quick start (they use its files)."""
    folder, env = quick_start
    work = tmp_path / "work"
    shutil.copytree(folder, work)
    for block in _runnable(path, ("fast",)):
        run_block(block, work, env)


@pytest.mark.slow
def test_readme_slow_blocks_run(quick_start, tmp_path):
    """The README's colour and Blender blocks, on a raw chart capture synthesised from measured sensitivities."""
    sys.path.insert(0, str(ROOT / "tests" / "colour" / "chart"))
    sys.path.insert(0, str(ROOT / "tests" / "io"))
    from raw_chart_scenes import write_raw_chart  # noqa: PLC0415

    from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: PLC0415

    folder, env = quick_start
    work = tmp_path / "work"
    shutil.copytree(folder, work)
    write_raw_chart(work / "chart_d65.dng", SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65"))
    for block in _runnable(ROOT / "README.md", ("slow",)):
        run_block(block, work, env)
    fit = json.loads((work / "cam.colour.json").read_text())
    assert fit["evaluation"]["loo"]["mean"] < 1.0  # 0.51 on this capture: the chart read, not a lucky pass
    assert (work / "ocio" / "config.ocio").is_file() and (work / "cam.icc").stat().st_size > 0
    assert (work / "cam.blend").is_file()


@pytest.mark.slow
def test_demo_blocks_run(tmp_path):
    """Every block marked demo, in README and docs/, after the demo ``make demo`` runs (minutes)."""
    env = _environment(tmp_path / "bin")
    subprocess.run([sys.executable, "-m", "camcal", "demo", "--out", "demo_out"], cwd=tmp_path, env=env,
                   check=True, capture_output=True)
    for block in [b for b in ALL_BLOCKS if b.kind == "demo"]:
        run_block(block, tmp_path if RUNNABLE[block.language] == "shell" else tmp_path / "demo_out", env)


# -- what the blocks are -----------------------------------------------------------------------


def test_every_block_is_run_or_says_why_not():
    kinds = {"fast", "slow", "demo", "skip"}
    for block in ALL_BLOCKS:
        assert block.kind in kinds, f"{block.where}: unknown docs-test marker {block.kind!r}"
        assert block.language in RUNNABLE or block.language in NOT_RUN, \
            f"{block.where}: fenced block without a known language ({block.language!r})"
        if block.kind == "skip":
            assert block.reason.startswith("(") and len(block.reason) > 10, f"{block.where}: a skip needs its reason"
    assert sum(b.kind == "fast" and b.language in RUNNABLE for b in ALL_BLOCKS) >= 3


def test_demo_blocks_start_in_the_demo_folder():
    """Shell blocks change into demo_out as a user would; Python blocks run there."""
    for block in ALL_BLOCKS:
        if block.kind == "demo" and RUNNABLE.get(block.language) == "shell":
            assert block.text.lstrip().startswith("cd demo_out"), f"{block.where}: a demo block starts with cd demo_out"


# -- generated files and words ------------------------------------------------------------------


def test_command_reference_is_current():
    """docs/commands.md is generated: `python -m camcal.cli.docs > docs/commands.md`."""
    assert (ROOT / "docs" / "commands.md").read_text() == command_reference()


def test_readme_is_a_quick_start():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    assert "make test" in text  # CI reads the test command from the README


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.name)
def test_documents_hold_no_internal_references(path):
    assert internal_references(path.read_text()) == []


def test_help_pages_hold_no_internal_references():
    pages = dict(help_pages())
    assert "camcal rig show" in pages and "camcal colour fit" in pages
    for command, text in pages.items():
        assert internal_references(text) == [], command


def test_internal_references_are_found():
    """The grep finds what it is for, and leaves ordinary text alone."""
    assert len(internal_references("as issue 27 asks; see #12 and ../shared/data/x.png, /work/main, /root/.cache")) == 5
    assert internal_references("the must-show") and internal_references("read from /tmp/data")
    clean = ('<style>p { color: #222 }</style> <p style="color: #333">0.97 x the best peer</p>; tests/data/real_boards; '
             "../SECURITY.md; &#39;")
    assert internal_references(clean) == []


def test_rig_format_example_conforms_and_loads():
    """The example rig file in docs/rig.md passes the schema and the loader."""
    from camcal.model.rig_schema import validate_rig_dict  # noqa: PLC0415

    example = next(b for b in fenced_blocks(ROOT / "docs" / "rig.md") if b.language == "json")
    data = json.loads(example.text)
    assert validate_rig_dict(data) == []
    assert Rig.from_dict(data).camera("left").distortion.model == "division"
