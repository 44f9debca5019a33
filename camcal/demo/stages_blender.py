"""The Blender stage of the demo: ``blender import`` and a projection check in the saved file."""

from __future__ import annotations

import dataclasses
import html

import numpy as np

from camcal.demo.core import DemoContext, DemoRow, ReportSection, StageResult, command_line, run_cli
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig

__all__ = [
    "stage_blender_import",
]


# -- stage: blender import ------------------------------------------------------------------------


def stage_blender_import(ctx: DemoContext) -> StageResult:
    from camcal.demo.blender_scene import project_in_blend  # noqa: PLC0415

    stage = "blender import"
    rig_path = ctx.artifacts.get("rectified_rig") or ctx.need("board_rig", stage)
    blend = ctx.path("blender", "rig.blend")
    argv = ["blender", "import", str(rig_path), "--blend", str(blend)]
    run_cli(argv, stage)
    outputs = [("Blender scene, board rig (rig.blend)", blend)]
    commands = [argv]
    if "solve_rig" in ctx.artifacts:
        sfm_blend = ctx.path("blender", "sfm.blend")
        sfm_argv = ["blender", "import", str(ctx.artifacts["solve_rig"]), "--blend", str(sfm_blend)]
        run_cli(sfm_argv, stage)
        outputs.append(("Blender scene, SfM rig with its points (sfm.blend)", sfm_blend))
        commands.append(sfm_argv)
    rig = Rig.load(rig_path)
    rng = np.random.default_rng(ctx.config.seed)
    X = np.column_stack([rng.uniform(-0.4, 0.5, 60), rng.uniform(-0.3, 0.3, 60), rng.uniform(0.4, 2.0, 60)])
    projected = project_in_blend(blend, X, ctx.out_dir / "blender")
    rows = []
    for camera in rig.cameras:
        pinhole = dataclasses.replace(camera, distortion=Distortion.none())
        err = float(np.max(np.linalg.norm(np.asarray(projected[camera.name]) - pinhole.project(X), axis=1)))
        rows.append(DemoRow(stage, f"{camera.name}: Blender projection vs rig (worst)", 0.0, err, err, 1e-3, "px", "Blender projection test (tests/addon/test_addon_importer.py)"))
    body = ("".join(f"<pre>{html.escape(command_line(a, ctx))}</pre>" for a in commands)
            + "<p>The .blend files hold the rig's cameras (exact intrinsics as lens, shift and pixel aspect), "
              "the lens as a MovieClip with a Movie Distortion compositor, and for the SfM rig the keyframed "
              "rig and its sparse points. The check projects 60 points with Blender's own "
              "<code>calc_matrix_camera</code> in the saved file.</p>")
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Blender", body, "blender"),))
