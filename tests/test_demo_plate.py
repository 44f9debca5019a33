"""The demo's plate resampling (:func:`camcal.demo.render.write_plate`) moves no chessboard corner with the map's phase.

A render's plate is the render resampled through the lens's redistort map, whose sub-pixel phase varies over the
plate with the distortion. Here the map is a pure translation by a quarter pixel, so every corner must come back
exactly a quarter pixel over: a sharp chessboard (area-sampled, 4 x 4 points a pixel, turned 20 degrees so that
its corners fall at every sub-pixel position) is written as the render, resampled both ways, and detected by
camcal. One cubic remap (OpenCV's) moves the corners by a shift common to all of them (a few hundredths of a
pixel, the bias the rendered anamorphic lens measured); the band-limited resampling must leave under 0.003 px and
under a quarter of that.
"""

import cv2
import numpy as np

from camcal.demo.render import write_plate
from camcal.geometry.board import Board, detect_board
from camcal.io.stmap import write_exr

BOARD = Board("chessboard", 9, 6, 1.0)
SIZE = (320, 240)
SQUARE_PX = 20.0
ANGLE = np.radians(20.0)
ROTATION = np.array([[np.cos(ANGLE), -np.sin(ANGLE)], [np.sin(ANGLE), np.cos(ANGLE)]])
#: The inner corners' centre, in board units (one a square, corner (0, 0) at the origin) and in canvas pixels.
MIDDLE = np.array([(BOARD.columns - 1) / 2, (BOARD.rows - 1) / 2])
CENTRE = np.array([161.3, 118.6])
SHIFT_PX = 0.25


def board_to_pixels(points: np.ndarray) -> np.ndarray:
    """Board units -> canvas pixels."""
    return (points - MIDDLE) @ ROTATION.T * SQUARE_PX + CENTRE


def sharp_render() -> np.ndarray:
    """The board (one white square of margin, black around it) area-sampled by 4 x 4 points a pixel."""
    offsets = (np.arange(4) + 0.5) / 4 - 0.5
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=np.float64), np.arange(SIZE[1], dtype=np.float64))
    value = np.zeros(u.shape)
    for dy in offsets:
        for dx in offsets:
            pixels = np.stack([u + dx, v + dy], axis=-1) - CENTRE
            x, y = np.moveaxis(pixels / SQUARE_PX @ ROTATION + MIDDLE, -1, 0)  # board units
            inside = (x > -2) & (x < BOARD.columns + 1) & (y > -2) & (y < BOARD.rows + 1)
            dark = ((np.floor(x) + np.floor(y)) % 2 == 0) & (x > -1) & (x < BOARD.columns) & (y > -1) & (y < BOARD.rows)
            value += inside & ~dark
    return value / offsets.size**2


def corner_shift(render, tmp_path, band_limit_px: float) -> np.ndarray:
    """Mean error (x, y) of the corners detected in the plate of ``render`` against where the translation puts
    them."""
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=np.float32), np.arange(SIZE[1], dtype=np.float32))
    plate = write_plate(render, (u + SHIFT_PX, v + SHIFT_PX), tmp_path / f"plate_{band_limit_px:g}.png", 8,
                        band_limit_px)
    detection = detect_board(BOARD, cv2.imread(str(plate), cv2.IMREAD_GRAYSCALE))
    truth = board_to_pixels(BOARD.object_points[detection.ids, :2] / BOARD.square) - SHIFT_PX
    return (detection.corners_px - truth).mean(axis=0)


def test_band_limited_plate_keeps_the_corners_where_the_map_puts_them(tmp_path):
    render = write_exr(tmp_path / "render.exr", np.repeat(sharp_render()[..., None], 3, axis=2).astype(np.float32))
    remapped, band_limited = corner_shift(render, tmp_path, 0.0), corner_shift(render, tmp_path, 1.0)
    print(f"corners' common shift, a quarter-pixel translation: cubic remap {remapped} px, band-limited "
          f"{band_limited} px")
    assert np.abs(band_limited).max() < 0.003
    assert np.abs(band_limited).max() < 0.25 * np.abs(remapped).max()
