"""Lateral chromatic aberration from files: colour board images in, each corner found in every channel out
(:mod:`camcal.geometry.lateral_ca`), for a Lensfun lens' TCA entries (``rig export --to lensfun --tca``)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.globs import expand_glob
from camcal.geometry.board import Board, detect_board
from camcal.geometry.lateral_ca import channel_corners
from camcal.io.frames import imread

__all__ = ["ChannelCorners", "channel_corners_from_files"]


@dataclass(frozen=True)
class ChannelCorners:
    """The board's corners in each channel of a set of colour images.

    Attributes
    ----------
    corners : ndarray, shape (N, 3, 2)
        Every corner every channel found, R, G, B.
    image_size : (int, int)
    n_images, n_used : int
        Images read, and those in which the board was found.
    """

    corners: NDArray[np.float64]
    image_size: tuple[int, int]
    n_images: int
    n_used: int


def channel_corners_from_files(images: str | os.PathLike | Sequence[str | os.PathLike], board: Board, *,
                               option: str = "--tca", name: str = "images") -> ChannelCorners:
    """Read colour board images (a glob or files), find the board in each, and its corners in every channel.

    Raises
    ------
    CamcalError
        No image matches, an image that is not 8-bit colour or of another size, or the board found in none, in one
        line starting ``OPTION NAME``.
    """
    if isinstance(images, (str, os.PathLike)):
        paths = [Path(path) for path in expand_glob(option, name, os.fspath(images))]
    else:
        paths = [Path(path) for path in images]
    option = f"{option} {name}"
    corners, sizes, used = [], set(), 0
    for path in paths:
        BGR = imread(path, cv2.IMREAD_UNCHANGED)
        if BGR.ndim != 3 or BGR.shape[2] < 3 or BGR.dtype != np.uint8:
            raise CamcalError(f"{option}: {path.name} is not an 8-bit colour image (lateral chromatic aberration is "
                              "measured between its red, green and blue channels)")
        BGR = BGR[:, :, :3]
        sizes.add((BGR.shape[1], BGR.shape[0]))
        if len(sizes) > 1:
            raise CamcalError(f"{option}: the images have different sizes: {sorted(sizes)}")
        detection = detect_board(board, BGR, path.name)
        if detection is None:
            continue
        found, ok = channel_corners(BGR[:, :, ::-1], board, detection)
        corners.append(found[ok])
        used += 1
    if not used:
        raise CamcalError(f"{option}: the board {board.spec()} is found in none of the {len(paths)} images")
    return ChannelCorners(np.concatenate(corners), sizes.pop(), len(paths), used)
