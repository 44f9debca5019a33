"""``--model auto``: choose the model, objective and regularisation by held-out error, the simplest within a margin.

Candidates (stage 1, objective ``xyz``, all closed form):

- ``matrix3x3``;
- ``polynomial:7``, ``polynomial:10`` and ``root-polynomial:2``,
  ``root-polynomial:3``, each with the ridge ``lambda`` of
  :data:`RIDGE_GRID`;
- ``rbf:polyharmonic-3`` and ``rbf:thin-plate`` (smoothing chosen inside
  every fit by its own leave-one-out, so their LOO figure is nested).

Candidates with as many parameters per output as patches minus two are
skipped. Stage 2 refits the :data:`N_REFINE` best linear-terms candidates of
stage 1 with the ``de2000`` objective (same ``lambda``). Stage 3 averages
each of those with its ``xyz`` fit (objective ``xyz+de2000``): both fit the
same terms, so the mean of their coefficients is one model of those terms
whose predictions, held out too, are the mean of theirs; its leave-one-out
figure needs no refit. Averaging two fits the patches cannot tell apart
lowers the variance of the prediction (model averaging: Breiman 1996,
Bagging predictors, Machine Learning 24; Hastie et al. 2009, 8.8): in the
five cases measured (Nikon 5100 under D65 and A, Sigma SDMerill under
D65, the demo's rendered Sigma SDMerill chart) its leave-one-out was the
lowest of the three, and on the independent set it lay between the two
fits, within 1.8 % of the better one.

Stage 4 shrinks each chart candidate with more terms than the matrix toward
the ``matrix3x3`` fit of its objective: the blend ``(1 - alpha) f + alpha
f_3x3`` (``shrinkage``, :func:`camcal.colour.fit.fitting.fit_linear_terms`),
one model of the candidate's terms, whose leave-one-out predictions are the
blend of the two fits' (no refit). The ``alpha`` of :data:`SHRINKAGE_GRID`
with the lowest leave-one-out is kept when it beats the unshrunk candidate.
Shrinking a many-parameter estimate toward a few-parameter one trades a
little bias for less variance (James & Stein 1961; the two-model case of
Breiman's 1996 stacked regressions, the weight chosen on held-out
predictions): the ridge ``lambda`` shrinks the non-linear coefficients
toward zero, which is not the 3x3 fit once the linear ones move with them.
The spectral route's candidates are not shrunk. The grid and the rule were
checked on scenes neither bench judges by: the Nikon 5100 and Sigma SDMerill
under D50, D75, FL2, FL7, FL11 and HP1 (0.2 % noise), judged on the 300
``Munsell validation`` colours: the pick's mean CIEDE2000 fell by 16 % on
average (6 to 30 %), worse in none of the 12; a grid up to 0.9 or in steps of
0.05 did no better, and the lowest score instead of the one-standard-error
rule did worse on one scene and no better on the others.

The score of a candidate is its leave-one-out mean CIEDE2000 over the
chart's patches (weighted by the patches' ``weights`` when given).
Leave-one-out over 24 patches is noisy: the lowest score is often a
chance winner (Sigma SDMerill under A: root-polynomial:3 at 2.481 on 190
independent colours where root-polynomial:2 gives 2.283). Parsimony, the
one-standard-error rule (Hastie, Tibshirani & Friedman 2009, The Elements
of Statistical Learning, 7.10): among the candidates whose score is within
one standard error of the best's (the standard error of the per-patch
differences from the best candidate, paired on the same patches), the
simplest is picked: the fewest terms, then the lower score. Simplicity is
the number of parameters only: the objectives (``xyz``, ``de2000`` and
their mean) fit the same terms, so between fits of one model the one with
the lowest held-out error is taken (a rule that preferred ``xyz`` as
simpler kept colour-science's Finlayson 2015 fit on the demo's Sigma
SDMerill, 1.729 on the independent set, where the mean gives 1.692).
When the export check (below) refuses candidates, the margin stays
anchored at the best candidate of all: the simplest exportable one within
it, else the exportable one with the lowest score (on the Sigma SDMerill
under A the best, root-polynomial:2, bakes to 0.24 and is refused; a
margin re-anchored at the next best would fall to the matrix, 2.876 on
the independent set, against 2.481 for the lowest score left).
On bench_colour's four scenes (Nikon 5100 under D65 and A, Sigma
SDMerill under D65 and A) the pick's mean CIEDE2000 on 190 independent
reflectances is 0.8, 2.4, 0.4 and 3.4 % above the best candidate's
(picks 0.779, 0.919, 1.852, 2.227; before stage 4 1.8, 1.2, 0.0 and 5.3 %
above, picks 0.794, 0.919, 1.916, 2.401); under A the Sigma's better
candidates, root-polynomial:2 shrunk with the de2000 and the mean objective,
fail the bake check, so the pick is the best that exports. Scoring on 300
Munsell colours rendered through the camera's sensitivities instead
(even the measured ones) did worse (8.7-13.6 %): those colours are not
the independent set's, and the chart's own patches held out judge better.
Other estimators of the chart's held-out error, judged first on
``bench/bench_colour_lights.py``'s 12 scenes (pick's gap to the best
candidate: mean 11.6 %, within 2 % on 3): repeated 6-fold
cross-validation (5 repeats) 11.7 %, bootstrap .632 (30 resamples;
Efron & Tibshirani 1997) 11.5 %: they rank the candidates as leave-one-out
does (the chart prefers the de2000 fits the off-chart colours do not).
Leave-one-out plus the jackknife spread of the refits over plausible
surface colours (Efron & Stein 1981) 15.8 % (under HP1 it picks the
matrix). That spread in place of the number of terms within the margin:
7.9 %, within 2 % on 6, worse on none; on bench_colour's scenes the Nikon
5100 under D65 and A fell to 1.017 and 1.000 x the floor, but the 15
cameras rose from 0.926 to 0.935 x colour-science's best (within 2 % on 6,
was 8) and ``--spectra`` on the Nikon under A from 0.919 to 0.942: not kept.

The spectral route (``spectral``: synthesised training colours,
:mod:`camcal.colour.fit.synthetic`): every linear-terms model is also
trained on those colours beside the chart's captures (anchors), with its
own ridge ``lambda`` (the grid's lowest ``xyz`` error on the synthesised
held-out colours) and, objective ``xyz``, with the chart's ``lambda`` too
(an unregularised root-polynomial:3 can fit the synthesised colours and
still fail the bake check outside them: Sigma SDMerill, bake errors up to
55); these candidates are scored on the synthesised held-out colours (``validation``)
with the same rule, and the spectral pick and the chart-only pick are
compared on the chart's patches held out (leave-one-out), the better one
written. Going down that order, each is fitted to all patches and handed to the exporters'
own check (``exportable``; ``colour fit`` passes
:func:`camcal.colour.bake.samples.bake_model` with the exporters' sizes: a
``matrix3x3`` is exact, any other model must bake within CIEDE2000 0.2 over
the chart gamut and plausible surface colours); the first that passes is
picked, the ones refused before it are recorded with their bake error. The
``matrix3x3`` always exports, so ``auto`` never picks a fit the OCIO and ICC
(v4) exporters refuse. White preserving variants are never picked by
``auto``: preserving the white is a constraint the user asks for, not an
accuracy choice.

The score of the pick is slightly optimistic (it won a selection on the
same colours): judge the pick on an independent patch set.
:meth:`Selection.ranking` prints every candidate: score, standard error of
its difference from the best, leave-one-out, bake error.
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

__all__ = ["RIDGE_GRID", "N_REFINE", "SHRINKAGE_GRID", "Candidate", "Selection", "fitter", "paired_standard_error",
           "select_model"]

RIDGE_GRID = (0.0, 1e-6, 1e-5, 1e-4, 1e-3)
N_REFINE = 3
#: weights ``alpha`` of the matrix3x3 fit blended into a chart candidate (stage 4): up to half, beyond which the
#: blend is more the matrix (itself a candidate) than the model
SHRINKAGE_GRID = (0.1, 0.2, 0.3, 0.4, 0.5)
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
    score: float = float("nan")
    score_se: float = 0.0
    validation_mean: float | None = None
    training: str = "chart"
    shrinkage: float = 0.0

    @property
    def n_params(self) -> int:
        return 1000 if self.spec.kind == "rbf" else len(self.spec.terms())

    @property
    def label(self) -> str:
        reg = f", lambda {self.regularisation:g}" if self.spec.kind != "rbf" else ""
        shrunk = f", shrunk {self.shrinkage:g} to matrix" if self.shrinkage else ""
        route = ", spectral" if self.training == "spectral" else ""
        return f"{self.spec.label} ({self.objective}{reg}{shrunk}{route})"

    def to_dict(self) -> dict:
        out = {"model": self.spec.label, "objective": self.objective,
               "regularisation": float(self.regularisation),
               "loo_mean": float(self.loo_mean), "loo_p95": float(self.loo_p95),
               "score": float(self.score), "score_se": float(self.score_se), "training": self.training}
        if self.shrinkage:
            out["shrinkage"] = float(self.shrinkage)
        if self.validation_mean is not None:
            out["validation_mean"] = float(self.validation_mean)
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
    rivals: tuple[Candidate, ...] = ()

    @property
    def best(self) -> Candidate:
        """The lowest score among the candidates trained like the pick (chart only or spectral)."""
        return min((c for c in self.candidates if c.training == self.picked.training), key=lambda c: c.score)

    @staticmethod
    def score_name_of(c: Candidate) -> str:
        return "held-out (synthesised)" if c.training == "spectral" else "leave-one-out"

    @property
    def reason(self) -> str:
        best = self.best
        refused = [c for c in self.candidates if c.exportable is False]
        within = self.picked.score <= best.score + self.picked.score_se + 1e-12
        text = (f"simplest of {len(self.candidates)} candidates within one standard error of the lowest "
                f"{self.score_name_of(self.picked)} mean CIEDE2000: {self.picked.score:.3f}" if within else
                f"lowest {self.score_name_of(self.picked)} mean CIEDE2000 of the {len(self.candidates)} candidates "
                f"that export (none within one standard error of the best does): {self.picked.score:.3f}")
        if best is not self.picked:
            text += f" against {best.score:.3f} for {best.label} (+{100 * (self.picked.score / best.score - 1):.1f} %)"
        else:
            text += " (the lowest)"
        if len(self.rivals) == 2:
            chart, spectral = self.rivals
            winner, loser = (spectral, chart) if self.picked is spectral else (chart, spectral)
            text += (f"; {'spectral route' if winner is spectral else 'chart-only fit'} written: on the chart's own "
                     f"patches held out (leave-one-out) {winner.label} gives {winner.loo_mean:.3f} against "
                     f"{loser.loo_mean:.3f} for {loser.label}")
        if refused:
            text += (f", once {len(refused)} candidate(s) failed the export bake check (CIEDE2000 over the chart "
                     "gamut and plausible surfaces: "
                     + ", ".join(f"{c.label} {c.bake_error_max if c.bake_error_max is not None else float('nan'):.2f}"
                                 for c in refused) + ")")
        return text

    def ranking(self, limit: int | None = None) -> list[str]:
        """One line per candidate, chart-only then spectral, best score first: score +- standard error (of the
        difference from the best of its kind), leave-one-out, synthesised held-out, bake error."""
        ranked = sorted(self.candidates, key=lambda c: (c.training, c.score))
        lines = []
        for c in ranked[:limit]:
            bake = ("" if c.exportable is None else "  bake: exact" if c.exportable and c.bake_error_max is None
                    else f"  bake max {c.bake_error_max:.3f}" if c.exportable else
                    f"  bake refused ({c.bake_error_max if c.bake_error_max is not None else float('nan'):.2f})")
            mark = "  <- picked" if c is self.picked else ""
            held = "" if c.validation_mean is None else f", synthesised held-out {c.validation_mean:.3f}"
            lines.append(f"  {c.label:54s} score {c.score:.3f} +- {c.score_se:.3f} "
                         f"(LOO {c.loo_mean:.3f}{held}){bake}{mark}")
        return lines

    def to_dict(self) -> dict:
        return {"method": "auto: simplest within one standard error of the lowest leave-one-out mean CIEDE2000 "
                          "(spectral candidates: synthesised held-out), among fits that export",
                "picked": self.picked.to_dict(), "reason": self.reason,
                "candidates": [c.to_dict() for c in self.candidates]}


def fitter(spec: ModelSpec, objective: str, lam: float, white_XYZ: Any, extra: tuple[Any, Any] | None = None,
           RGB_white: Any = None, shrinkage: float = 0.0) -> Callable[..., Any]:
    """``fit(RGB, XYZ, w=None) -> model`` with every choice fixed; with ``extra`` (synthesised RGB, XYZ) the
    spectral route: fitted on the patches given (the chart's captures, anchors) beside ``extra``, the anchors
    together weighing as much as all of ``extra``; ``shrinkage`` toward the matrix3x3 fit as
    :func:`camcal.colour.fit.fitting.fit_linear_terms` does."""
    def fit(R, X, w=None):
        if extra is not None:
            n, m = len(R), len(extra[0])
            anchor = (np.ones(n) if w is None else np.asarray(w, dtype=np.float64) / np.mean(w)) * m / n
            R, X = np.vstack([R, extra[0]]), np.vstack([X, extra[1]])
            w = np.concatenate([anchor, np.ones(m)])
        return fit_model(spec, R, X, objective=objective, regularisation=lam, white_XYZ=white_XYZ, weights=w,
                         RGB_white=RGB_white, shrinkage=shrinkage)

    return fit


def _predictions(spec: ModelSpec, objective: str, lam: float, RGB, XYZ, white_XYZ, weights, validation,
                 extra=None):
    """Leave-one-out XYZ of every patch and, with a validation set, the XYZ predicted for it."""
    fit = fitter(spec, objective, lam, white_XYZ, extra)
    loo = leave_one_out_predictions(fit, RGB, XYZ, weights)
    held = None if validation is None else fit(RGB, XYZ, weights).apply(validation[0])
    return loo, held


def _spectral_lambda(spec: ModelSpec, RGB, XYZ, white_XYZ, weights, validation, extra) -> float:
    """The ridge ``lambda`` of :data:`RIDGE_GRID` whose ``xyz`` fit on the chart and the synthesised training
    colours gives the lowest mean CIEDE2000 on the synthesised held-out colours. The chart's leave-one-out
    choice does not carry over: hundreds of training colours need less ridge than 24 patches (Sigma SDMerill
    under D65, root-polynomial:3 trained there: 1.36 held out at lambda 0, 1.88 at the chart's 1e-6)."""
    if spec.kind == "matrix3x3":
        return 0.0
    scores = [(float(np.mean(delta_E(fitter(spec, "xyz", lam, white_XYZ, extra)(RGB, XYZ, weights).apply(
        validation[0]), validation[1], white_XYZ))), lam) for lam in RIDGE_GRID]
    return min(scores)[1]


def paired_standard_error(errors: np.ndarray, best: np.ndarray, w: np.ndarray) -> float:
    """Standard error of the weighted mean of the paired differences ``d = errors - best``.

    ``sqrt(sum w^2 (d - dbar)^2) / sum w``, ``dbar = sum w d / sum w``: how far two candidates' held-out means
    on the same patches can be told apart.
    """
    d = errors - best
    mean = float(np.sum(w * d) / np.sum(w))
    return float(np.sqrt(np.sum(w**2 * (d - mean) ** 2)) / np.sum(w))


def select_model(
    RGB: Any,
    XYZ: Any,
    white_XYZ: Any,
    *,
    objectives: Sequence[str] = ("xyz", "de2000"),
    candidates: Sequence[str] | None = None,
    exportable: Callable[[Any], float | None] | None = None,
    weights: Any = None,
    validation: tuple[Any, Any] | None = None,
    spectral: tuple[Any, Any] | None = None,
) -> Selection:
    """Pick model, objective and ridge ``lambda`` by held-out CIEDE2000 with parsimony (module docstring).

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
    weights
        ``(N,)`` patch weights (signal-to-noise), used by every fit and the
        leave-one-out score.
    validation
        ``(RGB, XYZ)`` of held-out colours in the units of ``RGB`` and
        ``XYZ``: scores the spectral candidates; every candidate's mean
        CIEDE2000 on them is recorded (``validation_mean``).
    spectral
        ``(RGB, XYZ)`` of synthesised training colours (needs ``validation``):
        every linear-terms candidate also trained on them beside the chart's
        patches (the spectral route, :func:`fitter`). The simplest-within-margin
        spectral candidate and chart candidate are then compared on the
        chart's own patches held out (leave-one-out), the better one picked.

    Returns
    -------
    Selection
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    N = RGB.shape[0]
    if N < 6:
        raise CamcalError(f"--model auto needs at least 6 patches, got {N}")
    w = np.ones(N) if weights is None else np.asarray(weights, dtype=np.float64)
    if validation is not None:
        validation = tuple(np.asarray(a, dtype=np.float64) for a in validation)
    names = list(candidates) if candidates is not None else list(_LINEAR_CANDIDATES + _RBF_CANDIDATES)
    errors: dict[int, np.ndarray] = {}

    if spectral is not None and validation is None:
        raise CamcalError("the spectral candidates are scored on held-out colours: give validation too")
    extra = None if spectral is None else tuple(np.asarray(a, dtype=np.float64) for a in spectral)

    predictions: dict[int, tuple] = {}

    def candidate(spec: ModelSpec, objective: str, lam: float, route: str = "chart",
                  given: tuple | None = None, shrinkage: float = 0.0) -> Candidate:
        spectral_route = route == "spectral"
        loo_xyz, held_xyz = given if given is not None else _predictions(
            spec, objective, lam, RGB, XYZ, white_XYZ, weights, validation, extra if spectral_route else None)
        loo = delta_E(loo_xyz, XYZ, white_XYZ)
        held = None if held_xyz is None else delta_E(held_xyz, validation[1], white_XYZ)
        loo_mean = float(np.average(loo, weights=w))
        c = Candidate(spec, objective, lam, loo_mean, float(np.percentile(loo, 95)),
                      score=float(np.mean(held)) if spectral_route else loo_mean,
                      validation_mean=None if held is None else float(np.mean(held)), training=route,
                      shrinkage=shrinkage)
        errors[id(c)] = held if spectral_route else loo
        predictions[id(c)] = (loo_xyz, held_xyz)
        return c

    def averaged(fits: list[Candidate]) -> list[Candidate]:
        """The ``xyz+de2000`` mean of each de2000 fit and the xyz fit of its model, lambda and route: its
        predictions, held out too, are the mean of theirs (same terms), no refit needed."""
        out = []
        for d in (c for c in fits if c.objective == "de2000"):
            x = next((c for c in fits if c.objective == "xyz" and c.spec == d.spec and c.training == d.training
                      and c.regularisation == d.regularisation), None)
            if x is not None:
                (lx, hx), (ld, hd) = predictions[id(x)], predictions[id(d)]
                out.append(candidate(d.spec, "xyz+de2000", d.regularisation, d.training,
                                     ((lx + ld) / 2, None if hx is None else (hx + hd) / 2)))
        return out

    matrix_predictions: dict[str, tuple] = {}

    def matrix_fit(objective: str) -> tuple:
        """Leave-one-out (and validation) XYZ of the chart's matrix3x3 fit with ``objective``."""
        if objective not in matrix_predictions:
            if objective == "xyz+de2000":
                (lx, hx), (ld, hd) = matrix_fit("xyz"), matrix_fit("de2000")
                matrix_predictions[objective] = ((lx + ld) / 2, None if hx is None else (hx + hd) / 2)
            else:
                matrix_predictions[objective] = _predictions(parse_model_spec("matrix3x3"), objective, 0.0, RGB,
                                                             XYZ, white_XYZ, weights, validation)
        return matrix_predictions[objective]

    def shrunk(fits: list[Candidate]) -> list[Candidate]:
        """Each chart candidate with more terms than the matrix, blended with the matrix3x3 fit of its objective
        at the weight of :data:`SHRINKAGE_GRID` with the lowest leave-one-out, when that beats the unblended one:
        the blend's predictions, held out too, are the blend of theirs, no refit needed."""
        out = []
        for c in (c for c in fits if c.training == "chart" and c.spec.kind in ("polynomial", "root-polynomial")):
            (lc, hc), (lm, hm) = predictions[id(c)], matrix_fit(c.objective)
            blends = [(float(np.average(delta_E((1 - a) * lc + a * lm, XYZ, white_XYZ), weights=w)), a)
                      for a in SHRINKAGE_GRID]
            score, a = min(blends)
            if score < c.loo_mean:
                out.append(candidate(c.spec, c.objective, c.regularisation, "chart",
                                     ((1 - a) * lc + a * lm, None if hc is None else (1 - a) * hc + a * hm), a))
        return out

    stage1: list[Candidate] = []
    for name in names:
        spec = parse_model_spec(name)
        if spec.kind == "rbf":
            if N < 10:
                continue
            stage1.append(candidate(spec, "xyz", 0.0))
            continue
        T = len(spec.terms())
        grid = (0.0,) if spec.kind == "matrix3x3" else RIDGE_GRID
        for lam in grid:
            if lam == 0.0 and T > N - 2:
                continue
            stage1.append(candidate(spec, "xyz", lam))
    if not stage1:
        raise CamcalError(f"no model can be fitted to {N} patches")
    final = list(stage1) if "xyz" in objectives else []
    if "de2000" in objectives:
        linear = sorted((c for c in stage1 if c.spec.kind != "rbf"), key=lambda c: c.score)
        for c in linear[:N_REFINE]:
            final.append(candidate(c.spec, "de2000", c.regularisation))
    if extra is not None:
        seen = set()
        for c in sorted((c for c in stage1 if c.spec.kind != "rbf"), key=lambda c: c.score):
            if c.spec.label not in seen:  # each model once, with the lambda the synthesised held-out colours
                seen.add(c.spec.label)    # prefer and (in xyz) the chart's, a smoother fit should the first not bake
                lam = _spectral_lambda(c.spec, RGB, XYZ, white_XYZ, weights, validation, extra)
                if "xyz" in objectives:
                    final += [candidate(c.spec, "xyz", v, "spectral") for v in dict.fromkeys((lam, c.regularisation))]
                if "de2000" in objectives and len(seen) <= N_REFINE:
                    final.append(candidate(c.spec, "de2000", lam, "spectral"))
    if "xyz" in objectives and "de2000" in objectives:
        final += averaged(stage1 + final)
    final += shrunk(final)
    if not final:
        raise CamcalError("no candidate model for the objectives asked")
    def ew(c: Candidate) -> np.ndarray:
        return np.ones(len(validation[1])) if c.training == "spectral" else w

    remaining = list(final)
    checked: dict[int, Candidate] = {}
    scored = {}
    for route in ("chart", "spectral"):
        pool = [c for c in final if c.training == route]
        if pool:
            top = min(pool, key=lambda c: c.score)
            scored.update({id(c): replace(c, score_se=paired_standard_error(errors[id(c)], errors[id(top)], ew(c)))
                           for c in pool})

    def parsimonious(route: str) -> Candidate | None:
        pool = [c for c in remaining if c.training == route]
        if not pool:
            return None
        # the margin is one standard error from the best candidate of all, refused ones included: once the
        # export check has refused the best, simplicity is not bought with more than that
        best = min((c for c in final if c.training == route), key=lambda c: c.score)
        close = [c for c in pool
                 if c.score <= best.score + paired_standard_error(errors[id(c)], errors[id(best)], ew(c))]
        if not close:
            return min(pool, key=lambda c: c.score)
        return min(close, key=lambda c: (c.n_params, c.score))

    rivals: tuple = ()
    while True:
        picked = parsimonious("chart")
        rival = parsimonious("spectral")
        if rival is not None:
            rivals = tuple(x for x in (picked, rival) if x is not None)
            if picked is None or scored[id(rival)].loo_mean < scored[id(picked)].loo_mean:
                picked = rival
        if exportable is None:
            break
        model = fitter(picked.spec, picked.objective, picked.regularisation, white_XYZ,
                       extra if picked.training == "spectral" else None,
                       shrinkage=picked.shrinkage)(RGB, XYZ, weights)
        try:
            error = exportable(model)
        except CamcalError as refusal:
            reached = re.search(r"up to ([0-9.]+)", str(refusal))
            checked[id(picked)] = replace(scored[id(picked)], exportable=False,
                                          bake_error_max=float(reached.group(1)) if reached else None)
            remaining.remove(picked)
            if not remaining:
                raise CamcalError("no candidate model exports within the bake error") from None
            continue
        checked[id(picked)] = replace(scored[id(picked)], exportable=True, bake_error_max=error)
        break
    everything = tuple(checked.get(id(c), scored[id(c)]) for c in final)
    final_of = {id(c): x for c, x in zip(final, everything)}
    picked = final_of[id(picked)]
    return Selection(picked=picked, candidates=everything, rivals=tuple(final_of[id(r)] for r in rivals))
