"""Geometry stages of the demo: calibrate board, distortion fit (+ ST-maps), rectify, solve."""

from __future__ import annotations

import html
import os
import shutil
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.extras import require
from camcal.demo.core import DemoContext, DemoRow, ReportSection, StageResult, command_line, run_cli
from camcal.demo.report import img_tag, plot_epipolar, plot_residuals
from camcal.demo.truth import board_corners
from camcal.model.camera import pixels_from_colmap, rotation_angle_deg, similarity_Umeyama1991
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig

__all__ = [
    "stage_calibrate_board",
    "stage_distortion_fit",
    "stage_rectify",
    "stage_solve",
]


# Where each row's tolerance comes from, as the demo prints it: the bound the synthetic test of the
# same step asserts at the noise it names, or a probability.
_RIG_TEST = "synthetic rig test (tests/geometry/test_zhang.py), 0.1 px noise"
_PLUMB_LINE_TEST = "plumb-line test (tests/geometry/test_plumbline.py), 0.2 px noise"
_GAUSSIAN_TAIL = "2-D Gaussian, exceeded with probability 0.27 %"
_RECTIFY_TEST = "rectification test (tests/geometry/test_rectify.py), 0.2 px noise"
_SOLVE_TEST = "synthetic solve test (tests/pipelines/test_solve.py)"


# -- stage: calibrate board ----------------------------------------------------------------


def stage_calibrate_board(ctx: DemoContext) -> StageResult:
    from camcal.geometry.board import parse_board  # noqa: PLC0415
    from camcal.pipelines.board import detect_in_images  # noqa: PLC0415
    from camcal.geometry.zhang import calibrate_board  # noqa: PLC0415
    from camcal.report.calibration import write_report  # noqa: PLC0415
    from camcal.report.sigma import write_sigma_heatmaps  # noqa: PLC0415

    truth = ctx.truth
    images = ctx.need("board_images", "calibrate board")
    board = parse_board(truth.board_spec)
    detections = {name: detect_in_images(board, files).detections for name, files in images.items()}
    result = calibrate_board(board, detections, model="division", units="m")
    rig_path = result.rig.save(ctx.path("calibrate", "board.rig.json"))
    plots = write_report(result, ctx.out_dir / "calibrate")
    sigma_plots = write_sigma_heatmaps(result.rig.cameras, ctx.out_dir / "calibrate")
    ctx.artifacts["board_rig"] = rig_path
    rows = []
    stage = "calibrate board"
    for camera in result.rig.cameras:
        true = truth.rig.camera(camera.name)
        for i, name in ((0, "fx"), (1, "fy")):
            t_, r_ = true.K[i, i], camera.K[i, i]
            rows.append(DemoRow(stage, f"{camera.name} {name} error", t_, r_, 100 * (r_ - t_) / t_, 0.1, "%", _RIG_TEST))
        for i, name in ((0, "cx"), (1, "cy")):
            t_, r_ = true.K[i, 2], camera.K[i, 2]
            rows.append(DemoRow(stage, f"{camera.name} {name}", t_, r_, r_ - t_, 0.3, "px", _RIG_TEST))
        t_, r_ = true.distortion.params["lambda"], camera.distortion.params["lambda"]
        rows.append(DemoRow(stage, f"{camera.name} division lambda", t_, r_, 100 * (r_ - t_) / t_, 2.0, "%", _PLUMB_LINE_TEST))
    left_t, right_t = truth.rig.camera("left"), truth.rig.camera("right")
    left_r, right_r = result.rig.camera("left"), result.rig.camera("right")
    baseline_t = float(np.linalg.norm(right_t.c - left_t.c))
    baseline_r = float(np.linalg.norm(right_r.c - left_r.c))
    rows.append(DemoRow(stage, "baseline length error", baseline_t, baseline_r,
                        100 * (baseline_r - baseline_t) / baseline_t, 0.1, "%", _RIG_TEST))
    relative_t, relative_r = right_t.R @ left_t.R.T, right_r.R @ left_r.R.T
    rows.append(DemoRow(stage, "relative rotation error", 0.0, rotation_angle_deg(relative_r @ relative_t.T),
                        rotation_angle_deg(relative_r @ relative_t.T), 0.02, "deg", _RIG_TEST))
    sigma_row, sigma_text = _sigma_row(stage, board, detections["left"], result.rig.camera("left"), truth)
    rows.append(sigma_row)
    residual_plot = plot_residuals(ctx.path("plots", "board_residuals.png"), result.rig.cameras,
                                    result.camera_of_point, result.points_px,
                                    -result.residuals_px)  # zhang's residuals_px are projected - detected
    command = (f"camcal calibrate board --board {truth.board_spec} --images left='images/board/left/*.png' "
               f"right='images/board/right/*.png' --model division --out calibrate/board.rig.json "
               f"--report calibrate")
    body = (f"<pre>{html.escape(command)}</pre><pre>{html.escape(result.summary())}</pre>"
            f"{img_tag(ctx, residual_plot)}"
            + "".join(img_tag(ctx, p, width=320) for p in plots if p.suffix == ".png")
            + "".join(f'<p><a href="{html.escape(os.path.relpath(p.resolve(), ctx.out_dir.resolve()))}">'
                      f"{html.escape(p.name)}</a>: the calibration's own report (camera layout, held-out residuals)</p>"
                      for p in plots if p.suffix == ".html")
            + f"<h3>Projection uncertainty</h3><p>{html.escape(sigma_text)}</p>"
            + "".join(img_tag(ctx, p, width=420) for p in sigma_plots))
    return StageResult(tuple(rows), (("board calibration (board.rig.json)", rig_path),),
                       (ReportSection("Chessboard calibration", body, "calibrate-board"),))


def _sigma_row(stage: str, board, detections, camera, truth) -> tuple[DemoRow, str]:
    """The left camera's projection sigma against its true error in the board gauge (:mod:`camcal.demo.sigma_check`)."""
    from camcal.demo.sigma_check import TOLERANCE_SIGMA, sigma_against_truth  # noqa: PLC0415
    from camcal.geometry.board import frame_number  # noqa: PLC0415

    # the left camera is the rig's frame: its true cam_from_board is the board pose itself
    rotations = [truth.board_poses[frame_number(detection.image) - 1][0] for detection in detections]
    error, sigma, ratio = sigma_against_truth(camera, truth.rig.camera("left"), board, detections, rotations)
    text = (f"left camera, rays at infinity, 63 pixels over the frame, mrcal 2.2's board gauge: true projection "
            f"error RMS {error:.3f} px, predicted sigma RMS {sigma:.3f} px, error / sigma RMS {ratio:.2f}. One "
            f"calibration is one draw of its error: a 2-D Gaussian error exceeds {TOLERANCE_SIGMA:.2f} sigma with "
            f"probability 0.27 %, the row's tolerance.")
    return DemoRow(stage, "left projection error / sigma, RMS over the frame", error, sigma, ratio, TOLERANCE_SIGMA,
                   "sigma", _GAUSSIAN_TAIL), text


# -- stage: distortion fit (+ ST-maps) ----------------------------------------------------


def stage_distortion_fit(ctx: DemoContext) -> StageResult:
    from camcal.base.jsonfile import read_json  # noqa: PLC0415

    stage = "distortion fit"
    images = ctx.need("board_images", stage)["left"]
    lens = ctx.path("distortion", "left.lens.json")
    argv = ["distortion", "fit", "--images", *images, "--board", "chessboard:9x6", "--model", "division", "--fit-centre",
            "--out", str(lens), "--report", str(ctx.out_dir / "distortion")]
    run_cli(argv, stage)
    fitted = read_json(lens, "lens file")
    distortion = Distortion.from_dict(fitted["distortion"])
    true = ctx.truth.rig.camera("left")
    lam_t, lam_r = true.distortion.params["lambda"], distortion.params["lambda"]
    centre_t = true.K[:2, 2]
    centre_r = np.asarray(distortion.center if distortion.center is not None else centre_t)
    rows = [
        DemoRow(stage, "left division lambda (plumb-line)", lam_t, lam_r, 100 * (lam_r - lam_t) / lam_t, 2.0, "%", _PLUMB_LINE_TEST),
        DemoRow(stage, "left distortion centre (plumb-line)", 0.0, float(np.linalg.norm(centre_r - centre_t)),
                float(np.linalg.norm(centre_r - centre_t)), 3.0, "px", _PLUMB_LINE_TEST),
        DemoRow(stage, "left straightness after correction", 0.0, float(fitted["straightness_rms_px"]),
                float(fitted["straightness_rms_px"]), 0.15, "px", _PLUMB_LINE_TEST),
    ]
    board_rig = ctx.need("board_rig", stage)
    stmap_dir = ctx.out_dir / "stmap"
    stmap_argv = ["stmap", str(board_rig), "--camera", "left", "--out", str(stmap_dir), "--sigma", "--report",
                  str(stmap_dir / "report")]
    run_cli(stmap_argv, stage)
    outputs = (("plumb-line lens (left.lens.json)", lens),
               ("ST-map undistort, left (EXR)", stmap_dir / "left_undistort.exr"),
               ("ST-map redistort, left (EXR)", stmap_dir / "left_redistort.exr"),
               ("projection sigma, left (EXR, with the redistort map)", stmap_dir / "left_sigma.exr"))
    shown = ["distortion", "fit", "--images", str(Path(images[0]).parent / "*.png"), *argv[3 + len(images):]]
    body = (f"<pre>{html.escape(command_line(shown, ctx))}</pre>"
            f"<p>Plumb-line fit on the rows and columns of the left camera's chessboard views: lambda "
            f"{lam_r:.4e} (true {lam_t:.4e}), centre ({centre_r[0]:.2f}, {centre_r[1]:.2f}) px (true "
            f"({centre_t[0]:.2f}, {centre_t[1]:.2f})). ST-maps of the board calibration's left camera for comp "
            f"packages (Nuke STMap), with the projection sigma beside each map:</p>"
            f"<pre>{html.escape(command_line(stmap_argv, ctx))}</pre>"
            + "".join(img_tag(ctx, stmap_dir / "report" / f"{kind}_left.png", width=420)
                      for kind in ("sigma", "undistort_sigma")))
    return StageResult(tuple(rows), outputs, (ReportSection("Lens distortion (plumb-line) and ST-maps", body, "distortion"),))


# -- stage: rectify --------------------------------------------------------------------------


def stage_rectify(ctx: DemoContext) -> StageResult:
    import cv2  # noqa: PLC0415

    from camcal.geometry.board import detect_board, parse_board  # noqa: PLC0415
    from camcal.geometry.rectify import vertical_disparity  # noqa: PLC0415

    stage = "rectify"
    truth = ctx.truth
    board_rig = ctx.need("board_rig", stage)
    images = ctx.need("board_images", stage)
    pair_dir = ctx.out_dir / "rectify" / "input"
    chosen = {}
    for name in ("left", "right"):
        sources = [images[name][0]]
        if "room_dirs" in ctx.artifacts:
            sources.append(str(ctx.out_dir / "images" / "room" / name / "0003.png"))
        (pair_dir / name).mkdir(parents=True, exist_ok=True)
        for source in sources:
            shutil.copyfile(source, pair_dir / name / f"{Path(source).parent.parent.name}_{Path(source).name}")
        chosen[name] = sorted(str(p) for p in (pair_dir / name).iterdir())
    rect_path = ctx.path("rectify", "rectified.rig.json")
    written_dir = ctx.out_dir / "rectify" / "images"
    argv = ["rectify", str(board_rig), "--images", f"left={pair_dir / 'left'}/*.png", f"right={pair_dir / 'right'}/*.png",
            "--out", str(rect_path), "--write", str(written_dir), "--report", str(ctx.out_dir / "rectify"),
            "--sigma", "--distance", f"{np.median([np.linalg.norm(t) for _, t in truth.board_poses]):.4g}"]
    run_cli(argv, stage)
    ctx.artifacts["rectified_rig"] = rect_path
    rig = Rig.load(rect_path)
    board = parse_board(truth.board_spec)
    # held-out truth: every board corner of every view, projected by the TRUE cameras
    xl, xr = [], []
    for R, t in truth.board_poses:
        X = board_corners(board, R, t)
        xl.append(truth.rig.camera("left").project(X))
        xr.append(truth.rig.camera("right").project(X))
    truth_disparity = vertical_disparity(rig, {("left", "right"): (np.vstack(xl), np.vstack(xr))})[0]
    # the written rectified board pair: corners detected in the images themselves
    board_name = Path(chosen["left"][0]).name
    found = [detect_board(board, cv2.imread(str(written_dir / n / Path(chosen[n][0]).name), cv2.IMREAD_GRAYSCALE), n)
             for n in ("left", "right")]
    rows = [DemoRow(stage, "vertical disparity RMS, true corners", 0.0, truth_disparity.rms_px,
                    truth_disparity.rms_px, 0.3, "px", _RECTIFY_TEST)]
    if all(d is not None for d in found):
        ids_l, ids_r = list(found[0].ids), list(found[1].ids)
        common = [i for i in ids_l if i in ids_r]
        dy = np.array([found[0].corners_px[ids_l.index(i), 1] - found[1].corners_px[ids_r.index(i), 1] for i in common])
        rms = float(np.sqrt(np.mean(dy**2)))
        rows.append(DemoRow(stage, "vertical disparity RMS, detected in written pair", 0.0, rms, rms, 0.3, "px", _RECTIFY_TEST))
    else:
        rows.append(DemoRow(stage, "vertical disparity RMS, detected in written pair", 0.0, float("nan"),
                            float("nan"), 0.3, "px", _RECTIFY_TEST))
    figures = [plot_epipolar(ctx.path("plots", f"rectified_{Path(chosen['left'][i]).stem}.png"),
                              written_dir / "left" / Path(chosen["left"][i]).name,
                              written_dir / "right" / Path(chosen["right"][i]).name)
               for i in range(len(chosen["left"]))]
    body = (f"<pre>{html.escape(command_line(argv, ctx))}</pre>"
            f"<p>Calibrated (camera-based) rectification of the board calibration. The vertical disparity is "
            f"measured on every chessboard corner projected by the true cameras ({truth_disparity.n} "
            f"correspondences) and on the corners detected in the written rectified pair "
            f"<code>{html.escape(board_name)}</code>. Horizontal lines are epipolar lines after rectification.</p>"
            + "".join(img_tag(ctx, f) for f in figures)
            + "<h3>Uncertainty of the rectified pair</h3><p>The sigma of the vertical disparity (rectified px) and "
              "of the depth at the boards' median distance (rig units), propagated from the calibration's "
              "covariance:</p>"
            + "".join(img_tag(ctx, ctx.out_dir / "rectify" / f"sigma_{kind}_left-right.png", width=420)
                      for kind in ("vertical", "depth")))
    return StageResult(tuple(rows), (("rectified rig (rectified.rig.json)", rect_path),
                                     ("rectified images", written_dir)),
                       (ReportSection("Rectification", body, "rectify"),))


# -- stage: solve ------------------------------------------------------------------------------


def _sfm_residuals(model_dir: Path, camera_names: list[str]) -> tuple[NDArray, NDArray, NDArray]:
    """Camera index, observed pixel and residual (observed - projected) of every observation of the
    refined COLMAP model ``solve`` wrote (image names are ``camera/file``)."""
    pycolmap = require("pycolmap")

    reconstruction = pycolmap.Reconstruction(str(model_dir))
    cameras, points, residuals = [], [], []
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        index = camera_names.index(image.name.split("/", 1)[0])
        for point in image.get_observation_points2D():
            projected = image.project_point(reconstruction.points3D[point.point3D_id].xyz)
            if projected is not None:
                cameras.append(index)
                points.append(point.xy)
                residuals.append(point.xy - projected)  # both in COLMAP pixels: the half pixel cancels
    return np.asarray(cameras), pixels_from_colmap(np.asarray(points)), np.asarray(residuals)


def stage_solve(ctx: DemoContext) -> StageResult:
    stage = "solve"
    truth = ctx.truth
    folders = ctx.need("room_dirs", stage)
    out = ctx.out_dir / "solve"
    # COLMAP's INFO log (thousands of lines) would drown the demo's output; warnings still show
    os.environ.setdefault("GLOG_minloglevel", "1")
    argv = ["solve", *map(str, folders), "--out", str(out), "--model", "division", "--seed", str(ctx.config.seed)]
    run_cli(argv, stage)
    rig = Rig.load(out / "solve.rig.json")
    ctx.artifacts["solve_rig"] = out / "solve.rig.json"
    n_images = 2 * len(truth.rig.frames)
    solved = {(name, frame.index): rig.camera_at_frame(name, frame.index) for frame in rig.frames for name in frame.images}
    registered = len(solved)
    rows = [DemoRow(stage, "images registered", n_images, registered, n_images - registered, 0, "images", _SOLVE_TEST)]
    for camera in rig.cameras:
        f_t, f_r = truth.rig.camera(camera.name).K[0, 0], camera.K[0, 0]
        rows.append(DemoRow(stage, f"{camera.name} focal error", f_t, f_r, 100 * (f_r - f_t) / f_t, 0.5, "%", _SOLVE_TEST))
    # frames are numbered in order of the registered frames: match them by image name
    index_of = {frame.index: int(Path(next(iter(frame.images.values()))).stem) for frame in rig.frames}
    keys = sorted(solved)
    true_cams = {k: truth.rig.camera_at_frame(k[0], index_of[k[1]]) for k in keys}
    s, R_align, t = similarity_Umeyama1991(np.array([solved[k].c for k in keys]), np.array([true_cams[k].c for k in keys]))
    centre_err = max(float(np.linalg.norm(s * R_align @ solved[k].c + t - true_cams[k].c)) for k in keys)
    rot_err = max(rotation_angle_deg(true_cams[k].R @ (solved[k].R @ R_align.T).T) for k in keys)
    size = truth.room_extent_m
    rows.append(DemoRow(stage, "worst camera rotation error", 0.0, rot_err, rot_err, 0.1, "deg", _SOLVE_TEST))
    rows.append(DemoRow(stage, "worst camera centre error (% of scene)", 0.0, 100 * centre_err / size,
                        100 * centre_err / size, 0.5, "%", _SOLVE_TEST))
    right_t, right_r = truth.rig.camera("right"), rig.camera("right")
    d_t, d_r = right_t.c / np.linalg.norm(right_t.c), right_r.c / np.linalg.norm(right_r.c)
    angle = float(np.degrees(np.arccos(np.clip(d_t @ d_r, -1.0, 1.0))))
    rows.append(DemoRow(stage, "baseline direction error (rig constraint)", 0.0, angle, angle, 0.1, "deg", _SOLVE_TEST))
    quality = ", ".join(f"{c.name} {c.quality['rms_px']:.3f} px" for c in rig.cameras)
    residual_plot = plot_residuals(ctx.path("plots", "solve_residuals.png"), rig.cameras,
                                    *_sfm_residuals(out / "sparse" / "best", [c.name for c in rig.cameras]),
                                    what="feature")
    body = (f"<pre>{html.escape(command_line(argv, ctx))}</pre><p>pycolmap SIFT + incremental mapping with the rig "
            f"constraint (division lens: mapped with COLMAP's SIMPLE_DIVISION), then camcal's bundle adjustment (COLMAP's "
            f"DIVISION: fx and fy under the square-pixel prior); RMS reprojection error through camcal's rig: "
            f"{quality}. Poses compared after a similarity (Umeyama 1991) to the true ones; "
            f"scene size {size:g} m.</p>{img_tag(ctx, residual_plot)}")
    return StageResult(tuple(rows), (("SfM rig (solve.rig.json)", out / "solve.rig.json"), ("sparse points (points.ply)", out / "points.ply")),
                       (ReportSection("Structure from motion", body, "solve"),))
