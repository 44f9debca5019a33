"""The lens models of self-calibration: their COLMAP twins, the conversion between them, their held-out score.

Each camcal lens model is refined as a COLMAP camera model with two focal
lengths (:data:`MODELS`); a camera is converted from one to another by
fitting the new distortion to the old over the frame (:func:`with_lenses`),
and a fit's lens is scored by the reprojection error of points left out of
it, re-triangulated through its cameras (:func:`heldout_rms`).
:func:`camcal.geometry.selfcal.self_calibrate` chooses among them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, BundleState
from camcal.geometry.bundle.state import model_layout
from camcal.model.colmap import camera_from_colmap, camera_to_colmap
from camcal.model.distortion import Distortion, fit_distortion
from camcal.model.rig import Camera

__all__ = ["FIXED_PARAMS", "LENS_MODELS", "MAPPING_MODELS", "MODELS", "as_lens_model", "heldout_rms",
           "with_fixed_params", "with_lenses"]

#: camcal's distortion models and the COLMAP camera model with two focal lengths (fx, fy) that the
#: self-calibration refines each of them as: ``polynomial`` (k1, k2) is ``OPENCV`` with ``p1 = p2 = 0``
#: held (:data:`FIXED_PARAMS`), COLMAP having no two-focal radial model.
MODELS = {"division": "DIVISION", "polynomial": "OPENCV", "opencv": "OPENCV", "none": "PINHOLE",
          "kannala-brandt": "OPENCV_FISHEYE"}
#: COLMAP parameters held at 0 in each camcal lens model's twin (:data:`MODELS`).
FIXED_PARAMS = {"polynomial": ("p1", "p2")}
#: the COLMAP model structure from motion maps a camcal lens model with (one focal length where COLMAP has one:
#: the mapper's early bundle adjustments on two or three images do not determine the aspect).
MAPPING_MODELS = {"division": "SIMPLE_DIVISION", "polynomial": "RADIAL", "opencv": "OPENCV", "none": "SIMPLE_PINHOLE",
                  "kannala-brandt": "OPENCV_FISHEYE"}
#: the lens models ``solve`` chooses among by held-out residual (``--model auto``), simplest first;
#: pinhole models only: ``kannala-brandt`` (a fisheye) is used when named, never chosen.
LENS_MODELS = ("division", "polynomial", "opencv")


def _lens_params(state: BundleState, camera: int, model: str) -> NDArray[np.float64]:
    """Camera ``camera``'s COLMAP parameters in the COLMAP twin of camcal ``model`` (:data:`MODELS`).

    The focal lengths and principal point carry over; the distortion is
    :func:`camcal.model.distortion.fit_distortion` of the current one over
    the frame at the mean focal length (COLMAP's distortion acts on
    normalised coordinates: with ``fx`` and ``fy`` put back it is the
    start of the refinement, which moves all of them).
    """
    names = state.param_names(camera)
    if state.models[camera] == MODELS[model]:
        params = state.params[camera].copy()
        params[[names.index(key) for key in FIXED_PARAMS.get(model, ())]] = 0.0
        return params
    name, size = state.camera_names[camera], state.image_sizes[camera]
    lens = camera_from_colmap(name, state.models[camera], size, state.params[camera], np.eye(3), np.zeros(3))
    fx, fy = float(lens.K[0, 0]), float(lens.K[1, 1])
    K = lens.K.copy()
    K[0, 0] = K[1, 1] = 0.5 * (fx + fy)
    K[0, 1] = 0.0
    if model == "none":
        distortion = Distortion.none()
    else:
        distortion = fit_distortion(lens.distortion, K, size, model).distortion
        if model == "opencv":
            distortion = Distortion("opencv", {**distortion.params, "k3": 0.0})
    colmap = camera_to_colmap(dataclasses.replace(lens, K=K, distortion=distortion))
    single = colmap.model != "OPENCV" and not colmap.model.endswith("FISHEYE")
    params = (fx, fy) + colmap.params[1:] if single else (fx, fy) + colmap.params[2:]
    if model == "polynomial":  # RADIAL (f, cx, cy, k1, k2) -> OPENCV (fx, fy, cx, cy, k1, k2, p1, p2)
        params += (0.0, 0.0)
    if len(params) != len(model_layout(MODELS[model])[0]):
        raise CamcalError(f"camera {name!r}: {model} converted to COLMAP {colmap.model}, expected {MODELS[model]}")
    return np.array(params, dtype=np.float64)


def as_lens_model(camera: Camera, model: str) -> Camera:
    """The camera with its distortion named as camcal lens model ``model`` (the same projection).

    ``polynomial`` is refined as COLMAP's ``OPENCV`` with ``p1 = p2 = 0``
    held (:data:`MODELS`), which comes back as an ``opencv`` lens: its
    ``k1, k2`` are the polynomial's.
    """
    distortion = camera.distortion
    if model == "polynomial" and distortion.model == "opencv":
        params = distortion.params
        if any(params.get(key, 0.0) != 0.0 for key in ("p1", "p2", "k3")):
            raise CamcalError(f"camera {camera.name!r}: an opencv lens with tangential or k3 terms is not polynomial")
        return dataclasses.replace(camera, distortion=Distortion("polynomial", {"k1": params["k1"], "k2": params["k2"]}))
    return camera


def with_fixed_params(options: BundleOptions, lenses: dict[str, str]) -> BundleOptions:
    """``options`` with each camera's :data:`FIXED_PARAMS` held as well (``camera name -> camcal model``)."""
    fixed = {name: tuple(held) for name, held in options.fixed_params.items()}
    for name, model in lenses.items():
        fixed[name] = tuple(dict.fromkeys(fixed.get(name, ()) + FIXED_PARAMS.get(model, ())))
    return dataclasses.replace(options, fixed_params={name: held for name, held in fixed.items() if held})


def with_lenses(state: BundleState, lenses: dict[str, str]) -> BundleState:
    """The state with each camera's lens model replaced (``camera name -> camcal model``)."""
    params = tuple(_lens_params(state, k, lenses[name]) for k, name in enumerate(state.camera_names))
    return dataclasses.replace(state, models=tuple(MODELS[lenses[name]] for name in state.camera_names), params=params)


def _project_observations(state: BundleState, X: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels (camcal convention) of the points ``X`` (one per observation) through camcal's cameras."""
    out = np.full((len(X), 2), np.nan)
    lenses = [camera_from_colmap(name, model, size, params, np.eye(3), np.zeros(3))
              for name, model, size, params in zip(state.camera_names, state.models, state.image_sizes, state.params)]
    pairs = np.unique(np.stack([state.obs_camera, state.obs_frame], axis=1), axis=0)
    for camera, frame in pairs:
        mask = (state.obs_camera == camera) & (state.obs_frame == frame)
        R = state.sensor_R[camera] @ state.frame_R[frame]
        t = state.sensor_R[camera] @ state.frame_t[frame] + state.sensor_t[camera]
        posed = dataclasses.replace(lenses[camera], R=R, c=-R.T @ t)
        with np.errstate(invalid="ignore"):
            out[mask] = posed.project(X[mask])
    return out


def heldout_rms(fitted: BundleState, heldout: BundleState, iterations: int = 6) -> dict[str, float]:
    """RMS reprojection error per camera of points left out of a fit.

    Parameters
    ----------
    fitted : BundleState
        The fit: its cameras, rig and frame poses are held.
    heldout : BundleState
        The same cameras and frames with the held-out points and their
        observations (the points' coordinates are only the start).

    Returns
    -------
    dict of str to float
        Camera name -> RMS in pixels, each held-out point re-triangulated
        by Gauss-Newton on its reprojection error through the fitted
        cameras (forward-difference Jacobian, 3 columns per point).

    Notes
    -----
    A point seen ``n`` times leaves ``2 n - 3`` degrees of freedom, so the
    RMS sits slightly below the noise; it is the same for every lens model
    compared on the same points, which is what the comparison needs.
    """
    state = dataclasses.replace(heldout, models=fitted.models, params=fitted.params, sensor_R=fitted.sensor_R,
                                sensor_t=fitted.sensor_t, frame_R=fitted.frame_R, frame_t=fitted.frame_t)
    points = state.points.copy()
    n = len(points)
    for _ in range(iterations):
        X = points[state.obs_point]
        r = _project_observations(state, X) - state.obs_xy
        step = 1e-6 * max(1.0, float(np.abs(points).max()))
        J = np.empty((len(X), 2, 3))
        for axis in range(3):
            shifted = X.copy()
            shifted[:, axis] += step
            J[:, :, axis] = (_project_observations(state, shifted) - state.obs_xy - r) / step
        usable = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(J), axis=(1, 2))
        H = np.zeros((n, 3, 3))
        g = np.zeros((n, 3))
        np.add.at(H, state.obs_point[usable], np.einsum("nki,nkj->nij", J[usable], J[usable]))
        np.add.at(g, state.obs_point[usable], np.einsum("nki,nk->ni", J[usable], r[usable]))
        H += 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 1e-300 * np.eye(3)
        points = points - np.linalg.solve(H, g[:, :, None])[:, :, 0]
    r = _project_observations(state, points[state.obs_point]) - state.obs_xy
    rms = {}
    for index, name in enumerate(state.camera_names):
        mine = r[(state.obs_camera == index) & np.all(np.isfinite(r), axis=1)]
        if len(mine):
            rms[name] = float(np.sqrt(np.mean(np.sum(mine * mine, axis=1))))
    return rms
