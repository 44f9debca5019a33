"""Undistortion of image files (every image read and checked, then each written) and of videos (streamed), with the
undistorted rig."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_dir, final_path
from camcal.base.errors import CamcalError
from camcal.geometry.uncertainty import SigmaSummary, projection_sigma_map, summarise_sigma
from camcal.geometry.undistort import make_undistorter, undistorted_rig, undistorted_view
from camcal.io.frames import imread, imwrite
from camcal.io.stmap import write_sigma_map
from camcal.io.video import frame_file_name, is_video, iter_frames, video_info
from camcal.model.rig import Rig, make_provenance

__all__ = ["image_frame", "undistort_images", "undistort_videos", "write_undistorted_sigma"]


def undistort_images(
    rig: Rig,
    camera_name: str,
    images: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike,
    mode: str = "crop",
    overscan: float = 1.1,
    max_fov_deg: float | None = None,
    rig_dir: str | os.PathLike | None = None,
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
    rig_dir : path, optional
        The rig file's folder, against which its frames' ``images`` are
        resolved (:func:`image_frame`).

    Returns
    -------
    rig_path : Path
    image_paths : list of Path

    Notes
    -----
    A camera whose lens changes over the rig's frames (a zoom: its
    ``frames[i].lenses``) undistorts each image with the lens of its frame
    (:func:`image_frame`): each output is what a camera with that frame's
    lens alone gives. The undistorted rig holds each frame's undistorted
    camera as that frame's lens
    (:func:`camcal.geometry.undistort.undistorted_rig`).
    Every image is read and checked before anything is written; the folder
    is built under a temporary name and renamed at the end
    (:func:`camcal.base.atomic.atomic_dir`).
    """
    camera = rig.camera(camera_name)
    provenance = make_provenance("undistort", source_camera=camera_name, mode=mode)
    # checked before anything is read or written: a fixed output size, each image's frame known
    undistorted = undistorted_rig(rig, camera_name, lambda c: undistorted_view(c, mode, overscan, max_fov_deg),
                                  provenance)
    per_frame = bool(rig.lens_frames(camera_name))
    frames = [image_frame(rig, camera_name, path, rig_dir) if per_frame else None for path in images]
    undistorters = {frame: make_undistorter(camera if frame is None else rig.camera_at_frame(camera_name, frame),
                                            mode, overscan, max_fov_deg) for frame in dict.fromkeys(frames)}
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
    with atomic_dir(out_dir) as staging:
        written = [final_path(imwrite(staging / path.name, undistorters[frame].apply(image)), staging, out_dir)
                   for (path, image), frame in zip(loaded, frames)]
        undistorted.save(staging / "undistorted.rig.json")
    return out_dir / "undistorted.rig.json", written


def image_frame(rig: Rig, camera_name: str, path: str | os.PathLike, rig_dir: str | os.PathLike | None = None) -> int:
    """The rig frame an image of camera ``camera_name`` belongs to.

    The frame whose ``images`` names the file (resolved against
    ``rig_dir``, the rig file's folder, when given; else by file name);
    otherwise the frame number in the file name, the last run of digits
    of its stem (``plate.1001.exr``, ``left_0012.png``), when the rig has
    that frame.

    Raises
    ------
    CamcalError
        Neither gives a frame of the rig (the image named).
    """
    path = Path(path)
    for frame in rig.frames:
        listed = frame.images.get(camera_name)
        if listed is None:
            continue
        if rig_dir is not None and (Path(rig_dir) / listed).resolve() == path.resolve():
            return frame.index
        if rig_dir is None and Path(listed).name == path.name:
            return frame.index
    digits = re.findall(r"\d+", path.stem)
    indices = {frame.index for frame in rig.frames}
    if digits and int(digits[-1]) in indices:
        return int(digits[-1])
    raise CamcalError(f"{path}: camera {camera_name!r}'s lens changes over the rig's frames and this image is not "
                      "one of a frame's images, nor numbered like one (plate.1001.exr)")


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
    if rig.lens_frames(camera_name):
        raise CamcalError(f"camera {camera_name!r}'s lens changes over the rig's frames, which a video's frames do not "
                          "name: undistort the plate as numbered images (plate.1001.exr ...)")
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
