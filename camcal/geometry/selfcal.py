"""Self-calibration on a structure-from-motion seed: each camera's lens model and principal point chosen.

The lens model is chosen by the residual of points held out of the fit
(:func:`heldout_rms`), the principal point and the lens refined under the
sensor's Gaussian priors (:mod:`camcal.geometry.bundle.prior`: the principal
point about the image centre, never held there), and the sigmas are the
larger of the posterior covariance's and a delete-one-frame jackknife's
(:func:`self_calibrate`). Intrinsics are COLMAP parameter vectors of the
COLMAP twin of each camcal lens model (:data:`MODELS`,
:mod:`camcal.model.colmap`), each with two focal lengths: the aspect ``fx / fy``
is refined under a Gaussian prior (square pixels, ``fx - fy`` +-
:data:`~camcal.geometry.bundle.prior.ASPECT_PRIOR` of ``f``), not held at 1
(Strecha's real cameras: fx and fy 0.17 % apart), unless the motion does
not determine it: where a change of ``fx - fy`` by the prior's sigma moves
the images by less than a feature error shared by every image
(:func:`aspect_visibility`, :data:`FEATURE_BIAS_PX`; Sturm 1997's critical
motions: turning about one axis, or hardly at all), such an error could
move it further than the prior allows, so square pixels are held and the
prior's spread of fx - fy is carried to every parameter that trades against
it. Skew is 0: no COLMAP
camera model has it, and the pixel rows and columns of digital sensors are
orthogonal (said in :meth:`SelfCalibration.lines`).

References
----------
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, BundleResult, BundleState, bundle_adjust
from camcal.geometry.bundle.influences import FrameInfluences
from camcal.geometry.bundle.prior import (ASPECT_PRIOR, PRINCIPAL_POINT_PRIOR, UNDETERMINED_RATIO, PriorSpec,
                                         mean_focal, undetermined)
from camcal.geometry.jackknife import MAX_GROUPS, METHODS, MIN_FRAMES, frame_jackknife, without_frames
from camcal.geometry.selfcal_aspect import (ASPECT_HELD, FEATURE_BIAS_PX, SQUARE_PIXELS_HELD, aspect_visibility,
                                            spread_with_aspect_free)
from camcal.geometry.selfcal_models import (FIXED_PARAMS, LENS_MODELS, MAPPING_MODELS, MODELS, as_lens_model,
                                            heldout_rms, with_fixed_params, with_lenses)

__all__ = [
    "ASPECT_HELD",
    "FEATURE_BIAS_PX",
    "FEW_JACKKNIFE_GROUPS",
    "FIXED_PARAMS",
    "FOCAL_UNDETERMINED",
    "HELDOUT_FRACTION",
    "LENS_CHOICE_FRAMES",
    "LENS_CHOICE_TOLERANCE",
    "LENS_MODELS",
    "LENS_MODEL_MARGIN",
    "MAPPING_MODELS",
    "MODELS",
    "PRINCIPAL_POINT_MODES",
    "PrincipalPointDecision",
    "SelfCalibration",
    "as_lens_model",
    "aspect_visibility",
    "heldout_rms",
    "self_calibrate",
]

PRINCIPAL_POINT_MODES = ("auto", "refine", "centre")
#: a lens model later in the list must lower the held-out RMS by more than this fraction to be chosen
#: (held-out RMS of division and 2-term polynomial lenses differ by ~0.1 % where both fit).
LENS_MODEL_MARGIN = 0.01
#: fraction of the sparse points (whole tracks) held out of the fit to choose the lens model.
HELDOUT_FRACTION = 0.2
#: a longer plate chooses its lens model on this many of its frames, spread evenly over it (the final fit is on
#: every frame): neighbouring frames of a plate see the same points from nearly the same place, so the held-out
#: residual of a lens model is decided by the field of view the points cover, not by the frame count, and each
#: candidate's bundle adjustment on every frame of a long plate costs as much as the final one.
LENS_CHOICE_FRAMES = 40
#: Ceres' function tolerance of each lens candidate's fit: the choice compares held-out RMS values a
#: :data:`LENS_MODEL_MARGIN` apart, and the final fit starts from the structure from motion, not from the candidate.
#: A rendered 240-frame loop: 8-9 iterations per candidate instead of 21-27 (the tail lowers the cost by 2e-8 of
#: itself), the held-out RMS the same to 4e-7 of itself.
LENS_CHOICE_TOLERANCE = 1e-6
#: relative sigma of a focal length above which the report says that the images barely determine it: no
#: better than a lens's marked focal length (ISO 517 allows the marking +-5 % of the measured focal length).
FOCAL_UNDETERMINED = 0.05
#: fewest frames for which the delete-one-frame jackknife is a fair copy of the problem: with fewer, deleting one
#: frame leaves a weaker problem (a chain of frames cut), and the sigma it widens errs wide. Rendered orbits
#: (tests/pipelines/test_solve_coverage.py): 6-12 frames put 92.8-97.7 % of pixel errors within 2 sigma at a
#: median error / sigma of 0.32-0.41, the jackknife's design effect 15-212 on stereo orbits of 5-7 frames;
#: 18-24 frames put 91.3-97.1 % within 2 sigma at 0.61-0.78, design effect 1.0-4.6.
FEW_JACKKNIFE_GROUPS = 12


@dataclass(frozen=True)
class PrincipalPointDecision:
    """Whether a camera's principal point was refined, and why.

    Attributes
    ----------
    camera : str
    refined : bool
        True: refined with the rest; False: held at the image centre (asked).
    sigma_px : (float, float)
        Posterior one-sigma of (cx, cy) (points marginalised, the prior's
        information included); NaN when held or the covariance is singular.
    prior_sigma_px : float
        The prior's sigma about the image centre; NaN without a prior.
    determined : bool
        Whether the images determine it: the posterior sigma below
        :data:`~camcal.geometry.bundle.prior.UNDETERMINED_RATIO` of the prior's.
    reason : str
        The decision in words, with its numbers.
    """

    camera: str
    refined: bool
    sigma_px: tuple[float, float]
    prior_sigma_px: float
    determined: bool
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
    undetermined : tuple of str
        One line per intrinsic that the images barely determine (posterior
        sigma near its prior's: :func:`camcal.geometry.bundle.prior.undetermined`;
        a focal length without a prior: its sigma above :data:`FOCAL_UNDETERMINED`
        of its value, or undefined).
    unused_priors : tuple of str
        Given priors on an intrinsic the chosen lens model does not have.
    covariance_sigmas, jackknife_sigmas : dict of str to float
        The final fit's sigmas from the Ceres covariance and from the
        delete-one-frame jackknife, widened for its ``n - 1`` degrees of
        freedom (:attr:`camcal.geometry.jackknife.FrameJackknife.widened_sigmas`;
        empty when it was not run); the fit reports the larger of the two.
    jackknife_groups : int
        Frames (or groups of frames) left out in turn; 0 when not run.
    jackknife_skipped : str
        Why the jackknife was not run ("" when it was).
    jackknife_method : str
        How its replicates were solved (:data:`camcal.geometry.jackknife.METHODS`; "" when not run).
    aspect_prior : bool
        Whether ``fx - fy`` had the square-pixel prior (the default priors),
        or the images alone decided it (``principal_point="refine"``).
    given_aspect : tuple of str
        The user's priors on ``fx - fy`` (``"left: fx - fy = 0 +- 0.5 px"``); they replace the default there.
    aspect_visibility_px : dict of str to float
        Camera -> RMS image displacement of a change of ``fx - fy`` by the
        square-pixel prior's sigma once every other parameter re-adjusts
        (:func:`aspect_visibility`); empty where the default priors are off.
    aspect_held : tuple of str
        Cameras whose aspect the motion does not determine: square pixels
        held, the prior's spread of fx - fy carried into the covariance (:func:`self_calibrate`).
    frame_influences : FrameInfluences or None
        Each jackknife group's influence on the final fit, scene gauge included
        (:func:`camcal.geometry.bundle.influences.frame_influences`): the
        projection sigma's design effect
        (:func:`camcal.geometry.uncertainty.shrunk_design_effect`); None when
        the jackknife was not run or the problem has no one-step form.
    """

    lens_models: dict[str, str]
    heldout_rms_px: dict[str, dict[str, float]]
    n_heldout_points: int
    principal_point: tuple[PrincipalPointDecision, ...]
    undetermined: tuple[str, ...] = ()
    unused_priors: tuple[str, ...] = ()
    covariance_sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    jackknife_sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    jackknife_groups: int = 0
    jackknife_skipped: str = ""
    jackknife_method: str = ""
    aspect_prior: bool = True
    given_aspect: tuple[str, ...] = ()
    aspect_visibility_px: dict[str, float] = dataclasses.field(default_factory=dict)
    aspect_held: tuple[str, ...] = ()
    frame_influences: FrameInfluences | None = None

    def lines(self) -> list[str]:
        """The decisions, one line per camera and question, for the user."""
        rows = []
        for camera, model in self.lens_models.items():
            table = ", ".join(f"{name} {value:.4f}" for name, value in self.heldout_rms_px[camera].items())
            rows.append(f"{camera}: lens model {model} (held-out RMS px over {self.n_heldout_points} points: {table})")
        rows += [f"{decision.camera}: {decision.reason}" for decision in self.principal_point]
        rows += [line for line in self.undetermined if not line.split(":", 1)[0].endswith((".cx", ".cy"))]
        rows += [f"prior on {label} not used: the chosen lens model has no such parameter" for label in self.unused_priors]
        change = f"a {100 * ASPECT_PRIOR:g} % change of fx - fy"
        for camera in self.aspect_held:
            rows.append(f"aspect: {camera}: fx/fy not determined: the cameras turn about one axis or hardly at all "
                        f"(Sturm 1997): {change} moves the images by {self.aspect_visibility_px[camera]:.3g} px RMS once the scene "
                        f"re-adjusts, below the features' systematic error ({FEATURE_BIAS_PX:g} px); square pixels held, "
                        f"the aspect prior's +-{100 * ASPECT_PRIOR:g} % "
                        "of f carried into the sigmas")
        aspect = (f"under a prior fx - fy = 0 +- {100 * ASPECT_PRIOR:g} % of f (square pixels)" if self.aspect_prior
                  else "by the images alone (asked)")
        if self.given_aspect:
            aspect = f"under the given prior {', '.join(self.given_aspect)}" + (
                f", elsewhere {aspect}" if self.aspect_prior else "")
        apart = {camera: v for camera, v in self.aspect_visibility_px.items()
                 if camera not in self.aspect_held and np.isfinite(v)}
        if apart:
            aspect += f" ({change} moves the images by " + ", ".join(
                f"{v:.3g} px RMS ({camera})" for camera, v in apart.items()) + ")"
        first = (("aspect: on the other cameras " if self.aspect_held else "aspect: ") + "fx and fy refined apart " + aspect
                 if len(self.aspect_held) < len(self.lens_models) else "aspect: square pixels held on every camera")
        rows.append(f"{first}; skew: 0, not a parameter (no COLMAP camera model "
                    "has one; digital sensors' pixel rows and columns are orthogonal)")
        if self.jackknife_groups:
            ratios = ", ".join(f"{key} {self.jackknife_sigmas[key] / value:.2g}" for key, value in
                               self.covariance_sigmas.items() if key in self.jackknife_sigmas and value > 0)
            how = "full refits" if self.jackknife_method == "refit" else "one Gauss-Newton step each"
            rows.append(f"uncertainty: the larger of the covariance sigma and a delete-one-frame jackknife over "
                        f"{self.jackknife_groups} groups of frames ({how}), widened for its {self.jackknife_groups - 1} "
                        f"degrees of freedom (jackknife / covariance: {ratios})")
            if self.jackknife_groups < FEW_JACKKNIFE_GROUPS:
                rows.append(f"uncertainty: {self.jackknife_groups} groups of frames, fewer than "
                            f"{FEW_JACKKNIFE_GROUPS}: one frame left out leaves a weaker problem, so these sigmas "
                            "err wide (on rendered orbits of 6-12 frames the median error was 0.3-0.4 sigma); "
                            "more frames narrow them")
        else:
            rows.append(f"uncertainty: covariance sigmas only ({self.jackknife_skipped}); "
                        "they measure independent noise, not errors shared by an image's features")
        return rows


def self_calibrate(
    state: BundleState,
    options: BundleOptions,
    lens_models: tuple[str, ...] = LENS_MODELS,
    principal_point: str = "auto",
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    jackknife: str | None = "step",
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
        ``auto`` refines it under the sensor's prior (the image centre +-
        :data:`~camcal.geometry.bundle.prior.PRINCIPAL_POINT_PRIOR` of the
        diagonal), with the lens under its default priors
        (``BundleOptions.default_priors``); ``refine`` lets the images alone
        decide (no default prior); ``centre`` holds it at the image centre.
    seed : int
        Chooses the held-out points.
    progress : callable, optional
        Called with each stage's message (the CLI prints them to stderr).
    jackknife : {"step", "refit"} or None
        Also estimate the sigmas by the delete-one-frame jackknife
        (:func:`camcal.geometry.jackknife.frame_jackknife`), each replicate
        by one Gauss-Newton step (``step``) or a full refit (``refit``), and
        report the larger of the two; None: the covariance alone.

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
    on the rest (on a plate of more than :data:`LENS_CHOICE_FRAMES` frames,
    on that many frames spread evenly over it); the held-out points are re-triangulated through each fit
    (:func:`heldout_rms`) and each camera takes the model with the lowest
    held-out RMS (a model later in ``lens_models``, simplest first, must beat
    an earlier one by more than :data:`LENS_MODEL_MARGIN`; each fit to
    :data:`LENS_CHOICE_TOLERANCE`). Principal point
    and lens: every fit carries Gaussian priors on them (and the user's
    priors, ``options.priors``), so the estimate is the posterior's mode and
    the covariance (Ceres, ``sigma^2 (J^T J)^-1``, Triggs et al. 2000,
    section 6) the posterior's, the priors' information included; where the
    posterior sigma stays near the prior's the report says that the images do
    not determine the value. A principal point held at the centre instead
    moves its offset into the focal length and the lens (4-9 %
    focal errors on lateral slides). Uncertainty: features located
    in images share errors within an image (viewing angle, blur, sampling),
    which the covariance, built for independent noise, does not see; on
    rendered rigs its sigmas were 2-5 times below the error. The jackknife
    over frames sees them (widened by Tukey's t factor for its ``n - 1``
    degrees of freedom); the larger of the two is reported.
    """
    if principal_point not in PRINCIPAL_POINT_MODES:
        raise CamcalError(f"unknown principal point mode {principal_point!r}, "
                          f"expected one of: {', '.join(PRINCIPAL_POINT_MODES)}")
    if jackknife is not None and jackknife not in METHODS:
        raise CamcalError(f"unknown jackknife method {jackknife!r}, expected one of: {', '.join(METHODS)}, or None")
    if not lens_models:
        raise CamcalError("need at least one lens model to choose from")
    unknown = [model for model in lens_models if model not in MODELS]
    if unknown:
        raise CamcalError(f"unknown lens model {unknown[0]!r}, expected one of: {', '.join(MODELS)}")
    names = state.camera_names
    held_mask = np.random.default_rng(seed).random(len(state.points)) < HELDOUT_FRACTION
    frames = np.unique(state.obs_frame)
    spread = frames[np.unique(np.round(np.linspace(0, len(frames) - 1, min(len(frames), LENS_CHOICE_FRAMES))).astype(int))]
    left_out = np.setdiff1d(frames, spread)
    train, heldout = without_frames(state.subset(~held_mask), left_out), without_frames(state.subset(held_mask), left_out)
    on = f" on {len(spread)} of {len(frames)} frames" if len(left_out) else ""
    free_pp = dataclasses.replace(options, refine_principal_point=principal_point != "centre",
                                  default_priors=principal_point != "refine")
    table: dict[str, dict[str, float]] = {name: {} for name in names}
    for model in lens_models:
        _say(progress, f"lens model {model}: fitting {len(train.points)} points, {len(heldout.points)} held out{on}")
        lenses = dict.fromkeys(names, model)
        fit = bundle_adjust(with_lenses(train, lenses), dataclasses.replace(
            with_fixed_params(free_pp, lenses), compute_sigmas=False, tolerance=LENS_CHOICE_TOLERANCE))
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
    final_options = with_fixed_params(free_pp, chosen)
    final = bundle_adjust(with_lenses(state, chosen), final_options)
    visibility: dict[str, float] = {}
    if free_pp.default_priors:
        given = {spec.camera for spec in options.priors if spec.name == "aspect"}
        visibility = {name: aspect_visibility(final, k) for k, name in enumerate(names) if name not in given}
    held = tuple(name for name, v in visibility.items() if v < FEATURE_BIAS_PX)
    loose_options = final_options
    if held:
        _say(progress, f"bundle adjustment with square pixels held ({', '.join(held)}: the motion does not determine fx/fy)")
        final_options = dataclasses.replace(final_options, priors=final_options.priors + tuple(
            PriorSpec(name, "aspect", 0.0, ASPECT_HELD * mean_focal(final.state, names.index(name)),
                      SQUARE_PIXELS_HELD) for name in held))
        # it starts at the free fit's solution, whose solved noise weighs its priors (no second solve to re-weigh them)
        noise = final.noise_px if np.isfinite(final.noise_px) and final.noise_px > 0 else None
        held_fit = bundle_adjust(final.state, dataclasses.replace(final_options, prior_noise_px=noise, compute_sigmas=False))
        final = spread_with_aspect_free(final, held_fit, held)
    decisions = tuple(_principal_point_decision(final, k, principal_point) for k in range(len(names)))
    covariance_sigmas, jackknife_sigmas, groups, influences = dict(final.sigmas), {}, 0, None
    n_frames = len(np.unique(final.state.obs_frame))
    skipped = ("asked" if jackknife is None else
               f"the jackknife needs {MIN_FRAMES} frames, got {n_frames}" if n_frames < MIN_FRAMES else "")
    if not skipped:
        _say(progress, f"uncertainty: delete-one-frame jackknife ({min(n_frames, MAX_GROUPS)} groups of frames)")
        # held cameras: the replicates refit with the aspect under its prior (the hold moves the estimate, not
        # its spread over the frames); the influences are the fit's own, from the same pass over the groups
        spread = frame_jackknife(final, loose_options, method=jackknife, influence_options=final_options)
        jackknife_sigmas, groups, influences = spread.widened_sigmas, spread.n_groups, spread.influences
        # a singular covariance leaves keys only the jackknife has
        final = dataclasses.replace(final, sigmas={key: max(covariance_sigmas.get(key, 0.0), jackknife_sigmas.get(key, 0.0))
                                                   for key in {**covariance_sigmas, **jackknife_sigmas}})
    said = [i for i, prior in enumerate(final.priors) if prior.spec.source != SQUARE_PIXELS_HELD]  # held: its own aspect line
    report = SelfCalibration(
        lens_models=chosen, heldout_rms_px=table, n_heldout_points=len(heldout.points),
        principal_point=decisions,
        undetermined=tuple(undetermined(tuple(final.priors[i] for i in said),
                                        tuple(final.prior_posterior_sigmas[i] for i in said)) + _undetermined_focals(final)),
        unused_priors=tuple(spec.label for spec in final.unused_priors), covariance_sigmas=covariance_sigmas, jackknife_sigmas=jackknife_sigmas,
        jackknife_groups=groups, jackknife_skipped=skipped, jackknife_method=spread.method if not skipped else "",
        aspect_prior=free_pp.default_priors, frame_influences=influences,
        given_aspect=tuple(f"{spec.camera}: fx - fy = {spec.mean:g} +- {spec.sigma:g} px" for spec in options.priors
                           if spec.name == "aspect"),
        aspect_visibility_px=visibility, aspect_held=held,
    )
    return final, report


def _undetermined_focals(final: BundleResult) -> list[str]:
    """One line per focal length without a prior whose sigma is above :data:`FOCAL_UNDETERMINED` of it, or undefined."""
    state, lines = final.state, []
    given = {prior.spec.label for prior in final.priors}
    for camera, name in enumerate(state.camera_names):
        names = state.param_names(camera)
        for key in ("f", "fx", "fy"):
            if key not in names or f"{name}.{key}" in given or f"{name}.f" in given:
                continue
            value, sigma = float(state.params[camera][names.index(key)]), final.sigmas.get(f"{name}.{key}", np.nan)
            if np.isfinite(sigma) and sigma <= FOCAL_UNDETERMINED * value:
                continue
            spread = f"sigma {sigma:.3g} px ({100 * sigma / value:.2g} %)" if np.isfinite(sigma) else "sigma undefined"
            lines.append(f"{name}.{key}: the images barely determine it: {value:.6g} px, {spread}; give a prior "
                         f"(--prior {name}.f=MEAN+-SIGMA) or views with more depth and rotation")
    return lines


def _principal_point_decision(final: BundleResult, camera: int, mode: str) -> PrincipalPointDecision:
    """What became of camera ``camera``'s principal point, in one line with its sigmas."""
    state = final.state
    name, size = state.camera_names[camera], state.image_sizes[camera]
    if mode == "centre":
        return PrincipalPointDecision(name, False, (np.nan, np.nan), np.nan, False,
                                      "principal point held at the image centre (asked)")
    sigma = (final.sigmas.get(f"{name}.cx", np.nan), final.sigmas.get(f"{name}.cy", np.nan))
    numbers = (f"sigma(cx, cy) = ({sigma[0]:.3g}, {sigma[1]:.3g}) px" if np.all(np.isfinite(sigma))
               else "sigma(cx, cy) undefined (singular covariance)")
    if mode == "refine":
        return PrincipalPointDecision(name, True, sigma, np.nan, bool(np.all(np.isfinite(sigma))),
                                      f"principal point refined by the images alone (asked; {numbers})")
    prior = PRINCIPAL_POINT_PRIOR * float(np.hypot(*size))
    determined = bool(np.all(np.isfinite(sigma)) and max(sigma) < UNDETERMINED_RATIO * prior)
    reason = f"principal point refined: {numbers}, prior image centre +- {prior:.3g} px"
    if not determined:
        reason += (": the views barely determine it, the prior decides "
                   "(add rotation and roll about the viewing axis)")
    return PrincipalPointDecision(name, True, sigma, prior, determined, reason)


def _say(progress: Callable[[str], None] | None, message: str) -> None:
    """Hand a stage message to the caller's progress callback, if any."""
    if progress is not None:
        progress(message)
