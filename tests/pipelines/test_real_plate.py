"""Real footage with a known lens (bench/bench_real_plate.py): a KITTI-layout sequence read, solved, scored.

The slow test runs on real sequences when ``$CAMCAL_REAL_PLATE_DIR`` names one (or a folder of them; a public
51-frame KITTI odometry excerpt ships as ``KITTI_sequence_1`` in the GitHub repository Gongsta/vSLAM-py) and
is skipped otherwise; its fast sibling reads and scores a constructed sequence.
"""

import os
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from bench_real_plate import ENV, load_sequence, run_camcal, run_pycolmap, score, sequences  # noqa: E402

K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])


def _kitti_folder(folder: Path, n: int = 6) -> list[np.ndarray]:
    """A KITTI-layout sequence: ``n`` blank 64 x 20 frames, ``calib.txt`` (P0 labelled), ``poses.txt`` of a car
    driving forward and turning; the camera-to-world poses."""
    (folder / "image_l").mkdir(parents=True)
    poses = []
    for k in range(n):
        R_wc = Rotation.from_euler("y", 2.0 * k, degrees=True).as_matrix()
        poses.append(np.c_[R_wc, [0.05 * k * k, 0.01 * k, 1.2 * k]])
        cv2.imwrite(str(folder / "image_l" / f"{k:06d}.png"), np.zeros((20, 64), np.uint8))
    (folder / "calib.txt").write_text("P0: " + " ".join(f"{v:e}" for v in np.c_[K, np.zeros(3)].ravel()) + "\n"
                                      + "P1: " + " ".join(["0"] * 12) + "\n")
    (folder / "poses.txt").write_text("\n".join(" ".join(f"{v:.12e}" for v in pose.ravel()) for pose in poses))
    return poses


def test_a_kitti_sequence_is_read_and_a_similar_copy_of_its_truth_scores_zero(tmp_path):
    poses = _kitti_folder(tmp_path / "seq")
    sequence = load_sequence(tmp_path / "seq")
    assert [s.name for s in sequences(tmp_path)] == ["seq"] and sequences(tmp_path / "seq")[0].name == "seq"
    assert np.array_equal(sequence.camera.K, K) and sequence.camera.image_size == (64, 20)
    for k, pose in enumerate(poses):  # world -> camera is the transpose of poses.txt's camera -> world
        np.testing.assert_allclose(sequence.truth[k][0], pose[:, :3].T)
        np.testing.assert_allclose(sequence.truth[k][1], pose[:, 3])
    # a solve's world: turned, scaled by 3 and shifted; the frames the same cameras
    A = Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix()
    similar = {k: (R @ A.T, 3.0 * A @ c + [1.0, 2.0, 3.0]) for k, (R, c) in sequence.truth.items()}
    row = score("camcal", {"seconds": 1.0, "poses": similar}, sequence.truth)
    assert row["registered"] == 6 and row["position_pct"] < 1e-9 and row["rotation_deg"] < 1e-4
    # one frame 0.3 m off (path length: the centres' polyline) and turned 1 degree
    path = np.sum(np.linalg.norm(np.diff([p[:, 3] for p in poses], axis=0), axis=1))
    R, c = similar[3]
    moved = {**similar, 3: (Rotation.from_euler("z", 1.0, degrees=True).as_matrix() @ R, c + 3.0 * A @ [0.3, 0.0, 0.0])}
    row = score("camcal", {"seconds": 1.0, "poses": moved}, sequence.truth)
    assert row["rotation_max_deg"] == pytest.approx(1.0, abs=0.2)
    assert 0.3 * 100 / path * 0.5 < row["position_max_pct"] < 0.3 * 100 / path * 1.2


@pytest.mark.slow
def test_real_forward_footage_registers_every_frame_with_the_lens_held(tmp_path):
    """Every frame of each real sequence registered by camcal with the lens held; its cameras within 1 % of the
    path and 0.5 deg of the ground truth, and no worse than 1.5x plain pycolmap's given the same lens (allowed
    the same forward-moving first pair)."""
    root = os.environ.get(ENV)
    if not root:
        pytest.skip(f"real footage skipped: set {ENV} to a KITTI-layout sequence (image_l/, calib.txt, poses.txt) "
                    "or a folder of them")
    found = sequences(Path(root))
    if not found:
        pytest.skip(f"{root} holds no KITTI-layout sequence (image_l/ or image_0/, calib.txt, poses.txt)")
    for sequence in found:
        ours = score("camcal", run_camcal(sequence, tmp_path / sequence.name / "camcal"), sequence.truth)
        peer = score("pycolmap-forward", run_pycolmap(sequence, tmp_path / sequence.name / "pycolmap")[
            "pycolmap-forward"], sequence.truth)
        assert ours["registered"] == ours["frames"], sequence.name
        assert ours["position_pct"] < 1.0 and ours["rotation_deg"] < 0.5, (sequence.name, ours)
        if "position_pct" in peer:
            assert ours["position_pct"] <= 1.5 * peer["position_pct"], (sequence.name, ours, peer)
            assert ours["rotation_deg"] <= 1.5 * peer["rotation_deg"], (sequence.name, ours, peer)
