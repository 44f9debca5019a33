"""``model="auto"``: every lens model (and the board's shape) ranked by views held out.

Every model of :data:`AUTO_MODELS` is fitted with every k-th training frame held out (:func:`rank_models`); the
simplest within :data:`AUTO_MARGIN` of the lowest held-out RMS is kept (:func:`simplest_within_margin`). A
correction field or a board surface is taken only when it is better held out by more than :data:`AUTO_MARGIN` and
by more than one standard error of the paired per-view differences (:func:`spline_chosen`; Hastie, Tibshirani &
Friedman 2009, section 7.10). :func:`with_board_shape` chooses the board's surface on the same folds.

The folds cost a fit per fold; one camera's models and surfaces are first screened by the leave-one-view-out
error estimated from their one fit on every training view (:mod:`camcal.geometry.zhang_loo`, no refit), and only
the finalists within noise of the best are fitted fold by fold.

References
----------
Hastie, T., Tibshirani, R. & Friedman, J. (2009). The Elements of Statistical Learning, 2nd ed., section 7.10.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.board import Board
from camcal.geometry.board_shape import AUTO_SHAPES, SHAPE_SPECS, n_shape_params
from camcal.geometry.spline_fit import fit_spline_lens, grid_shape
from camcal.geometry.zhang_fit import calibrate_model, posed_residuals
from camcal.geometry.zhang_loo import leave_one_view_out, leave_one_view_out_on_shape
from camcal.geometry.zhang_refit import SPLINE_SUFFIX, calibrate_shaped, fit_shape, shape_specs, surface_fit
from camcal.geometry.zhang_result import CalibrationResult, ModelScore, fold_radius_px, quality_problems
from camcal.geometry.zhang_starts import FIT_ERRORS, MIN_IMAGES, MODELS, one_line

__all__ = ["AUTO_MODELS", "AUTO_MARGIN", "with_board_shape", "simplest_within_margin", "SPLINE_MIN_VIEWS",
           "rank_models", "SCREEN_MARGIN", "MAX_FINALISTS", "spline_chosen", "BOARD_SHAPES", "SHAPE_LENSES", "SHAPE_TAG",
           "shape_choice", "shape_params", "model_estimates", "shaped_or_flat", "surface_lens"]

#: The models ``model="auto"`` chooses among, simplest first (the parsimony order): every model.
AUTO_MODELS = ("none", "division", "polynomial", "kannala-brandt", "opencv", "opencv-rational", "opencv-thin-prism",
               "kannala-brandt-thin-prism")


#: ``model="auto"`` keeps the simplest model whose cross-validated RMS is within this share of the best.
AUTO_MARGIN = 0.01


def with_board_shape(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      flat: CalibrationResult, board_shape: str, spec: str, scored: list[ModelScore], squared: dict,
                      corners: NDArray, fold_results: dict, training: list[dict], options: dict
                      ) -> tuple[CalibrationResult, tuple[ModelScore, ...], list[str]]:
    """``model="auto"``'s result on the board shape of ``board_shape`` (see :func:`calibrate_board`): the flat
    result, or a model refitted on the surface chosen (or named); with the shapes' ranking and notes.

    ``auto``: the shape is chosen for the flat-ranked ``model`` (:func:`shape_choice`; with a correction field,
    among its surfaces and its parametric lens's, against ``model`` on the flat board), then the lens model is
    ranked again on that surface (:func:`_lens_on_shape`) and, when that changes it, the shape is chosen again
    for the new lens (the flat board among the candidates); the pair taken is printed in the notes."""
    if board_shape == "flat":
        return flat, (), []
    picked = model
    notes: list[str] = []
    if not spec:
        model, notes = surface_lens(model, scored)
        if model is None:
            return flat, (), []
    base = model.removesuffix(SPLINE_SUFFIX)
    flat_score = next((s for s in scored if s.model == model), None)
    shape_ranking: tuple[ModelScore, ...] = ()
    chosen = model
    if not spec:
        if (len(names) > 1 or flat_score is None or base not in fold_results or options["loss"] != "trivial"
                or len(training[0]) < SPLINE_MIN_VIEWS):
            return flat, (), []
        folds = fold_results["folds"]
        fits = fold_results.setdefault("shape_fits", {})
        shapes = _score_shapes(board, training[0], model, folds, fold_results[base], corners, squared, fits=fits,
                               screen=fold_results)
        if base != model:  # the field's parametric lens on every surface too: a surface may do the field's work
            shapes += _score_shapes(board, training[0], base, folds, fold_results[base], corners, squared, fits=fits,
                                    screen=fold_results)
        lens, spec = shape_choice(flat_score, shapes, squared)
        ranked = [flat_score, *shapes]
        if spec and lens != model:
            notes.append(f"board shape auto: {lens} on the {spec} surface beats {model} on the flat board held out "
                         f"(the surface chosen among {model}'s and {lens}'s)")
            model = lens
        if spec:
            done = {s.model for s in shapes}
            lenses = [s for lens in AUTO_MODELS if lens != model and lens in fold_results and lens in SHAPE_LENSES
                      and f"{lens}{SHAPE_TAG}{spec}" not in done
                      for s in _score_shapes(board, training[0], lens, folds, fold_results[lens], corners, squared,
                                             (spec,), fits)]
            ranked += lenses
            chosen = _lens_on_shape(model, spec, [*shapes, *lenses], squared)
            if chosen != model:
                have = {s.model for s in ranked}
                again = _score_shapes(board, training[0], chosen, folds, fold_results[chosen], corners, squared,
                                      tuple(s for s in shape_specs(board, AUTO_SHAPES)
                                            if f"{chosen}{SHAPE_TAG}{s}" not in have), fits, fold_results)
                chosen_flat = next(s for s in scored if s.model == chosen)
                ranked += [chosen_flat] * (chosen not in have) + again
                lens_shapes = [s for s in ranked if s.model.startswith(f"{chosen}{SHAPE_TAG}")]
                respec = shape_choice(chosen_flat, lens_shapes, squared)[1]
                notes.append(f"board shape auto: {chosen} ranked first on the {spec} surface "
                             f"({model} on the flat board); "
                             + (f"its surface: {respec}" if respec else f"flat beats every surface for it, "
                                f"{model} on {spec} kept"))
                chosen, spec = (chosen, respec) if respec else (model, spec)
            if not chosen.endswith(SPLINE_SUFFIX):
                plain = next(s for s in ranked if s.model == f"{chosen}{SHAPE_TAG}{spec}")
                field = [s for s in ranked if s.model == f"{chosen}{SPLINE_SUFFIX}{SHAPE_TAG}{spec}"]
                if not field:  # not scored yet (a field on the flat-ranked lens was)
                    field = _score_shapes(board, training[0], chosen + SPLINE_SUFFIX, folds, fold_results[chosen],
                                          corners, squared, (spec,), fits)
                    ranked += field
                if spline_chosen(field[0], plain, squared):
                    chosen += SPLINE_SUFFIX
        shape_ranking = tuple(sorted(ranked, key=lambda s: (s.rms_px is None, not s.screened_out,
                                                            s.rms_px or s.estimate_px or 0.0)))
        if not spec:
            return flat, shape_ranking, notes + ["board shape auto: flat (no surface beats the flat board held out)"]
    return shaped_or_flat(board, names, by_frame, chosen, holdout, spec, flat, chosen == picked, board_shape,
                          shape_ranking, notes, options)


def shaped_or_flat(board: Board, names: list[str], by_frame: list[dict], chosen: str, holdout: set[int], spec: str,
                   flat: CalibrationResult, from_flat: bool, board_shape: str, shape_ranking: tuple[ModelScore, ...],
                   notes: list[str], options: dict, fits: dict | None = None
                   ) -> tuple[CalibrationResult, tuple[ModelScore, ...], list[str]]:
    """``chosen`` refitted on the surface ``spec`` (:func:`calibrate_shaped`; from ``flat`` when ``from_flat`` and
    ``chosen`` has no correction field; ``fits``: surface fits already made), or ``flat`` with the reason when that
    fit fails or fails the quality gate (:func:`quality_problems`, a lens folding inside the image); with the
    shapes' ranking and the notes."""
    try:
        shaped = calibrate_shaped(board, names, by_frame, chosen, holdout, spec,
                                   flat=flat if from_flat and not chosen.endswith(SPLINE_SUFFIX) else None,
                                   fits=fits, **options)
    except FIT_ERRORS as error:
        return flat, shape_ranking, notes + [f"board shape: {chosen} on the {spec} surface failed "
                                             f"({one_line(error)}); flat kept"]
    problems = quality_problems(shaped)
    radius = fold_radius_px(shaped.rig.cameras[0])
    if radius is not None:
        problems.append(f"the lens folds {radius:.0f} px from the principal point, inside the image")
    if problems:
        return flat, shape_ranking, notes + [f"board shape: {chosen} on the {spec} surface fails the quality gate "
                                             f"({'; '.join(problems)}); flat kept"]
    return shaped, shape_ranking, notes + [f"board shape auto: {chosen} on {spec} chosen by held-out error"
                                           if board_shape == "auto" else f"board shape: {spec}"]


def simplest_within_margin(scores: list[ModelScore]) -> str:
    """The simplest model (:data:`AUTO_MODELS`' order) whose cross-validated RMS is within :data:`AUTO_MARGIN` of
    the best of ``scores`` (each scored, none with a correction field)."""
    limit = (1.0 + AUTO_MARGIN) * min(s.rms_px for s in scores)
    return min((s.model for s in scores if s.rms_px <= limit), key=AUTO_MODELS.index)


def surface_lens(model: str, scored: Sequence[ModelScore]) -> tuple[str | None, list[str]]:
    """The lens the board's surface is chosen with: ``model`` when it has a surface fit (:data:`SHAPE_LENSES`),
    else (OpenCV's own fit has no surface path) the simplest scored lens within :data:`AUTO_MARGIN` of the best
    that has one, said in a note; ``None`` when no scored lens has one."""
    if model.removesuffix(SPLINE_SUFFIX) in SHAPE_LENSES:
        return model, []
    capable = [s for s in scored if s.model in SHAPE_LENSES]
    if not capable:
        return None, []
    lens = simplest_within_margin(capable)
    return lens, [f"board shape auto: {model} (ranked on the flat board) has no surface fit; the surface is "
                  f"chosen with {lens}, the simplest lens within {100 * AUTO_MARGIN:g} % of the best that has one"]


def _lens_on_shape(model: str, spec: str, scores: list[ModelScore], squared: dict) -> str:
    """The lens model taken on the surface ``spec``: among the parametric models scored there
    (``<lens>@board-<spec>``), the simplest (order of :data:`AUTO_MODELS`) within :data:`AUTO_MARGIN` of the
    best, as on the flat board; ``model`` with a correction field stays when its score on ``spec`` beats the
    best parametric one there by :func:`spline_chosen`'s rule."""
    on = {s.model.rsplit(SHAPE_TAG, 1)[0]: s for s in scores
          if s.rms_px is not None and s.model.endswith(f"{SHAPE_TAG}{spec}")}
    parametric = [s for lens, s in on.items() if not lens.endswith(SPLINE_SUFFIX)]
    if not parametric:
        return model
    best = min(parametric, key=lambda s: s.rms_px)
    if model.endswith(SPLINE_SUFFIX) and model in on and spline_chosen(on[model], best, squared):
        return model
    limit = (1.0 + AUTO_MARGIN) * best.rms_px
    return min((s.model.rsplit(SHAPE_TAG, 1)[0] for s in parametric if s.rms_px <= limit), key=AUTO_MODELS.index)


#: Most folds of the leave-views-out cross-validation of ``model="auto"``.
_AUTO_FOLDS = 4


#: ``model="auto"`` scores the best model with a correction field from this many training views (one camera).
SPLINE_MIN_VIEWS = 8


def rank_models(board: Board, names: list[str], training: list[dict], options: dict, fold_results: dict | None = None
                 ) -> tuple[tuple[ModelScore, ...], dict[str, NDArray[np.float64]], NDArray[np.float64]]:
    """Every model of :data:`AUTO_MODELS` (and the best one with a correction field) scored by leave-views-out
    cross-validation, best first, with each model's squared error per held-out view.

    Notes
    -----
    The training frames are split into ``k = min(4, n)`` folds (every k-th
    frame); each model is fitted k times, each time without one fold, whose
    views are then posed by PnP with the fitted intrinsics held
    (:func:`heldout_figures`); the fold fits are scoring fits (no covariance,
    jackknife or sigmas: :func:`calibrate_model`'s ``scoring``) and the models
    of a fold share OpenCV's model-free starts (:func:`opencv_start`'s
    ``shared``). The score is the RMS over all held-out corners
    of all folds, ``sqrt(sum_folds sum |r|^2 / N)``. A model that fails in
    any fold (the fit refused or diverged, a held-out view not posable,
    a non-finite error) is ranked out with the reason, never raised.
    With fewer than ``MIN_IMAGES + 1`` frames nothing can be held out and
    every model is ranked out.

    One camera: the folds are fitted only for the finalists of a screen
    (:func:`_screen`): every model fitted once on every training frame, its
    leave-one-view-out error estimated from that fit
    (:func:`camcal.geometry.zhang_loo.leave_one_view_out`), and the models
    within :data:`SCREEN_MARGIN` of the best estimate or not worse than it by
    two standard errors of the paired per-view differences kept, at most
    :data:`MAX_FINALISTS` (the simplest within :data:`AUTO_MARGIN` of the
    best estimate always among them); the others are ranked out as screened
    (:attr:`ModelScore.estimate_px`), after the scored models, best
    estimate first.

    One camera with at least :data:`SPLINE_MIN_VIEWS` training frames and
    the plain least-squares loss: the best-scored model is also scored
    with a correction field (:mod:`camcal.geometry.spline_fit`), fitted
    in each fold from that fold's fit of the model, as ``<model>+spline``.

    Returns
    -------
    scores, squared (model -> sum of ``|r|^2`` of each held-out view, the same views in the same order for every
    scored model), corners (the number of corners of each of those views); ``fold_results``, when given, gets
    ``"folds"`` (the folds) and every scored model's fit in each fold.
    """
    frames = sorted(set().union(*[set(views) for views in training]))
    n_folds = min(_AUTO_FOLDS, len(frames))
    if len(frames) < MIN_IMAGES + 1:
        reason = f"{len(frames)} views: too few to hold one out (need {MIN_IMAGES + 1})"
        return tuple(ModelScore(m, None, 4 + len(MODELS[m]), reason) for m in AUTO_MODELS), {}, np.zeros(0)
    folds = [set(frames[k::n_folds]) for k in range(n_folds)]
    held_views = [(j, f) for fold in folds for j in range(len(names)) for f in sorted(fold) if f in training[j]]
    corners = np.array([len(training[j][f].ids) for j, f in held_views], dtype=np.float64)
    scores, squared = [], {}
    fold_results = {} if fold_results is None else fold_results
    fold_results["folds"] = folds
    shared: dict = {}  # the OpenCV starts every model of a fold shares
    screened = _screen(board, names, training, options, shared, fold_results) if len(names) == 1 else {}
    for candidate in AUTO_MODELS:
        if candidate in screened:
            scores.append(screened[candidate])
            continue
        per_view, results, reason = [], [], ""
        for fold in folds:
            try:
                result = calibrate_model(board, names, training, candidate, fold, scoring=True, shared=shared, **options)
            except FIT_ERRORS as error:
                reason = one_line(error)
                break
            if result.heldout_rms_px is None or not np.all(np.isfinite(result.heldout_view_rms_px)):
                reason = "non-finite held-out error"
                break
            per_view.extend(result.heldout_view_rms_px)
            results.append(result)
        n_params = 4 + len(MODELS[candidate])
        if not reason:
            squared[candidate] = np.square(per_view) * corners
            fold_results[candidate] = results
        scores.append(ModelScore(candidate, None if reason else float(np.sqrt(squared[candidate].sum() / corners.sum())),
                                 n_params, reason))
    fitted = [score for score in scores if score.rms_px is not None]
    if fitted and len(names) == 1 and len(frames) >= SPLINE_MIN_VIEWS and options["loss"] == "trivial":
        base = min(fitted, key=lambda score: score.rms_px).model
        scores.append(_score_spline(board, names[0], training[0], base, folds, fold_results[base], corners, squared))
    ranked = sorted(scores, key=lambda s: (s.rms_px is None, not s.screened_out, s.rms_px or s.estimate_px or 0.0,
                                           s.n_params))
    return tuple(ranked), squared, corners


#: The screen keeps for the exact folds the models whose estimate is within this share of the best estimate ...
SCREEN_MARGIN = 0.03
#: ... at most this many of them.
MAX_FINALISTS = 3


def _screen(board: Board, names: list[str], training: list[dict], options: dict,
            shared: dict, store: dict) -> dict[str, ModelScore]:
    """The models of :data:`AUTO_MODELS` that the exact folds of :func:`rank_models` need not fit: each one
    ranked out, as refused by its fit on every training frame (with the reason) or screened out by its
    leave-one-view-out estimate (:func:`camcal.geometry.zhang_loo.leave_one_view_out`).

    Kept (not in the result): the models whose estimated RMS is within :data:`SCREEN_MARGIN` of the best or
    whose paired per-view differences from the best are within two standard errors of zero (the noise of the
    ranking itself), the :data:`MAX_FINALISTS` best of them, the simplest within :data:`AUTO_MARGIN` of the best
    estimate replacing the last when it is not among them. Nothing is screened when no estimate could be made.
    ``store`` gets ``"full"`` (each model's fit on every training frame) and ``"estimates"`` (each model's
    estimated ``sum |r|^2`` per training frame, the frames in order), which the board shapes' screen starts from.
    """
    estimates, failed = model_estimates(board, names, training, options, shared, store)
    if not estimates:
        return {}
    corners = sum(len(d.ids) for views in training for d in views.values())
    rms = {m: float(np.sqrt(sq.sum() / corners)) for m, sq in estimates.items()}
    best = min(rms, key=rms.get)

    def within_noise(model: str) -> bool:
        d = estimates[model] - estimates[best]
        return len(d) > 1 and float(d.sum()) <= 2.0 * float(np.sqrt(len(d)) * np.std(d, ddof=1))

    kept = sorted((m for m in rms if rms[m] <= (1.0 + SCREEN_MARGIN) * rms[best] or within_noise(m)), key=rms.get)
    finalists = kept[:MAX_FINALISTS]
    simplest = min((m for m in rms if rms[m] <= (1.0 + AUTO_MARGIN) * rms[best]), key=AUTO_MODELS.index)
    if simplest not in finalists:
        finalists[-1] = simplest
    screened = {m: ModelScore(m, None, 4 + len(MODELS[m]), f"screened out: {rms[m]:.4f} px estimated leave one view "
                              f"out from its one fit ({100 * (rms[m] / rms[best] - 1):.1f} % above the best "
                              f"estimate, {best})", rms[m]) for m in rms if m not in finalists}
    return {**failed, **screened}


def model_estimates(board: Board, names: list[str], training: list[dict], options: dict, shared: dict, store: dict
                    ) -> tuple[dict[str, NDArray[np.float64]], dict[str, ModelScore]]:
    """Every model of :data:`AUTO_MODELS` fitted once on every training frame (a scoring fit; ``shared``:
    :func:`opencv_start`'s) and its leave-one-view-out error estimated from that fit
    (:func:`camcal.geometry.zhang_loo.leave_one_view_out`): ``(estimates, failed)``, each model's estimated
    ``sum |r|^2`` per training view (the views ``(camera, frame)`` in order) and the models refused, ranked out
    with the reason. ``store`` gets ``"full"`` (each model's fit) and ``"estimates"``."""
    estimates, failed = {}, {}
    fulls = store.setdefault("full", {})
    for candidate in AUTO_MODELS:
        n_params = 4 + len(MODELS[candidate])
        try:
            full = calibrate_model(board, names, training, candidate, set(), scoring=True, shared=shared, **options)
            per_view = leave_one_view_out(board, full, candidate, names, training)
        except FIT_ERRORS as error:
            failed[candidate] = ModelScore(candidate, None, n_params, one_line(error))
            continue
        estimates[candidate] = np.array([per_view[key] for key in sorted(per_view)])
        fulls[candidate] = full
    store["estimates"] = estimates
    return estimates, failed


def _score_spline(board: Board, name: str, views: dict, base: str, folds: list[set[int]],
                  results: list[CalibrationResult], corners: NDArray, squared: dict) -> ModelScore:
    """``<base>+spline`` scored on the folds of :func:`rank_models` (adds its per-view errors to ``squared``)."""
    model = base + SPLINE_SUFFIX
    nx, ny = grid_shape(next(iter(views.values())).image_size)
    n_params = 4 + len(MODELS[base]) + 2 * nx * ny
    per_view = []
    for fold, result in zip(folds, results):
        camera = result.rig.cameras[0]
        kept = {image for _, image in result.images}
        train = {f: d for f, d in views.items() if f not in fold and d.image in kept}
        try:
            fit = fit_spline_lens(board, train, camera.K, camera.distortion, MODELS[base])
            splined = dataclasses.replace(camera, K=fit.K, distortion=fit.distortion)
            per_view.extend(float(np.sum(r * r)) for r in
                            (posed_residuals(board, splined, views[f]) for f in sorted(fold) if f in views))
        except FIT_ERRORS as error:
            return ModelScore(model, None, n_params, one_line(error))
    per_view = np.asarray(per_view)
    if not np.all(np.isfinite(per_view)):
        return ModelScore(model, None, n_params, "non-finite held-out error")
    squared[model] = per_view
    return ModelScore(model, float(np.sqrt(per_view.sum() / corners.sum())), n_params)


def spline_chosen(spline: ModelScore, base: ModelScore, squared: dict[str, NDArray]) -> bool:
    """True when the correction field's cross-validated error is below its model's by more than
    :data:`AUTO_MARGIN` and by more than one standard error of the paired per-view differences.

    The views are the units (their corners' errors are correlated): with ``d_v`` the difference of
    squared errors of view ``v`` (model minus model with the field), ``sum_v d_v > sqrt(V) sd(d)``
    (the one-standard-error rule, Hastie, Tibshirani & Friedman 2009, section 7.10, on paired differences).
    """
    if spline.rms_px is None or base.rms_px is None or spline.rms_px >= (1.0 - AUTO_MARGIN) * base.rms_px:
        return False
    d = squared[base.model] - squared[spline.model]
    return len(d) > 1 and float(d.sum()) > float(np.sqrt(len(d)) * np.std(d, ddof=1))


#: ``board_shape`` values: chosen by held-out error, flat, or a named shape.
BOARD_SHAPES = ("auto", "flat") + SHAPE_SPECS


#: The lens models a board surface is fitted with (opencv-thin-prism is OpenCV's fit: no surface path).
SHAPE_LENSES = tuple(m for m in AUTO_MODELS if m != "opencv-thin-prism")


#: The name of a lens model fitted on a board shape in :attr:`CalibrationResult.shape_ranking`: ``<model>@board-<shape>``.
SHAPE_TAG = "@board-"


def _score_shapes(board: Board, view_sets: dict, model: str, folds: list[set[int]],
                  results: list[CalibrationResult], corners: NDArray, squared: dict,
                  specs: Sequence[str] | None = None, fits: dict | None = None,
                  screen: dict | None = None) -> list[ModelScore]:
    """``<model>@board-<shape>`` for every shape of ``specs`` (default: every shape of :data:`AUTO_SHAPES` the
    board holds), scored on the folds of :func:`rank_models` from each fold's flat fit (adds each one's per-view
    squared errors to ``squared``; ``fits``: :func:`fit_shape`'s). ``screen``: :func:`_screen`'s store; with it,
    a parametric ``model`` and several shapes, the shapes are screened first (:func:`_screen_shapes`) and only
    the finalists are fitted fold by fold."""
    specs = shape_specs(board, AUTO_SHAPES) if specs is None else tuple(specs)
    scores = []
    if (screen is not None and len(specs) > 1 and not model.endswith(SPLINE_SUFFIX)
            and model in screen.get("full", {})):
        specs, scores = _screen_shapes(board, view_sets, model, specs, screen, fits)
    for spec in specs:
        name = f"{model}{SHAPE_TAG}{spec}"
        n_params = shape_params(board, view_sets, model, spec)
        per_view, reason = [], ""
        for fold, result in zip(folds, results):
            train = {f: d for f, d in view_sets.items() if f not in fold}
            try:
                camera, shape, _, _ = fit_shape(board, result, train, model, spec, fits)
                points = shape.points(board)
                per_view.extend(float(np.sum(r * r)) for r in
                                (posed_residuals(board, camera, view_sets[f], points) for f in sorted(fold)
                                 if f in view_sets))
            except FIT_ERRORS as error:
                reason = one_line(error)
                break
        if not reason and not np.all(np.isfinite(per_view)):
            reason = "non-finite held-out error"
        if not reason:
            squared[name] = np.asarray(per_view)
        scores.append(ModelScore(name, None if reason else float(np.sqrt(squared[name].sum() / corners.sum())),
                                 n_params, reason))
    return scores


def shape_params(board: Board, view_sets: dict, model: str, spec: str) -> int:
    """The parameters of ``model`` (lens, correction field) on the surface ``spec``."""
    n_params = 4 + len(MODELS[model.removesuffix(SPLINE_SUFFIX)]) + n_shape_params(board, spec)
    if model.endswith(SPLINE_SUFFIX):
        n_params += 2 * math.prod(grid_shape(next(iter(view_sets.values())).image_size))
    return n_params


def _screen_shapes(board: Board, view_sets: dict, model: str, specs: Sequence[str], screen: dict,
                   fits: dict | None) -> tuple[tuple[str, ...], list[ModelScore]]:
    """The shapes of ``specs`` worth the folds for the parametric lens ``model``, and the others ranked out.

    Each surface is fitted once on every training frame from the model's fit there (:func:`_screen`'s) and its
    leave-one-view-out error estimated from that fit
    (:func:`camcal.geometry.zhang_loo.leave_one_view_out_on_shape`). Kept: the shapes whose estimate is below
    the flat board's estimate, the :data:`MAX_FINALISTS` best of them, the one with fewest parameters within
    :data:`AUTO_MARGIN` of the best estimate replacing the last when it is not among them (the rule of
    :func:`shape_choice` takes a shape only when it beats the flat board held out; among those, the one with
    fewest parameters within the margin). A shape whose fit fails on every frame is ranked out with the reason.
    """
    full, flat = screen["full"][model], screen["estimates"][model]
    corners = sum(len(d.ids) for d in view_sets.values())
    estimates, out = {}, []
    for spec in specs:
        try:
            fit = surface_fit(board, full, view_sets, model, spec, fits)
            per_view = leave_one_view_out_on_shape(board, fit, MODELS[model], view_sets)
        except FIT_ERRORS as error:
            out.append(ModelScore(f"{model}{SHAPE_TAG}{spec}", None, shape_params(board, view_sets, model, spec),
                                  one_line(error)))
            continue
        estimates[spec] = float(np.sqrt(sum(per_view.values()) / corners))
    flat_rms = float(np.sqrt(flat.sum() / corners))
    better = sorted((spec for spec in estimates if estimates[spec] < flat_rms), key=estimates.get)
    finalists = better[:MAX_FINALISTS]
    if better:
        best = estimates[better[0]]
        simplest = min((spec for spec in better if estimates[spec] <= (1.0 + AUTO_MARGIN) * best),
                       key=lambda spec: n_shape_params(board, spec))
        if simplest not in finalists:
            finalists[-1] = simplest
    for spec, rms in estimates.items():
        if spec not in finalists:
            out.append(ModelScore(f"{model}{SHAPE_TAG}{spec}", None, shape_params(board, view_sets, model, spec),
                                  f"screened out: {rms:.4f} px estimated leave one view out from its one fit "
                                  f"(flat board {flat_rms:.4f} px)", rms))
    return tuple(spec for spec in specs if spec in finalists), out


def shape_choice(flat: ModelScore, shapes: list[ModelScore], squared: dict) -> tuple[str, str]:
    """``(lens, shape)`` taken among ``shapes`` (``<lens>@board-<shape>``; ``("", "")``: the flat board, ``flat``):
    the one with fewest parameters within :data:`AUTO_MARGIN` of the best among those better than ``flat`` by more
    than :data:`AUTO_MARGIN` and one standard error of the paired per-view differences (:func:`spline_chosen`'s
    rule)."""
    better = [s for s in shapes if s.rms_px is not None and spline_chosen(s, flat, squared)]
    if not better:
        return "", ""
    best = min(s.rms_px for s in better)
    simplest = min((s for s in better if s.rms_px <= (1.0 + AUTO_MARGIN) * best), key=lambda s: s.n_params)
    lens, spec = simplest.model.rsplit(SHAPE_TAG, 1)
    return lens, spec
