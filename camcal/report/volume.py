"""The capture volume as a page: camera layout from above and from the side, each camera's held-out residuals.

``index.html`` (static, offline: inline CSS, images by relative path) shows

- ``layout.png``: the N cameras seen from above and from the side, each
  with its name, its centre and its frustum (the image corners' rays to
  :data:`FRUSTUM_SHARE` of the volume's size), and every board position
  solved (its outline, or its origin without a board);
- ``heldout_residuals.png``: per camera, the held-out corners' residuals
  ``observed - projected`` (px), the training and held-out RMS in its title;
- a table per camera: centre, focal length, training and held-out RMS,
  views used and held out;
- given them, each camera's projection-sigma heat map
  (:func:`camcal.report.sigma.write_sigma_heatmaps`).

"Up" is the mean of the cameras' up axes (``-y`` of each camera, in the
reference camera's coordinates: ``P = K [R | -R c]``, camera axes x right,
y down, z forward); "from above" looks down it, "from the side" looks along
the horizontal axis perpendicular to the reference camera's view.
"""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import quote

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_write_text
from camcal.geometry.board import Board
from camcal.geometry.zhang import CalibrationResult
from camcal.report import RESIDUAL_LABEL
from camcal.report.figures import pyplot, save_figure

__all__ = ["FRUSTUM_SHARE", "PAGE_STYLE", "layout_axes", "write_volume_report"]

#: Frustum depth as a share of the volume's size (the largest extent of camera centres and boards).
FRUSTUM_SHARE = 0.12
#: The stylesheet of the verbs' report pages (this one and :mod:`camcal.report.rectification`'s).
PAGE_STYLE = """body{font-family:sans-serif;margin:2em;max-width:1300px} table{border-collapse:collapse}
td,th{border:1px solid #bbb;padding:3px 8px} td.num{text-align:right;font-family:monospace}
img{max-width:100%}"""


def layout_axes(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows ``(across, forward, up)``: a right-handed frame of the volume from the cameras' rotations ``R`` (N, 3, 3).

    ``up`` is the mean of the cameras' up axes ``-R[i, 1, :]``; ``forward`` the
    reference camera's optical axis ``R[0, 2, :]`` made horizontal.
    """
    up = -np.asarray(R)[:, 1, :].sum(axis=0)
    up /= np.linalg.norm(up)
    forward = R[0, 2, :] - (R[0, 2, :] @ up) * up
    if np.linalg.norm(forward) < 1e-9:  # the reference looks straight up or down
        forward = R[0, 0, :] - (R[0, 0, :] @ up) * up
    forward /= np.linalg.norm(forward)
    return np.array([np.cross(forward, up), forward, up])


def _board_outlines(result: CalibrationResult, board: Board | None) -> list[NDArray[np.float64]]:
    """World points of each solved board pose: its outline (closed) or its origin."""
    if board is None:
        return [t[None, :] for _, _, t in result.board_poses]
    X = np.asarray(board.object_points, dtype=np.float64)
    lo, hi = X.min(axis=0), X.max(axis=0)
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0],
                        [lo[0], lo[1], 0]])
    return [outline @ R.T + t for _, R, t in result.board_poses]


def _plot_layout(result: CalibrationResult, board: Board | None, path: Path) -> Path:
    plt = pyplot()
    cameras = result.rig.cameras
    axes3 = layout_axes(np.array([c.R for c in cameras]))
    boards = _board_outlines(result, board)
    points = np.vstack([np.array([c.c for c in cameras]), *boards]) if boards else np.array([c.c for c in cameras])
    size = max(float(np.ptp(points, axis=0).max()), 1e-6)
    depth = FRUSTUM_SHARE * size
    fig, panels = plt.subplots(1, 2, figsize=(13, 6.2))
    views = (("from above", 0, 1, "across", "forward"), ("from the side", 1, 2, "forward", "up"))
    colours = plt.get_cmap("tab20")(np.arange(len(cameras)) % 20)
    for ax, (title, a, b, xlabel, ylabel) in zip(panels, views):
        for outline in boards:
            q = outline @ axes3.T
            ax.plot(q[:, a], q[:, b], "-" if len(q) > 1 else ".", color="0.6", lw=0.6, ms=3)
        for camera, colour in zip(cameras, colours):
            width, height = camera.image_size
            pixels = np.array([[0, 0, 1], [width - 1, 0, 1], [width - 1, height - 1, 1], [0, height - 1, 1]], float)
            rays = pixels @ np.linalg.inv(camera.K).T
            corners = camera.c + depth * rays @ camera.R  # R^T ray: camera to world
            c, q = camera.c @ axes3.T, corners @ axes3.T
            for corner in q:
                ax.plot([c[a], corner[a]], [c[b], corner[b]], color=colour, lw=0.9)
            ring = np.vstack([q, q[:1]])
            ax.plot(ring[:, a], ring[:, b], color=colour, lw=0.9)
            ax.plot(c[a], c[b], "o", color=colour, ms=4)
            ax.annotate(camera.name, (c[a], c[b]), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_title(f"cameras and {len(result.board_poses)} board positions {title}")
        ax.set_xlabel(f"{xlabel} ({result.rig.units})")
        ax.set_ylabel(f"{ylabel} ({result.rig.units})")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def _plot_heldout(result: CalibrationResult, path: Path) -> Path:
    plt = pyplot()
    cameras = result.rig.cameras
    columns = min(4, len(cameras))
    rows = -(-len(cameras) // columns)
    fig, panels = plt.subplots(rows, columns, figsize=(3.4 * columns, 3.4 * rows), squeeze=False)
    residuals = -result.heldout_residuals_px  # stored as projected - detected
    limit = max(float(np.percentile(np.abs(residuals), 99.5)) * 1.1, 1e-3) if len(residuals) else 1.0
    for j, ax in enumerate(panels.ravel()):
        if j >= len(cameras):
            ax.axis("off")
            continue
        camera, mine = cameras[j], residuals[result.heldout_camera_of_point == j]
        heldout = camera.quality.get("heldout_rms_px")
        title = f"{camera.name}: RMS {camera.quality['rms_px']:.3f} px"
        title += f", held-out {heldout:.3f} px" if heldout is not None else ", none held out"
        ax.scatter(mine[:, 0], mine[:, 1], s=2, alpha=0.5)
        if heldout is not None:
            ax.add_patch(plt.Circle((0, 0), heldout, fill=False, color="C3", lw=1))
        ax.set_xlim(-limit, limit)
        ax.set_ylim(limit, -limit)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=8)
        ax.set_xlabel(RESIDUAL_LABEL, fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(f"held-out corners ({len(residuals)}, {len(result.heldout_images)} views), "
                 "circle: the camera's held-out RMS", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def write_volume_report(result: CalibrationResult, out_dir: str | os.PathLike,
                        board: Board | None = None, sigma_maps: Sequence[Path] = ()) -> list[Path]:
    """``layout.png``, ``heldout_residuals.png`` and ``index.html`` in ``out_dir`` (see the module docstring);
    ``sigma_maps``: heat-map PNGs already in ``out_dir``, shown on the page.

    Returns
    -------
    list of Path
        The files written.
    """
    directory = Path(out_dir)
    layout = _plot_layout(result, board, directory / "layout.png")
    heldout = _plot_heldout(result, directory / "heldout_residuals.png")
    views = {camera.name: 0 for camera in result.rig.cameras}
    for name, _ in result.images:
        views[name] += 1
    held = {camera.name: 0 for camera in result.rig.cameras}
    for name, _ in result.heldout_images:
        held[name] += 1
    units = html.escape(result.rig.units)
    rows = []
    for camera in result.rig.cameras:
        heldout_rms = camera.quality.get("heldout_rms_px")
        rows.append(
            f"<tr><td>{html.escape(camera.name)}</td>"
            f"<td class='num'>{', '.join(f'{v:.4f}' for v in camera.c)}</td>"
            f"<td class='num'>{camera.K[0, 0]:.2f}</td><td class='num'>{camera.quality['rms_px']:.4f}</td>"
            f"<td class='num'>{'-' if heldout_rms is None else f'{heldout_rms:.4f}'}</td>"
            f"<td class='num'>{views[camera.name]}</td><td class='num'>{held[camera.name]}</td></tr>")
    summary = html.escape(result.summary())
    sigma = ""
    if sigma_maps:
        images = "".join(f'<img class="sigma" src="{html.escape(quote(Path(path).name))}" '
                         f'alt="projection sigma {html.escape(Path(path).stem)}" width="560"> ' for path in sigma_maps)
        sigma = ("<h2>Projection uncertainty</h2>\n<p>Worst-direction sigma of the projected pixel (rays at the "
                 "distance in each title), from the calibration's covariance: sampling noise, not model error. Each "
                 f"scale runs from 0 to the map's worst value.</p>\n<p id=\"sigma\">{images}</p>\n")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>camcal: {len(result.rig.cameras)}-camera calibration</title>
<style>{PAGE_STYLE}</style></head><body>
<h1>{len(result.rig.cameras)}-camera calibration</h1>
<p id="summary">{summary}</p>
<h2>Camera layout</h2>
<p><img id="layout" src="{layout.name}" alt="camera layout from above and from the side"></p>
<h2>Cameras</h2>
<table id="cameras"><thead><tr><th>camera</th><th>centre ({units})</th><th>fx (px)</th><th>RMS (px)</th>
<th>held-out RMS (px)</th><th>views solved</th><th>views held out</th></tr></thead>
<tbody>{''.join(rows)}</tbody></table>
<h2>Held-out residuals</h2>
<p><img id="heldout" src="{heldout.name}" alt="held-out residuals per camera"></p>
{sigma}</body></html>
"""
    index = directory / "index.html"
    atomic_write_text(index, page)
    return [layout, heldout, index]
