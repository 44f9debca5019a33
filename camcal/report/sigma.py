"""Sigma maps drawn as heat maps with a colour bar (``calibrate board --report``, ``stmap --report``, the demo).

A map holds, per pixel, a standard deviation (:mod:`camcal.geometry.uncertainty`,
:mod:`camcal.geometry.rectify.sigma`): the heat map shows it on a
perceptually ordered scale (viridis) from 0 to its largest value, with
contour lines, NaN pixels (no source pixel) in grey, and the worst and
median values in the title.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_path
from camcal.base.extras import require
from camcal.geometry.uncertainty import projection_sigma_map
from camcal.model.rig import Camera
from camcal.report.figures import pyplot

__all__ = ["heatmap_image", "plot_sigma_map", "write_heatmap_png", "write_sigma_heatmaps"]


def plot_sigma_map(sigma: NDArray, path: str | os.PathLike, title: str, unit: str = "px") -> Path:
    """Write a PNG heat map of one sigma map with its colour bar, atomically.

    Parameters
    ----------
    sigma : ndarray, shape (H, W)
        The map; NaN pixels are drawn grey.
    path : path
        The PNG to write.
    title : str
        First line of the title; the worst and median values are added.
    unit : str
        Of the values (the colour bar's label).
    """
    plt = pyplot()

    values = np.asarray(sigma, dtype=np.float64)
    finite = values[np.isfinite(values)]
    worst = float(finite.max()) if finite.size else float("nan")
    median = float(np.median(finite)) if finite.size else float("nan")
    height, width = values.shape
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * height / width + 0.9))
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.6")
    image = ax.imshow(np.ma.masked_invalid(values), cmap=cmap, vmin=0.0, vmax=worst if finite.size else 1.0,
                      interpolation="nearest")
    if finite.size and worst > 0:
        levels = np.linspace(0.0, worst, 7)[1:-1]
        lines = ax.contour(np.where(np.isfinite(values), values, np.nan), levels=levels, colors="white",
                           linewidths=0.6)
        ax.clabel(lines, fmt="%.3g", fontsize=7)
    ax.set_title(f"{title}\nworst {worst:.3g} {unit}, median {median:.3g} {unit}", fontsize=9)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04, label=f"sigma ({unit})")
    fig.tight_layout()
    target = Path(path)
    with atomic_path(target, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return target


def heatmap_image(sigma: NDArray, vmax: float | None = None) -> NDArray[np.uint8]:
    """The map as a (H, W, 3) RGB heat map, pixel for pixel: viridis from 0 to ``vmax`` (default: its largest
    value), NaN pixels black. For overlays (the Blender add-on's camera background)."""
    matplotlib = require("matplotlib")

    values = np.asarray(sigma, dtype=np.float64)
    finite = values[np.isfinite(values)]
    top = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    scaled = np.clip(np.nan_to_num(values, nan=0.0) / max(top, 1e-300), 0.0, 1.0)
    rgb = np.round(255 * matplotlib.colormaps["viridis"](scaled)[..., :3]).astype(np.uint8)
    rgb[~np.isfinite(values)] = 0
    return rgb


def write_heatmap_png(sigma: NDArray, path: str | os.PathLike, vmax: float | None = None) -> Path:
    """Write :func:`heatmap_image` as an 8-bit PNG, atomically; the scale's top is in the PNG's text
    (``camcal.sigma_max``, pixels)."""
    from PIL import Image, PngImagePlugin  # noqa: PLC0415

    values = np.asarray(sigma, dtype=np.float64)
    finite = values[np.isfinite(values)]
    top = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    info = PngImagePlugin.PngInfo()
    info.add_text("camcal.sigma_max", f"{top:.6g}")
    target = Path(path)
    with atomic_path(target, suffix=".png") as tmp:
        Image.fromarray(heatmap_image(values, top)).save(tmp, format="PNG", pnginfo=info)
    return target


def write_sigma_heatmaps(cameras: Sequence[Camera], out_dir: str | os.PathLike,
                         distance: float | None = None) -> list[Path]:
    """``sigma_<camera>.png`` in ``out_dir``: each camera's projection-sigma map (plate pixels, rays at
    ``distance``, None: infinity) as a heat map; cameras without ``quality.covariance`` are skipped."""
    written = []
    where = "at infinity" if distance is None else f"at distance {distance:g}"
    for camera in cameras:
        if camera.quality.covariance is None:
            continue
        sigma = projection_sigma_map(camera, distance)
        written.append(plot_sigma_map(sigma, Path(out_dir) / f"sigma_{camera.name}.png",
                                      f"{camera.name}: projection sigma {where}"))
    return written
