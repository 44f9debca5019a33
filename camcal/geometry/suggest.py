"""Capture guidance: the next board pose that most lowers a camera's worst projection sigma.

The information a board view adds is ``J^T J`` of its corners at the
current estimate (:func:`camcal.geometry.view_jackknife.board_jacobian`):
for each candidate pose the normal matrix of the views already taken (the
intrinsics and one pose per view) is extended by the candidate's rows and
its own pose, inverted, carried to the intrinsics and the board gauge
(mrcal's mean over the views, now including the candidate) and propagated
to the projection at infinity over a grid of the frame
(:mod:`camcal.geometry.uncertainty`); the candidate with the lowest worst
sigma wins, is added, and the search repeats for a short shot list.

Candidates: the board's centre on a 5 x 4 grid over the frame, facing the
camera or turned by 35 degrees about its horizontal or vertical axis, at
the nearest, median and farthest distance of the views taken, and always
turned by :data:`ROLL_DEG` in its own plane; a candidate must show every
corner inside the frame (8 px margin). The figures are scaled so that the
views taken give the camera's own ``quality.worst_projection_sigma_px``
(the corners' noise and the design effect of the calibration): an
expected value, for corners like those seen.

The roll is what lets that expectation hold. The information above
assumes each corner errs on its own; the reported sigma is inflated by
the design effect the delete-one-view jackknife measures
(:mod:`camcal.geometry.view_jackknife`), ``deff = 1 + (m - 1) rho`` for
``m`` corners of a view whose errors correlate by ``rho`` (Kish 1965). A
board whose edges run along the pixel rows and columns images every
corner of a row at the same sub-pixel phase, so the detector's sampling
error is shared along the row and column: ``rho`` is large, and one such
view moved the design effect from 1 to 2-5 on rendered 320x240 boards
(its corners' RMS 0.14 px against 0.07). Turned in its plane by
``theta``, neighbouring corners ``s`` pixels apart differ in phase by
``s sin theta`` (a pixel and more for ``s`` >= 4 px at 15 degrees),
which decorrelates their errors -- the reason ISO 12233 measures
sharpness on a slanted, not an aligned, edge (Burns 2000) -- and the
design effect stayed at 1-1.6: over six rendered scenes the expected
sigma of each of five suggested views was off the
recalibrated one at the median 6 %, at worst 27 % (unturned, seed 300's
first view: 0.31 px expected, 0.82 px reported).

References
----------
Kish, L. (1965). Survey Sampling. Wiley (the design effect of clusters).
Burns, P. D. (2000). Slanted-edge MTF for digital camera and scanner
analysis. Proc. IS&T PICS Conference, 135-138.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.optimize
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.uncertainty import GAUGE, projection_jacobian, sigma_grid
from camcal.geometry.view_jackknife import board_jacobian
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera

__all__ = ["SuggestedView", "candidate_poses", "expected_worst_sigma", "pose_views", "suggest_views"]

#: Tilts (degrees about the board's x and y axes) of the candidates.
TILTS_DEG = ((0.0, 0.0), (35.0, 0.0), (-35.0, 0.0), (0.0, 35.0), (0.0, -35.0))
#: Turn (degrees) of every candidate about the board's normal: its edges never run along the pixel grid.
ROLL_DEG = 15.0
_GRID = (5, 4)
_MARGIN_PX = 8.0


@dataclass(frozen=True)
class SuggestedView:
    """One suggested board pose.

    Attributes
    ----------
    R, t : ndarray
        ``cam_from_board``.
    corners_px : ndarray, shape (M, 2)
        Where the board's corners would be imaged.
    centre_px : ndarray, shape (2,)
        The pixel of the board's centre.
    distance : float
        Of the board's centre, in the board's units.
    tilt_deg : tuple of float
        About the board's x and y axes, after its turn of :data:`ROLL_DEG` about its normal.
    worst_sigma_px : float
        Expected worst projection sigma at infinity after this view (and the ones before it in the list).
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    corners_px: NDArray[np.float64]
    centre_px: NDArray[np.float64]
    distance: float
    tilt_deg: tuple[float, float]
    worst_sigma_px: float

    def describe(self) -> str:
        """``board centre at (320, 240) px, distance 0.45, turned 15 deg in its plane, tilt +35 / +0 deg (about
        x / y): worst sigma 0.12 px expected``."""
        return (f"board centre at ({self.centre_px[0]:.0f}, {self.centre_px[1]:.0f}) px, distance {self.distance:.3g}, "
                f"turned {ROLL_DEG:.0f} deg in its plane, "
                f"tilt {self.tilt_deg[0]:+.0f} / {self.tilt_deg[1]:+.0f} deg (about x / y): "
                f"worst sigma {self.worst_sigma_px:.3g} px expected")


def _free(camera: Camera) -> tuple[str, ...]:
    """The camera's intrinsics as the board calibration fits them (``f`` for the division model's one focal)."""
    lens = tuple(camera.distortion.params)
    return (("f", "cx", "cy") if camera.distortion.model == "division" else ("fx", "fy", "cx", "cy")) + lens


def _cross(t: NDArray) -> NDArray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


class _Information:
    """The normal matrix of the views taken (unit corner noise) and what a candidate view adds to it."""

    def __init__(self, camera: Camera, object_points: NDArray, poses: list, candidates: list) -> None:
        self.X = object_points
        everything = list(poses) + [(R, t) for R, t, _, _ in candidates]
        n_all, m = len(everything), len(object_points)
        frame = np.repeat(np.arange(n_all), m)
        columns, Jg, Jp, _ = board_jacobian([(camera.K, camera.distortion, _free(camera))], np.eye(3)[None],
                                            np.zeros((1, 3)), np.array([R for R, _ in everything]),
                                            np.array([t for _, t in everything]), np.tile(object_points, (n_all, 1)),
                                            np.zeros(n_all * m, dtype=np.int64), frame)
        self.scale = 1.0 / np.maximum(np.linalg.norm(Jg[:2 * m * len(poses)], axis=0), 1e-300)
        Jg = Jg * self.scale
        self.G = G = len(columns)
        # per view: (A = Jg^T Jg, B = Jg^T Jp, C = Jp^T Jp)
        self.blocks = []
        for f in range(n_all):
            rows = slice(2 * m * f, 2 * m * (f + 1))
            self.blocks.append((Jg[rows].T @ Jg[rows], Jg[rows].T @ Jp[rows], Jp[rows].T @ Jp[rows]))
        self.translations = [np.asarray(t, float) for _, t in everything]
        self.taken = list(range(len(poses)))
        names = [name for _, name in columns]
        A = np.eye(G + 6)
        if "f" in names:  # fx and fy are one parameter
            k = names.index("f")
            A = np.insert(A, k + 1, A[k], axis=0)
            names = names[:k] + ["fx", "fy"] + names[k + 1:]
        self.expand = A @ np.diag(np.r_[self.scale, np.ones(6)])
        names = tuple(names) + GAUGE
        # the steps of the derivatives: a parameter's scale moves the corners by about a pixel
        sigmas = np.r_[self.scale, np.full(6, 1e-3)]
        covariance = ParameterCovariance(names, A @ np.diag(sigmas**2) @ A.T)
        self.Jq = projection_jacobian(camera, _grid(camera), None, covariance) @ self.expand  # (N, 2, G + 6)

    def worst(self, views: list[int]) -> float:
        """Worst projection sigma over the grid with the views ``views`` (indices) and unit corner noise."""
        G, n = self.G, len(views)
        N = np.zeros((G + 6 * n, G + 6 * n))
        T = np.zeros((G + 6, G + 6 * n))
        T[:G, :G] = np.eye(G)
        for k, f in enumerate(views):
            A, B, C = self.blocks[f]
            o = G + 6 * k
            N[:G, :G] += A
            N[:G, o:o + 6], N[o:o + 6, :G], N[o:o + 6, o:o + 6] = B, B.T, C
            T[G:G + 3, o:o + 3] = np.eye(3) / n
            T[G + 3:, o:o + 3] = _cross(self.translations[f]) / n
            T[G + 3:, o + 3:o + 6] = np.eye(3) / n
        try:
            C = T @ np.linalg.inv(N) @ T.T
        except np.linalg.LinAlgError:
            return float("inf")
        S = np.einsum("nip,pq,njq->nij", self.Jq, C, self.Jq)
        a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
        return float(np.sqrt(np.max(0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b**2))))


def _grid(camera: Camera) -> NDArray[np.float64]:
    width, height = camera.image_size
    xs, ys = sigma_grid((width, height), max(width, height) / 8.0)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def _now(camera: Camera) -> float:
    now = camera.quality.get("worst_projection_sigma_px")
    if now is None:
        raise CamcalError(f"camera {camera.name!r} has no worst projection sigma: calibrate it with a board first")
    return float(now)


def expected_worst_sigma(camera: Camera, object_points: NDArray, poses, extra=()) -> float:
    """The expected worst projection sigma (pixels) from the views ``poses`` plus ``extra`` (``cam_from_board``
    each), scaled so that ``poses`` alone give the camera's ``quality.worst_projection_sigma_px``."""
    X = np.asarray(object_points, dtype=np.float64)
    poses = [(np.asarray(R, float), np.asarray(t, float)) for R, t in poses]
    information = _Information(camera, X, poses, [(np.asarray(R, float), np.asarray(t, float), 0.0, ())
                                                  for R, t in extra])
    n = len(poses)
    return _now(camera) * information.worst(list(range(n + len(extra)))) / information.worst(list(range(n)))


def candidate_poses(camera: Camera, object_points: NDArray, poses) -> list[tuple[NDArray, NDArray, float, tuple]]:
    """``(R, t, distance, tilt)`` of every candidate (module docstring) showing all corners inside the frame."""
    X = np.asarray(object_points, dtype=np.float64)
    centre = X.mean(axis=0)
    depths = [float((R @ centre + t)[2]) for R, t in poses]
    distances = sorted({round(d, 9) for d in np.quantile(depths, [0.0, 0.5, 1.0])})
    width, height = camera.image_size
    out = []
    for v in np.linspace(0.1, 0.9, _GRID[1]) * (height - 1):
        for u in np.linspace(0.1, 0.9, _GRID[0]) * (width - 1):
            ray = camera.distortion.rays_from_pixels(np.array([[u, v]]), camera.K)[0]
            if not np.isfinite(ray).all() or ray[2] <= 0:
                continue
            for d in distances:
                for tilt in TILTS_DEG:
                    R = Rotation.from_euler("zxy", (ROLL_DEG, *tilt), degrees=True).as_matrix()  # turned, then tilted
                    t = ray / ray[2] * d - R @ centre
                    p = X @ R.T + t
                    if np.any(p[:, 2] <= 0):
                        continue
                    q = camera.distortion.project_rays(p, camera.K)
                    inside = (q > _MARGIN_PX) & (q < np.array([width, height]) - 1 - _MARGIN_PX)
                    if np.all(inside):
                        out.append((R, t, d, tilt))
    return out


def suggest_views(camera: Camera, object_points: NDArray, poses, n: int = 1) -> list[SuggestedView]:
    """The next ``n`` board poses, each the candidate that most lowers the expected worst projection sigma
    given the views ``poses`` (``cam_from_board`` of each view taken) and the suggestions before it.

    Raises
    ------
    CamcalError
        No candidate pose shows the whole board inside the frame.
    """
    X = np.asarray(object_points, dtype=np.float64)
    taken = [(np.asarray(R, float), np.asarray(t, float)) for R, t in poses]
    candidates = candidate_poses(camera, X, taken)
    if not candidates:
        raise CamcalError("no candidate board pose shows every corner inside the frame at the distances seen")
    information = _Information(camera, X, taken, candidates)
    views = list(range(len(taken)))
    unit = _now(camera) / information.worst(views)
    out = []
    for _ in range(n):
        scores = [information.worst(views + [len(taken) + k]) for k in range(len(candidates))]
        best = int(np.argmin(scores))
        R, t, d, tilt = candidates[best]
        corners = camera.distortion.project_rays(X @ R.T + t, camera.K)
        centre = camera.distortion.project_rays((R @ X.mean(axis=0) + t)[None], camera.K)[0]
        out.append(SuggestedView(R, t, corners, centre, d, tilt, unit * scores[best]))
        views.append(len(taken) + best)
    return out


def pose_views(camera: Camera, object_points: NDArray, detections) -> list[tuple[NDArray, NDArray]]:
    """``cam_from_board`` of each detection with the camera's intrinsics held: PnP on the undistorted rays,
    then least squares on the reprojection (:meth:`~camcal.model.distortion.Distortion.project_rays`)."""
    X_all = np.asarray(object_points, dtype=np.float64)
    poses = []
    for detection in detections:
        X, x = X_all[detection.ids], np.asarray(detection.corners_px, dtype=np.float64)
        rays = camera.distortion.rays_from_pixels(x, camera.K)
        ok, rvec, tvec = cv2.solvePnP(X, rays[:, :2] / rays[:, 2:], np.eye(3), None)
        if not ok:
            raise CamcalError(f"{detection.image}: the board could not be posed with the calibrated camera")

        def residuals(pose, X=X, x=x):
            R = Rotation.from_rotvec(pose[:3]).as_matrix()
            return (camera.distortion.project_rays(X @ R.T + pose[3:], camera.K) - x).ravel()

        pose = scipy.optimize.least_squares(residuals, np.r_[rvec.ravel(), tvec.ravel()], method="lm").x
        poses.append((Rotation.from_rotvec(pose[:3]).as_matrix(), pose[3:]))
    return poses
