"""Matplotlib figures of the reports: the headless backend, and PNGs written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from camcal.base.atomic import atomic_path
from camcal.base.extras import require

__all__ = ["pyplot", "save_figure"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no display needed), imported on first use."""
    require("matplotlib").use("Agg")
    return require("matplotlib.pyplot")


def save_figure(fig: Any, path: Path) -> Path:
    """Write ``fig`` to the PNG ``path`` (90 dpi, atomic) and close it."""
    with atomic_path(path, suffix=".png") as temporary:
        fig.savefig(temporary, dpi=90, format="png")
    pyplot().close(fig)
    return path
