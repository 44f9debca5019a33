"""Frames for the solve chosen by coverage: image cells x board tilts per camera, and cameras sharing frames.

A long recording of a rig (thousands of frames per camera) holds far more
views than the bundle adjustment needs, most of them near repeats. The frames
kept are chosen greedily for weighted coverage (the greedy algorithm for
maximum coverage, Nemhauser, Wolsey & Fisher 1978: each pick adds the most
not-yet-covered weight), over three kinds of items:

- per camera, (image cell, tilt bin): a corner in cell ``(u, v)`` of a
  :data:`GRID` over the image, seen with the board at a tilt in one of nine
  bins (facing the camera within 15 degrees, or tilted 15-35 / over 35
  degrees towards one of four directions);
- per pair of cameras, a frame both see (up to :data:`PAIR_FRAMES`): what
  links their poses;
- per camera, a view (up to :data:`MIN_CAMERA_VIEWS`): every camera keeps
  enough views for its own fit.

When nothing new can be covered, the targets are raised by their first
values and the picking goes on (a second round of coverage), up to
``max_frames``. The tilt of a view is the board's pose by PnP, with the
camera's known intrinsics or, without them, a focal length fitted to the
camera's views with the principal point at the image centre and no
distortion (enough to sort views into bins of 20 degrees). Ties go to the
frame drawn first by a seeded permutation: the choice is deterministic.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import cv2
import numpy as np
import scipy.sparse
from numpy.typing import NDArray

from camcal.geometry.board import Board, Detection, frame_number, opencv_threads_off
from camcal.model.rig import Camera

__all__ = ["GRID", "MIN_CAMERA_VIEWS", "PAIR_FRAMES", "select_frames", "tilt_bin"]

#: Image cells (columns, rows) of the coverage grid.
GRID = (8, 6)
#: Shared frames per pair of cameras covered in one round.
PAIR_FRAMES = 3
#: Views per camera covered in one round.
MIN_CAMERA_VIEWS = 6
#: Weights of a pair's shared frame and of a camera's view against one (cell, tilt) item.
_PAIR_WEIGHT, _VIEW_WEIGHT = 20.0, 20.0


def tilt_bin(R: NDArray[np.float64]) -> int:
    """Bin of a board pose ``cam_from_board`` rotation: 0 facing the camera (< 15 deg), else 1 + 4 x ring + side.

    The tilt is the angle between the board's normal and the camera's
    optical axis; ring 0 is 15-35 degrees, ring 1 beyond; the side is the
    quadrant (right, down, left, up in the image) the normal leans to.
    """
    normal = R[:, 2] * (1.0 if R[2, 2] <= 0 else -1.0)  # the side facing the camera, pointing at it (z < 0)
    tilt = np.degrees(np.arccos(np.clip(-normal[2], -1.0, 1.0)))
    if tilt < 15.0:
        return 0
    side = int(((np.degrees(np.arctan2(normal[1], normal[0])) + 45.0) % 360.0) // 90.0)
    return 1 + 4 * int(tilt >= 35.0) + side


@opencv_threads_off()  # same input, same output (calibrate_board's reason)
def _focal_guess(board: Board, views: Sequence[Detection]) -> NDArray[np.float64]:
    """K with a focal length fitted to up to 30 views (centre fixed, no distortion); ``max(w, h)`` if that fails."""
    width, height = views[0].image_size
    K = np.array([[max(width, height), 0, (width - 1) / 2], [0, max(width, height), (height - 1) / 2], [0, 0, 1.0]])
    usable = [d for d in views if len(d.ids) >= 6]
    picked = [usable[i] for i in np.linspace(0, len(usable) - 1, min(30, len(usable))).astype(int)] if usable else []
    if len(picked) < 3:
        return K
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    try:
        _, fitted, _, _, _ = cv2.calibrateCamera(
            [board.object_points[d.ids].astype(np.float32) for d in picked],
            [d.corners_px.astype(np.float32) for d in picked], (width, height), K.copy(), np.zeros(5), flags=flags)
    except cv2.error:
        return K
    return fitted if np.all(np.isfinite(fitted)) and fitted[0, 0] > 0 else K


def _view_tilt(board: Board, detection: Detection, K: NDArray, camera: Camera | None) -> int:
    """:func:`tilt_bin` of one view posed by PnP (undistorted with the known lens when there is one)."""
    x = detection.corners_px
    if camera is not None:
        x = camera.distortion.undistort(x, camera.K)
        if not np.all(np.isfinite(x)):
            return 0
    ok, rvec, _ = cv2.solvePnP(board.object_points[detection.ids].astype(np.float64), x.astype(np.float64), K, None,
                               flags=cv2.SOLVEPNP_IPPE)
    return tilt_bin(cv2.Rodrigues(rvec)[0]) if ok else 0


def select_frames(
    board: Board,
    detections: Mapping[str, Sequence[Detection]],
    max_frames: int,
    *,
    intrinsics: Mapping[str, Camera] | None = None,
    exclude: Collection[int] = (),
    seed: int = 0,
) -> tuple[int, ...]:
    """Up to ``max_frames`` frame numbers (sorted) whose views cover the cameras best (see the module docstring).

    Parameters
    ----------
    board : Board
    detections : mapping of str to sequence of Detection
        Camera name -> its views, matched across cameras by frame number
        (:func:`camcal.geometry.board.frame_number`).
    max_frames : int
        Frames to keep; all of them (less ``exclude``) when there are no more.
    intrinsics : mapping of str to Camera, optional
        Known cameras: their K and lens pose the views for the tilt bins.
    exclude : collection of int
        Frames never chosen (e.g. those held out).
    seed : int
        Seed of the permutation that breaks ties.

    Returns
    -------
    tuple of int
    """
    exclude = {int(f) for f in exclude}
    names = list(detections)
    frames = sorted({frame_number(d.image) for views in detections.values() for d in views} - exclude)
    if len(frames) <= max_frames:
        return tuple(frames)
    row_of = {f: n for n, f in enumerate(frames)}
    n_cells = GRID[0] * GRID[1]
    per_camera = n_cells * 9
    n_pairs = len(names) * (len(names) - 1) // 2
    pair_base = len(names) * per_camera
    view_base = pair_base + n_pairs
    rows, cols = [], []
    seen_by: list[list[int]] = [[] for _ in frames]
    for j, name in enumerate(names):
        views = [d for d in detections[name] if frame_number(d.image) in row_of]
        if not views:
            continue
        camera = (intrinsics or {}).get(name)
        K = camera.K if camera is not None else _focal_guess(board, views)
        width, height = views[0].image_size
        for d in views:
            row = row_of[frame_number(d.image)]
            seen_by[row].append(j)
            cu = np.clip((d.corners_px[:, 0] + 0.5) * GRID[0] // width, 0, GRID[0] - 1).astype(int)
            cv = np.clip((d.corners_px[:, 1] + 0.5) * GRID[1] // height, 0, GRID[1] - 1).astype(int)
            cells = np.unique(cv * GRID[0] + cu)
            items = j * per_camera + _view_tilt(board, d, K, camera) * n_cells + cells
            rows.extend([row] * (len(items) + 1))
            cols.extend([*items.tolist(), view_base + j])
    for row, cameras in enumerate(seen_by):
        for a in range(len(cameras)):
            for b in range(a + 1, len(cameras)):
                i, j = sorted((cameras[a], cameras[b]))
                rows.append(row)  # pair (i, j) at its index in the upper triangle
                cols.append(pair_base + i * (2 * len(names) - i - 1) // 2 + (j - i - 1))
    n_items = view_base + len(names)
    M = scipy.sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(frames), n_items))
    M.sum_duplicates()
    M.data[:] = 1.0
    weight = np.ones(n_items)
    weight[pair_base:view_base] = _PAIR_WEIGHT
    weight[view_base:] = _VIEW_WEIGHT
    step = np.ones(n_items)
    step[pair_base:view_base] = PAIR_FRAMES
    step[view_base:] = MIN_CAMERA_VIEWS
    target = step.copy()
    count = np.zeros(n_items)
    # ties: a seeded order, far below the smallest weight
    order = np.random.default_rng(seed).permutation(len(frames)) * (0.5 / len(frames))
    free = np.ones(len(frames), bool)
    chosen = []
    while len(chosen) < max_frames and free.any():
        gain = M @ (weight * (count < target))
        gain[~free] = -np.inf
        if not np.any(gain[free] > 0):
            target = target + step  # everything reachable is covered: the next round
            continue
        best = int(np.argmax(gain - order))
        chosen.append(frames[best])
        free[best] = False
        count[M.indices[M.indptr[best]:M.indptr[best + 1]]] += 1
    return tuple(sorted(chosen))
