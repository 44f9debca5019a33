"""Judging a characterisation honestly: leave-one-out, per-set Delta E, per-patch tables.

Statistics are reported on three sets:

``train``
    the training patches, predicted by the model fitted on all of them;
``loo``
    leave-one-out: each training patch predicted by the model refitted
    without it (the model choice, objective and regularisation held fixed);
``test``
    an independent patch set, when one is given.

The colour differences are :mod:`camcal.colour.difference`'s (colour-science).
Conventions: ``XYZ`` is relative with ``Y = 1`` for the perfect white of the
target space; ``white_XYZ`` is that white (its Y is 1).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.colour.difference import DELTA_E_METHODS, DeltaEStats, XYZ_to_Lab, delta_E

__all__ = ["leave_one_out_predictions", "ColourFitResult", "evaluate_model", "patch_table"]


def leave_one_out_predictions(
    fit: Callable[..., Any], RGB: Any, XYZ: Any, weights: Any = None
) -> np.ndarray:
    """Predict each patch from a model refitted without it.

    Parameters
    ----------
    fit
        ``fit(RGB, XYZ) -> model`` with ``model.apply(RGB) -> XYZ``; every
        choice (model, objective, regularisation) must be fixed inside it.
    RGB, XYZ
        ``(N, 3)`` training data.
    weights
        ``(N,)`` patch weights: when given, ``fit(RGB, XYZ, weights)`` is
        called with the kept patches' weights.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` leave-one-out predicted XYZ.
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    N = RGB.shape[0]
    weights = None if weights is None else np.asarray(weights, dtype=np.float64)
    out = np.empty_like(XYZ)
    keep = np.ones(N, dtype=bool)
    for i in range(N):
        keep[i] = False
        model = fit(RGB[keep], XYZ[keep]) if weights is None else fit(RGB[keep], XYZ[keep], weights[keep])
        out[i] = model.apply(RGB[i : i + 1])[0]
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
    weights: Any = None,
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
    weights
        ``(N,)`` patch weights handed to ``fit(RGB, XYZ, weights)`` (see
        :func:`leave_one_out_predictions`); the figures stay unweighted.

    Returns
    -------
    ColourFitResult
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    if model is None:
        model = fit(RGB, XYZ) if weights is None else fit(RGB, XYZ, weights)
    dE_train = delta_E(model.apply(RGB), XYZ, white_XYZ)
    XYZ_loo = leave_one_out_predictions(fit, RGB, XYZ, weights) if loo else None
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
