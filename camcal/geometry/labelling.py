"""One corner labelling per frame across a rig: symmetric and two-sided chessboards.

A chessboard's corners are labelled from the image alone
(:func:`camcal.geometry.board.detect_board`: the board's axes right-handed
in the image, the darker end of the diagonal first). Two things defeat that
labelling, and each makes a view's labelling one of a few candidates:

- a board with ``W + H`` even (inner corners) looks the same after a half
  turn about its normal: the labelling as detected or turned by it;
- a two-sided board (printed on the back as the mirror image, each back
  corner at the same board point) seen from behind shows the front pattern
  mirrored: its true labelling is left-handed in the image, i.e. the one
  detected mirrored across a board axis (across the columns when ``W`` is
  even, across the rows when ``W`` is odd: the mirror that keeps the darker
  end of the diagonal first).

For one camera every candidate is as good as another (each is a rigid pose
of the board: a half turn is a rotation of pi about the board's normal, a
mirror across a board axis a rotation of pi about that axis, which the
plane ``z = 0`` cannot tell from the mirror). For a rig they are not: the
cameras of one frame see one board pose. :func:`resolve_labellings` picks,
camera by camera, the candidate whose relative pose agrees with the cameras
already labelled, as a consensus over the frames they share.

Board coordinates: corner ``id = row * W + col`` at ``(col s, row s, 0)``
(:class:`camcal.geometry.board.Board`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.board import Board, Detection
from camcal.model.camera import chordal_mean_rotation, rotation_angle_deg

__all__ = ["LABEL_AGREEMENT_DEG", "Symmetry", "board_symmetries", "relabelled", "relabelled_pose",
           "resolve_labellings"]

#: A view's relative pose must agree with the rig's consensus within this angle (the candidates differ by 180 deg).
LABEL_AGREEMENT_DEG = 20.0


@dataclass(frozen=True)
class Symmetry:
    """A relabelling of a chessboard's corners that the board's image cannot rule out.

    Attributes
    ----------
    name : str
        ``"as detected"``, ``"half turn"``, ``"mirrored across the columns"``
        or ``"mirrored across the rows"``.
    M : ndarray, shape (3, 3)
        Rotation with ``X_detected = M X_relabelled + shift`` (board points
        of one physical corner under the two labellings).
    shift : ndarray, shape (3,)
    flip_rows, flip_cols : bool
        ``(row, col) -> (H - 1 - row, col)`` and ``(row, W - 1 - col)``.
    """

    name: str
    M: NDArray[np.float64]
    shift: NDArray[np.float64]
    flip_rows: bool
    flip_cols: bool


def board_symmetries(board: Board) -> tuple[Symmetry, ...]:
    """The candidate labellings of a view of ``board``, ``as detected`` first.

    One for a ChArUco board (its markers fix the labelling) and for a
    one-sided chessboard with ``W + H`` odd; a half turn too when ``W + H``
    is even; a two-sided chessboard adds its back: the mirror keeping the
    darker diagonal end first (across the columns for ``W`` even, the rows
    for ``W`` odd), or both mirrors when ``W + H`` is even.
    """
    W, H, s = board.columns, board.rows, board.square

    def make(name: str, flip_rows: bool, flip_cols: bool) -> Symmetry:
        M = np.diag([-1.0 if flip_cols else 1.0, -1.0 if flip_rows else 1.0, 1.0])
        M[2, 2] = np.linalg.det(M)  # a proper rotation: the mirror in the plane is a turn about the in-plane axis
        shift = np.array([(W - 1) * s if flip_cols else 0.0, (H - 1) * s if flip_rows else 0.0, 0.0])
        return Symmetry(name, M, shift, flip_rows, flip_cols)

    found = [make("as detected", False, False)]
    if board.kind != "chessboard":
        return tuple(found)
    symmetric = (W + H) % 2 == 0
    if symmetric:
        found.append(make("half turn", True, True))
    if board.two_sided:
        if symmetric or W % 2 == 0:
            found.append(make("mirrored across the columns", False, True))
        if symmetric or W % 2 == 1:
            found.append(make("mirrored across the rows", True, False))
    return tuple(found)


def relabelled_pose(symmetry: Symmetry, R: NDArray, t: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``cam_from_board`` of a view relabelled by ``symmetry``, from its pose ``(R, t)`` as detected.

    ``R X_detected + t = R (M X' + shift) + t``, so ``R' = R M`` and ``t' = R shift + t``.
    """
    return R @ symmetry.M, R @ symmetry.shift + t


def relabelled(board: Board, symmetry: Symmetry, detection: Detection) -> Detection:
    """The same corners under the labelling ``symmetry`` (ids sorted)."""
    row, col = np.divmod(detection.ids, board.columns)
    if symmetry.flip_rows:
        row = board.rows - 1 - row
    if symmetry.flip_cols:
        col = board.columns - 1 - col
    ids = row * board.columns + col
    order = np.argsort(ids)
    return Detection(detection.image, detection.image_size, ids[order], detection.corners_px[order],
                     detection.detector)


#: Most frames the consensus of one camera's relative rotation is taken over.
_CONSENSUS_FRAMES = 200
_COS_AGREEMENT = np.cos(np.radians(LABEL_AGREEMENT_DEG))


def _cosine(A: NDArray, B: NDArray) -> NDArray[np.float64]:
    """``cos`` of the angle of ``A_a B_b^T`` for every pair: ``(trace - 1) / 2``, shape (len(A), len(B))."""
    return (np.einsum("aij,bij->ab", A, B) - 1.0) / 2.0


def resolve_labellings(board: Board, names: list[str], by_frame: list[dict[int, Detection]],
                       starts: list[dict[int, tuple[NDArray, NDArray]]]):
    """Relabel views so that every camera of a frame labels the board alike.

    Parameters
    ----------
    board : Board
    names : list of str
        Camera names, the reference first.
    by_frame : list of dict
        Per camera, frame number -> detection.
    starts : list of dict
        Per camera, frame number -> ``cam_from_board`` ``(R, t)`` of that view (as detected).

    Returns
    -------
    by_frame, starts, relabelled, dropped
        New dicts (the inputs are not changed); ``relabelled`` and
        ``dropped`` list ``(camera, image, reason)``.

    Notes
    -----
    Cameras are labelled in turn, the reference first (its views as
    detected), then always the camera sharing the most frames with those
    labelled already (breadth first over the view graph). For camera ``j``,
    each frame ``f`` it shares with a labelled camera ``i`` (the first
    labelled) gives one candidate rotation per symmetry ``g``,
    ``R_j(f) M_g R_i(f)^T Q_i``, of ``cam_j_from_reference`` (``Q_i`` that
    of camera ``i``). The candidate within :data:`LABEL_AGREEMENT_DEG` of
    the most frames is the consensus (taken over at most 200 frames spread
    over the shared ones); each view takes the symmetry closest
    to it, a view with none within the angle is dropped, and ``Q_j`` is the
    chordal mean of the kept candidates (Hartley et al. 2013). A wrong
    candidate ``R_j M_g R_i^T`` with ``g`` not the view's own moves with the
    board's orientation from frame to frame, the right one does not: a
    consensus needs frames where the board turns. Views of frames no
    labelled camera sees keep their labelling and anchor the cameras after.
    """
    symmetries = board_symmetries(board)
    by_frame = [dict(views) for views in by_frame]
    starts = [dict(poses) for poses in starts]
    if len(symmetries) == 1:
        return by_frame, starts, [], []
    done_relabelled, dropped = [], []
    labelled: dict[int, NDArray[np.float64]] = {0: np.eye(3)}
    order = [0]
    while True:
        shared = {j: [f for f in starts[j] if any(f in starts[i] for i in order)]
                  for j in range(len(names)) if j not in labelled}
        shared = {j: frames for j, frames in shared.items() if frames}
        if not shared:
            break
        j = max(shared, key=lambda k: (len(shared[k]), -k))
        frames = sorted(shared[j])
        candidates = np.empty((len(frames), len(symmetries), 3, 3))
        for n, f in enumerate(frames):
            i = next(i for i in order if f in starts[i])
            R_i, R_j = starts[i][f][0], starts[j][f][0]
            candidates[n] = [R_j @ g.M @ R_i.T @ labelled[i] for g in symmetries]
        # the consensus among at most _CONSENSUS_FRAMES frames spread over them (the support is quadratic)
        sample = candidates[np.unique(np.linspace(0, len(frames) - 1, min(len(frames), _CONSENSUS_FRAMES)).round()
                                      .astype(int))]
        flat = sample.reshape(-1, 3, 3)
        close = _cosine(flat, flat).reshape(len(flat), len(sample), len(symmetries)) > _COS_AGREEMENT
        consensus = flat[int(np.argmax(close.any(axis=2).sum(axis=1)))]
        kept = []
        for f, rotations in zip(frames, candidates):
            angles = [rotation_angle_deg(R @ consensus.T) for R in rotations]
            best = int(np.argmin(angles))
            if angles[best] > LABEL_AGREEMENT_DEG:
                dropped.append((names[j], by_frame[j].pop(f).image, "no labelling agrees with the rig"))
                del starts[j][f]
                continue
            kept.append(rotations[best])
            if best:
                symmetry = symmetries[best]
                by_frame[j][f] = relabelled(board, symmetry, by_frame[j][f])
                starts[j][f] = relabelled_pose(symmetry, *starts[j][f])
                done_relabelled.append((names[j], by_frame[j][f].image, symmetry.name))
        labelled[j] = chordal_mean_rotation(np.array(kept)) if kept else consensus
        order.append(j)
    return by_frame, starts, done_relabelled, dropped
