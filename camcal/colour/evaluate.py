"""Judging a characterisation honestly: Delta E statistics, leave-one-out, plots.

Every colour difference comes from colour-science (``colour.delta_E``):
CIE 1976, CIE 1994, CMC (l:c = 2:1) and CIE 2000, computed in CIELAB with
the white of the target space. Statistics are reported on three sets:

``train``
    the training patches, predicted by the model fitted on all of them;
``loo``
    leave-one-out: each training patch predicted by the model refitted
    without it (the model choice, objective and regularisation held fixed);
``test``
    an independent patch set, when one is given.

Conventions: ``XYZ`` is relative with ``Y = 1`` for the perfect white of the
target space; ``white_XYZ`` is that white (its Y is 1).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_path

__all__ = [
    "DELTA_E_METHODS",
    "XYZ_to_Lab",
    "delta_E",
    "DeltaEStats",
    "ColourFitResult",
    "leave_one_out_predictions",
    "evaluate_model",
    "patch_table",
    "write_patch_table",
    "plot_report",
]

DELTA_E_METHODS = ("CIE 1976", "CIE 1994", "CMC", "CIE 2000")


def XYZ_to_Lab(XYZ: Any, white_XYZ: Any) -> np.ndarray:
    """CIELAB of relative XYZ (white Y = 1) under the white ``white_XYZ``.

    Parameters
    ----------
    XYZ
        ``(..., 3)`` relative XYZ.
    white_XYZ
        XYZ of the reference white; only its chromaticity is used, the
        white's luminance is taken as Y = 1.

    Returns
    -------
    numpy.ndarray
        ``(..., 3)`` L*, a*, b*.

    Examples
    --------
    >>> [round(float(v), 6) + 0 for v in XYZ_to_Lab([0.9505, 1.0, 1.089], [0.9505, 1.0, 1.089])]
    [100.0, 0.0, 0.0]
    """
    import colour

    white = np.asarray(white_XYZ, dtype=np.float64)
    return colour.XYZ_to_Lab(np.asarray(XYZ, dtype=np.float64), colour.XYZ_to_xy(white))


def delta_E(
    XYZ_a: Any,
    XYZ_b: Any,
    white_XYZ: Any,
    method: str = "CIE 2000",
    reference_is_Lab: bool = False,
) -> np.ndarray:
    """Colour difference between two XYZ arrays (colour-science's formulas).

    Parameters
    ----------
    XYZ_a, XYZ_b
        ``(..., 3)`` relative XYZ; ``XYZ_b`` is CIELAB already when
        ``reference_is_Lab`` is true.
    white_XYZ
        White of the target space.
    method
        ``"CIE 1976"``, ``"CIE 1994"``, ``"CMC"`` or ``"CIE 2000"``.

    Returns
    -------
    numpy.ndarray
        ``(...)`` Delta E.

    References
    ----------
    Sharma, G., Wu, W., Dalal, E. N. (2005). The CIEDE2000 color-difference
    formula. Color Research & Application, 30(1), 21-30.

    Examples
    --------
    >>> w = [0.9505, 1.0, 1.089]
    >>> float(delta_E([0.2, 0.2, 0.2], [0.2, 0.2, 0.2], w))
    0.0
    """
    import colour

    if method not in DELTA_E_METHODS:
        raise CamcalError(
            f"unknown Delta E method {method!r}, expected one of: {', '.join(DELTA_E_METHODS)}"
        )
    Lab_a = XYZ_to_Lab(XYZ_a, white_XYZ)
    Lab_b = np.asarray(XYZ_b, dtype=np.float64) if reference_is_Lab else XYZ_to_Lab(XYZ_b, white_XYZ)
    return np.asarray(colour.delta_E(Lab_a, Lab_b, method=method), dtype=np.float64)


@dataclass(frozen=True)
class DeltaEStats:
    """Summary of a set of Delta E values (units: Delta E)."""

    n: int
    mean: float
    median: float
    p90: float
    p95: float
    max: float

    @classmethod
    def from_values(cls, values: Any) -> DeltaEStats:
        """Statistics of a 1-D array of Delta E (linear-interpolated percentiles)."""
        v = np.asarray(values, dtype=np.float64).ravel()
        if v.size == 0:
            raise CamcalError("no Delta E values to summarise")
        return cls(
            n=int(v.size),
            mean=float(np.mean(v)),
            median=float(np.median(v)),
            p90=float(np.percentile(v, 90)),
            p95=float(np.percentile(v, 95)),
            max=float(np.max(v)),
        )

    def to_dict(self) -> dict:
        return {"n": self.n, "mean": self.mean, "median": self.median,
                "p90": self.p90, "p95": self.p95, "max": self.max}

    def __str__(self) -> str:
        return (f"mean {self.mean:.2f}, median {self.median:.2f}, p95 {self.p95:.2f}, "
                f"max {self.max:.2f} (n = {self.n})")


def leave_one_out_predictions(
    fit: Callable[[np.ndarray, np.ndarray], Any], RGB: Any, XYZ: Any
) -> np.ndarray:
    """Predict each patch from a model refitted without it.

    Parameters
    ----------
    fit
        ``fit(RGB, XYZ) -> model`` with ``model.apply(RGB) -> XYZ``; every
        choice (model, objective, regularisation) must be fixed inside it.
    RGB, XYZ
        ``(N, 3)`` training data.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` leave-one-out predicted XYZ.
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    N = RGB.shape[0]
    out = np.empty_like(XYZ)
    keep = np.ones(N, dtype=bool)
    for i in range(N):
        keep[i] = False
        out[i] = fit(RGB[keep], XYZ[keep]).apply(RGB[i : i + 1])[0]
        keep[i] = True
    return out


@dataclass(frozen=True, eq=False)
class ColourFitResult:
    """A fitted model with its CIEDE2000 on training, leave-one-out and test.

    ``delta_E_*`` are per-patch arrays (``delta_E_test`` is ``None`` without
    an independent set); ``stats_*`` summarise them.
    """

    model: Any
    delta_E_train: np.ndarray
    delta_E_loo: np.ndarray | None
    delta_E_test: np.ndarray | None
    XYZ_loo: np.ndarray | None = None

    @property
    def stats_train(self) -> DeltaEStats:
        return DeltaEStats.from_values(self.delta_E_train)

    @property
    def stats_loo(self) -> DeltaEStats | None:
        return None if self.delta_E_loo is None else DeltaEStats.from_values(self.delta_E_loo)

    @property
    def stats_test(self) -> DeltaEStats | None:
        return None if self.delta_E_test is None else DeltaEStats.from_values(self.delta_E_test)

    def evaluation_dict(self) -> dict:
        """The ``evaluation`` block of the fit file."""
        return {
            "metric": "CIE 2000",
            "train": self.stats_train.to_dict(),
            "loo": None if self.stats_loo is None else self.stats_loo.to_dict(),
            "test": None if self.stats_test is None else self.stats_test.to_dict(),
        }


def evaluate_model(
    fit: Callable[[np.ndarray, np.ndarray], Any],
    RGB: Any,
    XYZ: Any,
    white_XYZ: Any,
    *,
    test: tuple[Any, Any] | None = None,
    loo: bool = True,
    model: Any = None,
) -> ColourFitResult:
    """Fit on all patches and report CIEDE2000 on train, leave-one-out, test.

    Parameters
    ----------
    fit
        ``fit(RGB, XYZ) -> model`` (all choices fixed inside).
    RGB, XYZ
        ``(N, 3)`` training data (linear RGB, XYZ with white Y = 1).
    white_XYZ
        White of the target space.
    test
        ``(RGB_test, XYZ_test)`` of an independent patch set, or ``None``.
    loo
        Whether to compute the leave-one-out figures.
    model
        The model already fitted on all patches (refitted when ``None``).

    Returns
    -------
    ColourFitResult
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    if model is None:
        model = fit(RGB, XYZ)
    dE_train = delta_E(model.apply(RGB), XYZ, white_XYZ)
    XYZ_loo = leave_one_out_predictions(fit, RGB, XYZ) if loo else None
    dE_loo = None if XYZ_loo is None else delta_E(XYZ_loo, XYZ, white_XYZ)
    dE_test = None
    if test is not None:
        RGB_t, XYZ_t = (np.asarray(a, dtype=np.float64) for a in test)
        dE_test = delta_E(model.apply(RGB_t), XYZ_t, white_XYZ)
    return ColourFitResult(model, dE_train, dE_loo, dE_test, XYZ_loo)


def patch_table(
    names: Sequence[str], XYZ_ref: Any, XYZ_pred: Any, white_XYZ: Any
) -> list[dict]:
    """Per-patch rows: reference and predicted CIELAB and the four Delta E."""
    Lab_r = XYZ_to_Lab(XYZ_ref, white_XYZ)
    Lab_p = XYZ_to_Lab(XYZ_pred, white_XYZ)
    dE = {m: delta_E(XYZ_pred, XYZ_ref, white_XYZ, method=m) for m in DELTA_E_METHODS}
    rows = []
    for i, name in enumerate(names):
        row = {"name": name}
        for j, c in enumerate(("L", "a", "b")):
            row[f"{c}_ref"] = float(Lab_r[i, j])
        for j, c in enumerate(("L", "a", "b")):
            row[f"{c}_pred"] = float(Lab_p[i, j])
        for m in DELTA_E_METHODS:
            row["dE" + m.replace("CIE ", "").replace(" ", "")] = float(dE[m][i])
        rows.append(row)
    return rows


def write_patch_table(path: str | os.PathLike, rows: list[dict]) -> None:
    """Write :func:`patch_table` rows as CSV (atomically)."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})


def _XYZ_to_display(XYZ: np.ndarray, white_XYZ: Any) -> np.ndarray:
    """sRGB (0-1, clipped) of XYZ for swatches, adapted to D65 with CAT02."""
    import colour

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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
