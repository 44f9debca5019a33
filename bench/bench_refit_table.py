"""Every camcal lens model to every export target's lens family, on real board calibrations.

Each camera of each set is calibrated by camcal (:func:`camcal.geometry.zhang.calibrate_board`, the solver of
``camcal calibrate board``, flat board, every view) once per camcal lens model, and each calibrated camera is
taken to every lens family an export writes through the one refit core
(:func:`camcal.io.conversion.refit_camera`; Lensfun's poly3 / poly5 / ptlens through
:func:`camcal.io.lensfun.fit_lens`, which runs the same core's grid, weights and solver). The table prints the
core's own figures (:class:`camcal.io.conversion.Refit`): max / RMS residual in pixels inside the image and over
the 1.25 overscan border, ``exact`` where the family holds the model (< 1e-6 px), the shares of the image and of the
border inside the source lens' fold when they are not all of it, and the grid pixels the target lens does not image.

Targets (column -> the formats that write it):

- ``opencv``: k1 k2 p1 p2 k3 (OpenCV, Kalibr radtan, COLMAP FULL_OPENCV, USD); ``brown``: the same, refitted with
  k4..k6, s1..s4 held at zero (Blender's BROWN); ``polynomial`` (Blender POLYNOMIAL); ``division`` (COLMAP,
  Blender NUKE); ``kannala-brandt`` (OpenCV fisheye, Kalibr equidistant, COLMAP OPENCV_FISHEYE, Cycles fisheye);
  ``kannala-brandt-thin-prism`` (COLMAP RAD_TAN_THIN_PRISM_FISHEYE);
- 3DE4's families (Nuke LensDistortion / LDPK, 3DE lens files): ``3de-classic``, ``3de4-radial-deg4``,
  ``3de4-anamorphic-deg4``, ``3de4-fisheye-deg8``;
- Lensfun: ``poly3``, ``poly5``, ``ptlens``.

Usage::

    python bench/bench_refit_table.py [--set DIR PATTERN COLUMNS ROWS]... [--corners FILE]... [--models M,M,...]

``--set``: images matching PATTERN in DIR, a chessboard of COLUMNS x ROWS inner corners (camcal's detector).
``--corners``: a JSON of corners (tests/data/real_boards format). It prints what it ran on (each set's folder and
pattern or corners file, image size, board, views) before its tables. OpenCV runs on one thread.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from camcal.base.errors import CamcalError
from camcal.geometry import zhang
from camcal.geometry.board import Board, Detection
from camcal.io.conversion import DEFAULT_OVERSCAN, Refit, refit_camera
from camcal.io.lensfun import MODEL_TERMS, crop_factor, fit_lens
from camcal.model.rig import Camera
from camcal.model.tde4 import TDE4_MODELS
from camcal.pipelines.board import detect_in_images

__all__ = ["EXACT_PX", "MODELS", "TARGETS", "Row", "Target", "calibrate_models", "format_table", "refit_table"]

#: An exact pair's residual must be below this (px).
EXACT_PX = 1e-6
#: Lens models every camera is calibrated with (camcal's board models and 3DE4's).
MODELS = tuple(m for m in (*zhang.AUTO_MODELS, *TDE4_MODELS) if m != "none")
#: Blender's BROWN holds k1 k2 p1 p2 k3 only.
_BROWN_HELD = dict.fromkeys(("k4", "k5", "k6", "s1", "s2", "s3", "s4"), 0.0)


@dataclass(frozen=True)
class Target:
    """An export target's lens family: its column name and how a camera goes into it (the refit core)."""

    name: str
    convert: Callable[[Camera], Refit]


def _core(family: str, fixed: Mapping[str, float] | None = None) -> Target:
    return Target(family if fixed is None else "brown", lambda camera: refit_camera(camera, family, fixed=fixed)[1])


def _lensfun(model: str) -> Target:
    return Target(model, lambda camera: fit_lens(camera, model, crop_factor(camera))[1])


TARGETS: tuple[Target, ...] = (
    _core("opencv"), _core("opencv", _BROWN_HELD), _core("polynomial"), _core("division"), _core("kannala-brandt"),
    _core("kannala-brandt-thin-prism"), *(_core(family) for family in TDE4_MODELS), *map(_lensfun, MODEL_TERMS),
)


@dataclass(frozen=True)
class Row:
    """One camera (calibrated with one model) taken to one target: the refit core's figures, or why it failed."""

    camera: str
    model: str
    target: str
    refit: Refit | None
    error: str = ""

    @property
    def exact(self) -> bool:
        """True when the target's family holds the source lens (the core did not fit)."""
        return self.refit is not None and self.refit.exact


def calibrate_models(board: Board, detections: Sequence[Detection], models: Sequence[str], name: str,
                     log: Callable[[str], None] = print) -> dict[str, Camera]:
    """One camera calibrated with each model (flat board, every view); a model that fails is left out, said."""
    cameras = {}
    for model in models:
        start = time.perf_counter()
        try:
            result = zhang.calibrate_board(board, {name: detections}, model=model, board_shape="flat")
        except CamcalError as error:
            log(f"  {name} {model}: calibration failed: {error}")
            continue
        cameras[model] = result.rig.cameras[0]
        log(f"  {name} {model}: RMS {result.rms_px:.4f} px over {len(detections)} views "
            f"({time.perf_counter() - start:.1f} s)")
    return cameras


def refit_table(cameras: Mapping[str, Camera], targets: Sequence[Target] = TARGETS) -> list[Row]:
    """Each camera (keyed by its model) taken to each target by the refit core, in order."""
    rows = []
    for model, camera in cameras.items():
        for target in targets:
            try:
                rows.append(Row(camera.name, model, target.name, target.convert(camera)))
            except CamcalError as error:
                rows.append(Row(camera.name, model, target.name, None, str(error)))
    return rows


def _cell(row: Row) -> str:
    refit = row.refit
    if refit is None:
        return "fails"
    if refit.exact and refit.max_px < EXACT_PX and refit.border_max_px < EXACT_PX:
        return "exact"
    border = "n/a" if math.isnan(refit.border_max_px) else f"{refit.border_max_px:.3g}/{refit.border_rms_px:.3g}"
    image = f" ({100 * refit.image_usable:.1f}%)" if refit.image_usable < 1.0 else ""
    usable = f" ({100 * refit.border_usable:.0f}%)" if refit.border_usable < 1.0 else ""
    lost = f" [{refit.n_lost} lost]" if refit.n_lost else ""
    return f"{refit.max_px:.3g}/{refit.rms_px:.3g}{image} \\| {border}{usable}{lost}"


def format_table(rows: Sequence[Row], camera: str) -> str:
    """A Markdown table of one camera's rows: a line per source model, a column per target."""
    mine = [r for r in rows if r.camera == camera]
    targets = list(dict.fromkeys(r.target for r in mine))
    models = list(dict.fromkeys(r.model for r in mine))
    lines = ["| model | " + " | ".join(targets) + " |", "| --- |" + " --- |" * len(targets)]
    for model in models:
        cells = {r.target: _cell(r) for r in mine if r.model == model}
        lines.append(f"| {model} | " + " | ".join(cells.get(t, "") for t in targets) + " |")
    return "\n".join(lines)


def _corners_set(path: Path) -> tuple[str, Board, list[Detection]]:
    data = json.loads(path.read_text())
    board = Board("chessboard", data["board"]["columns"], data["board"]["rows"], 1.0)
    size = tuple(data["image_size"])
    views = [Detection(name, size, np.arange(board.n_corners), np.asarray(corners, np.float64), "sb")
             for name, corners in data["corners_px"].items()]
    return path.stem, board, views


def _image_set(folder: Path, pattern: str, columns: int, rows: int) -> tuple[str, Board, list[Detection]]:
    board = Board("chessboard", columns, rows, 1.0)
    paths = sorted(folder.glob(pattern))
    if not paths:
        raise CamcalError(f"no image matches {pattern!r} in {folder}")
    report = detect_in_images(board, paths)
    sizes = [d.image_size for d in report.detections]
    common = max(set(sizes), key=sizes.count)  # images of another size than most are left out
    views = [d for d in report.detections if d.image_size == common]
    print(f"{folder.name}/{pattern}: {report.summary()}, {len(views)} views of {common[0]}x{common[1]}")
    return f"{folder.name}/{pattern}", board, views


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--set", nargs=4, action="append", default=[], metavar=("DIR", "PATTERN", "COLUMNS", "ROWS"))
    parser.add_argument("--corners", action="append", default=[], type=Path)
    parser.add_argument("--models", default=",".join(MODELS))
    args = parser.parse_args(argv)
    if not args.set and not args.corners:
        parser.error("give at least one --set DIR PATTERN COLUMNS ROWS or --corners FILE")
    cv2.setNumThreads(1)
    sets = [_image_set(Path(d), p, int(c), int(r)) for d, p, c, r in args.set]
    sets += [_corners_set(path) for path in args.corners]
    models = args.models.split(",")
    print(f"overscan {DEFAULT_OVERSCAN:g}; cell: max/RMS px inside the image (share of the image inside the source "
          f"lens' fold) | max/RMS px over the border (share of the border inside the fold) "
          f"[grid pixels the target does not image]")
    for name, board, views in sets:
        size = views[0].image_size
        print(f"\n### {name}: {size[0]}x{size[1]}, {board.columns}x{board.rows} board, {len(views)} views")
        cameras = calibrate_models(board, views, models, name)
        start = time.perf_counter()
        rows = refit_table(cameras)
        print(f"({len(rows)} conversions, {time.perf_counter() - start:.0f} s)")
        print(format_table(rows, name))
        for row in rows:
            if row.refit is not None and row.refit.exact and row.refit.max_px >= EXACT_PX:
                print(f"NOT EXACT: {row.model} -> {row.target}: {row.refit.describe()}")
            if row.error:
                print(f"{row.model} -> {row.target}: {row.error}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
