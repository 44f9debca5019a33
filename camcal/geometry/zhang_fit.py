"""One lens model fitted to a board's views: the joint refinement, the outlier rounds, the held-out views, the rig.

:func:`calibrate_model` is steps 3-6 of :func:`camcal.geometry.zhang.calibrate_board` for one model: ONE bundle
adjustment (:mod:`camcal.geometry.bundle`, pycolmap's Ceres adjuster) of every camera's intrinsics and distortion,
every camera-to-reference pose and every board pose, the board's corners constant; images far above the median RMS
dropped and the problem solved again; ``Sigma = sigma^2 (J^T J)^-1`` with the board poses marginalised out (Triggs
et al. 2000) and the delete-one-view jackknife; held-out views posed by PnP with the intrinsics held.
``opencv-thin-prism`` (no COLMAP model) is OpenCV's own fit (:func:`calibrate_opencv`).

References
----------
Triggs, B. et al. (2000). Bundle adjustment - a modern synthesis (sparse structure, covariance from the Jacobian).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.board_shape import BoardShape
from camcal.geometry.bundle import BoardObservations, BundleOptions, BundleState, bundle_adjust
from camcal.geometry.bundle import residuals as board_residuals
from camcal.geometry.bundle.solve import GAUGE_NAMES
from camcal.geometry.labelling import resolve_labellings
from camcal.geometry.spline_fit import pose_view
from camcal.geometry.uncertainty import GAUGE, POSE, projection_sigma, sigma_grid
from camcal.geometry.view_jackknife import design_effect, view_jackknife
from camcal.geometry.zhang_result import CalibrationResult
from camcal.geometry.zhang_starts import (COLMAP_MODELS, COLMAP_NAMES, FISHEYE_MODELS, INTRINSICS, MIN_IMAGES, MODELS,
                                          OPENCV_FLAGS, camcal_lens, camera_poses, colmap_params, corners_in_front,
                                          known_start, one_line, opencv_start, poses_in_front)
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera, Rig, make_provenance

__all__ = ["calibrate_model", "heldout_fields", "heldout_figures", "posed_residuals"]

_MAX_OUTLIER_ROUNDS = 3


def _camcal_covariance(covariance: NDArray, colmap_names: tuple[str, ...], names: list[str], model: str,
                       params: list[NDArray]) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """The engine's covariance (COLMAP parameters) in camcal's parameters: ``A Sigma A^T``."""
    labels, rows = [], []
    column = {name: k for k, name in enumerate(colmap_names)}

    def row(entries: dict[str, float]) -> NDArray[np.float64]:
        r = np.zeros(len(colmap_names))
        for name, value in entries.items():
            if name in column:  # a held parameter is not in the covariance: its sigma is 0
                r[column[name]] = value
        return r

    for j, camera in enumerate(names):
        for label in INTRINSICS + MODELS[model]:
            labels.append(f"{camera}.{label}")
            if label == "lambda":  # lambda = k / fx^2
                fx, k = params[j][0], params[j][4]
                rows.append(row({f"{camera}.fx": -2.0 * k / fx**3, f"{camera}.k": 1.0 / fx**2}))
            else:
                rows.append(row({f"{camera}.{COLMAP_NAMES.get(model, {}).get(label, label)}": 1.0}))
        if j:
            for label in ("rx", "ry", "rz", "tx", "ty", "tz"):
                labels.append(f"{camera}.{label}")
                rows.append(row({f"{camera}.{label}": 1.0}))
    for label in GAUGE_NAMES if GAUGE_NAMES[0] in column else ():  # the board gauge (projection uncertainty)
        labels.append(label)
        rows.append(row({label: 1.0}))
    A = np.array(rows)
    return A @ covariance @ A.T, tuple(labels)


def calibrate_model(board: Board, names: list[str], by_frame_all: list[dict], model: str, holdout: set[int], units: str,
               outlier_factor: float, min_outlier_px: float, loss: str, loss_scale: float,
               known: Mapping[str, NDArray] | None = None, refine_known: bool = False,
               shape: BoardShape | None = None, scoring: bool = False, shared: dict | None = None
               ) -> CalibrationResult:
    """One model, the views of ``holdout`` left out of the fit and then measured.

    ``scoring``: the fit only, for its held-out residuals (:func:`rank_models`' folds): no covariance,
    no jackknife, no sigmas (the result's ``covariance`` is empty; its lens, poses, residuals and held-out
    figures are the full fit's). ``shared``: :func:`opencv_start`'s.

    ``known``: camera name -> COLMAP parameters of a calibrated lens (:func:`known_lenses`), held unless
    ``refine_known``; the start poses are then PnP with those lenses. ``shape``: a board surface held (its
    corners are the bundle's constant points, the PnP starts with known lenses and the held-out views are posed
    against it); the starts of fitted lenses are OpenCV's flat-board fits.
    """
    points = board.object_points if shape is None else shape.points(board)
    by_frame = [{f: d for f, d in views.items() if f not in holdout} for views in by_frame_all]
    held = [{f: d for f, d in views.items() if f in holdout} for views in by_frame_all]
    for name, views in zip(names, by_frame):
        if len(views) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: {len(views)} images left for the fit after holding out "
                              f"{len(holdout)} frames, need at least {MIN_IMAGES}")
    if model == "opencv-thin-prism":
        result = _calibrate_opencv(board, names, by_frame, model, units, outlier_factor, min_outlier_px, shared)
        if not holdout:
            return result
        heldout_rms, per_camera, heldout_images, heldout, per_view = heldout_figures(board, result.rig, held)
        camera = result.rig.cameras[0]
        rig = Rig((dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]}),),
                  units=result.rig.units, provenance=result.rig.provenance)
        return dataclasses.replace(result, rig=rig, heldout_rms_px=heldout_rms, heldout_images=heldout_images,
                                   heldout_view_rms_px=per_view, **heldout_fields(heldout))
    colmap_model, fixed = COLMAP_MODELS[model]
    starts, params = [], []
    for name, views in zip(names, by_frame):
        if known is not None:
            params.append(np.asarray(known[name], dtype=np.float64).copy())
            K, lens = camcal_lens(model, params[-1])
            starts.append(known_start(board, views, K, lens, points))
            continue
        K, dist, poses = opencv_start(board, views, model, name, shared)
        if model not in FISHEYE_MODELS:
            poses = poses_in_front(board, views, K, dist, poses)
        starts.append(poses)
        params.append(colmap_params(model, K, dist))
    behind = [(name, views.pop(f).image) for name, views, poses in zip(names, by_frame, starts)
              for f in sorted(set(views) - set(poses))]
    for name, views in zip(names, by_frame):
        if len(views) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: {len(views)} views with the board in front of the camera at the "
                              f"start, need at least {MIN_IMAGES}")
    by_frame, starts, relabelling, dropped = resolve_labellings(board, names, by_frame, starts)
    relabelled = [(name, image) for name, image, _ in relabelling]
    dropped = behind + [(name, image) for name, image, _ in dropped]
    notes = []
    for how in sorted({how for _, _, how in relabelling}):
        views = [image for _, image, other in relabelling if other == how]
        notes.append(f"{len(views)} view(s) relabelled ({how}) to agree with the rig's other cameras: "
                     + ", ".join(views))
    if behind:
        notes.append(f"{len(behind)} view(s) left out: no start pose puts the board in front of the camera "
                     f"({', '.join(image for _, image in behind)})")
    if model in FISHEYE_MODELS:
        by_frame, n_behind = corners_in_front(board, by_frame, starts)
        if n_behind:
            notes.append(f"{n_behind} corner(s) beyond 90 degrees from the optical axis left out "
                         f"(COLMAP's {colmap_model}, the engine's model, images only rays in front of the camera)")
    cam_poses = camera_poses(names, starts)

    # every frame seen by any camera is one board pose, first placed by the lowest camera seeing it
    frames = sorted(set().union(*[set(v) for v in by_frame]))
    observed = {(j, f) for j, views in enumerate(by_frame) for f in views}
    outliers: list[tuple[int, int]] = []
    view_start = {}
    for f in frames:
        j = min(j for j in range(len(names)) if f in by_frame[j])
        R_j, t_j = cam_poses[j]
        R_b, t_b = starts[j][f]
        view_start[f] = (R_j.T @ R_b, R_j.T @ (t_b - t_j))
    options = BundleOptions(refine_principal_point=True, refine_points3D=False, loss=loss, loss_scale=loss_scale,
                            fixed_params={name: fixed for name in names},
                            constant_intrinsics=tuple(names) if known is not None and not refine_known else (),
                            compute_sigmas=not scoring)
    if known is not None:
        notes.append("intrinsics " + ("refined from the given start" if refine_known else "held (extrinsics only)"))
    image_sizes = tuple(next(iter(views.values())).image_size for views in by_frame)

    for round_ in range(_MAX_OUTLIER_ROUNDS + 1):
        kept = sorted(observed - set(outliers))
        kept_frames = sorted({f for _, f in kept})
        frame_index = {f: n for n, f in enumerate(kept_frames)}
        for j, name in enumerate(names):
            n_left = sum(1 for jj, _ in kept if jj == j)
            if n_left < MIN_IMAGES:
                raise CamcalError(f"camera {name!r}: only {n_left} images left after dropping outliers, need {MIN_IMAGES}")
        det = [by_frame[j][f] for j, f in kept]
        observations = BoardObservations(
            object_points=np.asarray(points, dtype=np.float64),
            camera=np.concatenate([np.full(len(d.ids), j) for (j, _), d in zip(kept, det)]),
            frame=np.concatenate([np.full(len(d.ids), frame_index[f]) for (_, f), d in zip(kept, det)]),
            corner=np.concatenate([d.ids for d in det]),
            xy=np.concatenate([d.corners_px for d in det]),
        )
        state = BundleState(
            camera_names=tuple(names), models=(colmap_model,) * len(names), image_sizes=image_sizes,
            params=tuple(params), sensor_R=np.array([R for R, _ in cam_poses]),
            sensor_t=np.array([t for _, t in cam_poses]), frame_R=np.array([view_start[f][0] for f in kept_frames]),
            frame_t=np.array([view_start[f][1] for f in kept_frames]), frame_ids=tuple(kept_frames),
            points=np.zeros((0, 3)), point_ids=(), obs_camera=np.zeros(0, np.int64), obs_frame=np.zeros(0, np.int64),
            obs_point=np.zeros(0, np.int64), obs_xy=np.zeros((0, 2)),
            board=observations, board_R=np.eye(3), board_t=np.zeros(3),
        )
        solution = bundle_adjust(state, options)
        refined = solution.state
        residuals = board_residuals(refined)[1]
        if not np.all(np.isfinite(residuals)):
            raise CamcalError("the joint refinement diverged (non-finite residuals): check the detections")
        params = list(refined.params)
        cam_poses = list(zip(refined.sensor_R, refined.sensor_t))
        for f in kept_frames:
            view_start[f] = (refined.frame_R[frame_index[f]], refined.frame_t[frame_index[f]])
        image_of_point = np.concatenate([np.full(len(d.ids), n) for n, d in enumerate(det)])
        squared = np.bincount(image_of_point, np.sum(residuals**2, axis=1)) / np.bincount(image_of_point)
        image_rms = np.sqrt(squared)
        threshold = max(outlier_factor * np.median(image_rms), min_outlier_px)
        new = [kept[n] for n in np.flatnonzero(image_rms > threshold)]
        if not new or round_ == _MAX_OUTLIER_ROUNDS:
            break
        outliers.extend(new)

    if scoring:
        covariance, labels, jackknife = None, (), None
    elif solution.covariance.size == 0:
        raise CamcalError("the calibration is degenerate (singular normal equations): vary the board poses more")
    else:
        covariance, labels = _camcal_covariance(solution.covariance, solution.covariance_names, names, model, params)
        jackknife = _view_jackknife(labels, names, model, params, refined, observations) if loss == "trivial" else None
    rig = _build_rig(names, image_sizes, params, cam_poses, observations.camera, image_of_point, residuals,
                     covariance, labels, board, model, units, jackknife)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if shape is not None:
        rig = Rig(rig.cameras, units=rig.units, provenance={**rig.provenance, "board_shape": shape.to_dict()})
        notes.append(f"{shape.describe(board)}; held, not fitted")
    if holdout:
        heldout_rms, per_camera, heldout_images, heldout, per_view = heldout_figures(
            board, rig, held, None if shape is None else points)
        rig = Rig(tuple(dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]})
                        if camera.name in per_camera else camera for camera in rig.cameras),
                  units=rig.units, provenance=rig.provenance)
    norms = np.linalg.norm(residuals, axis=1)
    return CalibrationResult(
        rig=rig,
        residuals_px=residuals,
        points_px=observations.xy,
        camera_of_point=observations.camera,
        image_of_point=image_of_point,
        images=tuple((names[j], by_frame[j][f].image) for j, f in kept),
        rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()),
        outliers=tuple((names[j], by_frame[j][f].image) for j, f in sorted(outliers)),
        covariance=np.zeros((0, 0)) if covariance is None else covariance,
        parameter_names=labels,
        model=model,
        heldout_rms_px=heldout_rms,
        heldout_images=heldout_images,
        heldout_view_rms_px=per_view,
        relabelled=tuple(relabelled),
        dropped=tuple(dropped),
        notes=tuple(notes),
        board_poses=tuple((f, *view_start[f]) for f in sorted({f for _, f in kept})),
        board_shape=shape,
        **heldout_fields(heldout),
    )


def heldout_fields(heldout: list) -> dict:
    """The result's held-out residuals, points and camera indices from :func:`heldout_figures`'s ``views``."""
    if not heldout:
        return {"heldout_residuals_px": np.zeros((0, 2)), "heldout_points_px": np.zeros((0, 2)),
                "heldout_camera_of_point": np.zeros(0, np.int64)}
    return {"heldout_residuals_px": np.concatenate([r for _, r, _ in heldout]),
            "heldout_points_px": np.concatenate([x for _, _, x in heldout]),
            "heldout_camera_of_point": np.concatenate([np.full(len(r), j) for j, r, _ in heldout])}


def _view_jackknife(labels: tuple[str, ...], names: list[str], model: str, params: list[NDArray],
                    refined: BundleState, observations: BoardObservations) -> NDArray | None:
    """The delete-one-view jackknife covariance over ``labels`` (:mod:`camcal.geometry.view_jackknife`);
    None below its minimum of views (plain least squares only: no robust loss)."""
    free = ("f", "cx", "cy") if model == "division" else INTRINSICS
    lenses = [(*camcal_lens(model, params[j]), free + MODELS[model]) for j in range(len(names))]
    jackknife = view_jackknife(lenses, refined.sensor_R, refined.sensor_t, refined.frame_R, refined.frame_t,
                               observations, labels, names)
    return None if jackknife is None else jackknife.covariance


def _calibrate_opencv(board: Board, names: list[str], by_frame: list[dict], model: str, units: str,
                      outlier_factor: float, min_outlier_px: float, shared: dict | None = None) -> CalibrationResult:
    """One camera fitted by OpenCV's ``calibrateCameraExtended`` alone (a model the Ceres engine lacks).

    COLMAP has no pinhole camera with thin-prism terms, so ``opencv-thin-prism``
    is OpenCV's Levenberg-Marquardt (flags ``CALIB_RATIONAL_MODEL |
    CALIB_THIN_PRISM_MODEL``, the same cost: squared distorted-pixel
    residuals), with the same outlier rounds. Its covariance is diagonal:
    OpenCV's ``stdDeviationsIntrinsics`` (``sigma^2 (J^T J)^-1`` of the
    intrinsics, ``sigma^2`` from the residuals).
    """
    if len(names) > 1:
        raise CamcalError(f"model {model} calibrates one camera at a time (COLMAP's models, the rig engine's, "
                          f"have no thin prism); got {len(names)} cameras")
    name, views = names[0], by_frame[0]
    size = next(iter(views.values())).image_size
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    outliers: list[int] = []
    for round_ in range(_MAX_OUTLIER_ROUNDS + 1):
        kept = [f for f in sorted(views) if f not in outliers]
        if len(kept) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: only {len(kept)} images left after dropping outliers, need {MIN_IMAGES}")
        object_points = [board.object_points[views[f].ids].astype(np.float32) for f in kept]
        image_points = [views[f].corners_px.astype(np.float32).reshape(-1, 1, 2) for f in kept]
        K, dist, _ = opencv_start(board, {f: views[f] for f in kept}, model, name, shared)
        try:
            _, K, dist, rvecs, tvecs, std_intrinsics, _, _ = cv2.calibrateCameraExtended(
                object_points, image_points, size, K, dist, criteria=criteria,
                flags=OPENCV_FLAGS[model] | cv2.CALIB_USE_INTRINSIC_GUESS)
        except cv2.error as error:
            raise CamcalError(f"camera {name!r}: OpenCV calibrateCamera failed ({one_line(error)})") from None
        params = np.concatenate([[K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5], dist.ravel()[:len(MODELS[model])]])
        _, lens = camcal_lens(model, params)
        residuals = np.concatenate([
            lens.project_rays(board.object_points[views[f].ids] @ cv2.Rodrigues(r)[0].T + t.ravel(), K)
            - views[f].corners_px for f, r, t in zip(kept, rvecs, tvecs)])
        if not np.all(np.isfinite(residuals)) or not np.all(np.isfinite(params)):
            raise CamcalError(f"camera {name!r}: OpenCV's {model} fit diverged (non-finite residuals)")
        image_of_point = np.concatenate([np.full(len(views[f].ids), n) for n, f in enumerate(kept)])
        image_rms = np.sqrt(np.bincount(image_of_point, np.sum(residuals**2, axis=1)) / np.bincount(image_of_point))
        threshold = max(outlier_factor * np.median(image_rms), min_outlier_px)
        new = [kept[n] for n in np.flatnonzero(image_rms > threshold)]
        if not new or round_ == _MAX_OUTLIER_ROUNDS:
            break
        outliers.extend(new)
    labels = tuple(f"{name}.{label}" for label in INTRINSICS + MODELS[model])
    sigmas = std_intrinsics.ravel()[:len(labels)]
    if not np.all(np.isfinite(sigmas)):
        raise CamcalError(f"camera {name!r}: the {model} calibration is degenerate (OpenCV's intrinsic sigmas are "
                          "not finite): vary the board poses more")
    covariance = np.diag(sigmas**2)
    camera_of_point = np.zeros(len(residuals), np.int64)
    rig = _build_rig(names, (size,), [params], [(np.eye(3), np.zeros(3))], camera_of_point, image_of_point,
                     residuals, covariance, labels, board, model, units)
    norms = np.linalg.norm(residuals, axis=1)
    return CalibrationResult(
        rig=rig, residuals_px=residuals, points_px=np.concatenate([views[f].corners_px for f in kept]),
        camera_of_point=camera_of_point, image_of_point=image_of_point,
        images=tuple((name, views[f].image) for f in kept), rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()), outliers=tuple((name, views[f].image) for f in sorted(outliers)),
        covariance=covariance, parameter_names=labels, model=model,
        board_poses=tuple((f, cv2.Rodrigues(r)[0], np.ravel(t).copy()) for f, r, t in zip(kept, rvecs, tvecs)),
        notes=(f"{model}: fitted by OpenCV's calibrateCamera (the Ceres engine's COLMAP models have no thin prism); "
               "its covariance is diagonal",),
    )


def heldout_figures(board: Board, rig: Rig, held: list[dict], points: NDArray | None = None):
    """RMS of the held-out views, each posed by PnP with the fitted intrinsics held (against the board's fitted
    surface, ``points``, when it is not flat).

    Each view's ``cam_from_board`` minimises ``sum |project(K, d, R X + t) -
    x|^2`` over its six pose parameters alone (:func:`camcal.geometry.spline_fit.pose_view`:
    Levenberg-Marquardt, camcal's own projection of the fitted lens, so every
    model is measured alike), started from OpenCV's ``solvePnP`` on the
    undistorted corners. A view is posed on its own: a corner seen in one
    view only counts like any other.

    Returns
    -------
    rms_px, per_camera_rms_px, images, views, per_view_rms_px
        ``views``: ``(camera index, projected - detected, detected)`` of each held-out view;
        ``per_view_rms_px``: the RMS of each held-out view (both in the order of images).
    """
    squared, counts, per_camera, images, residuals, per_view = 0.0, 0, {}, [], [], []
    for j, (camera, views) in enumerate(zip(rig.cameras, held)):
        if not views:
            continue
        s_camera, n_camera = 0.0, 0
        for key in sorted(views):
            r = posed_residuals(board, camera, views[key], points)
            s_camera, n_camera = s_camera + float(np.sum(r * r)), n_camera + len(r)
            images.append((camera.name, views[key].image))
            residuals.append((j, r, views[key].corners_px))
            per_view.append(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))))
        per_camera[camera.name] = float(np.sqrt(s_camera / n_camera))
        squared, counts = squared + s_camera, counts + n_camera
    return float(np.sqrt(squared / counts)), per_camera, tuple(images), residuals, tuple(per_view)


def posed_residuals(board: Board, camera: Camera, detection: Detection,
                     points: NDArray | None = None) -> NDArray[np.float64]:
    """``projected - detected`` (N, 2) of one view posed with the camera's intrinsics held (see :func:`heldout_figures`)."""
    try:
        return pose_view(board, camera.K, camera.distortion, detection, points)[2]
    except CamcalError as error:
        raise CamcalError(f"camera {camera.name!r}, held-out view {error}") from None


def _with_projection_sigma(camera: Camera, covariance: NDArray, labels: tuple[str, ...], model: str,
                           jackknife: NDArray | None = None, earlier: Sequence[str] = ()) -> Camera:
    """The camera with ``quality.covariance`` (its intrinsics, its pose, the board gauge and, under their
    ``NAME.param`` labels, the intrinsics and poses of the ``earlier`` cameras: the cross-covariance a
    pair's figures need, :mod:`camcal.geometry.rectify.sigma`) and
    ``quality.worst_projection_sigma_px`` (at infinity, over a 16-pixel grid of the frame;
    :mod:`camcal.geometry.uncertainty`).

    With the delete-one-view ``jackknife`` covariance the block is scaled by
    the design effect of the camera's projection
    (:func:`camcal.geometry.view_jackknife.design_effect`): the corners'
    errors are correlated within a view. ``quality.sigma`` (per parameter)
    stays the corners' covariance."""
    pairs = [(f"{camera.name}.{label}", label) for label in INTRINSICS + MODELS[model] + POSE]
    pairs += [(f"{other}.{label}",) * 2 for other in earlier for label in INTRINSICS + MODELS[model] + POSE]
    pairs = [(label, name) for label, name in pairs + list(zip(GAUGE_NAMES, GAUGE)) if label in labels]
    index = [labels.index(label) for label, _ in pairs]
    names = [name for _, name in pairs]

    def block_of(matrix: NDArray) -> ParameterCovariance:
        block = matrix[np.ix_(index, index)]
        return ParameterCovariance(tuple(names), 0.5 * (block + block.T))

    parameters = block_of(covariance)
    camera = dataclasses.replace(camera, quality={**camera.quality.to_dict(), "covariance": parameters})
    xs, ys = sigma_grid(camera.image_size, 16.0)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    sigma = projection_sigma(camera, grid)
    if jackknife is not None:
        factor = design_effect(sigma, projection_sigma(camera, grid, covariance=block_of(jackknife)))
        parameters = ParameterCovariance(tuple(names), factor * parameters.array)
        sigma = sigma * np.sqrt(factor)
    worst = float(np.nanmax(sigma))
    return dataclasses.replace(camera, quality={**camera.quality.to_dict(), "covariance": parameters,
                                                "worst_projection_sigma_px": worst})


def _build_rig(names, image_sizes, params, cam_poses, camera_of_point, image_of_point, residuals, covariance, labels,
               board, model, units, jackknife=None) -> Rig:
    """The rig of a fit; ``covariance`` None (a scoring fit, :func:`calibrate_model`): no sigmas."""
    sigma_by_label = {} if covariance is None else dict(zip(labels, np.sqrt(np.clip(np.diag(covariance), 0.0, None))))
    cameras = []
    for j, name in enumerate(names):
        K, distortion = camcal_lens(model, params[j])
        R, t = cam_poses[j]
        mine = camera_of_point == j
        norms = np.linalg.norm(residuals[mine], axis=1)
        if covariance is None:
            cameras.append(Camera(name, image_sizes[j], K, distortion, R if j else np.eye(3), -R.T @ t if j else np.zeros(3),
                                  quality={"rms_px": float(np.sqrt(np.mean(norms**2))), "worst_px": float(norms.max()),
                                           "n_views": int(len(np.unique(image_of_point[mine]))),
                                           "n_observations": int(mine.sum())}))
            continue
        sigmas = {label: float(sigma_by_label[f"{name}.{label}"]) for label in INTRINSICS + MODELS[model]}
        if j > 0:
            o = labels.index(f"{name}.rx")
            rotation, translation = covariance[o:o + 3, o:o + 3], covariance[o + 3:o + 6, o + 3:o + 6]
            length = float(np.linalg.norm(t))
            along = t / max(length, 1e-300)
            across = np.eye(3) - np.outer(along, along)
            sigmas["baseline_rel"] = float(np.sqrt(max(along @ translation @ along, 0.0))) / max(length, 1e-300)
            sigmas["baseline_direction_deg"] = float(
                np.degrees(np.sqrt(max(np.trace(across @ translation @ across), 0.0)) / max(length, 1e-300)))
            sigmas["rotation_deg"] = float(np.degrees(np.sqrt(max(np.trace(rotation), 0.0))))
        cameras.append(_with_projection_sigma(
            Camera(
                name=name,
                image_size=image_sizes[j],
                K=K,
                distortion=distortion,
                R=R if j else np.eye(3),
                c=-R.T @ t if j else np.zeros(3),
                quality={
                    "rms_px": float(np.sqrt(np.mean(norms**2))),
                    "worst_px": float(norms.max()),
                    "n_views": int(len(np.unique(image_of_point[mine]))),
                    "n_observations": int(mine.sum()),
                    "sigma": sigmas,
                },
            ), covariance, labels, model, jackknife, names[:j]))
    method = "chessboard" if board.kind == "chessboard" else "charuco"
    return Rig(tuple(cameras), units=units, provenance=make_provenance(method, board=board.spec(), model=model))
