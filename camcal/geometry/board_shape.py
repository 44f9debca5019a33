"""The shape of a board that is not flat: a smooth, low-order surface ``z(x, y)`` fitted with the lens and the poses.

A printed board glued to a panel bows and twists by a fraction of a square; every flat-board calibration
carries that error into its intrinsics and its held-out figures. Strobl & Hirzinger (2011) refine the
board's points with the camera; mrcal models the board as flat plus a two-parameter parabolic "calobject
warp" (a bow along x and one along y). camcal's surface generalises mrcal's warp to the tensor products of
Legendre polynomials of total degree ``2..d`` over the board's corner extent,

    z(x, y) = sum_{2 <= i + j <= d} w_ij P_i(u) P_j(v),   u = (x - x_c) / h_x,  v = (y - y_c) / h_y,

(``d = 2``: bow along x, bow along y and a twist; 3 coefficients; ``d = 3``: 7; ``d = 4``: 12), the corner
points moving along the board's normal (``X = (x, y, z)``). Gauge: a surface ``a + b u + c v`` is a small
rigid motion of a flat board, which the board poses already hold, so every basis column has its least-squares
part in ``span{1, u, v}`` over the board's corners removed: the fitted surface has zero mean and zero tilt
over the corners and cannot trade with the poses. Its scale is the board's (the corners' ``x, y`` are known),
so it does not trade with the focal length either. A term ``P_i`` with ``i`` at or above the board's corner
columns (``j``: rows) repeats lower ones on the corners and is left out, so the degree ``columns + rows - 2``
(``free``) frees every corner's height. With ``in_plane`` the corners also move in the board's plane by the
same terms (a print stretched, sheared or warped), the similarity part (shift, turn, scale: the poses' and the
square size's) taken out over the corners; ``free`` with ``in_plane`` frees every corner's 3D point like
Strobl & Hirzinger's refinement (``3N - 7`` parameters).

:func:`fit_board_shape` refines jointly the intrinsics ``fx, fy, cx, cy``, the lens's distortion parameters,
every view's board pose and the surface's coefficients, minimising ``sum |project(K, d, R X(w) + t) - x|^2``
by Levenberg-Marquardt (the Jacobian from forward differences: one column per lens parameter, the six pose
columns of every view perturbed at once, a view's corners depending on its own pose only, and the surface's
columns by the chain rule through each corner's point in the camera, whose three differences are taken for
every corner at once), started
from a flat calibration. Which degree (or flat) a calibration keeps is decided by held-out error in
:mod:`camcal.geometry.zhang`.

References
----------
Strobl, K. H. & Hirzinger, G. (2011). More accurate pinhole camera calibration with imperfect planar target.
ICCV Workshops (the board's points estimated with the camera).
Kogan, D. mrcal (2019-): ``calobject_warp``, a parabolic board deflection along x and along y, solved jointly.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.spline_fit import levenberg_marquardt
from camcal.model.distortion import Distortion

__all__ = ["BoardShape", "BoardShapeFit", "SHAPE_SPECS", "AUTO_SHAPES", "fit_board_shape", "flat_start", "max_degree",
           "n_shape_params", "n_shape_terms", "parse_shape"]

#: Named board shapes: a surface of total degree 2, 3, 4 or 6, or ``free`` (every corner's height free: the
#: degree :func:`max_degree`); ``+plane`` adds the corners' displacement in the board's plane (same terms).
SHAPE_SPECS = tuple(f"{d}{p}" for d in ("2", "3", "4", "6", "free") for p in ("", "+plane"))
#: The shapes ``board_shape="auto"`` scores (simplest first).
AUTO_SHAPES = ("2", "4", "6", "free", "2+plane", "4+plane", "6+plane", "free+plane")
#: Corners whose ray is further than this off the optical axis at the start pose are left out (no lens images them).
_MAX_ANGLE_DEG = 89.0
_FD_STEP = 1e-7


def _grid(board: Board) -> tuple[int, int]:
    """Distinct corner columns and rows of the board (the highest Legendre order each direction can tell apart)."""
    xy = np.round(board.object_points[:, :2] / board.square, 6)
    return len(np.unique(xy[:, 0])), len(np.unique(xy[:, 1]))


def _terms(degree: int, board: Board, lowest: int = 2) -> list[tuple[int, int]]:
    """``(i, j)`` of every ``P_i(u) P_j(v)`` with ``lowest <= i + j <= degree``, ``i`` below the board's corner
    columns and ``j`` below its rows (higher orders repeat lower ones on the corners), by total degree."""
    nu, nv = _grid(board)
    return [(total - j, j) for total in range(lowest, degree + 1) for j in range(total + 1)
            if total - j < nu and j < nv]


def n_shape_terms(degree: int, board: Board) -> int:
    """Free coefficients of a surface of ``degree`` on ``board`` (the affine part is the pose's):
    ``(d + 1)(d + 2) / 2 - 3`` while ``d`` is below the corners per side; at ``columns + rows - 2`` every corner's
    height is free (``columns x rows - 3``)."""
    return len(_terms(degree, board))


def max_degree(board: Board) -> int:
    """The degree at which every corner's height is free (the surface interpolates any heights)."""
    nu, nv = _grid(board)
    return nu + nv - 2


def parse_shape(board: Board, spec: str) -> tuple[int, bool]:
    """``(degree, in_plane)`` of a name of :data:`SHAPE_SPECS` on ``board``."""
    if spec not in SHAPE_SPECS:
        raise CamcalError(f"unknown board shape {spec!r}, expected one of: {', '.join(SHAPE_SPECS)}")
    degree, _, plane = spec.partition("+")
    return (max_degree(board) if degree == "free" else int(degree)), bool(plane)


def n_shape_params(board: Board, spec: str) -> int:
    """Free parameters of the board shape ``spec``: its height terms and, with ``+plane``, its in-plane ones."""
    degree, in_plane = parse_shape(board, spec)
    n = n_shape_terms(degree, board)
    return n + (_in_plane_basis(board, degree)[0].shape[1] if in_plane else 0)


def _legendre(n: int, s: NDArray[np.float64]) -> NDArray[np.float64]:
    return legendre.legval(s, np.eye(n + 1)[n])


@dataclass(frozen=True)
class BoardShape:
    """A board's surface ``z(x, y)`` (board units, along the board's normal) as Legendre coefficients.

    Attributes
    ----------
    degree : int
        Highest total degree of the fitted terms.
    coefficients : mapping of (int, int) to float
        ``w_ij`` of ``P_i(u) P_j(v)`` (the affine terms ``(0, 0), (1, 0), (0, 1)`` included: they carry the
        gauge, zero mean and zero tilt over the corners).
    centre, half_size : tuple of float
        ``(x_c, y_c)`` and ``(h_x, h_y)``: ``u = (x - x_c) / h_x``, ``v = (y - y_c) / h_y``.
    in_plane : mapping of (int, int) to (float, float)
        ``(a_ij, b_ij)``: the corners' displacement in the board's plane, ``dx = sum a_ij P_i(u) P_j(v)``,
        ``dy = sum b_ij P_i(u) P_j(v)`` (a print stretched or sheared; empty: the printed grid is exact). Its
        similarity part (shift, turn, scale: the pose's and the square size's) is zero over the corners.
    """

    degree: int
    coefficients: Mapping[tuple[int, int], float]
    centre: tuple[float, float]
    half_size: tuple[float, float]
    in_plane: Mapping[tuple[int, int], tuple[float, float]] = dataclasses.field(default_factory=dict)

    def displacements(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(dx, dy)`` (N, 2) in the board's plane at board points ``xy`` (N, 2), in the board's units."""
        u, v = _normalised(xy, self.centre, self.half_size)
        d = np.zeros((len(u), 2))
        for (i, j), (a, b) in sorted(self.in_plane.items()):
            term = _legendre(i, u) * _legendre(j, v)
            d[:, 0] += a * term
            d[:, 1] += b * term
        return d

    def heights(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """``z`` at board points ``xy`` (N, 2), in the board's units."""
        u, v = _normalised(xy, self.centre, self.half_size)
        z = np.zeros(len(u))
        for (i, j), w in sorted(self.coefficients.items()):
            z += w * _legendre(i, u) * _legendre(j, v)
        return z

    def points(self, board: Board) -> NDArray[np.float64]:
        """The board's corners ``(x, y, z(x, y))`` (N, 3) on this surface."""
        X = np.array(board.object_points, dtype=np.float64)
        X[:, 2] = self.heights(X[:, :2])
        if self.in_plane:
            X[:, :2] += self.displacements(board.object_points[:, :2])
        return X

    def relief(self, board: Board) -> tuple[float, float]:
        """``(peak-to-valley, largest |z|)`` of the surface over the board's corners, in the board's units."""
        z = self.heights(board.object_points[:, :2])
        return float(z.max() - z.min()), float(np.abs(z).max())

    def describe(self, board: Board) -> str:
        """``board relief: max 0.071 squares (peak to valley 0.12 squares), degree-2 surface (3 coefficients)``."""
        span, largest = self.relief(board)
        free = " (every corner's height free)" if self.degree >= max_degree(board) else ""
        text = (f"board relief: max {largest / board.square:.3f} squares (peak to valley {span / board.square:.3f} "
                f"squares, {largest:.4g} board units) on a degree-{self.degree} surface{free}")
        if self.in_plane:
            shift = float(np.linalg.norm(self.displacements(board.object_points[:, :2]), axis=1).max())
            text += f"; corners off the printed grid in its plane by up to {shift / board.square:.3f} squares"
        return text

    def to_dict(self) -> dict:
        """The rig file's ``provenance.board_shape`` (:meth:`from_dict` reads it back exactly)."""
        data = {"surface": "legendre", "degree": self.degree, "centre": list(self.centre),
                "half_size": list(self.half_size),
                "coefficients": [[i, j, float(w)] for (i, j), w in sorted(self.coefficients.items())]}
        if self.in_plane:
            data["in_plane"] = [[i, j, float(a), float(b)] for (i, j), (a, b) in sorted(self.in_plane.items())]
        return data

    @classmethod
    def from_dict(cls, data: Mapping) -> BoardShape:
        """The shape of :meth:`to_dict`; a clear error naming the bad field."""
        try:
            if data["surface"] != "legendre":
                raise CamcalError(f"board_shape.surface {data['surface']!r} is not 'legendre'")
            coefficients = {(int(i), int(j)): float(w) for i, j, w in data["coefficients"]}
            centre = (float(data["centre"][0]), float(data["centre"][1]))
            half = (float(data["half_size"][0]), float(data["half_size"][1]))
            degree = int(data["degree"])
            in_plane = {(int(i), int(j)): (float(a), float(b)) for i, j, a, b in data.get("in_plane", [])}
        except (KeyError, TypeError, ValueError, IndexError) as error:
            raise CamcalError(f"board_shape: bad or missing field ({error})") from None
        if not (half[0] > 0 and half[1] > 0) or not all(np.isfinite(w) for w in coefficients.values()):
            raise CamcalError("board_shape: half_size must be positive and the coefficients finite")
        if not all(np.isfinite(a) and np.isfinite(b) for a, b in in_plane.values()):
            raise CamcalError("board_shape: the in-plane coefficients must be finite")
        return cls(degree, coefficients, centre, half, in_plane)


def _frame(board: Board) -> tuple[tuple[float, float], tuple[float, float]]:
    xy = board.object_points[:, :2]
    low, high = xy.min(axis=0), xy.max(axis=0)
    half = np.maximum((high - low) / 2.0, board.square)
    return (float((low[0] + high[0]) / 2), float((low[1] + high[1]) / 2)), (float(half[0]), float(half[1]))


def _normalised(xy: NDArray, centre: tuple[float, float], half: tuple[float, float]) -> tuple[NDArray, NDArray]:
    """``u = (x - x_c) / h_x``, ``v = (y - y_c) / h_y`` of board points ``xy`` (N, 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    return (xy[:, 0] - centre[0]) / half[0], (xy[:, 1] - centre[1]) / half[1]


def _term_columns(board: Board, degree: int) -> tuple[NDArray[np.float64], list[tuple[int, int]]]:
    """Every term ``P_i(u) P_j(v)`` of total degree up to ``degree`` at the board's corners (N, T_all), affine
    ones first, and those terms."""
    u, v = _normalised(board.object_points[:, :2], *_frame(board))
    every = _terms(degree, board, lowest=0)
    return np.column_stack([_legendre(i, u) * _legendre(j, v) for i, j in every]), every


@functools.lru_cache(maxsize=32)
def _basis(board: Board, degree: int) -> tuple[NDArray[np.float64], NDArray[np.float64], list[tuple[int, int]]]:
    """The gauge-free basis over the board's corners (N, T), the map from its coefficients to every term's
    Legendre coefficient (``A``: (T_all, T)) and those terms (affine ones first)."""
    columns, every = _term_columns(board, degree)
    affine, raw = columns[:, :3], columns[:, 3:]
    # each free column minus its least-squares part in span{1, u, v} over the corners
    removal = np.linalg.lstsq(affine, raw, rcond=None)[0]  # (3, T)
    A = np.vstack([-removal, np.eye(raw.shape[1])])
    return _read_only(columns @ A), _read_only(A), every


@functools.lru_cache(maxsize=32)
def _in_plane_basis(board: Board, degree: int) -> tuple[NDArray[np.float64], NDArray[np.float64], list]:
    """The in-plane displacement basis over the corners, stacked ``(dx_1..dx_N, dy_1..dy_N)`` (2N, S), with the
    similarity motions (shift x, shift y, turn, scale) removed, orthonormal; the map from its coefficients to
    every term's ``(a_ij, b_ij)`` (``(2 T, S)``, a's then b's) and the terms."""
    columns, every = _term_columns(board, degree)
    centre, _ = _frame(board)
    xy = board.object_points[:, :2]
    zero = np.zeros_like(columns)
    M = np.block([[columns, zero], [zero, columns]])  # (2N, 2T)
    x, y = xy[:, 0] - centre[0], xy[:, 1] - centre[1]
    one, none = np.ones(len(xy)), np.zeros(len(xy))
    G = np.column_stack([np.concatenate(g) for g in ((one, none), (none, one), (-y, x), (x, y))])
    free = M - G @ np.linalg.lstsq(G, M, rcond=None)[0]
    U, sv, _ = np.linalg.svd(free, full_matrices=False)
    Q = U[:, sv > 1e-9 * sv[0]]
    return _read_only(Q), _read_only(np.linalg.lstsq(M, Q, rcond=None)[0]), every


def _read_only(array: NDArray[np.float64]) -> NDArray[np.float64]:
    """``array`` made read-only (the bases are cached per board and degree, and shared)."""
    array.setflags(write=False)
    return array


@dataclass(frozen=True)
class BoardShapeFit:
    """The fitted intrinsics, lens, board surface, board poses (frame -> rvec, tvec) and training residuals."""

    K: NDArray[np.float64]
    distortion: Distortion
    shape: BoardShape
    poses: Mapping[int, tuple[NDArray[np.float64], NDArray[np.float64]]]
    residuals_px: NDArray[np.float64]
    rms_px: float
    views: Mapping[int, Detection]


def _imaged(board: Board, views: Mapping[int, Detection], poses: Mapping[int, tuple[NDArray, NDArray]]
            ) -> dict[int, Detection]:
    """The views (frame -> detection) without the corners no lens images at their pose ``(R, t)`` (a fisheye's
    beyond 90 degrees: further than ``_MAX_ANGLE_DEG`` off the optical axis); a view left with fewer than 4 is
    dropped."""
    cos_limit = np.cos(np.radians(_MAX_ANGLE_DEG))
    kept = {}
    for f in sorted(views):
        R, t = poses[f]
        X = board.object_points[views[f].ids] @ np.asarray(R).T + np.asarray(t).ravel()
        front = X[:, 2] > cos_limit * np.linalg.norm(X, axis=1)
        if front.sum() >= 4:
            d = views[f]
            kept[f] = d if front.all() else dataclasses.replace(d, ids=d.ids[front], corners_px=d.corners_px[front])
    return kept


def flat_start(board: Board, views: Mapping[int, Detection], K: NDArray, distortion: Distortion,
               poses: Mapping[int, tuple[NDArray, NDArray]], degree: int, in_plane: bool = False) -> BoardShapeFit:
    """The start of :func:`fit_board_shape` as a fit: the flat calibration ``K, distortion, poses`` (frame ->
    ``cam_from_board`` ``(R, t)``) with every term of the surface of ``degree`` (and, with ``in_plane``, of the
    in-plane displacement) present at zero, on the views it keeps (the corners no lens images left out). The
    point a first-order estimate of that surface's fit is taken from
    (:func:`camcal.geometry.zhang_loo.leave_one_view_out_on_shape`)."""
    kept = _imaged(board, views, poses)
    every = _terms(degree, board, lowest=0)
    shape = BoardShape(degree, {term: 0.0 for term in every}, *_frame(board),
                       {term: (0.0, 0.0) for term in every} if in_plane else {})
    rvecs = {f: cv2.Rodrigues(np.asarray(poses[f][0], np.float64))[0].ravel() for f in kept}
    tvecs = {f: np.asarray(poses[f][1], np.float64).ravel() for f in kept}
    data = np.concatenate([distortion.project_rays(board.object_points[kept[f].ids] @ np.asarray(poses[f][0]).T
                                                   + tvecs[f], K) - kept[f].corners_px for f in sorted(kept)])
    return BoardShapeFit(K=np.asarray(K, np.float64), distortion=distortion, shape=shape,
                         poses={f: (rvecs[f], tvecs[f]) for f in kept}, residuals_px=data,
                         rms_px=float(np.sqrt(np.mean(np.sum(data * data, axis=1)))), views=kept)


def fit_board_shape(board: Board, views: Mapping[int, Detection], K: NDArray, distortion: Distortion,
                    refine: Sequence[str], poses: Mapping[int, tuple[NDArray, NDArray]], degree: int,
                    in_plane: bool = False) -> BoardShapeFit:
    """Fit the board's surface of ``degree`` jointly with the lens and the poses (see the module docstring).

    Parameters
    ----------
    board, views :
        The board and the training views (frame -> detection), all of one image size.
    K, distortion :
        A flat-board calibration of those views (a lens with ``aspect`` keeps it at ``fx / fy``).
    refine :
        The distortion parameters refined with the surface (the others are held).
    poses :
        Frame -> ``cam_from_board`` ``(R, t)`` of each view under that calibration (the start).
    degree :
        Highest total degree of the surface (:func:`parse_shape`).
    in_plane :
        Also fit the corners' displacement in the board's plane (same terms, the similarity part removed).

    Raises
    ------
    CamcalError
        A view without a start pose, or a fit that diverges.
    """
    if degree < 2:
        raise CamcalError(f"a board surface needs degree 2 or more, got {degree}")
    frames = sorted(views)
    missing = [f for f in frames if f not in poses]
    if missing:
        raise CamcalError(f"board shape: {len(missing)} view(s) have no start pose")
    B_all, A, every = _basis(board, degree)
    n_z = B_all.shape[1]
    if in_plane:
        Q, A_plane, _ = _in_plane_basis(board, degree)
        n_corners = board.n_corners
        Qx, Qy = Q[:n_corners], Q[n_corners:]
    else:
        Qx = Qy = np.zeros((board.n_corners, 0))
    n_terms = n_z + Qx.shape[1]
    kept = _imaged(board, views, poses)
    frames = sorted(kept)
    ids = [kept[f].ids for f in frames]
    corner = np.concatenate(ids)  # each observation's corner id, views in order
    flat_stack = np.asarray(board.object_points[corner], dtype=np.float64)
    B_stack, Bx_stack, By_stack = B_all[corner], Qx[corner], Qy[corner]
    x = np.concatenate([kept[f].corners_px for f in frames])
    view_of = np.repeat(np.arange(len(frames)), [len(i) for i in ids])
    n_lens = 4 + len(refine)
    n_views = len(frames)
    base = Distortion(distortion.model, dict(distortion.params), distortion.center)
    tie_aspect = "aspect" in base.params and "aspect" not in refine

    def unpack(p: NDArray[np.float64]):
        Kp = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        values = {**base.params, **dict(zip(refine, p[4:n_lens]))}
        if tie_aspect:
            values["aspect"] = p[0] / p[1]
        lens = Distortion(base.model, values, base.center)
        return Kp, lens, p[n_lens:n_lens + 6 * n_views].reshape(n_views, 6), p[n_lens + 6 * n_views:]

    def in_camera(p: NDArray[np.float64]):
        """``(K, lens, every corner in its camera's frame, each corner's view rotation)``."""
        Kp, lens, pose, w = unpack(p)
        X = flat_stack.copy()
        X[:, 2] = B_stack @ w[:n_z]
        if in_plane:
            X[:, 0] += Bx_stack @ w[n_z:]
            X[:, 1] += By_stack @ w[n_z:]
        R = np.stack([cv2.Rodrigues(pv[:3])[0] for pv in pose])[view_of]
        return Kp, lens, np.einsum("nij,nj->ni", R, X) + pose[view_of, 3:], R

    def project(p: NDArray[np.float64]) -> NDArray[np.float64]:
        Kp, lens, X, _ = in_camera(p)
        return lens.project_rays(X, Kp)

    def residuals(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.nan_to_num(project(p) - x, nan=1e6, posinf=1e6, neginf=-1e6).ravel()

    def jacobian(p: NDArray[np.float64]) -> NDArray[np.float64]:
        q0 = project(p)
        J = np.zeros((2 * len(x), len(p)))
        steps = _FD_STEP * np.maximum(1.0, np.abs(p))
        for k in range(n_lens):  # the lens: one column each
            dp = p.copy()
            dp[k] += steps[k]
            J[:, k] = np.nan_to_num((project(dp) - q0) / steps[k]).ravel()
        # the surface by the chain rule: d q / d w = (d q / d X_cam) R (d X_board / d w), where d q / d X_cam
        # (2 x 3 per corner, each corner's projection depending on its own point only) is three forward
        # differences of every corner at once instead of one per surface term
        Kp, lens, X, R = in_camera(p)
        G = np.empty((len(x), 2, 3))
        for axis in range(3):
            step = _FD_STEP * np.maximum(1.0, np.abs(X[:, axis]))
            dX = X.copy()
            dX[:, axis] += step
            G[:, :, axis] = np.nan_to_num((lens.project_rays(dX, Kp) - q0) / step[:, None])
        M = G @ R  # d q / d X_board
        surface = slice(n_lens + 6 * n_views, len(p))
        J_surface = np.concatenate([M[:, :, 2, None] * B_stack[:, None, :],
                                    M[:, :, 0, None] * Bx_stack[:, None, :] + M[:, :, 1, None] * By_stack[:, None, :]],
                                   axis=2)  # (corners, 2, terms)
        J[:, surface] = J_surface.reshape(2 * len(x), n_terms)
        rows = np.arange(len(x))
        for k in range(6):  # the k-th pose parameter of every view at once
            dp = p.copy()
            cols = n_lens + 6 * np.arange(n_views) + k
            dp[cols] += steps[cols]
            delta = np.nan_to_num((project(dp) - q0) / steps[cols][view_of, None])
            J[2 * rows, cols[view_of]] = delta[:, 0]
            J[2 * rows + 1, cols[view_of]] = delta[:, 1]
        return J

    start = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [base.params[name] for name in refine],
                            np.concatenate([np.concatenate([cv2.Rodrigues(np.asarray(poses[f][0], np.float64))[0].ravel(),
                                                            np.asarray(poses[f][1], np.float64).ravel()])
                                            for f in frames]), np.zeros(n_terms)])
    if len(x) * 2 <= len(start):
        raise CamcalError(f"board shape: {len(x)} corners cannot fit {len(start)} parameters")
    # Marquardt's damping on the normal equations (BLAS): MINPACK's unblocked QR of the dense Jacobian cost seconds
    # per step on a few thousand corners
    p = levenberg_marquardt(residuals, jacobian, start, max_iter=100, tol=1e-12)
    data = project(p) - x
    if not np.all(np.isfinite(p)) or not np.all(np.isfinite(data)):
        raise CamcalError("the board shape fit diverged (non-finite parameters or corners left unprojected)")
    Kp, lens, pose, w = unpack(p)
    centre, half = _frame(board)
    plane = {}
    if in_plane:
        ab = (A_plane @ w[n_z:]).reshape(2, -1)
        plane = {term: (float(a), float(b)) for term, a, b in sorted(zip(every, ab[0], ab[1]))}
    shape = BoardShape(degree, {term: float(c) for term, c in sorted(zip(every, A @ w[:n_z]))}, centre, half, plane)
    return BoardShapeFit(K=Kp, distortion=lens, shape=shape,
                         poses={f: (pv[:3].copy(), pv[3:].copy()) for f, pv in zip(frames, pose)},
                         residuals_px=data, rms_px=float(np.sqrt(np.mean(np.sum(data * data, axis=1)))), views=kept)
