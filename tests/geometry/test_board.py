"""Board parsing and detection: synthetic renders with known corners, and the real stereo set."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, detect_board, frame_number, parse_board
from camcal.pipelines.board import detect_in_images


def render_chessboard(columns: int, rows: int, square_px: int, margin: int = 40, flip: bool = False):
    """A (rows+1) x (columns+1) squares chessboard image and its true inner corners (pixel centres at 0)."""
    width = (columns + 1) * square_px + 2 * margin
    height = (rows + 1) * square_px + 2 * margin
    image = np.full((height, width), 230, np.uint8)
    for r in range(rows + 1):
        for c in range(columns + 1):
            if (r + c) % 2 == 0:
                y, x = margin + r * square_px, margin + c * square_px
                image[y : y + square_px, x : x + square_px] = 25
    # the inner corner between pixels x-1 and x lies at x - 0.5 in camcal's convention
    col, row = np.meshgrid(np.arange(1, columns + 1), np.arange(1, rows + 1))
    corners = np.stack([margin + col.ravel() * square_px - 0.5, margin + row.ravel() * square_px - 0.5], axis=1)
    image = cv2.GaussianBlur(image, (5, 5), 1.0)
    if flip:  # a half turn of the image: same board, other corner first
        image = image[::-1, ::-1].copy()
        corners = np.array([width - 1, height - 1]) - corners
    return image, corners


def test_parse_board_specs():
    board = parse_board("chessboard:9x6:0.025")
    assert (board.columns, board.rows, board.n_corners) == (9, 6, 54)
    assert np.allclose(board.object_points[10], [0.025, 0.025, 0.0])
    assert parse_board(board.spec()) == board
    charuco = parse_board("charuco:DICT_5X5_100:7x5:0.04:0.03")
    assert charuco.n_corners == 6 * 4
    assert parse_board(charuco.spec()) == charuco


@pytest.mark.parametrize(
    "spec",
    ["chessboard:9x6", "chess:9x6:1", "chessboard:9by6:1", "chessboard:9x6:-1", "chessboard:1x6:1",
     "charuco:DICT_NOPE:7x5:0.04:0.03", "charuco:DICT_5X5_100:7x5:0.04:0.05", "chessboard:9x6:abc"],
)
def test_bad_board_specs_raise_one_line(spec):
    with pytest.raises(CamcalError) as info:
        parse_board(spec)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("flip", [False, True])
def test_chessboard_corners_subpixel_and_canonical(flip):
    """Rendered board: corners within 0.1 px of the truth, same labelling after a half turn."""
    board = Board("chessboard", 9, 6, 1.0)
    image, truth = render_chessboard(9, 6, 40, flip=flip)
    detection = detect_board(board, image, "render.png")
    assert detection is not None and detection.image_size == (image.shape[1], image.shape[0])
    error = np.linalg.norm(detection.corners_px - truth, axis=1)
    assert error.max() < 0.1


def test_classic_fallback_gives_same_corners(monkeypatch):
    """When the SB detector fails, findChessboardCorners + cornerSubPix finds the same corners."""
    board = Board("chessboard", 9, 6, 1.0)
    image, truth = render_chessboard(9, 6, 40, flip=True)
    monkeypatch.setattr(cv2, "findChessboardCornersSB", lambda *a, **k: (False, None))
    detection = detect_board(board, image)
    assert detection.detector == "classic"
    assert np.linalg.norm(detection.corners_px - truth, axis=1).max() < 0.1


def test_charuco_detection_matches_generated_board():
    """Corners of a generated ChArUco board within 0.1 px (OpenCV 4.11 alone is 0.5 px off)."""
    board = parse_board("charuco:DICT_5X5_100:7x5:40:30")
    margin, px_per_unit = 20, 2  # 80 px squares
    image = board.charuco_board().generateImage((7 * 80 + 2 * margin, 5 * 80 + 2 * margin), marginSize=margin)
    image = cv2.GaussianBlur(image, (5, 5), 1.0)  # sub-pixel refinement needs graded edges
    detection = detect_board(board, image)
    assert detection is not None and len(detection.ids) == board.n_corners
    truth = margin + board.object_points[detection.ids, :2] * px_per_unit - 0.5
    assert np.linalg.norm(detection.corners_px - truth, axis=1).max() < 0.1


def test_missing_board_is_reported_not_raised(tmp_path):
    board = Board("chessboard", 9, 6, 1.0)
    image, _ = render_chessboard(9, 6, 30)
    cv2.imwrite(str(tmp_path / "cam01.png"), image)
    cv2.imwrite(str(tmp_path / "cam02.png"), np.full_like(image, 128))
    (tmp_path / "cam03.png").write_bytes(b"not an image")
    report = detect_in_images(board, sorted(tmp_path.glob("*.png")))
    assert [d.image for d in report.detections] == ["cam01.png"]
    assert report.skipped == ("cam02.png", "cam03.png")
    assert report.summary() == "board found in 1 / 3 images (skipped: cam02.png, cam03.png)"


def test_frame_number():
    assert frame_number("left07.jpg") == 7
    assert frame_number("/x/cam2_frame_0113.png") == 113
    with pytest.raises(CamcalError):
        frame_number("left.jpg")


def test_real_pairs_labelled_alike(shared_data):
    """Left and right detections of a real pair label the same physical corner alike:
    the cameras are side by side, 4 degrees apart, so a corner moves mostly along x."""
    board = Board("chessboard", 9, 6, 1.0)
    folder = shared_data / "stereo_chessboard"
    for number in ("02", "10", "13"):
        left = detect_board(board, cv2.imread(str(folder / f"left{number}.jpg"), cv2.IMREAD_GRAYSCALE))
        right = detect_board(board, cv2.imread(str(folder / f"right{number}.jpg"), cv2.IMREAD_GRAYSCALE))
        shift = right.corners_px - left.corners_px
        assert np.std(shift[:, 1]) < 15.0
        assert np.abs(np.median(shift[:, 1])) < 40.0


def test_detections_cached_by_content_and_threads_agree(tmp_path, monkeypatch):
    """A second pass reads the cache (no detection runs); a changed image is detected again; threads give the same corners."""
    import camcal.pipelines.board as board_module

    board = Board("chessboard", 9, 6, 1.0)
    image, truth = render_chessboard(9, 6, 40)
    for n in range(3):
        cv2.imwrite(str(tmp_path / f"cam{n:02d}.png"), image if n < 2 else np.full_like(image, 128))
    paths = sorted(tmp_path.glob("cam*.png"))
    cache = tmp_path / "cache"
    calls = []
    first = detect_in_images(board, paths, workers=2, cache=cache, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)]  # one call per image, in order, ending at the total
    serial = detect_in_images(board, paths, workers=1)
    assert [d.image for d in first.detections] == ["cam00.png", "cam01.png"] and first.skipped == ("cam02.png",)
    assert all(np.array_equal(a.corners_px, b.corners_px) for a, b in zip(first.detections, serial.detections))
    assert len(list(cache.glob("*.json"))) == 2  # two distinct contents

    def no_detection(*args, **kwargs):
        raise AssertionError("detected although cached")

    monkeypatch.setattr(board_module, "detect_board", no_detection)
    calls.clear()
    again = detect_in_images(board, paths, cache=cache, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(3, 3)]  # all from the cache: one call
    assert again.skipped == first.skipped and [d.image for d in again.detections] == [d.image for d in first.detections]
    assert all(np.array_equal(a.corners_px, b.corners_px) and np.array_equal(a.ids, b.ids)
               for a, b in zip(again.detections, first.detections))
    changed = image.copy()
    changed[0, 0] ^= 1
    cv2.imwrite(str(paths[2]), changed)  # new content: not in the cache
    with pytest.raises(AssertionError, match="detected although cached"):
        detect_in_images(board, paths, cache=cache)


def test_4k_board_the_classic_search_misses_found_by_reduced_sb_and_refined(monkeypatch):
    """A 4K frame where the classic search fails: SB runs on the quarter-size copy (never at full size, 30 s
    there), and the full-size refinement brings its corners to the truth."""
    board = Board("chessboard", 9, 6, 1.0)
    image, truth = render_chessboard(9, 6, 200)
    offset = np.array([880, 700])
    image = np.pad(image, ((offset[1], 2880 - image.shape[0] - offset[1]), (offset[0], 3840 - image.shape[1] - offset[0])),
                   constant_values=230)
    noise = np.random.default_rng(27).normal(0.0, 2.0, image.shape)
    image = np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)
    truth = truth + offset
    searched = []
    find_sb = cv2.findChessboardCornersSB

    def recording_sb(gray, *args, **kwargs):
        searched.append(gray.shape)
        return find_sb(gray, *args, **kwargs)

    monkeypatch.setattr(cv2, "findChessboardCorners", lambda *a, **k: (False, None))
    monkeypatch.setattr(cv2, "findChessboardCornersSB", recording_sb)
    detection = detect_board(board, image)
    assert detection is not None and detection.detector == "sb"
    assert searched == [(720, 960)]  # the quarter-size copy, found at the first call
    error = np.linalg.norm(detection.corners_px - truth, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.015 and error.max() < 0.03  # measured 0.0050 and 0.0105
