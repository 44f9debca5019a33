"""Rendering the demo's shots with Blender and applying the true lens distortion."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from camcal.demo.core import DemoContext, OVERSCAN, ReportSection, StageResult
from camcal.demo.report import img_tag, plot_images
from camcal.demo.truth import (
    board_outline, chart_albedos, make_chart_quads, make_match_quads, room_quads, true_match_matrix,
)
from camcal.base.errors import CamcalError
from camcal.model.rig import Camera

if TYPE_CHECKING:
    from camcal.geometry.board import Board

__all__ = [
    "chessboard_texture", "pinhole_shot", "redistort_maps", "render_board_views", "stage_render", "write_plate",
]


# -- stage: render -----------------------------------------------------------------------


def chessboard_texture(board, path: Path, px: int = 64) -> Path:
    """Write the printed chessboard (its squares and one white square of margin, :func:`board_outline`) as an
    8-bit PNG of ``px`` pixels a square, the texture of a board quad of :func:`render_shots`."""
    import cv2  # noqa: PLC0415

    cols, rows = board.columns + 1, board.rows + 1
    image = np.full(((rows + 2) * px, (cols + 2) * px), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                image[(r + 1) * px:(r + 2) * px, (c + 1) * px:(c + 2) * px] = 0
    cv2.imwrite(str(path), image)
    return path


def pinhole_shot(camera: Camera, quads: Sequence[str], out: Path, overscan: float = OVERSCAN) -> dict:
    """A shot of :func:`~camcal.demo.blender_scene.render_shots`: the undistorted ``overscan`` canvas of ``camera``
    (a pinhole, Cycles has no lens distortion), which :func:`redistort_maps` turns into ``camera``'s plate."""
    from camcal.geometry.undistort import undistorted_view  # noqa: PLC0415

    view = undistorted_view(camera, "overscan", overscan)
    return {"camera": {"K": view.K_new.tolist(), "R": camera.R.tolist(), "c": camera.c.tolist(),
                       "image_size": list(view.image_size)},
            "quads": list(quads), "out": str(out)}


def redistort_maps(camera: Camera, overscan: float = OVERSCAN) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Plate pixel -> pixel of the :func:`pinhole_shot` render of the same ``overscan`` (camcal's exact redistort
    mapping, :func:`camcal.geometry.stmap.make_stmaps`), as ``cv2.remap``'s x and y maps."""
    from camcal.geometry.stmap import make_stmaps, pixels_from_st  # noqa: PLC0415
    from camcal.geometry.undistort import undistorted_view  # noqa: PLC0415

    maps = make_stmaps(camera, overscan)
    x, y = pixels_from_st(maps.redistort, maps.plate_size)  # in the undistorted image's format, the plate's
    # the render's canvas holds that format at the overscan view's offset
    dx, dy = undistorted_view(camera, "overscan", overscan).K_new[:2, 2] - camera.K[:2, 2]
    return (x + dx).astype(np.float32), (y + dy).astype(np.float32)


def write_plate(render: Path, maps, out: Path, bits: int, band_limit_px: float = 0.0) -> Path:
    """Apply the lens to a render (an EXR of :func:`pinhole_shot`, through :func:`redistort_maps`) and write it as
    a linear 8- or 16-bit PNG (atomically).

    ``band_limit_px = 0``: one cubic remap (OpenCV's, Keys' kernel with ``a = -0.75``). It shifts the sharp edges
    of a render with the map's sub-pixel phase, which varies over the plate with the distortion: on a 2x
    anamorphic 3DE lens, chessboard corners move by up to 0.02-0.04 px (``0.02-0.04 sin(2 pi phase)``), enough to
    bias a calibrated lens beyond its sigma (docs/benchmarks.md, the rendered anamorphic lens). ``> 0``: the render
    is first blurred by a Gaussian of that sigma (canvas pixels; 1 band-limits it), then resampled with a cubic
    B-spline (``scipy.ndimage.map_coordinates``, order 3, its prefilter), whose phase error on such an image is
    below 0.002 px.
    """
    import cv2  # noqa: PLC0415

    from camcal.io.stmap import read_exr  # noqa: PLC0415
    from camcal.base.atomic import atomic_path  # noqa: PLC0415

    rgb = read_exr(render)[..., :3]
    if band_limit_px > 0.0:
        from scipy.ndimage import map_coordinates  # noqa: PLC0415

        blurred = cv2.GaussianBlur(rgb.astype(np.float64), (0, 0), band_limit_px)
        where = [maps[1].astype(np.float64), maps[0].astype(np.float64)]
        plate = np.stack([map_coordinates(blurred[..., c], where, order=3, mode="constant", cval=0.0)
                          for c in range(3)], axis=-1)
    else:
        plate = cv2.remap(rgb, maps[0], maps[1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT)
    plate = np.clip(plate, 0.0, 1.0)
    top = 255 if bits == 8 else 65535
    codes = np.round(plate * top).astype(np.uint8 if bits == 8 else np.uint16)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(codes[..., ::-1])):
            raise CamcalError(f"cannot write {out}")
    return out


def render_board_views(board: Board, views: Mapping[str, tuple[Camera, Sequence[tuple[NDArray, NDArray]]]], folder: Path,
                       samples: int, seed: int = 7, band_limit_px: float = 0.0) -> dict[str, str]:
    """Render chessboard views through each camera's exact lens: Cycles, then camcal's redistort map.

    Each view is an undistorted pinhole render of the printed board (emissive, its texture sampled without
    filtering, no depth of field) on the camera's overscan canvas (:func:`pinhole_shot`: Blender's
    ``pixel_aspect_x`` / ``pixel_aspect_y`` carry a non-square pixel, e.g. an anamorphic squeeze), turned into
    the camera's plate through :func:`redistort_maps` (:func:`write_plate`) and written as an 8-bit PNG.

    Parameters
    ----------
    board : camcal.geometry.board.Board
        The chessboard printed (its squares and one white square of margin).
    views : mapping of str to (Camera, sequence of (R, t))
        A label -> the camera (at the origin, ``R = I``, ``c = 0``) and the board's poses (``cam_from_board``).
    folder : Path
        Receives ``LABEL/vNN.png`` (one per pose, in order) and the render job under ``renders/``.
    samples, seed : int
        Cycles' samples a pixel and its seed.
    band_limit_px : float
        :func:`write_plate`'s: 0 for one cubic remap, > 0 to blur the render by that sigma and resample it with a
        cubic B-spline (no edge shift with the map's phase).

    Returns
    -------
    dict of str to str
        Each label -> the glob of its images (``folder/LABEL/v*.png``).
    """
    from camcal.demo.blender_scene import render_shots  # noqa: PLC0415

    renders = folder / "renders"
    renders.mkdir(parents=True, exist_ok=True)
    texture = chessboard_texture(board, renders / "chessboard.png")
    outline = board_outline(board)
    quads, shots, plates = [], [], []
    for label, (camera, poses) in views.items():
        for k, (R, t) in enumerate(poses):
            name = f"{label}_{k:02d}"
            # the camera sits at the origin looking down +z: the board's world corners are cam_from_board of it
            quads.append({"name": name, "corners": (outline @ np.transpose(R) + t).tolist(), "texture": str(texture),
                          "shader": "emission", "interpolation": "Closest"})
            shots.append(pinhole_shot(camera, [name], renders / f"{name}.exr"))
            plates.append((label, folder / label / f"v{k:02d}.png"))
    exrs = render_shots({"samples": samples, "seed": seed, "quads": quads, "shots": shots, "suns": []}, renders)
    maps = {label: redistort_maps(camera) for label, (camera, _) in views.items()}
    for exr, (label, plate) in zip(exrs, plates):
        write_plate(exr, maps[label], plate, 8, band_limit_px)
        exr.unlink()
    return {label: str(folder / label / "v*.png") for label in views}


def stage_render(ctx: DemoContext) -> StageResult:
    from camcal.demo.blender_scene import render_shots  # noqa: PLC0415
    from camcal.geometry.board import parse_board  # noqa: PLC0415

    truth, config = ctx.truth, ctx.config
    board = parse_board(truth.board_spec)
    renders = ctx.out_dir / "renders"
    renders.mkdir(parents=True, exist_ok=True)
    texture = chessboard_texture(board, renders / "chessboard.png")
    outline = board_outline(board)
    quads, shots, plates = [], [], []
    names = [camera.name for camera in truth.rig.cameras]
    for k, (R, t) in enumerate(truth.board_poses):
        quads.append({"name": f"board_{k:02d}", "corners": (outline @ R.T + t).tolist(), "texture": str(texture),
                      "shader": "emission", "interpolation": "Closest"})
        for name in names:
            shots.append(pinhole_shot(truth.rig.camera(name), [f"board_{k:02d}"],
                                      renders / f"board_{name}_{k:02d}.exr"))
            plates.append((name, ctx.path("images", "board", name, f"{name}_{k + 1:02d}.png"), 8))
    run_solve = config.stages is None or "solve" in config.stages
    if run_solve:
        room = room_quads(truth, renders, np.random.default_rng(config.seed))
        quads += room
        for frame in truth.rig.frames:
            for name in names:
                shots.append(pinhole_shot(truth.rig.camera_at_frame(name, frame.index), [q["name"] for q in room],
                                   renders / f"room_{name}_{frame.index:02d}.exr"))
                plates.append((name, ctx.path("images", "room", name, f"{frame.index:04d}.png"), 8))
    albedos = chart_albedos(truth)
    chart_quads, seen, grid = make_chart_quads(truth, albedos)
    quads += chart_quads
    for name in names:
        shots.append(pinhole_shot(truth.rig.camera(name), seen[name], renders / f"chart_{name}.exr"))
        plates.append((name, ctx.path("images", "chart", f"{name}.png"), 16))
    run_match = config.stages is None or "colour match" in config.stages
    if run_match:
        N = true_match_matrix(albedos)
        match_quads, match_seen = make_match_quads(truth, albedos, N, renders, np.random.default_rng(config.seed + 1))
        quads += match_quads
        for name in names:
            shots.append(pinhole_shot(truth.rig.camera(name), match_seen[name], renders / f"match_{name}.exr"))
            plates.append((name, ctx.path("images", "match", f"{name}.png"), 16))
        ctx.artifacts["match_images"] = {n: ctx.out_dir / "images" / "match" / f"{n}.png" for n in names}
        ctx.artifacts["match_truth"] = N
    R_chart = truth.chart_pose[0]
    job = {"samples": config.samples, "seed": config.seed, "quads": quads, "shots": shots,
           # irradiance pi along the chart's normal: radiance = albedo (Lambertian, albedo E / pi)
           "suns": [{"direction": (R_chart @ [0.0, 0.0, 1.0]).tolist(), "strength": float(np.pi)}]}
    exrs = render_shots(job, renders)
    maps = {name: redistort_maps(truth.rig.camera(name)) for name in names}
    for exr, (name, plate, bits) in zip(exrs, plates):
        write_plate(exr, maps[name], plate, bits)
    ctx.artifacts["board_images"] = {n: sorted(str(p) for c, p, _ in plates if c == n and "board" in p.parts)
                                     for n in names}
    if run_solve:
        ctx.artifacts["room_dirs"] = [ctx.out_dir / "images" / "room" / n for n in names]
    ctx.artifacts["chart_images"] = {n: ctx.out_dir / "images" / "chart" / f"{n}.png" for n in names}
    ctx.artifacts["chart_truth"] = albedos
    ctx.artifacts["chart_grid"] = {n: truth.rig.camera(n).project(grid) for n in names}
    truth.rig.save(ctx.path("truth.rig.json"))
    board_pair = [ctx.artifacts["board_images"][n][0] for n in names]
    chart_pair = [str(ctx.artifacts["chart_images"][n]) for n in names]
    figure = plot_images(ctx.path("plots", "renders.png"), board_pair + chart_pair,
                          [f"{n}: chessboard" for n in names] + [f"{n}: chart (linear, {truth.sensors[n]})" for n in names],
                          columns=2)
    match_note = ("<p>Colour match scene: a slanted wall and a box in front of it, emissive mosaics of real "
                  "surface colours shaded by grey noise. The right camera's textures are <i>T</i>, the left "
                  "one's <i>T N</i><sup>T</sup>, with <i>N</i> the least-squares 3x3 between the two sensors "
                  "over the 190 reflectances: the true right-to-left match is <i>N</i> at every pixel.</p>"
                  if run_match else "")
    room_note = (f"{len(truth.rig.frames)} rig positions in a {truth.room_extent_m:g} m room corner, "
                 if run_solve else "")
    body = (
        f"<p>{len(shots)} Cycles renders ({config.samples} samples, seed {config.seed}, CPU): "
        f"{len(truth.board_poses)} chessboard poses, {room_note}a ColorChecker per camera. "
        f"Cycles has no lens distortion for perspective cameras: each view is rendered undistorted on a "
        f"{OVERSCAN:g}x overscan canvas, then the rig's known division-model distortion is applied with "
        f"camcal's exact redistort mapping (<code>camcal.geometry.stmap.make_stmaps</code>, one cubic remap).</p>"
        f"<p>Colour truth: Blender renders RGB, not spectra. Each camera's sensor is a measured one "
        f"(left {html.escape(truth.sensors['left'])}, right {html.escape(truth.sensors['right'])}) under CIE "
        f"{truth.illuminant}; the patches' diffuse albedos are that sensor's linear RGB for the ISO 17321-1 "
        f"ColorChecker spectra, and a sun of irradiance &pi; W/m&sup2; along the chart's normal makes the "
        f"rendered radiance equal to the albedo. The true XYZ are the spectra under {truth.illuminant} (CIE 1931 observer, 380-780 nm), "
        f"for the chart and for the independent set of 190 RAW-to-ACES reflectances alike.</p>"
        f"{match_note}{img_tag(ctx, figure)}"
    )
    return StageResult(
        outputs=(("true rig (truth.rig.json)", ctx.out_dir / "truth.rig.json"),
                 ("Blender render job", renders / "render_job.json")),
        sections=(ReportSection("Rendered plates", body, "renders"),),
    )
