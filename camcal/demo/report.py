"""The demo's plots and its static HTML report."""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.demo.core import COLOUR_EXPORTS_SECTION, DemoContext, DemoReport, format_number
from camcal.report import RESIDUAL_LABEL
from camcal.report.figures import pyplot, save_figure
from camcal.model.rig import Camera

__all__ = [
    "img_tag",
    "plot_epipolar",
    "plot_images",
    "plot_residuals",
    "write_html",
]


def img_tag(ctx: DemoContext, path: Path, width: int | None = None) -> str:
    rel = os.path.relpath(Path(path).resolve(), ctx.out_dir.resolve())
    size = f' width="{width}"' if width else ""
    return f'<a href="{html.escape(rel)}"><img src="{html.escape(rel)}" alt="{html.escape(Path(rel).stem)}"{size}></a>'


def plot_images(path: Path, images: Sequence[str], titles: Sequence[str], columns: int) -> Path:
    import cv2  # noqa: PLC0415

    plt = pyplot()
    rows = -(-len(images) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for ax, image, title in zip(axes.ravel(), images, titles):
        data = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
        data = data.astype(np.float64) / (65535.0 if data.dtype == np.uint16 else 255.0)
        if data.ndim == 3:
            data = data[..., ::-1]
        ax.imshow(np.clip(data, 0, 1) ** (1 / 2.2) if "linear" in title else data, cmap="gray")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    for ax in axes.ravel()[len(images):]:
        ax.axis("off")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_residuals(path: Path, cameras: Sequence[Camera], camera_of_point: NDArray, points_px: NDArray,
                    residuals_px: NDArray, what: str = "corner", max_arrows: int = 3000) -> Path:
    """Reprojection residuals (observed - projected, :mod:`camcal.report`): vectors over each camera's image (at most
    ``max_arrows``, a fixed random subset), and the spread of all of them."""
    plt = pyplot()
    rng = np.random.default_rng(0)
    fig, axes = plt.subplots(2, len(cameras), figsize=(5.2 * len(cameras), 8.0), squeeze=False)
    for j, camera in enumerate(cameras):
        mine = camera_of_point == j
        points, residuals = points_px[mine], residuals_px[mine]
        width, height = camera.image_size
        ax = axes[0, j]
        gain = 0.03 * width / max(float(np.percentile(np.linalg.norm(residuals, axis=1), 99)), 1e-9)
        shown = np.sort(rng.choice(len(points), min(len(points), max_arrows), replace=False))
        ax.quiver(points[shown, 0], points[shown, 1], residuals[shown, 0], -residuals[shown, 1], color="tab:red",
                  angles="xy", scale_units="xy", scale=1 / gain, width=0.003)
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{camera.name}: residuals x{gain:.0f} (RMS {camera.quality['rms_px']:.3f} px)", fontsize=10)
        ax = axes[1, j]
        ax.scatter(residuals[:, 0], residuals[:, 1], s=3, alpha=0.5)
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_aspect("equal")
        ax.set_xlabel(f"x: {RESIDUAL_LABEL}")
        ax.set_ylabel(f"y: {RESIDUAL_LABEL}")
        ax.set_title(f"{camera.name}: {len(residuals)} {what} residuals", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_epipolar(path: Path, left: Path, right: Path) -> Path:
    import cv2  # noqa: PLC0415

    plt = pyplot()
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in (left, right)]
    height = max(image.shape[0] for image in images)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, image, title in zip(axes, images, ("left (rectified)", "right (rectified)")):
        ax.imshow(image, cmap="gray", vmin=0, vmax=255)
        for y in np.linspace(0.05 * height, 0.95 * height, 12):
            ax.axhline(y, color="tab:orange", lw=0.7)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    return save_figure(fig, path)


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;line-height:1.45;padding:0 1em}
h1{margin-bottom:0}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.88em;width:100%}th,td{padding:.25em .5em;border-bottom:1px solid #e4e4e4}
td.num{text-align:right;font-variant-numeric:tabular-nums}tr.pass td.ok{color:#137333;font-weight:600}
tr.fail{background:#fce8e6}tr.fail td.ok{color:#a50e0e;font-weight:700}
pre{background:#f6f8fa;padding:.6em;overflow-x:auto;font-size:.85em}img{max-width:100%;margin:.3em 0}
.verdict{font-size:1.2em;font-weight:600}.verdict.pass{color:#137333}.verdict.fail{color:#a50e0e}
.placeholder{color:#666;font-style:italic}
"""


def write_html(report: DemoReport, out_dir: str | os.PathLike) -> Path:
    """Write ``out_dir/report.html``: static, offline (inline CSS, images by relative path).

    Sections: verdict, the recovered-vs-true table, each stage's sections,
    the outputs (relative links), the colour exports section
    (:data:`COLOUR_EXPORTS_SECTION`) and the time per stage.
    """
    from camcal import __version__  # noqa: PLC0415
    from camcal.base.atomic import atomic_write_text  # noqa: PLC0415

    out_dir = Path(out_dir)
    n_fail = len(report.failed)
    verdict = (f'<p class="verdict pass" id="verdict">All {len(report.rows)} recovered values are within tolerance.</p>'
               if not n_fail else
               f'<p class="verdict fail" id="verdict">{n_fail} of {len(report.rows)} values are outside tolerance.</p>')
    rows = "".join(
        f'<tr class="{"pass" if row.ok else "fail"}"><td>{html.escape(row.stage)}</td><td>{html.escape(row.quantity)}</td>'
        f'<td class="num">{format_number(row.true)}</td><td class="num">{format_number(row.recovered)}</td><td class="num">{format_number(row.error)}</td>'
        f'<td class="num">{format_number(row.tolerance)}</td><td>{html.escape(row.unit)}</td>'
        f'<td class="ok">{"pass" if row.ok else "FAIL"}</td><td>{html.escape(row.source)}</td></tr>'
        for row in report.rows
    )
    table = ('<table id="truth-table"><thead><tr><th>stage</th><th>quantity</th><th>true</th><th>recovered</th>'
             '<th>error</th><th>tolerance</th><th>unit</th><th>ok</th><th>tolerance from</th></tr></thead>'
             f"<tbody>{rows}</tbody></table>")
    sections = "".join(
        f'<section id="{html.escape(s.anchor)}"><h2>{html.escape(s.title)}</h2>{s.body}</section>' for s in report.sections
    )
    links = []
    for label, path in report.outputs:
        rel = os.path.relpath(Path(path).resolve(), out_dir.resolve())
        links.append(f'<li><a href="{html.escape(rel)}">{html.escape(label)}</a> <code>{html.escape(rel)}</code></li>')
    exports = [s for s in report.sections if s.anchor == COLOUR_EXPORTS_SECTION]
    exports_html = "" if exports else (
        f'<section id="{COLOUR_EXPORTS_SECTION}"><h2>Colour exports: OCIO config and ICC profiles</h2>'
        '<p class="placeholder">Not produced by this run: the colour export stage (OCIO colour spaces, '
        'ICC camera profiles) adds its links here.</p></section>')
    timing = "".join(f"<tr><td>{html.escape(n)}</td><td class='num'>{s:.1f}</td></tr>" for n, s in report.seconds)
    stages = ", ".join(n for n, _ in report.seconds)
    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>camcal demo report</title>'
        f"<style>{_CSS}</style></head><body>"
        f"<h1>camcal demo</h1><p>camcal {__version__}: a stereo rig rendered with Blender, calibrated by camcal, "
        f"compared with the truth. Stages: {html.escape(stages)}.</p>"
        f'{verdict}<section id="truth"><h2>Recovered vs true</h2>{table}</section>{sections}{exports_html}'
        f'<section id="outputs"><h2>Outputs</h2><ul>{"".join(links)}</ul></section>'
        f'<section id="timing"><h2>Time per stage (s)</h2><table>{timing}</table></section>'
        "</body></html>\n"
    )
    path = out_dir / "report.html"
    atomic_write_text(path, page)
    return path
