"""Two-sided and symmetric chessboards in a rig: a ring of cameras around a rendered two-sided chessboard.

A camera behind a two-sided chessboard sees the front pattern mirrored; the detector labels every view as if
seen from the front, so a back view's labelling is the true one mirrored across a board axis. The rig's
labelling (camcal.geometry.labelling) must pick, per view, the side the other cameras of its frame agree on.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from camcal.geometry import zhang, zhang_fit
from camcal.geometry.board import Board, Detection, detect_board, parse_board
from camcal.geometry.labelling import board_symmetries, relabelled, relabelled_pose
from camcal.model.camera import rotation_angle_deg

sys.path.insert(0, str(Path(__file__).resolve().parent))
from capture_volume import board_origin_pose, board_texture, make_volume, render_view, true_corners  # noqa: E402


@pytest.mark.parametrize("spec, names", [
    ("chessboard:7x6:0.05", ["as detected"]),
    ("chessboard:8x6:0.05", ["as detected", "half turn"]),
    ("chessboard:8x5:0.05:two-sided", ["as detected", "mirrored across the columns"]),
    ("chessboard:7x6:0.05:two-sided", ["as detected", "mirrored across the rows"]),
    ("chessboard:8x6:0.05:two-sided", ["as detected", "half turn", "mirrored across the columns",
                                       "mirrored across the rows"]),
    ("charuco:DICT_4X4_50:5x4:0.05:0.04:two-sided", ["as detected"]),
])
def test_symmetries_map_one_physical_corner_to_one_pixel(spec, names):
    """Each relabelling with its pose projects every corner to the same point as the labelling it came from."""
    board = parse_board(spec)
    symmetries = board_symmetries(board)
    assert [s.name for s in symmetries] == names
    rng = np.random.default_rng(0)
    R, t = np.linalg.qr(rng.normal(size=(3, 3)))[0], rng.normal(size=3)
    R *= np.linalg.det(R)
    ids = np.sort(rng.choice(board.n_corners, 12, replace=False))
    seen = board.object_points[ids] @ R.T + t
    detection = Detection("a.png", (640, 480), ids, seen[:, :2], "synthetic")
    for symmetry in symmetries:
        assert np.allclose(symmetry.M @ symmetry.M.T, np.eye(3)) and np.isclose(np.linalg.det(symmetry.M), 1.0)
        other = relabelled(board, symmetry, detection)
        R2, t2 = relabelled_pose(symmetry, R, t)
        assert np.allclose((board.object_points[other.ids] @ R2.T + t2)[:, :2], other.corners_px)
        assert sorted(other.ids.tolist()) == other.ids.tolist() and len(set(other.ids.tolist())) == len(ids)


def ring_detections(board, volume, noise=1.0, seed=5):
    """Rendered views of every camera and frame, detected; and the side each view sees (True: the back)."""
    rng = np.random.default_rng(seed)
    texture = board_texture(board)
    detections, back, errors = {c.name: [] for c in volume.cameras}, {}, {}
    for f, (R_wb, centre) in enumerate(zip(volume.board_R, volume.board_t)):
        R_wb, t_wb = board_origin_pose(board, R_wb, centre)
        for camera in volume.cameras:
            image = render_view(board, texture, camera, R_wb, t_wb, rng, noise=noise)
            if image is None:
                continue
            found = detect_board(board, image, f"{camera.name}_{f:03d}.png")
            if found is None:
                continue
            # the board's z axis points away from a camera that sees its printed front (x right, y down in its image)
            behind = float((camera.c - t_wb) @ R_wb[:, 2]) > 0.0
            grid = true_corners(board, camera, R_wb, t_wb).reshape(board.rows, board.columns, 2)
            labellings = {"front": grid, "back": grid[:, ::-1], "rows": grid[::-1], "half turn": grid[::-1, ::-1]}
            errors[found.image] = {name: float(np.abs(found.corners_px - x.reshape(-1, 2)).max())
                                   for name, x in labellings.items()}
            detections[camera.name].append(found)
            back[camera.name, f] = behind
    return detections, back, errors


@pytest.fixture(scope="module")
def ring():
    """Six cameras on a 2.2 m ring around a two-sided 8x5 chessboard (W + H odd) turning 1.5 times in 36 frames."""
    board = parse_board("chessboard:8x5:0.05:two-sided")
    volume = make_volume(6, 36, seed=4)
    return (board, volume, *ring_detections(board, volume))


def multiview_rotation_error(board, volume, detections, relabel, symmetry):
    """Worst camera rotation error of ``cv2.calibrateMultiview`` on the views (those in ``relabel`` relabelled)."""
    import cv2

    names = [c.name for c in volume.cameras]
    frames = sorted({int(d.image[-7:-4]) for views in detections.values() for d in views})
    mask = np.zeros((len(names), len(frames)), np.uint8)
    points = [[np.zeros((board.n_corners, 2), np.float32) for _ in frames] for _ in names]
    for i, name in enumerate(names):
        for d in detections[name]:
            view = relabelled(board, symmetry, d) if d.image in relabel else d
            n = frames.index(int(d.image[-7:-4]))
            mask[i, n] = 1
            points[i][n] = view.corners_px.astype(np.float32)
    pinhole = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    obj = np.asarray(board.object_points, np.float32)
    try:
        _, _, _, rvecs, _ = cv2.calibrateMultiview([obj] * len(frames), points, [c.image_size for c in volume.cameras],
                                                   mask, np.zeros(len(names), np.uint8), None, None, None, None,
                                                   flagsForIntrinsics=np.full(len(names), pinhole, np.int32))
    except cv2.error:
        return float("inf")
    ref = volume.cameras[0]
    return max(rotation_angle_deg(cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0] @ (t.R @ ref.R.T).T)
               for r, t in zip(rvecs, volume.cameras))


def rig_errors(rig, volume):
    ref = volume.cameras[0]
    rotations, centres = [], []
    for camera, true in zip(rig.cameras, volume.cameras):
        rotations.append(rotation_angle_deg(camera.R @ (true.R @ ref.R.T).T))
        centres.append(float(np.linalg.norm(camera.c - ref.R @ (true.c - ref.c))))
    return max(rotations), max(centres)


@pytest.mark.slow
def test_ring_around_a_two_sided_chessboard_against_truth(ring, monkeypatch):
    board, volume, detections, back, errors = ring
    # the detector labels every view as seen from the front: a back view's labelling is the true one mirrored
    # (W even: across the columns), checked against the true corners
    for (name, f), behind in back.items():
        distances = errors[f"{name}_{f:03d}.png"]
        assert min(distances, key=distances.get) == ("back" if behind else "front"), (name, f, distances)
    misdetected = {image for image, distances in errors.items() if min(distances.values()) > 1.0}
    n_back = sum(back.values())
    assert 0.25 * len(back) < n_back < 0.75 * len(back)  # both sides seen, by every camera
    assert all(any(back[c.name, f] for (name, f) in back if name == c.name) for c in volume.cameras)
    result = zhang.calibrate_board(board, detections, intrinsics={c.name: c for c in volume.cameras})
    rotation, centre = rig_errors(result.rig, volume)
    print(f"\n{len(back)} views ({n_back} of the back, {len(misdetected)} with corners > 1 px off at grazing angles), "
          f"{len(result.relabelled)} relabelled, {len(result.dropped)} dropped, {result.n_outliers} outliers; "
          f"worst rotation {rotation:.4f} deg, worst centre {centre * 1e3:.3f} mm "
          f"({100 * centre / volume.size_m:.4f} % of {volume.size_m:.1f} m); RMS {result.rms_px:.3f} px")
    assert result.dropped == () and {image for _, image in result.outliers} <= misdetected
    assert rotation < 0.05 and centre < 1e-3 * volume.size_m
    # each frame's views agree on the side after relabelling: a view relabelled iff its side differs from the
    # side of the frame's views left as detected
    relabelled_views = {image for _, image in result.relabelled}
    for f in {f for _, f in back}:
        views = [(name, b) for (name, g), b in back.items() if g == f]
        sides = {b != (f"{name}_{f:03d}.png" in relabelled_views) for name, b in views}
        assert len(sides) == 1, (f, views)

    # the peer on the same corners, cv2.calibrateMultiview (fits its own pinhole intrinsics: OpenCV 5.0's binding
    # refuses given ones): with the detector's labelling as a user would pass it, and with camcal's relabelling
    mirrored = board_symmetries(board)[1]
    fixed = {image for _, image in result.relabelled}
    peer = {name: multiview_rotation_error(board, volume, detections, fixed if labelled else set(), mirrored)
            for name, labelled in (("as detected", False), ("relabelled by camcal", True))}
    print("calibrateMultiview: worst rotation " + ", ".join(f"{v:.4f} deg (corners {k})" for k, v in peer.items()))
    assert peer["as detected"] > 1.0  # the peer has no two-sided labelling: a user's corners break it

    # without the labelling the same views break the rig
    monkeypatch.setattr(zhang_fit, "resolve_labellings", lambda board, names, by_frame, starts: (by_frame, starts, [], []))
    try:
        broken = zhang.calibrate_board(board, detections, intrinsics={c.name: c for c in volume.cameras})
    except Exception:
        return
    rotation_broken, _ = rig_errors(broken.rig, volume)
    print(f"without the labelling: worst rotation {rotation_broken:.2f} deg, RMS {broken.rms_px:.2f} px")
    assert rotation_broken > 1.0 or broken.rms_px > 10 * result.rms_px


@pytest.mark.slow
def test_two_sided_chessboard_rig_fits_its_own_lenses(ring):
    """Intrinsics fitted too (no lens): the same bounds."""
    board, volume, detections, back, _ = ring
    result = zhang.calibrate_board(board, detections, model="none")
    rotation, centre = rig_errors(result.rig, volume)
    for camera, true in zip(result.rig.cameras, volume.cameras):
        assert abs(camera.K[0, 0] / true.K[0, 0] - 1) < 2e-3
    print(f"\nfitted lenses: worst rotation {rotation:.4f} deg, worst centre {centre * 1e3:.3f} mm")
    assert rotation < 0.05 and centre < 1e-3 * volume.size_m


@pytest.mark.parametrize("spec", ["chessboard:8x5:0.05:two-sided", "chessboard:8x6:0.05:two-sided"])
def test_ring_labelled_like_the_detector_against_truth(spec):
    """The ring's corners projected (no rendering), labelled as the detector labels them: a back view mirrored,
    and on a board with W + H even any view turned by a half turn at random. Rotations and centres against truth."""
    board = parse_board(spec)
    volume = make_volume(6, 16, seed=4)
    rng = np.random.default_rng(8)
    symmetries = {s.name: s for s in board_symmetries(board)}
    detections, n_back = {c.name: [] for c in volume.cameras}, 0
    for f, (R_wb, centre) in enumerate(zip(volume.board_R, volume.board_t)):
        R_wb, t_wb = board_origin_pose(board, R_wb, centre)
        for camera in volume.cameras:
            X_cam = (board.object_points @ R_wb.T + t_wb - camera.c) @ camera.R.T
            pixels = camera.project(board.object_points @ R_wb.T + t_wb)
            if np.any(X_cam[:, 2] < 0.1) or np.any(pixels < 5) or np.any(pixels > np.array(camera.image_size) - 5):
                continue
            view = Detection(f"{camera.name}_{f:03d}.png", camera.image_size, np.arange(board.n_corners),
                             pixels + rng.normal(0, 0.1, pixels.shape), "synthetic")
            if float((camera.c - t_wb) @ R_wb[:, 2]) > 0.0:  # seen from behind: labelled mirrored
                view = relabelled(board, symmetries["mirrored across the columns"], view)
                n_back += 1
            if "half turn" in symmetries and rng.uniform() < 0.3:
                view = relabelled(board, symmetries["half turn"], view)
            detections[camera.name].append(view)
    assert 0 < n_back < sum(map(len, detections.values()))
    result = zhang.calibrate_board(board, detections, intrinsics={c.name: c for c in volume.cameras})
    rotation, centre = rig_errors(result.rig, volume)
    print(f"\n{spec}: {sum(map(len, detections.values()))} views ({n_back} of the back), "
          f"{len(result.relabelled)} relabelled; worst rotation {rotation:.4f} deg, centre {centre * 1e3:.3f} mm")
    assert result.dropped == () and result.n_outliers == 0
    assert rotation < 0.05 and centre < 1e-3 * volume.size_m
