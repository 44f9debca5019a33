"""Colour report plots: reference vs predicted swatches, Delta E histogram, a*b* errors, sensitivity curves.

Written as PNG files with matplotlib's Agg backend.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from camcal.base.atomic import atomic_path
from camcal.base.extras import require
from camcal.colour.difference import DeltaEStats, XYZ_to_Lab, delta_E
from camcal.colour.spectral.sensitivities import Sensitivities
from camcal.report.figures import pyplot

__all__ = ["plot_report", "plot_sensitivities"]


def _XYZ_to_display(XYZ: np.ndarray, white_XYZ: Any) -> np.ndarray:
    """sRGB (0-1, clipped) of XYZ for swatches, adapted to D65 with CAT02."""
    colour = require("colour")

    white_D65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    XYZ_D65 = colour.chromatic_adaptation(
        XYZ, np.asarray(white_XYZ, dtype=np.float64), white_D65, method="Von Kries", transform="CAT02"
    )
    RGB = colour.XYZ_to_sRGB(XYZ_D65, apply_cctf_encoding=True)
    return np.clip(RGB, 0, 1)


def plot_report(
    directory: str | os.PathLike,
    names: Sequence[str],
    XYZ_ref: Any,
    XYZ_pred: Any,
    white_XYZ: Any,
    *,
    title: str = "",
    columns: int = 6,
) -> list[Path]:
    """Write the three report plots as PNG files in ``directory``.

    - ``swatches.png``: each patch split, reference (left) and prediction
      (right), shown as sRGB after CAT02 adaptation to D65, with its
      CIEDE2000;
    - ``delta_E_histogram.png``: histogram of CIEDE2000 with mean and p95;
    - ``ab_errors.png``: arrows on the a*b* plane from reference to
      prediction.

    Returns
    -------
    list of Path
        The files written.
    """
    plt = pyplot()

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    XYZ_ref = np.asarray(XYZ_ref, dtype=np.float64)
    XYZ_pred = np.asarray(XYZ_pred, dtype=np.float64)
    dE = delta_E(XYZ_pred, XYZ_ref, white_XYZ)
    stats = DeltaEStats.from_values(dE)
    written = []

    # Swatches
    n = len(names)
    rows = int(np.ceil(n / columns))
    ref_rgb = _XYZ_to_display(XYZ_ref, white_XYZ)
    pred_rgb = _XYZ_to_display(XYZ_pred, white_XYZ)
    fig, ax = plt.subplots(figsize=(1.6 * columns, 1.6 * rows + 0.6))
    for i in range(n):
        r, c = divmod(i, columns)
        y = rows - 1 - r
        ax.add_patch(plt.Rectangle((c, y + 0.14), 0.45, 0.8, color=ref_rgb[i]))
        ax.add_patch(plt.Rectangle((c + 0.45, y + 0.14), 0.45, 0.8, color=pred_rgb[i]))
        ax.text(c + 0.45, y + 0.06, f"{names[i][:14]}  {dE[i]:.2f}", ha="center", va="center", fontsize=6)
    ax.set_xlim(-0.05, columns)
    ax.set_ylim(-0.05, rows)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title(f"{title}\nreference (left) | predicted (right), CIEDE2000".strip(), fontsize=9)
    path = directory / "swatches.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    # Histogram
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.hist(dE, bins=min(30, max(5, n // 2)), color="0.45")
    ax.axvline(stats.mean, color="tab:blue", label=f"mean {stats.mean:.2f}")
    ax.axvline(stats.p95, color="tab:red", label=f"p95 {stats.p95:.2f}")
    ax.set_xlabel("CIEDE2000")
    ax.set_ylabel("patches")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    path = directory / "delta_E_histogram.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    # a*b* plane
    Lab_r = XYZ_to_Lab(XYZ_ref, white_XYZ)
    Lab_p = XYZ_to_Lab(XYZ_pred, white_XYZ)
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.scatter(Lab_r[:, 1], Lab_r[:, 2], c=ref_rgb, edgecolors="k", s=40, label="reference", zorder=3)
    ax.quiver(Lab_r[:, 1], Lab_r[:, 2], Lab_p[:, 1] - Lab_r[:, 1], Lab_p[:, 2] - Lab_r[:, 2],
              angles="xy", scale_units="xy", scale=1, width=0.004, color="tab:red", label="to predicted")
    ax.axhline(0, color="0.8", lw=0.5)
    ax.axvline(0, color="0.8", lw=0.5)
    ax.set_xlabel("a*")
    ax.set_ylabel("b*")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    path = directory / "ab_errors.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    written.append(path)
    return written


def plot_sensitivities(
    path: str | os.PathLike,
    sens: Sensitivities,
    truth: Sensitivities | None = None,
    title: str = "",
) -> Path:
    """Plot the curves with ``+-1.96 sigma`` bands and, if given, other curves to compare.

    ``sigma`` includes the smoothing bias (see
    :class:`~camcal.colour.spectral.estimate.SensitivityEstimate`): the nominal 95 %
    band covered 94.2 % of the true curves' samples on simulated cameras
    (89.6-96.9 % per case, 84-100 % per draw; tests/colour/spectral/test_colour_ssf.py, slow).

    ``truth`` is resampled on the grid and scaled by the common factor of
    :func:`camcal.colour.spectral.sensitivities.relative_rms_error`. Written with matplotlib's Agg backend.
    """
    plt = pyplot()

    path = Path(path)
    wl = sens.wavelengths
    fig, ax = plt.subplots(figsize=(7, 4))
    sigma = sens.sigma
    for ch, colour_name in enumerate(("tab:red", "tab:green", "tab:blue")):
        ax.plot(wl, sens.values[:, ch], color=colour_name, label=f"{'RGB'[ch]} ({sens.source})")
        if sigma is not None:
            ax.fill_between(wl, np.maximum(sens.values[:, ch] - 1.96 * sigma[:, ch], 0),
                            sens.values[:, ch] + 1.96 * sigma[:, ch], color=colour_name, alpha=0.2, linewidth=0)
    if truth is not None:
        other = truth.resampled(wl).values
        k = float(np.sum(sens.values * other) / np.sum(other * other))
        for ch, colour_name in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(wl, k * other[:, ch], "--", color=colour_name, linewidth=1,
                    label=f"{'RGB'[ch]} ({truth.camera or 'reference'})")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("relative sensitivity")
    band = ", band: 95 % (+-1.96 sigma)" if sigma is not None else ""
    ax.set_title((title + " " if title else "") + f"mu-factor {sens.mu_factor():.3f}{band}", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path
