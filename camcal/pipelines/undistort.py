"""Undistortion of image files (every image read and checked, then each written) and of videos (streamed), with the
undistorted rig."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_dir, final_path
from camcal.base.errors import CamcalError
from camcal.geometry.uncertainty import SigmaSummary, projection_sigma_map, summarise_sigma
from camcal.geometry.undistort import make_undistorter
from camcal.io.frames import imread, imwrite
from camcal.io.stmap import write_sigma_map
from camcal.io.video import frame_file_name, is_video, iter_frames, video_info
from camcal.model.rig import Rig, make_provenance

__all__ = ["undistort_images", "undistort_videos", "write_undistorted_sigma"]


def undistort_images(
    rig: Rig,
    camera_name: str,
    images: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike,
    mode: str = "crop",
    overscan: float = 1.1,
    max_fov_deg: float | None = None,
) -> tuple[Path, list[Path]]:
    """Undistort image files of one rig camera and write the undistorted rig.

    Parameters
    ----------
    rig : Rig
    camera_name : str
    images : sequence of path
        Images of that camera, read with ``cv2.IMREAD_UNCHANGED`` (8/16 bit,
        float EXR where OpenCV reads them).
    out_dir : path
        Receives each image under its own name and ``undistorted.rig.json``
        (the rig with that camera replaced by its undistorted camera).
    mode, overscan, max_fov_deg
        See :func:`undistorted_view`.

    Returns
    -------
    rig_path : Path
    image_paths : list of Path

    Notes
    -----
    Every image is read and checked before anything is written; the folder
    is built under a temporary name and renamed at the end
    (:func:`camcal.base.atomic.atomic_dir`).
    """
    camera = rig.camera(camera_name)
    undistorter = make_undistorter(camera, mode, overscan, max_fov_deg)
    out_dir = Path(out_dir)
    loaded = []
    for path in images:
        image = imread(path)
        width, height = camera.image_size
        if image.shape[:2] != (height, width):
            raise CamcalError(f"{path} is {image.shape[1]}x{image.shape[0]} px, camera {camera_name!r} is {width}x{height}")
        loaded.append((Path(path), image))
    if len({path.name for path, _ in loaded}) != len(loaded):
        raise CamcalError("input images must have distinct file names (outputs keep them)")
    cameras = tuple(undistorter.undistorted_camera() if c.name == camera_name else c for c in rig.cameras)
    provenance = make_provenance("undistort", source_camera=camera_name, mode=mode)
    with atomic_dir(out_dir) as staging:
        written = [final_path(imwrite(staging / path.name, undistorter.apply(image)), staging, out_dir)
                   for path, image in loaded]
        Rig(cameras, rig.units, rig.frames, rig.points, provenance).save(staging / "undistorted.rig.json")
    return out_dir / "undistorted.rig.json", written


def undistort_videos(
    rig: Rig,
    camera_name: str,
    videos: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike,
    every: int = 1,
    mode: str = "crop",
    overscan: float = 1.1,
    max_fov_deg: float | None = None,
) -> tuple[Path, list[Path]]:
    """Undistort every ``every``-th frame of videos of one rig camera, streamed, and write the undistorted rig.

    Frame ``k`` of ``clip.mp4`` is written as ``clip_00000k.png`` (8-bit,
    :func:`camcal.io.video.frame_file_name`); one decoded frame is held at
    a time (:func:`camcal.io.video.iter_frames`). Every video's size is
    checked before anything is written; the folder is built under a
    temporary name and renamed at the end (removed if a frame fails).
    Other arguments as :func:`undistort_images`.
    """
    camera = rig.camera(camera_name)
    if not videos or not all(is_video(video) for video in videos):
        raise CamcalError("undistort_videos takes videos only (.mp4 .mov .avi .mkv)")
    if len({Path(video).stem for video in videos}) != len(videos):
        raise CamcalError("input videos must have distinct names (the frames written are named after them)")
    width, height = camera.image_size
    for video in videos:
        size = video_info(video).size
        if size != (width, height):
            raise CamcalError(f"{video} is {size[0]}x{size[1]} px, camera {camera_name!r} is {width}x{height}")
    undistorter = make_undistorter(camera, mode, overscan, max_fov_deg)
    cameras = tuple(undistorter.undistorted_camera() if c.name == camera_name else c for c in rig.cameras)
    provenance = make_provenance("undistort", source_camera=camera_name, mode=mode)
    out_dir = Path(out_dir)
    written = []
    with atomic_dir(out_dir) as staging:
        for video in videos:
            for k, image in iter_frames(video, every=every, gray=False):
                path = imwrite(staging / frame_file_name(video, k), undistorter.apply(image))
                written.append(final_path(path, staging, out_dir))
        Rig(cameras, rig.units, rig.frames, rig.points, provenance).save(staging / "undistorted.rig.json")
    return out_dir / "undistorted.rig.json", written


def write_undistorted_sigma(rig: Rig, camera_name: str, out_dir: str | os.PathLike, mode: str = "crop",
                            overscan: float = 1.1, max_fov_deg: float | None = None,
                            distance: float | None = None) -> tuple[Path, SigmaSummary]:
    """Write ``sigma.exr``: pixel for pixel with :func:`undistort_images`' outputs (same arguments).

    Each pixel holds the projection sigma (plate pixels, worst direction;
    :mod:`camcal.geometry.uncertainty`) of the plate pixel the undistortion
    samples there, NaN where it samples none.
    """
    undistorter = make_undistorter(rig.camera(camera_name), mode, overscan, max_fov_deg)
    maps = undistorter.maps
    source = np.stack([maps.map_x, maps.map_y], axis=-1).astype(np.float64)
    source[(maps.map_x < 0) | (maps.map_y < 0)] = np.nan
    sigma = projection_sigma_map(undistorter.camera, distance, source)
    return write_sigma_map(Path(out_dir) / "sigma.exr", sigma), summarise_sigma(sigma, distance)
