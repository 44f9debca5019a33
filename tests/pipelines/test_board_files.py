"""Board images in EXR (the OpenCV 5 wheels have no EXR codec): detected through camcal.io.frames."""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.board import Board
from camcal.pipelines.board import detect_in_images
from camcal.model.distortion import Distortion
from camcal.io.frames import imwrite

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from test_board import render_chessboard
from test_plumbline import lambda_for_corner_move, render_distorted


@pytest.mark.parametrize("channels", [1, 3])
def test_exr_board_is_detected_like_the_same_png(tmp_path, channels):
    board = Board("chessboard", 9, 6, 1.0)
    image, truth = render_chessboard(9, 6, 40)
    linear = image.astype(np.float32) / 255.0  # round(255 v) gives the 8-bit image back exactly
    pixels = linear if channels == 1 else np.dstack([linear] * 3)
    imwrite(tmp_path / "board.exr", pixels)
    cv2.imwrite(str(tmp_path / "board.png"), image)
    report = detect_in_images(board, [tmp_path / "board.exr", tmp_path / "board.png"], cache=tmp_path / "cache")
    assert [d.image for d in report.detections] == ["board.exr", "board.png"]
    exr, png = report.detections
    assert exr.image_size == png.image_size == (image.shape[1], image.shape[0])
    assert np.array_equal(exr.corners_px, png.corners_px)
    assert np.linalg.norm(exr.corners_px - truth, axis=1).max() < 0.1
    # the cached result of the EXR is found again
    again = detect_in_images(board, [tmp_path / "board.exr"], cache=tmp_path / "cache")
    assert np.array_equal(again.detections[0].corners_px, exr.corners_px)


def test_corrupt_exr_is_skipped_like_any_unreadable_image(tmp_path):
    board = Board("chessboard", 9, 6, 1.0)
    image, _ = render_chessboard(9, 6, 40)
    cv2.imwrite(str(tmp_path / "good.png"), image)
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    report = detect_in_images(board, [tmp_path / "good.png", tmp_path / "bad.exr"])
    assert [d.image for d in report.detections] == ["good.png"] and report.skipped == ("bad.exr",)


def test_cli_distortion_fit_reads_an_exr_board(tmp_path, capsys):
    image, _ = render_chessboard(9, 6, 60, margin=60)
    height, width = image.shape
    centre = (width / 2 + 7.0, height / 2 - 5.0)
    lam = lambda_for_corner_move(12.0, centre, (width, height))
    distorted = render_distorted(image.astype(np.float32), Distortion("division", {"lambda": lam}, center=centre))
    linear = distorted / np.float32(255.0)
    imwrite(tmp_path / "board.exr", linear)
    cv2.imwrite(str(tmp_path / "board.png"), np.round(np.clip(linear, 0, 1) * 255).astype(np.uint8))
    lenses = {}
    for suffix in ("exr", "png"):
        out = tmp_path / f"lens_{suffix}.json"
        assert main(["distortion", "fit", "--images", str(tmp_path / f"board.{suffix}"), "--board", "chessboard:9x6", "--out", str(out)]) == 0
        lenses[suffix] = json.loads(out.read_text())
    assert "board found in 1 / 1 images" in capsys.readouterr().out
    # the EXR is read to the same 8-bit image as the PNG: the same fit, and the lens it was rendered with
    assert lenses["exr"] == lenses["png"]
    fitted = lenses["exr"]["distortion"]["params"]["lambda"]
    print(f"lambda from the EXR board: {fitted:.4g} (true {lam:.4g})")
    assert abs(fitted / lam - 1) < 0.03
