"""Planar-target calibration of one camera or of an N-camera rig, refined jointly.

Pipeline (Zhang 2000, extended to rigs as in multi-camera toolboxes):

1. Per camera, OpenCV's ``calibrateCamera`` (Zhang's closed form + LM)
   gives the starting K, distortion and one board pose per image
   (``cv2.fisheye.calibrate`` for the ``kannala-brandt`` model).
2. Views of several cameras are matched by the frame number in their file
   names (:func:`camcal.geometry.board.frame_number`); each camera's pose
   relative to the reference (the first camera) is the robust average of
   the per-view relative poses ``cam_j_from_board (cam_i_from_board)^-1``,
   chained over cameras sharing views.
   On a chessboard that is symmetric under a half turn (``W + H`` even)
   or printed on both sides (a camera behind it sees it mirrored) the
   corner labelling of a view may differ between cameras: each
   non-reference view takes the labelling (as detected, turned by a half
   turn, or mirrored: :mod:`camcal.geometry.labelling`) whose relative
   pose agrees with the consensus of the cameras labelled before it; a
   view that agrees with none is dropped and reported.
3. ONE bundle adjustment (:mod:`camcal.geometry.bundle`, pycolmap's Ceres
   adjuster) refines every camera's intrinsics and distortion, every
   camera-to-reference pose (``sensor_from_rig``) and every board pose (one
   frame per view, ``rig_from_board``), the board's corners being constant
   points: the board's frame is the world. camcal's models are COLMAP's
   exactly: ``polynomial`` is ``OPENCV`` with p1 = p2 = 0 held, ``opencv``
   is ``FULL_OPENCV`` with k4 = k5 = k6 = 0 held, ``division`` is
   ``DIVISION`` (two focal lengths: the lens's ``aspect`` is ``fx / fy``,
   so non-square pixels and anamorphic squeezes are estimated),
   ``kannala-brandt`` is ``OPENCV_FISHEYE`` and
   ``kannala-brandt-thin-prism`` is ``RAD_TAN_THIN_PRISM_FISHEYE``.
4. Images whose RMS is far above the median (``> max(outlier_factor x
   median, min_outlier_px)``) are dropped, reported, and the problem is
   solved again.
5. Uncertainty: ``Sigma = sigma^2 (J^T J)^-1`` at the solution (Ceres'
   covariance), with ``sigma^2 = 2 cost / (m - n)``; the board poses are
   marginalised out. These sigmas measure sampling noise of the corners,
   not model error.
6. Held-out views (``holdout``) are not used in the fit; each is then
   posed by PnP with the fitted intrinsics held (the same engine, one frame
   per view) and their RMS is reported beside the training RMS. With
   ``model="auto"`` every model of :data:`AUTO_MODELS` is fitted with
   every 4th training frame held out, the simplest within 1 % of the
   lowest RMS on those is kept and fitted on all training frames: the
   choice never sees ``holdout``. One camera: the folds are fitted only for
   the finalists of a screen, each model fitted once on every training
   frame and its leave-one-view-out error estimated from that fit
   (:mod:`camcal.geometry.zhang_loo`); the board's shapes are screened
   the same way. One camera with enough views: the best
   model is also scored with a smooth correction field over the image
   (``<model>+spline``, :mod:`camcal.geometry.spline_fit`), taken only
   when it is better held out by more than 1 % and by more than one
   standard error of the paired per-view differences.
7. The board's shape (one camera, ``board_shape``): the chosen model is
   also scored on the same folds with the board's surface fitted
   (:mod:`camcal.geometry.board_shape`: Legendre heights of total degree
   2..d, every corner's height free, with or without the corners'
   in-plane displacement; the flat fit's K, lens and poses refined with
   it), each fold's held-out views posed against that fold's board, and a
   shape is taken by the correction field's rule. The lens model is then
   ranked again on that surface (every model the surface is fitted with,
   the same folds, the simplest within 1 % of the best), the shape chosen
   again for a new lens, and the correction field scored on top of the
   surface (taken by its rule). A shape can be named, or given and held
   (a rig seeing the same board again).
8. By default (plain loss) steps 6-7 take each candidate's leave-one-view-out
   error estimated from its one fit instead of the folds
   (:mod:`camcal.geometry.zhang_quick`): every lens model fitted once, every
   shape scored to first order from the chosen lens's flat fit and the two the
   rule depends on fitted, the lenses scored on the surface taken to first
   order too, no correction field; the same rules. ``thorough=True`` runs the
   folds.

Conventions: ``x ~ K [R | -R c] X`` with ``R`` world -> camera; the world
is the reference camera's frame (``R = I``, ``c = 0``); lengths are in the
board's units (its square size); pixel (0, 0) is the centre of the
top-left pixel; skew is fixed at 0 (COLMAP's models have none).
Distortion models (see :mod:`camcal.model.distortion`): ``polynomial``
(k1, k2), ``opencv`` (k1, k2, p1, p2, k3) or ``division`` (Strand & Hayman
lambda in 1/px^2, centred on the principal point, radius in x pixels with
``aspect = fx / fy``; OpenCV has no such model: it is initialised from
OpenCV's k1 as ``lambda = -k1 / fx^2``) or ``kannala-brandt`` (k1..k4 of
OpenCV's fisheye model) or ``kannala-brandt-thin-prism`` (k1..k6, p1, p2,
s1..s4; started from OpenCV's fisheye fit, the rest at 0).

References
----------
Zhang, Z. (2000). A flexible new technique for camera calibration. IEEE
TPAMI 22(11).
Strand, R. & Hayman, E. (2005). Correcting radial distortion by circle
fitting. BMVC.
Hartley, R., Trumpf, J., Dai, Y. & Li, H. (2013). Rotation averaging. IJCV
(chordal L2 mean).
Triggs, B. et al. (2000). Bundle adjustment - a modern synthesis (sparse
structure, covariance from the Jacobian).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping, Sequence

import numpy as np

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection, opencv_threads_off
from camcal.geometry.board_shape import BoardShape
from camcal.geometry.tde4_fit import fit_tde4_lens
from camcal.geometry.zhang_fit import calibrate_model, heldout_fields, heldout_figures
from camcal.geometry.zhang_rank import (AUTO_MARGIN, AUTO_MODELS, BOARD_SHAPES, SPLINE_MIN_VIEWS, rank_models,
                                        simplest_within_margin, spline_chosen, with_board_shape)
from camcal.geometry.zhang_quick import rank_by_estimate, shape_by_estimate
from camcal.geometry.zhang_refit import SPLINE_SUFFIX, calibrate_shaped, calibrate_spline, shape_specs
from camcal.geometry.zhang_result import CalibrationResult, ModelScore, fold_radius_px, quality_problems
from camcal.geometry.zhang_starts import (COLMAP_MODELS, FIT_ERRORS, MIN_IMAGES, MODELS, checked_views, known_lenses,
                                          one_line)
from camcal.model.quality import Quality
from camcal.model.rig import Camera, Rig
from camcal.model.tde4 import LDPK_PARAMETERS, TDE4_MODELS

__all__ = ["MODELS", "AUTO_MODELS", "AUTO_MARGIN", "BOARD_SHAPES", "MIN_IMAGES", "SPLINE_MIN_VIEWS", "SPLINE_SUFFIX",
           "ModelScore", "CalibrationResult", "calibrate_board", "quality_problems", "fold_radius_px"]


@opencv_threads_off()  # OpenCV's calibrations on one thread: same input, same output
def calibrate_board(
    board: Board,
    detections: Mapping[str, Sequence[Detection]],
    model: str = "auto",
    units: str = "m",
    outlier_factor: float = 3.0,
    min_outlier_px: float = 1.0,
    loss: str = "trivial",
    loss_scale: float = 1.0,
    holdout: Collection[int] = (),
    intrinsics: Mapping[str, Camera] | None = None,
    refine_intrinsics: bool = False,
    board_shape: str | BoardShape = "auto",
    thorough: bool = False,
) -> CalibrationResult:
    """Calibrate one camera or an N-camera rig from images of a planar board.

    Parameters
    ----------
    board : Board
        The target; its square size sets the unit of every length.
    detections : mapping of str to sequence of Detection
        Camera name -> the board detections of its images (from
        :func:`camcal.pipelines.board.detect_in_images`). The first camera
        is the reference. Views are matched (and held out) by the frame
        number in the image file names (one camera with repeated numbers:
        by position).
    model : str
        ``auto`` (default) or one of :data:`MODELS`: ``none``, ``division``
        (Strand & Hayman lambda, centred on the principal point, its
        ``aspect`` = fx / fy), ``polynomial`` (k1, k2), ``kannala-brandt``
        (k1..k4), ``opencv`` (k1, k2, p1, p2, k3), ``opencv-rational``
        (+ k4, k5, k6), ``opencv-thin-prism`` (+ s1..s4; one camera, fitted
        by OpenCV), ``kannala-brandt-thin-prism`` (k1..k6, p1, p2, s1..s4:
        COLMAP's RAD_TAN_THIN_PRISM_FISHEYE).
        ``auto`` ranks every model by leave-views-out cross-validation on
        the training views (:func:`rank_models`; ``holdout`` is never used
        to choose; one camera: only the finalists of a one-fit-per-model
        leave-one-view-out estimate are refitted fold by fold, the others are
        ranked out as screened) and keeps the simplest (order of :data:`AUTO_MODELS`)
        within :data:`AUTO_MARGIN` (1 %) of the best; a model that cannot be
        fitted is ranked out with its reason; the chosen model is fitted on
        every training view, and if that fit fails, fails
        :func:`quality_problems` or folds inside the image
        (:func:`fold_radius_px`: the views may leave the image's rim
        unseen, and a polynomial can turn over there), the next in the
        ranking is (said in :attr:`CalibrationResult.notes`). The ranking is
        :attr:`CalibrationResult.model_ranking`. One camera with at least
        :data:`SPLINE_MIN_VIEWS` training views and the plain loss: the
        best model with a correction field (``<model>+spline``) is ranked
        too and taken first when :func:`spline_chosen` says so. A model
        with a correction field can be named (``kannala-brandt+spline``;
        one camera, no given intrinsics).
    units : str
        Name of the board's length unit, stored in the rig.
    outlier_factor, min_outlier_px : float
        An image is an outlier when its RMS exceeds
        ``max(outlier_factor x median image RMS, min_outlier_px)``.
    loss, loss_scale : str, float
        Robust loss on each corner's residual (Ceres': ``trivial``,
        ``huber``, ``soft_l1``, ``cauchy``), scale in pixels.
    holdout : collection of int
        Frame numbers left out of the fit and reported as held-out RMS.
    intrinsics : mapping of str to Camera, optional
        Camera name -> a calibrated camera (e.g. the cameras of a rig file):
        its K and lens are held and only the poses are solved (extrinsics
        only), unless ``refine_intrinsics``. Every camera of
        ``detections`` must be in it, with the same image size, zero skew,
        and one lens model shared by all (the fitted model: ``model`` must
        be ``auto`` or that model); each camera's start poses are PnP with
        its own lens.
    refine_intrinsics : bool
        With ``intrinsics``: use them as the start and refine them.
    board_shape : str or BoardShape
        The board's shape (:mod:`camcal.geometry.board_shape`, one camera): ``flat``, a named shape of
        :data:`~camcal.geometry.board_shape.SHAPE_SPECS` (a surface ``z(x, y)`` of Legendre terms of total
        degree 2..d, ``2``, ``3``, ``4``, ``6`` or ``free``: every corner's height; ``+plane``: the corners'
        in-plane displacement too; fitted jointly with the lens and the poses), or ``auto`` (default): with
        ``model="auto"``, one camera, at least :data:`SPLINE_MIN_VIEWS` training views and the plain loss,
        every shape of :data:`~camcal.geometry.board_shape.AUTO_SHAPES` is scored on the model ranking's folds
        from the chosen model's fit in each fold (a model with a correction field: it and its parametric lens on
        every shape; the pair is taken by the same rule), and taken only when it beats the flat board by more than
        :data:`AUTO_MARGIN` and one standard error of the paired per-view differences (the one with fewest
        parameters within :data:`AUTO_MARGIN` of the best such); otherwise flat. On the surface taken, every
        lens model is scored again on the same folds and the simplest within :data:`AUTO_MARGIN` of the best is
        taken (the shape chosen again for it when it is another lens), then the correction field on top of it
        (:func:`spline_chosen`'s rule). The ranking is
        :attr:`CalibrationResult.shape_ranking`; the surface, :attr:`CalibrationResult.board_shape`.
        A :class:`~camcal.geometry.board_shape.BoardShape` (e.g. a rig file's ``provenance.board_shape``) is
        held: the same board seen again, by any number of cameras, with any model (its corners are the
        bundle's constant points; the held-out views are posed against it).
        Without ``thorough`` (default) and with the plain loss, ``auto`` (model and shape) takes each candidate's
        leave-one-view-out error estimated from its one fit instead of the folds
        (:mod:`camcal.geometry.zhang_quick`: every lens model fitted once on every training view, every board
        shape scored to first order from the lens's flat fit and the two its rule depends on fitted, no
        correction field scored), with the same rules: about as costly as a few single-model fits.
    thorough : bool
        ``model="auto"``: rank by the folds as described above (the finalists of the screen fold by fold, the
        correction field, the lenses ranked again on the surface taken), dozens of fits; always so with a robust
        loss (the one-fit estimate is of plain least squares).

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CamcalError
        Unknown model, fewer than :data:`MIN_IMAGES` usable images for a
        camera, cameras not linked to each other through shared frames (one
        line naming the separate groups), intrinsics that do not fit the
        cameras, or a degenerate problem.

    Notes
    -----
    Minimises ``1/2 sum_ij rho(|pi_j(K_j, d_j, T_j T_i X) - x_ij|^2)`` over
    the intrinsics ``K_j`` and distortion ``d_j`` of every camera ``j``, its
    pose ``T_j`` (``cam_from_reference``, identity for the reference) and
    the board pose ``T_i`` of every view ``i``; then
    ``Sigma = sigma^2 (J^T J)^-1``, ``sigma^2 = 2 cost / (2M - n)``.
    """
    if model in TDE4_MODELS:
        return _calibrate_tde4(board, detections, model, holdout, intrinsics, board_shape, units=units,
                               outlier_factor=outlier_factor, min_outlier_px=min_outlier_px, loss=loss,
                               loss_scale=loss_scale)
    splined = model.endswith(SPLINE_SUFFIX) and model[:-len(SPLINE_SUFFIX)] in MODELS
    if model != "auto" and model not in MODELS and not splined:
        raise CamcalError(f"unknown distortion model {model!r}, expected one of: {', '.join(MODELS)}, auto "
                          f"(or a model with a correction field, '<model>{SPLINE_SUFFIX}'), or 3DE's "
                          f"{', '.join(TDE4_MODELS)}")
    if isinstance(board_shape, BoardShape):
        return _calibrate_held_shape(board, detections, model, holdout, intrinsics, refine_intrinsics, board_shape,
                                     units=units, outlier_factor=outlier_factor, min_outlier_px=min_outlier_px,
                                     loss=loss, loss_scale=loss_scale)
    if board_shape not in BOARD_SHAPES:
        raise CamcalError(f"unknown board shape {board_shape!r}, expected one of: {', '.join(BOARD_SHAPES)}")
    spec = board_shape if board_shape not in ("auto", "flat") else ""
    if spec and (len(detections) > 1 or intrinsics is not None or model == "opencv-thin-prism"
                 or spec not in shape_specs(board)):
        raise CamcalError(f"board shape {board_shape}: a board surface is fitted with one camera, without given "
                          f"intrinsics, a model of the Ceres engine (not opencv-thin-prism), and a degree the "
                          f"board's grid holds ({', '.join(shape_specs(board)) or 'none'} here)")
    names, by_frame, holdout = checked_views(detections, board, holdout)
    options = dict(units=units, outlier_factor=outlier_factor, min_outlier_px=min_outlier_px, loss=loss,
                   loss_scale=loss_scale)
    if splined and (len(names) > 1 or intrinsics is not None):
        raise CamcalError(f"model {model} calibrates one camera at a time, without given intrinsics")
    if intrinsics is not None:
        model, known = known_lenses(names, by_frame, intrinsics, model)
        return calibrate_model(board, names, by_frame, model, holdout, known=known, refine_known=refine_intrinsics,
                          **options)
    if spec and model != "auto":
        return calibrate_shaped(board, names, by_frame, model, holdout, spec, **options)
    if splined:
        return calibrate_spline(board, names, by_frame, model, holdout, **options)
    if model != "auto":
        return calibrate_model(board, names, by_frame, model, holdout, **options)
    # the choice never sees the held-out frames
    training = [{f: d for f, d in views.items() if f not in holdout} for views in by_frame]
    fold_results: dict = {}
    # the folds (thorough), or each candidate's one fit (its leave-one-view-out error estimated: plain least squares)
    quick = not thorough and loss == "trivial"
    ranking, squared, corners = (rank_by_estimate if quick else rank_models)(board, names, training, options,
                                                                             fold_results)
    scored = [score for score in ranking if score.rms_px is not None]
    parametric = [score for score in scored if not score.model.endswith(SPLINE_SUFFIX)]
    # the models the screen left out of the folds come after the scored ones (best estimate first)
    order = [score.model for score in parametric] + [score.model for score in ranking if score.screened_out]
    order = order or ["polynomial"]
    if parametric:  # parsimony: the simplest model within AUTO_MARGIN of the best goes first
        simplest = simplest_within_margin(parametric)
        order.remove(simplest)
        order.insert(0, simplest)
        spline = next((s for s in scored if s.model.endswith(SPLINE_SUFFIX)), None)
        if spline is not None and spline_chosen(spline, parametric[0], squared):
            order.insert(0, spline.model)
    failures = []
    for candidate in order:
        try:
            fit = calibrate_spline if candidate.endswith(SPLINE_SUFFIX) else calibrate_model
            result = fit(board, names, by_frame, candidate, holdout, **options)
        except FIT_ERRORS as error:
            failures.append(f"{candidate}: {one_line(error)}")
            continue
        problems = quality_problems(result)
        folds = [(camera.name, fold_radius_px(camera)) for camera in result.rig.cameras]
        problems += [f"{name}: the lens folds {radius:.0f} px from the principal point, inside the image (its rays "
                     "stop turning outward)" for name, radius in folds if radius is not None]
        if problems and candidate != order[-1]:
            failures.append(f"{candidate}: {'; '.join(problems)}")
            continue
        notes = [f"model auto: {failure} (next model tried)" for failure in failures]
        if not scored:
            notes.append("model auto: too few views to hold any out (need "
                         f"{MIN_IMAGES + 1}); the polynomial model is fitted without a choice")
        result, shape_ranking, shape_notes = (shape_by_estimate if quick else with_board_shape)(
            board, names, by_frame, candidate, holdout, result, board_shape, spec, scored, squared, corners,
            fold_results, training, options)
        return dataclasses.replace(result, model_ranking=ranking, notes=result.notes + tuple(notes + shape_notes),
                                   model_heldout_rms_px={s.model: s.rms_px for s in scored},
                                   shape_ranking=shape_ranking)
    raise CamcalError("no lens model could be fitted: " + "; ".join(failures))


def _calibrate_held_shape(board: Board, detections: Mapping[str, Sequence[Detection]], model: str,
                          holdout: Collection[int], intrinsics: Mapping[str, Camera] | None, refine_intrinsics: bool,
                          shape: BoardShape, **options) -> CalibrationResult:
    """:func:`calibrate_board` on a board whose surface is known and held (``model`` named, or ``auto`` with
    ``intrinsics``: their model)."""
    names, by_frame, holdout = checked_views(detections, board, holdout)
    known = None
    if intrinsics is not None:
        model, known = known_lenses(names, by_frame, intrinsics, model)
    if model not in COLMAP_MODELS:
        raise CamcalError(f"a held board shape needs a named model of the rig engine or given intrinsics, got model "
                          f"{model} (one of: {', '.join(COLMAP_MODELS)})")
    return calibrate_model(board, names, by_frame, model, holdout, known=known, refine_known=refine_intrinsics,
                      shape=shape, **options)


def _calibrate_tde4(board: Board, detections: Mapping[str, Sequence[Detection]], model: str, holdout: Collection[int],
                    intrinsics: Mapping[str, Camera] | None, board_shape: str | BoardShape,
                    **options) -> CalibrationResult:
    """3DE's models (:mod:`camcal.model.tde4`), one camera on a flat board: the ``opencv`` calibration
    (``kannala-brandt`` for the fisheye; its outliers dropped; a scoring fit: its covariance and jackknife would
    be thrown away) refined into the 3DE lens, K and poses by
    :func:`camcal.geometry.tde4_fit.fit_tde4_lens`; held-out views measured as for every model."""
    if len(detections) != 1 or intrinsics is not None or board_shape not in ("auto", "flat"):
        raise CamcalError(f"model {model} calibrates one camera on a flat board, without given intrinsics")
    names, by_frame, holdout = checked_views(detections, board, holdout)
    start_model = "kannala-brandt" if model == "3de4-fisheye-deg8" else "opencv"
    start = calibrate_model(board, names, by_frame, start_model, holdout, scoring=True, **options)  # K, lens, poses
    camera = start.rig.cameras[0]
    views = [by_frame[0][f] for f, _, _ in start.board_poses]
    fit = fit_tde4_lens(board.object_points, [(view.ids, view.corners_px) for view in views], camera.K,
                        camera.distortion, [(R, t) for _, R, t in start.board_poses], model, camera.image_size,
                        options["loss"], options["loss_scale"])
    norms = np.linalg.norm(fit.residuals_px, axis=1)
    sigma = dict(zip(fit.parameter_names, (float(s) for s in np.sqrt(np.diag(fit.covariance)))))
    quality = Quality(rms_px=float(np.sqrt(np.mean(norms**2))), worst_px=float(norms.max()), n_views=len(views),
                      n_observations=len(norms), n_outliers=len(start.outliers), sigma=sigma)
    rig = Rig((dataclasses.replace(camera, K=fit.K, distortion=fit.distortion, quality=quality),),
              units=start.rig.units, provenance=start.rig.provenance)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if holdout:
        held = [{f: d for f, d in by_frame[0].items() if f in holdout}]
        heldout_rms, per_camera, heldout_images, heldout, per_view = heldout_figures(board, rig, held)
        rig = Rig((dataclasses.replace(rig.cameras[0], quality={**rig.cameras[0].quality, "heldout_rms_px": heldout_rms}),),
                  units=rig.units, provenance=rig.provenance)
    held_params = [f"{p.key} {p.default:g}" for p in LDPK_PARAMETERS[model] if p.key not in fit.parameter_names]
    return dataclasses.replace(
        start, rig=rig, residuals_px=fit.residuals_px, points_px=np.concatenate([view.corners_px for view in views]),
        camera_of_point=np.zeros(len(norms), np.int64),
        image_of_point=np.concatenate([np.full(len(view.ids), n) for n, view in enumerate(views)]),
        rms_px=quality.rms_px, worst_px=quality.worst_px, covariance=fit.covariance,
        parameter_names=tuple(f"{camera.name}.{label}" for label in fit.parameter_names), model=model,
        heldout_rms_px=heldout_rms, heldout_images=heldout_images, heldout_view_rms_px=per_view,
        notes=start.notes + (f"{model}: started from the {start_model} fit (its outlier images dropped); held at "
                             f"LDPK's defaults: {', '.join(held_params)} (the pixel aspect is fy / fx)",)
        + ((f"{model}: {fit.held}",) if fit.held else ()),
        board_poses=tuple((f, R, t) for (f, _, _), (R, t) in zip(start.board_poses, fit.poses)),
        **heldout_fields(heldout))
