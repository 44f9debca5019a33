"""The readout time a plate's observations determine: a rolling-shutter bundle adjustment after the solve.

Each observation of point ``X_j`` in frame ``k`` on row ``y`` was read at
``t_k + tau(y)``, ``tau(y) = T_r (y / (H - 1) - 1/2)``
(:mod:`camcal.geometry.rolling_shutter`), when the camera was, to first
order in ``tau`` (constant velocity over the readout; Hedborg et al. 2012),

    R(tau) = exp(tau [omega_k]_x) R_k,    c(tau) = c_k + tau v_k,

with ``R_k, c_k`` the frame's pose at its middle row and ``omega_k, v_k``
its angular and linear velocity from the neighbouring frames' poses
(:func:`camcal.geometry.rolling_shutter.camera_velocities`: central
differences, second-order one-sided at the ends). The observation is the pinhole image
of ``X_j`` from that pose (Meingast et al. 2005):

    u_jk = K_k pi(R(tau) (X_j - c(tau))),

``pi(x) = (x_1 / x_3, x_2 / x_3)``. The readout ``T_r`` is one unknown for
the plate, refined jointly with every frame's pose and every point
(Levenberg-Marquardt; the Jacobian by forward differences over its
sparsity, one evaluation per group of unknowns no residual shares; the
points eliminated from each step by their Schur complement, Triggs et al.
2000, section 6.1; the similarity the observations leave free held by the
first frame's pose and one coordinate of the last frame's centre). The
velocities are not free: they follow the poses, so the readout is fixed by
how far the frames' rows disagree with the motion between frames; the
intrinsics stay the solve's.

The adjustment starts from the solve's poses and points at readout 0. A
global-shutter solve absorbs what it can of the shutter's shear into its
path and points, and where the motion leaves the depths weakly determined
(a camera that mostly pans) it can bend them into another minimum of the
rolling-shutter model, which the adjustment then does not leave (a plate
rendered a pose per row, 30 ms: 25.8 ms and 0.385 px RMS from there, 29.6 ms
and 0.223 px from the true poses). Its residuals then disagree frame by
frame, so where the block jackknife's sigma passes the noise's
:data:`START_MISFIT` times, the adjustment is also started from starts that
need no poses but the solve's rotations:
:func:`camcal.geometry.rolling_shutter_start.linear_start` gives the
centres and points that fit the observations best, linearly, at each
readout of a grid over the frame interval (:data:`START_FRACTIONS`); each is
adjusted a few iterations with its readout held (:data:`START_ITERATIONS`,
on the longest tracks' observations, :data:`START_OBSERVATIONS`), the
cheapest adjusted on all the observations with the readout held, then free,
and of it and the first adjustment the lower cost is kept.

The constant-velocity model takes the velocities from central differences,
which slow a motion that oscillates at ``f`` Hz by ``(2 pi f dt)^2 / 6``
and make the readout high by as much (0.9 % for 1.1 Hz at 30 fps, 6.6 % for
a 3 Hz tremor), and leaves out the acceleration over the readout (0.4 % on
48 frames of a handheld walk, noise-free). The estimate is therefore moved
by one Gauss-Newton step, from the optimum, of the model whose velocities
are the fourth-order (Richardson) ones
(:func:`camcal.geometry.rolling_shutter.camera_velocities` with ``order=4``)
and whose poses also move by ``tau^2 / 2`` times the frame's angular and
linear acceleration (second differences of the neighbours' poses,
:func:`_accelerations`): ``-influence . r_4``, ``influence = J (J^T J)^-1
e_T`` and ``r_4`` the residuals there with that model (the adjustment
itself keeps the constant velocities of the central differences, whose
Jacobian touches one neighbour a side; on the synthetic plates the step
lands within 0.15 % of that model's own optimum).

Two standard deviations are computed. The observations' noise alone gives
``s^2 (J^T J)^-1_TT``, read from the points' Schur complement, ``s^2`` the
residuals' variance (sum of squares over the degrees of freedom). That
assumes the model is right and the errors white; a model that misfits
(velocities that change within a frame interval, features whose positions
err alike along a track) leaves residuals correlated within frames, which
the infinitesimal jackknife over contiguous blocks of frames sees
(:func:`_block_jackknife_sigma`). The printed one is the larger. When the
motion does not determine the readout (a camera tracking sideways or
driving straight at a constant speed: the shutter is then a deformation of
the scene the points absorb; Albl, Sugimoto & Pajdla 2016) the readout's
column of the Jacobian lies nearly in the span of the others and the
standard deviation grows without bound: the estimate is kept only when it
is below a fraction of the frame interval (:data:`DETERMINED_FRACTION`).
Neither covers an error every frame shares alike (a bias of the features'
positions that follows the motion), which no resampling of the frames can
see.

References
----------
Meingast, M., Geyer, C. & Sastry, S. (2005). Geometric Models of
Rolling-Shutter Cameras. OMNIVIS.
Hedborg, J., Forssen, P.-E., Felsberg, M. & Ringaby, E. (2012). Rolling
Shutter Bundle Adjustment. CVPR.
Albl, C., Sugimoto, A. & Pajdla, T. (2016). Degeneracies in Rolling Shutter
SfM. ECCV.
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment: A Modern Synthesis. Vision Algorithms: Theory and Practice.
Jaeckel, L. A. (1972). The infinitesimal jackknife. Bell Laboratories
Memorandum MM 72-1215-11.
Efron, B. (1982). The Jackknife, the Bootstrap and Other Resampling Plans.
SIAM.
Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals of
Statistics 9(3).
Kuensch, H. R. (1989). The jackknife and the bootstrap for general
stationary observations. Annals of Statistics 17(3).
Liang, K.-Y. & Zeger, S. L. (1986). Longitudinal data analysis using
generalized linear models. Biometrika 73(1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix, diags
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.rolling_shutter import camera_velocities
from camcal.geometry.rolling_shutter_start import linear_start, schur_solve

__all__ = ["DETERMINED_FRACTION", "JACKKNIFE_BLOCKS", "MAX_OBSERVATIONS", "MIN_TRACK", "START_FRACTIONS",
           "START_ITERATIONS", "START_MISFIT", "START_OBSERVATIONS", "ReadoutEstimate", "estimate_readout"]

#: the readout counts as determined when its standard deviation is at most this fraction of the frame interval
#: (4.2 ms at 24 fps): a readout cannot exceed the interval, and a wider one says little about it.
DETERMINED_FRACTION = 0.1
#: at most this many observations enter the adjustment: those of the points seen in the most frames, taken until
#: the next would pass it (ties by a seeded draw).
MAX_OBSERVATIONS = 20000
#: points seen in fewer frames are left out: over a few neighbouring frames their depth is barely determined,
#: which leaves the adjustment a long, curved valley to crawl along.
MIN_TRACK = 5
#: the infinitesimal jackknife over blocks (:func:`_block_jackknife_sigma`) splits the frames into this many
#: contiguous blocks (at most one a frame): its variance then has about this many less one degrees of freedom.
JACKKNIFE_BLOCKS = 10
#: other starts are tried when the first adjustment's block jackknife sigma exceeds its noise sigma this many times
#: (a misfit: a wrong minimum, or a model that does not fit). Where the model fits, the jackknife over
#: :data:`JACKKNIFE_BLOCKS` blocks scatters by about a quarter around the noise's sigma; the wrong minima measured
#: gave 1.9 to 11 times it (a plate whose velocities change within a frame interval, 1.9 too: searched in vain).
START_MISFIT = 1.5
#: the readouts, as fractions of the frame interval, at which the adjustment is also started from the solve's
#: rotations with the centres and points the linear constraints give there
#: (:func:`camcal.geometry.rolling_shutter_start.linear_start`; module notes).
START_FRACTIONS = np.arange(-4, 5) / 4
#: each start is adjusted this many iterations with its readout held before the best one is continued.
START_ITERATIONS = 3
#: the starts are ranked on the observations of the longest tracks, at most this many (:func:`_chosen_observations`).
START_OBSERVATIONS = 5000


@dataclass(frozen=True)
class ReadoutEstimate:
    """The readout time a plate's observations determine, or that they do not.

    Attributes
    ----------
    readout_s, sigma_s : float
        The estimate (signed: negative is a bottom-to-top readout) and its standard deviation, in seconds: the
        larger of ``noise_sigma_s`` and ``jackknife_sigma_s``.
    noise_sigma_s : float
        The standard deviation the observations' noise alone gives (the inverse Gauss-Newton matrix).
    jackknife_sigma_s : float
        The infinitesimal jackknife's over contiguous blocks of frames: it also sees the model's misfit.
    determined : bool
        ``sigma_s`` at most :data:`DETERMINED_FRACTION` of the frame interval; otherwise ``readout_s`` means nothing.
    limit_s : float
        That bound.
    rms_px : float
        The observations' RMS residual after the adjustment.
    n_frames, n_points, n_observations : int
        What entered it.
    """

    readout_s: float
    sigma_s: float
    noise_sigma_s: float
    jackknife_sigma_s: float
    determined: bool
    limit_s: float
    rms_px: float
    n_frames: int
    n_points: int
    n_observations: int


def estimate_readout(K: ArrayLike, height: int, rotations: ArrayLike, centres: ArrayLike, times: ArrayLike,
                     points: ArrayLike, frame_of: ArrayLike, point_of: ArrayLike, pixels: ArrayLike,
                     rows: ArrayLike | None = None, *, max_observations: int = MAX_OBSERVATIONS,
                     seed: int = 0
                     ) -> ReadoutEstimate:
    """Refine poses, points and one readout time on the rolling-shutter model (module notes) and judge it.

    Parameters
    ----------
    K : array_like, shape (3, 3) or (N, 3, 3)
        The pinhole intrinsics of every frame (held).
    height : int
        Image rows.
    rotations, centres : array_like, shapes (N, 3, 3), (N, 3)
        The frames' world -> camera rotations and centres from the global-shutter solve (the start).
    times : array_like, shape (N,)
        The frames' times in seconds, strictly increasing.
    points : array_like, shape (M, 3)
        The solved points (the start).
    frame_of, point_of : array_like of int, shape (P,)
        Each observation's frame and point.
    pixels : array_like, shape (P, 2)
        Each observation in undistorted pinhole pixels of ``K`` (pixel centres at integers).
    rows : array_like, shape (P,), optional
        The sensor row each observation was read on (its distorted row; default ``pixels[:, 1]``).
    max_observations : int
        At most this many observations are adjusted (:data:`MAX_OBSERVATIONS`).
    seed : int
        Seeds the choice among equally long tracks.

    Returns
    -------
    ReadoutEstimate
    """
    R0 = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    c0 = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    X0 = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    frame_of = np.asarray(frame_of, dtype=np.intp).reshape(-1)
    point_of = np.asarray(point_of, dtype=np.intp).reshape(-1)
    uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    y = uv[:, 1] if rows is None else np.asarray(rows, dtype=np.float64).reshape(-1)
    if not (len(frame_of) == len(point_of) == len(uv) == len(y)):
        raise CamcalError("observations' frames, points, pixels and rows differ in length")
    if len(R0) < 3:
        raise CamcalError(f"estimating a readout time needs at least 3 solved frames, got {len(R0)}")
    camera_velocities(R0, c0, t)  # checks the lengths and the times' order
    Ks = np.broadcast_to(np.asarray(K, dtype=np.float64), (len(R0), 3, 3))
    keep = _chosen_observations(point_of, len(X0), max_observations, seed)
    frame_of, point_of, uv, y = frame_of[keep], point_of[keep], uv[keep], y[keep]
    if not keep.any():
        raise CamcalError(f"no point is seen in {MIN_TRACK} frames or more")
    used_points, point_of = np.unique(point_of, return_inverse=True)
    X0 = X0[used_points]
    n_frames, n_points, n_obs = len(R0), len(X0), len(uv)
    row_fraction = y / max(int(height) - 1, 1) - 0.5
    focal, centre = Ks[frame_of][:, [0, 1], [0, 1]], Ks[frame_of][:, :2, 2]
    # the solve's poses and points adjusted with the readout free; where the block jackknife sees a misfit beyond the
    # noise's, other starts too: the solve's rotations with the centres and points the linear constraints give at
    # each readout of a grid over the frame interval, ranked by their cost after a few iterations with that readout
    # held (on the longest tracks' observations), the best adjusted on all of them with the readout held, then free;
    # the lower cost is kept (module notes)
    model = _Model(focal, centre, t, frame_of, point_of, uv, row_fraction)
    fit = model.adjust(R0, c0, X0, 0.0)
    sigmas = _sigmas(fit, frame_of, n_frames)
    if sigmas[2] > START_MISFIT * sigmas[1]:
        seeded = _seeded_fit(model, R0, 1e3 * float(np.median(np.diff(t))), seed)
        if seeded is not None and seeded.cost < fit.cost:
            fit, sigmas = seeded, _sigmas(seeded, frame_of, n_frames)
    x, residuals, cost = fit.x, fit.residuals, fit.cost
    influence, noise_sigma_ms, jackknife_sigma_ms = sigmas
    # the Gauss-Newton step of the fourth-order velocities and the accelerations from the optimum (module notes)
    readout_ms = float(x[0] - influence @ residuals(x, order=4))
    sigma_s = max(noise_sigma_ms, jackknife_sigma_ms) * 1e-3
    if not np.isfinite(readout_ms):
        readout_ms, sigma_s = float(x[0]), np.inf
    limit = DETERMINED_FRACTION * float(np.median(np.diff(t)))
    return ReadoutEstimate(readout_ms * 1e-3, sigma_s, noise_sigma_ms * 1e-3, jackknife_sigma_ms * 1e-3,
                           bool(sigma_s <= limit), limit, float(np.sqrt(cost / max(n_obs, 1))), n_frames, n_points,
                           n_obs)


@dataclass(frozen=True)
class _Fit:
    """A Levenberg-Marquardt adjustment's solution ``x``, residuals ``r``, Jacobian ``J``, ``A = J^T J`` (both over
    the ``free`` unknowns), the residual function (of ``x`` and the velocities' order) and the poses and points."""

    x: NDArray[np.float64]
    r: NDArray[np.float64]
    J: object
    A: object
    free: NDArray[np.bool_]
    residuals: Callable[..., NDArray[np.float64]]
    state: Callable[[], tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]

    @property
    def cost(self) -> float:
        return float(self.r @ self.r)


class _Model:
    """The rolling-shutter residuals of a set of observations (module notes), adjusted from a start."""

    def __init__(self, focal: NDArray[np.float64], centre: NDArray[np.float64], times: NDArray[np.float64],
                 frame_of: NDArray[np.intp], point_of: NDArray[np.intp], pixels: NDArray[np.float64],
                 row_fraction: NDArray[np.float64]) -> None:
        self.focal, self.centre, self.times, self.frame_of, self.point_of = focal, centre, times, frame_of, point_of
        self.pixels, self.row_fraction = pixels, row_fraction
        self.n_frames, self.n_points = len(times), int(point_of.max()) + 1
        self.pattern = _sparsity(frame_of, point_of, self.n_frames, self.n_points)
        self.groups = _column_groups(self.n_frames, self.n_points)

    def adjust(self, rotations: NDArray[np.float64], centres: NDArray[np.float64], points: NDArray[np.float64],
               readout_ms: float, *, hold_readout: bool = False, max_iterations: int = 30, jacobian: bool = True
               ) -> _Fit:
        """Levenberg-Marquardt from these poses, points and readout (ms); the unknowns ``x`` are the readout in ms,
        then the frames' rotation vectors and centres' and the points' offsets from the start (``J``, ``A`` None
        without ``jacobian``)."""
        n_frames, frame_of, point_of = self.n_frames, self.frame_of, self.point_of

        def state(x: NDArray[np.float64]):
            rotation = np.einsum("nij,njk->nik",
                                 Rotation.from_rotvec(x[1:1 + 3 * n_frames].reshape(-1, 3)).as_matrix(), rotations)
            return (rotation, centres + x[1 + 3 * n_frames:1 + 6 * n_frames].reshape(-1, 3),
                    points + x[1 + 6 * n_frames:].reshape(-1, 3))

        def residuals(x: NDArray[np.float64], order: int = 2) -> NDArray[np.float64]:
            readout = x[0] * 1e-3  # the unknown is in ms: its step is then on the poses' scale
            rotation, c, X = state(x)
            omega, velocity = camera_velocities(rotation, c, self.times, order=order)
            tau = (readout * self.row_fraction)[:, None]
            turn, shift = tau * omega[frame_of], tau * velocity[frame_of]
            if order == 4:  # and the acceleration over the readout (module notes)
                angular, linear = _accelerations(rotation, c, self.times)
                turn, shift = turn + tau ** 2 / 2 * angular[frame_of], shift + tau ** 2 / 2 * linear[frame_of]
            at_frame = np.einsum("nij,nj->ni", rotation[frame_of], X[point_of] - c[frame_of] - shift)
            camera = np.einsum("nij,nj->ni", Rotation.from_rotvec(turn).as_matrix(), at_frame)
            projected = camera[:, :2] / camera[:, 2:3] * self.focal + self.centre
            return (projected - self.pixels).ravel()

        depth = float(np.median(np.linalg.norm(points[point_of] - centres[frame_of], axis=1)))
        steps = np.r_[1e-4, np.full(3 * n_frames, 1e-6), np.full(3 * n_frames + 3 * self.n_points, 1e-6 * depth)]
        free = _gauge_free(centres, self.n_points)
        free[0] = not hold_readout
        x, r, J, A = _levenberg_marquardt(residuals, self.pattern, self.groups, steps, free, 3 * self.n_points,
                                          max_iterations, readout_ms, jacobian)
        return _Fit(x, r, J, A, free, residuals, lambda: state(x))


def _sigmas(fit: _Fit, frame_of: NDArray[np.intp], n_frames: int) -> tuple[NDArray[np.float64], float, float]:
    """The readout's influence ``J (J^T J)^-1 e_T`` on the residuals and its standard deviations (ms): the
    observations' noise's, ``s^2 (J^T J)^-1_TT``, and the block jackknife's (module notes)."""
    variance = fit.cost / max(fit.r.size - int(fit.free.sum()), 1)
    n_points = int(fit.free.size - 1 - 6 * n_frames)  # the points' unknowns come last
    try:
        readout_column = schur_solve(fit.A, np.eye(fit.A.shape[0], 1).ravel(), n_points)  # (A^-1)[:, 0]
    except np.linalg.LinAlgError:  # exactly singular: nothing determines the readout
        readout_column = np.full(fit.A.shape[0], np.inf)
    influence = fit.J @ readout_column  # d(readout) / d(residuals) of a Gauss-Newton step, up to the sign
    return (influence, float(np.sqrt(variance * abs(readout_column[0]))),
            _block_jackknife_sigma(influence, fit.r, frame_of, n_frames))


def _seeded_fit(model: _Model, rotations: NDArray[np.float64], interval_ms: float, seed: int) -> _Fit | None:
    """``model``'s adjustment from the best of the linear starts
    (:func:`camcal.geometry.rolling_shutter_start.linear_start`) with ``rotations`` at the readouts
    :data:`START_FRACTIONS` of the frame interval, each ranked by its cost after :data:`START_ITERATIONS` with its
    readout held, on the observations of the longest tracks (:data:`START_OBSERVATIONS`); None if none could be
    made."""
    focal, centre, times, frame_of, point_of = model.focal, model.centre, model.times, model.frame_of, model.point_of
    pixels, row_fraction, n_points = model.pixels, model.row_fraction, model.n_points
    ranked = _chosen_observations(point_of, n_points, START_OBSERVATIONS, seed)
    ranked_points, ranked_point_of = np.unique(point_of[ranked], return_inverse=True)
    ranking = _Model(focal[ranked], centre[ranked], times, frame_of[ranked], ranked_point_of, pixels[ranked],
                     row_fraction[ranked])
    best = (np.inf,)
    for readout in START_FRACTIONS * interval_ms:
        try:
            c, X = linear_start(focal, centre, rotations, times, frame_of, point_of, pixels,
                                 row_fraction * readout * 1e-3, n_points)
        except np.linalg.LinAlgError:  # a point the start's rays do not fix
            continue
        cost = ranking.adjust(rotations, c, X[ranked_points], readout, hold_readout=True,
                              max_iterations=START_ITERATIONS, jacobian=False).cost
        best = min(best, (cost, readout, c, X), key=lambda entry: entry[0])
    if not np.isfinite(best[0]):
        return None
    held = model.adjust(rotations, best[2], best[3], best[1], hold_readout=True, max_iterations=START_ITERATIONS,
                        jacobian=False)
    return model.adjust(*held.state(), best[1])


def _accelerations(rotations: NDArray[np.float64], centres: NDArray[np.float64], times: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each frame's angular (camera axes, rad/s^2) and linear acceleration from its neighbours' poses: the second
    differences ``2 (d_+ / h_+ - d_- / h_-) / (h_+ + h_-)``, ``d_+ = log(R_next R^T)`` or ``c_next - c`` over
    ``h_+`` and ``d_-`` the same from the previous frame; at an end, its neighbour's."""
    n = len(times)
    angular, linear = np.zeros((n, 3)), np.zeros((n, 3))
    if n < 3:
        return angular, linear
    steps = np.diff(times)[:, None]
    turns = Rotation.from_matrix(np.einsum("nij,nkj->nik", rotations[1:], rotations[:-1])).as_rotvec() / steps
    moves = np.diff(centres, axis=0) / steps
    span = (steps[1:] + steps[:-1]) / 2
    angular[1:-1], linear[1:-1] = np.diff(turns, axis=0) / span, np.diff(moves, axis=0) / span
    angular[[0, -1]], linear[[0, -1]] = angular[[1, -2]], linear[[1, -2]]
    return angular, linear


def _block_jackknife_sigma(influence: NDArray[np.float64], r: NDArray[np.float64], frame_of: NDArray[np.intp],
                           n_frames: int, n_blocks: int = JACKKNIFE_BLOCKS) -> float:
    """The readout's standard deviation by the infinitesimal jackknife over contiguous blocks of frames (ms).

    Leaving out block ``b``'s observations moves the readout, to first order, by its share of the
    Gauss-Newton step, ``-sum_(i in b) influence_i r_i`` (``influence = J (J^T J)^-1 e_T``, the readout's
    column); over ``g`` blocks the variance is ``g / (g - 1) sum_b (sum_(i in b) influence_i r_i)^2``: the
    infinitesimal jackknife (Jaeckel 1972; Efron 1982, section 6), over contiguous blocks so that errors
    correlated between neighbouring frames stay in one block (Kuensch 1989), which is the cluster-robust
    ("sandwich") variance of Liang & Zeger (1986). With white noise of one variance it is the inverse
    Gauss-Newton matrix's; a model that misfits frame by frame widens it.
    """
    g = min(n_blocks, n_frames)
    if g < 2:
        return np.inf
    block_of = np.repeat(np.arange(g), [len(b) for b in np.array_split(np.arange(n_frames), g)])
    share = influence * r
    per_block = np.bincount(block_of[frame_of], share[0::2] + share[1::2], minlength=g)
    return float(np.sqrt(g / (g - 1) * np.sum(per_block ** 2)))


def _chosen_observations(point_of: NDArray[np.intp], n_points: int, max_observations: int, seed: int
                         ) -> NDArray[np.bool_]:
    """The observations of the points seen in :data:`MIN_TRACK` frames or more, the longest tracks first, until
    their number would pass ``max_observations``."""
    counts = np.bincount(point_of, minlength=n_points)
    tie = np.random.default_rng(seed).permutation(n_points)
    order = np.lexsort((tie, -counts))
    order = order[counts[order] >= MIN_TRACK]
    chosen = order[np.cumsum(counts[order]) <= max_observations]
    return np.isin(point_of, chosen)


def _sparsity(frame_of: NDArray[np.intp], point_of: NDArray[np.intp], n_frames: int, n_points: int):
    """Which unknowns each residual depends on: the readout, its frame's and neighbours' poses, its point."""
    rows = np.arange(2 * len(frame_of))
    obs = rows // 2
    columns = [np.zeros_like(rows)]
    for neighbour in (frame_of - 1, frame_of, frame_of + 1):
        frame = np.clip(neighbour, 0, n_frames - 1)[obs]
        columns += [1 + 3 * frame + k for k in range(3)] + [1 + 3 * n_frames + 3 * frame + k for k in range(3)]
    columns += [1 + 6 * n_frames + 3 * point_of[obs] + k for k in range(3)]
    structure = coo_matrix((np.ones(len(rows) * len(columns), dtype=np.int8),
                            (np.tile(rows, len(columns)), np.concatenate(columns))),
                           shape=(len(rows), 1 + 6 * n_frames + 3 * n_points)).tocsr()
    structure.sum_duplicates()  # an end frame is its own neighbour
    return structure.tocoo()


def _column_groups(n_frames: int, n_points: int) -> NDArray[np.intp]:
    """Each unknown's finite-difference group: no residual depends on two unknowns of one group (frames 3 apart
    share one, every point's x, y or z share one), so one evaluation per group gives all their columns."""
    frame = np.arange(n_frames) % 3
    pose = lambda first: (1 + 6 * frame[:, None] + first + np.arange(3)).ravel()  # noqa: E731
    return np.r_[0, pose(0), pose(3), np.tile(19 + np.arange(3), n_points)].astype(np.intp)


def _gauge_free(centres: NDArray[np.float64], n_points: int) -> NDArray[np.bool_]:
    """The unknowns left free: all but the first frame's pose and the last frame's centre along the path's
    largest coordinate (the similarity the observations do not fix: rotation, translation and scale)."""
    n_frames = len(centres)
    free = np.ones(1 + 6 * n_frames + 3 * n_points, dtype=bool)
    free[[1, 2, 3]] = False
    free[1 + 3 * n_frames + np.arange(3)] = False
    axis = int(np.argmax(np.abs(centres[-1] - centres[0])))
    free[1 + 3 * n_frames + 3 * (n_frames - 1) + axis] = False
    return free


def _jacobian(residuals, x: NDArray[np.float64], r: NDArray[np.float64], pattern, groups: NDArray[np.intp],
              steps: NDArray[np.float64]):
    """The residuals' Jacobian on ``pattern`` by forward differences, one evaluation per column group."""
    differences = np.empty((groups.max() + 1, r.size))
    for group in range(groups.max() + 1):
        moved = x + np.where(groups == group, steps, 0.0)
        differences[group] = residuals(moved) - r
    rows, cols = pattern.row, pattern.col
    values = differences[groups[cols], rows] / steps[cols]
    return coo_matrix((values, (rows, cols)), shape=pattern.shape).tocsc()


def _levenberg_marquardt(residuals, pattern, groups, steps, free, n_points: int, max_iterations: int = 30,
                         readout_ms: float = 0.0, jacobian: bool = True):
    """Minimise ``|residuals(x)|^2`` from ``x = (readout_ms, 0, ...)`` over the ``free`` unknowns
    (Levenberg-Marquardt on the sparse normal equations, damping ``lambda diag(J^T J)``, the last ``n_points``
    unknowns, 3 a point, eliminated by :func:`camcal.geometry.rolling_shutter_start.schur_solve`); the solution, its
    residuals, ``J`` and ``J^T J`` there (None without ``jacobian``).

    It stops when a step lowers the chi-square (the cost over the residuals' variance) by less than 0.01: the
    Gauss-Newton step then left every unknown within about a tenth of its standard deviation of the optimum.
    """
    x = np.zeros(free.size)
    x[0] = readout_ms
    r = residuals(x)
    cost, damping = float(r @ r), 1e-4
    dof = max(r.size - int(free.sum()), 1)
    for _ in range(max_iterations):
        J = _jacobian(residuals, x, r, pattern, groups, steps)[:, free]
        A, gradient = (J.T @ J).tocsc(), J.T @ r
        while damping < 1e8:
            try:
                step = schur_solve(A + diags(damping * A.diagonal()), -gradient, n_points)
            except np.linalg.LinAlgError:
                step = np.full(gradient.size, np.nan)
            trial = x.copy()
            trial[free] += step
            r_trial = residuals(trial)
            cost_trial = float(r_trial @ r_trial)
            if np.isfinite(cost_trial) and cost_trial < cost:
                break
            damping *= 10.0
        else:
            break
        chi_square_drop = (cost - cost_trial) / (cost_trial / dof)
        x, r, cost, damping = trial, r_trial, cost_trial, max(damping / 10.0, 1e-9)
        if chi_square_drop < 0.01:
            break
    if not jacobian:
        return x, r, None, None
    J = _jacobian(residuals, x, r, pattern, groups, steps)[:, free]
    return x, r, J, (J.T @ J).tocsc()
