"""The ``colour match --report`` files: difference images, Delta E maps or chart plots."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_path
from camcal.base.extras import require
from camcal.colour.difference import delta_E
from camcal.colour.match.routes import MatchResult, target_space
from camcal.io.frames import imwrite
from camcal.report.colour_plots import plot_report

__all__ = [
    "write_report",
]


# --------------------------------------------------------------------------
# Report


def _display(RGB: np.ndarray, peak: float) -> np.ndarray:
    """8-bit BGR for viewing: linear RGB / peak, sRGB encoded, NaN black."""
    colour = require("colour")

    encoded = colour.cctf_encoding(np.clip(np.nan_to_num(RGB / peak), 0, 1), function="sRGB")
    return np.round(255 * encoded[..., ::-1]).astype(np.uint8)


def _heat(values: np.ndarray, vmax: float) -> np.ndarray:
    """8-bit BGR colour map of a ``(H, W)`` map in [0, vmax] (NaN black)."""
    matplotlib = require("matplotlib")

    rgba = matplotlib.colormaps["inferno"](np.clip(np.nan_to_num(values, nan=0.0) / vmax, 0, 1))
    rgba[~np.isfinite(values)] = (0, 0, 0, 1)
    return np.round(255 * rgba[..., 2::-1]).astype(np.uint8)


def write_report(result: MatchResult, out_dir: str | os.PathLike, delta_E_max: float = 10.0) -> list[Path]:
    """Write the match report into ``out_dir``.

    Image route: ``target.png`` (A), ``source_before.png`` (B at A's pixels)
    and ``source_after.png`` (matched B), ``difference_before.png`` /
    ``difference_after.png`` (``|B - A|`` and ``|f(B) - A|``, x4, on the
    kept pixels), ``delta_E_before.png`` / ``delta_E_after.png``
    (CIEDE2000 maps, colour map 0 to ``delta_E_max``, black where no
    correspondence was kept) and ``valid.png`` (white: kept pixels). Chart
    route: the swatches, histogram and a*b* plots of
    :func:`camcal.report.colour_plots.plot_report`, reference A and prediction
    ``f(B)``, both through A's characterisation. Both: ``summary.txt``.

    Returns
    -------
    list of Path
    """
    directory = Path(out_dir)
    directory.mkdir(parents=True, exist_ok=True)
    to_XYZ, white, _ = target_space(result.fit_target)
    written: list[Path] = []
    corr = result.correspondences
    if corr is None:
        names = [f"patch{i + 1}" for i in range(result.train_source.shape[0])]
        written += plot_report(directory, names, to_XYZ(result.train_target),
                               to_XYZ(result.match.apply(result.train_source)), white,
                               title=f"{result.match.source} -> {result.match.target}: {result.match.model.label}")
    else:
        A = corr.target
        B = corr.source
        after = result.match.apply(np.nan_to_num(B.reshape(-1, 3))).reshape(B.shape)
        after[~np.isfinite(B)] = np.nan
        peak = float(np.nanpercentile(A, 99.5)) or 1.0
        keep = corr.valid[..., None]
        images = {
            "target.png": _display(A, peak),
            "source_before.png": _display(B, peak),
            "source_after.png": _display(after, peak),
            "difference_before.png": _display(np.where(keep, 4 * np.abs(B - A), np.nan), peak),
            "difference_after.png": _display(np.where(keep, 4 * np.abs(after - A), np.nan), peak),
            "valid.png": (255 * corr.valid).astype(np.uint8),
        }
        for name, pred in (("delta_E_before.png", B), ("delta_E_after.png", after)):
            dE = np.full(corr.valid.shape, np.nan)
            dE[corr.valid] = delta_E(to_XYZ(pred[corr.valid]), to_XYZ(A[corr.valid]), white)
            images[name] = _heat(dE, delta_E_max)
        for name, image in images.items():
            written.append(imwrite(directory / name, image))
    lines = [result.match.summary()]
    if corr is not None:
        counts = corr.counts
        lines.append(f"pixels: {counts['valid']} kept of {counts['total']} (disparity {counts['disparity']}, "
                     f"left-right consistent {counts['consistent']}, away from depth edges {counts['smooth']}); "
                     f"A is the {'left' if corr.a_is_left else 'right'} view")
        lines.append(f"Delta E maps: colour map 0 to {delta_E_max:g}, black where no correspondence was kept")
    path = directory / "summary.txt"
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    written.append(path)
    return written
