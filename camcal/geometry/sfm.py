"""Cameras from image correspondences: pycolmap structure from motion -> Rig.

One folder of images gives one camera moving over frames; several folders,
one per camera of a rig with the same file name per frame, give a rig whose
cameras share one relative pose over all frames (pycolmap's rig support:
``RigConfig`` + ``apply_rig_config`` before mapping, so that the mapper's
bundle adjustment keeps ``sensor_from_rig`` common to every frame).

The result is a :class:`camcal.model.rig.Rig` whose ``frames`` hold each frame's
``rig_from_world`` and whose cameras hold ``cam_from_rig`` (the first folder
is the reference sensor, at the rig origin), plus a sibling PLY of the
sparse points. COLMAP's pixel centre (0.5) is converted at the boundary
(:mod:`camcal.io.colmap`).

After mapping, camcal's bundle adjustment (:mod:`camcal.geometry.bundle`)
refines the seed: intrinsics shared per camera, one rig pose for all frames,
optionally held at a known calibration (``known_rig``, e.g. from
``calibrate board``, which also gives the reconstruction its units), a robust
loss, and the uncertainty of the intrinsics and the rig pose.

pycolmap is imported only here (and in the bundle adjustment module).

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import (
    BundleOptions,
    BundleResult,
    BundleState,
    bundle_adjust,
    hold_rig,
    state_from_reconstruction,
    state_to_reconstruction,
)
from camcal.model.camera import from_colmap, pixels_from_colmap
from camcal.model.distortion import Distortion, fit_distortion
from camcal.geometry.jackknife import MAX_GROUPS, MIN_FRAMES, frame_jackknife
from camcal.io.colmap import camera_from_colmap, camera_to_colmap
from camcal.io.ply import write_points_ply
from camcal.model.rig import Camera, Frame, Rig, make_provenance

__all__ = [
    "HELDOUT_FRACTION",
    "IMAGE_SUFFIXES",
    "LENS_MODELS",
    "LENS_MODEL_MARGIN",
    "MIN_TRIANGULATION_ANGLE_DEG",
    "MODELS",
    "PRINCIPAL_POINT_MODES",
    "PrincipalPointDecision",
    "PycolmapPeer",
    "SelfCalibration",
    "SfmResult",
    "collect_images",
    "heldout_rms",
    "principal_point_limit_px",
    "self_calibrate",
    "solve_pycolmap_plain",
    "solve_sfm",
]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
MATCHERS = ("exhaustive", "sequential")
MAPPERS = ("incremental", "global")
#: camcal's distortion models and the COLMAP camera model that is exactly each of them.
MODELS = {"division": "SIMPLE_DIVISION", "polynomial": "RADIAL", "opencv": "OPENCV", "none": "SIMPLE_PINHOLE",
          "kannala-brandt": "OPENCV_FISHEYE"}
#: the lens models ``solve`` chooses among by held-out residual (``--model auto``), simplest first;
#: pinhole models only: ``kannala-brandt`` (a fisheye) is used when named, never chosen.
LENS_MODELS = ("division", "polynomial", "opencv")
PRINCIPAL_POINT_MODES = ("auto", "refine", "centre")
#: a lens model later in the list must lower the held-out RMS by more than this fraction to be chosen
#: (held-out RMS of division and 2-term polynomial lenses differ by ~0.1 % where both fit).
LENS_MODEL_MARGIN = 0.01
#: fraction of the sparse points (whole tracks) held out of the fit to choose the lens model.
HELDOUT_FRACTION = 0.2
#: points triangulated under a smaller angle are dropped before the refinement (COLMAP's mapper default).
MIN_TRIANGULATION_ANGLE_DEG = 1.5


@dataclass(frozen=True)
class SfmResult:
    """What structure from motion recovered.

    Attributes
    ----------
    rig : Rig
        Cameras (cam_from_rig), per-frame rig poses, points file name.
    n_images, n_registered : int
        Images given, images with a pose.
    unregistered : tuple of str
        Images without a pose (``camera/file``).
    n_points : int
        Sparse 3D points.
    rms_px : float
        RMS reprojection error of every observation through the camcal rig
        (distortion included), in pixels.
    per_camera_rms_px : dict
        The same per camera.
    reconstruction_dir : Path
        The COLMAP model (binary), for other tools.
    bundle : BundleResult or None
        camcal's refinement of the pycolmap seed (costs, RMS before/after,
        sigmas), None when not refined.
    self_calibration : SelfCalibration or None
        The lens models chosen (held-out RMS of each) and the principal point
        decisions, None when not refined or with one fixed COLMAP model.
    """

    rig: Rig
    n_images: int
    n_registered: int
    unregistered: tuple[str, ...]
    n_points: int
    rms_px: float
    per_camera_rms_px: dict[str, float]
    reconstruction_dir: Path
    bundle: BundleResult | None = None
    self_calibration: SelfCalibration | None = None


@dataclass(frozen=True)
class PrincipalPointDecision:
    """Whether a camera's principal point was refined, and why.

    Attributes
    ----------
    camera : str
    refined : bool
        True: refined with the rest; False: held at the image centre.
    sigma_px : (float, float)
        One-sigma of (cx, cy) from the fit with the principal point free
        (points marginalised); NaN when that fit was not run (``centre``).
    limit_px : float
        The largest sigma at which the data count as determining it.
    reason : str
        The decision in words, with its numbers.
    """

    camera: str
    refined: bool
    sigma_px: tuple[float, float]
    limit_px: float
    reason: str


@dataclass(frozen=True)
class SelfCalibration:
    """What :func:`self_calibrate` decided and measured.

    Attributes
    ----------
    lens_models : dict of str to str
        Camera -> the camcal lens model chosen (``division``, ``polynomial``...).
    heldout_rms_px : dict of str to dict of str to float
        Camera -> lens model -> RMS reprojection error of the held-out points
        (tracks left out of that model's fit, triangulated afterwards with
        its cameras held), in pixels.
    n_heldout_points : int
        Sparse points held out.
    principal_point : tuple of PrincipalPointDecision
    covariance_sigmas, jackknife_sigmas : dict of str to float
        The final fit's sigmas from the Ceres covariance and from the
        delete-one-frame jackknife, widened for its ``n - 1`` degrees of
        freedom (:attr:`camcal.geometry.jackknife.FrameJackknife.widened_sigmas`;
        empty when it was not run); the fit reports the larger of the two.
    jackknife_groups : int
        Frames (or groups of frames) left out in turn; 0 when not run.
    jackknife_skipped : str
        Why the jackknife was not run ("" when it was).
    """

    lens_models: dict[str, str]
    heldout_rms_px: dict[str, dict[str, float]]
    n_heldout_points: int
    principal_point: tuple[PrincipalPointDecision, ...]
    covariance_sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    jackknife_sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    jackknife_groups: int = 0
    jackknife_skipped: str = ""

    def lines(self) -> list[str]:
        """The decisions, one line per camera and question, for the user."""
        rows = []
        for camera, model in self.lens_models.items():
            table = ", ".join(f"{name} {value:.4f}" for name, value in self.heldout_rms_px[camera].items())
            rows.append(f"{camera}: lens model {model} (held-out RMS px over {self.n_heldout_points} points: {table})")
        rows += [f"{decision.camera}: {decision.reason}" for decision in self.principal_point]
        if self.jackknife_groups:
            ratios = ", ".join(f"{key} {self.jackknife_sigmas[key] / value:.2g}" for key, value in
                               self.covariance_sigmas.items() if key in self.jackknife_sigmas and value > 0)
            rows.append(f"uncertainty: the larger of the covariance sigma and a delete-one-frame jackknife over "
                        f"{self.jackknife_groups} groups of frames, widened for its {self.jackknife_groups - 1} "
                        f"degrees of freedom (jackknife / covariance: {ratios})")
        else:
            rows.append(f"uncertainty: covariance sigmas only ({self.jackknife_skipped}); "
                        "they measure independent noise, not errors shared by an image's features")
        return rows


def principal_point_limit_px(image_size: tuple[int, int]) -> float:
    """Sigma below which the views determine a principal point: 0.2 % of the diagonal, at least 1 px.

    Holding the principal point at the image centre costs its true offset
    (commonly 0.2-1 % of the diagonal); refining it costs its sigma. Refining
    wins when the sigma is smaller than the offsets lenses commonly have.
    """
    return max(1.0, 0.002 * float(np.hypot(*image_size)))


def _lens_params(state: BundleState, camera: int, model: str) -> NDArray[np.float64]:
    """Camera ``camera``'s COLMAP parameters in the COLMAP twin of camcal ``model``.

    The focal length and principal point carry over; the distortion is
    :func:`camcal.model.distortion.fit_distortion` of the current one
    over the frame (a non-square focal becomes the mean focal first).
    """
    if state.models[camera] == MODELS[model]:
        return state.params[camera].copy()
    name, size = state.camera_names[camera], state.image_sizes[camera]
    lens = camera_from_colmap(name, state.models[camera], size, state.params[camera], np.eye(3), np.zeros(3))
    K = lens.K.copy()
    K[0, 0] = K[1, 1] = 0.5 * (K[0, 0] + K[1, 1])
    K[0, 1] = 0.0
    if model == "none":
        distortion = Distortion.none()
    else:
        distortion = fit_distortion(lens.distortion, K, size, model).distortion
        if model == "opencv":
            distortion = Distortion("opencv", {**distortion.params, "k3": 0.0})
    colmap = camera_to_colmap(dataclasses.replace(lens, K=K, distortion=distortion))
    if colmap.model != MODELS[model]:
        raise CamcalError(f"camera {name!r}: {model} converted to COLMAP {colmap.model}, expected {MODELS[model]}")
    return np.array(colmap.params, dtype=np.float64)


def _with_lenses(state: BundleState, lenses: dict[str, str]) -> BundleState:
    """The state with each camera's lens model replaced (``camera name -> camcal model``)."""
    params = tuple(_lens_params(state, k, lenses[name]) for k, name in enumerate(state.camera_names))
    return dataclasses.replace(state, models=tuple(MODELS[lenses[name]] for name in state.camera_names), params=params)


def _centred(state: BundleState, camera: int) -> NDArray[np.float64]:
    """Camera ``camera``'s parameters with the principal point at the image centre (COLMAP: w/2, h/2)."""
    params = state.params[camera].copy()
    names = state.param_names(camera)
    width, height = state.image_sizes[camera]
    params[names.index("cx")], params[names.index("cy")] = width / 2.0, height / 2.0
    return params


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


def self_calibrate(
    state: BundleState,
    options: BundleOptions,
    lens_models: tuple[str, ...] = LENS_MODELS,
    principal_point: str = "auto",
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    jackknife: bool = True,
) -> tuple[BundleResult, SelfCalibration]:
    """Bundle adjustment that chooses each camera's lens model and whether to refine its principal point.

    Parameters
    ----------
    state : BundleState
        The seed (structure from motion), e.g. from
        :func:`camcal.geometry.bundle.state_from_reconstruction`.
    options : BundleOptions
        Loss, rig handling...; ``refine_principal_point`` is decided here.
    lens_models : tuple of str
        camcal lens models to choose among (:data:`LENS_MODELS`); one model
        is used as given (its held-out RMS is still measured).
    principal_point : {"auto", "refine", "centre"}
        ``auto`` refines each camera's where its sigma(cx), sigma(cy) are below
        :func:`principal_point_limit_px`, and holds the others at the image centre.
    seed : int
        Chooses the held-out points.
    progress : callable, optional
        Called with each stage's message (the CLI prints them to stderr).
    jackknife : bool
        Also estimate the sigmas by the delete-one-frame jackknife
        (:func:`camcal.geometry.jackknife.frame_jackknife`, one refinement
        per frame or group of frames) and report the larger of the two.

    Returns
    -------
    BundleResult
        The final refinement on every point (sigmas of the free intrinsics
        and of the rig pose, points marginalised; the larger of covariance
        and jackknife).
    SelfCalibration
        The lens models chosen with the held-out RMS of each candidate,
        and the principal point decisions with their sigmas.

    Notes
    -----
    Lens model: :data:`HELDOUT_FRACTION` of the points (whole tracks) are
    left out; each candidate model is fitted, with the principal point free,
    on the rest; the held-out points are re-triangulated through each fit
    (:func:`heldout_rms`) and each camera takes the model with the lowest
    held-out RMS (a model later in ``lens_models``, simplest first, must beat
    an earlier one by more than :data:`LENS_MODEL_MARGIN`). Principal point:
    the final fit runs with it free; its covariance (Ceres, ``sigma^2
    (J^T J)^-1``, Triggs et al. 2000, section 6) gives sigma(cx), sigma(cy); when
    they exceed the limit the fit is run again with that camera's held at the
    centre (``BundleOptions.fixed_params``). Uncertainty: features located
    in images share errors within an image (viewing angle, blur, sampling),
    which the covariance, built for independent noise, does not see; on
    rendered rigs its sigmas were 2-5 times below the error. The jackknife
    over frames sees them (widened by Tukey's t factor for its ``n - 1``
    degrees of freedom); the larger of the two is reported.
    """
    if principal_point not in PRINCIPAL_POINT_MODES:
        raise CamcalError(f"unknown principal point mode {principal_point!r}, "
                          f"expected one of: {', '.join(PRINCIPAL_POINT_MODES)}")
    if not lens_models:
        raise CamcalError("need at least one lens model to choose from")
    unknown = [model for model in lens_models if model not in MODELS]
    if unknown:
        raise CamcalError(f"unknown lens model {unknown[0]!r}, expected one of: {', '.join(MODELS)}")
    names = state.camera_names
    held_mask = np.random.default_rng(seed).random(len(state.points)) < HELDOUT_FRACTION
    train, heldout = state.subset(~held_mask), state.subset(held_mask)
    free_pp = dataclasses.replace(options, refine_principal_point=principal_point != "centre")
    table: dict[str, dict[str, float]] = {name: {} for name in names}
    for model in lens_models:
        _say(progress, f"lens model {model}: fitting {len(train.points)} points, {len(heldout.points)} held out")
        fit = bundle_adjust(_with_lenses(train, dict.fromkeys(names, model)),
                            dataclasses.replace(free_pp, compute_sigmas=False))
        for name, value in heldout_rms(fit.state, heldout).items():
            table[name][model] = value
    chosen = {}
    for name in names:
        best = lens_models[0]
        for model in lens_models[1:]:
            if table[name].get(model, np.inf) < table[name].get(best, np.inf) * (1.0 - LENS_MODEL_MARGIN):
                best = model
        chosen[name] = best
    _say(progress, "bundle adjustment with the chosen lens models")
    final_options = free_pp
    final = bundle_adjust(_with_lenses(state, chosen), final_options)
    decisions = []
    if principal_point == "centre":
        decisions = [PrincipalPointDecision(name, False, (np.nan, np.nan), principal_point_limit_px(size),
                                            "principal point held at the image centre (asked)")
                     for name, size in zip(names, state.image_sizes)]
    else:
        for name, size in zip(names, state.image_sizes):
            sigma = (final.sigmas.get(f"{name}.cx", np.inf), final.sigmas.get(f"{name}.cy", np.inf))
            limit = principal_point_limit_px(size)
            numbers = (f"sigma(cx, cy) = ({sigma[0]:.3g}, {sigma[1]:.3g}) px" if np.all(np.isfinite(sigma))
                       else "sigma(cx, cy) undefined (singular covariance)")
            if principal_point == "refine":
                decision = PrincipalPointDecision(name, True, sigma, limit, f"principal point refined (asked; {numbers})")
            elif max(sigma) < limit:
                decision = PrincipalPointDecision(name, True, sigma, limit,
                                                  f"principal point refined: {numbers} < {limit:.3g} px")
            else:
                bound = f" >= {limit:.3g} px" if np.all(np.isfinite(sigma)) else ""
                decision = PrincipalPointDecision(
                    name, False, sigma, limit, f"principal point held at the image centre: {numbers}{bound}, "
                    "the views do not determine it (add rotation and roll about the viewing axis)")
            decisions.append(decision)
        held = [k for k, decision in enumerate(decisions) if not decision.refined]
        if held:
            _say(progress, "bundle adjustment with the undetermined principal points at the image centre")
            params = tuple(_centred(final.state, k) if k in held else final.state.params[k] for k in range(len(names)))
            fixed = {names[k]: ("cx", "cy") for k in held}
            final_options = dataclasses.replace(free_pp, fixed_params=fixed)
            final = bundle_adjust(dataclasses.replace(final.state, params=params), final_options)
    covariance_sigmas, jackknife_sigmas, groups = dict(final.sigmas), {}, 0
    n_frames = len(np.unique(final.state.obs_frame))
    skipped = ("asked" if not jackknife else
               f"the jackknife needs {MIN_FRAMES} frames, got {n_frames}" if n_frames < MIN_FRAMES else "")
    if not skipped:
        _say(progress, f"uncertainty: delete-one-frame jackknife ({min(n_frames, MAX_GROUPS)} refinements)")
        spread = frame_jackknife(final, final_options)
        jackknife_sigmas, groups = spread.widened_sigmas, spread.n_groups
        # a singular covariance leaves keys only the jackknife has
        final = dataclasses.replace(final, sigmas={key: max(covariance_sigmas.get(key, 0.0), jackknife_sigmas.get(key, 0.0))
                                                   for key in {**covariance_sigmas, **jackknife_sigmas}})
    report = SelfCalibration(
        lens_models=chosen, heldout_rms_px=table, n_heldout_points=int(held_mask.sum()),
        principal_point=tuple(decisions), covariance_sigmas=covariance_sigmas, jackknife_sigmas=jackknife_sigmas,
        jackknife_groups=groups, jackknife_skipped=skipped,
    )
    return final, report


def _list_images(folder: Path, pattern: str = "*") -> list[Path]:
    if not folder.is_dir():
        raise CamcalError(f"image folder not found: {folder}")
    images = sorted(p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise CamcalError(f"no images ({', '.join(IMAGE_SUFFIXES)}) matching {pattern!r} in {folder}")
    return images


def collect_images(folders: list[Path], camera_globs: dict[str, str] | None = None) -> dict[str, list[Path]]:
    """Images per camera: one folder per camera (named after it), or globs in one folder.

    Parameters
    ----------
    folders : list of Path
        Image folders. Without ``camera_globs`` each is one camera; a single
        folder holding only sub-folders of images is a rig, one camera per
        sub-folder.
    camera_globs : dict of str to str, optional
        Camera name -> glob relative to the (single) folder, e.g.
        ``{"left": "*_L.png", "right": "*_R.png"}``; frames pair up by sorted order.
    """
    folders = [Path(folder) for folder in folders]
    if camera_globs:
        if len(folders) != 1:
            raise CamcalError("--camera NAME=GLOB selects images inside one folder: give exactly one")
        return {name: _list_images(folders[0], pattern) for name, pattern in camera_globs.items()}
    if len(folders) == 1 and folders[0].is_dir():
        subfolders = sorted(p for p in folders[0].iterdir() if p.is_dir())
        if subfolders and not any(p.suffix.lower() in IMAGE_SUFFIXES for p in folders[0].iterdir() if p.is_file()):
            folders = subfolders
    names = [folder.name for folder in folders]
    if len(set(names)) != len(names):
        raise CamcalError("image folders must have distinct names (they name the cameras)")
    return {folder.name: _list_images(folder) for folder in folders}


def _stage_images(images: dict[str, list[Path]], staging: Path) -> dict[str, Path]:
    """Link each camera's images under ``staging/<camera>/`` (COLMAP's rig layout).

    Frames pair up by position in each camera's sorted list: the k-th image
    of every camera is linked under the same name ``<k>.<suffix>``.

    Returns
    -------
    dict
        Staged name (``camera/<k>.<suffix>``, COLMAP's image name) -> the user's image.
    """
    if staging.exists():
        shutil.rmtree(staging)
    staged: dict[str, Path] = {}
    for camera, paths in images.items():
        (staging / camera).mkdir(parents=True)
        for index, path in enumerate(paths):
            name = f"{index:06d}{path.suffix.lower()}"
            os.symlink(path.resolve(), staging / camera / name)
            staged[f"{camera}/{name}"] = path
    return staged


def solve_sfm(
    folders: dict[str, Path | list[Path]],
    out_dir: Path,
    camera_model: str = "SIMPLE_RADIAL",
    matcher: str = "exhaustive",
    mapper: str = "incremental",
    seed: int = 0,
    num_threads: int = -1,
    refine: bool = True,
    known_rig: Rig | None = None,
    loss: str = "trivial",
    lens_models: tuple[str, ...] | None = LENS_MODELS,
    principal_point: str = "auto",
    max_num_features: int = 8192,
    progress: Callable[[str], None] | None = None,
    jackknife: bool = True,
) -> SfmResult:
    """Run pycolmap SfM, refine it with camcal's bundle adjustment, convert it to a Rig.

    Parameters
    ----------
    folders : dict of str to Path or list of Path
        Camera name -> its image folder (or its images, see
        :func:`collect_images`). With several cameras, frames pair up by the
        sorted order of each camera's images; the first camera is the rig's
        reference.
    out_dir : Path
        Receives ``database.db``, ``images/`` (links), ``sparse/`` (the COLMAP
        model), ``solve.rig.json`` and ``points.ply``.
    camera_model : str
        COLMAP model for every camera: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL,
        RADIAL, OPENCV, SIMPLE_DIVISION... (one with a camcal counterpart).
    matcher : {"exhaustive", "sequential"}
        Exhaustive for unordered sets under ~50 images; sequential for video.
    mapper : {"incremental", "global"}
    seed : int
        The mapper's random seed (repeatable runs).
    num_threads : int
        -1 uses every core.
    refine : bool
        Run camcal's bundle adjustment after pycolmap's mapping.
    known_rig : Rig, optional
        A calibrated rig with the same camera names (``calibrate board``):
        the cameras' relative poses are held at it and the reconstruction
        takes its units.
    loss : {"trivial", "huber", "soft_l1", "cauchy"}
        Robust loss of the refinement (scale 1 px).
    lens_models : tuple of str or None
        camcal lens models each camera chooses among by held-out residual
        (:func:`self_calibrate`); one model is used as given; None keeps
        ``camera_model``.
    principal_point : {"auto", "refine", "centre"}
        Refine the principal point where its sigma says the views determine
        it (``auto``), always, or never (COLMAP's default).
    max_num_features : int
        SIFT features per image (pycolmap's ``max_num_features``).
    progress : callable, optional
        Called with each stage's message (the CLI prints them to stderr).
    jackknife : bool
        Sigmas also by the delete-one-frame jackknife (:func:`self_calibrate`).

    Returns
    -------
    SfmResult
    """
    import pycolmap  # noqa: PLC0415 - optional heavy dependency, only here

    if not folders:
        raise CamcalError("need at least one image folder")
    if matcher not in MATCHERS:
        raise CamcalError(f"unknown matcher {matcher!r}, expected one of: {', '.join(MATCHERS)}")
    if mapper not in MAPPERS:
        raise CamcalError(f"unknown mapper {mapper!r}, expected one of: {', '.join(MAPPERS)}")
    if not hasattr(pycolmap.CameraModelId, camera_model):
        raise CamcalError(f"unknown COLMAP camera model {camera_model!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    image_dir = out_dir / "images"
    images = {name: _list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    if known_rig is not None:
        missing = [name for name in images if name not in {camera.name for camera in known_rig.cameras}]
        if missing:
            raise CamcalError(f"the known rig has no camera named {', '.join(map(repr, missing))}")
    options = BundleOptions(loss=loss, refine_sensor_from_rig=known_rig is None)
    staged = _stage_images(images, image_dir)
    image_names = list(staged)
    if len(image_names) < 2:
        raise CamcalError(f"need at least 2 images, got {len(image_names)}")
    database = out_dir / "database.db"
    database.unlink(missing_ok=True)

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.sift.max_num_features = max_num_features
    _say(progress, f"extracting features from {len(image_names)} images")
    pycolmap.extract_features(
        database, image_dir, image_names=image_names, camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    _say(progress, f"matching ({matcher})")
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    # matches re-searched along the verified epipolar geometry: more, longer tracks
    matching.guided_matching = True
    match = pycolmap.match_exhaustive if matcher == "exhaustive" else pycolmap.match_sequential
    match(database, matching_options=matching, device=pycolmap.Device.cpu)
    sparse = out_dir / "sparse"
    if sparse.exists():
        shutil.rmtree(sparse)
    sparse.mkdir()
    _say(progress, f"mapping ({mapper})")
    models = _map(pycolmap, database, image_dir, sparse, mapper, seed, num_threads)
    if len(folders) > 1 and models:
        # COLMAP needs sensor_from_rig to start a rig-constrained mapping: take it
        # from an unconstrained first pass, then map again with the rig.
        rig_config = pycolmap.RigConfig(
            cameras=[
                pycolmap.RigConfigCamera(ref_sensor=index == 0, image_prefix=f"{name}/")
                for index, name in enumerate(folders)
            ]
        )
        first_pass = max(models.values(), key=lambda r: r.num_reg_images())
        db = pycolmap.Database.open(database)
        try:
            pycolmap.apply_rig_config([rig_config], db, first_pass)
        finally:
            db.close()
        shutil.rmtree(sparse)
        sparse.mkdir()
        _say(progress, f"mapping ({mapper}) with the rig constraint")
        models = _map(pycolmap, database, image_dir, sparse, mapper, seed, num_threads)
    if not models:
        raise CamcalError("structure from motion registered no images: too little texture or overlap?")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    bundle = calibration = None
    if refine:
        _say(progress, "bundle adjustment (camcal)")
        names = {camera_id: _camera_name(reconstruction, camera_id) for camera_id in reconstruction.cameras}
        state = state_from_reconstruction(reconstruction, names)
        if known_rig is not None:
            state = hold_rig(state, _relative_poses(known_rig, state.camera_names[0]))
        if lens_models is None:
            pp_options = dataclasses.replace(options, refine_principal_point=principal_point == "refine")
            bundle = bundle_adjust(state, pp_options)
        else:
            # the mapper's principal point is the image centre: free it once, then drop the matches
            # that no camera model explains (mismatches, features astride an occluding edge)
            _say(progress, "bundle adjustment (camcal) with the principal point free, then outlier rejection")
            pre = bundle_adjust(state, dataclasses.replace(options, refine_principal_point=principal_point != "centre"))
            state_to_reconstruction(pre.state, reconstruction)
            _say(progress, _reject_outliers(pycolmap, reconstruction))
            state = state_from_reconstruction(reconstruction, names)
            bundle, calibration = self_calibrate(state, options, tuple(lens_models), principal_point, seed, progress,
                                                 jackknife)
            for line in calibration.lines():
                _say(progress, line)
        camera_ids = {name: camera_id for camera_id, name in names.items()}
        for name, model in zip(bundle.state.camera_names, bundle.state.models):
            reconstruction.cameras[camera_ids[name]].model = getattr(pycolmap.CameraModelId, model)
        state_to_reconstruction(bundle.state, reconstruction)
    model_dir = sparse / "best"
    model_dir.mkdir(exist_ok=True)
    reconstruction.write(model_dir)
    originals = {name: Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()
                 for name, path in staged.items()}
    units = known_rig.units if known_rig is not None else "arbitrary"
    return _to_result(reconstruction, list(folders), out_dir, model_dir, originals, units, bundle, calibration)


@dataclass(frozen=True)
class PycolmapPeer:
    """Plain pycolmap's self-calibration of the same images, for comparison.

    Attributes
    ----------
    cameras : dict of str to Camera
        Camera name -> its intrinsics and lens (pose: identity).
    rms_px : dict of str to float
        Camera name -> RMS reprojection error (pycolmap's own residuals).
    right_from_left : dict of str to list of ndarray
        Camera name -> ``cam_from_reference`` rotation of every frame in which
        both it and the reference camera (the first) are registered: plain
        pycolmap has no rig constraint, so each frame has its own.
    n_registered : int
    """

    cameras: dict[str, Camera]
    rms_px: dict[str, float]
    right_from_left: dict[str, list[NDArray[np.float64]]]
    n_registered: int


def solve_pycolmap_plain(folders: dict[str, Path | list[Path]], out_dir: Path, camera_model: str = "SIMPLE_DIVISION",
                         seed: int = 0) -> PycolmapPeer:
    """The plain pycolmap pipeline a user would script, on the same images as :func:`solve_sfm`.

    Default SIFT extraction with one camera per folder (``camera_model``),
    exhaustive matching, incremental mapping, then
    ``pycolmap.bundle_adjustment`` with ``refine_principal_point``. No rig
    constraint. Writes only under ``out_dir``.
    """
    import pycolmap  # noqa: PLC0415

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    images = {name: _list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    staged = _stage_images(images, out_dir / "images")
    database = out_dir / "database.db"
    database.unlink(missing_ok=True)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    pycolmap.extract_features(database, out_dir / "images", image_names=list(staged),
                              camera_mode=pycolmap.CameraMode.PER_FOLDER, reader_options=reader,
                              device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    sparse = out_dir / "sparse"
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir()
    models = _map(pycolmap, database, out_dir / "images", sparse, "incremental", seed, -1)
    if not models:
        raise CamcalError("plain pycolmap registered no images")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_principal_point = True
    pycolmap.bundle_adjustment(reconstruction, options)
    cameras, squared, rotations = {}, {}, {}
    for camera_id, camera in reconstruction.cameras.items():
        name = _camera_name(reconstruction, camera_id)
        cameras[name] = camera_from_colmap(name, camera.model.name, (camera.width, camera.height), camera.params,
                                           np.eye(3), np.zeros(3))
    reference = next(iter(folders))
    by_frame: dict[str, dict[str, NDArray[np.float64]]] = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        name, file = image.name.split("/", 1)
        by_frame.setdefault(file, {})[name] = image.cam_from_world().rotation.matrix()
        for point in image.points2D:
            if point.has_point3D():
                projected = image.project_point(reconstruction.points3D[point.point3D_id].xyz)
                if projected is not None:
                    squared.setdefault(name, []).append(float(np.sum((point.xy - projected) ** 2)))
    for poses in by_frame.values():
        for name, R in poses.items():
            if name != reference and reference in poses:
                rotations.setdefault(name, []).append(R @ poses[reference].T)
    return PycolmapPeer(cameras, {name: float(np.sqrt(np.mean(v))) for name, v in squared.items()}, rotations,
                        reconstruction.num_reg_images())


def _reject_outliers(pycolmap, reconstruction, n_sigma: float = 4.0) -> str:
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
    errors = []
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        for point in image.get_observation_points2D():
            projected = image.project_point(reconstruction.points3D[point.point3D_id].xyz)
            errors.append(np.inf if projected is None else float(np.linalg.norm(point.xy - projected)))
    if not errors:
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


def _relative_poses(rig: Rig, reference: str) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Each camera's ``cam_from_reference`` (R, t) in a calibrated rig (X_cam = R X_ref + t)."""
    names = {camera.name for camera in rig.cameras}
    if reference not in names:
        raise CamcalError(f"the known rig has no camera named {reference!r}")
    ref = rig.camera(reference)
    return {camera.name: (camera.R @ ref.R.T, camera.R @ (ref.c - camera.c)) for camera in rig.cameras}


def _map(pycolmap, database: Path, image_dir: Path, sparse: Path, mapper: str, seed: int, num_threads: int) -> dict:
    if mapper == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = seed
        options.num_threads = num_threads
        return pycolmap.incremental_mapping(database, image_dir, sparse, options=options)
    return pycolmap.global_mapping(database, image_dir, sparse)


def _to_result(reconstruction, camera_names: list[str], out_dir: Path, model_dir: Path,
               originals: dict[str, str], units: str, bundle: BundleResult | None,
               calibration: SelfCalibration | None) -> SfmResult:
    """Convert a pycolmap reconstruction with one rig into camcal's Rig.

    ``originals`` maps every staged image name (COLMAP's) to the user's
    image, relative to ``out_dir``: the frames point at those.
    """
    if reconstruction.num_rigs() != 1:
        raise CamcalError(f"expected one rig in the reconstruction, got {reconstruction.num_rigs()}")
    rig = next(iter(reconstruction.rigs.values()))
    cameras = []
    camera_of_sensor: dict[int, str] = {}
    for camera_id, colmap_camera in reconstruction.cameras.items():
        name = _camera_name(reconstruction, camera_id)
        if rig.is_ref_sensor(_sensor(camera_id)):
            R, c = np.eye(3), np.zeros(3)
        else:
            sensor_from_rig = rig.sensor_from_rig(_sensor(camera_id))
            R, c = from_colmap(sensor_from_rig.rotation.quat, sensor_from_rig.translation)
        cameras.append(
            camera_from_colmap(name, colmap_camera.model.name, (colmap_camera.width, colmap_camera.height),
                               colmap_camera.params, R, c)
        )
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
        frames.append(Frame(frame_index, R, c, images))
    points_path = out_dir / "points.ply"
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()]).reshape(-1, 3)
    colours = np.array([p.color for p in reconstruction.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in reconstruction.points3D.values()], dtype=np.int32)
    write_points_ply(points_path, xyz, colours, tracks)
    result_rig = Rig(
        tuple(cameras), units=units, frames=tuple(frames), points=points_path.name,
        provenance=make_provenance("sfm (pycolmap)" + (" + camcal bundle adjustment" if bundle else ""),
                                   images=len(originals),
                                   **({"self_calibration": calibration.lines()} if calibration else {})),
    )
    per_camera, rms = _reprojection_rms(reconstruction, result_rig, camera_of_sensor, frame_of_image)
    result_rig = _with_quality(result_rig, per_camera, bundle, calibration)
    result_rig.save(out_dir / "solve.rig.json")
    return SfmResult(
        rig=result_rig,
        n_images=len(originals),
        n_registered=len(frame_of_image),
        unregistered=tuple(sorted(set(originals) - set(frame_of_image))),
        n_points=len(xyz),
        rms_px=rms,
        per_camera_rms_px={name: value for name, (value, _) in per_camera.items()},
        reconstruction_dir=model_dir,
        bundle=bundle,
        self_calibration=calibration,
    )


def _sensor(camera_id: int):
    """The pycolmap sensor id of a camera."""
    import pycolmap  # noqa: PLC0415

    return pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_id)


def _camera_name(reconstruction, camera_id: int) -> str:
    """The camera's folder name, from the name of one of its images."""
    for image in reconstruction.images.values():
        if image.camera_id == camera_id:
            return image.name.split("/", 1)[0]
    raise CamcalError(f"COLMAP camera {camera_id} has no registered image")


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
    COLMAP's division ``k`` becomes camcal's ``lambda = k / f^2`` (focal's own spread neglected),
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
        if bundle is not None:
            quality["rms_seed_px"] = bundle.rms_before_px[camera.name]
            index = bundle.state.camera_names.index(camera.name)
            quality["sigma"] = _quality_sigma(bundle.sigmas, camera.name, bundle.state.models[index],
                                              float(bundle.state.params[index][0]))
        cameras.append(dataclasses.replace(camera, quality=quality))
    return dataclasses.replace(rig, cameras=tuple(cameras))


def _say(progress: Callable[[str], None] | None, message: str) -> None:
    """Hand a stage message to the caller's progress callback, if any."""
    if progress is not None:
        progress(message)
