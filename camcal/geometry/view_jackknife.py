"""Delete-one-view jackknife of a board calibration: a covariance that sees errors correlated within a view.

``sigma^2 (J^T J)^-1`` assumes each corner errs independently. A corner
detector does not: one view's corners share its blur, tilt and sampling, so
their errors are correlated, and the intrinsics and the board gauge move
more from scene to scene than the corner count suggests (on rendered
boards the projection sigma covered 60-70 % of the true error within two
sigma, not 95 %). Leaving out one whole view at a time keeps every
within-view correlation inside the deleted unit, so the spread of the
replicates measures it (the grouped jackknife: Shao & Tu 1995, section
2.3; Efron & Stein 1981).

Each replicate is one Gauss-Newton step from the full solution on the
problem without view ``i``, in camcal's own parameters ``x`` (the
intrinsics of every camera, each non-reference camera's pose
``cam_from_reference``, one pose per view ``rig_from_board``, all perturbed
on the left: ``R' = exp(delta) R``, ``t' = t + tau``). For least squares
that step is exactly ``x_(i) - x = -(J^T J)^-1 J_i^T (I - H_ii)^-1 r_i``,
with ``H_ii = J_i (J^T J)^-1 J_i^T`` the view's block of the hat matrix: the
jackknife is the cluster-robust sandwich with the "CR3" correction, which
over-states the variance by ``(I - H_ii)^-1`` where a view has leverage --
and with 12 views of 4-8 intrinsics and a gauge every view does (on
independent corner noise the plain jackknife gave 1.5-3 times the true
variance). The influences used here are Bell & McCaffrey's "CR2" ones,
unbiased when the corners' errors ARE independent::

    d_i = (J^T J)^-1 J_i^T (I - H_ii)^-1/2 r_i,      C_jack = sum_i T d_i d_i^T T^T

(the pseudo-inverse square root: the view's own pose, which only it sees,
has ``H = 1`` and no residual along it). ``T`` maps a step to the global
parameters and to the board gauge, mrcal's mean over the views of
``(delta_j, tau_j + t_j x delta_j)``
(:func:`camcal.geometry.bundle.solve._gauge_rows`). The Jacobian is a
central difference of :meth:`camcal.model.distortion.Distortion.project_rays`.

With ``n`` views the estimate has ``n - 1`` degrees of freedom; Tukey's
interval ``theta +- t_(n-1) sigma_jack`` is kept by scaling ``C_jack`` by
``(t_(n-1, 0.975) / z_0.975)^2`` (:func:`camcal.geometry.jackknife.interval_factor`).

The calibration scales the camera's covariance by the design effect of its
projection (:func:`design_effect`, Kish 1965): the ratio of the jackknife's
to the covariance's projection variance pooled over the frame, never below
one. Pooled, because a maximum taken direction by direction over two
estimates, one of them with 11 degrees of freedom, is inflated by the
noise of the larger (on independent noise it halved the median error /
sigma); never below one, because independent corners are the least the
error can be. A bias common to every view (a lens model slightly wrong, a
detector that errs the same way on every view) makes the views agree and
is seen by neither.

References
----------
Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals
of Statistics 9.
Shao, J. & Tu, D. (1995). The Jackknife and Bootstrap. Springer.
Bell, R. M. & McCaffrey, D. F. (2002). Bias reduction in standard errors for linear regression
with multi-stage samples. Survey Methodology 28(2).
Kish, L. (1965). Survey Sampling. Wiley (the design effect).
Tukey, J. W. (1958). Bias and confidence in not-quite large samples.
Annals of Mathematical Statistics 29.
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.geometry.bundle import BoardObservations
from camcal.geometry.jackknife import MIN_FRAMES, interval_factor
from camcal.model.distortion import Distortion

__all__ = ["ViewJackknife", "board_jacobian", "design_effect", "view_jackknife"]

_K_ENTRIES = {"fx": ((0, 0),), "fy": ((1, 1),), "cx": ((0, 2),), "cy": ((1, 2),), "f": ((0, 0), (1, 1))}
_POSE = ("rx", "ry", "rz", "tx", "ty", "tz")
_GAUGE = ("gauge.rx", "gauge.ry", "gauge.rz", "gauge.tx", "gauge.ty", "gauge.tz")


@dataclasses.dataclass(frozen=True)
class ViewJackknife:
    """The jackknife covariance of a board calibration.

    Attributes
    ----------
    covariance : ndarray, shape (P, P)
        Over :attr:`names`, widened by the t factor (module docstring).
    names : tuple of str
        The calibration's labels: ``camera.fx``..., ``camera.rx``...,
        ``gauge.rx``...
    n_views : int
        Views left out in turn.
    factor : float
        The t factor its variances were multiplied by.
    """

    covariance: NDArray[np.float64]
    names: tuple[str, ...]
    n_views: int
    factor: float


def _lens(K: NDArray, distortion: Distortion, name: str, step: float) -> tuple[NDArray, Distortion]:
    """K and distortion with parameter ``name`` (``f``: fx and fy together) moved by ``step``."""
    if name in _K_ENTRIES:
        K = np.array(K, dtype=np.float64)
        for entry in _K_ENTRIES[name]:
            K[entry] += step
        return K, distortion
    params = dict(distortion.params)
    params[name] += step
    return K, dataclasses.replace(distortion, params=params)


def _cross(t: NDArray) -> NDArray:
    """``[t]x``: ``[t]x d = t x d``."""
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def _rotate(R: NDArray, rotvec: NDArray) -> NDArray:
    """``exp(rotvec) R`` for each of a stack."""
    return Rotation.from_rotvec(rotvec).as_matrix() @ R


def board_jacobian(lenses: Sequence[tuple[NDArray, Distortion, tuple[str, ...]]], sensor_R: NDArray,
                   sensor_t: NDArray, frame_R: NDArray, frame_t: NDArray, X: NDArray, cam: NDArray, frame: NDArray,
                   ) -> tuple[list[tuple[int, str]], NDArray, NDArray, NDArray]:
    """Central-difference Jacobian of board corners' projections (module docstring's parameters).

    ``X`` (N, 3) are the corners on the board, ``cam`` and ``frame`` (N,)
    the camera and view of each. Returns the global columns ``(camera,
    name)``, their Jacobian (2N, G) (rows ``x0, y0, x1, ...``), the Jacobian
    (2N, 6) of each corner's projection by its own view's pose ``(delta,
    tau)`` and the projections (N, 2).
    """
    X = np.asarray(X, dtype=np.float64)
    n_views = len(frame_R)
    # the global parameters: (camera, name) per free intrinsic, then (camera, pose axis) per non-reference camera
    columns = [(c, name) for c, (_, _, free) in enumerate(lenses) for name in free]
    columns += [(c, axis) for c in range(1, len(lenses)) for axis in _POSE]

    def project(lens_of, sR, st, fR, ft) -> NDArray:
        out = np.empty((len(X), 2))
        p_rig = np.einsum("nij,nj->ni", fR[frame], X) + ft[frame]
        for c, (K, distortion) in enumerate(lens_of):
            rows = cam == c
            out[rows] = distortion.project_rays(p_rig[rows] @ sR[c].T + st[c], K)
        return out

    base = [(np.asarray(K, dtype=np.float64), d) for K, d, _ in lenses]
    sR, st = np.asarray(sensor_R, dtype=np.float64), np.asarray(sensor_t, dtype=np.float64)
    fR, ft = np.asarray(frame_R, dtype=np.float64), np.asarray(frame_t, dtype=np.float64)
    projected = project(base, sR, st, fR, ft)

    def global_step(k: int, h: float) -> NDArray:
        c, name = columns[k]
        if name in _POSE:
            e = np.zeros(3)
            e[_POSE.index(name) % 3] = h
            R2, t2 = sR.copy(), st.copy()
            if name[0] == "r":
                R2[c] = _rotate(sR[c], e)
            else:
                t2[c] = st[c] + e
            return project(base, R2, t2, fR, ft)
        lens = list(base)
        lens[c] = _lens(*base[c], name, h)
        return project(lens, sR, st, fR, ft)

    def steps(k: int) -> float:
        c, name = columns[k]
        if name in _POSE:
            return 1e-6 if name[0] == "r" else 1e-6 * max(float(np.linalg.norm(st[c])), 1e-3)
        K, distortion = base[c]
        value = abs(K[_K_ENTRIES[name][0]]) if name in _K_ENTRIES else abs(distortion.params[name])
        if name in _K_ENTRIES:
            return 1e-6 * max(value, 1.0)
        # a distortion coefficient: relative to its value
        return 1e-6 * max(value, 1e-12) if value else 1e-9

    Jg = np.empty((2 * len(X), len(columns)))
    for k in range(len(columns)):
        h = steps(k)
        Jg[:, k] = (global_step(k, h).ravel() - global_step(k, -h).ravel()) / (2.0 * h)
    # each view's pose moves only its own corners: one pass per axis for all views at once
    scale = 1e-6 * max(float(np.median(np.linalg.norm(ft, axis=1))), 1e-3)
    Jp = np.empty((2 * len(X), 6))
    for axis in range(6):
        h = 1e-6 if axis < 3 else scale
        e = np.zeros((n_views, 3))
        e[:, axis % 3] = h
        plus = (fR, ft + e) if axis >= 3 else (_rotate(fR, e), ft)
        minus = (fR, ft - e) if axis >= 3 else (_rotate(fR, -e), ft)
        Jp[:, axis] = (project(base, sR, st, *plus).ravel() - project(base, sR, st, *minus).ravel()) / (2.0 * h)

    return columns, Jg, Jp, projected


def view_jackknife(lenses: Sequence[tuple[NDArray, Distortion, tuple[str, ...]]], sensor_R: NDArray,
                   sensor_t: NDArray, frame_R: NDArray, frame_t: NDArray, observations: BoardObservations,
                   names: Sequence[str], camera_names: Sequence[str]) -> ViewJackknife | None:
    """The delete-one-view jackknife covariance over ``names`` (module docstring), or None below
    :data:`~camcal.geometry.jackknife.MIN_FRAMES` views.

    Parameters
    ----------
    lenses : sequence of (K, Distortion, free)
        Per camera its solved K, distortion and the names of its free
        intrinsics (``f`` for one focal length shared by fx and fy).
    sensor_R, sensor_t : ndarray, shapes (C, 3, 3), (C, 3)
        ``cam_from_reference`` of each camera (the first is the identity, held).
    frame_R, frame_t : ndarray, shapes (F, 3, 3), (F, 3)
        ``rig_from_board`` of each view.
    observations : BoardObservations
        The corners the solution was fitted to.
    names : sequence of str
        The labels of the covariance the result is to sit beside
        (``camera.fx``, ``camera.rx``, ``gauge.rx``...); a name of the form
        ``camera.fx`` / ``camera.fy`` takes the value of the shared ``f`` when the camera has one.
    camera_names : sequence of str
        The cameras' names, in ``lenses`` order.
    """
    n_views = len(frame_R)
    if n_views < MIN_FRAMES:
        return None
    cam, frame, xy = observations.camera, observations.frame, observations.xy
    X = np.asarray(observations.object_points, dtype=np.float64)[observations.corner]
    columns, Jg, Jp, projected = board_jacobian(lenses, sensor_R, sensor_t, frame_R, frame_t, X, cam, frame)
    r = (projected - xy).ravel()
    ft = np.asarray(frame_t, dtype=np.float64)
    # Jacobi scaling: a distortion coefficient's column is ~1e8 times a focal length's
    column_scale = 1.0 / np.maximum(np.linalg.norm(Jg, axis=0), 1e-300)
    G = len(columns)
    J = np.zeros((len(r), G + 6 * n_views))
    J[:, :G] = Jg * column_scale
    row_frame = np.repeat(frame, 2)
    for f in range(n_views):
        rows = row_frame == f
        J[rows, G + 6 * f:G + 6 * f + 6] = Jp[rows]
    M = np.linalg.inv(J.T @ J)
    # the board gauge of a step: the mean over the views of (delta_f, tau_f + t_f x delta_f)
    gauge = np.zeros((6, J.shape[1]))
    for f in range(n_views):
        o = G + 6 * f
        gauge[:3, o:o + 3] = np.eye(3) / n_views
        gauge[3:, o:o + 3] = _cross(ft[f]) / n_views  # d(t x delta)/d delta = [t]x
        gauge[3:, o + 3:o + 6] = np.eye(3) / n_views
    influences = []
    for f in range(n_views):
        rows = row_frame == f
        Jf = J[rows]
        w, U = np.linalg.eigh(np.eye(len(Jf)) - Jf @ M @ Jf.T)
        # (I - H_ff)^-1/2; its null space (the view's own pose, which only the view sees) holds no residual
        inv_sqrt = (U / np.sqrt(np.where(w > 1e-9, w, np.inf))) @ U.T
        dx = M @ (Jf.T @ (inv_sqrt @ r[rows]))
        influences.append(np.r_[dx[:G] * column_scale, gauge @ dx])
    T = np.array(influences)
    jack = T.T @ T

    # onto the caller's labels: camera.fx / camera.fy take the shared f where the camera has one
    index = {}
    for k, (c, name) in enumerate(columns):
        if name == "f":
            index[f"{camera_names[c]}.fx"] = index[f"{camera_names[c]}.fy"] = k
        else:
            index[f"{camera_names[c]}.{name}"] = k
    for k, name in enumerate(_GAUGE):
        index[name] = G + k
    A = np.zeros((len(names), jack.shape[0]))
    for row, name in enumerate(names):
        if name in index:
            A[row, index[name]] = 1.0
    factor = interval_factor(n_views) ** 2
    return ViewJackknife(factor * (A @ jack @ A.T), tuple(names), n_views, factor)


def design_effect(sigma: NDArray, sigma_jackknife: NDArray) -> float:
    """``max(1, mean(sigma_jack^2) / mean(sigma^2))`` over a frame's pixels: how much the views' own
    spread exceeds what independent corners predict (Kish's design effect of clustered samples).

    Pooled over the frame (not per pixel or direction) so that the
    jackknife's few degrees of freedom do not turn the maximum of two noisy
    estimates into an inflated one; never below 1, since independent
    corners are the least the error can be.
    """
    ok = np.isfinite(sigma) & np.isfinite(sigma_jackknife)
    if not ok.any():
        return 1.0
    return float(max(1.0, np.mean(sigma_jackknife[ok] ** 2) / max(np.mean(sigma[ok] ** 2), 1e-300)))
