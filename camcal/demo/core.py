"""The demo's data: configuration, truth container, rows, stages, report and the CLI runner."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.rig import Rig

__all__ = [
    "COLOUR_EXPORTS_SECTION",
    "DemoConfig",
    "DemoContext",
    "DemoReport",
    "DemoRow",
    "DemoTruth",
    "FULL",
    "OVERSCAN",
    "QUICK",
    "ReportSection",
    "Stage",
    "StageResult",
    "command_line",
    "format_number",
    "run_cli",
]


#: Undistorted render canvas as a multiple of the plate (covers the barrel corners).
OVERSCAN = 1.15
#: Report section (``id``) where the colour export stage links its OCIO config and ICC profiles.
COLOUR_EXPORTS_SECTION = "colour-exports"


# -- results ---------------------------------------------------------------------------


@dataclass(frozen=True)
class DemoRow:
    """One recovered-vs-true comparison and the tolerance it must meet.

    ``error`` is what the tolerance bounds (``ok`` when ``|error| <=
    tolerance``); ``source`` names where the tolerance comes from.
    """

    stage: str
    quantity: str
    true: float
    recovered: float
    error: float
    tolerance: float
    unit: str
    source: str

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.error)) and abs(self.error) <= self.tolerance


@dataclass(frozen=True)
class ReportSection:
    """A titled piece of the HTML report; ``body`` is HTML (images by relative path)."""

    title: str
    body: str
    anchor: str = ""


@dataclass(frozen=True)
class StageResult:
    """What one stage measured, wrote and shows."""

    rows: tuple[DemoRow, ...] = ()
    outputs: tuple[tuple[str, Path], ...] = ()
    sections: tuple[ReportSection, ...] = ()


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo run.

    ``stages`` names the stages to run (in :data:`STAGES` order); a stage
    that needs an artifact of a skipped one fails with a clear error.
    """

    image_size: tuple[int, int] = (640, 480)
    n_board_views: int = 12
    n_scene_positions: int = 7
    samples: int = 32
    colour_model: str = "auto"
    seed: int = 0
    stages: tuple[str, ...] | None = None


#: What ``make demo`` runs.
FULL = DemoConfig()
#: A small real run for the fast tests: 6 board views, 8 samples, no SfM. Its renders are
#: noisier and its views fewer than the tolerances of the synthetic tests assume: the calibration rows
#: of a QUICK run may miss them (the tests check those that hold; ``make demo`` runs FULL).
QUICK = DemoConfig(n_board_views=6, samples=8,
                   stages=("render", "calibrate board", "rig export", "distortion fit", "rectify", "colour fit",
                           "colour match", "colour export", "blender import"))


@dataclass(frozen=True)
class DemoTruth:
    """The known rig and scene.

    Attributes
    ----------
    rig : Rig
        The true cameras (left is the reference) with their distortion;
        ``frames`` are the rig's poses in the room (``rig_from_world``).
    board_spec : str
        The chessboard (``chessboard:9x6:0.04``, metres).
    board_poses : list of (R, t)
        ``X_rig = R X_board + t`` for each chessboard view.
    chart_pose : (R, t)
        The ColorChecker's pose, the same way.
    sensors : dict
        Camera name -> colour-science camera whose sensitivities it has.
    illuminant : str
        The light's CIE name.
    room_extent_m : float
        Side of the room corner's planes (the scene size for ``solve``).
    """

    rig: Rig
    board_spec: str
    board_poses: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    chart_pose: tuple[NDArray[np.float64], NDArray[np.float64]]
    sensors: dict[str, str]
    illuminant: str = "D65"
    room_extent_m: float = 2.5


@dataclass
class DemoContext:
    """Shared state of one run: where to write, the truth, and what stages produced.

    ``artifacts`` maps names (``"board_rig"``, ``"chart_images"``...) to what a
    stage wrote for the following ones.
    """

    out_dir: Path
    config: DemoConfig
    truth: DemoTruth
    artifacts: dict[str, Any] = field(default_factory=dict)

    def path(self, *parts: str) -> Path:
        """A path under the output folder (its parent created)."""
        path = self.out_dir.joinpath(*parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def need(self, name: str, stage: str) -> Any:
        if name not in self.artifacts:
            raise CamcalError(f"demo stage {stage!r} needs {name!r}, made by an earlier stage that did not run")
        return self.artifacts[name]


@dataclass(frozen=True)
class Stage:
    """One step of the demo: ``run(context) -> StageResult``."""

    name: str
    run: Callable[[DemoContext], StageResult]


@dataclass(frozen=True)
class DemoReport:
    """The whole run: rows, outputs, sections and seconds per stage."""

    rows: tuple[DemoRow, ...]
    outputs: tuple[tuple[str, Path], ...]
    sections: tuple[ReportSection, ...]
    seconds: tuple[tuple[str, float], ...]
    report: Path | None = None

    @property
    def failed(self) -> tuple[DemoRow, ...]:
        return tuple(row for row in self.rows if not row.ok)

    def table(self) -> str:
        """The recovered-vs-true table as aligned text."""
        header = (f"{'stage':<16}{'quantity':<44}{'true':>12}{'recovered':>12}{'error':>11}"
                  f"{'tolerance':>11}  {'unit':<7}{'ok':<4}source")
        lines = [header, "-" * len(header)]
        for row in self.rows:
            lines.append(
                f"{row.stage:<16}{row.quantity:<44}{format_number(row.true):>12}{format_number(row.recovered):>12}"
                f"{format_number(row.error):>11}{format_number(row.tolerance):>11}  {row.unit:<7}{'yes' if row.ok else 'NO':<4}{row.source}"
            )
        return "\n".join(lines)


def format_number(value: float) -> str:
    value = float(value)
    if not np.isfinite(value):
        return str(value)
    if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e5):
        return f"{value:.3e}"
    return f"{value:.4f}"


def run_cli(argv: Sequence[str], stage: str) -> None:
    """Run a camcal verb in a child process (``python -m camcal``), as a user would.

    The demo never calls :mod:`camcal.cli` in its own process: the command
    line is exercised exactly as typed, and the CLI may import the demo.
    """
    argv = [str(arg) for arg in argv]
    print(f"$ camcal {' '.join(argv)}", flush=True)
    code = subprocess.run([sys.executable, "-m", "camcal", *argv], check=False).returncode
    if code != 0:
        raise CamcalError(f"demo stage {stage!r}: camcal {argv[0]} exited with code {code}")


def command_line(argv: Sequence[str], ctx: DemoContext) -> str:
    """The command line, with paths relative to the output folder."""
    root = str(ctx.out_dir.resolve())
    parts = []
    for arg in argv:
        text = str(arg).replace(root + os.sep, "").replace(str(ctx.out_dir) + os.sep, "")
        parts.append(f"'{text}'" if "*" in text else text)
    return "camcal " + " ".join(parts)
