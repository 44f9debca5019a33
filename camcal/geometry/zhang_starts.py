"""Board calibration's lens models and starting point: the models' tables, the inputs checked, OpenCV's starts.

The first step of :func:`camcal.geometry.zhang.calibrate_board` (Zhang 2000): the detections checked and keyed by
frame; per camera, OpenCV's ``calibrateCamera`` (``cv2.fisheye.calibrate`` for the Kannala-Brandt models) gives the
starting K, distortion and one board pose per view, checked against a plain pinhole fit; the poses put the board in
front of the camera; each camera's pose relative to the reference is the robust average of the per-view relative
poses (chordal L2 mean, Hartley et al. 2013), chained over cameras sharing views; calibrated lenses given by the
caller start the poses by PnP. camcal's models and COLMAP's (the rig engine's) are converted here both ways.

References
----------
Zhang, Z. (2000). A flexible new technique for camera calibration. IEEE TPAMI 22(11).
Hartley, R., Trumpf, J., Dai, Y. & Li, H. (2013). Rotation averaging. IJCV (chordal L2 mean).
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Collection, Mapping, Sequence
from types import MappingProxyType

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import missing_extra
from camcal.geometry.board import Board, Detection, frame_number
from camcal.model.camera import chordal_mean_rotation
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

__all__ = ["MODELS", "MIN_IMAGES", "INTRINSICS", "OPENCV_FLAGS", "COLMAP_MODELS", "FISHEYE_MODELS", "COLMAP_NAMES",
           "opencv_start", "poses_in_front", "fisheye_flags", "corners_in_front", "camera_poses", "colmap_params",
           "camcal_lens", "checked_views", "known_lenses", "known_start", "FIT_ERRORS", "one_line"]

#: Lens models a board calibration fits and the distortion parameters refined for each.
MODELS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {"none": (), "division": ("lambda",), "polynomial": ("k1", "k2"), "kannala-brandt": ("k1", "k2", "k3", "k4"),
     "opencv": ("k1", "k2", "p1", "p2", "k3"),
     "opencv-rational": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
     "opencv-thin-prism": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
     "kannala-brandt-thin-prism": ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "s1", "s2", "s3", "s4")}
)


#: The camcal distortion model of each fitted lens model.
_LENS = {"opencv-rational": "opencv", "opencv-thin-prism": "opencv"}


#: Fewest images with the board per camera.
MIN_IMAGES = 3


INTRINSICS = ("fx", "fy", "cx", "cy")


OPENCV_FLAGS = {
    "none": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
    "polynomial": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    "opencv": 0,
    "opencv-rational": cv2.CALIB_RATIONAL_MODEL,
    "opencv-thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
    "division": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
}


#: camcal model -> the COLMAP model that is exactly it, and the COLMAP parameters held at 0.
COLMAP_MODELS: Mapping[str, tuple[str, tuple[str, ...]]] = MappingProxyType({
    "none": ("PINHOLE", ()),
    "polynomial": ("OPENCV", ("p1", "p2")),
    "opencv": ("FULL_OPENCV", ("k4", "k5", "k6")),
    "opencv-rational": ("FULL_OPENCV", ()),
    "division": ("DIVISION", ()),
    "kannala-brandt": ("OPENCV_FISHEYE", ()),
    "kannala-brandt-thin-prism": ("RAD_TAN_THIN_PRISM_FISHEYE", ()),
})


#: The Kannala-Brandt models: started from ``cv2.fisheye``, corners beyond 90 degrees left out.
FISHEYE_MODELS = ("kannala-brandt", "kannala-brandt-thin-prism")


#: camcal parameter -> COLMAP parameter where the names differ (RAD_TAN_THIN_PRISM_FISHEYE's k0..k5, p0, s0..s3).
COLMAP_NAMES = {"kannala-brandt-thin-prism": {"k1": "k0", "k2": "k1", "k3": "k2", "k4": "k3", "k5": "k4", "k6": "k5",
                                               "p1": "p1", "p2": "p0", "s1": "s0", "s2": "s1", "s3": "s2", "s4": "s3"}}


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


def opencv_start(board: Board, views: Mapping[int, Detection], model: str, name: str, shared: dict | None = None):
    """OpenCV's calibrateCamera: K, distortion vector and cam_from_board per view.

    ``shared``: the fits that do not depend on the model (the pinhole check below, ``cv2.fisheye``'s start),
    by camera and views, made once for every model fitted to the same views (:func:`rank_models`' folds).

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
    if model in FISHEYE_MODELS:
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
            return None, one_line(error)
        values = np.concatenate([K.ravel(), dist.ravel(), np.ravel(rvecs), np.ravel(tvecs)])
        return ((rms, K, dist, rvecs, tvecs) if np.all(np.isfinite(values)) and np.isfinite(rms) else None), ""

    key = (name, "pinhole", tuple(keys))
    if key not in shared:
        shared[key] = fit(OPENCV_FLAGS["none"] | cv2.CALIB_FIX_PRINCIPAL_POINT)
    plain, reason = shared[key]
    if plain is None:
        raise CamcalError(f"camera {name!r}: OpenCV calibrateCamera failed ({reason or 'non-finite result'})")

    def sound(candidate) -> bool:
        return (candidate is not None and candidate[0] <= plain[0] * (1.0 + 1e-9)
                and all(0.5 < candidate[1][i, i] / plain[1][i, i] < 2.0 for i in (0, 1)))

    chosen, _ = fit(OPENCV_FLAGS[model])
    if not sound(chosen):
        chosen, _ = fit(OPENCV_FLAGS[model] | cv2.CALIB_USE_INTRINSIC_GUESS, plain[1].copy(), None)
    if not sound(chosen):
        chosen = plain
    _, K, dist, rvecs, tvecs = chosen
    poses = {k: (cv2.Rodrigues(r)[0], t.ravel().copy()) for k, r, t in zip(keys, rvecs, tvecs)}
    return K.copy(), dist.ravel().copy(), poses


def poses_in_front(board: Board, views: Mapping[int, Detection], K: NDArray, dist: NDArray,
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


def fisheye_flags(*names: str) -> int:
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
    flags = fisheye_flags("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW")
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    size = views[keys[0]].image_size
    try:
        _, K, dist, _, _ = cv2.fisheye.calibrate(
            object_points, image_points, size, None, None,
            flags=flags | fisheye_flags("CALIB_FIX_K3", "CALIB_FIX_K4"), criteria=criteria,
        )
        _, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
            object_points, image_points, size, K, dist,
            flags=flags | fisheye_flags("CALIB_USE_INTRINSIC_GUESS"), criteria=criteria,
        )
    except cv2.error as error:
        raise CamcalError(
            f"camera {name!r}: OpenCV fisheye.calibrate failed ({str(error).strip().splitlines()[-1]})"
        ) from None
    poses = {k: (cv2.Rodrigues(r)[0], np.asarray(t, dtype=np.float64).ravel()) for k, r, t in zip(keys, rvecs, tvecs)}
    return K, np.asarray(dist, dtype=np.float64).ravel(), poses


def corners_in_front(board: Board, by_frame: list[dict], starts: list[dict],
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


def camera_poses(names: list[str], starts: list[dict]) -> list[tuple[NDArray, NDArray]]:
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


def colmap_params(model: str, K: NDArray, dist: NDArray) -> NDArray[np.float64]:
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


def camcal_lens(model: str, params: NDArray) -> tuple[NDArray[np.float64], Distortion]:
    """camcal's K (pixel centre at 0) and distortion of COLMAP parameters (:data:`COLMAP_MODELS`)."""
    fx, fy, cx, cy = params[:4]
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    if model == "division":  # COLMAP's DIVISION: k in normalised units, round in normalised coordinates
        return K, Distortion("division", {"lambda": params[4] / fx**2, "aspect": fx / fy})
    names = COLMAP_NAMES.get(model, {})
    if names:  # by COLMAP's parameter order
        by_colmap = {colmap: camcal for camcal, colmap in names.items()}
        order = [by_colmap[n] for n in ("k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3")]
        return K, Distortion(model, dict(zip(order, params[4:4 + len(order)])))
    return K, Distortion(_LENS.get(model, model), dict(zip(MODELS[model], params[4:4 + len(MODELS[model])])))


def checked_views(detections: Mapping[str, Sequence[Detection]], board: Board,
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


def known_lenses(names: list[str], by_frame: list[dict], intrinsics: Mapping[str, Camera],
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
        return "none", colmap_params("none", K, np.zeros(0))
    if distortion.model == "polynomial":
        if values.get("k3", 0.0) != 0.0:
            raise CamcalError(f"camera {name!r}: a polynomial lens with k3 is not a model the rig engine has "
                              "(polynomial is k1, k2)")
        return "polynomial", colmap_params("polynomial", K, np.array([values["k1"], values["k2"]]))
    if distortion.model == "division":
        centre = np.asarray(distortion.center if distortion.center is not None else K[:2, 2], dtype=np.float64)
        if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0] or np.abs(centre - K[:2, 2]).max() > 1e-6:
            raise CamcalError(f"camera {name!r}: a division lens needs fx = fy and its centre at the principal "
                              "point here (COLMAP's SIMPLE_DIVISION)")
        f = K[0, 0]
        return "division", np.array([f, K[0, 2] + 0.5, K[1, 2] + 0.5, values["lambda"] * f**2])
    if distortion.model == "kannala-brandt":
        return "kannala-brandt", colmap_params("kannala-brandt", K, np.array([values[k] for k in MODELS["kannala-brandt"]]))
    if distortion.model == "opencv":
        if any(values.get(k, 0.0) != 0.0 for k in ("s1", "s2", "s3", "s4")):
            raise CamcalError(f"camera {name!r}: thin-prism terms are not in the rig engine's models")
        rational = any(values.get(k, 0.0) != 0.0 for k in ("k4", "k5", "k6"))
        lens = "opencv-rational" if rational else "opencv"
        vector = np.array([values.get(k, 0.0) for k in MODELS[lens]])
        return lens, colmap_params(lens, K, vector)
    raise CamcalError(f"camera {name!r}: lens model {distortion.model!r} cannot be held")


def known_start(board: Board, views: Mapping[int, Detection], K: NDArray, lens: Distortion,
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
FIT_ERRORS = (CamcalError, cv2.error, ValueError, np.linalg.LinAlgError)


def one_line(error: Exception) -> str:
    """The last line of ``error``'s message (a missing extra: the line naming it, as the Ceres engine's need)."""
    missing = missing_extra(error)
    if missing is not None:
        return missing.line("the Ceres engine's fit")
    text = str(error).strip().splitlines()
    return text[-1] if text else type(error).__name__
