"""A one-camera board calibration refined after its parametric fit: a correction field or a board surface.

``<model>+spline`` adds a smooth correction field over the image (:mod:`camcal.geometry.spline_fit`) to the
parametric fit; a board shape fits the board's surface (:mod:`camcal.geometry.board_shape`) with the lens and the
poses, started from the flat fit. Both keep the flat fit's covariance and pose the held-out views again (against
the fitted surface when the board is not flat).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.board_shape import (SHAPE_SPECS, BoardShape, BoardShapeFit, fit_board_shape, max_degree,
                                        parse_shape)
from camcal.geometry.spline_fit import fit_spline_lens
from camcal.geometry.zhang_fit import calibrate_model, heldout_fields, heldout_figures
from camcal.geometry.zhang_result import CalibrationResult
from camcal.geometry.zhang_starts import MODELS
from camcal.model.rig import Camera, Rig

__all__ = ["SPLINE_SUFFIX", "calibrate_spline", "shape_specs", "surface_fit", "fit_shape", "calibrate_shaped"]

#: The name of a model with a correction field: ``<model>+spline``.
SPLINE_SUFFIX = "+spline"


def calibrate_spline(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      **options) -> CalibrationResult:
    """``<model>+spline``: the model fitted by :func:`calibrate_model`, then its correction field on the views it kept.

    The covariance and the sigmas are the parametric part's at its own fit (the field's are not propagated).
    """
    base = model[:-len(SPLINE_SUFFIX)]
    result = calibrate_model(board, names, by_frame, base, holdout, **options)
    camera = result.rig.cameras[0]
    kept = {image for _, image in result.images}
    views = {f: d for f, d in by_frame[0].items() if f not in holdout and d.image in kept}
    fit = fit_spline_lens(board, views, camera.K, camera.distortion, MODELS[base])
    ny, nx = fit.distortion.correction.shape
    return _refitted(board, result, dataclasses.replace(camera, K=fit.K, distortion=fit.distortion), fit.residuals_px,
                     views, by_frame[0], holdout, model,
                     (f"{model}: {base} with a {nx}x{ny} B-spline correction field (RMS "
                      f"{fit.distortion.correction.rms_px():.3f} px over the image); its covariance is "
                      f"{base}'s at its own fit",))


def _refitted(board: Board, flat: CalibrationResult, camera: Camera, residuals: NDArray, views: Mapping[int, Detection],
              all_views: Mapping[int, Detection], holdout: set[int], model: str, notes: tuple[str, ...],
              shape: BoardShape | None = None) -> CalibrationResult:
    """The one-camera calibration ``flat`` with its camera refitted after it (a correction field, a board surface):
    the camera's training figures from ``residuals`` on ``views``, the held-out views of ``all_views`` posed again
    (against ``shape``'s corners when the board is not flat), the rig's provenance naming ``model`` (and the
    shape), and ``notes`` added."""
    norms = np.linalg.norm(residuals, axis=1)
    rms = float(np.sqrt(np.mean(norms**2)))
    quality = {**camera.quality, "rms_px": rms, "worst_px": float(norms.max()), "n_observations": int(len(norms))}
    quality.pop("heldout_rms_px", None)
    camera = dataclasses.replace(camera, quality=quality)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if holdout:
        held = [{f: d for f, d in all_views.items() if f in holdout}]
        heldout_rms, per_camera, heldout_images, heldout, per_view = heldout_figures(
            board, Rig((camera,)), held, None if shape is None else shape.points(board))
        camera = dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]})
    provenance = {**flat.rig.provenance, "model": model}
    if shape is not None:
        provenance["board_shape"] = shape.to_dict()
    frames = sorted(views)
    return dataclasses.replace(
        flat, rig=Rig((camera,), units=flat.rig.units, provenance=provenance), residuals_px=residuals,
        points_px=np.concatenate([views[f].corners_px for f in frames]), camera_of_point=np.zeros(len(norms), np.int64),
        image_of_point=np.concatenate([np.full(len(views[f].ids), n) for n, f in enumerate(frames)]),
        images=tuple((camera.name, views[f].image) for f in frames), rms_px=rms, worst_px=float(norms.max()),
        model=model, heldout_rms_px=heldout_rms, heldout_images=heldout_images, heldout_view_rms_px=per_view,
        board_shape=shape, **heldout_fields(heldout), notes=flat.notes + notes)


def shape_specs(board: Board, names: Sequence[str] = SHAPE_SPECS) -> tuple[str, ...]:
    """The shapes of ``names`` the board's corner grid holds (a degree up to :func:`max_degree`)."""
    return tuple(s for s in names if parse_shape(board, s)[0] <= max_degree(board))


def surface_fit(board: Board, result: CalibrationResult, views: Mapping[int, Detection], model: str, spec: str,
                fits: dict | None = None) -> BoardShapeFit:
    """The board's surface ``spec`` fitted with the parametric lens ``model`` on the views ``result`` kept, started
    from its flat fit and board poses (:func:`camcal.geometry.board_shape.fit_board_shape`); ``fits``: the fits
    already made, by flat fit, lens, shape and views (each made once)."""
    camera = result.rig.cameras[0]
    kept = {image for _, image in result.images}
    train = {f: d for f, d in views.items() if d.image in kept}
    key = (id(result), model, spec, tuple(sorted(train)))
    fit = None if fits is None else fits.get(key)
    if fit is None:
        degree, in_plane = parse_shape(board, spec)
        poses = {f: (R, t) for f, R, t in result.board_poses}
        fit = fit_board_shape(board, train, camera.K, camera.distortion.without_correction(), MODELS[model], poses,
                              degree, in_plane)
        if fits is not None:
            fits[key] = fit
    return fit


def fit_shape(board: Board, result: CalibrationResult, views: Mapping[int, Detection], model: str, spec: str,
               fits: dict | None = None):
    """``(camera, shape, training residuals, views kept)``: the board's surface fitted with the lens on the views
    ``result`` kept (started from its flat fit and board poses), then, for ``<model>+spline``, the correction
    field on top with the surface held. ``fits``: the surface fits already made, by flat fit and shape (the
    surface under ``<model>+spline`` is ``<model>``'s on it: made once)."""
    base = model.removesuffix(SPLINE_SUFFIX)
    camera = result.rig.cameras[0]
    fit = surface_fit(board, result, views, base, spec, fits)
    K, distortion, residuals = fit.K, fit.distortion, fit.residuals_px
    if base != model:
        splined = fit_spline_lens(board, fit.views, K, distortion, MODELS[base], points=fit.shape.points(board))
        K, distortion, residuals = splined.K, splined.distortion, splined.residuals_px
    return dataclasses.replace(camera, K=K, distortion=distortion), fit.shape, residuals, fit.views


def calibrate_shaped(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      spec: str, flat: CalibrationResult | None = None, fits: dict | None = None,
                      **options) -> CalibrationResult:
    """``model`` on a board of shape ``spec`` (:mod:`camcal.geometry.board_shape`): the flat fit of its
    parametric part (:func:`calibrate_model`; ``flat`` when it is already made), then the surface, the lens and the
    poses refined jointly (and the correction field on top, with the surface held; ``fits``: :func:`surface_fit`'s,
    the surface fits already made); the held-out views posed against the fitted surface. One camera. The
    covariance and the sigmas are the flat fit's."""
    if len(names) > 1:
        raise CamcalError(f"a board surface is fitted with one camera at a time; got {len(names)} cameras")
    result = flat if flat is not None else calibrate_model(board, names, by_frame, model.removesuffix(SPLINE_SUFFIX),
                                                      holdout, **options)
    training = {f: d for f, d in by_frame[0].items() if f not in holdout}
    camera, shape, residuals, views = fit_shape(board, result, training, model, spec, fits)
    return _refitted(board, result, camera, residuals, views, by_frame[0], holdout, model,
                     (shape.describe(board) + f"; training RMS {result.rms_px:.4f} px on a flat board",
                      f"{model} on board shape {spec}: its covariance is the flat fit's"), shape)
