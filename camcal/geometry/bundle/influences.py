"""Each group of frames' influence on a bundle adjustment's intrinsics, rig poses and scene gauge.

The projection sigma's design effect (:func:`camcal.geometry.uncertainty.shrunk_design_effect`) needs how far
leaving out each cluster of observations moves the solution: the delete-one-cluster form of MacKinnon &
White's (1985) jackknife covariance, which Bell & McCaffrey (2002) call CR3. To first order the move is the
one-step replicate of :mod:`camcal.geometry.bundle.deletion`: ``theta_(g) - theta = (H - J_g^T J_g)^+ J_g^T
r_g``, which the Woodbury identity writes ``H^-1 J_g^T (I - H_gg)^+ r_g`` (``H = J^T J`` of the whole problem,
``H_gg = J_g H^-1 J_g^T`` the cluster's block of the hat matrix). It is taken over every free column, the
frames' poses included, so that the scene gauge's turn (:func:`camcal.geometry.uncertainty.scene_gauge_rows`)
moves with the intrinsics.

The two forms differ where the rows kept leave directions free: the group's own frame poses (only its rows
see them) and the gauge, when the group held it. ``I - H_gg`` is singular there and its Moore-Penrose inverse
(Pustejovsky & Tipton 2018), taken with the points eliminated (``X``: the group's rows of the reduced system,
``z`` its residuals, so that ``S - S_(g) = X^T X`` with ``S`` the reduced system of every row and ``S_(g)``
that of the rows kept), picks the move ``delta`` with ``n^T S delta = 0`` for every free direction ``n``
(``S_(g) n = 0``): ``u = (I - H_gg)^+ z`` is orthogonal to the null space's ``X n``, and ``n^T X^T u = n^T S
delta``. That is the step of the reduced system without the group plus the free directions' share that
minimises ``delta^T S delta``: the group's frames resected against the moved solution, the gauge held as the
whole problem holds it (:func:`frame_influences`).
So each group costs the one-step replicate's sums over its rows and one Cholesky factorisation of the reduced
system (``(6 F + 5)^3 / 3`` flops for ``F`` frames) plus a solve over a few free directions; the Woodbury form
costs an eigen-decomposition over every column the group's points touch, and a group's rows times their
columns squared to build it: per frame, on a plate whose frames all share points, ``F^3`` each.

The frame jackknife's one-step replicates (:func:`camcal.geometry.jackknife.frame_jackknife`) are the same
groups' steps with the whole gradient: :func:`replicates_and_influences` makes both from one pass over the
groups' sums, on the observations' rows, each problem adding its own priors' normal equations (the
self-calibration's replicates and its fit differ only there).

Clusters: one frame each on a short sequence; on a long plate the contiguous groups of the frame jackknife
(:func:`camcal.geometry.jackknife.frame_groups`), a bounded count whatever the length. Neighbouring frames of a
plate see the same points from nearly the same place and their features are tracked from one to the next, so
their errors are correlated: the cluster-robust variance needs clusters that hold the correlation (Bell &
McCaffrey 2002; Cameron & Miller 2015, section IV), which contiguous groups do better than single frames.

References
----------
MacKinnon, J. G. & White, H. (1985). Some heteroskedasticity-consistent covariance matrix estimators with
improved finite sample properties. Journal of Econometrics 29.
Bell, R. M. & McCaffrey, D. F. (2002). Bias reduction in standard errors for linear regression with
multi-stage samples. Survey Methodology 28.
Pustejovsky, J. E. & Tipton, E. (2018). Small-sample methods for cluster-robust variance estimation and
hypothesis testing in fixed effects models. Journal of Business & Economic Statistics 36.
Cameron, A. C. & Miller, D. L. (2015). A practitioner's guide to cluster-robust inference. Journal of Human
Resources 50.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.bundle.deletion import (FrameDeletion, LinearisedBundle, apply_step, linearise, one_step_replicates,
                                             prior_sums, split_priors)
from camcal.geometry.bundle.solve import bundle_adjust
from camcal.geometry.bundle.state import BundleOptions, BundleState
from camcal.geometry.uncertainty import scene_gauge_rows

__all__ = ["FrameInfluences", "frame_influences", "replicates_and_influences"]


@dataclasses.dataclass(frozen=True)
class FrameInfluences:
    """Each group of frames' influence on a bundle adjustment's intrinsics, rig poses and scene gauge.

    Attributes
    ----------
    names : tuple of str
        :attr:`camcal.geometry.bundle.BundleResult.covariance_names`' names
        (``CAMERA.f``..., ``CAMERA.rx``..., ``gauge.rx``...; rotations as
        rotation vectors).
    values : ndarray, shape (n_groups, len(names))
        ``theta_(g) - theta`` of each group ``g``: the solution without its
        observations, to first order (:func:`frame_influences`).
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]


def _resected(reduced: NDArray[np.float64], delta: NDArray[np.float64], free: NDArray[np.float64]) -> NDArray[np.float64]:
    """A group's own move (:meth:`~camcal.geometry.bundle.deletion.FrameDeletion.step` with ``group_gradient``)
    with the directions ``free`` the rows kept leave free chosen as the Woodbury form's Moore-Penrose inverse
    chooses them: ``delta + N a`` with ``N^T S (delta + N a) = 0`` (module docstring; ``S``: ``reduced``)."""
    if free.shape[1] == 0:
        return delta
    S_free = reduced @ free
    inner = free.T @ S_free
    scale = 1.0 / np.sqrt(np.maximum(np.diag(inner), np.finfo(float).tiny))
    share = np.linalg.pinv(inner * np.outer(scale, scale), rcond=1e-12, hermitian=True) @ (scale * (S_free.T @ delta))
    return delta - free @ (scale * share)


def _parameter_rows(state: BundleState, system: LinearisedBundle, colmap) -> tuple[list[str], NDArray[np.float64]]:
    """The names of the intrinsics, rig poses and scene gauge, and the rows taking the columns' move to them."""
    names, columns, scales = [], [], []
    for block in system.blocks:
        if block.kind == "camera":
            param_names = state.param_names(block.index)
            names += [f"{state.camera_names[block.index]}.{param_names[k]}" for k in block.free]
            scales += [1.0] * len(block.free)
        elif block.kind == "sensor":
            names += [f"{state.camera_names[block.index]}.{axis}" for axis in ("rx", "ry", "rz", "tx", "ty", "tz")]
            scales += [2.0, 2.0, 2.0, 1.0, 1.0, 1.0]  # Ceres' quaternion tangent is half the rotation vector
        else:
            continue
        columns += list(range(block.columns.start, block.columns.stop))
    B = np.zeros((len(names), system.J_c.shape[1]))
    B[np.arange(len(names)), columns] = scales
    frames = sorted(colmap.frame_ids.items())
    rows = scene_gauge_rows([colmap.reconstruction.frame(fid).rig_from_world.rotation.matrix() for _, fid in frames])
    if rows is not None:  # the scene gauge of the frames' turns, held frames unperturbed (as the covariance's)
        gauge = np.zeros((3, B.shape[1]))
        for i, (frame, _) in enumerate(frames):
            for block in system.blocks:
                if block.kind == "frame" and block.index == frame:
                    gauge[:, block.columns.start:block.columns.start + 3] = 2.0 * rows[:, 3 * i:3 * i + 3]
        B = np.vstack([B, gauge])
        names += ["gauge.rx", "gauge.ry", "gauge.rz"]
    return names, B


def frame_influences(state: BundleState, options: BundleOptions,
                     groups: list[NDArray[np.int64]] | None = None) -> FrameInfluences:
    """How much leaving out each group of frames moves the solution, the scene gauge included (module docstring).

    Parameters
    ----------
    state : BundleState
        A converged bundle adjustment (every frame).
    options : BundleOptions
        The options it was solved with.
    groups : list of ndarray of int, optional
        Frame positions left out together (contiguous on a plate); by default each frame with observations alone.

    Returns
    -------
    FrameInfluences
        One row per group.

    Raises
    ------
    DeletionUnsupported
        As :func:`camcal.geometry.bundle.deletion.one_step_replicates`.
    """
    if groups is None:
        groups = [np.array([frame]) for frame in np.unique(state.obs_frame)]
    system, names, B = _linearised(state, options)
    deletion = FrameDeletion(system)
    return FrameInfluences(tuple(names), np.array([B @ _resected(deletion.reduced, *deletion.step(group, group_gradient=True))
                                                   for group in groups]))


def replicates_and_influences(state: BundleState, replicate_options: BundleOptions, options: BundleOptions,
                              groups: list[NDArray[np.int64]]) -> tuple[list[BundleState], FrameInfluences]:
    """:func:`~camcal.geometry.bundle.deletion.one_step_replicates` under ``replicate_options`` and
    :func:`frame_influences` under ``options`` over the same groups, from one pass over the groups' sums.

    Where the two options differ only in their priors (the self-calibration's replicates leave the aspect under
    its prior, its fit held it: :func:`camcal.geometry.selfcal.self_calibrate`), the sums over each group's
    observations are shared, each problem adding its own priors' normal equations
    (:meth:`~camcal.geometry.bundle.deletion.FrameDeletion.moves`: a few rows on the intrinsics, kept by every
    group; the replicates' made as ``options``' are, :func:`~camcal.geometry.bundle.deletion.prior_sums`);
    where they differ otherwise, or the priors' rows are not as made, each is computed on its own.

    Parameters
    ----------
    state : BundleState
        A converged bundle adjustment (every frame).
    replicate_options, options : BundleOptions
        The replicates' options and the influences' (the fit's).
    groups : list of ndarray of int
        Frame positions left out together.

    Returns
    -------
    list of BundleState
        One replicate per group (:func:`~camcal.geometry.bundle.deletion.one_step_replicates`).
    FrameInfluences
        One row per group (:func:`frame_influences`).

    Raises
    ------
    DeletionUnsupported
        As :func:`camcal.geometry.bundle.deletion.one_step_replicates`.
    """
    def linear(given: BundleOptions) -> BundleOptions:
        return dataclasses.replace(given, max_iterations=0, compute_sigmas=False)

    def apart() -> tuple[list[BundleState], FrameInfluences]:
        return one_step_replicates(state, replicate_options, groups), frame_influences(state, options, groups)

    system, names, B = _linearised(state, options)
    observations, own_priors = split_priors(system)
    step_priors = own_priors
    if linear(replicate_options) != linear(options):
        if dataclasses.replace(linear(replicate_options), priors=options.priors) != linear(options):
            return apart()
        step_priors = prior_sums(state, system, options, replicate_options)
        if step_priors is None:
            return apart()
    deletion = FrameDeletion(observations)
    reduced = deletion.reduced + own_priors[0]
    replicates, values = [], []
    for group in groups:
        step, own, free = deletion.moves(group, step_priors, own_priors)
        replicates.append(apply_step(state, system.blocks, step))
        values.append(B @ _resected(reduced, own, free))
    return replicates, FrameInfluences(tuple(names), np.array(values))


def _linearised(state: BundleState, options: BundleOptions,
                ) -> tuple[LinearisedBundle, list[str], NDArray[np.float64]]:
    """The problem of ``options`` at ``state`` (:func:`~camcal.geometry.bundle.deletion.linearise`) and its
    parameters' names and rows (:func:`_parameter_rows`)."""
    out = []

    def inspect(problem, colmap) -> None:
        system = linearise(state, options, colmap, problem)
        out.append((system, *_parameter_rows(state, system, colmap)))

    bundle_adjust(state, dataclasses.replace(options, max_iterations=0, compute_sigmas=False), inspect=inspect)
    return out[0]
