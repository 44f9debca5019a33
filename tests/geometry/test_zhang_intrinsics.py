"""Rig calibration with intrinsics given (held or refined) and the view-graph check."""

import dataclasses

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board
from camcal.geometry.zhang import calibrate_board
from test_zhang import BOARD, board_views, check_against_truth, rotation_error_deg, true_rig


def test_intrinsics_held_solve_only_the_poses():
    truth = true_rig(3, "polynomial")
    detections = board_views(truth, 12, np.random.default_rng(1))
    result = calibrate_board(BOARD, detections, intrinsics={c.name: c for c in truth})
    assert result.model == "polynomial" and "intrinsics held (extrinsics only)" in result.notes
    for camera, true in zip(result.rig.cameras, truth):
        assert np.allclose(camera.K, true.K) and camera.distortion.params == pytest.approx(true.distortion.params)
        assert camera.quality["sigma"]["fx"] == 0.0
        assert rotation_error_deg(camera.R, true.R @ truth[0].R.T) < 0.02


def test_refine_intrinsics_starts_from_them():
    truth = true_rig(2, "polynomial")
    detections = board_views(truth, 30, np.random.default_rng(0))  # test_zhang's scene for these bounds
    start = {c.name: dataclasses.replace(c, K=c.K * [[1.01], [1.01], [1]]) for c in truth}
    result = calibrate_board(BOARD, detections, intrinsics=start, refine_intrinsics=True)
    check_against_truth(result, truth)


def test_intrinsics_that_do_not_fit_raise_one_line():
    truth = true_rig(2, "polynomial")
    detections = board_views(truth, 6, np.random.default_rng(3))
    cases = [({"cam0": truth[0]}, "cam1 not in the intrinsics"),
             ({c.name: dataclasses.replace(c, image_size=(640, 400)) for c in truth}, "640x400"),
             ({"cam0": truth[0], "cam1": true_rig(2, "division")[1]}, "different lens models")]
    for intrinsics, message in cases:
        with pytest.raises(CamcalError, match=message) as info:
            calibrate_board(BOARD, detections, intrinsics=intrinsics)
        assert "\n" not in str(info.value)
    with pytest.raises(CamcalError, match="--model opencv"):
        calibrate_board(BOARD, detections, model="opencv", intrinsics={c.name: c for c in truth})


def test_cameras_not_linked_name_the_groups():
    truth = true_rig(3, "polynomial")
    detections = board_views(truth, 8, np.random.default_rng(4))
    detections["cam2"] = [dataclasses.replace(d, image=d.image.replace("_0", "_9")) for d in detections["cam2"]]
    with pytest.raises(CamcalError, match=r"not linked through shared frames: cam0, cam1 \| cam2"):
        calibrate_board(BOARD, detections)


def test_two_sided_chessboard_seen_from_the_front_by_a_rig():
    """Every view from the front: no view relabelled, the rig as with a one-sided board (the ring of cameras
    around one is tests/geometry/test_labelling.py)."""
    truth = true_rig(2, "polynomial")
    detections = board_views(truth, 20, np.random.default_rng(5))
    two_sided = Board("chessboard", 12, 9, 0.04, two_sided=True)
    result = calibrate_board(two_sided, detections, model="polynomial")
    assert result.relabelled == () and result.dropped == ()
    check_against_truth(result, truth)
