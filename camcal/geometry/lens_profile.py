"""A lens over its states: smooth surfaces of the calibrated parameters, their uncertainty, the next state to shoot.

Each parameter ``p`` (``fx fy cx cy`` and the lens model's) of the states
calibrated is fitted by weighted least squares (weights ``1 / sigma^2``,
the state's own calibration sigma) as a polynomial ``sum c_ij u^i v^j`` in
the state's coordinates (:func:`camcal.model.lens_profile.state_coordinates`:
the focal length and the focus vergence ``1 / focus``, each on ``[-1, 1]``;
sampling focus in ``1 / distance`` is how lens-mapping tools space focus
toward infinity). The degrees (focal up to 3, vergence up to 2, every product
of their powers or a total degree at most the larger) are chosen per parameter by leaving one state out
in turn: the fit without state ``k`` predicts it, and the surfaces are
scored by the weighted prediction error ``mean ((y_k - yhat_k) / sigma_k)^2``
(the weighted PRESS statistic; Allen 1974, *Technometrics* 16(1)), summed
over the parameters that share their terms (:func:`_groups`: ``fx`` with
``fy``, the lens coefficients together; surfaces of different terms for two
parameters a board ties together would break the tie between states); the
best score wins.
The chosen surface's standardised residuals ``z_k = (y_k - yhat_k) /
sqrt(sigma_k^2 + var(yhat_k))`` give its ``scale`` and the states no
surface predicts. A joint factor on every sigma follows from the states'
joint leave-one-out misses (:func:`_joint_scale`), which catch what the
parameters miss together (fx and k1 trade off on a board).

The fit is linear in the states' values, ``yhat_p(s) = h_p(s) . y_p``, so
the covariance of two predicted parameters at a state ``s`` is
``sum_k h_p,k(s) h_q,k(s) C_k[p, q]`` from each state's covariance ``C_k``
(Bevington & Robinson, *Data Reduction and Error Analysis*, ch. 7), times
each surface's ``scale``: the root of its leave-one-out ``mean z^2`` when
that is over 1, so the sigma covers what the surface misses between states.
A projected pixel's sigma follows by the Jacobian of the projection
(numerical, central differences).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.stats
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion, frame_grid
from camcal.model.lens_profile import INTRINSIC_NAMES, LensProfile, LensState, Surface, state_coordinates
from camcal.model.rig import Camera

__all__ = ["DISAGREE_Z", "ProfileFit", "StateSuggestion", "camera_at", "fit_profile", "parameters_at",
           "projection_sigma_px", "suggest_state"]

#: A state disagrees with every smooth profile when, for some parameter, each candidate surface fitted
#: without it misses it by more than this many of its sigmas.
DISAGREE_Z = 5.0
#: ... and by more than this many times the median state's miss (sigmas too small for every state are not one
#: state's fault).
_STANDS_OUT = 3.0
_MAX_FOCAL_DEGREE = 3
_MAX_FOCUS_DEGREE = 2


@dataclass(frozen=True)
class ProfileFit:
    """The surfaces fitted to the states and the states none of them agrees with.

    Attributes
    ----------
    surfaces : dict of str to Surface
    disagreeing : dict of str to str
        State label -> the parameter and its smallest leave-one-out miss in sigmas (``k1 12.3 sigma``).
    """

    surfaces: dict[str, Surface]
    disagreeing: dict[str, str]


def _candidates(n_states: int, n_focals: int, n_focuses: int) -> list[tuple[tuple[int, int], ...]]:
    """Term sets ``u^i v^j`` with ``i <= a``, ``j <= b``: the full product and the total degree ``i + j <= max(a,
    b)``, fewer terms than states, fewest terms first."""
    found = []
    for a in range(min(_MAX_FOCAL_DEGREE, n_focals - 1) + 1):
        for b in range(min(_MAX_FOCUS_DEGREE, n_focuses - 1) + 1):
            for total in (max(a, b), a + b):
                terms = tuple((i, j) for i in range(a + 1) for j in range(b + 1) if i + j <= total)
                if len(terms) <= max(2, n_states // 2):
                    found.append(terms)
    return sorted(set(found), key=lambda terms: (len(terms), terms))


def _design(terms: Sequence[tuple[int, int]], u: NDArray, v: NDArray) -> NDArray[np.float64]:
    return np.column_stack([np.atleast_1d(u) ** i * np.atleast_1d(v) ** j for i, j in terms])


def _smoother(design: NDArray, weights: NDArray) -> NDArray[np.float64] | None:
    """``G = (A^T W A)^-1 A^T W`` (coefficients = ``G y``), or None when ``A`` lacks rank."""
    normal = design.T @ (design * weights[:, None])
    if np.linalg.matrix_rank(normal) < design.shape[1]:
        return None
    return np.linalg.solve(normal, design.T * weights[None, :])


def _variances(states: Sequence[LensState], column: int) -> NDArray[np.float64]:
    """Each state's variance of one parameter, floored so a parameter held exactly still has a weight."""
    values = np.array([s.covariance[column, column] for s in states])
    scale = np.array([abs(list(s.params.values())[column]) for s in states])
    return np.maximum(values, (1e-9 * np.maximum(scale, 1e-3)) ** 2)


def _leave_one_out(terms, u, v, y, variance) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Each state's leave-one-out residual under ``terms`` and the same over the root of its variance plus the
    prediction's, or None where a fold lacks rank."""
    z, residual = np.empty(len(y)), np.empty(len(y))
    for k in range(len(y)):
        keep = np.arange(len(y)) != k
        G = _smoother(_design(terms, u[keep], v[keep]), 1.0 / variance[keep])
        if G is None:
            return None
        h = _design(terms, u[k:k + 1], v[k:k + 1])[0] @ G
        residual[k] = y[k] - h @ y[keep]
        z[k] = residual[k] / math.sqrt(variance[k] + h @ (variance[keep] * h))
    return residual, z


def _groups(parameters: Sequence[str]) -> list[tuple[str, ...]]:
    """The parameters that share one surface's terms: ``fx fy`` (a board fixes their ratio far better than
    either), ``cx``, ``cy``, and the lens model's together (its coefficients trade off against each other)."""
    groups = [tuple(name for name in ("fx", "fy") if name in parameters), ("cx",), ("cy",),
              tuple(name for name in parameters if name not in INTRINSIC_NAMES)]
    return [group for group in groups if group]


def fit_profile(states: Sequence[LensState], parameters: Sequence[str]) -> ProfileFit:
    """Fit one surface per parameter to the states (see the module docstring).

    Parameters
    ----------
    states : sequence of LensState
        At least 2, each with every parameter and its covariance.
    parameters : sequence of str
        The order of the states' covariances.

    Returns
    -------
    ProfileFit

    Raises
    ------
    CamcalError
        Fewer than 2 states.
    """
    if len(states) < 2:
        raise CamcalError(f"a lens profile needs at least 2 states, got {len(states)}")
    focals = np.array([s.focal_mm for s in states])
    vergences = np.array([s.vergence for s in states])
    u, v = state_coordinates(focals, np.array([s.focus_m for s in states]), (focals.min(), focals.max()),
                             (vergences.min(), vergences.max()))
    candidates = _candidates(len(states), len(set(focals)), len(set(vergences)))
    surfaces, worst_miss = {}, {}
    for group in _groups(parameters):
        columns = [parameters.index(name) for name in group]
        ys = {name: np.array([s.params[name] for s in states]) for name in group}
        variances = {name: _variances(states, column) for name, column in zip(group, columns)}
        scored = []  # (terms, {name: (residual, z)}) of the candidates every parameter of the group can hold out
        for terms in candidates:
            outs = {name: _leave_one_out(terms, u, v, ys[name], variances[name]) for name in group}
            if all(out is not None for out in outs.values()):
                scored.append((terms, outs))
        if len(states) == 2 or not scored:
            # two states: no state to hold out; the line through them (or their weighted mean)
            terms = ((0, 0), (1, 0)) if len(set(focals)) == 2 else ((0, 0), (0, 1)) if len(set(vergences)) == 2 \
                else ((0, 0),)
            chosen = None
        else:
            # the group's weighted PRESS: the sum of its parameters'
            scores = [sum(float(np.mean(outs[name][0] ** 2 / variances[name])) for name in group)
                      for _, outs in scored]
            terms, chosen = scored[int(np.argmin(scores))]  # the first (fewest terms) of equal scores
        for name in group:
            if chosen is None:
                scale, loso = 1.0, None
            else:
                residual, z = chosen[name]
                scale = math.sqrt(max(1.0, float(np.mean(z**2))))
                loso = float(np.sqrt(np.mean(residual**2)))
                misses = np.min(np.abs(np.array([outs[name][1] for _, outs in scored])), axis=0)
                typical = float(np.median(misses))
                for state, miss in zip(states, misses):
                    # a state stands out: far beyond its sigma and beyond the other states' misses
                    if miss > max(DISAGREE_Z, _STANDS_OUT * typical) and \
                            miss > worst_miss.get(state.label, (0.0, ""))[0]:
                        worst_miss[state.label] = (float(miss), name)
            G = _smoother(_design(terms, u, v), 1.0 / variances[name])
            surfaces[name] = Surface(tuple(terms), G @ ys[name], scale, loso)
    joint = _joint_scale(states, parameters, surfaces, u, v)
    surfaces = {name: Surface(s.terms, s.coefficients, max(s.scale, joint), s.loso_rms) for name, s in surfaces.items()}
    disagreeing = {label: f"{name} {miss:.3g} sigma" for label, (miss, name) in worst_miss.items()}
    return ProfileFit(surfaces, disagreeing)


def _joint_scale(states: Sequence[LensState], parameters: Sequence[str], surfaces: Mapping[str, Surface],
                 u: NDArray, v: NDArray) -> float:
    """The factor (>= 1) on every sigma that makes the surfaces' joint leave-one-out misses agree with their
    covariance: each state ``k`` predicted from the others, ``d_k^2 = r^T (C_pred + C_k)^-1 r``, whose median
    is the chi-square median of ``P`` degrees of freedom when the covariance is right (the median: a state
    that disagrees does not set the scale)."""
    if len(states) < 3:
        return 1.0
    values = np.array([[s.params[name] for name in parameters] for s in states])
    variances = np.column_stack([_variances(states, column) for column in range(len(parameters))])
    distances = []
    for k in range(len(states)):
        keep = u != u[k] if np.count_nonzero(u != u[k]) >= 2 else np.arange(len(states)) != k
        h = []
        for column, name in enumerate(parameters):
            terms = surfaces[name].terms
            G = _smoother(_design(terms, u[keep], v[keep]), 1.0 / variances[keep, column])
            if G is None:
                keep = np.arange(len(states)) != k
                G = _smoother(_design(terms, u[keep], v[keep]), 1.0 / variances[keep, column])
            if G is None:
                return max(s.scale for s in surfaces.values())
            h.append(_design(terms, u[k:k + 1], v[k:k + 1])[0] @ G)
        if any(len(row) != np.count_nonzero(keep) for row in h):
            continue  # the parameters' folds differ for this state: no joint miss
        h = np.array(h)  # (P, kept)
        residual = values[k] - np.sum(h * values[keep].T, axis=1)
        covariance = states[k].covariance + sum(np.outer(h[:, j], h[:, j]) * states[i].covariance
                                                for j, i in enumerate(np.flatnonzero(keep)))
        distances.append(float(residual @ np.linalg.lstsq(covariance, residual, rcond=None)[0]))
    return math.sqrt(max(1.0, float(np.median(distances)) / scipy.stats.chi2.median(len(parameters))))


def parameters_at(profile: LensProfile, focal_mm: float, focus_m: float) -> tuple[dict[str, float], NDArray]:
    """Every parameter of ``profile`` at a lens state, and their covariance (module docstring).

    Returns
    -------
    params : dict of str to float
        In the order of ``profile.parameters``.
    covariance : ndarray, shape (P, P)
    """
    states = profile.states
    u_states, v_states = profile.coordinates(np.array([s.focal_mm for s in states]),
                                             np.array([s.focus_m for s in states]))
    u, v = profile.coordinates(focal_mm, focus_m)
    params, rows = {}, []
    for column, name in enumerate(profile.parameters):
        surface = profile.surfaces[name]
        G = _smoother(_design(surface.terms, u_states, v_states), 1.0 / _variances(states, column))
        row = _design(surface.terms, u, v)[0]
        params[name] = float(row @ surface.coefficients)
        rows.append(surface.scale * (row @ G if G is not None else np.zeros(len(states))))
    h = np.array(rows)  # (P, n_states)
    covariance = np.zeros((len(rows), len(rows)))
    for k, state in enumerate(states):
        covariance += np.outer(h[:, k], h[:, k]) * state.covariance
    return params, covariance


def _camera(profile: LensProfile, params: Mapping[str, float], name: str) -> Camera:
    fx, fy, cx, cy = (params[key] for key in INTRINSIC_NAMES)
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    lens = Distortion(profile.model, {key: params[key] for key in profile.parameters[4:]})
    return Camera(name, profile.image_size, K, lens, np.eye(3), np.zeros(3))


def camera_at(profile: LensProfile, focal_mm: float, focus_m: float, name: str = "camera") -> Camera:
    """The camera (``R = I``, ``c = 0``) of ``profile`` at a lens state; its quality's sigma the profile's."""
    params, covariance = parameters_at(profile, focal_mm, focus_m)
    camera = _camera(profile, params, name)
    sigma = {key: float(math.sqrt(max(c, 0.0))) for key, c in zip(profile.parameters, np.diag(covariance))}
    worst = float(np.max(projection_sigma_px(profile, focal_mm, focus_m, frame_grid(profile.image_size, max(
        profile.image_size) / 8.0))))
    return Camera(camera.name, camera.image_size, camera.K, camera.distortion, camera.R, camera.c,
                  quality={"sigma": sigma, "worst_projection_sigma_px": worst})


def projection_sigma_px(profile: LensProfile, focal_mm: float, focus_m: float,
                        points_px: NDArray) -> NDArray[np.float64]:
    """The worst-direction one-sigma (px) of the profile's projection of the rays of ``points_px`` at a state.

    The rays are those the profile's camera at the state sees at ``points_px``;
    ``J C J^T`` (``J`` the projection's Jacobian in the parameters, ``C``
    their covariance at the state) gives each pixel's 2x2 covariance, whose
    largest eigenvalue's root is returned, shape ``(N,)``.
    """
    params, covariance = parameters_at(profile, focal_mm, focus_m)
    camera = _camera(profile, params, "camera")
    rays = camera.distortion.rays_from_pixels(points_px, camera.K)
    values = np.array(list(params.values()))
    steps = np.maximum(1e-3 * np.sqrt(np.maximum(np.diag(covariance), 0.0)), 1e-9 * np.maximum(abs(values), 1.0))
    jacobian = np.empty((len(rays), 2, len(values)))
    for column, step in enumerate(steps):
        pixels = []
        for sign in (1.0, -1.0):
            shifted = values.copy()
            shifted[column] += sign * step
            moved = _camera(profile, dict(zip(params, shifted)), "camera")
            pixels.append(moved.distortion.project_rays(rays, moved.K))
        jacobian[:, :, column] = (pixels[0] - pixels[1]) / (2.0 * step)
    pixel_covariance = jacobian @ covariance @ jacobian.transpose(0, 2, 1)
    return np.sqrt(np.maximum(np.linalg.eigvalsh(pixel_covariance)[:, -1], 0.0))


@dataclass(frozen=True)
class StateSuggestion:
    """The lens state to calibrate next.

    Attributes
    ----------
    focal_mm, focus_m : float
        Where the profile's worst projection sigma over the image, weighted by the distance to the states shot,
        is largest (``focus_m`` may be inf).
    worst_sigma_px : float
        That sigma.
    calibrated_worst_sigma_px : float
        The largest such sigma at the states calibrated, for comparison.
    """

    focal_mm: float
    focus_m: float
    worst_sigma_px: float
    calibrated_worst_sigma_px: float


def suggest_state(profile: LensProfile, focal_steps: int = 13, focus_steps: int = 7) -> StateSuggestion:
    """The state over the calibrated focal x focus range where the profile's projection is least certain.

    A grid of ``focal_steps`` focal lengths and ``focus_steps`` vergences
    (``1 / focus``, so toward infinity) over the calibrated ranges; at each,
    the largest :func:`projection_sigma_px` over a coarse grid of the image,
    times ``1 + d / spacing`` (``d`` the distance to the nearest state shot
    and ``spacing`` the states' mean nearest-neighbour distance, in the
    surfaces' coordinates): a polynomial's propagated sigma is largest at
    the ends of the range, where states were shot already, while what a
    low-order surface misses between states grows with the gap.
    """
    points = frame_grid(profile.image_size, max(profile.image_size) / 6.0)
    (f_low, f_high), (v_low, v_high) = profile.focal_range, profile.vergence_range
    focals = np.linspace(f_low, f_high, focal_steps if f_high > f_low else 1)
    vergences = np.linspace(v_low, v_high, focus_steps if v_high > v_low else 1)

    def worst(focal: float, focus: float) -> float:
        return float(np.max(projection_sigma_px(profile, focal, focus, points)))

    u_states, v_states = profile.coordinates(np.array([s.focal_mm for s in profile.states]),
                                             np.array([s.focus_m for s in profile.states]))
    gaps = [np.hypot(u_states - u, v_states - v) for u, v in zip(u_states, v_states)]
    spacing = float(np.mean([np.min(gap[gap > 0]) for gap in gaps if np.any(gap > 0)]))

    def score(item: tuple[float, float, float]) -> float:
        u, v = profile.coordinates(item[1], item[2])
        return item[0] * (1.0 + float(np.min(np.hypot(u_states - u, v_states - v))) / spacing)

    best = max(((worst(f, 1.0 / v if v > 0 else math.inf), f, 1.0 / v if v > 0 else math.inf)
                for f in focals for v in vergences), key=score)
    calibrated = max(worst(s.focal_mm, s.focus_m) for s in profile.states)
    return StateSuggestion(float(best[1]), float(best[2]), best[0], calibrated)
