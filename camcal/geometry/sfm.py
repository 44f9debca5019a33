"""A pycolmap reconstruction as camcal's rig: cameras, frames, sparse points and their reprojection.

The reconstruction (one rig, from :mod:`camcal.pipelines.solve`) becomes a
:class:`camcal.model.rig.Rig` whose ``frames`` hold each frame's
``rig_from_world`` and whose cameras hold ``cam_from_rig`` (the reference
sensor at the rig origin), with its sparse points beside it
(:class:`SparseModel`). COLMAP's pixel centre (0.5) is converted at the
boundary (:mod:`camcal.model.colmap`). Before camcal's refinement, observations
the noise does not explain are dropped (:func:`reject_outliers`).

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.bundle import BundleResult
from camcal.geometry.bundle.reconstruction import image_observations
from camcal.geometry.selfcal import SelfCalibration, as_lens_model
from camcal.geometry.uncertainty import (covariance_from_colmap, projection_covariance, projection_sigma,
                                         shrunk_design_effect, sigma_grid)
from camcal.model.colmap import camera_from_colmap
from camcal.model.camera import from_colmap, pixels_from_colmap
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera, Frame, Rig, make_provenance
from camcal.model.rig_frames import Lens

__all__ = [
    "MIN_TRIANGULATION_ANGLE_DEG",
    "SparseModel",
    "camera_name",
    "check_every_camera_registered",
    "reject_outliers",
    "relative_poses",
    "sparse_model",
]

#: points triangulated under a smaller angle are dropped before the refinement (COLMAP's mapper default).
MIN_TRIANGULATION_ANGLE_DEG = 1.5


@dataclass(frozen=True)
class SparseModel:
    """A pycolmap reconstruction as camcal's rig, its sparse points and how well the rig reprojects them.

    Attributes
    ----------
    rig : Rig
        Cameras (cam_from_rig), per-frame rig poses (their images named as
        in ``originals`` of :func:`sparse_model`), ``points`` the file name
        the points are to be written under.
    xyz : ndarray, shape (P, 3)
        Sparse 3D points, in the rig's units.
    colours : ndarray of uint8, shape (P, 3)
        Their RGB colours.
    track_lengths : ndarray of int32, shape (P,)
        Observations per point.
    registered : tuple of str
        COLMAP image names with a pose.
    rms_px : float
        RMS reprojection error of every observation through the camcal rig
        (distortion included), in pixels.
    per_camera_rms_px : dict of str to float
        The same per camera.
    """

    rig: Rig
    xyz: NDArray[np.float64]
    colours: NDArray[np.uint8]
    track_lengths: NDArray[np.int32]
    registered: tuple[str, ...]
    rms_px: float
    per_camera_rms_px: dict[str, float]


def reject_outliers(reconstruction, n_sigma: float = 4.0) -> str:
    """Delete the observations beyond ``n_sigma`` sigma of the reprojection noise (in place).

    Notes
    -----
    With Gaussian noise of sigma per axis the residual norm follows a
    Rayleigh law: its median is ``sigma sqrt(2 ln 2)`` (1.1774 sigma), so
    sigma is estimated robustly from the median; beyond ``4 sigma`` lie
    ``exp(-8)`` = 0.03 % of the inliers. Points left with fewer than two
    observations go (COLMAP's ``ObservationManager``), and so do points whose
    rays meet under less than :data:`MIN_TRIANGULATION_ANGLE_DEG` (COLMAP's
    mapper filter).

    Returns
    -------
    str
        What was dropped, with the threshold, for the user.
    """
    pycolmap = require("pycolmap")

    errors = _reprojection_errors(reconstruction)
    if not len(errors):
        raise CamcalError("the reconstruction has no observations to refine")
    sigma = float(np.median(errors)) / np.sqrt(2.0 * np.log(2.0))
    threshold = n_sigma * sigma
    manager = pycolmap.ObservationManager(reconstruction)
    dropped = manager.filter_points3D_with_large_reprojection_error(threshold, set(reconstruction.points3D))
    # a point seen along nearly parallel rays has a depth the data barely fix: one such point
    # makes the covariance of the whole problem singular
    narrow = manager.filter_points3D_with_small_triangulation_angle(MIN_TRIANGULATION_ANGLE_DEG,
                                                                    set(reconstruction.points3D))
    return (f"dropped {dropped} of {len(errors)} observations beyond {threshold:.3f} px "
            f"({n_sigma:g} sigma; sigma {sigma:.3f} px from the median residual) and {narrow} of the points "
            f"triangulated under {MIN_TRIANGULATION_ANGLE_DEG:g} deg")


def _reprojection_errors(reconstruction) -> NDArray[np.float64]:
    """Reprojection error (px) of every observation of every posed image, image by image; inf behind the camera."""
    points = reconstruction.points3D
    ids = np.fromiter(points.keys(), dtype=np.int64, count=len(points))
    order = np.argsort(ids)
    xyz = np.array([point.xyz for point in points.values()], dtype=np.float64).reshape(-1, 3)[order]
    ids = ids[order]
    errors = []
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        which, xy = image_observations(image, ids)
        if not len(which):
            continue
        # img_from_cam with its cheirality check: NaN for a point behind the camera
        projected = reconstruction.cameras[image.camera_id].img_from_cam(image.cam_from_world() * xyz[which])
        error = np.linalg.norm(xy - projected, axis=1)
        errors.append(np.where(np.isnan(error), np.inf, error))
    return np.concatenate(errors) if errors else np.zeros(0)


def relative_poses(rig: Rig, reference: str) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Each camera's ``cam_from_reference`` (R, t) in a calibrated rig (X_cam = R X_ref + t)."""
    names = {camera.name for camera in rig.cameras}
    if reference not in names:
        raise CamcalError(f"the known rig has no camera named {reference!r}")
    ref = rig.camera(reference)
    return {camera.name: (camera.R @ ref.R.T, camera.R @ (ref.c - camera.c)) for camera in rig.cameras}


def sparse_model(reconstruction, camera_names: list[str], originals: dict[str, str], units: str,
                 bundle: BundleResult | None, calibration: SelfCalibration | None,
                 points_file: str = "points.ply", lenses: Mapping[str, Lens] | None = None) -> SparseModel:
    """Convert a pycolmap reconstruction with one rig into camcal's rig and sparse points.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    camera_names : list of str
        The cameras, in the rig's order (the folder names its images sit in).
    originals : dict of str to str
        Every COLMAP image name -> the user's image (as the frames are to
        name it).
    units : str
        The reconstruction's units.
    bundle, calibration : BundleResult or None, SelfCalibration or None
        camcal's refinement and self-calibration, for the cameras' quality.
    points_file : str
        The name the rig gives its points.
    lenses : mapping of str to Lens, optional
        A lens per frame (a zoom, a refocus): COLMAP image name -> its lens, which the frame of that image
        carries (:attr:`camcal.model.rig_frames.Frame.lenses`); the reconstruction then has one COLMAP camera
        (and rig) per image of one camera, and the rig's camera is the first of them.
    """
    if reconstruction.num_rigs() != 1 and not lenses:
        raise CamcalError(f"expected one rig in the reconstruction, got {reconstruction.num_rigs()}")
    rig = next(iter(reconstruction.rigs.values()))
    cameras = []
    camera_of_sensor: dict[int, str] = {}
    for camera_id, colmap_camera in sorted(reconstruction.cameras.items()):
        name = camera_name(reconstruction, camera_id)
        if name in camera_of_sensor.values():  # a lens per frame: the camera once, its lenses in the frames
            camera_of_sensor[camera_id] = name
            continue
        if lenses or rig.is_ref_sensor(_sensor(camera_id)):
            R, c = np.eye(3), np.zeros(3)
        else:
            sensor_from_rig = rig.sensor_from_rig(_sensor(camera_id))
            R, c = from_colmap(sensor_from_rig.rotation.quat, sensor_from_rig.translation)
        camera = camera_from_colmap(name, colmap_camera.model.name, (colmap_camera.width, colmap_camera.height),
                                    colmap_camera.params, R, c)
        if calibration is not None and name in calibration.lens_models:
            camera = as_lens_model(camera, calibration.lens_models[name])
        cameras.append(camera)
        camera_of_sensor[camera_id] = name
    order = {name: index for index, name in enumerate(camera_names)}
    cameras.sort(key=lambda camera: order[camera.name])

    frames = []
    frame_of_image: dict[str, int] = {}
    for frame_index, frame_id in enumerate(sorted(reconstruction.reg_frame_ids())):
        frame = reconstruction.frame(frame_id)
        R, c = from_colmap(frame.rig_from_world.rotation.quat, frame.rig_from_world.translation)
        images = {}
        for data_id in frame.image_ids:
            image = reconstruction.image(data_id.id)
            images[camera_of_sensor[image.camera_id]] = originals[image.name]
            frame_of_image[image.name] = frame_index
        frame_lenses = {} if not lenses else {
            camera_of_sensor[reconstruction.image(data_id.id).camera_id]: lenses[reconstruction.image(data_id.id).name]
            for data_id in frame.image_ids}
        frames.append(Frame(frame_index, R, c, images, frame_lenses))
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()]).reshape(-1, 3)
    colours = np.array([p.color for p in reconstruction.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in reconstruction.points3D.values()], dtype=np.int32)
    result_rig = Rig(
        tuple(cameras), units=units, frames=tuple(frames), points=points_file,
        provenance=make_provenance("sfm (pycolmap)" + (" + camcal bundle adjustment" if bundle else ""),
                                   images=len(originals),
                                   **({"self_calibration": calibration.lines()} if calibration else {})),
    )
    per_camera, rms = _reprojection_rms(reconstruction, result_rig, camera_of_sensor, frame_of_image)
    return SparseModel(
        rig=_with_quality(result_rig, per_camera, bundle, calibration), xyz=xyz, colours=colours,
        track_lengths=tracks, registered=tuple(frame_of_image), rms_px=rms,
        per_camera_rms_px={name: value for name, (value, _) in per_camera.items()},
    )


def _sensor(camera_id: int):
    """The pycolmap sensor id of a camera."""
    pycolmap = require("pycolmap")

    return pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_id)


def camera_name(reconstruction, camera_id: int) -> str:
    """The camera's folder name, from the name of one of its images."""
    for image in reconstruction.images.values():
        if image.camera_id == camera_id:
            return image.name.split("/", 1)[0]
    raise CamcalError(f"COLMAP camera {camera_id} has no registered image")


def check_every_camera_registered(reconstruction, image_counts: Mapping[str, int]) -> None:
    """Refuse a reconstruction in which a camera of a rig has no registered image.

    COLMAP takes each camera's pose in the rig (``sensor_from_rig``) from an
    unconstrained first pass; a camera none of whose images that pass
    registered stops ``apply_rig_config`` with an internal error. This names
    the camera instead.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        The first pass (anything whose ``images`` values have ``name``,
        ``camera/<file>``, and ``has_pose``).
    image_counts : mapping of str to int
        Camera name -> how many of its images went into the pass.

    Raises
    ------
    CamcalError
        Naming every camera with no registered image, and what to try.
    """
    registered = {name: 0 for name in image_counts}
    for image in reconstruction.images.values():
        camera = image.name.split("/", 1)[0]
        if image.has_pose and camera in registered:
            registered[camera] += 1
    missing = [name for name, count in registered.items() if count == 0]
    if missing:
        which = ", ".join(f"{name!r} (0 of {image_counts[name]} images)" for name in missing)
        raise CamcalError(f"structure from motion registered no image of camera {which}, so the cameras cannot "
                          "form a rig: give its images more overlap with the other cameras' views, mask what moves "
                          "(--mask), name a fisheye lens (--model kannala-brandt), or solve that camera alone")


def _reprojection_rms(reconstruction, rig: Rig, camera_of_sensor: dict[int, str], frame_of_image: dict[str, int]):
    """Reproject every observation through camcal's rig (checks the conversion too)."""
    squared: dict[str, list[NDArray[np.float64]]] = {}
    for image in reconstruction.images.values():
        if image.name not in frame_of_image:
            continue
        observed = [(p.xy, reconstruction.points3D[p.point3D_id].xyz) for p in image.points2D if p.has_point3D()]
        if not observed:
            continue
        xy = pixels_from_colmap([o[0] for o in observed])
        X = np.array([o[1] for o in observed])
        name = camera_of_sensor[image.camera_id]
        camera = rig.camera_at_frame(name, frame_of_image[image.name])
        squared.setdefault(name, []).append(np.sum((camera.project(X) - xy) ** 2, axis=1))
    per_camera = {name: (float(np.sqrt(np.mean(np.concatenate(v)))), int(sum(len(a) for a in v))) for name, v in squared.items()}
    everything = np.concatenate([np.concatenate(v) for v in squared.values()])
    return per_camera, float(np.sqrt(np.mean(everything)))


def _quality_sigma(sigmas: dict[str, float], camera: str, model: str, focal: float) -> dict[str, float]:
    """A camera's sigmas under :mod:`camcal.model.quality`'s names: one focal ``f`` is ``fx`` and ``fy``,
    COLMAP's division ``k`` becomes camcal's ``lambda = k / fx^2`` (focal's own spread neglected),
    SIMPLE_RADIAL's ``k`` is ``k1``."""
    prefix = f"{camera}."
    out = {}
    for key, value in sigmas.items():
        if not key.startswith(prefix):
            continue
        name = key[len(prefix):]
        if name == "k" and model in ("SIMPLE_DIVISION", "DIVISION"):
            name, value = "lambda", value / (focal * focal)
        elif name == "k":
            name = "k1"
        if name == "f":
            out["fx"] = out["fy"] = value
        else:
            out[name] = value
    return out


def _projection_quality(rig: Rig, camera: Camera, bundle: BundleResult, calibration: SelfCalibration | None) -> dict:
    """``covariance`` and ``worst_projection_sigma_px`` of a solved camera (:mod:`camcal.geometry.uncertainty`:
    its intrinsics, its rig pose and the scene gauge, :func:`camcal.geometry.uncertainty.scene_gauge_rows`,
    when the frames' turns determine it), empty without a covariance.

    With the delete-one-frame jackknife the covariance is scaled by the design effect of the camera's projection
    (:func:`camcal.geometry.uncertainty.shrunk_design_effect`: the features' errors are correlated within a
    frame and between neighbouring frames), pooled over a grid of its frame: each jackknife group's influence
    (one frame, or contiguous frames on a plate) on the intrinsics, the rig pose and the scene gauge together
    (:func:`camcal.geometry.bundle.influences.frame_influences`) projected, so that a principal point's move and
    the gauge's turn that cancel in the projection cancel in it too."""
    state = bundle.state
    if not len(bundle.covariance_names) or camera.name not in state.camera_names:
        return {}
    order = [rig.camera(name) for name in state.camera_names]
    index = state.camera_names.index(camera.name)

    def in_camcal_names(names, matrix) -> ParameterCovariance | None:
        return covariance_from_colmap(order, state.models, state.params, [state.param_names(k) for k in range(len(order))],
                                      names, matrix, index)

    covariance = in_camcal_names(bundle.covariance_names, bundle.covariance)
    if covariance is None:
        return {}
    xs, ys = sigma_grid(camera.image_size, 16.0)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    influences = calibration.frame_influences if calibration is not None else None
    if influences is not None and len(influences.values) >= 2:
        moves = influences.values - influences.values.mean(axis=0)
        n = len(moves)

        def pooled(matrix) -> float:
            spread = in_camcal_names(influences.names, matrix)
            if spread is None:
                return float("nan")
            return float(np.nanmean(np.trace(projection_covariance(camera, grid, covariance=spread), axis1=1, axis2=2)))

        model = float(np.nanmean(np.trace(projection_covariance(camera, grid, covariance=covariance), axis1=1, axis2=2)))
        factor = shrunk_design_effect(model, [(n - 1) / n * pooled(np.outer(move, move)) for move in moves])
        covariance = ParameterCovariance(covariance.names, factor * covariance.array)
    worst = float(np.nanmax(projection_sigma(camera, grid, covariance=covariance)))
    return {"covariance": covariance, "worst_projection_sigma_px": worst}


def _with_quality(rig: Rig, per_camera: dict[str, tuple[float, int]], bundle: BundleResult | None,
                  calibration: SelfCalibration | None) -> Rig:
    cameras = []
    for camera in rig.cameras:
        if camera.name not in per_camera:
            cameras.append(camera)
            continue
        quality: dict = {"rms_px": per_camera[camera.name][0], "n_observations": per_camera[camera.name][1]}
        if calibration is not None:
            quality["heldout_rms_px"] = calibration.heldout_rms_px[camera.name][calibration.lens_models[camera.name]]
        if bundle is not None and camera.name in bundle.state.camera_names:
            quality["rms_seed_px"] = bundle.rms_before_px[camera.name]
            index = bundle.state.camera_names.index(camera.name)
            quality["sigma"] = _quality_sigma(bundle.sigmas, camera.name, bundle.state.models[index],
                                              float(bundle.state.params[index][0]))
            quality.update(_projection_quality(rig, camera, bundle, calibration))
        cameras.append(dataclasses.replace(camera, quality=quality))
    return dataclasses.replace(rig, cameras=tuple(cameras))


