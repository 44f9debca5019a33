"""Rectification on image files: SIFT matches between the cameras' images, rectified images written."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.geometry.rectify import RectifyWarper, match_images
from camcal.io.frames import imread, imwrite
from camcal.io.video import first_frame, frame_file_name, is_video, iter_frames
from camcal.model.rig import Rig

__all__ = ["match_image_files", "write_rectified"]


def match_image_files(
    rig: Rig, images: Mapping[str, str | os.PathLike], ratio: float = 0.75, threshold_px: float = 1.0
) -> dict[tuple[str, str], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """SIFT matches between every pair of the cameras' image files (read grey).

    Parameters
    ----------
    rig : Rig
        Gives each camera's K and distortion.
    images : mapping of str to path
        One image per camera (e.g. the first frame of each sequence), or a
        video (its frame 0).
    ratio, threshold_px : float
        As :func:`camcal.geometry.rectify.match_images`.

    Returns
    -------
    dict
        :data:`camcal.geometry.rectify.Matches` in distorted pixels, one entry per pair of cameras.
    """
    grey = {}
    for name, path in images.items():
        rig.camera(name)
        grey[name] = first_frame(path, gray=True) if is_video(path) else imread(path, cv2.IMREAD_GRAYSCALE)
    return match_images(rig, grey, ratio, threshold_px)


def write_rectified(warper: RectifyWarper, name: str, sources: Sequence[str | os.PathLike],
                    out_dir: str | os.PathLike, every: int = 1) -> list[Path]:
    """Rectify image files of camera ``name`` to ``out_dir/<camera>/<file name>``, each written atomically.

    A video among ``sources`` is streamed (one decoded frame at a time):
    its every ``every``-th frame ``k`` is written as ``<stem>_00000k.png``
    (:func:`camcal.io.video.frame_file_name`).

    Returns
    -------
    list of Path
        The written files, in the order of ``sources``.
    """
    written = []
    for source in sources:
        if is_video(source):
            for k, image in iter_frames(source, every=every, gray=False):
                written.append(imwrite(Path(out_dir) / name / frame_file_name(source, k), warper.warp(name, image)))
            continue
        image = imread(source)
        written.append(imwrite(Path(out_dir) / name / Path(source).name, warper.warp(name, image)))
    return written
