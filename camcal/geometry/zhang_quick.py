"""``model="auto"`` at one fit per candidate: lens models and board shapes ranked by their leave-one-view-out error
estimated from that fit, without folds.

The thorough ranking (:mod:`camcal.geometry.zhang_rank`, ``thorough=True``) fits its finalists once per fold, scores
a correction field fold by fold and ranks the lens models again on the surface taken: dozens of fits. This ranking
fits every lens model of :data:`~camcal.geometry.zhang_rank.AUTO_MODELS` once on every training view and takes the
leave-one-view-out error of each from that one fit (:mod:`camcal.geometry.zhang_loo`: one Gauss-Newton step of the
problem without the view, Cook & Weisberg 1982), which is leave-one-out cross-validation (as many folds as views)
to first order. The rules are the thorough ranking's, on those errors: the simplest model within
:data:`~camcal.geometry.zhang_rank.AUTO_MARGIN` of the best (:func:`simplest_within_margin`), and a board surface
only when it beats the flat board by more than the margin and one standard error of the paired per-view
differences (:func:`~camcal.geometry.zhang_rank.shape_choice`; Hastie, Tibshirani & Friedman 2009, section 7.10).
Every surface of :data:`~camcal.geometry.board_shape.AUTO_SHAPES` is first scored at the taken lens's flat fit
(one Gauss-Newton step of each surface's fit, no iterations); only the two shapes the rule depends on are fitted,
and the surface taken is that fit (no fit repeated). No correction field is scored (name it:
``<model>+spline``, or run the thorough ranking).

References
----------
Cook, R. D. & Weisberg, S. (1982). Residuals and Influence in Regression. Chapman & Hall (case deletion).
Hastie, T., Tibshirani, R. & Friedman, J. (2009). The Elements of Statistical Learning, 2nd ed., section 7.10.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.board import Board
from camcal.geometry.board_shape import AUTO_SHAPES, flat_start, parse_shape
from camcal.geometry.zhang_loo import leave_one_view_out_on_shape
from camcal.geometry.zhang_rank import (SHAPE_LENSES, SHAPE_TAG, SPLINE_MIN_VIEWS,
                                        model_estimates, rank_models, shape_choice, shape_params, shaped_or_flat,
                                        simplest_within_margin, spline_chosen, surface_lens)
from camcal.geometry.zhang_refit import shape_specs, surface_fit
from camcal.geometry.zhang_result import CalibrationResult, ModelScore
from camcal.geometry.zhang_starts import FIT_ERRORS, MIN_IMAGES, MODELS, one_line

__all__ = ["rank_by_estimate", "shape_by_estimate"]


def rank_by_estimate(board: Board, names: list[str], training: list[dict], options: dict, store: dict
                     ) -> tuple[tuple[ModelScore, ...], dict[str, NDArray[np.float64]], NDArray[np.float64]]:
    """Every model of :data:`AUTO_MODELS` scored by its leave-one-view-out RMS estimated from its one fit on every
    training view (module docstring), best first; as :func:`camcal.geometry.zhang_rank.rank_models` returns.

    Returns
    -------
    scores (each scored one with ``rms_px`` = ``estimate_px`` = its estimate; a model whose fit or estimate failed
    ranked out with the reason), squared (model -> estimated ``sum |r|^2`` of each training view, the views
    ``(camera, frame)`` in order), corners (the number of corners of each of those views). ``store`` gets
    ``"full"`` (each model's fit on every training view) and ``"estimates"``.
    """
    frames = sorted(set().union(*[set(views) for views in training]))
    if len(frames) < MIN_IMAGES + 1:  # nothing can be held out: every model ranked out with the reason
        return rank_models(board, names, training, options, store)
    estimates, failed = model_estimates(board, names, training, options, {}, store)
    keys = sorted((j, f) for j, views in enumerate(training) for f in views)
    corners = np.array([len(training[j][f].ids) for j, f in keys], dtype=np.float64)
    scores = list(failed.values())
    for model, squared in estimates.items():
        rms = float(np.sqrt(squared.sum() / corners.sum()))
        scores.append(ModelScore(model, rms, 4 + len(MODELS[model]), "", rms))
    ranked = sorted(scores, key=lambda s: (s.rms_px is None, s.rms_px or 0.0, s.n_params))
    return tuple(ranked), dict(estimates), corners


def shape_by_estimate(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      flat: CalibrationResult, board_shape: str, spec: str, scored: list[ModelScore], squared: dict,
                      corners: NDArray, store: dict, training: list[dict], options: dict
                      ) -> tuple[CalibrationResult, tuple[ModelScore, ...], list[str]]:
    """The result of :func:`rank_by_estimate`'s ranking on the board shape of ``board_shape`` (see
    :func:`camcal.geometry.zhang.calibrate_board`): the flat result ``flat`` of ``model``, or the lens refitted on
    the surface chosen (or named), with the shapes' ranking and notes.

    ``auto`` (one camera, at least :data:`SPLINE_MIN_VIEWS` training views): every shape the board holds is
    scored by its leave-one-view-out error estimated to first order from the lens's flat fit, the two the rule
    depends on fitted and scored at their own solution (:func:`_shape_screen`); the shape is taken by
    :func:`~camcal.geometry.zhang_rank.shape_choice` against the flat board's estimate. A lens without a surface
    fit (OpenCV's thin-prism fit) has the surface chosen with the simplest lens within :data:`AUTO_MARGIN` of the
    best that has one, as in the thorough ranking.
    """
    if board_shape == "flat":
        return flat, (), []
    lens, notes = surface_lens(model, scored)
    if lens is None:
        return flat, (), []
    fits: dict = {}
    ranking: tuple[ModelScore, ...] = ()
    # the surfaces start from the flat fit taken (the same views: its surface fit is the one refitted last)
    start = flat if lens == model else store.get("full", {}).get(lens)
    if not spec:
        flat_score = next((s for s in scored if s.model == lens), None)
        if len(names) > 1 or flat_score is None or start is None or len(training[0]) < SPLINE_MIN_VIEWS:
            return flat, (), []
        spec, ranking = _shape_screen(board, training[0], lens, start, flat_score, squared, corners, fits)
        if not spec:
            return flat, ranking, notes + ["board shape auto: flat (no surface beats the flat board held out)"]
        lenses = _lenses_on_shape(board, training[0], spec, {lens: start, **store.get("full", {})}, corners)
        ranking = tuple(sorted([*ranking, *(s for s in lenses if not s.model.startswith(f"{lens}{SHAPE_TAG}"))],
                               key=lambda s: (s.rms_px is None, not s.screened_out, s.rms_px or s.estimate_px or 0.0)))
        chosen = simplest_within_margin([dataclasses.replace(s, model=s.model.rsplit(SHAPE_TAG, 1)[0])
                                         for s in lenses if s.rms_px is not None])
        if chosen != lens:  # confirmed at its own solution: the first-order estimate's error differs between lenses
            chosen = _confirmed(board, training[0], spec, lens, chosen, store["full"][chosen], ranking, squared,
                                corners, fits)
        if chosen != lens:
            notes.append(f"board shape auto: {chosen} ranked first on the {spec} surface ({lens} on the flat board)")
            lens = chosen
    return shaped_or_flat(board, names, by_frame, lens, holdout, spec, flat, lens == model, board_shape, ranking,
                          notes, options, fits)


def _shape_screen(board: Board, views: dict, lens: str, start: CalibrationResult, flat_score: ModelScore,
                  squared: dict, corners: NDArray, fits: dict) -> tuple[str, tuple[ModelScore, ...]]:
    """The surface taken for ``lens`` from its flat fit ``start`` on the training ``views`` (``""``: flat), and
    the shapes' ranking.

    Every shape the board holds is first scored at the flat fit, each surface's term present at zero
    (:func:`camcal.geometry.board_shape.flat_start`): the leave-one-view-out estimate there is one Gauss-Newton
    step of the surface's fit without each view, from the flat solution (the first-order estimate of that fit's
    error, without its iterations). The shape :func:`~camcal.geometry.zhang_rank.shape_choice` takes on those
    estimates and the best of them (the two its rule depends on, among the shapes that beat the flat board by
    it) are then fitted (:func:`surface_fit`, kept in ``fits`` for the last refit) and scored by their estimate
    at their own solution; the rule takes among those. The others are ranked out as screened.
    """
    camera = start.rig.cameras[0]
    kept = {image for _, image in start.images}
    train = {f: d for f, d in views.items() if d.image in kept}
    poses = {f: (R, t) for f, R, t in start.board_poses}
    first, out = [], {}
    for spec in shape_specs(board, AUTO_SHAPES):
        name = f"{lens}{SHAPE_TAG}{spec}"
        n_params = shape_params(board, views, lens, spec)
        try:
            at_flat = flat_start(board, train, camera.K, camera.distortion.without_correction(), poses,
                                 *parse_shape(board, spec))
            squared[name] = _per_view(leave_one_view_out_on_shape(board, at_flat, MODELS[lens], views))
        except FIT_ERRORS as error:
            out[name] = ModelScore(name, None, n_params, one_line(error))
            continue
        rms = float(np.sqrt(squared[name].sum() / corners.sum()))
        first.append(ModelScore(name, rms, n_params, "", rms))
    better = [s for s in first if spline_chosen(s, flat_score, squared)]
    finalists = set()
    if better:
        taken = shape_choice(flat_score, better, squared)[1]
        finalists = {min(better, key=lambda s: s.rms_px).model, f"{lens}{SHAPE_TAG}{taken}"}
    fitted = []
    for score in first:
        if score.model not in finalists:
            out[score.model] = ModelScore(score.model, None, score.n_params, f"screened out: {score.rms_px:.4f} px "
                                          "estimated leave one view out, to first order from the flat fit (flat "
                                          f"board {flat_score.rms_px:.4f} px)", score.rms_px)
            continue
        spec = score.model.rsplit(SHAPE_TAG, 1)[1]
        try:
            fit = surface_fit(board, start, views, lens, spec, fits)
            squared[score.model] = _per_view(leave_one_view_out_on_shape(board, fit, MODELS[lens], views))
        except FIT_ERRORS as error:
            out[score.model] = ModelScore(score.model, None, score.n_params, one_line(error))
            continue
        rms = float(np.sqrt(squared[score.model].sum() / corners.sum()))
        fitted.append(ModelScore(score.model, rms, score.n_params, "", rms))
    ranking = tuple(sorted([flat_score, *fitted, *out.values()],
                           key=lambda s: (s.rms_px is None, not s.screened_out, s.rms_px or s.estimate_px or 0.0)))
    return shape_choice(flat_score, fitted, squared)[1], ranking


def _lenses_on_shape(board: Board, views: dict, spec: str, fulls: dict[str, CalibrationResult], corners: NDArray
                     ) -> list[ModelScore]:
    """Every lens with a surface fit (``fulls``: its flat fit on the training ``views``) scored on the surface
    ``spec`` by its leave-one-view-out error estimated to first order from its flat fit, as :func:`_shape_screen`
    screens (the same estimate for every lens: the thorough ranking's lenses ranked again on the surface taken,
    without their fits); a lens whose estimate fails is ranked out with the reason."""
    out = []
    for lens, start in fulls.items():
        if lens not in SHAPE_LENSES:
            continue
        name, n_params = f"{lens}{SHAPE_TAG}{spec}", shape_params(board, views, lens, spec)
        camera = start.rig.cameras[0]
        kept = {image for _, image in start.images}
        try:
            at_flat = flat_start(board, {f: d for f, d in views.items() if d.image in kept}, camera.K,
                                 camera.distortion.without_correction(), {f: (R, t) for f, R, t in start.board_poses},
                                 *parse_shape(board, spec))
            squared = sum(leave_one_view_out_on_shape(board, at_flat, MODELS[lens], views).values())
        except FIT_ERRORS as error:
            out.append(ModelScore(name, None, n_params, one_line(error)))
            continue
        rms = float(np.sqrt(squared / corners.sum()))
        out.append(ModelScore(name, rms, n_params, "", rms))
    return out


def _confirmed(board: Board, views: dict, spec: str, lens: str, other: str, start: CalibrationResult,
               ranking: tuple[ModelScore, ...], squared: dict, corners: NDArray, fits: dict) -> str:
    """``other`` or ``lens`` on the surface ``spec``: ``other`` (ranked first there to first order) fitted on it from
    its flat fit ``start`` and scored at its own solution like ``lens`` (fitted by :func:`_shape_screen`), the
    simplest within :data:`AUTO_MARGIN` of the better taken; ``lens`` when ``other``'s fit fails."""
    taken = next((s for s in ranking if s.model == f"{lens}{SHAPE_TAG}{spec}" and s.rms_px is not None), None)
    try:
        fit = surface_fit(board, start, views, other, spec, fits)
        per_view = _per_view(leave_one_view_out_on_shape(board, fit, MODELS[other], views))
    except FIT_ERRORS:
        return lens
    if taken is None:
        return other
    rms = float(np.sqrt(per_view.sum() / corners.sum()))
    squared[f"{other}{SHAPE_TAG}{spec}"] = per_view
    return simplest_within_margin([dataclasses.replace(taken, model=lens),
                                   ModelScore(other, rms, taken.n_params, "", rms)])


def _per_view(per_view: dict[int, float]) -> NDArray[np.float64]:
    """The estimated ``sum |r|^2`` of each view, the frames in order."""
    return np.array([per_view[f] for f in sorted(per_view)])
