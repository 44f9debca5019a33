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
   On a chessboard that is symmetric under a half turn (``W + H`` even)
   or printed on both sides (a camera behind it sees it mirrored) the
   corner labelling of a view may differ between cameras: each
   non-reference view takes the labelling (as detected, turned by a half
   turn, or mirrored: :mod:`camcal.geometry.labelling`) whose relative
   pose agrees with the consensus of the cameras labelled before it; a
   view that agrees with none is dropped and reported.
3. ONE bundle adjustment (:mod:`camcal.geometry.bundle`, pycolmap's Ceres
   adjuster) refines every camera's intrinsics and distortion, every
   camera-to-reference pose (``sensor_from_rig``) and every board pose (one
   frame per view, ``rig_from_board``), the board's corners being constant
   points: the board's frame is the world. camcal's models are COLMAP's
   exactly: ``polynomial`` is ``OPENCV`` with p1 = p2 = 0 held, ``opencv``
   is ``FULL_OPENCV`` with k4 = k5 = k6 = 0 held, ``division`` is
   ``DIVISION`` (two focal lengths: the lens's ``aspect`` is ``fx / fy``,
   so non-square pixels and anamorphic squeezes are estimated),
   ``kannala-brandt`` is ``OPENCV_FISHEYE`` and
   ``kannala-brandt-thin-prism`` is ``RAD_TAN_THIN_PRISM_FISHEYE``.
4. Images whose RMS is far above the median (``> max(outlier_factor x
   median, min_outlier_px)``) are dropped, reported, and the problem is
   solved again.
5. Uncertainty: ``Sigma = sigma^2 (J^T J)^-1`` at the solution (Ceres'
   covariance), with ``sigma^2 = 2 cost / (m - n)``; the board poses are
   marginalised out. These sigmas measure sampling noise of the corners,
   not model error.
6. Held-out views (``holdout``) are not used in the fit; each is then
   posed by PnP with the fitted intrinsics held (the same engine, one frame
   per view) and their RMS is reported beside the training RMS. With
   ``model="auto"`` every model of :data:`AUTO_MODELS` is fitted with
   every 4th training frame held out, the simplest within 1 % of the
   lowest RMS on those is kept and fitted on all training frames: the
   choice never sees ``holdout``. One camera with enough views: the best
   model is also scored with a smooth correction field over the image
   (``<model>+spline``, :mod:`camcal.geometry.spline_fit`), taken only
   when it is better held out by more than 1 % and by more than one
   standard error of the paired per-view differences.
7. The board's shape (one camera, ``board_shape``): the chosen model is
   also scored on the same folds with the board's surface fitted
   (:mod:`camcal.geometry.board_shape`: Legendre heights of total degree
   2..d, every corner's height free, with or without the corners'
   in-plane displacement; the flat fit's K, lens and poses refined with
   it), each fold's held-out views posed against that fold's board, and a
   shape is taken by the correction field's rule. The lens model is then
   ranked again on that surface (every model the surface is fitted with,
   the same folds, the simplest within 1 % of the best), the shape chosen
   again for a new lens, and the correction field scored on top of the
   surface (taken by its rule). A shape can be named, or given and held
   (a rig seeing the same board again).

Conventions: ``x ~ K [R | -R c] X`` with ``R`` world -> camera; the world
is the reference camera's frame (``R = I``, ``c = 0``); lengths are in the
board's units (its square size); pixel (0, 0) is the centre of the
top-left pixel; skew is fixed at 0 (COLMAP's models have none).
Distortion models (see :mod:`camcal.model.distortion`): ``polynomial``
(k1, k2), ``opencv`` (k1, k2, p1, p2, k3) or ``division`` (Strand & Hayman
lambda in 1/px^2, centred on the principal point, radius in x pixels with
``aspect = fx / fy``; OpenCV has no such model: it is initialised from
OpenCV's k1 as ``lambda = -k1 / fx^2``) or ``kannala-brandt`` (k1..k4 of
OpenCV's fisheye model) or ``kannala-brandt-thin-prism`` (k1..k6, p1, p2,
s1..s4; started from OpenCV's fisheye fit, the rest at 0).

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

import dataclasses
import math
from collections import deque
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection, frame_number, opencv_threads_off
from camcal.geometry.board_shape import (AUTO_SHAPES, SHAPE_SPECS, BoardShape, fit_board_shape, max_degree,
                                        n_shape_params, parse_shape)
from camcal.geometry.bundle import BoardObservations, BundleOptions, BundleState, bundle_adjust
from camcal.geometry.bundle import residuals as board_residuals
from camcal.geometry.bundle.solve import GAUGE_NAMES
from camcal.geometry.labelling import resolve_labellings
from camcal.geometry.spline_fit import fit_spline_lens, grid_shape, pose_view
from camcal.geometry.tde4_fit import FITTED_PARAMS as TDE4_FITTED_PARAMS
from camcal.geometry.tde4_fit import fit_tde4_lens
from camcal.geometry.uncertainty import GAUGE, POSE, projection_sigma, sigma_grid
from camcal.geometry.view_jackknife import design_effect, view_jackknife
from camcal.model.camera import chordal_mean_rotation, rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.model.quality import ParameterCovariance, Quality
from camcal.model.rig import Camera, Rig, make_provenance
from camcal.model.tde4 import LDPK_PARAMETERS, TDE4_MODELS

__all__ = ["MODELS", "AUTO_MODELS", "AUTO_MARGIN", "BOARD_SHAPES", "MIN_IMAGES", "SPLINE_MIN_VIEWS", "SPLINE_SUFFIX",
           "ModelScore", "CalibrationResult", "calibrate_board", "quality_problems", "fold_radius_px"]

#: Lens models a board calibration fits and the distortion parameters refined for each.
MODELS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {"none": (), "division": ("lambda",), "polynomial": ("k1", "k2"), "kannala-brandt": ("k1", "k2", "k3", "k4"),
     "opencv": ("k1", "k2", "p1", "p2", "k3"),
     "opencv-rational": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
     "opencv-thin-prism": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
     "kannala-brandt-thin-prism": ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "s1", "s2", "s3", "s4")}
)
#: The models ``model="auto"`` chooses among, simplest first (the parsimony order): every model.
AUTO_MODELS = ("none", "division", "polynomial", "kannala-brandt", "opencv", "opencv-rational", "opencv-thin-prism",
               "kannala-brandt-thin-prism")
#: ``model="auto"`` keeps the simplest model whose cross-validated RMS is within this share of the best.
AUTO_MARGIN = 0.01
#: The camcal distortion model of each fitted lens model.
_LENS = {"opencv-rational": "opencv", "opencv-thin-prism": "opencv"}
#: Fewest images with the board per camera.
MIN_IMAGES = 3
_INTRINSICS = ("fx", "fy", "cx", "cy")
_OPENCV_FLAGS = {
    "none": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
    "polynomial": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    "opencv": 0,
    "opencv-rational": cv2.CALIB_RATIONAL_MODEL,
    "opencv-thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
    "division": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
}
_MAX_OUTLIER_ROUNDS = 3
#: camcal model -> the COLMAP model that is exactly it, and the COLMAP parameters held at 0.
_COLMAP_MODELS: Mapping[str, tuple[str, tuple[str, ...]]] = MappingProxyType({
    "none": ("PINHOLE", ()),
    "polynomial": ("OPENCV", ("p1", "p2")),
    "opencv": ("FULL_OPENCV", ("k4", "k5", "k6")),
    "opencv-rational": ("FULL_OPENCV", ()),
    "division": ("DIVISION", ()),
    "kannala-brandt": ("OPENCV_FISHEYE", ()),
    "kannala-brandt-thin-prism": ("RAD_TAN_THIN_PRISM_FISHEYE", ()),
})
#: The Kannala-Brandt models: started from ``cv2.fisheye``, corners beyond 90 degrees left out.
_FISHEYE = ("kannala-brandt", "kannala-brandt-thin-prism")
#: camcal parameter -> COLMAP parameter where the names differ (RAD_TAN_THIN_PRISM_FISHEYE's k0..k5, p0, s0..s3).
_COLMAP_NAMES = {"kannala-brandt-thin-prism": {"k1": "k0", "k2": "k1", "k3": "k2", "k4": "k3", "k5": "k4", "k6": "k5",
                                               "p1": "p1", "p2": "p0", "s1": "s0", "s2": "s1", "s3": "s2", "s4": "s3"}}
#: Quality gate (:func:`quality_problems`): a calibration beyond these is not written without --force.
MAX_RMS_PX = 1.5
MAX_FOCAL_SIGMA_REL = 0.05


@dataclass(frozen=True)
class ModelScore:
    """One lens model's cross-validated error in ``model="auto"``.

    Attributes
    ----------
    model : str
        A name of :data:`MODELS`.
    rms_px : float or None
        RMS over every held-out view of every fold (each view posed by PnP
        with the fold's intrinsics held), in pixels; None when ranked out.
    n_params : int
        Lens parameters (focal lengths, principal point, distortion).
    reason : str
        Why the model was ranked out (empty when scored).
    """

    model: str
    rms_px: float | None
    n_params: int
    reason: str = ""

    def describe(self) -> str:
        """``opencv-rational  0.3821 px  (12 parameters)`` or ``... ranked out: <reason>``."""
        if self.rms_px is None:
            return f"{self.model}: ranked out: {self.reason}"
        return f"{self.model}: {self.rms_px:.4f} px held out ({self.n_params} parameters)"


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated camera or rig with its residuals and uncertainty.

    Attributes
    ----------
    rig : Rig
        The cameras; the first is the reference (``R = I``, ``c = 0``),
        lengths in the board's units. Each camera's ``quality`` holds
        ``rms_px``, ``worst_px``, ``n_views``, ``n_observations``,
        ``heldout_rms_px`` (with held-out views) and ``sigma`` (one-sigma of
        fx, fy, cx, cy, the distortion parameters and, for the other
        cameras, ``rotation_deg``, ``baseline_rel`` and
        ``baseline_direction_deg`` from the reference; see
        :mod:`camcal.model.quality`).
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
        (``cam_from_reference``: rotation vector applied on the left, and translation).
    model : str
        The distortion model fitted (the one chosen when ``model="auto"``).
    heldout_rms_px : float or None
        RMS over the held-out views (PnP with the intrinsics held), in pixels.
    heldout_images : tuple of (str, str)
        ``(camera name, image name)`` of the held-out views.
    heldout_view_rms_px : tuple of float
        The RMS of each held-out view, in the order of :attr:`heldout_images`.
    model_heldout_rms_px : dict of str to float
        ``model="auto"``: the cross-validated RMS of every model that could
        be fitted (:func:`_rank_models`).
    model_ranking : tuple of ModelScore
        ``model="auto"``: every model, best first, those ranked out last
        with their reason (:meth:`ModelScore.describe` prints one line each).
    relabelled : tuple of (str, str)
        Views whose corner labelling was turned by a half turn or mirrored
        (seen from the back) to agree with the rig (symmetric or two-sided
        chessboards only; :attr:`notes` says which).
    dropped : tuple of (str, str)
        Views dropped because no labelling agreed with the rig.
    notes : tuple of str
        Constraints the fit imposed beyond the model's definition.
    board_poses : tuple of (int, ndarray, ndarray)
        ``(frame, R, t)`` of every frame solved: ``reference_from_board``
        (a board point ``X`` is at ``R X + t`` in the reference camera's
        coordinates), in the board's units.
    heldout_residuals_px, heldout_points_px : ndarray, shape (H, 2)
        ``projected - detected`` and the detected corners of the held-out views.
    heldout_camera_of_point : ndarray of int, shape (H,)
        Index into ``rig.cameras`` of each held-out corner.
    board_shape : BoardShape or None
        The board's fitted surface (:mod:`camcal.geometry.board_shape`); None for a flat board. The held-out
        views are posed against it; the rig's ``provenance.board_shape`` stores it.
    shape_ranking : tuple of ModelScore
        ``board_shape="auto"``: the flat board and every shape scored (``<model>@board-<shape>``), best first,
        scored on the same folds as the lens models.
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
    model: str = "polynomial"
    heldout_rms_px: float | None = None
    heldout_images: tuple[tuple[str, str], ...] = ()
    heldout_view_rms_px: tuple[float, ...] = ()
    model_heldout_rms_px: Mapping[str, float] = field(default_factory=dict)
    model_ranking: tuple[ModelScore, ...] = ()
    relabelled: tuple[tuple[str, str], ...] = ()
    dropped: tuple[tuple[str, str], ...] = ()
    notes: tuple[str, ...] = ()
    board_poses: tuple[tuple[int, NDArray[np.float64], NDArray[np.float64]], ...] = ()
    heldout_residuals_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    heldout_points_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    heldout_camera_of_point: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    board_shape: BoardShape | None = None
    shape_ranking: tuple[ModelScore, ...] = ()

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
        """``RMS reprojection error: 0.19 px (worst 0.84 px, 3 outliers of 50 images)``, held-out RMS beside."""
        text = (
            f"RMS reprojection error: {self.rms_px:.3f} px (worst {self.worst_px:.3f} px, "
            f"{self.n_outliers} outlier images of {len(self.images) + self.n_outliers}, "
            f"{len(self.residuals_px)} corners)"
        )
        if self.heldout_rms_px is not None:
            text += f"; held-out RMS {self.heldout_rms_px:.4f} px over {len(self.heldout_images)} views (training {self.rms_px:.4f} px)"
        return text


# -- poses -------------------------------------------------------------------------


def _average_rotation(rotations: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Robust chordal mean of rotations (K, 3, 3) and the inlier mask.

    Notes
    -----
    Start from the medoid (least summed angle to the others), keep the
    rotations within ``max(1 deg, 3 x median angle)`` of it, and return
    their chordal L2 mean (:func:`camcal.model.camera.chordal_mean_rotation`).
    """
    def angles(reference: NDArray[np.float64], many: NDArray[np.float64]) -> NDArray[np.float64]:
        cosine = (np.einsum("ij,kij->k", reference, many) - 1.0) / 2.0
        return np.arccos(np.clip(cosine, -1.0, 1.0))

    pairwise = np.array([angles(R, rotations) for R in rotations])
    medoid = rotations[np.argmin(pairwise.sum(axis=1))]
    distance = angles(medoid, rotations)
    inliers = distance <= max(np.radians(1.0), 3.0 * np.median(distance))
    return chordal_mean_rotation(rotations[inliers]), inliers


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
        numbers = [_frame_number_or_none(d.image) for d in views]
        if len(names) == 1 and (None in numbers or len(set(numbers)) < len(numbers)):
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


def _frame_number_or_none(name: str) -> int | None:
    try:
        return frame_number(name)
    except CamcalError:
        return None


def _opencv_start(board: Board, views: Mapping[int, Detection], model: str, name: str, shared: dict | None = None):
    """OpenCV's calibrateCamera: K, distortion vector and cam_from_board per view.

    ``shared``: the fits that do not depend on the model (the pinhole check below, ``cv2.fisheye``'s start),
    by camera and views, made once for every model fitted to the same views (:func:`_rank_models`' folds).

    With few views OpenCV's own start can diverge (a focal length ten times
    off). The start is therefore checked against a plain pinhole fit
    (no distortion, principal point at the image centre: few unknowns, it
    does not diverge): when the model's fit is not finite, fits worse than
    that pinhole, or puts the focal length off it by more than a factor of
    two, the model is fitted again from the pinhole's K
    (``CALIB_USE_INTRINSIC_GUESS``), and failing that the pinhole itself
    (zero distortion) is the start.
    """
    keys = sorted(views)
    shared = {} if shared is None else shared
    if model in _FISHEYE:
        key = (name, "fisheye", tuple(keys))
        if key not in shared:
            shared[key] = _opencv_fisheye_start(board, views, keys, name)
        K, dist, poses = shared[key]
        return K.copy(), dist.copy(), dict(poses)
    object_points = [board.object_points[views[k].ids].astype(np.float32) for k in keys]
    image_points = [views[k].corners_px.astype(np.float32).reshape(-1, 1, 2) for k in keys]
    size = views[keys[0]].image_size

    def fit(flags: int, K=None, dist=None):
        try:
            rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(object_points, image_points, size, K, dist, flags=flags)
        except cv2.error as error:
            return None, _one_line(error)
        values = np.concatenate([K.ravel(), dist.ravel(), np.ravel(rvecs), np.ravel(tvecs)])
        return ((rms, K, dist, rvecs, tvecs) if np.all(np.isfinite(values)) and np.isfinite(rms) else None), ""

    key = (name, "pinhole", tuple(keys))
    if key not in shared:
        shared[key] = fit(_OPENCV_FLAGS["none"] | cv2.CALIB_FIX_PRINCIPAL_POINT)
    plain, reason = shared[key]
    if plain is None:
        raise CamcalError(f"camera {name!r}: OpenCV calibrateCamera failed ({reason or 'non-finite result'})")

    def sound(candidate) -> bool:
        return (candidate is not None and candidate[0] <= plain[0] * (1.0 + 1e-9)
                and all(0.5 < candidate[1][i, i] / plain[1][i, i] < 2.0 for i in (0, 1)))

    chosen, _ = fit(_OPENCV_FLAGS[model])
    if not sound(chosen):
        chosen, _ = fit(_OPENCV_FLAGS[model] | cv2.CALIB_USE_INTRINSIC_GUESS, plain[1].copy(), None)
    if not sound(chosen):
        chosen = plain
    _, K, dist, rvecs, tvecs = chosen
    poses = {k: (cv2.Rodrigues(r)[0], t.ravel().copy()) for k, r, t in zip(keys, rvecs, tvecs)}
    return K.copy(), dist.ravel().copy(), poses


def _poses_in_front(board: Board, views: Mapping[int, Detection], K: NDArray, dist: NDArray,
                    poses: Mapping[int, tuple[NDArray, NDArray]]) -> dict[int, tuple[NDArray, NDArray]]:
    """The start poses with every corner in front of the camera (``z > 0``).

    A view whose corners nearly line up (a strip of a board) can get a
    mirrored pose from OpenCV's start, with the board behind the camera,
    where no pinhole model images it. Such a view is posed again by
    ``solvePnP`` (IPPE, then iterative) with the start's K and distortion;
    a view still behind the camera is left out of the result.
    """
    kept = {}
    for f, (R, t) in poses.items():
        X = board.object_points[views[f].ids]
        if np.all(X @ R.T @ [0.0, 0.0, 1.0] + t[2] > 0.0):
            kept[f] = (R, t)
            continue
        for method in (cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_ITERATIVE):
            try:
                ok, rvec, tvec = cv2.solvePnP(X, views[f].corners_px, K, dist, flags=method)
            except cv2.error:
                continue
            if ok:
                R_new, t_new = cv2.Rodrigues(rvec)[0], tvec.ravel()
                if np.all((X @ R_new.T + t_new)[:, 2] > 0.0):
                    kept[f] = (R_new, t_new)
                    break
    return kept


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


def _corners_in_front(board: Board, by_frame: list[dict], starts: list[dict],
                      max_angle_deg: float = 89.0) -> tuple[list[dict], int]:
    """The detections without the corners whose ray, at the start pose, is beyond ``max_angle_deg`` off axis.

    A fisheye sees corners behind its image plane; the engine's
    ``OPENCV_FISHEYE`` (like COLMAP) cannot image them. Returns the
    filtered detections (a view left with fewer than 4 corners is dropped)
    and the number of corners left out.
    """
    cos_limit = np.cos(np.radians(max_angle_deg))
    kept_views, n_left_out = [], 0
    for views, poses in zip(by_frame, starts):
        kept = {}
        for f, d in views.items():
            R, t = poses[f]
            X = board.object_points[d.ids] @ R.T + t
            front = X[:, 2] > cos_limit * np.linalg.norm(X, axis=1)
            n_left_out += int(np.sum(~front))
            if front.all():
                kept[f] = d
            elif front.sum() >= 4:
                kept[f] = dataclasses.replace(d, ids=d.ids[front], corners_px=d.corners_px[front])
        kept_views.append(kept)
    return kept_views, n_left_out


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


# -- COLMAP parameters <-> camcal cameras -----------------------------------------------------


def _colmap_params(model: str, K: NDArray, dist: NDArray) -> NDArray[np.float64]:
    """COLMAP's parameter vector (pixel centre at 0.5) from OpenCV's K and distortion vector."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    if model == "none":
        return np.array([fx, fy, cx, cy])
    if model == "polynomial":
        return np.array([fx, fy, cx, cy, dist[0], dist[1], 0.0, 0.0])
    if model in ("opencv", "opencv-rational"):  # FULL_OPENCV: k1 k2 p1 p2 k3 k4 k5 k6, OpenCV's order
        vector = np.zeros(8)
        vector[:len(dist[:8 if model == "opencv-rational" else 5])] = dist[:8 if model == "opencv-rational" else 5]
        return np.concatenate([[fx, fy, cx, cy], vector])
    if model == "kannala-brandt":  # OpenCV's fisheye vector is COLMAP's OPENCV_FISHEYE k1..k4
        return np.array([fx, fy, cx, cy, dist[0], dist[1], dist[2], dist[3]])
    if model == "kannala-brandt-thin-prism":  # k0..k3 from OpenCV's fisheye k1..k4, the rest at 0
        return np.concatenate([[fx, fy, cx, cy], dist[:4], np.zeros(8)])
    # division: x_d ~ x_u (1 - lambda r^2) to first order, so lambda = -k1 / fx^2 and COLMAP's k = lambda fx^2 = -k1
    return np.array([fx, fy, cx, cy, -dist[0]])


def _camcal_lens(model: str, params: NDArray) -> tuple[NDArray[np.float64], Distortion]:
    """camcal's K (pixel centre at 0) and distortion of COLMAP parameters (:data:`_COLMAP_MODELS`)."""
    fx, fy, cx, cy = params[:4]
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    if model == "division":  # COLMAP's DIVISION: k in normalised units, round in normalised coordinates
        return K, Distortion("division", {"lambda": params[4] / fx**2, "aspect": fx / fy})
    names = _COLMAP_NAMES.get(model, {})
    if names:  # by COLMAP's parameter order
        by_colmap = {colmap: camcal for camcal, colmap in names.items()}
        order = [by_colmap[n] for n in ("k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3")]
        return K, Distortion(model, dict(zip(order, params[4:4 + len(order)])))
    return K, Distortion(_LENS.get(model, model), dict(zip(MODELS[model], params[4:4 + len(MODELS[model])])))


def _camcal_covariance(covariance: NDArray, colmap_names: tuple[str, ...], names: list[str], model: str,
                       params: list[NDArray]) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """The engine's covariance (COLMAP parameters) in camcal's parameters: ``A Sigma A^T``."""
    labels, rows = [], []
    column = {name: k for k, name in enumerate(colmap_names)}

    def row(entries: dict[str, float]) -> NDArray[np.float64]:
        r = np.zeros(len(colmap_names))
        for name, value in entries.items():
            if name in column:  # a held parameter is not in the covariance: its sigma is 0
                r[column[name]] = value
        return r

    for j, camera in enumerate(names):
        for label in _INTRINSICS + MODELS[model]:
            labels.append(f"{camera}.{label}")
            if label == "lambda":  # lambda = k / fx^2
                fx, k = params[j][0], params[j][4]
                rows.append(row({f"{camera}.fx": -2.0 * k / fx**3, f"{camera}.k": 1.0 / fx**2}))
            else:
                rows.append(row({f"{camera}.{_COLMAP_NAMES.get(model, {}).get(label, label)}": 1.0}))
        if j:
            for label in ("rx", "ry", "rz", "tx", "ty", "tz"):
                labels.append(f"{camera}.{label}")
                rows.append(row({f"{camera}.{label}": 1.0}))
    for label in GAUGE_NAMES if GAUGE_NAMES[0] in column else ():  # the board gauge (projection uncertainty)
        labels.append(label)
        rows.append(row({label: 1.0}))
    A = np.array(rows)
    return A @ covariance @ A.T, tuple(labels)


# -- the public entry point ------------------------------------------------------------


@opencv_threads_off()  # OpenCV's calibrations on one thread: same input, same output
def calibrate_board(
    board: Board,
    detections: Mapping[str, Sequence[Detection]],
    model: str = "auto",
    units: str = "m",
    outlier_factor: float = 3.0,
    min_outlier_px: float = 1.0,
    loss: str = "trivial",
    loss_scale: float = 1.0,
    holdout: Collection[int] = (),
    intrinsics: Mapping[str, Camera] | None = None,
    refine_intrinsics: bool = False,
    board_shape: str | BoardShape = "auto",
) -> CalibrationResult:
    """Calibrate one camera or an N-camera rig from images of a planar board.

    Parameters
    ----------
    board : Board
        The target; its square size sets the unit of every length.
    detections : mapping of str to sequence of Detection
        Camera name -> the board detections of its images (from
        :func:`camcal.pipelines.board.detect_in_images`). The first camera
        is the reference. Views are matched (and held out) by the frame
        number in the image file names (one camera with repeated numbers:
        by position).
    model : str
        ``auto`` (default) or one of :data:`MODELS`: ``none``, ``division``
        (Strand & Hayman lambda, centred on the principal point, its
        ``aspect`` = fx / fy), ``polynomial`` (k1, k2), ``kannala-brandt``
        (k1..k4), ``opencv`` (k1, k2, p1, p2, k3), ``opencv-rational``
        (+ k4, k5, k6), ``opencv-thin-prism`` (+ s1..s4; one camera, fitted
        by OpenCV), ``kannala-brandt-thin-prism`` (k1..k6, p1, p2, s1..s4:
        COLMAP's RAD_TAN_THIN_PRISM_FISHEYE).
        ``auto`` ranks every model by leave-views-out cross-validation on
        the training views (:func:`_rank_models`; ``holdout`` is never used
        to choose) and keeps the simplest (order of :data:`AUTO_MODELS`)
        within :data:`AUTO_MARGIN` (1 %) of the best; a model that cannot be
        fitted is ranked out with its reason; the chosen model is fitted on
        every training view, and if that fit fails, fails
        :func:`quality_problems` or folds inside the image
        (:func:`fold_radius_px`: the views may leave the image's rim
        unseen, and a polynomial can turn over there), the next in the
        ranking is (said in :attr:`CalibrationResult.notes`). The ranking is
        :attr:`CalibrationResult.model_ranking`. One camera with at least
        :data:`SPLINE_MIN_VIEWS` training views and the plain loss: the
        best model with a correction field (``<model>+spline``) is ranked
        too and taken first when :func:`_spline_chosen` says so. A model
        with a correction field can be named (``kannala-brandt+spline``;
        one camera, no given intrinsics).
    units : str
        Name of the board's length unit, stored in the rig.
    outlier_factor, min_outlier_px : float
        An image is an outlier when its RMS exceeds
        ``max(outlier_factor x median image RMS, min_outlier_px)``.
    loss, loss_scale : str, float
        Robust loss on each corner's residual (Ceres': ``trivial``,
        ``huber``, ``soft_l1``, ``cauchy``), scale in pixels.
    holdout : collection of int
        Frame numbers left out of the fit and reported as held-out RMS.
    intrinsics : mapping of str to Camera, optional
        Camera name -> a calibrated camera (e.g. the cameras of a rig file):
        its K and lens are held and only the poses are solved (extrinsics
        only), unless ``refine_intrinsics``. Every camera of
        ``detections`` must be in it, with the same image size, zero skew,
        and one lens model shared by all (the fitted model: ``model`` must
        be ``auto`` or that model); each camera's start poses are PnP with
        its own lens.
    refine_intrinsics : bool
        With ``intrinsics``: use them as the start and refine them.
    board_shape : str or BoardShape
        The board's shape (:mod:`camcal.geometry.board_shape`, one camera): ``flat``, a named shape of
        :data:`~camcal.geometry.board_shape.SHAPE_SPECS` (a surface ``z(x, y)`` of Legendre terms of total
        degree 2..d, ``2``, ``3``, ``4``, ``6`` or ``free``: every corner's height; ``+plane``: the corners'
        in-plane displacement too; fitted jointly with the lens and the poses), or ``auto`` (default): with
        ``model="auto"``, one camera, at least :data:`SPLINE_MIN_VIEWS` training views and the plain loss,
        every shape of :data:`~camcal.geometry.board_shape.AUTO_SHAPES` is scored on the model ranking's folds
        from the chosen model's fit in each fold (a model with a correction field: it and its parametric lens on
        every shape; the pair is taken by the same rule), and taken only when it beats the flat board by more than
        :data:`AUTO_MARGIN` and one standard error of the paired per-view differences (the one with fewest
        parameters within :data:`AUTO_MARGIN` of the best such); otherwise flat. On the surface taken, every
        lens model is scored again on the same folds and the simplest within :data:`AUTO_MARGIN` of the best is
        taken (the shape chosen again for it when it is another lens), then the correction field on top of it
        (:func:`_spline_chosen`'s rule). The ranking is
        :attr:`CalibrationResult.shape_ranking`; the surface, :attr:`CalibrationResult.board_shape`.
        A :class:`~camcal.geometry.board_shape.BoardShape` (e.g. a rig file's ``provenance.board_shape``) is
        held: the same board seen again, by any number of cameras, with any model (its corners are the
        bundle's constant points; the held-out views are posed against it).

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CamcalError
        Unknown model, fewer than :data:`MIN_IMAGES` usable images for a
        camera, cameras not linked to each other through shared frames (one
        line naming the separate groups), intrinsics that do not fit the
        cameras, or a degenerate problem.

    Notes
    -----
    Minimises ``1/2 sum_ij rho(|pi_j(K_j, d_j, T_j T_i X) - x_ij|^2)`` over
    the intrinsics ``K_j`` and distortion ``d_j`` of every camera ``j``, its
    pose ``T_j`` (``cam_from_reference``, identity for the reference) and
    the board pose ``T_i`` of every view ``i``; then
    ``Sigma = sigma^2 (J^T J)^-1``, ``sigma^2 = 2 cost / (2M - n)``.
    """
    if model in TDE4_MODELS:
        return _calibrate_tde4(board, detections, model, holdout, intrinsics, board_shape, units=units,
                               outlier_factor=outlier_factor, min_outlier_px=min_outlier_px, loss=loss,
                               loss_scale=loss_scale)
    splined = model.endswith(SPLINE_SUFFIX) and model[:-len(SPLINE_SUFFIX)] in MODELS
    if model != "auto" and model not in MODELS and not splined:
        raise CamcalError(f"unknown distortion model {model!r}, expected one of: {', '.join(MODELS)}, auto "
                          f"(or a model with a correction field, '<model>{SPLINE_SUFFIX}'), or 3DE's "
                          f"{', '.join(TDE4_MODELS)}")
    if isinstance(board_shape, BoardShape):
        return _calibrate_held_shape(board, detections, model, holdout, intrinsics, refine_intrinsics, board_shape,
                                     units=units, outlier_factor=outlier_factor, min_outlier_px=min_outlier_px,
                                     loss=loss, loss_scale=loss_scale)
    if board_shape not in BOARD_SHAPES:
        raise CamcalError(f"unknown board shape {board_shape!r}, expected one of: {', '.join(BOARD_SHAPES)}")
    spec = board_shape if board_shape not in ("auto", "flat") else ""
    if spec and (len(detections) > 1 or intrinsics is not None or model == "opencv-thin-prism"
                 or spec not in _shape_specs(board)):
        raise CamcalError(f"board shape {board_shape}: a board surface is fitted with one camera, without given "
                          f"intrinsics, a model of the Ceres engine (not opencv-thin-prism), and a degree the "
                          f"board's grid holds ({', '.join(_shape_specs(board)) or 'none'} here)")
    names, by_frame, holdout = _checked_views(detections, board, holdout)
    options = dict(units=units, outlier_factor=outlier_factor, min_outlier_px=min_outlier_px, loss=loss,
                   loss_scale=loss_scale)
    if splined and (len(names) > 1 or intrinsics is not None):
        raise CamcalError(f"model {model} calibrates one camera at a time, without given intrinsics")
    if intrinsics is not None:
        model, known = _known_lenses(names, by_frame, intrinsics, model)
        return _calibrate(board, names, by_frame, model, holdout, known=known, refine_known=refine_intrinsics,
                          **options)
    if spec and model != "auto":
        return _calibrate_shaped(board, names, by_frame, model, holdout, spec, **options)
    if splined:
        return _calibrate_spline(board, names, by_frame, model, holdout, **options)
    if model != "auto":
        return _calibrate(board, names, by_frame, model, holdout, **options)
    # the choice never sees the held-out frames
    training = [{f: d for f, d in views.items() if f not in holdout} for views in by_frame]
    fold_results: dict = {}
    ranking, squared, corners = _rank_models(board, names, training, options, fold_results)
    scored = [score for score in ranking if score.rms_px is not None]
    parametric = [score for score in scored if not score.model.endswith(SPLINE_SUFFIX)]
    order = [score.model for score in parametric] or ["polynomial"]
    if parametric:  # parsimony: the simplest model within AUTO_MARGIN of the best goes first
        simplest = _simplest_within_margin(parametric)
        order.remove(simplest)
        order.insert(0, simplest)
        spline = next((s for s in scored if s.model.endswith(SPLINE_SUFFIX)), None)
        if spline is not None and _spline_chosen(spline, parametric[0], squared):
            order.insert(0, spline.model)
    failures = []
    for candidate in order:
        try:
            fit = _calibrate_spline if candidate.endswith(SPLINE_SUFFIX) else _calibrate
            result = fit(board, names, by_frame, candidate, holdout, **options)
        except _FIT_ERRORS as error:
            failures.append(f"{candidate}: {_one_line(error)}")
            continue
        problems = quality_problems(result)
        folds = [(camera.name, fold_radius_px(camera)) for camera in result.rig.cameras]
        problems += [f"{name}: the lens folds {radius:.0f} px from the principal point, inside the image (its rays "
                     "stop turning outward)" for name, radius in folds if radius is not None]
        if problems and candidate != order[-1]:
            failures.append(f"{candidate}: {'; '.join(problems)}")
            continue
        notes = [f"model auto: {failure} (next model tried)" for failure in failures]
        if not scored:
            notes.append("model auto: too few views to hold any out (need "
                         f"{MIN_IMAGES + 1}); the polynomial model is fitted without a choice")
        result, shape_ranking, shape_notes = _with_board_shape(
            board, names, by_frame, candidate, holdout, result, board_shape, spec, scored, squared, corners,
            fold_results, training, options)
        return dataclasses.replace(result, model_ranking=ranking, notes=result.notes + tuple(notes + shape_notes),
                                   model_heldout_rms_px={s.model: s.rms_px for s in scored},
                                   shape_ranking=shape_ranking)
    raise CamcalError("no lens model could be fitted: " + "; ".join(failures))


def _with_board_shape(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      flat: CalibrationResult, board_shape: str, spec: str, scored: list[ModelScore], squared: dict,
                      corners: NDArray, fold_results: dict, training: list[dict], options: dict
                      ) -> tuple[CalibrationResult, tuple[ModelScore, ...], list[str]]:
    """``model="auto"``'s result on the board shape of ``board_shape`` (see :func:`calibrate_board`): the flat
    result, or a model refitted on the surface chosen (or named); with the shapes' ranking and notes.

    ``auto``: the shape is chosen for the flat-ranked ``model`` (:func:`_shape_choice`; with a correction field,
    among its surfaces and its parametric lens's, against ``model`` on the flat board), then the lens model is
    ranked again on that surface (:func:`_lens_on_shape`) and, when that changes it, the shape is chosen again
    for the new lens (the flat board among the candidates); the pair taken is printed in the notes."""
    if board_shape == "flat":
        return flat, (), []
    picked = model
    notes: list[str] = []
    if not spec and model.removesuffix(SPLINE_SUFFIX) not in _SHAPE_LENSES:
        # OpenCV's own fit has no surface path: the surface is chosen with the simplest lens that has one
        capable = [s for s in scored if s.model in _SHAPE_LENSES]
        if not capable:
            return flat, (), []
        model = _simplest_within_margin(capable)
        notes.append(f"board shape auto: {picked} (ranked on the flat board) has no surface fit; the surface is "
                     f"chosen with {model}, the simplest lens within {100 * AUTO_MARGIN:g} % of the best that has one")
    base = model.removesuffix(SPLINE_SUFFIX)
    flat_score = next((s for s in scored if s.model == model), None)
    shape_ranking: tuple[ModelScore, ...] = ()
    chosen = model
    if not spec:
        if (len(names) > 1 or flat_score is None or base not in fold_results or options["loss"] != "trivial"
                or len(training[0]) < SPLINE_MIN_VIEWS):
            return flat, (), []
        folds = fold_results["folds"]
        fits = fold_results.setdefault("shape_fits", {})
        shapes = _score_shapes(board, training[0], model, folds, fold_results[base], corners, squared, fits=fits)
        if base != model:  # the field's parametric lens on every surface too: a surface may do the field's work
            shapes += _score_shapes(board, training[0], base, folds, fold_results[base], corners, squared, fits=fits)
        lens, spec = _shape_choice(flat_score, shapes, squared)
        ranked = [flat_score, *shapes]
        if spec and lens != model:
            notes.append(f"board shape auto: {lens} on the {spec} surface beats {model} on the flat board held out "
                         f"(the surface chosen among {model}'s and {lens}'s)")
            model = lens
        if spec:
            done = {s.model for s in shapes}
            lenses = [s for lens in AUTO_MODELS if lens != model and lens in fold_results and lens in _SHAPE_LENSES
                      and f"{lens}{_SHAPE_TAG}{spec}" not in done
                      for s in _score_shapes(board, training[0], lens, folds, fold_results[lens], corners, squared,
                                             (spec,), fits)]
            ranked += lenses
            chosen = _lens_on_shape(model, spec, [*shapes, *lenses], squared)
            if chosen != model:
                have = {s.model for s in ranked}
                again = _score_shapes(board, training[0], chosen, folds, fold_results[chosen], corners, squared,
                                      tuple(s for s in _shape_specs(board, AUTO_SHAPES)
                                            if f"{chosen}{_SHAPE_TAG}{s}" not in have), fits)
                chosen_flat = next(s for s in scored if s.model == chosen)
                ranked += [chosen_flat] * (chosen not in have) + again
                lens_shapes = [s for s in ranked if s.model.startswith(f"{chosen}{_SHAPE_TAG}")]
                respec = _shape_choice(chosen_flat, lens_shapes, squared)[1]
                notes.append(f"board shape auto: {chosen} ranked first on the {spec} surface "
                             f"({model} on the flat board); "
                             + (f"its surface: {respec}" if respec else f"flat beats every surface for it, "
                                f"{model} on {spec} kept"))
                chosen, spec = (chosen, respec) if respec else (model, spec)
            if not chosen.endswith(SPLINE_SUFFIX):
                plain = next(s for s in ranked if s.model == f"{chosen}{_SHAPE_TAG}{spec}")
                field = [s for s in ranked if s.model == f"{chosen}{SPLINE_SUFFIX}{_SHAPE_TAG}{spec}"]
                if not field:  # not scored yet (a field on the flat-ranked lens was)
                    field = _score_shapes(board, training[0], chosen + SPLINE_SUFFIX, folds, fold_results[chosen],
                                          corners, squared, (spec,), fits)
                    ranked += field
                if _spline_chosen(field[0], plain, squared):
                    chosen += SPLINE_SUFFIX
        shape_ranking = tuple(sorted(ranked, key=lambda s: (s.rms_px is None, s.rms_px or 0.0)))
        if not spec:
            return flat, shape_ranking, notes + ["board shape auto: flat (no surface beats the flat board held out)"]
    try:
        shaped = _calibrate_shaped(board, names, by_frame, chosen, holdout, spec,
                                   flat=flat if chosen == picked and not picked.endswith(SPLINE_SUFFIX) else None,
                                   **options)
    except _FIT_ERRORS as error:
        return flat, shape_ranking, notes + [f"board shape: {chosen} on the {spec} surface failed "
                                             f"({_one_line(error)}); flat kept"]
    problems = quality_problems(shaped)
    radius = fold_radius_px(shaped.rig.cameras[0])
    if radius is not None:
        problems.append(f"the lens folds {radius:.0f} px from the principal point, inside the image")
    if problems:
        return flat, shape_ranking, notes + [f"board shape: {chosen} on the {spec} surface fails the quality gate "
                                             f"({'; '.join(problems)}); flat kept"]
    return shaped, shape_ranking, notes + [f"board shape auto: {chosen} on {spec} chosen by held-out error"
                                           if board_shape == "auto" else f"board shape: {spec}"]


def _simplest_within_margin(scores: list[ModelScore]) -> str:
    """The simplest model (:data:`AUTO_MODELS`' order) whose cross-validated RMS is within :data:`AUTO_MARGIN` of
    the best of ``scores`` (each scored, none with a correction field)."""
    limit = (1.0 + AUTO_MARGIN) * min(s.rms_px for s in scores)
    return min((s.model for s in scores if s.rms_px <= limit), key=AUTO_MODELS.index)


def _lens_on_shape(model: str, spec: str, scores: list[ModelScore], squared: dict) -> str:
    """The lens model taken on the surface ``spec``: among the parametric models scored there
    (``<lens>@board-<spec>``), the simplest (order of :data:`AUTO_MODELS`) within :data:`AUTO_MARGIN` of the
    best, as on the flat board; ``model`` with a correction field stays when its score on ``spec`` beats the
    best parametric one there by :func:`_spline_chosen`'s rule."""
    on = {s.model.rsplit(_SHAPE_TAG, 1)[0]: s for s in scores
          if s.rms_px is not None and s.model.endswith(f"{_SHAPE_TAG}{spec}")}
    parametric = [s for lens, s in on.items() if not lens.endswith(SPLINE_SUFFIX)]
    if not parametric:
        return model
    best = min(parametric, key=lambda s: s.rms_px)
    if model.endswith(SPLINE_SUFFIX) and model in on and _spline_chosen(on[model], best, squared):
        return model
    limit = (1.0 + AUTO_MARGIN) * best.rms_px
    return min((s.model.rsplit(_SHAPE_TAG, 1)[0] for s in parametric if s.rms_px <= limit), key=AUTO_MODELS.index)


def _calibrate_held_shape(board: Board, detections: Mapping[str, Sequence[Detection]], model: str,
                          holdout: Collection[int], intrinsics: Mapping[str, Camera] | None, refine_intrinsics: bool,
                          shape: BoardShape, **options) -> CalibrationResult:
    """:func:`calibrate_board` on a board whose surface is known and held (``model`` named, or ``auto`` with
    ``intrinsics``: their model)."""
    names, by_frame, holdout = _checked_views(detections, board, holdout)
    known = None
    if intrinsics is not None:
        model, known = _known_lenses(names, by_frame, intrinsics, model)
    if model not in _COLMAP_MODELS:
        raise CamcalError(f"a held board shape needs a named model of the rig engine or given intrinsics, got model "
                          f"{model} (one of: {', '.join(_COLMAP_MODELS)})")
    return _calibrate(board, names, by_frame, model, holdout, known=known, refine_known=refine_intrinsics,
                      shape=shape, **options)


def _checked_views(detections: Mapping[str, Sequence[Detection]], board: Board,
                   holdout: Collection[int]) -> tuple[list[str], list[dict[int, Detection]], set[int]]:
    """The cameras' names, their views by frame and the held-out frames, checked: every held-out frame is a view
    and the cameras are linked through the frames left for training (else one line)."""
    names, by_frame = _check_detections(detections, board)
    holdout = {int(f) for f in holdout}
    unknown = holdout - set().union(*[set(views) for views in by_frame])
    if unknown:
        raise CamcalError(f"held-out frame(s) {', '.join(map(str, sorted(unknown)))} are not among the views")
    _check_linked(names, [{f for f in views if f not in holdout} for views in by_frame])
    return names, by_frame, holdout


def _check_linked(names: list[str], frames: list[set[int]]) -> None:
    """Every camera linked to the others through frames they share (the view graph is connected), else one line.

    Raises
    ------
    CamcalError
        ``cameras not linked through shared frames: cam0, cam1 | cam2 (...)``, naming the separate groups.
    """
    groups: list[list[int]] = []
    left = set(range(len(names)))
    while left:
        queue, group = deque([min(left)]), []
        left.discard(queue[0])
        while queue:
            i = queue.popleft()
            group.append(i)
            for j in sorted(left):
                if frames[i] & frames[j]:
                    left.discard(j)
                    queue.append(j)
        groups.append(sorted(group))
    if len(groups) > 1:
        described = " | ".join(", ".join(names[i] for i in group) for group in groups)
        raise CamcalError(f"cameras not linked through shared frames: {described} (the groups share no frame "
                          "with the board: the rig cannot be placed in one frame)")


def _known_lenses(names: list[str], by_frame: list[dict], intrinsics: Mapping[str, Camera],
                  model: str) -> tuple[str, dict[str, NDArray[np.float64]]]:
    """The fitted model and each camera's COLMAP parameters from calibrated cameras (``intrinsics=``)."""
    missing = [name for name in names if name not in intrinsics]
    if missing:
        raise CamcalError(f"camera(s) {', '.join(missing)} not in the intrinsics (it has: "
                          f"{', '.join(intrinsics) or 'no camera'})")
    lenses, known = {}, {}
    for name, views in zip(names, by_frame):
        camera = intrinsics[name]
        size = tuple(next(iter(views.values())).image_size)
        if tuple(camera.image_size) != size:
            raise CamcalError(f"camera {name!r}: the intrinsics are for {camera.image_size[0]}x{camera.image_size[1]} "
                              f"images, its frames are {size[0]}x{size[1]}")
        if abs(camera.K[0, 1]) > 1e-9 * abs(camera.K[0, 0]):
            raise CamcalError(f"camera {name!r}: the intrinsics have skew {camera.K[0, 1]:g}; the rig engine's models "
                              "have none")
        lenses[name], known[name] = _lens_params(name, camera)
    if len(set(lenses.values())) > 1:
        raise CamcalError("the intrinsics' cameras have different lens models ("
                          + ", ".join(f"{name}: {lens}" for name, lens in lenses.items()) + "); give one model")
    lens = next(iter(lenses.values()))
    if model not in ("auto", lens):
        raise CamcalError(f"--model {model} but the intrinsics' lens model is {lens}")
    return lens, known


def _lens_params(name: str, camera: Camera) -> tuple[str, NDArray[np.float64]]:
    """The calibration model and COLMAP parameters (pixel centre at 0.5) of a calibrated camera."""
    distortion, K = camera.distortion, camera.K
    values = dict(distortion.params)
    if distortion.model == "none":
        return "none", _colmap_params("none", K, np.zeros(0))
    if distortion.model == "polynomial":
        if values.get("k3", 0.0) != 0.0:
            raise CamcalError(f"camera {name!r}: a polynomial lens with k3 is not a model the rig engine has "
                              "(polynomial is k1, k2)")
        return "polynomial", _colmap_params("polynomial", K, np.array([values["k1"], values["k2"]]))
    if distortion.model == "division":
        centre = np.asarray(distortion.center if distortion.center is not None else K[:2, 2], dtype=np.float64)
        if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0] or np.abs(centre - K[:2, 2]).max() > 1e-6:
            raise CamcalError(f"camera {name!r}: a division lens needs fx = fy and its centre at the principal "
                              "point here (COLMAP's SIMPLE_DIVISION)")
        f = K[0, 0]
        return "division", np.array([f, K[0, 2] + 0.5, K[1, 2] + 0.5, values["lambda"] * f**2])
    if distortion.model == "kannala-brandt":
        return "kannala-brandt", _colmap_params("kannala-brandt", K, np.array([values[k] for k in MODELS["kannala-brandt"]]))
    if distortion.model == "opencv":
        if any(values.get(k, 0.0) != 0.0 for k in ("s1", "s2", "s3", "s4")):
            raise CamcalError(f"camera {name!r}: thin-prism terms are not in the rig engine's models")
        rational = any(values.get(k, 0.0) != 0.0 for k in ("k4", "k5", "k6"))
        lens = "opencv-rational" if rational else "opencv"
        vector = np.array([values.get(k, 0.0) for k in MODELS[lens]])
        return lens, _colmap_params(lens, K, vector)
    raise CamcalError(f"camera {name!r}: lens model {distortion.model!r} cannot be held")


def _known_start(board: Board, views: Mapping[int, Detection], K: NDArray, lens: Distortion,
                 points: NDArray | None = None) -> dict[int, tuple[NDArray, NDArray]]:
    """cam_from_board of each view by PnP with a calibrated lens (views not posable in front are left out);
    ``points``: the board's corners when it is not flat."""
    poses = {}
    for f, detection in views.items():
        X = np.asarray((board.object_points if points is None else points)[detection.ids], dtype=np.float64)
        ideal = lens.undistort(detection.corners_px, K)
        front = np.all(np.isfinite(ideal), axis=1)
        if front.sum() < 4:
            continue
        for method in (cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_ITERATIVE):
            try:
                ok, rvec, tvec = cv2.solvePnP(X[front], ideal[front], K, None, flags=method)
            except cv2.error:
                continue
            if not ok or rvec is None or np.size(rvec) != 3:  # IPPE is for planar points only
                continue
            R, t = cv2.Rodrigues(rvec)[0], tvec.ravel()
            if np.all((X @ R.T + t)[:, 2] > 0.0):
                poses[f] = (R, t)
                break
    return poses


#: Errors of a model that cannot be fitted to a set of views (the engine's own checks surface as ValueError).
_FIT_ERRORS = (CamcalError, cv2.error, ValueError, np.linalg.LinAlgError)
#: Most folds of the leave-views-out cross-validation of ``model="auto"``.
_AUTO_FOLDS = 4
#: ``model="auto"`` scores the best model with a correction field from this many training views (one camera).
SPLINE_MIN_VIEWS = 8
#: The name of a model with a correction field: ``<model>+spline``.
SPLINE_SUFFIX = "+spline"


def _one_line(error: Exception) -> str:
    text = str(error).strip().splitlines()
    return text[-1] if text else type(error).__name__


def _rank_models(board: Board, names: list[str], training: list[dict], options: dict, fold_results: dict | None = None
                 ) -> tuple[tuple[ModelScore, ...], dict[str, NDArray[np.float64]], NDArray[np.float64]]:
    """Every model of :data:`AUTO_MODELS` (and the best one with a correction field) scored by leave-views-out
    cross-validation, best first, with each model's squared error per held-out view.

    Notes
    -----
    The training frames are split into ``k = min(4, n)`` folds (every k-th
    frame); each model is fitted k times, each time without one fold, whose
    views are then posed by PnP with the fitted intrinsics held
    (:func:`_heldout_rms`); the fold fits are scoring fits (no covariance,
    jackknife or sigmas: :func:`_calibrate`'s ``scoring``) and the models
    of a fold share OpenCV's model-free starts (:func:`_opencv_start`'s
    ``shared``). The score is the RMS over all held-out corners
    of all folds, ``sqrt(sum_folds sum |r|^2 / N)``. A model that fails in
    any fold (the fit refused or diverged, a held-out view not posable,
    a non-finite error) is ranked out with the reason, never raised.
    With fewer than ``MIN_IMAGES + 1`` frames nothing can be held out and
    every model is ranked out.

    One camera with at least :data:`SPLINE_MIN_VIEWS` training frames and
    the plain least-squares loss: the best-scored model is also scored
    with a correction field (:mod:`camcal.geometry.spline_fit`), fitted
    in each fold from that fold's fit of the model, as ``<model>+spline``.

    Returns
    -------
    scores, squared (model -> sum of ``|r|^2`` of each held-out view, the same views in the same order for every
    scored model), corners (the number of corners of each of those views); ``fold_results``, when given, gets
    ``"folds"`` (the folds) and every scored model's fit in each fold.
    """
    frames = sorted(set().union(*[set(views) for views in training]))
    n_folds = min(_AUTO_FOLDS, len(frames))
    if len(frames) < MIN_IMAGES + 1:
        reason = f"{len(frames)} views: too few to hold one out (need {MIN_IMAGES + 1})"
        return tuple(ModelScore(m, None, 4 + len(MODELS[m]), reason) for m in AUTO_MODELS), {}, np.zeros(0)
    folds = [set(frames[k::n_folds]) for k in range(n_folds)]
    held_views = [(j, f) for fold in folds for j in range(len(names)) for f in sorted(fold) if f in training[j]]
    corners = np.array([len(training[j][f].ids) for j, f in held_views], dtype=np.float64)
    scores, squared = [], {}
    fold_results = {} if fold_results is None else fold_results
    fold_results["folds"] = folds
    shared: dict = {}  # the OpenCV starts every model of a fold shares
    for candidate in AUTO_MODELS:
        per_view, results, reason = [], [], ""
        for fold in folds:
            try:
                result = _calibrate(board, names, training, candidate, fold, scoring=True, shared=shared, **options)
            except _FIT_ERRORS as error:
                reason = _one_line(error)
                break
            if result.heldout_rms_px is None or not np.all(np.isfinite(result.heldout_view_rms_px)):
                reason = "non-finite held-out error"
                break
            per_view.extend(result.heldout_view_rms_px)
            results.append(result)
        n_params = 4 + len(MODELS[candidate])
        if not reason:
            squared[candidate] = np.square(per_view) * corners
            fold_results[candidate] = results
        scores.append(ModelScore(candidate, None if reason else float(np.sqrt(squared[candidate].sum() / corners.sum())),
                                 n_params, reason))
    fitted = [score for score in scores if score.rms_px is not None]
    if fitted and len(names) == 1 and len(frames) >= SPLINE_MIN_VIEWS and options["loss"] == "trivial":
        base = min(fitted, key=lambda score: score.rms_px).model
        scores.append(_score_spline(board, names[0], training[0], base, folds, fold_results[base], corners, squared))
    ranked = sorted(scores, key=lambda s: (s.rms_px is None, s.rms_px or 0.0, s.n_params))
    return tuple(ranked), squared, corners


def _score_spline(board: Board, name: str, views: dict, base: str, folds: list[set[int]],
                  results: list[CalibrationResult], corners: NDArray, squared: dict) -> ModelScore:
    """``<base>+spline`` scored on the folds of :func:`_rank_models` (adds its per-view errors to ``squared``)."""
    model = base + SPLINE_SUFFIX
    nx, ny = grid_shape(next(iter(views.values())).image_size)
    n_params = 4 + len(MODELS[base]) + 2 * nx * ny
    per_view = []
    for fold, result in zip(folds, results):
        camera = result.rig.cameras[0]
        kept = {image for _, image in result.images}
        train = {f: d for f, d in views.items() if f not in fold and d.image in kept}
        try:
            fit = fit_spline_lens(board, train, camera.K, camera.distortion, MODELS[base])
            splined = dataclasses.replace(camera, K=fit.K, distortion=fit.distortion)
            per_view.extend(float(np.sum(r * r)) for r in
                            (_posed_residuals(board, splined, views[f]) for f in sorted(fold) if f in views))
        except _FIT_ERRORS as error:
            return ModelScore(model, None, n_params, _one_line(error))
    per_view = np.asarray(per_view)
    if not np.all(np.isfinite(per_view)):
        return ModelScore(model, None, n_params, "non-finite held-out error")
    squared[model] = per_view
    return ModelScore(model, float(np.sqrt(per_view.sum() / corners.sum())), n_params)


def _spline_chosen(spline: ModelScore, base: ModelScore, squared: dict[str, NDArray]) -> bool:
    """True when the correction field's cross-validated error is below its model's by more than
    :data:`AUTO_MARGIN` and by more than one standard error of the paired per-view differences.

    The views are the units (their corners' errors are correlated): with ``d_v`` the difference of
    squared errors of view ``v`` (model minus model with the field), ``sum_v d_v > sqrt(V) sd(d)``
    (the one-standard-error rule, Hastie, Tibshirani & Friedman 2009, section 7.10, on paired differences).
    """
    if spline.rms_px is None or base.rms_px is None or spline.rms_px >= (1.0 - AUTO_MARGIN) * base.rms_px:
        return False
    d = squared[base.model] - squared[spline.model]
    return len(d) > 1 and float(d.sum()) > float(np.sqrt(len(d)) * np.std(d, ddof=1))


def _calibrate_spline(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      **options) -> CalibrationResult:
    """``<model>+spline``: the model fitted by :func:`_calibrate`, then its correction field on the views it kept.

    The covariance and the sigmas are the parametric part's at its own fit (the field's are not propagated).
    """
    base = model[:-len(SPLINE_SUFFIX)]
    result = _calibrate(board, names, by_frame, base, holdout, **options)
    camera = result.rig.cameras[0]
    kept = {image for _, image in result.images}
    views = {f: d for f, d in by_frame[0].items() if f not in holdout and d.image in kept}
    fit = fit_spline_lens(board, views, camera.K, camera.distortion, MODELS[base])
    ny, nx = fit.distortion.correction.shape
    return _refitted(board, result, dataclasses.replace(camera, K=fit.K, distortion=fit.distortion), fit.residuals_px,
                     views, by_frame[0], holdout, model,
                     (f"{model}: {base} with a {nx}x{ny} B-spline correction field (RMS "
                      f"{fit.distortion.correction.rms_px():.3f} px over the image); its covariance is "
                      f"{base}'s at its own fit",))


def _refitted(board: Board, flat: CalibrationResult, camera: Camera, residuals: NDArray, views: Mapping[int, Detection],
              all_views: Mapping[int, Detection], holdout: set[int], model: str, notes: tuple[str, ...],
              shape: BoardShape | None = None) -> CalibrationResult:
    """The one-camera calibration ``flat`` with its camera refitted after it (a correction field, a board surface):
    the camera's training figures from ``residuals`` on ``views``, the held-out views of ``all_views`` posed again
    (against ``shape``'s corners when the board is not flat), the rig's provenance naming ``model`` (and the
    shape), and ``notes`` added."""
    norms = np.linalg.norm(residuals, axis=1)
    rms = float(np.sqrt(np.mean(norms**2)))
    quality = {**camera.quality, "rms_px": rms, "worst_px": float(norms.max()), "n_observations": int(len(norms))}
    quality.pop("heldout_rms_px", None)
    camera = dataclasses.replace(camera, quality=quality)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if holdout:
        held = [{f: d for f, d in all_views.items() if f in holdout}]
        heldout_rms, per_camera, heldout_images, heldout, per_view = _heldout_rms(
            board, Rig((camera,)), held, None if shape is None else shape.points(board))
        camera = dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]})
    provenance = {**flat.rig.provenance, "model": model}
    if shape is not None:
        provenance["board_shape"] = shape.to_dict()
    frames = sorted(views)
    return dataclasses.replace(
        flat, rig=Rig((camera,), units=flat.rig.units, provenance=provenance), residuals_px=residuals,
        points_px=np.concatenate([views[f].corners_px for f in frames]), camera_of_point=np.zeros(len(norms), np.int64),
        image_of_point=np.concatenate([np.full(len(views[f].ids), n) for n, f in enumerate(frames)]),
        images=tuple((camera.name, views[f].image) for f in frames), rms_px=rms, worst_px=float(norms.max()),
        model=model, heldout_rms_px=heldout_rms, heldout_images=heldout_images, heldout_view_rms_px=per_view,
        board_shape=shape, **_heldout_fields(heldout), notes=flat.notes + notes)


#: ``board_shape`` values: chosen by held-out error, flat, or a named shape.
BOARD_SHAPES = ("auto", "flat") + SHAPE_SPECS
#: The lens models a board surface is fitted with (opencv-thin-prism is OpenCV's fit: no surface path).
_SHAPE_LENSES = tuple(m for m in AUTO_MODELS if m != "opencv-thin-prism")
#: The name of a lens model fitted on a board shape in :attr:`CalibrationResult.shape_ranking`: ``<model>@board-<shape>``.
_SHAPE_TAG = "@board-"


def _shape_specs(board: Board, names: Sequence[str] = SHAPE_SPECS) -> tuple[str, ...]:
    """The shapes of ``names`` the board's corner grid holds (a degree up to :func:`max_degree`)."""
    return tuple(s for s in names if parse_shape(board, s)[0] <= max_degree(board))


def _fit_shape(board: Board, result: CalibrationResult, views: Mapping[int, Detection], model: str, spec: str,
               fits: dict | None = None):
    """``(camera, shape, training residuals, views kept)``: the board's surface fitted with the lens on the views
    ``result`` kept (started from its flat fit and board poses), then, for ``<model>+spline``, the correction
    field on top with the surface held. ``fits``: the surface fits already made, by flat fit and shape (the
    surface under ``<model>+spline`` is ``<model>``'s on it: made once)."""
    base = model.removesuffix(SPLINE_SUFFIX)
    camera = result.rig.cameras[0]
    kept = {image for _, image in result.images}
    train = {f: d for f, d in views.items() if d.image in kept}
    poses = {f: (R, t) for f, R, t in result.board_poses}
    degree, in_plane = parse_shape(board, spec)
    key = (id(result), base, spec, tuple(sorted(train)))
    fit = None if fits is None else fits.get(key)
    if fit is None:
        fit = fit_board_shape(board, train, camera.K, camera.distortion.without_correction(), MODELS[base], poses,
                              degree, in_plane)
        if fits is not None:
            fits[key] = fit
    K, distortion, residuals = fit.K, fit.distortion, fit.residuals_px
    if base != model:
        splined = fit_spline_lens(board, fit.views, K, distortion, MODELS[base], points=fit.shape.points(board))
        K, distortion, residuals = splined.K, splined.distortion, splined.residuals_px
    return dataclasses.replace(camera, K=K, distortion=distortion), fit.shape, residuals, fit.views


def _calibrate_shaped(board: Board, names: list[str], by_frame: list[dict], model: str, holdout: set[int],
                      spec: str, flat: CalibrationResult | None = None, **options) -> CalibrationResult:
    """``model`` on a board of shape ``spec`` (:mod:`camcal.geometry.board_shape`): the flat fit of its
    parametric part (:func:`_calibrate`; ``flat`` when it is already made), then the surface, the lens and the
    poses refined jointly (and the correction field on top, with the surface held); the held-out views posed
    against the fitted surface. One camera. The covariance and the sigmas are the flat fit's."""
    if len(names) > 1:
        raise CamcalError(f"a board surface is fitted with one camera at a time; got {len(names)} cameras")
    result = flat if flat is not None else _calibrate(board, names, by_frame, model.removesuffix(SPLINE_SUFFIX),
                                                      holdout, **options)
    training = {f: d for f, d in by_frame[0].items() if f not in holdout}
    camera, shape, residuals, views = _fit_shape(board, result, training, model, spec)
    return _refitted(board, result, camera, residuals, views, by_frame[0], holdout, model,
                     (shape.describe(board) + f"; training RMS {result.rms_px:.4f} px on a flat board",
                      f"{model} on board shape {spec}: its covariance is the flat fit's"), shape)


def _score_shapes(board: Board, view_sets: dict, model: str, folds: list[set[int]],
                  results: list[CalibrationResult], corners: NDArray, squared: dict,
                  specs: Sequence[str] | None = None, fits: dict | None = None) -> list[ModelScore]:
    """``<model>@board-<shape>`` for every shape of ``specs`` (default: every shape of :data:`AUTO_SHAPES` the
    board holds), scored on the folds of :func:`_rank_models` from each fold's flat fit (adds each one's per-view
    squared errors to ``squared``; ``fits``: :func:`_fit_shape`'s)."""
    scores = []
    for spec in _shape_specs(board, AUTO_SHAPES) if specs is None else specs:
        name = f"{model}{_SHAPE_TAG}{spec}"
        n_params = 4 + len(MODELS[model.removesuffix(SPLINE_SUFFIX)]) + n_shape_params(board, spec)
        if model.endswith(SPLINE_SUFFIX):
            n_params += 2 * math.prod(grid_shape(next(iter(view_sets.values())).image_size))
        per_view, reason = [], ""
        for fold, result in zip(folds, results):
            train = {f: d for f, d in view_sets.items() if f not in fold}
            try:
                camera, shape, _, _ = _fit_shape(board, result, train, model, spec, fits)
                points = shape.points(board)
                per_view.extend(float(np.sum(r * r)) for r in
                                (_posed_residuals(board, camera, view_sets[f], points) for f in sorted(fold)
                                 if f in view_sets))
            except _FIT_ERRORS as error:
                reason = _one_line(error)
                break
        if not reason and not np.all(np.isfinite(per_view)):
            reason = "non-finite held-out error"
        if not reason:
            squared[name] = np.asarray(per_view)
        scores.append(ModelScore(name, None if reason else float(np.sqrt(squared[name].sum() / corners.sum())),
                                 n_params, reason))
    return scores


def _shape_choice(flat: ModelScore, shapes: list[ModelScore], squared: dict) -> tuple[str, str]:
    """``(lens, shape)`` taken among ``shapes`` (``<lens>@board-<shape>``; ``("", "")``: the flat board, ``flat``):
    the one with fewest parameters within :data:`AUTO_MARGIN` of the best among those better than ``flat`` by more
    than :data:`AUTO_MARGIN` and one standard error of the paired per-view differences (:func:`_spline_chosen`'s
    rule)."""
    better = [s for s in shapes if s.rms_px is not None and _spline_chosen(s, flat, squared)]
    if not better:
        return "", ""
    best = min(s.rms_px for s in better)
    simplest = min((s for s in better if s.rms_px <= (1.0 + AUTO_MARGIN) * best), key=lambda s: s.n_params)
    lens, spec = simplest.model.rsplit(_SHAPE_TAG, 1)
    return lens, spec


def _calibrate(board: Board, names: list[str], by_frame_all: list[dict], model: str, holdout: set[int], units: str,
               outlier_factor: float, min_outlier_px: float, loss: str, loss_scale: float,
               known: Mapping[str, NDArray] | None = None, refine_known: bool = False,
               shape: BoardShape | None = None, scoring: bool = False, shared: dict | None = None
               ) -> CalibrationResult:
    """One model, the views of ``holdout`` left out of the fit and then measured.

    ``scoring``: the fit only, for its held-out residuals (:func:`_rank_models`' folds): no covariance,
    no jackknife, no sigmas (the result's ``covariance`` is empty; its lens, poses, residuals and held-out
    figures are the full fit's). ``shared``: :func:`_opencv_start`'s.

    ``known``: camera name -> COLMAP parameters of a calibrated lens (:func:`_known_lenses`), held unless
    ``refine_known``; the start poses are then PnP with those lenses. ``shape``: a board surface held (its
    corners are the bundle's constant points, the PnP starts with known lenses and the held-out views are posed
    against it); the starts of fitted lenses are OpenCV's flat-board fits.
    """
    points = board.object_points if shape is None else shape.points(board)
    by_frame = [{f: d for f, d in views.items() if f not in holdout} for views in by_frame_all]
    held = [{f: d for f, d in views.items() if f in holdout} for views in by_frame_all]
    for name, views in zip(names, by_frame):
        if len(views) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: {len(views)} images left for the fit after holding out "
                              f"{len(holdout)} frames, need at least {MIN_IMAGES}")
    if model == "opencv-thin-prism":
        result = _calibrate_opencv(board, names, by_frame, model, units, outlier_factor, min_outlier_px, shared)
        if not holdout:
            return result
        heldout_rms, per_camera, heldout_images, heldout, per_view = _heldout_rms(board, result.rig, held)
        camera = result.rig.cameras[0]
        rig = Rig((dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]}),),
                  units=result.rig.units, provenance=result.rig.provenance)
        return dataclasses.replace(result, rig=rig, heldout_rms_px=heldout_rms, heldout_images=heldout_images,
                                   heldout_view_rms_px=per_view, **_heldout_fields(heldout))
    colmap_model, fixed = _COLMAP_MODELS[model]
    starts, params = [], []
    for name, views in zip(names, by_frame):
        if known is not None:
            params.append(np.asarray(known[name], dtype=np.float64).copy())
            K, lens = _camcal_lens(model, params[-1])
            starts.append(_known_start(board, views, K, lens, points))
            continue
        K, dist, poses = _opencv_start(board, views, model, name, shared)
        if model not in _FISHEYE:
            poses = _poses_in_front(board, views, K, dist, poses)
        starts.append(poses)
        params.append(_colmap_params(model, K, dist))
    behind = [(name, views.pop(f).image) for name, views, poses in zip(names, by_frame, starts)
              for f in sorted(set(views) - set(poses))]
    for name, views in zip(names, by_frame):
        if len(views) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: {len(views)} views with the board in front of the camera at the "
                              f"start, need at least {MIN_IMAGES}")
    by_frame, starts, relabelling, dropped = resolve_labellings(board, names, by_frame, starts)
    relabelled = [(name, image) for name, image, _ in relabelling]
    dropped = behind + [(name, image) for name, image, _ in dropped]
    notes = []
    for how in sorted({how for _, _, how in relabelling}):
        views = [image for _, image, other in relabelling if other == how]
        notes.append(f"{len(views)} view(s) relabelled ({how}) to agree with the rig's other cameras: "
                     + ", ".join(views))
    if behind:
        notes.append(f"{len(behind)} view(s) left out: no start pose puts the board in front of the camera "
                     f"({', '.join(image for _, image in behind)})")
    if model in _FISHEYE:
        by_frame, n_behind = _corners_in_front(board, by_frame, starts)
        if n_behind:
            notes.append(f"{n_behind} corner(s) beyond 90 degrees from the optical axis left out "
                         f"(COLMAP's {colmap_model}, the engine's model, images only rays in front of the camera)")
    cam_poses = _camera_poses(names, starts)

    # every frame seen by any camera is one board pose, first placed by the lowest camera seeing it
    frames = sorted(set().union(*[set(v) for v in by_frame]))
    observed = {(j, f) for j, views in enumerate(by_frame) for f in views}
    outliers: list[tuple[int, int]] = []
    view_start = {}
    for f in frames:
        j = min(j for j in range(len(names)) if f in by_frame[j])
        R_j, t_j = cam_poses[j]
        R_b, t_b = starts[j][f]
        view_start[f] = (R_j.T @ R_b, R_j.T @ (t_b - t_j))
    options = BundleOptions(refine_principal_point=True, refine_points3D=False, loss=loss, loss_scale=loss_scale,
                            fixed_params={name: fixed for name in names},
                            constant_intrinsics=tuple(names) if known is not None and not refine_known else (),
                            compute_sigmas=not scoring)
    if known is not None:
        notes.append("intrinsics " + ("refined from the given start" if refine_known else "held (extrinsics only)"))
    image_sizes = tuple(next(iter(views.values())).image_size for views in by_frame)

    for round_ in range(_MAX_OUTLIER_ROUNDS + 1):
        kept = sorted(observed - set(outliers))
        kept_frames = sorted({f for _, f in kept})
        frame_index = {f: n for n, f in enumerate(kept_frames)}
        for j, name in enumerate(names):
            n_left = sum(1 for jj, _ in kept if jj == j)
            if n_left < MIN_IMAGES:
                raise CamcalError(f"camera {name!r}: only {n_left} images left after dropping outliers, need {MIN_IMAGES}")
        det = [by_frame[j][f] for j, f in kept]
        observations = BoardObservations(
            object_points=np.asarray(points, dtype=np.float64),
            camera=np.concatenate([np.full(len(d.ids), j) for (j, _), d in zip(kept, det)]),
            frame=np.concatenate([np.full(len(d.ids), frame_index[f]) for (_, f), d in zip(kept, det)]),
            corner=np.concatenate([d.ids for d in det]),
            xy=np.concatenate([d.corners_px for d in det]),
        )
        state = BundleState(
            camera_names=tuple(names), models=(colmap_model,) * len(names), image_sizes=image_sizes,
            params=tuple(params), sensor_R=np.array([R for R, _ in cam_poses]),
            sensor_t=np.array([t for _, t in cam_poses]), frame_R=np.array([view_start[f][0] for f in kept_frames]),
            frame_t=np.array([view_start[f][1] for f in kept_frames]), frame_ids=tuple(kept_frames),
            points=np.zeros((0, 3)), point_ids=(), obs_camera=np.zeros(0, np.int64), obs_frame=np.zeros(0, np.int64),
            obs_point=np.zeros(0, np.int64), obs_xy=np.zeros((0, 2)),
            board=observations, board_R=np.eye(3), board_t=np.zeros(3),
        )
        solution = bundle_adjust(state, options)
        refined = solution.state
        residuals = board_residuals(refined)[1]
        if not np.all(np.isfinite(residuals)):
            raise CamcalError("the joint refinement diverged (non-finite residuals): check the detections")
        params = list(refined.params)
        cam_poses = list(zip(refined.sensor_R, refined.sensor_t))
        for f in kept_frames:
            view_start[f] = (refined.frame_R[frame_index[f]], refined.frame_t[frame_index[f]])
        image_of_point = np.concatenate([np.full(len(d.ids), n) for n, d in enumerate(det)])
        squared = np.bincount(image_of_point, np.sum(residuals**2, axis=1)) / np.bincount(image_of_point)
        image_rms = np.sqrt(squared)
        threshold = max(outlier_factor * np.median(image_rms), min_outlier_px)
        new = [kept[n] for n in np.flatnonzero(image_rms > threshold)]
        if not new or round_ == _MAX_OUTLIER_ROUNDS:
            break
        outliers.extend(new)

    if scoring:
        covariance, labels, jackknife = None, (), None
    elif solution.covariance.size == 0:
        raise CamcalError("the calibration is degenerate (singular normal equations): vary the board poses more")
    else:
        covariance, labels = _camcal_covariance(solution.covariance, solution.covariance_names, names, model, params)
        jackknife = _view_jackknife(labels, names, model, params, refined, observations) if loss == "trivial" else None
    rig = _build_rig(names, image_sizes, params, cam_poses, observations.camera, image_of_point, residuals,
                     covariance, labels, board, model, units, jackknife)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if shape is not None:
        rig = Rig(rig.cameras, units=rig.units, provenance={**rig.provenance, "board_shape": shape.to_dict()})
        notes.append(f"{shape.describe(board)}; held, not fitted")
    if holdout:
        heldout_rms, per_camera, heldout_images, heldout, per_view = _heldout_rms(
            board, rig, held, None if shape is None else points)
        rig = Rig(tuple(dataclasses.replace(camera, quality={**camera.quality, "heldout_rms_px": per_camera[camera.name]})
                        if camera.name in per_camera else camera for camera in rig.cameras),
                  units=rig.units, provenance=rig.provenance)
    norms = np.linalg.norm(residuals, axis=1)
    return CalibrationResult(
        rig=rig,
        residuals_px=residuals,
        points_px=observations.xy,
        camera_of_point=observations.camera,
        image_of_point=image_of_point,
        images=tuple((names[j], by_frame[j][f].image) for j, f in kept),
        rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()),
        outliers=tuple((names[j], by_frame[j][f].image) for j, f in sorted(outliers)),
        covariance=np.zeros((0, 0)) if covariance is None else covariance,
        parameter_names=labels,
        model=model,
        heldout_rms_px=heldout_rms,
        heldout_images=heldout_images,
        heldout_view_rms_px=per_view,
        relabelled=tuple(relabelled),
        dropped=tuple(dropped),
        notes=tuple(notes),
        board_poses=tuple((f, *view_start[f]) for f in sorted({f for _, f in kept})),
        board_shape=shape,
        **_heldout_fields(heldout),
    )


def _calibrate_tde4(board: Board, detections: Mapping[str, Sequence[Detection]], model: str, holdout: Collection[int],
                    intrinsics: Mapping[str, Camera] | None, board_shape: str | BoardShape,
                    **options) -> CalibrationResult:
    """3DE's models (:mod:`camcal.model.tde4`), one camera on a flat board: the ``opencv`` calibration
    (``kannala-brandt`` for the fisheye; its outliers dropped) refined into the 3DE lens, K and poses by
    :func:`camcal.geometry.tde4_fit.fit_tde4_lens`; held-out views measured as for every model."""
    if len(detections) != 1 or intrinsics is not None or board_shape not in ("auto", "flat"):
        raise CamcalError(f"model {model} calibrates one camera on a flat board, without given intrinsics")
    names, by_frame, holdout = _checked_views(detections, board, holdout)
    start_model = "kannala-brandt" if model == "3de4-fisheye-deg8" else "opencv"
    start = _calibrate(board, names, by_frame, start_model, holdout, **options)
    camera = start.rig.cameras[0]
    views = [by_frame[0][f] for f, _, _ in start.board_poses]
    fit = fit_tde4_lens(board.object_points, [(view.ids, view.corners_px) for view in views], camera.K,
                        camera.distortion, [(R, t) for _, R, t in start.board_poses], model, camera.image_size,
                        options["loss"], options["loss_scale"])
    norms = np.linalg.norm(fit.residuals_px, axis=1)
    sigma = dict(zip(fit.parameter_names, (float(s) for s in np.sqrt(np.diag(fit.covariance)))))
    quality = Quality(rms_px=float(np.sqrt(np.mean(norms**2))), worst_px=float(norms.max()), n_views=len(views),
                      n_observations=len(norms), n_outliers=len(start.outliers), sigma=sigma)
    rig = Rig((dataclasses.replace(camera, K=fit.K, distortion=fit.distortion, quality=quality),),
              units=start.rig.units, provenance=start.rig.provenance)
    heldout_rms, heldout_images, heldout, per_view = None, (), [], ()
    if holdout:
        held = [{f: d for f, d in by_frame[0].items() if f in holdout}]
        heldout_rms, per_camera, heldout_images, heldout, per_view = _heldout_rms(board, rig, held)
        rig = Rig((dataclasses.replace(rig.cameras[0], quality={**rig.cameras[0].quality, "heldout_rms_px": heldout_rms}),),
                  units=rig.units, provenance=rig.provenance)
    held_params = [f"{p.key} {p.default:g}" for p in LDPK_PARAMETERS[model] if p.key not in TDE4_FITTED_PARAMS[model]]
    return dataclasses.replace(
        start, rig=rig, residuals_px=fit.residuals_px, points_px=np.concatenate([view.corners_px for view in views]),
        camera_of_point=np.zeros(len(norms), np.int64),
        image_of_point=np.concatenate([np.full(len(view.ids), n) for n, view in enumerate(views)]),
        rms_px=quality.rms_px, worst_px=quality.worst_px, covariance=fit.covariance,
        parameter_names=tuple(f"{camera.name}.{label}" for label in fit.parameter_names), model=model,
        heldout_rms_px=heldout_rms, heldout_images=heldout_images, heldout_view_rms_px=per_view,
        notes=start.notes + (f"{model}: started from the {start_model} fit (its outlier images dropped); held at "
                             f"LDPK's defaults: {', '.join(held_params)} (the pixel aspect is fy / fx)",),
        board_poses=tuple((f, R, t) for (f, _, _), (R, t) in zip(start.board_poses, fit.poses)),
        **_heldout_fields(heldout))


def _heldout_fields(heldout: list) -> dict:
    """The result's held-out residuals, points and camera indices from :func:`_heldout_rms`'s ``views``."""
    if not heldout:
        return {"heldout_residuals_px": np.zeros((0, 2)), "heldout_points_px": np.zeros((0, 2)),
                "heldout_camera_of_point": np.zeros(0, np.int64)}
    return {"heldout_residuals_px": np.concatenate([r for _, r, _ in heldout]),
            "heldout_points_px": np.concatenate([x for _, _, x in heldout]),
            "heldout_camera_of_point": np.concatenate([np.full(len(r), j) for j, r, _ in heldout])}


def _view_jackknife(labels: tuple[str, ...], names: list[str], model: str, params: list[NDArray],
                    refined: BundleState, observations: BoardObservations) -> NDArray | None:
    """The delete-one-view jackknife covariance over ``labels`` (:mod:`camcal.geometry.view_jackknife`);
    None below its minimum of views (plain least squares only: no robust loss)."""
    free = ("f", "cx", "cy") if model == "division" else _INTRINSICS
    lenses = [(*_camcal_lens(model, params[j]), free + MODELS[model]) for j in range(len(names))]
    jackknife = view_jackknife(lenses, refined.sensor_R, refined.sensor_t, refined.frame_R, refined.frame_t,
                               observations, labels, names)
    return None if jackknife is None else jackknife.covariance


def _calibrate_opencv(board: Board, names: list[str], by_frame: list[dict], model: str, units: str,
                      outlier_factor: float, min_outlier_px: float, shared: dict | None = None) -> CalibrationResult:
    """One camera fitted by OpenCV's ``calibrateCameraExtended`` alone (a model the Ceres engine lacks).

    COLMAP has no pinhole camera with thin-prism terms, so ``opencv-thin-prism``
    is OpenCV's Levenberg-Marquardt (flags ``CALIB_RATIONAL_MODEL |
    CALIB_THIN_PRISM_MODEL``, the same cost: squared distorted-pixel
    residuals), with the same outlier rounds. Its covariance is diagonal:
    OpenCV's ``stdDeviationsIntrinsics`` (``sigma^2 (J^T J)^-1`` of the
    intrinsics, ``sigma^2`` from the residuals).
    """
    if len(names) > 1:
        raise CamcalError(f"model {model} calibrates one camera at a time (COLMAP's models, the rig engine's, "
                          f"have no thin prism); got {len(names)} cameras")
    name, views = names[0], by_frame[0]
    size = next(iter(views.values())).image_size
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    outliers: list[int] = []
    for round_ in range(_MAX_OUTLIER_ROUNDS + 1):
        kept = [f for f in sorted(views) if f not in outliers]
        if len(kept) < MIN_IMAGES:
            raise CamcalError(f"camera {name!r}: only {len(kept)} images left after dropping outliers, need {MIN_IMAGES}")
        object_points = [board.object_points[views[f].ids].astype(np.float32) for f in kept]
        image_points = [views[f].corners_px.astype(np.float32).reshape(-1, 1, 2) for f in kept]
        K, dist, _ = _opencv_start(board, {f: views[f] for f in kept}, model, name, shared)
        try:
            _, K, dist, rvecs, tvecs, std_intrinsics, _, _ = cv2.calibrateCameraExtended(
                object_points, image_points, size, K, dist, criteria=criteria,
                flags=_OPENCV_FLAGS[model] | cv2.CALIB_USE_INTRINSIC_GUESS)
        except cv2.error as error:
            raise CamcalError(f"camera {name!r}: OpenCV calibrateCamera failed ({_one_line(error)})") from None
        params = np.concatenate([[K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5], dist.ravel()[:len(MODELS[model])]])
        _, lens = _camcal_lens(model, params)
        residuals = np.concatenate([
            lens.project_rays(board.object_points[views[f].ids] @ cv2.Rodrigues(r)[0].T + t.ravel(), K)
            - views[f].corners_px for f, r, t in zip(kept, rvecs, tvecs)])
        if not np.all(np.isfinite(residuals)) or not np.all(np.isfinite(params)):
            raise CamcalError(f"camera {name!r}: OpenCV's {model} fit diverged (non-finite residuals)")
        image_of_point = np.concatenate([np.full(len(views[f].ids), n) for n, f in enumerate(kept)])
        image_rms = np.sqrt(np.bincount(image_of_point, np.sum(residuals**2, axis=1)) / np.bincount(image_of_point))
        threshold = max(outlier_factor * np.median(image_rms), min_outlier_px)
        new = [kept[n] for n in np.flatnonzero(image_rms > threshold)]
        if not new or round_ == _MAX_OUTLIER_ROUNDS:
            break
        outliers.extend(new)
    labels = tuple(f"{name}.{label}" for label in _INTRINSICS + MODELS[model])
    sigmas = std_intrinsics.ravel()[:len(labels)]
    if not np.all(np.isfinite(sigmas)):
        raise CamcalError(f"camera {name!r}: the {model} calibration is degenerate (OpenCV's intrinsic sigmas are "
                          "not finite): vary the board poses more")
    covariance = np.diag(sigmas**2)
    camera_of_point = np.zeros(len(residuals), np.int64)
    rig = _build_rig(names, (size,), [params], [(np.eye(3), np.zeros(3))], camera_of_point, image_of_point,
                     residuals, covariance, labels, board, model, units)
    norms = np.linalg.norm(residuals, axis=1)
    return CalibrationResult(
        rig=rig, residuals_px=residuals, points_px=np.concatenate([views[f].corners_px for f in kept]),
        camera_of_point=camera_of_point, image_of_point=image_of_point,
        images=tuple((name, views[f].image) for f in kept), rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()), outliers=tuple((name, views[f].image) for f in sorted(outliers)),
        covariance=covariance, parameter_names=labels, model=model,
        notes=(f"{model}: fitted by OpenCV's calibrateCamera (the Ceres engine's COLMAP models have no thin prism); "
               "its covariance is diagonal",),
    )


def _heldout_rms(board: Board, rig: Rig, held: list[dict], points: NDArray | None = None):
    """RMS of the held-out views, each posed by PnP with the fitted intrinsics held (against the board's fitted
    surface, ``points``, when it is not flat).

    Each view's ``cam_from_board`` minimises ``sum |project(K, d, R X + t) -
    x|^2`` over its six pose parameters alone (:func:`camcal.geometry.spline_fit.pose_view`:
    Levenberg-Marquardt, camcal's own projection of the fitted lens, so every
    model is measured alike), started from OpenCV's ``solvePnP`` on the
    undistorted corners. A view is posed on its own: a corner seen in one
    view only counts like any other.

    Returns
    -------
    rms_px, per_camera_rms_px, images, views, per_view_rms_px
        ``views``: ``(camera index, projected - detected, detected)`` of each held-out view;
        ``per_view_rms_px``: the RMS of each held-out view (both in the order of images).
    """
    squared, counts, per_camera, images, residuals, per_view = 0.0, 0, {}, [], [], []
    for j, (camera, views) in enumerate(zip(rig.cameras, held)):
        if not views:
            continue
        s_camera, n_camera = 0.0, 0
        for key in sorted(views):
            r = _posed_residuals(board, camera, views[key], points)
            s_camera, n_camera = s_camera + float(np.sum(r * r)), n_camera + len(r)
            images.append((camera.name, views[key].image))
            residuals.append((j, r, views[key].corners_px))
            per_view.append(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))))
        per_camera[camera.name] = float(np.sqrt(s_camera / n_camera))
        squared, counts = squared + s_camera, counts + n_camera
    return float(np.sqrt(squared / counts)), per_camera, tuple(images), residuals, tuple(per_view)


def _posed_residuals(board: Board, camera: Camera, detection: Detection,
                     points: NDArray | None = None) -> NDArray[np.float64]:
    """``projected - detected`` (N, 2) of one view posed with the camera's intrinsics held (see :func:`_heldout_rms`)."""
    try:
        return pose_view(board, camera.K, camera.distortion, detection, points)[2]
    except CamcalError as error:
        raise CamcalError(f"camera {camera.name!r}, held-out view {error}") from None


def quality_problems(result: CalibrationResult) -> list[str]:
    """What makes a calibration unusable by its own figures (empty when it looks sound).

    A camera is refused when its principal point lies outside the image,
    its RMS exceeds :data:`MAX_RMS_PX`, or its focal length's one-sigma
    exceeds :data:`MAX_FOCAL_SIGMA_REL` of the focal length.
    """
    problems = []
    for camera in result.rig.cameras:
        width, height = camera.image_size
        cx, cy = camera.K[0, 2], camera.K[1, 2]
        if not (0 <= cx <= width - 1 and 0 <= cy <= height - 1):
            problems.append(f"{camera.name}: principal point ({cx:.0f}, {cy:.0f}) outside the {width}x{height} image")
        rms = camera.quality.get("rms_px", 0.0)
        if rms > MAX_RMS_PX:
            problems.append(f"{camera.name}: RMS {rms:.2f} px > {MAX_RMS_PX} px")
        sigma_fx = camera.quality.get("sigma", {}).get("fx", 0.0)
        if sigma_fx > MAX_FOCAL_SIGMA_REL * abs(camera.K[0, 0]):
            problems.append(f"{camera.name}: fx {camera.K[0, 0]:.0f} +/- {sigma_fx:.0f} px "
                            f"(> {100 * MAX_FOCAL_SIGMA_REL:.0f} %)")
    return problems


#: Directions from the principal point along which :func:`fold_radius_px` follows the lens, and its step in pixels.
_FOLD_DIRECTIONS = 72
_FOLD_STEP_PX = 1.0


def fold_radius_px(camera: Camera) -> float | None:
    """Distance from the principal point at which the lens stops mapping the image one-to-one, within the largest
    circle about the principal point that the image holds (None when it does not fold there).

    Along :data:`_FOLD_DIRECTIONS` lines out of the principal point, every :data:`_FOLD_STEP_PX` pixels, the ray of
    each pixel (:meth:`Distortion.rays_from_pixels`) must exist and its angle from the optical axis must grow: a
    lens whose angle stops growing (or has no ray) there maps two parts of the image onto one field, and every
    point it would have to project beyond that radius is lost. Polynomial radial models fitted on views that leave
    the image's rim empty can turn over before the rim (Kannala & Brandt 2006 discuss the same for their
    polynomial in the angle); a held-out view out there is then posed far off.
    """
    width, height = camera.image_size
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    radius = min(cx, cy, width - 1 - cx, height - 1 - cy)
    if radius <= _FOLD_STEP_PX:
        return None
    steps = np.arange(_FOLD_STEP_PX, radius + _FOLD_STEP_PX, _FOLD_STEP_PX)
    angles = np.linspace(0.0, 2.0 * np.pi, _FOLD_DIRECTIONS, endpoint=False)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    pixels = np.array([cx, cy]) + (steps[None, :, None] * directions[:, None, :]).reshape(-1, 2)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        rays = camera.distortion.rays_from_pixels(pixels, camera.K).reshape(len(angles), len(steps), 3)
        theta = np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2])
    bad = ~np.isfinite(theta)
    bad[:, 1:] |= ~(np.diff(theta, axis=1) > 0.0)
    if not bad.any():
        return None
    return float(steps[np.argmax(bad, axis=1)[bad.any(axis=1)].min()])


def _with_projection_sigma(camera: Camera, covariance: NDArray, labels: tuple[str, ...], model: str,
                           jackknife: NDArray | None = None, earlier: Sequence[str] = ()) -> Camera:
    """The camera with ``quality.covariance`` (its intrinsics, its pose, the board gauge and, under their
    ``NAME.param`` labels, the intrinsics and poses of the ``earlier`` cameras: the cross-covariance a
    pair's figures need, :mod:`camcal.geometry.rectify.sigma`) and
    ``quality.worst_projection_sigma_px`` (at infinity, over a 16-pixel grid of the frame;
    :mod:`camcal.geometry.uncertainty`).

    With the delete-one-view ``jackknife`` covariance the block is scaled by
    the design effect of the camera's projection
    (:func:`camcal.geometry.view_jackknife.design_effect`): the corners'
    errors are correlated within a view. ``quality.sigma`` (per parameter)
    stays the corners' covariance."""
    pairs = [(f"{camera.name}.{label}", label) for label in _INTRINSICS + MODELS[model] + POSE]
    pairs += [(f"{other}.{label}",) * 2 for other in earlier for label in _INTRINSICS + MODELS[model] + POSE]
    pairs = [(label, name) for label, name in pairs + list(zip(GAUGE_NAMES, GAUGE)) if label in labels]
    index = [labels.index(label) for label, _ in pairs]
    names = [name for _, name in pairs]

    def block_of(matrix: NDArray) -> ParameterCovariance:
        block = matrix[np.ix_(index, index)]
        return ParameterCovariance(tuple(names), 0.5 * (block + block.T))

    parameters = block_of(covariance)
    camera = dataclasses.replace(camera, quality={**camera.quality.to_dict(), "covariance": parameters})
    xs, ys = sigma_grid(camera.image_size, 16.0)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    sigma = projection_sigma(camera, grid)
    if jackknife is not None:
        factor = design_effect(sigma, projection_sigma(camera, grid, covariance=block_of(jackknife)))
        parameters = ParameterCovariance(tuple(names), factor * parameters.array)
        sigma = sigma * np.sqrt(factor)
    worst = float(np.nanmax(sigma))
    return dataclasses.replace(camera, quality={**camera.quality.to_dict(), "covariance": parameters,
                                                "worst_projection_sigma_px": worst})


def _build_rig(names, image_sizes, params, cam_poses, camera_of_point, image_of_point, residuals, covariance, labels,
               board, model, units, jackknife=None) -> Rig:
    """The rig of a fit; ``covariance`` None (a scoring fit, :func:`_calibrate`): no sigmas."""
    sigma_by_label = {} if covariance is None else dict(zip(labels, np.sqrt(np.clip(np.diag(covariance), 0.0, None))))
    cameras = []
    for j, name in enumerate(names):
        K, distortion = _camcal_lens(model, params[j])
        R, t = cam_poses[j]
        mine = camera_of_point == j
        norms = np.linalg.norm(residuals[mine], axis=1)
        if covariance is None:
            cameras.append(Camera(name, image_sizes[j], K, distortion, R if j else np.eye(3), -R.T @ t if j else np.zeros(3),
                                  quality={"rms_px": float(np.sqrt(np.mean(norms**2))), "worst_px": float(norms.max()),
                                           "n_views": int(len(np.unique(image_of_point[mine]))),
                                           "n_observations": int(mine.sum())}))
            continue
        sigmas = {label: float(sigma_by_label[f"{name}.{label}"]) for label in _INTRINSICS + MODELS[model]}
        if j > 0:
            o = labels.index(f"{name}.rx")
            rotation, translation = covariance[o:o + 3, o:o + 3], covariance[o + 3:o + 6, o + 3:o + 6]
            length = float(np.linalg.norm(t))
            along = t / max(length, 1e-300)
            across = np.eye(3) - np.outer(along, along)
            sigmas["baseline_rel"] = float(np.sqrt(max(along @ translation @ along, 0.0))) / max(length, 1e-300)
            sigmas["baseline_direction_deg"] = float(
                np.degrees(np.sqrt(max(np.trace(across @ translation @ across), 0.0)) / max(length, 1e-300)))
            sigmas["rotation_deg"] = float(np.degrees(np.sqrt(max(np.trace(rotation), 0.0))))
        cameras.append(_with_projection_sigma(
            Camera(
                name=name,
                image_size=image_sizes[j],
                K=K,
                distortion=distortion,
                R=R if j else np.eye(3),
                c=-R.T @ t if j else np.zeros(3),
                quality={
                    "rms_px": float(np.sqrt(np.mean(norms**2))),
                    "worst_px": float(norms.max()),
                    "n_views": int(len(np.unique(image_of_point[mine]))),
                    "n_observations": int(mine.sum()),
                    "sigma": sigmas,
                },
            ), covariance, labels, model, jackknife, names[:j]))
    method = "chessboard" if board.kind == "chessboard" else "charuco"
    return Rig(tuple(cameras), units=units, provenance=make_provenance(method, board=board.spec(), model=model))
