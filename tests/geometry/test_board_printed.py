"""Boards as printed: inverted and two-sided ChArUco boards, legacy patterns, the options of the board spec."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, detect_board, frame_number, parse_board, video_frame_label
from capture_volume import board_origin_pose, board_texture, make_volume, render_view, true_corners

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405"


def test_board_options_parse_and_round_trip():
    board = parse_board(SPEC + ":inverted:two-sided")
    assert (board.inverted, board.two_sided, board.legacy) == (True, True, False)
    assert board.spec() == SPEC + ":inverted:two-sided" and parse_board(board.spec()) == board
    assert parse_board(SPEC + ":two-sided:inverted") == board  # any order
    chess = parse_board("chessboard:9x6:0.025:two-sided")
    assert chess.two_sided and parse_board(chess.spec()) == chess
    legacy = parse_board("charuco:DICT_5X5_100:6x6:0.04:0.03:legacy")
    assert legacy.legacy and legacy.charuco_board().getLegacyPattern()


@pytest.mark.parametrize("spec", [SPEC + ":mirrored", SPEC + ":inverted:inverted", "chessboard:9x6:1:inverted",
                                  "chessboard:9x6:1:legacy", SPEC + ":"])
def test_bad_board_options_raise_one_line(spec):
    with pytest.raises(CamcalError) as info:
        parse_board(spec)
    assert "\n" not in str(info.value) and spec in str(info.value)


def test_legacy_pattern_detected_only_as_legacy():
    """An even number of rows: the legacy layout differs; each spec finds its own print."""
    legacy = parse_board("charuco:DICT_5X5_100:6x6:40:30:legacy")
    modern = parse_board("charuco:DICT_5X5_100:6x6:40:30")
    image = legacy.charuco_board().generateImage((6 * 80 + 40, 6 * 80 + 40), marginSize=20)
    image = cv2.GaussianBlur(image, (5, 5), 1.0)
    found = detect_board(legacy, image)
    assert found is not None and len(found.ids) == legacy.n_corners
    truth = 20 + legacy.object_points[found.ids, :2] * 2 - 0.5
    assert np.linalg.norm(found.corners_px - truth, axis=1).max() < 0.1
    other = detect_board(modern, image)
    assert other is None or len(other.ids) < modern.n_corners


def test_two_sided_inverted_board_seen_from_both_sides_gives_the_true_board_points():
    """Views from in front and from behind a two-sided inverted board: every id at its true pixel.

    The back is the front's mirror image with the same corners at the same board points, so the corner with id k
    seen from behind must project from board point k: the detections are compared with the truth projections.
    """
    board = parse_board(SPEC + ":inverted:two-sided")
    one_sided = parse_board(SPEC + ":inverted")
    plain = parse_board(SPEC)
    volume = make_volume(6, 12)
    texture = board_texture(board)
    rng = np.random.default_rng(5)
    sides = {"front": 0, "back": 0}
    errors = []
    for f in range(12):
        R_wb, t_wb = board_origin_pose(board, volume.board_R[f], volume.board_t[f])
        for camera in volume.cameras:
            image = render_view(board, texture, camera, R_wb, t_wb, rng)
            if image is None:
                continue
            found = detect_board(board, image)
            if found is None:
                continue
            # the side the camera sees: the board's +z normal points away from a camera in front of it
            normal = camera.R @ R_wb[:, 2]
            centre = camera.R @ (t_wb - camera.c)
            behind = normal @ centre < 0
            assert found.detector == ("charuco-mirrored" if behind else "charuco")
            sides["back" if behind else "front"] += 1
            # a wrong id would be a square (20-40 px here) off; the corners' own error is the detector's
            truth = true_corners(board, camera, R_wb, t_wb)
            spacing = np.linalg.norm(truth[1] - truth[0])
            errors.append(np.linalg.norm(found.corners_px - truth[found.ids], axis=1))
            assert errors[-1].max() < 0.1 * spacing
            if behind:  # a one-sided spec does not see the back; a non-inverted spec sees nothing
                back = detect_board(one_sided, image)
                assert back is None or len(back.ids) < len(found.ids)
            assert detect_board(plain, image) is None
    assert sides["front"] >= 5 and sides["back"] >= 5
    assert np.median(np.concatenate(errors)) < 0.15


def test_video_frame_labels_carry_the_frame_number():
    assert video_frame_label("/x/cam_0.mp4", 12) == "cam_0.mp4#12"
    assert frame_number("cam_0.mp4#12") == 12 and frame_number("cam_3.mkv#0") == 0
