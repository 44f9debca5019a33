"""``camcal demo``: the whole pipeline on a stereo rig it renders itself.

The demo makes a known stereo rig (two 640x480 cameras with division-model
lens distortion, 0.1 m apart, toed in by 2 degrees), renders with Blender
(Cycles, CPU, in a subprocess: :mod:`camcal.demo.blender_scene`) what a crew
would shoot with it - a chessboard at several poses, a textured room corner
seen from seven rig positions, a ColorChecker under a known light, a
coloured scene for colour matching - and runs camcal's verbs on those
images: ``calibrate board``, ``distortion fit``, ``stmap``, ``rectify``,
``solve``, ``colour fit``, ``colour match``, ``colour export`` and
``blender import``. Each stage compares what it recovered with the truth,
against a tolerance named by its source (the bound a test of the same
step asserts, a peer's figure on the same data, a probability), and adds sections to
``DIR/report.html``.

Stages are an ordered list (:data:`STAGES`): a name and a function
``DemoContext -> StageResult`` (rows of recovered vs true values, output
files, report sections). Later stages read what earlier ones left in
``DemoContext.artifacts``; a new stage is added by inserting a
:class:`Stage` into the list; colour exports go in the report section
:data:`COLOUR_EXPORTS_SECTION`.

How the truth is made (stated in the report too):

- Geometry: Cycles has no lens distortion for perspective cameras, so each
  view is rendered by the undistorted camera on an overscan canvas
  (``camcal.geometry.undistort``, factor :data:`OVERSCAN`), and the rig's
  known distortion is then applied with camcal's own exact mapping (the
  redistort map of ``camcal.geometry.stmap.make_stmaps``: plate pixel ``x_d``
  samples the render at ``K_os K^-1 undistort(x_d)``), one cubic remap.
  Blender cameras are set by the add-on's mapping, exact to < 1e-3 px.
- Colour: Blender renders RGB, not spectra. Each camera's sensor is a
  measured one from colour-science (left: Nikon 5100, right: Sigma SDMerill)
  under CIE D65: the chart's patches (ISO 17321-1 ColorChecker spectra) get
  as diffuse albedo that sensor's linear RGB for the patch
  (``SimulatedCamera.RGB``), times one scale per camera. A sun of
  irradiance pi W/m^2 along the chart's normal makes Cycles' radiance
  ``albedo E / pi = albedo``: the rendered linear RGB is the simulated
  camera RGB, and the true XYZ are the spectra integrated under D65 with the
  CIE 1931 observer (:func:`reference_XYZ`, as the chart reference is). The
  independent set (190 RAW-to-ACES reflectances) goes through the same
  sensors and scale, without Blender.
- Colour match: the match scene's surfaces are mosaics of real surface
  colours; the right camera sees texture ``T``, the left one ``T N^T`` with
  ``N`` the least-squares 3x3 between the two sensors (:func:`true_match_matrix`),
  so the true right -> left match is ``N``; it is judged on the 190
  independent colours, which the fit never saw.

The package by concern: :mod:`~camcal.demo.core` (configuration, rows,
context, the CLI runner: a child ``python -m camcal``, never
:mod:`camcal.cli` in this process), :mod:`~camcal.demo.truth` (the known rig
and scene), :mod:`~camcal.demo.render` (Blender shots and the true lens),
``stages_geometry`` / ``stages_colour`` / ``stages_blender`` (the stages by
area), :mod:`~camcal.demo.report` (plots and HTML).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from camcal.demo.core import (
    COLOUR_EXPORTS_SECTION, DemoConfig, DemoContext, DemoReport, DemoRow, DemoTruth, FULL, QUICK,
    ReportSection, Stage, StageResult,
)
from camcal.demo.render import stage_render
from camcal.demo.report import write_html
from camcal.demo.stages_blender import stage_blender_import
from camcal.demo.stages_colour import stage_colour_export, stage_colour_fit, stage_colour_match
from camcal.demo.stages_geometry import (
    stage_calibrate_board, stage_distortion_fit, stage_rectify, stage_solve,
)
from camcal.demo.stages_interchange import stage_rig_export
from camcal.demo.truth import make_truth, reference_XYZ, true_match_matrix
from camcal.base.atomic import atomic_dir, final_path
from camcal.base.errors import CamcalError

__all__ = [
    "COLOUR_EXPORTS_SECTION",
    "DemoConfig",
    "DemoContext",
    "DemoReport",
    "DemoRow",
    "DemoTruth",
    "FULL",
    "QUICK",
    "ReportSection",
    "STAGES",
    "Stage",
    "StageResult",
    "make_truth",
    "reference_XYZ",
    "run_demo",
    "true_match_matrix",
    "write_html",
]


#: The demo's stages, in order. Artifacts stages leave for later ones (``ctx.artifacts``):
#: ``board_images``, ``room_dirs``, ``chart_images``, ``chart_truth``, ``chart_grid``,
#: ``match_images``, ``match_truth`` (render); ``board_rig`` (calibrate board); ``rectified_rig``
#: (rectify); ``solve_rig`` (solve); ``colour_fits``, ``chart_patches``, ``independent_patches``
#: (colour fit); ``colour_match`` (colour match).
STAGES: list[Stage] = [
    Stage("render", stage_render),
    Stage("calibrate board", stage_calibrate_board),
    Stage("rig export", stage_rig_export),
    Stage("distortion fit", stage_distortion_fit),
    Stage("rectify", stage_rectify),
    Stage("solve", stage_solve),
    Stage("colour fit", stage_colour_fit),
    Stage("colour match", stage_colour_match),
    Stage("colour export", stage_colour_export),
    Stage("blender import", stage_blender_import),
]


def run_demo(out_dir: str | os.PathLike, config: DemoConfig = FULL, stages: Sequence[Stage] | None = None) -> DemoReport:
    """Run the demo's stages into ``out_dir`` and write ``report.html``.

    Parameters
    ----------
    out_dir : path
        Output folder: built under a temporary name beside it and renamed at
        the end, removed if a stage raises
        (:func:`camcal.base.atomic.atomic_dir`).
    config : DemoConfig
        Sizes and the stages to run (:data:`FULL` for ``make demo``).
    stages : sequence of Stage, optional
        The stage list (default :data:`STAGES`).

    Returns
    -------
    DemoReport
        Every row, output and section; ``report`` is the HTML file.
    """
    out_dir = Path(out_dir)
    stages = list(stages if stages is not None else STAGES)
    unknown = sorted(set(config.stages or ()) - {stage.name for stage in stages})
    if unknown:
        raise CamcalError(f"demo: unknown stage(s) {', '.join(map(repr, unknown))}; expected some of: "
                          + ", ".join(s.name for s in stages))
    with atomic_dir(out_dir) as staging:
        ctx = DemoContext(staging, config, make_truth(config))
        rows, outputs, sections, seconds = [], [], [], []
        for stage in stages:
            if config.stages is not None and stage.name not in config.stages:
                continue
            print(f"camcal demo: {stage.name}", file=sys.stderr, flush=True)
            start = time.perf_counter()
            result = stage.run(ctx)
            seconds.append((stage.name, time.perf_counter() - start))
            rows += result.rows
            outputs += result.outputs
            sections += result.sections
        report = DemoReport(tuple(rows), tuple(outputs), tuple(sections), tuple(seconds))
        write_html(report, staging)
    outputs = tuple((label, final_path(path, staging, out_dir)) for label, path in report.outputs)
    return dataclasses.replace(report, outputs=outputs, report=out_dir / "report.html")
