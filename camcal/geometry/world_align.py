"""The world of a reconstruction set from constraints: up axis, ground plane, origin, heading and scale.

Structure from motion fixes its world only up to a similarity (7 degrees of
freedom: rotation, translation, scale). A matchmove wants the set's: the
ground at ``z = 0`` with ``+z`` up (Blender's convention; the rig file's
world is right-handed), the origin at a chosen point, lengths in a known unit.
:func:`world_from_constraints` builds the similarity ``X_new = s R X + t``
that does it from

- an up direction (the normal of the ground plane, :func:`ground_plane_RANSAC`,
  or the cameras' mean up, :func:`mean_camera_up`), which ``R`` turns to
  ``+z``;
- a heading: a direction whose ground projection ``R`` turns to ``+y``
  (the first camera's viewing direction by default: the shot looks down
  ``+y``, Blender's front view);
- an origin, which goes to ``(0, 0, 0)``;
- a scale: two points and their known distance.

Or, all at once, from a calibration board lying in the set
(:func:`world_from_board`): its corners triangulated from the solved cameras
(:func:`triangulate_corners`) are matched to the board's own coordinates by
a similarity, so that the board's plane becomes the ground, its first inner
corner the origin, its columns ``+x`` and its square size the unit.

Pure maths on arrays; the solve applies the result to its cameras and points
(:mod:`camcal.pipelines.solve_world`).

References
----------
Fischler, M. A. & Bolles, R. C. (1981). Random Sample Consensus: A Paradigm
for Model Fitting with Applications to Image Analysis and Automated
Cartography. Communications of the ACM 24(6).
Umeyama, S. (1991). Least-Squares Estimation of Transformation Parameters
Between Two Point Patterns. IEEE TPAMI 13(4) (the similarity ``s R X + t``).
Rousseeuw, P. J. (1984). Least Median of Squares Regression. Journal of the
American Statistical Association 79(388).
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry in Computer Vision,
2nd ed., section 12.2 (linear triangulation); section 5.2 (the covariance of a
least-squares estimate, ``sigma^2 (J^T J)^-1``).
Pathak, K., Birk, A., Vaskevicius, N. & Poppinga, J. (2010). Fast Registration
Based on Noisy Planes With Unknown Correspondences for 3-D Mapping. IEEE
Transactions on Robotics 26(3) (the covariance of a fitted plane's normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.camera import similarity_Umeyama1991

__all__ = [
    "MAX_GROUND_TILT_DEG",
    "BoardWorld",
    "GroundPlane",
    "Similarity",
    "ground_plane_RANSAC",
    "mean_camera_up",
    "plane_normal_covariance",
    "point_under",
    "triangulate_corners",
    "world_from_board",
    "world_from_constraints",
]

#: the ground's normal may lean this far from the cameras' up (degrees): half way between the floor (0 deg
#: from a level camera's up) and a wall (90 deg), so a camera pitched by less than that still finds the floor.
MAX_GROUND_TILT_DEG = 45.0


@dataclass(frozen=True)
class Similarity:
    """``X_new = s R X + t``: a 3D similarity (rotation ``R``, scale ``s > 0``, translation ``t``).

    Attributes
    ----------
    s : float
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)

    Examples
    --------
    >>> S = Similarity(2.0, np.eye(3), np.array([0.0, 0.0, 1.0]))
    >>> S.apply([[1.0, 0.0, 0.0]]).tolist(), S.inverse().apply(S.apply([[1.0, 2.0, 3.0]])).tolist()
    ([[2.0, 0.0, 1.0]], [[1.0, 2.0, 3.0]])
    """

    s: float
    R: NDArray[np.float64]
    t: NDArray[np.float64]

    def __post_init__(self) -> None:
        R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.t, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.s) and self.s > 0):
            raise CamcalError(f"a similarity's scale must be positive and finite, got {self.s!r}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise CamcalError("a similarity's R must be a rotation")
        object.__setattr__(self, "s", float(self.s))
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    def apply(self, X: ArrayLike) -> NDArray[np.float64]:
        """The points ``X`` (shape (N, 3)) in the new world."""
        return self.s * np.asarray(X, dtype=np.float64).reshape(-1, 3) @ self.R.T + self.t

    def inverse(self) -> Similarity:
        """``X = (R^T (X_new - t)) / s``."""
        return Similarity(1.0 / self.s, self.R.T, -self.R.T @ self.t / self.s)

    def pose(self, R_cam: ArrayLike, c: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A camera's pose (``R`` world -> camera, centre ``c``) in the new world: ``R R_S^T``, ``s R_S c + t``."""
        return np.asarray(R_cam, dtype=np.float64) @ self.R.T, self.apply(c)[0]


@dataclass(frozen=True)
class GroundPlane:
    """A plane ``n . X = d`` (``n`` unit) and the points that lie on it.

    Attributes
    ----------
    normal : ndarray, shape (3,)
        Unit normal, on the side of the cameras when they were given.
    offset : float
        ``d``.
    inliers : ndarray of bool, shape (N,)
        The points within the RANSAC threshold of the plane.
    threshold : float
        That threshold (the points' units).
    normal_covariance : ndarray, shape (3, 3)
        The normal's covariance from its inliers' scatter (:func:`plane_normal_covariance`; NaN with only 3).
    """

    normal: NDArray[np.float64]
    offset: float
    inliers: NDArray[np.bool_]
    threshold: float
    normal_covariance: NDArray[np.float64]

    @property
    def tilt_sigma_deg(self) -> float:
        """The normal's one-sigma tilt, degrees: the RMS angle of its error, ``sqrt(trace(normal_covariance))``."""
        return float(np.degrees(np.sqrt(np.trace(self.normal_covariance))))


def _unit(v: ArrayLike, what: str) -> NDArray[np.float64]:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(v))
    if not np.isfinite(norm) or norm < 1e-12:
        raise CamcalError(f"{what} has no direction (length {norm:.3g})")
    return v / norm


def _plane_through(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Least-squares plane through ``points`` (the smallest singular vector of the centred points)."""
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre)[2][-1]
    return normal, float(normal @ centre)


def plane_normal_covariance(points: ArrayLike) -> NDArray[np.float64]:
    """The covariance of the normal of the least-squares plane through ``points`` (radians squared).

    The centred points' scatter ``sum (X - c)(X - c)^T`` has eigenvalues
    ``l1 >= l2 >= l3`` and eigenvectors ``u, v, n`` (``n`` the normal). Tilting
    the normal to ``n + a u + b v`` changes each point's distance by
    ``a (X - c).u + b (X - c).v``, so the Jacobian's normal matrix of
    ``(a, b)`` is ``diag(l1, l2)`` and the covariance of the estimate is
    ``sigma^2 (J^T J)^-1`` (Hartley & Zisserman 2004, 5.2; Pathak et al.
    2010): ``sigma^2 (u u^T / l1 + v v^T / l2)``, the points' spread off the
    plane ``sigma^2 = l3 / (N - 3)`` (three parameters fitted).

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The plane's points (its inliers).

    Returns
    -------
    ndarray, shape (3, 3)
        In the points' axes; NaN with ``N <= 3`` (no spread to measure).

    Examples
    --------
    >>> grid = np.array([[x, y, 0.01 * (-1) ** (x + y)] for x in range(10) for y in range(10)], dtype=float)
    >>> C = plane_normal_covariance(grid)  # sigma^2 = 100 * 0.01^2 / 97, l1 = l2 = 10 * 82.5
    >>> [round(float(np.degrees(np.sqrt(abs(C[k, k])))), 4) for k in range(3)]  # the normal: z
    [0.0203, 0.0203, 0.0]
    """
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(X) <= 3:
        return np.full((3, 3), np.nan)
    _, singular, axes = np.linalg.svd(X - X.mean(axis=0), full_matrices=False)
    spread = singular**2
    sigma2 = spread[2] / (len(X) - 3)
    return sigma2 * (np.outer(axes[0], axes[0]) / spread[0] + np.outer(axes[1], axes[1]) / spread[1])


def ground_plane_RANSAC(points: ArrayLike, threshold: float | None = None, iterations: int = 500, seed: int = 0,
                        cameras: ArrayLike | None = None, up_hint: ArrayLike | None = None,
                        max_tilt_deg: float = MAX_GROUND_TILT_DEG) -> GroundPlane:
    """The dominant plane of a point cloud (Fischler & Bolles 1981), refitted to its inliers.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Sparse points (N >= 3).
    threshold : float, optional
        Inlier distance; default 1 % of the median distance of the points to
        their median (a scale-free choice: the reconstruction's units are
        arbitrary).
    iterations : int
        Random triples tried.
    seed : int
        Seeds the triples: the same points give the same plane.
    cameras : array_like, shape (M, 3), optional
        Camera centres: the normal is turned towards their majority (the
        cameras stand above the ground).
    up_hint : array_like, shape (3,), optional
        A rough up (e.g. :func:`mean_camera_up`): only planes whose normal is
        within ``max_tilt_deg`` of it count, so that a wall with more points
        than the floor is not taken for the ground.
    max_tilt_deg : float
        That tolerance (degrees).

    Returns
    -------
    GroundPlane

    Notes
    -----
    Of all triples, the plane with the most points within ``threshold``
    wins (the first in draw order on a tie); its inliers are then fitted by
    least squares (total least squares: the normal is the smallest right
    singular vector of the centred inliers), the threshold narrowed to
    ``4 sigma`` of the inliers' distances (sigma from their median absolute
    deviation, 1.4826 MAD) when that is narrower, and the plane fitted again
    to the inliers that leaves; its normal's covariance is that of the fit to
    them (:func:`plane_normal_covariance`).
    """
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    X = X[np.all(np.isfinite(X), axis=1)]
    if len(X) < 3:
        raise CamcalError(f"a ground plane needs at least 3 points, got {len(X)}")
    if threshold is None:
        threshold = 0.01 * float(np.median(np.linalg.norm(X - np.median(X, axis=0), axis=1)))
    if not threshold > 0:
        raise CamcalError(f"the ground plane's inlier threshold must be positive, got {threshold!r}")
    hint = None if up_hint is None else _unit(up_hint, "the up hint")
    min_cos = float(np.cos(np.radians(max_tilt_deg)))
    rng = np.random.default_rng(seed)
    best_count, best = -1, None
    for _ in range(int(iterations)):
        a, b, c = X[rng.choice(len(X), 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-12:
            continue
        normal /= norm
        if hint is not None and abs(normal @ hint) < min_cos:
            continue
        count = int(np.count_nonzero(np.abs((X - a) @ normal) < threshold))
        if count > best_count:
            best_count, best = count, (normal, float(normal @ a))
    if best is None:
        within = "" if hint is None else f" within {max_tilt_deg:g} deg of level"
        raise CamcalError(f"no plane{within} through the points (collinear, or no ground seen)")
    inliers = np.abs(X @ best[0] - best[1]) < threshold
    normal, offset = _plane_through(X[inliers])
    distance = np.abs(X @ normal - offset)
    spread = 4.0 * 1.4826 * float(np.median(distance[distance < threshold]))
    if 0 < spread < threshold:
        threshold = spread
        normal, offset = _plane_through(X[distance < threshold])
    inliers = np.abs(X @ normal - offset) < threshold
    if cameras is not None:
        side = np.asarray(cameras, dtype=np.float64).reshape(-1, 3) @ normal - offset
        if np.sum(np.sign(side)) < 0:
            normal, offset = -normal, -offset
    return GroundPlane(normal, offset, inliers, float(threshold), plane_normal_covariance(X[inliers]))


def mean_camera_up(rotations: ArrayLike) -> NDArray[np.float64]:
    """The cameras' mean up direction in the world: the mean of ``-R^T e_y`` (camera y points down).

    Parameters
    ----------
    rotations : array_like, shape (M, 3, 3)
        Each camera's ``R`` (world -> camera).
    """
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    if not len(R):
        raise CamcalError("the mean camera up needs at least one camera")
    return _unit(-R[:, 1, :].mean(axis=0), "the cameras' mean up")


def point_under(plane: GroundPlane, X: ArrayLike) -> NDArray[np.float64]:
    """The foot of ``X`` on the plane: ``X - (n . X - d) n``."""
    X = np.asarray(X, dtype=np.float64).reshape(3)
    return X - (plane.normal @ X - plane.offset) * plane.normal


def _rotation_to(up: NDArray[np.float64], heading: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation taking ``up`` to ``+z`` and the ground projection of ``heading`` to ``+y``."""
    z = _unit(up, "the up direction")
    y = heading - (heading @ z) * z
    if np.linalg.norm(y) < 1e-9 * max(np.linalg.norm(heading), 1e-300):
        raise CamcalError("the heading is parallel to the up direction: it gives no direction on the ground")
    y = _unit(y, "the heading on the ground")
    x = np.cross(y, z)
    return np.stack([x, y, z])  # rows: the old coordinates of the new axes


def world_from_constraints(up: ArrayLike | None, heading: ArrayLike, origin: ArrayLike | None = None,
                           scale: tuple[ArrayLike, ArrayLike, float] | None = None) -> Similarity:
    """The similarity ``X_new = s R X + t`` that puts a reconstruction in the set's world.

    Parameters
    ----------
    up : array_like, shape (3,), or None
        The world's up, in the reconstruction's coordinates: becomes ``+z``;
        None keeps the reconstruction's axes (``R = I``).
    heading : array_like, shape (3,)
        A direction (e.g. the first camera's viewing axis ``R[2]``) whose
        projection on the ground becomes ``+y`` (unused without ``up``).
    origin : array_like, shape (3,), optional
        The point that becomes ``(0, 0, 0)``; default: the reconstruction's origin stays.
    scale : (A, B, distance), optional
        Two points (reconstruction coordinates) and their distance in the
        new world's units: ``s = distance / |B - A|``; default ``s = 1``.

    Returns
    -------
    Similarity

    Examples
    --------
    >>> S = world_from_constraints([0, 0, 2], [0, 1, 0], [1, 1, 1], ([0, 0, 0], [0, 0, 4], 2.0))
    >>> S.s, S.apply([[1, 1, 1]]).tolist()
    (0.5, [[0.0, 0.0, 0.0]])
    """
    R = np.eye(3) if up is None else _rotation_to(np.asarray(up, dtype=np.float64).reshape(3),
                                                  np.asarray(heading, dtype=np.float64).reshape(3))
    s = 1.0
    if scale is not None:
        A, B, distance = scale
        length = float(np.linalg.norm(np.asarray(B, dtype=np.float64) - np.asarray(A, dtype=np.float64)))
        if not (np.isfinite(distance) and distance > 0):
            raise CamcalError(f"the known distance must be positive, got {distance!r}")
        if not length > 0:
            raise CamcalError("the two scale points are the same point: their distance sets no scale")
        s = float(distance) / length
    t = np.zeros(3) if origin is None else -s * R @ np.asarray(origin, dtype=np.float64).reshape(3)
    return Similarity(s, R, t)


def triangulate_corners(rotations: ArrayLike, translations: ArrayLike, ids: list[ArrayLike],
                        rays: list[ArrayLike]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each corner seen in two views or more, triangulated linearly (Hartley & Zisserman 2004, 12.2).

    Parameters
    ----------
    rotations, translations : array_like, shapes (V, 3, 3), (V, 3)
        Each view's pose ``x_cam = R X + t``.
    ids : list of array_like of int
        Per view, the corners it saw (ids of the board's points).
    rays : list of array_like, shape (M_v, 2)
        Per view, those corners' normalised image coordinates ``(x / z, y / z)`` (lens distortion removed; a
        non-finite one is left out).

    Returns
    -------
    ids : ndarray of int, shape (N,)
        The corners seen at least twice, increasing.
    points : ndarray, shape (N, 3)
        Their positions: the smallest right singular vector of the stacked
        rows ``x P_3 - P_1``, ``y P_3 - P_2`` of every view ``P = [R | t]``
        (each row scaled to unit length), exact for exact rays.
    """
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    if not (len(R) == len(t) == len(ids) == len(rays)):
        raise CamcalError("triangulation needs one pose, one id list and one ray list per view")
    rows: dict[int, list[NDArray[np.float64]]] = {}
    for view, (view_ids, view_rays) in enumerate(zip(ids, rays)):
        P = np.column_stack([R[view], t[view]])
        for corner, (x, y) in zip(np.asarray(view_ids, dtype=np.int64), np.asarray(view_rays, dtype=np.float64)):
            if not (np.isfinite(x) and np.isfinite(y)):  # a pixel the lens model cannot unproject
                continue
            for row in (x * P[2] - P[0], y * P[2] - P[1]):
                rows.setdefault(int(corner), []).append(row / np.linalg.norm(row))
    seen = np.array(sorted(corner for corner, stacked in rows.items() if len(stacked) >= 4), dtype=np.int64)
    points = np.empty((len(seen), 3))
    for k, corner in enumerate(seen):
        X = np.linalg.svd(np.array(rows[int(corner)]))[2][-1]
        points[k] = X[:3] / X[3]
    return seen, points


@dataclass(frozen=True)
class BoardWorld:
    """A world set from a board (:func:`world_from_board`).

    Attributes
    ----------
    similarity : Similarity
        Reconstruction -> the board's world.
    n_corners : int
        The corners the similarity was fitted to.
    rms : float
        Their residual after the fit, RMS, in the board's units.
    """

    similarity: Similarity
    n_corners: int
    rms: float


def world_from_board(object_points: ArrayLike, rotations: ArrayLike, translations: ArrayLike,
                     ids: list[ArrayLike], rays: list[ArrayLike], seed: int = 0, trials: int = 200) -> BoardWorld:
    """The similarity that puts a reconstruction in the world of a board its cameras saw.

    1. The corners seen twice or more are triangulated
       (:func:`triangulate_corners`) and matched to the board's own
       coordinates (columns along ``x``, rows along ``y``, ``z = 0``; in the
       board's units) by a least-squares similarity (Umeyama 1991) after a
       least-median-of-squares search over triples of corners (Rousseeuw
       1984): corners farther than ``4 sigma`` from the triple with the
       smallest median residual (sigma: 1.4826 times that median) are
       dropped.
    2. The board's pose and size in the reconstruction (7 parameters) are
       then refined on the kept corners' rays of every view, by least
       squares of the normalised reprojection error: the maximum-likelihood
       pose of a rigid board, where step 1 weighs the triangulations' poor
       depths as much as their good directions.
    3. The board's ``z`` axis is turned towards the cameras (a half turn
       about ``x``, if they stand on its ``-z`` side, as they do for a board
       seen from its printed side): the board's plane is the ground
       ``z = 0``, ``+z`` up on the cameras' side, the first corner the
       origin, the columns ``+x``, the board's unit the world's.

    Parameters
    ----------
    object_points : array_like, shape (N, 3)
        The board's corners in its own coordinates
        (:attr:`camcal.geometry.board.Board.object_points`), indexed by the ids.
    rotations, translations, ids, rays
        The views, as :func:`triangulate_corners` takes them.
    seed : int
        Seeds the triples: the same views give the same world.
    trials : int
        Triples tried.

    Returns
    -------
    BoardWorld
    """
    board_all = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    R_views = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    t_views = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    seen, X = triangulate_corners(R_views, t_views, ids, rays)
    board = board_all[seen]
    keep = np.all(np.isfinite(X), axis=1)
    if keep.sum() < 3 or np.linalg.matrix_rank(board[keep] - board[keep].mean(axis=0), tol=1e-9) < 2:
        raise CamcalError(f"the board's pose needs 3 corners not on one line seen in two views, got {int(keep.sum())}")
    candidates = np.flatnonzero(keep)
    rng = np.random.default_rng(seed)
    best_median, best = np.inf, None
    for _ in range(int(trials)):
        triple = rng.choice(candidates, 3, replace=False)
        if np.linalg.norm(np.cross(board[triple[1]] - board[triple[0]], board[triple[2]] - board[triple[0]])) < 1e-12:
            continue
        s, R, t = similarity_Umeyama1991(X[triple], board[triple])
        median = float(np.median(np.linalg.norm(s * X[keep] @ R.T + t - board[keep], axis=1)))
        if median < best_median:
            best_median, best = median, (s, R, t)
    if best is not None:
        s, R, t = best
        residual = np.linalg.norm(s * X @ R.T + t - board, axis=1)
        inliers = keep & (residual <= max(4.0 * 1.4826 * best_median, 1e-12 * float(np.ptp(board))))
        if inliers.sum() >= 3:
            keep = inliers
    s, R, t = similarity_Umeyama1991(X[keep], board[keep])
    s, R, t = _refine_board_pose(Similarity(s, R, t).inverse(), board_all, set(seen[keep].tolist()), R_views,
                                 t_views, ids, rays)
    rms = float(np.sqrt(np.mean(np.sum((s * X[keep] @ R.T + t - board[keep]) ** 2, axis=1))))
    heights = -s * np.einsum("vji,vj->vi", R_views, t_views) @ R.T[:, 2] + t[2]  # the camera centres' z
    if np.sum(np.sign(heights)) < 0:
        flip = np.diag([1.0, -1.0, -1.0])
        R, t = flip @ R, flip @ t
    return BoardWorld(Similarity(s, R, t), int(keep.sum()), rms)


def _refine_board_pose(board_to_world: Similarity, board: NDArray[np.float64], kept: set[int],
                       rotations: NDArray[np.float64], translations: NDArray[np.float64], ids: list[ArrayLike],
                       rays: list[ArrayLike]) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """The board's pose and size in the reconstruction that best reproject its kept corners onto every view's
    rays (Levenberg-Marquardt from ``board_to_world``); returned as the inverse: ``s, R, t`` world -> board."""
    views = []
    for view, (view_ids, view_rays) in enumerate(zip(ids, rays)):
        view_rays = np.asarray(view_rays, dtype=np.float64).reshape(-1, 2)
        mask = np.isin(np.asarray(view_ids), list(kept)) & np.all(np.isfinite(view_rays), axis=1)
        views.append((view, board[np.asarray(view_ids)[mask]], view_rays[mask]))

    def residuals(params: NDArray[np.float64]) -> NDArray[np.float64]:
        Q = Rotation.from_rotvec(params[:3]).as_matrix()
        out = []
        for view, corners, observed in views:
            x_cam = (np.exp(params[6]) * corners @ Q.T + params[3:6]) @ rotations[view].T + translations[view]
            out.append((x_cam[:, :2] / x_cam[:, 2:] - observed).ravel())
        return np.concatenate(out)

    start = np.concatenate([Rotation.from_matrix(board_to_world.R).as_rotvec(), board_to_world.t,
                            [np.log(board_to_world.s)]])
    solution = least_squares(residuals, start, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    refined = Similarity(float(np.exp(solution.x[6])), Rotation.from_rotvec(solution.x[:3]).as_matrix(),
                         solution.x[3:6]).inverse()
    return refined.s, refined.R, refined.t
