"""Interchange stage of the demo: the board rig as OpenCV YAML and USD, each read back by its own tool."""

from __future__ import annotations

import html

import numpy as np

from camcal.base.extras import require
from camcal.demo.core import DemoContext, DemoRow, ReportSection, StageResult, command_line, run_cli
from camcal.model.rig import Rig

__all__ = ["stage_rig_export"]

_USD_TOLERANCE_PX = 1e-3  # USD camera projection vs camcal, as the USD export tests hold it


def stage_rig_export(ctx: DemoContext) -> StageResult:
    """``camcal rig export`` of the calibrated board rig to OpenCV YAML and USD.

    Rows: OpenCV's own projection (``cv2.FileStorage`` + ``cv2.projectPoints``)
    of the YAML against camcal over each camera's frame, bounded by the
    residual the export printed (the division lens becomes OpenCV's nearest
    model); pxr's ``Gf.Camera`` frustum of the USD cameras against camcal's
    pinhole projection (USD has no lens), bounded by 1e-3 px.
    """
    import cv2  # noqa: PLC0415
    require("pxr")
    from pxr import Usd, UsdGeom  # noqa: PLC0415

    from camcal.io.conversion import max_pixel_residual  # noqa: PLC0415
    from camcal.io.interchange import import_rig  # noqa: PLC0415

    stage = "rig export"
    rig_path = ctx.need("board_rig", stage)
    rig = Rig.load(rig_path)
    yaml_path, usd_path = ctx.path("interchange", "board.yaml"), ctx.path("interchange", "board.usda")
    commands = []
    for fmt, out in (("opencv", yaml_path), ("usd", usd_path)):
        argv = ["rig", "export", rig_path, "--to", fmt, out]
        run_cli(argv, stage)
        commands.append(command_line(argv, ctx))
    # the residual the export printed: camcal's camera against the one the YAML holds
    imported = import_rig(yaml_path, "opencv").rig
    printed = {c.name: max_pixel_residual(c, b) for c, b in zip(rig.cameras, imported.cameras)}
    storage = cv2.FileStorage(str(yaml_path), cv2.FILE_STORAGE_READ)
    usd_stage = Usd.Stage.Open(str(usd_path))
    rows = []
    rng = np.random.default_rng(20)
    for index, camera in enumerate(rig.cameras, start=1):
        width, height = camera.image_size
        pixels = rng.uniform([0, 0], [width - 1, height - 1], (2000, 2))
        ideal = camera.distortion.undistort(pixels, camera.K)
        rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(camera.K).T
        X = rays * rng.uniform(1.0, 5.0, (len(rays), 1)) @ camera.R + camera.c
        R_first, c_first = rig.cameras[0].R, rig.cameras[0].c
        K, D = storage.getNode(f"K{index}").mat(), storage.getNode(f"D{index}").mat()
        in_first = (X - c_first) @ R_first.T  # the file's origin is the first camera
        R = storage.getNode("R").mat() if index == 2 else np.eye(3)
        T = storage.getNode("T").mat().ravel() if index == 2 else np.zeros(3)
        cv_pixels, _ = cv2.projectPoints(in_first, cv2.Rodrigues(R)[0], T, K, D)
        observed = float(np.abs(cv_pixels.reshape(-1, 2) - pixels).max())
        rows.append(DemoRow(stage, f"{camera.name} OpenCV YAML: cv2.projectPoints vs camcal (max)", printed[camera.name],
                            observed, observed, printed[camera.name] * 1.05 + 1e-9, "px", "the residual the export printed"))
        frustum = UsdGeom.Camera(usd_stage.GetPrimAtPath(f"/rig/{camera.name}")).GetCamera(Usd.TimeCode.Default()).frustum
        M = np.array(frustum.ComputeViewMatrix()) @ np.array(frustum.ComputeProjectionMatrix())
        clip = np.column_stack([X * [1.0, -1.0, -1.0], np.ones(len(X))]) @ M
        ndc = clip[:, :2] / clip[:, 3:]
        usd_pixels = np.column_stack([(ndc[:, 0] + 1) / 2 * width - 0.5, (1 - ndc[:, 1]) / 2 * height - 0.5])
        usd_error = float(np.abs(usd_pixels - ideal).max())
        rows.append(DemoRow(stage, f"{camera.name} USD: Gf.Camera vs camcal pinhole (max)", 0.0, usd_error, usd_error,
                            _USD_TOLERANCE_PX, "px", "USD export test (tests/io/test_usd_interchange.py)"))
    body = "".join(f"<pre>{html.escape(c)}</pre>" for c in commands) + (
        "<p>OpenCV holds no division lens: the YAML carries the nearest OpenCV lens and the export printed its "
        "residual; USD cameras hold no lens (kept in customData, ST-maps apply it in comp).</p>")
    return StageResult(tuple(rows), (("board rig as OpenCV YAML (board.yaml)", yaml_path),
                                     ("board rig as USD (board.usda)", usd_path)),
                       (ReportSection("Rig interchange", body, "rig-export"),))
