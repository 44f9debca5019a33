"""Planar-target calibration of one camera or of an N-camera rig, refined jointly.

Pipeline (Zhang 2000, extended to rigs as in multi-camera toolboxes):

1. Per camera, OpenCV's ``calibrateCamera`` (Zhang's closed form + LM)
   gives the starting K, distortion and one board pose per image
   (``cv2.fisheye.calibrate`` for the ``kannala-brandt`` model).
2. Views of several cameras are matched by the frame number in their file
   names (:func:`camcal.geometry.board.frame_number`); each camera's pose
   relative to the reference (the first camera) is the robust average of
   the per-view relative poses ``cam_j_from_board (cam_i_from_board)^-1``,
   chained over cameras sharing views.
3. ONE nonlinear least-squares problem refines every camera's intrinsics
   and distortion, every camera-to-reference pose and every board pose,
   minimising the reprojection error over all cameras
   (``scipy.optimize.least_squares``, trust-region reflective, with the
   sparse Jacobian pattern: a residual depends only on its camera's
   intrinsics and pose and on its view's board pose).
4. Images whose RMS is far above the median (``> max(outlier_factor x
   median, min_outlier_px)``) are dropped, reported, and the problem is
   solved again.
5. Uncertainty: ``Sigma = sigma^2 (J^T J)^-1`` at the solution, with
   ``sigma^2 = |r|^2 / (m - n)``; the board poses are marginalised out.
   These sigmas measure sampling noise of the corners, not model error.

Conventions: ``x ~ K [R | -R c] X`` with ``R`` world -> camera; the world
is the reference camera's frame (``R = I``, ``c = 0``); lengths are in the
board's units (its square size); pixel (0, 0) is the centre of the
top-left pixel; skew is fixed at 0. Distortion models (see
:mod:`camcal.geometry.distortion`): ``polynomial`` (k1, k2), ``opencv``
(k1, k2, p1, p2, k3) or ``division`` (Strand & Hayman lambda in 1/px^2,
centred on the principal point, refined here since OpenCV has no such model;
it is initialised from OpenCV's k1 as ``lambda = -k1 / f^2``) or
``kannala-brandt`` (k1..k4 of OpenCV's fisheye model, projected from the
ray angle ``atan2(|(x, y)|, z)`` so views beyond 90 degrees count too).

References
----------
Zhang, Z. (2000). A flexible new technique for camera calibration. IEEE
TPAMI 22(11).
Strand, R. & Hayman, E. (2005). Correcting radial distortion by circle
fitting. BMVC.
Hartley, R., Trumpf, J., Dai, Y. & Li, H. (2013). Rotation averaging. IJCV
(chordal L2 mean).
Triggs, B. et al. (2000). Bundle adjustment - a modern synthesis (sparse
structure, covariance from the Jacobian).
"""

from __future__ import annotations

import colorsys
import os
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import cv2
import numpy as np
import scipy.sparse
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camcal.errors import CamcalError
from camcal.geometry.board import Board, Detection, frame_number
from camcal.geometry.distortion import Distortion
from camcal.io.atomic import atomic_path
from camcal.rig import Camera, Rig, make_provenance

__all__ = ["MODELS", "MIN_IMAGES", "CalibrationResult", "calibrate_board", "write_report"]

#: Distortion models and the parameters refined for each.
MODELS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {"polynomial": ("k1", "k2"), "opencv": ("k1", "k2", "p1", "p2", "k3"), "division": ("lambda",),
     "kannala-brandt": ("k1", "k2", "k3", "k4")}
)
#: Fewest images with the board per camera.
MIN_IMAGES = 3
_INTRINSICS = ("fx", "fy", "cx", "cy")
_OPENCV_FLAGS = {
    "polynomial": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    "opencv": 0,
    "division": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
}
_MAX_OUTLIER_ROUNDS = 3


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated camera or rig with its residuals and uncertainty.

    Attributes
    ----------
    rig : Rig
        The cameras; the first is the reference (``R = I``, ``c = 0``),
        lengths in the board's units. Each camera's ``quality`` holds
        ``rms_px``, ``worst_px``, ``n_views``, ``n_points`` and ``sigma``
        (one-sigma of fx, fy, cx, cy, the distortion parameters and, for
        the other cameras, ``baseline`` and ``rotation_deg`` from the
        reference).
    residuals_px : ndarray, shape (M, 2)
        ``projected - detected`` for every corner kept, in pixels.
    points_px : ndarray, shape (M, 2)
        The detected corners of those residuals.
    camera_of_point, image_of_point : ndarray of int, shape (M,)
        Index into ``rig.cameras`` and into :attr:`images` of each corner.
    images : tuple of (str, str)
        ``(camera name, image name)`` of every image kept.
    rms_px, worst_px : float
        RMS and largest reprojection error (per-corner norm), in pixels.
    outliers : tuple of (str, str)
        ``(camera name, image name)`` of the images dropped as outliers.
    covariance : ndarray, shape (P, P)
        ``sigma^2 (J^T J)^-1`` of the camera parameters named in
        :attr:`parameter_names` (board poses marginalised out); rotations
        are rotation vectors in radians, translations in board units.
    parameter_names : tuple of str
        ``"<camera>.<name>"``, e.g. ``left.fx``, ``right.k1``, ``right.rx``, ``right.tx``
        (``cam_from_reference`` rotation vector and translation).
    """

    rig: Rig
    residuals_px: NDArray[np.float64]
    points_px: NDArray[np.float64]
    camera_of_point: NDArray[np.int64]
    image_of_point: NDArray[np.int64]
    images: tuple[tuple[str, str], ...]
    rms_px: float
    worst_px: float
    outliers: tuple[tuple[str, str], ...]
    covariance: NDArray[np.float64]
    parameter_names: tuple[str, ...]

    @property
    def n_outliers(self) -> int:
        """Number of images dropped as outliers."""
        return len(self.outliers)

    @property
    def per_image_rms_px(self) -> dict[tuple[str, str], float]:
        """RMS reprojection error of each kept image, in pixels."""
        squared = np.sum(self.residuals_px**2, axis=1)
        sums = np.bincount(self.image_of_point, squared, minlength=len(self.images))
        counts = np.bincount(self.image_of_point, minlength=len(self.images))
        return {key: float(np.sqrt(s / n)) for key, s, n in zip(self.images, sums, counts)}

    def summary(self) -> str:
        """``RMS reprojection error: 0.19 px (worst 0.84 px, 3 outliers of 50 images)``."""
        return (
            f"RMS reprojection error: {self.rms_px:.3f} px (worst {self.worst_px:.3f} px, "
            f"{self.n_outliers} outlier images of {len(self.images) + self.n_outliers}, "
            f"{len(self.residuals_px)} corners)"
        )


# -- poses -------------------------------------------------------------------------


def _average_rotation(rotations: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Robust chordal mean of rotations (K, 3, 3) and the inlier mask.

    Notes
    -----
    Start from the medoid (least summed angle to the others), keep the
    rotations within ``max(1 deg, 3 x median angle)`` of it, and return
    the projection of their arithmetic mean onto SO(3) (chordal L2 mean,
    Hartley et al. 2013): ``R = U diag(1, 1, det(U V^T)) V^T``.
    """
    def angles(reference: NDArray[np.float64], many: NDArray[np.float64]) -> NDArray[np.float64]:
        cosine = (np.einsum("ij,kij->k", reference, many) - 1.0) / 2.0
        return np.arccos(np.clip(cosine, -1.0, 1.0))

    pairwise = np.array([angles(R, rotations) for R in rotations])
    medoid = rotations[np.argmin(pairwise.sum(axis=1))]
    distance = angles(medoid, rotations)
    inliers = distance <= max(np.radians(1.0), 3.0 * np.median(distance))
    U, _, Vt = np.linalg.svd(rotations[inliers].sum(axis=0))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, inliers


def _relative_pose(
    poses_i: Mapping[int, tuple[NDArray, NDArray]], poses_j: Mapping[int, tuple[NDArray, NDArray]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``cam_j_from_cam_i`` from the board poses of the views both cameras saw.

    ``R_ji = R_j R_i^T``, ``t_ji = t_j - R_ji t_i`` per view; rotations
    averaged robustly, translations by the median over the inlier views.
    """
    shared = sorted(set(poses_i) & set(poses_j))
    R_rel = np.array([poses_j[v][0] @ poses_i[v][0].T for v in shared])
    t_rel = np.array([poses_j[v][1] - R_rel[n] @ poses_i[v][1] for n, v in enumerate(shared)])
    R, inliers = _average_rotation(R_rel)
    return R, np.median(t_rel[inliers], axis=0)


# -- the joint problem ---------------------------------------------------------------


@dataclass(frozen=True)
class _Problem:
    """Observations and parameter layout of the joint refinement."""

    model: str
    n_cameras: int
    n_views: int
    object_points: NDArray[np.float64]  # (M, 3)
    detected: NDArray[np.float64]  # (M, 2)
    camera: NDArray[np.int64]  # (M,)
    view: NDArray[np.int64]  # (M,)
    division_scale: NDArray[np.float64]  # (n_cameras,) lambda = scaled / s^2

    @property
    def n_intrinsics(self) -> int:
        return len(_INTRINSICS) + len(MODELS[self.model])

    @property
    def pose_offset(self) -> int:
        return self.n_cameras * self.n_intrinsics

    @property
    def view_offset(self) -> int:
        return self.pose_offset + 6 * (self.n_cameras - 1)

    @property
    def n_parameters(self) -> int:
        return self.view_offset + 6 * self.n_views

    def unpack(self, x: NDArray[np.float64]):
        intrinsics = x[: self.pose_offset].reshape(self.n_cameras, self.n_intrinsics)
        cam_poses = np.vstack([np.zeros(6), x[self.pose_offset : self.view_offset].reshape(-1, 6)])
        view_poses = x[self.view_offset :].reshape(self.n_views, 6)
        return intrinsics, cam_poses, view_poses

    def project(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distorted pixels of every observation for parameters ``x``, shape (M, 2)."""
        intrinsics, cam_poses, view_poses = self.unpack(x)
        R_cam = Rotation.from_rotvec(cam_poses[:, :3]).as_matrix()
        R_view = Rotation.from_rotvec(view_poses[:, :3]).as_matrix()
        X_ref = np.einsum("mij,mj->mi", R_view[self.view], self.object_points) + view_poses[self.view, 3:]
        X_cam = np.einsum("mij,mj->mi", R_cam[self.camera], X_ref) + cam_poses[self.camera, 3:]
        k = intrinsics[self.camera]
        f, centre, d = k[:, 0:2], k[:, 2:4], k[:, 4:]
        if self.model == "kannala-brandt":
            rho = np.hypot(X_cam[:, 0], X_cam[:, 1])
            theta = np.arctan2(rho, X_cam[:, 2])
            t2 = theta * theta
            theta_d = theta * (1.0 + t2 * (d[:, 0] + t2 * (d[:, 1] + t2 * (d[:, 2] + t2 * d[:, 3]))))
            scale = np.where(rho > 0.0, theta_d / np.maximum(rho, 1e-300), 0.0)
            return centre + f * X_cam[:, :2] * scale[:, None]
        xy = X_cam[:, :2] / X_cam[:, 2:3]
        if self.model == "division":
            lam = d[:, 0] / self.division_scale[self.camera] ** 2
            offset = f * xy
            r2 = np.sum(offset**2, axis=1)
            scale = 2.0 / (1.0 + np.sqrt(np.maximum(1.0 - 4.0 * lam * r2, 0.0)))
            return centre + offset * scale[:, None]
        x_, y_ = xy[:, 0], xy[:, 1]
        r2 = x_ * x_ + y_ * y_
        k3 = d[:, 4] if self.model == "opencv" else 0.0
        radial = 1.0 + r2 * (d[:, 0] + r2 * (d[:, 1] + r2 * k3))
        xd, yd = x_ * radial, y_ * radial
        if self.model == "opencv":
            p1, p2 = d[:, 2], d[:, 3]
            xd = xd + 2.0 * p1 * x_ * y_ + p2 * (r2 + 2.0 * x_ * x_)
            yd = yd + p1 * (r2 + 2.0 * y_ * y_) + 2.0 * p2 * x_ * y_
        return centre + f * np.stack([xd, yd], axis=1)

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return (self.project(x) - self.detected).ravel()

    def sparsity(self) -> scipy.sparse.csr_matrix:
        """Which parameters each residual (2 per corner) depends on."""
        rows, cols = [], []
        index = np.arange(len(self.camera))

        def touch(col_start: NDArray[np.int64], width: int, mask: NDArray[np.bool_]) -> None:
            obs = index[mask]
            c = col_start[mask][:, None] + np.arange(width)
            for coordinate in (0, 1):
                rows.append(np.repeat(2 * obs + coordinate, width))
                cols.append(c.ravel())

        every = np.ones(len(index), dtype=bool)
        touch(self.camera * self.n_intrinsics, self.n_intrinsics, every)
        touch(self.pose_offset + 6 * (self.camera - 1), 6, self.camera > 0)
        touch(self.view_offset + 6 * self.view, 6, every)
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        return scipy.sparse.csr_matrix(
            (np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(2 * len(index), self.n_parameters)
        )

    def solve(self, x0: NDArray[np.float64]):
        return least_squares(
            self.residuals,
            x0,
            jac_sparsity=self.sparsity(),
            method="trf",
            x_scale="jac",
            ftol=1e-10,
            xtol=1e-10,
            gtol=1e-10,
            # tight inner (LSMR) tolerances: loose ones stall the outer iterations near the minimum
            tr_options={"atol": 1e-12, "btol": 1e-12},
            max_nfev=200,
        )


# -- inputs and initialisation -------------------------------------------------------


def _check_detections(
    detections: Mapping[str, Sequence[Detection]], board: Board
) -> tuple[list[str], list[dict[int, Detection]]]:
    """Camera names and, per camera, its detections keyed by frame number."""
    if not isinstance(detections, Mapping) or not detections:
        raise CamcalError("no cameras given")
    names = list(detections)
    by_frame = []
    for name in names:
        views = list(detections[name])
        if len(views) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: board found in {len(views)} images, need at least {MIN_IMAGES}")
        sizes = {d.image_size for d in views}
        if len(sizes) > 1:
            raise CamcalError(f"camera {name!r}: images of different sizes {sorted(sizes)}")
        for d in views:
            if len(d.ids) < 4 or np.any(d.ids < 0) or np.any(d.ids >= board.n_corners):
                raise CamcalError(f"camera {name!r}, {d.image}: corner ids do not fit the board {board.spec()}")
        if len(names) == 1:
            keyed = dict(enumerate(views))
        else:
            keyed = {}
            for d in views:
                number = frame_number(d.image)
                if number in keyed:
                    raise CamcalError(f"camera {name!r}: {keyed[number].image} and {d.image} have the same frame number {number}")
                keyed[number] = d
        by_frame.append(keyed)
    return names, by_frame


def _opencv_start(board: Board, views: Mapping[int, Detection], model: str, name: str):
    """OpenCV's calibrateCamera: K, distortion vector and cam_from_board per view."""
    keys = sorted(views)
    if model == "kannala-brandt":
        return _opencv_fisheye_start(board, views, keys, name)
    object_points = [board.object_points[views[k].ids].astype(np.float32) for k in keys]
    image_points = [views[k].corners_px.astype(np.float32).reshape(-1, 1, 2) for k in keys]
    try:
        _, K, dist, rvecs, tvecs = cv2.calibrateCamera(
            object_points, image_points, views[keys[0]].image_size, None, None, flags=_OPENCV_FLAGS[model]
        )
    except cv2.error as error:
        raise CamcalError(f"camera {name!r}: OpenCV calibrateCamera failed ({str(error).strip().splitlines()[-1]})") from None
    poses = {k: (cv2.Rodrigues(r)[0], t.ravel()) for k, r, t in zip(keys, rvecs, tvecs)}
    return K, dist.ravel(), poses


def _fisheye_flags(*names: str) -> int:
    """OpenCV's fisheye calibration flags (OpenCV 4 keeps them in ``cv2.fisheye``, OpenCV 5 in ``cv2``)."""
    return sum(getattr(cv2.fisheye, n, None) or getattr(cv2, n) for n in names)


def _opencv_fisheye_start(board: Board, views: Mapping[int, Detection], keys: list[int], name: str):
    """``cv2.fisheye.calibrate`` (skew fixed at 0): K, (k1..k4) and cam_from_board per view.

    Two stages: k1, k2 only (k3 = k4 = 0), then all four from there
    (``CALIB_USE_INTRINSIC_GUESS``); OpenCV's own start for the four at
    once can wander off on wide lenses.
    """
    object_points = [board.object_points[views[k].ids].reshape(1, -1, 3).astype(np.float64) for k in keys]
    image_points = [views[k].corners_px.reshape(1, -1, 2).astype(np.float64) for k in keys]
    flags = _fisheye_flags("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW")
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    size = views[keys[0]].image_size
    try:
        _, K, dist, _, _ = cv2.fisheye.calibrate(
            object_points, image_points, size, None, None,
            flags=flags | _fisheye_flags("CALIB_FIX_K3", "CALIB_FIX_K4"), criteria=criteria,
        )
        _, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
            object_points, image_points, size, K, dist,
            flags=flags | _fisheye_flags("CALIB_USE_INTRINSIC_GUESS"), criteria=criteria,
        )
    except cv2.error as error:
        raise CamcalError(
            f"camera {name!r}: OpenCV fisheye.calibrate failed ({str(error).strip().splitlines()[-1]})"
        ) from None
    poses = {k: (cv2.Rodrigues(r)[0], np.asarray(t, dtype=np.float64).ravel()) for k, r, t in zip(keys, rvecs, tvecs)}
    return K, np.asarray(dist, dtype=np.float64).ravel(), poses


def _initial_distortion(model: str, K: NDArray, dist: NDArray, scale: float) -> list[float]:
    if model == "kannala-brandt":
        return [dist[0], dist[1], dist[2], dist[3]]
    if model == "polynomial":
        return [dist[0], dist[1]]
    if model == "opencv":
        return [dist[0], dist[1], dist[2], dist[3], dist[4]]
    # division: x_d ~ x_u (1 - lambda r^2) to first order, so lambda = -k1 / f^2 (scaled by s^2)
    return [-dist[0] / (0.5 * (K[0, 0] + K[1, 1])) ** 2 * scale**2]


def _camera_poses(names: list[str], starts: list[dict]) -> list[tuple[NDArray, NDArray]]:
    """cam_from_reference of every camera, by breadth-first chaining over shared views."""
    poses: list = [None] * len(names)
    poses[0] = (np.eye(3), np.zeros(3))
    queue = deque([0])
    while queue:
        i = queue.popleft()
        for j in range(len(names)):
            if poses[j] is None and set(starts[i]) & set(starts[j]):
                R_ji, t_ji = _relative_pose(starts[i], starts[j])
                R_i, t_i = poses[i]
                poses[j] = (R_ji @ R_i, R_ji @ t_i + t_ji)
                queue.append(j)
    missing = [names[j] for j in range(len(names)) if poses[j] is None]
    if missing:
        raise CamcalError(f"camera(s) {', '.join(missing)} share no frame with the others: cannot place them in the rig")
    return poses


# -- the public entry point ------------------------------------------------------------


def calibrate_board(
    board: Board,
    detections: Mapping[str, Sequence[Detection]],
    model: str = "polynomial",
    units: str = "m",
    outlier_factor: float = 3.0,
    min_outlier_px: float = 1.0,
) -> CalibrationResult:
    """Calibrate one camera or an N-camera rig from images of a planar board.

    Parameters
    ----------
    board : Board
        The target; its square size sets the unit of every length.
    detections : mapping of str to sequence of Detection
        Camera name -> the board detections of its images (from
        :func:`camcal.geometry.board.detect_in_images`). The first camera
        is the reference. With several cameras, views are matched by the
        frame number in the image file names.
    model : str
        ``polynomial`` (k1, k2), ``opencv`` (k1, k2, p1, p2, k3),
        ``division`` (Strand & Hayman lambda, centred on the principal point)
        or ``kannala-brandt`` (fisheye k1..k4).
    units : str
        Name of the board's length unit, stored in the rig.
    outlier_factor, min_outlier_px : float
        An image is an outlier when its RMS exceeds
        ``max(outlier_factor x median image RMS, min_outlier_px)``.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CamcalError
        Unknown model, fewer than :data:`MIN_IMAGES` usable images for a
        camera, a camera sharing no frame with the others, or a degenerate
        problem.

    Notes
    -----
    Minimises ``sum_ij |pi_j(K_j, d_j, T_j T_i X) - x_ij|^2`` over the
    intrinsics ``K_j`` and distortion ``d_j`` of every camera ``j``, its
    pose ``T_j`` (``cam_from_reference``, identity for the reference) and
    the board pose ``T_i`` of every view ``i``; then
    ``Sigma = sigma^2 (J^T J)^-1``, ``sigma^2 = |r|^2 / (2M - n)``.
    """
    if model not in MODELS:
        raise CamcalError(f"unknown distortion model {model!r}, expected one of: {', '.join(MODELS)}")
    names, by_frame = _check_detections(detections, board)
    starts, intrinsics, scales = [], [], []
    for name, views in zip(names, by_frame):
        K, dist, poses = _opencv_start(board, views, model, name)
        scale = max(next(iter(views.values())).image_size) / 2.0
        starts.append(poses)
        scales.append(scale)
        intrinsics.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *_initial_distortion(model, K, dist, scale)])
    cam_poses = _camera_poses(names, starts)

    # every frame seen by any camera is one board pose, first placed by the lowest camera seeing it
    frames = sorted(set().union(*[set(v) for v in by_frame]))
    observed = {(j, f) for j, views in enumerate(by_frame) for f in views}
    outliers: list[tuple[int, int]] = []
    x_cams = np.concatenate([np.ravel(intrinsics)] + [np.r_[Rotation.from_matrix(R).as_rotvec(), t] for R, t in cam_poses[1:]])
    view_start = {}
    for f in frames:
        j = min(j for j in range(len(names)) if f in by_frame[j])
        R_j, t_j = cam_poses[j]
        R_b, t_b = starts[j][f]
        view_start[f] = np.r_[Rotation.from_matrix(R_j.T @ R_b).as_rotvec(), R_j.T @ (t_b - t_j)]

    for round_ in range(_MAX_OUTLIER_ROUNDS + 1):
        kept = sorted(observed - set(outliers))
        kept_frames = sorted({f for _, f in kept})
        frame_index = {f: n for n, f in enumerate(kept_frames)}
        for j, name in enumerate(names):
            n_left = sum(1 for jj, _ in kept if jj == j)
            if n_left < MIN_IMAGES:
                raise CamcalError(f"camera {name!r}: only {n_left} images left after dropping outliers, need {MIN_IMAGES}")
        det = [by_frame[j][f] for j, f in kept]
        problem = _Problem(
            model=model,
            n_cameras=len(names),
            n_views=len(kept_frames),
            object_points=np.concatenate([board.object_points[d.ids] for d in det]),
            detected=np.concatenate([d.corners_px for d in det]),
            camera=np.concatenate([np.full(len(d.ids), j) for (j, _), d in zip(kept, det)]),
            view=np.concatenate([np.full(len(d.ids), frame_index[f]) for (_, f), d in zip(kept, det)]),
            division_scale=np.asarray(scales),
        )
        x0 = np.concatenate([x_cams, *[view_start[f] for f in kept_frames]])
        solution = problem.solve(x0)
        if not np.all(np.isfinite(solution.fun)):
            raise CamcalError("the joint refinement diverged (non-finite residuals): check the detections")
        x_cams = solution.x[: problem.view_offset]
        for f in kept_frames:
            view_start[f] = solution.x[problem.view_offset + 6 * frame_index[f] :][:6]
        residuals = solution.fun.reshape(-1, 2)
        image_of_point = np.concatenate([np.full(len(d.ids), n) for n, d in enumerate(det)])
        squared = np.bincount(image_of_point, np.sum(residuals**2, axis=1)) / np.bincount(image_of_point)
        image_rms = np.sqrt(squared)
        threshold = max(outlier_factor * np.median(image_rms), min_outlier_px)
        new = [kept[n] for n in np.flatnonzero(image_rms > threshold)]
        if not new or round_ == _MAX_OUTLIER_ROUNDS:
            break
        outliers.extend(new)

    covariance, names_out = _camera_covariance(problem, solution, names)
    rig = _build_rig(problem, solution.x, names, by_frame, kept, residuals, image_of_point, covariance, names_out, board, model, units)
    norms = np.linalg.norm(residuals, axis=1)
    return CalibrationResult(
        rig=rig,
        residuals_px=residuals,
        points_px=problem.detected,
        camera_of_point=problem.camera,
        image_of_point=image_of_point,
        images=tuple((names[j], by_frame[j][f].image) for j, f in kept),
        rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()),
        outliers=tuple((names[j], by_frame[j][f].image) for j, f in sorted(outliers)),
        covariance=covariance,
        parameter_names=names_out,
    )


def _camera_covariance(problem: _Problem, solution, names: list[str]) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """``sigma^2 (J^T J)^-1`` restricted to the camera parameters (board poses marginalised)."""
    J = scipy.sparse.csr_matrix(solution.jac)
    m, n = J.shape
    if m <= n:
        raise CamcalError(f"too few corners for the parameters: {m // 2} corners for {n} unknowns")
    sigma2 = float(solution.fun @ solution.fun) / (m - n)
    JtJ = (J.T @ J).toarray()
    wanted = np.arange(problem.view_offset)
    try:
        block = np.linalg.solve(JtJ, np.eye(n)[:, wanted])[wanted]
    except np.linalg.LinAlgError:
        raise CamcalError("the calibration is degenerate (singular normal equations): vary the board poses more") from None
    # undo the scaling of the division parameter: lambda = lambda' / s^2
    factors = np.ones(len(wanted))
    labels = []
    for j, name in enumerate(names):
        for p, label in enumerate(_INTRINSICS + MODELS[problem.model]):
            labels.append(f"{name}.{label}")
            if label == "lambda":
                factors[j * problem.n_intrinsics + p] = 1.0 / problem.division_scale[j] ** 2
    for name in names[1:]:
        labels.extend(f"{name}.{label}" for label in ("rx", "ry", "rz", "tx", "ty", "tz"))
    return sigma2 * block * np.outer(factors, factors), tuple(labels)


def _pose_sigmas(rt: NDArray[np.float64], covariance: NDArray[np.float64]) -> tuple[float, float]:
    """One-sigma of the baseline |c| and rotation angle of a ``cam_from_reference`` pose.

    First-order propagation ``sigma_g^2 = g^T Sigma g`` with the gradient of
    ``|c| = |R(r)^T t|`` and of ``|r|`` by central differences.
    """
    def baseline(p: NDArray[np.float64]) -> float:
        return float(np.linalg.norm(Rotation.from_rotvec(p[:3]).as_matrix().T @ p[3:]))

    step = 1e-7 * max(1.0, float(np.abs(rt).max()))
    gradient = np.array([(baseline(rt + step * e) - baseline(rt - step * e)) / (2 * step) for e in np.eye(6)])
    angle_gradient = np.r_[rt[:3] / max(np.linalg.norm(rt[:3]), 1e-12), np.zeros(3)]
    return (
        float(np.sqrt(max(gradient @ covariance @ gradient, 0.0))),
        float(np.degrees(np.sqrt(max(angle_gradient @ covariance @ angle_gradient, 0.0)))),
    )


def _build_rig(problem, x, names, by_frame, kept, residuals, image_of_point, covariance, labels, board, model, units) -> Rig:
    intrinsics, cam_poses, _ = problem.unpack(x)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    sigma_by_label = dict(zip(labels, sigma))
    cameras = []
    for j, name in enumerate(names):
        fx, fy, cx, cy, *d = intrinsics[j]
        if model == "division":
            d = [d[0] / problem.division_scale[j] ** 2]
        R = Rotation.from_rotvec(cam_poses[j, :3]).as_matrix()
        c = -R.T @ cam_poses[j, 3:]
        mine = problem.camera == j
        norms = np.linalg.norm(residuals[mine], axis=1)
        sigmas = {label: float(sigma_by_label[f"{name}.{label}"]) for label in _INTRINSICS + MODELS[model]}
        if j > 0:
            start = problem.pose_offset + 6 * (j - 1)
            block = covariance[start : start + 6, start : start + 6]
            sigmas["baseline"], sigmas["rotation_deg"] = _pose_sigmas(cam_poses[j], block)
        cameras.append(
            Camera(
                name=name,
                image_size=by_frame[j][next(iter(by_frame[j]))].image_size,
                K=np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
                distortion=Distortion(model, dict(zip(MODELS[model], d))),
                R=R if j else np.eye(3),
                c=c if j else np.zeros(3),
                quality={
                    "rms_px": float(np.sqrt(np.mean(norms**2))),
                    "worst_px": float(norms.max()),
                    "n_views": int(len(np.unique(image_of_point[mine]))),
                    "n_points": int(mine.sum()),
                    "sigma": sigmas,
                },
            )
        )
    method = "chessboard" if board.kind == "chessboard" else "charuco"
    return Rig(tuple(cameras), units=units, provenance=make_provenance(method, board=board.spec(), model=model))


# -- report ------------------------------------------------------------------------------


def _palette(n: int) -> list[tuple[int, int, int]]:
    """``n`` distinct BGR colours (hues spread evenly)."""
    return [tuple(int(255 * v) for v in colorsys.hsv_to_rgb(i / max(n, 1), 0.85, 0.8)[::-1]) for i in range(n)]


def _write_png(path: Path, image: NDArray[np.uint8]) -> Path:
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image):
            raise CamcalError(f"cannot write {path}")
    return path


def write_report(result: CalibrationResult, directory: str | os.PathLike) -> list[Path]:
    """PNG plots of a calibration, written atomically into ``directory``.

    Per camera, ``residuals_<camera>.png`` (every corner with its
    reprojection residual magnified, over the image frame) and
    ``coverage_<camera>.png`` (the corners of each image in its own colour,
    with the board outline); for the whole rig, ``per_image_rms.png``
    (RMS of each image kept, one bar per image, cameras in turn, the
    median as a line).

    Returns
    -------
    list of Path
        The files written.
    """
    directory = Path(directory)
    written = []
    norms = np.linalg.norm(result.residuals_px, axis=1)
    for j, camera in enumerate(result.rig.cameras):
        width, height = camera.image_size
        mine = result.camera_of_point == j
        points, residuals = result.points_px[mine], result.residuals_px[mine]
        gain = 0.03 * np.hypot(width, height) / max(np.percentile(norms[mine], 99), 1e-9)
        canvas = np.full((height, width, 3), 255, np.uint8)
        for p, r in zip(points, residuals):
            start = tuple(int(v) for v in np.round(p))
            end = tuple(int(v) for v in np.round(p + gain * r))
            cv2.line(canvas, start, end, (40, 40, 200), 1, cv2.LINE_AA)
            cv2.circle(canvas, start, 1, (0, 0, 0), -1)
        cv2.putText(canvas, f"{camera.name}: residuals x{gain:.0f}, RMS {camera.quality['rms_px']:.3f} px",
                    (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        written.append(_write_png(directory / f"residuals_{camera.name}.png", canvas))

        canvas = np.full((height, width, 3), 255, np.uint8)
        images = np.unique(result.image_of_point[mine])
        for image, colour in zip(images, _palette(len(images))):
            corners = result.points_px[result.image_of_point == image]
            hull = cv2.convexHull(corners.astype(np.float32)).astype(np.int32)
            cv2.polylines(canvas, [hull], True, colour, 1, cv2.LINE_AA)
            for p in corners:
                cv2.circle(canvas, tuple(int(v) for v in np.round(p)), 2, colour, -1)
        cv2.putText(canvas, f"{camera.name}: corner coverage, {len(images)} images",
                    (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        written.append(_write_png(directory / f"coverage_{camera.name}.png", canvas))

    rms = list(result.per_image_rms_px.items())
    bar, margin, plot_height = 14, 40, 300
    canvas = np.full((plot_height + 2 * margin, 2 * margin + bar * len(rms), 3), 255, np.uint8)
    top = max(value for _, value in rms)
    colours = _palette(len(result.rig.cameras))
    index_of = {camera.name: j for j, camera in enumerate(result.rig.cameras)}
    for n, ((camera, _), value) in enumerate(rms):
        x = margin + n * bar
        y = margin + plot_height - int(plot_height * value / top)
        cv2.rectangle(canvas, (x + 1, y), (x + bar - 2, margin + plot_height), colours[index_of[camera]], -1)
    median_y = margin + plot_height - int(plot_height * np.median([v for _, v in rms]) / top)
    cv2.line(canvas, (margin, median_y), (canvas.shape[1] - margin, median_y), (0, 0, 0), 1)
    cv2.putText(canvas, f"RMS per image (max {top:.3f} px, line = median)", (10, 25),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    written.append(_write_png(directory / "per_image_rms.png", canvas))
    return written
