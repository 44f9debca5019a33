"""Delete-one-frame jackknife of a bundle adjustment: uncertainty that sees correlated errors.

``sigma^2 (J^T J)^-1`` (:mod:`camcal.geometry.bundle`) assumes independent
errors of equal spread on every observation. Feature points located by SIFT
in real or rendered images are not like that: one image's errors share its
viewing angle, blur and sampling, and a lens model that is slightly wrong
errs the same way on every image. The intrinsics then move more from scene
to scene than the observation count suggests, and the covariance sigma is
too small for the error (2-5 sigma on rendered rigs).

The jackknife solves the refinement ``n`` times, each time without one
frame's observations (both cameras of a rig position; with more than
:data:`MAX_GROUPS` frames, one group of consecutive frames), starting from
the full solution, and estimates the variance of each quantity ``theta`` from
the spread of the replicates ``theta_(i)`` (Quenouille 1956; Tukey 1958;
Efron & Stein 1981; for grouped data Shao & Tu 1995, section 2.3)::

    var_jack = (n - 1) / n  sum_i (theta_(i) - mean(theta_(.)))^2

Whatever makes the frames disagree (correlated location errors, scene
dependence) is in it; a bias common to every frame is not.

Each replicate is by default one Gauss-Newton step from the full solution
on the problem without the group (``method="step"``,
:func:`camcal.geometry.bundle.deletion.one_step_replicates`: one Jacobian,
one reduced system per group), not a full refit (``method="refit"``, one
nonlinear bundle adjustment per group); on pycolmap's synthetic rigs and
camcal's rendered scenes the two give sigmas within a few percent
(``bench/bench_sfm.py`` prints the ratio and the times).

With ``n`` as small as a rig's 10 positions the variance estimate has
``n - 1`` degrees of freedom and is itself uncertain: Tukey's jackknife
interval is ``theta +- t_(n-1) sigma_jack``, not ``+- z sigma_jack``
(Tukey 1958). :attr:`FrameJackknife.widened_sigmas` scales the sigmas by
``t_(n-1, 0.975) / z_0.975`` (1.15 for 10 frames, 1.42 for 5) so that two of
them cover as the t interval does; on 15 rendered stereo rigs of 10
frames the plain jackknife sigmas covered 89 % of the focal and principal
point errors within two sigma.

Quantities: every free intrinsic (COLMAP's parameter names), and per
non-reference camera the rig rotation (rotation vector of ``R_(i) R^T``,
degrees), the baseline direction (change of the unit baseline, degrees) and
the baseline length relative to the rig's path (the baseline over the RMS
distance of the rig positions from their centroid, which the gauge's scale
does not change).

References
----------
Quenouille, M. H. (1956). Notes on bias in estimation. Biometrika 43.
Tukey, J. W. (1958). Bias and confidence in not-quite large samples.
Annals of Mathematical Statistics 29.
Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals
of Statistics 9.
Shao, J. & Tu, D. (1995). The Jackknife and Bootstrap. Springer.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import norm, t

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, BundleResult, BundleState, bundle_adjust
from camcal.geometry.bundle.deletion import DeletionUnsupported, one_step_replicates
from camcal.geometry.bundle.influences import FrameInfluences, frame_influences, replicates_and_influences

__all__ = ["MAX_GROUPS", "METHODS", "MIN_FRAMES", "FrameJackknife", "frame_groups", "frame_jackknife",
           "interval_factor", "without_frames"]

#: fewer frames give a variance estimate with too few degrees of freedom to print.
MIN_FRAMES = 5
#: more frames are left out in consecutive groups (a long sequence costs at most this many refinements).
MAX_GROUPS = 20
#: how each replicate is solved: one Gauss-Newton step from the full solution, or a full refit.
METHODS = ("step", "refit")


@dataclass(frozen=True)
class FrameJackknife:
    """Delete-one-frame jackknife of a bundle adjustment.

    Attributes
    ----------
    sigmas : dict of str to float
        One-sigma of each quantity (``camera.f``, ``camera.cx``...,
        ``camera.rotation_deg``, ``camera.baseline_direction_deg``,
        ``camera.baseline_rel``), the keys of :attr:`BundleResult.sigmas`.
    replicates : dict of str to ndarray, shape (n, d)
        Each quantity in every replicate (intrinsics as values, rig
        quantities as deviations from the full fit, see :func:`_rig_deviations`).
    n_frames : int
        Frames with observations.
    n_groups : int
        Groups of frames left out in turn (the jackknife's ``n``).
    method : str
        How the replicates were solved (:data:`METHODS`); ``refit`` also
        when ``step`` was asked of a problem it does not handle.
    influences : FrameInfluences or None
        Each group's influence on the fit
        (:func:`camcal.geometry.bundle.influences.frame_influences`) when
        asked for (``influence_options`` of :func:`frame_jackknife`) and the
        problem has a one-step form; else None.
    """

    sigmas: dict[str, float]
    replicates: dict[str, NDArray[np.float64]]
    n_frames: int
    n_groups: int
    method: str = "refit"
    influences: FrameInfluences | None = None

    @property
    def widened_sigmas(self) -> dict[str, float]:
        """The sigmas times :func:`interval_factor`: ``+- 1.96`` of them is the 95 % t interval."""
        factor = interval_factor(self.n_groups)
        return {key: value * factor for key, value in self.sigmas.items()}


def interval_factor(n_groups: int) -> float:
    """``t_(n-1, 0.975) / z_0.975``: Tukey's t interval over the normal one for a jackknife over ``n`` groups."""
    return float(t.ppf(0.975, n_groups - 1) / norm.ppf(0.975))


def frame_groups(state: BundleState, max_groups: int = MAX_GROUPS) -> list[NDArray[np.int64]]:
    """The frames with observations in at most ``max_groups`` groups of consecutive frames (one frame each when
    there are fewer), the groups the jackknife leaves out in turn."""
    frames = np.unique(state.obs_frame)
    return np.array_split(frames, min(len(frames), max_groups))


def without_frames(state: BundleState, frames: NDArray[np.int64]) -> BundleState:
    """The state without the observations of ``frames``; points left with fewer than 2 are dropped."""
    keep_obs = ~np.isin(state.obs_frame, frames)
    counts = np.bincount(state.obs_point[keep_obs], minlength=len(state.points))
    return state.subset(counts >= 2, keep_obs)


def _path_scale(state: BundleState, frames: NDArray[np.int64]) -> float:
    """RMS distance of the rig positions ``frames`` from their centroid (the gauge's length unit)."""
    centres = np.einsum("fji,fj->fi", state.frame_R[frames], -state.frame_t[frames])
    return float(np.sqrt(np.mean(np.sum((centres - centres.mean(axis=0)) ** 2, axis=1))))


def _rig_deviations(full: BundleState, replicate: BundleState, frames: NDArray[np.int64]) -> dict[str, NDArray[np.float64]]:
    """Per non-reference camera, the replicate's rig pose against the full fit's.

    ``rotation_deg``: rotation vector of ``R_(i) R^T`` (3, degrees);
    ``baseline_direction_deg``: the unit baseline's change across the full
    fit's direction (3, degrees); ``baseline_rel``: relative change of the
    baseline over the rig path's scale (1).
    """
    out = {}
    for index in range(1, len(full.camera_names)):
        name = full.camera_names[index]
        t_full, t_rep = full.sensor_t[index], replicate.sensor_t[index]
        along = t_full / np.linalg.norm(t_full)
        change = t_rep / np.linalg.norm(t_rep) - along
        out[f"{name}.rotation_deg"] = np.degrees(
            Rotation.from_matrix(replicate.sensor_R[index] @ full.sensor_R[index].T).as_rotvec())
        out[f"{name}.baseline_direction_deg"] = np.degrees(change - (change @ along) * along)
        out[f"{name}.baseline_rel"] = np.array([(float(np.linalg.norm(t_rep)) / _path_scale(replicate, frames)) / (
            float(np.linalg.norm(t_full)) / _path_scale(full, frames)) - 1.0])
    return out


def frame_jackknife(result: BundleResult, options: BundleOptions,
                    progress: Callable[[int, int], None] | None = None,
                    max_groups: int = MAX_GROUPS, method: str = "step",
                    influence_options: BundleOptions | None = None) -> FrameJackknife:
    """Sigmas of a refinement's intrinsics and rig pose by leaving out one frame at a time.

    Parameters
    ----------
    result : BundleResult
        The refinement on every frame; each replicate starts from it.
    options : BundleOptions
        The same options (what is free, the loss); sigmas are not computed
        for the replicates.
    progress : callable, optional
        ``progress(done, total)`` after each replicate.
    max_groups : int
        Frames are left out in at most this many groups of consecutive frames.
    method : {"step", "refit"}
        Each replicate by one Gauss-Newton step from the full solution
        (:func:`~camcal.geometry.bundle.deletion.one_step_replicates`; falls
        back to refits where it does not apply, e.g. with a board) or by a
        full bundle adjustment.
    influence_options : BundleOptions, optional
        Also each group's influence on the fit under these options (the
        fit's own; they may differ from ``options`` in their priors), with
        the ``step`` replicates from the same sums
        (:func:`~camcal.geometry.bundle.influences.replicates_and_influences`).

    Returns
    -------
    FrameJackknife

    Raises
    ------
    CamcalError
        Fewer than :data:`MIN_FRAMES` frames with observations.

    Notes
    -----
    A vector quantity (rotation vector, baseline direction change) gets the
    square root of its jackknife covariance's trace, as
    :func:`camcal.geometry.bundle.bundle_adjust` does with ``sigma^2 (J^T J)^-1``.
    """
    state = result.state
    frames = np.unique(state.obs_frame)
    if len(frames) < MIN_FRAMES:
        raise CamcalError(f"the frame jackknife needs at least {MIN_FRAMES} frames with observations, got {len(frames)}")
    if method not in METHODS:
        raise CamcalError(f"unknown jackknife method {method!r}, expected one of: {', '.join(METHODS)}")
    quiet = dataclasses.replace(options, compute_sigmas=False)
    intrinsics = {f"{state.camera_names[k]}.{name}": (k, i) for k in range(len(state.camera_names))
                  for i, name in enumerate(state.param_names(k))}
    values: dict[str, list[NDArray[np.float64]]] = {key: [] for key in intrinsics}
    groups = frame_groups(state, max_groups)
    steps, influences = None, None
    if method == "step":
        try:
            if influence_options is None:
                steps = one_step_replicates(state, quiet, groups)
            else:
                steps, influences = replicates_and_influences(state, quiet, influence_options, groups)
        except DeletionUnsupported:
            method = "refit"
    elif influence_options is not None:
        try:
            influences = frame_influences(state, influence_options, groups)
        except DeletionUnsupported:
            influences = None
    for done, group in enumerate(groups, start=1):
        replicate = steps[done - 1] if steps is not None else bundle_adjust(without_frames(state, group), quiet).state
        for key, (k, i) in intrinsics.items():
            values[key].append(replicate.params[k][i:i + 1])
        if options.refine_sensor_from_rig:
            for key, value in _rig_deviations(state, replicate, np.setdiff1d(frames, group)).items():
                values.setdefault(key, []).append(value)
        if progress is not None:
            progress(done, len(groups))
    n = len(groups)
    # held parameters never move from the full fit's value: they have no sigma
    replicates = {key: np.array(v) for key, v in values.items()
                  if key not in intrinsics or np.any(np.array(v) != state.params[intrinsics[key][0]][intrinsics[key][1]])}
    sigmas = {key: float(np.sqrt((n - 1) / n * np.sum((v - v.mean(axis=0)) ** 2))) for key, v in replicates.items()}
    return FrameJackknife(sigmas=sigmas, replicates=replicates, n_frames=len(frames), n_groups=n, method=method,
                          influences=influences)
