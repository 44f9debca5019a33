"""``--model auto``: choose the model, objective and regularisation by LOO.

Candidates (stage 1, objective ``xyz``, all closed form):

- ``matrix3x3``;
- ``polynomial:7``, ``polynomial:10`` and ``root-polynomial:2``,
  ``root-polynomial:3``, each with the ridge ``lambda`` of
  :data:`RIDGE_GRID`;
- ``rbf:polyharmonic-3`` and ``rbf:thin-plate`` (smoothing chosen inside
  every fit by its own leave-one-out, so their LOO figure is nested).

Candidates with as many parameters per output as patches minus two are
skipped. Stage 2 refits the :data:`N_REFINE` best linear-terms candidates of
stage 1 with the ``de2000`` objective (same ``lambda``). Candidates are
ranked by leave-one-out mean CIEDE2000 over both stages; ties within
:data:`TIE` go to the simpler model (fewer terms, then ``xyz``). Going down
that ranking, each is fitted to all patches and handed to the exporters'
own check (``exportable``; ``colour fit`` passes
:func:`camcal.colour.bake.samples.bake_model` with the exporters' sizes: a
``matrix3x3`` is exact, any other model must bake within CIEDE2000 0.2 over
the chart gamut and plausible surface colours); the first that passes is
picked, the ones refused before it are recorded with their bake error. The
``matrix3x3`` always exports, so ``auto`` never picks a fit the OCIO and ICC
(v4) exporters refuse. White preserving variants are never picked by
``auto``: preserving the white is a constraint the user asks for, not an
accuracy choice.

The LOO figure of the pick is slightly optimistic (it won a selection on
the same patches): judge the pick on an independent patch set.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import re

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.difference import delta_E
from camcal.colour.fit.evaluate import leave_one_out_predictions
from camcal.colour.fit.fitting import fit_model
from camcal.colour.fit.terms import ModelSpec, parse_model_spec

__all__ = ["RIDGE_GRID", "N_REFINE", "TIE", "Candidate", "Selection", "select_model"]

RIDGE_GRID = (0.0, 1e-6, 1e-5, 1e-4, 1e-3)
N_REFINE = 3
TIE = 0.005
_LINEAR_CANDIDATES = ("matrix3x3", "polynomial:7", "polynomial:10", "root-polynomial:2", "root-polynomial:3")
_RBF_CANDIDATES = ("rbf:polyharmonic-3", "rbf:thin-plate")


@dataclass(frozen=True)
class Candidate:
    """One configuration tried by ``auto`` and its leave-one-out CIEDE2000."""

    spec: ModelSpec
    objective: str
    regularisation: float
    loo_mean: float
    loo_p95: float
    bake_error_max: float | None = None
    exportable: bool | None = None

    @property
    def n_params(self) -> int:
        return 1000 if self.spec.kind == "rbf" else len(self.spec.terms())

    @property
    def label(self) -> str:
        reg = f", lambda {self.regularisation:g}" if self.spec.kind != "rbf" else ""
        return f"{self.spec.label} ({self.objective}{reg})"

    def to_dict(self) -> dict:
        out = {"model": self.spec.label, "objective": self.objective,
               "regularisation": float(self.regularisation),
               "loo_mean": float(self.loo_mean), "loo_p95": float(self.loo_p95)}
        if self.exportable is not None:
            out["exportable"] = bool(self.exportable)
            if self.bake_error_max is not None:
                out["bake_error_max"] = float(self.bake_error_max)
        return out


@dataclass(frozen=True)
class Selection:
    """What ``auto`` picked, why, and every candidate it compared."""

    picked: Candidate
    candidates: tuple[Candidate, ...]

    @property
    def reason(self) -> str:
        ranked = sorted(self.candidates, key=lambda c: c.loo_mean)
        runner = next((c for c in ranked if c is not self.picked), None)
        refused = [c for c in self.candidates if c.exportable is False]
        text = (f"lowest leave-one-out mean CIEDE2000 {self.picked.loo_mean:.3f} "
                f"of {len(self.candidates)} candidates")
        if refused:
            text = (f"lowest leave-one-out mean CIEDE2000 {self.picked.loo_mean:.3f} of {len(self.candidates)} "
                    f"candidates once {len(refused)} better one(s) failed the export bake check (CIEDE2000 "
                    f"over the chart gamut and plausible surfaces: "
                    + ", ".join(f"{c.label} {c.bake_error_max if c.bake_error_max is not None else float('nan'):.2f}"
                               for c in refused) + ")")
        elif runner is not None:
            text += f" (next: {runner.label} at {runner.loo_mean:.3f})"
        return text

    def to_dict(self) -> dict:
        return {"method": "auto: leave-one-out mean CIEDE2000 among fits that export",
                "picked": self.picked.to_dict(), "reason": self.reason,
                "candidates": [c.to_dict() for c in self.candidates]}


def _loo_stats(spec: ModelSpec, objective: str, lam: float, RGB, XYZ, white_XYZ, RGB_white) -> tuple[float, float]:
    def fit(R, X):
        return fit_model(spec, R, X, objective=objective, regularisation=lam,
                         white_XYZ=white_XYZ, RGB_white=RGB_white)

    pred = leave_one_out_predictions(fit, RGB, XYZ)
    dE = delta_E(pred, XYZ, white_XYZ)
    return float(np.mean(dE)), float(np.percentile(dE, 95))


def select_model(
    RGB: Any,
    XYZ: Any,
    white_XYZ: Any,
    *,
    objectives: Sequence[str] = ("xyz", "de2000"),
    candidates: Sequence[str] | None = None,
    exportable: Callable[[Any], float | None] | None = None,
) -> Selection:
    """Pick model, objective and ridge ``lambda`` by leave-one-out CIEDE2000.

    Parameters
    ----------
    RGB, XYZ
        ``(N, 3)`` training patches (linear RGB, XYZ with white Y = 1).
    white_XYZ
        White of the target space.
    objectives
        Objectives allowed; ``("xyz",)`` skips stage 2, ``("de2000",)``
        runs stage 1 with ``xyz`` only to rank, then keeps de2000 fits.
    candidates
        Model names to try instead of the default list.
    exportable
        ``exportable(model) -> bake error max (None when exact)``, raising
        :class:`CamcalError` when the exporters refuse the model; ``None``
        skips the check (only for studies of the fits themselves: the pick
        may then not export).

    Returns
    -------
    Selection
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    N = RGB.shape[0]
    if N < 6:
        raise CamcalError(f"--model auto needs at least 6 patches, got {N}")
    names = list(candidates) if candidates is not None else list(_LINEAR_CANDIDATES + _RBF_CANDIDATES)
    stage1: list[Candidate] = []
    for name in names:
        spec = parse_model_spec(name)
        if spec.kind == "rbf":
            if N < 10:
                continue
            mean, p95 = _loo_stats(spec, "xyz", 0.0, RGB, XYZ, white_XYZ, None)
            stage1.append(Candidate(spec, "xyz", 0.0, mean, p95))
            continue
        T = len(spec.terms())
        grid = (0.0,) if spec.kind == "matrix3x3" else RIDGE_GRID
        for lam in grid:
            if lam == 0.0 and T > N - 2:
                continue
            mean, p95 = _loo_stats(spec, "xyz", lam, RGB, XYZ, white_XYZ, None)
            stage1.append(Candidate(spec, "xyz", lam, mean, p95))
    if not stage1:
        raise CamcalError(f"no model can be fitted to {N} patches")
    final = list(stage1) if "xyz" in objectives else []
    if "de2000" in objectives:
        linear = sorted((c for c in stage1 if c.spec.kind != "rbf"), key=lambda c: c.loo_mean)
        for c in linear[:N_REFINE]:
            mean, p95 = _loo_stats(c.spec, "de2000", c.regularisation, RGB, XYZ, white_XYZ, None)
            final.append(Candidate(c.spec, "de2000", c.regularisation, mean, p95))
    if not final:
        raise CamcalError("no candidate model for the objectives asked")
    remaining = list(final)
    checked: dict[int, Candidate] = {}
    while True:
        best = min(c.loo_mean for c in remaining)
        close = [c for c in remaining if c.loo_mean <= best + TIE]
        picked = min(close, key=lambda c: (c.n_params, c.objective != "xyz", c.loo_mean))
        if exportable is None:
            break
        model = fit_model(picked.spec, RGB, XYZ, objective=picked.objective, regularisation=picked.regularisation,
                          white_XYZ=white_XYZ)
        try:
            error = exportable(model)
        except CamcalError as refusal:
            reached = re.search(r"up to ([0-9.]+)", str(refusal))
            checked[id(picked)] = replace(picked, exportable=False,
                                          bake_error_max=float(reached.group(1)) if reached else None)
            remaining.remove(picked)
            if not remaining:
                raise CamcalError("no candidate model exports within the bake error") from None
            continue
        checked[id(picked)] = replace(picked, exportable=True, bake_error_max=error)
        break
    everything = tuple(checked.get(id(c), c) for c in final)
    if exportable is not None:
        picked = next(c for c in everything if c.exportable)
    return Selection(picked=picked, candidates=everything)
