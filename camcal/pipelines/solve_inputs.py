"""The images of a solve: folders, globs, plates and videos per camera, staged in COLMAP's rig layout.

Each camera's images (a folder, a glob, a plate ``left.%04d.exr`` or one
video) are linked, or decoded one at a time, under ``images/<camera>/<k>.<suffix>``
so that the k-th frames of every camera pair up; mattes become COLMAP's
feature masks beside them.
"""

from __future__ import annotations

import os
import re
import shutil
from collections import Counter
from pathlib import Path

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import frame_runs
from camcal.io.frames import imwrite
from camcal.io.headers import declared_size
from camcal.io.sequence import (
    camera_of, feature_image, feature_mask, is_sequence_pattern, read_image, sequence_paths,
)
from camcal.io.video import is_video, iter_frames

__all__ = [
    "DECODED_SUFFIXES",
    "IMAGE_SUFFIXES",
    "check_one_size_per_camera",
    "collect_images",
    "list_images",
    "plate_frame_number",
    "stage_images",
    "stage_masks",
    "unregistered_line",
    "video_of",
]

#: Suffixes COLMAP reads itself (linked into the work folder) and those of plates it does not (EXR, DPX,
#: Cineon: read with OpenImageIO and staged as 8-bit PNG, :func:`camcal.io.sequence.feature_image`).
DECODED_SUFFIXES = (".exr", ".dpx", ".cin")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp") + DECODED_SUFFIXES


def list_images(folder: Path, pattern: str = "*") -> list[Path]:
    """The images of ``folder`` matching ``pattern``, sorted by name; none is an error naming the folder."""
    if not folder.is_dir():
        raise CamcalError(f"image folder not found: {folder}")
    images = sorted(p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise CamcalError(f"no images ({', '.join(IMAGE_SUFFIXES)}) matching {pattern!r} in {folder}")
    return images


def collect_images(folders: list[Path], camera_globs: dict[str, str] | None = None,
                   frames: str | None = None) -> dict[str, list[Path]]:
    """Images per camera: one folder per camera (named after it), or globs in one folder, or plates.

    Parameters
    ----------
    folders : list of Path
        Image folders. Without ``camera_globs`` each is one camera; a single
        folder holding only sub-folders of images is a rig, one camera per
        sub-folder. An entry (or a glob) with a frame placeholder
        (``plates/left.%04d.exr``, ``left.####.dpx``) is a plate: the
        frames of ``frames`` (or all on disk), every one checked to exist
        (:func:`camcal.io.sequence.sequence_paths`); its camera is named by
        the file name before the placeholder.
    camera_globs : dict of str to str, optional
        Camera name -> glob relative to the (single) folder, e.g.
        ``{"left": "*_L.png", "right": "*_R.png"}``; frames pair up by sorted order.
    frames : str, optional
        The frame range of plates (``1001-1100``, ``1001-1100x2``).
    """
    folders = [Path(folder) for folder in folders]
    if camera_globs:
        if len(folders) != 1:
            raise CamcalError("--camera NAME=GLOB selects images inside one folder: give exactly one")
        return {name: sequence_paths(folders[0] / pattern, frames) if is_sequence_pattern(pattern)
                else list_images(folders[0], pattern) for name, pattern in camera_globs.items()}
    if any(is_sequence_pattern(folder) for folder in folders):
        if not all(is_sequence_pattern(folder) for folder in folders):
            raise CamcalError("give plates (a frame placeholder like %04d or ####) or image folders, not both")
        plates = {camera_of(folder): sequence_paths(folder, frames) for folder in folders}
        if len(plates) != len(folders):
            raise CamcalError("plates must have distinct names before their frame numbers (they name the cameras)")
        return plates
    if len(folders) == 1 and folders[0].is_dir():
        subfolders = sorted(p for p in folders[0].iterdir() if p.is_dir())
        if subfolders and not any(p.suffix.lower() in IMAGE_SUFFIXES for p in folders[0].iterdir() if p.is_file()):
            folders = subfolders
    names = [folder.name for folder in folders]
    if len(set(names)) != len(names):
        raise CamcalError("image folders must have distinct names (they name the cameras)")
    return {folder.name: list_images(folder) for folder in folders}


def video_of(paths: list[Path]) -> Path | None:
    """The video a camera's images are (one video file), else None; a video among images is refused."""
    videos = [path for path in paths if is_video(path)]
    if videos and len(paths) > 1:
        raise CamcalError(f"give a camera one video or images, not both ({videos[0].name} among {len(paths)} files)")
    return videos[0] if videos else None


def stage_images(images: dict[str, list[Path]], staging: Path, every: int = 1) -> dict[str, Path]:
    """Link each camera's images under ``staging/<camera>/`` (COLMAP's rig layout).

    Frames pair up by position in each camera's sorted list: the k-th image
    of every camera is linked under the same name ``<k>.<suffix>``. A
    camera given as one video has its every ``every``-th frame decoded
    (streamed, :func:`camcal.io.video.iter_frames`) and written there as
    ``<k>.png`` instead: the k-th kept frame of every video pairs up. A
    plate frame COLMAP cannot read (:data:`DECODED_SUFFIXES`) is decoded
    and staged as ``<k>.png`` the same way, one at a time.

    Returns
    -------
    dict
        Staged name (``camera/<k>.<suffix>``, COLMAP's image name) -> the user's image (a video's frame: the
        staged file).
    """
    if staging.exists():
        shutil.rmtree(staging)
    staged: dict[str, Path] = {}
    for camera, paths in images.items():
        (staging / camera).mkdir(parents=True)
        video = video_of(paths)
        if video is not None:
            for index, (_, image) in enumerate(iter_frames(video, every=every, gray=False)):
                name = f"{index:06d}.png"
                staged[f"{camera}/{name}"] = imwrite(staging / camera / name, image)
            continue
        for index, path in enumerate(paths):
            if path.suffix.lower() in DECODED_SUFFIXES:  # one frame decoded at a time
                name = f"{index:06d}.png"
                imwrite(staging / camera / name, feature_image(read_image(path), bgr=True))
            else:
                name = f"{index:06d}{path.suffix.lower()}"
                os.symlink(path.resolve(), staging / camera / name)
            staged[f"{camera}/{name}"] = path
    return staged


def check_one_size_per_camera(staged: dict[str, Path], image_dir: Path) -> dict[str, tuple[int, int]]:
    """Each camera's one image size; a camera whose staged images differ in size (a plate with a frame of another
    size) is refused, naming both files.

    COLMAP gives each camera one size (its folder, ``CameraMode.PER_FOLDER``)
    and skips an image of another size, which would leave the camera short
    of frames or unregistered with no word why. Sizes are read from the
    staged files' headers (:func:`camcal.io.headers.declared_size`).
    """
    first: dict[str, tuple[str, tuple[int, int]]] = {}
    for name in staged:
        size = declared_size(image_dir / name)
        if size is None:
            continue
        camera = name.split("/")[0]
        first_name, first_size = first.setdefault(camera, (name, size))
        if size != first_size:
            raise CamcalError(f"camera {camera!r}: {staged[name]} is {size[0]}x{size[1]} but "
                              f"{staged[first_name]} is {first_size[0]}x{first_size[1]}: a camera's images must all "
                              "have one size")
    return {camera: size for camera, (_, size) in first.items()}


def stage_masks(masks: dict[str, list[Path]], staged: dict[str, Path], image_dir: Path, mask_dir: Path) -> Path:
    """Each matte as COLMAP's mask of its image, ``mask_dir/<camera>/<k>.<suffix>.png``; one matte read at a time."""
    for camera, mattes in masks.items():
        names = [name for name in staged if name.split("/")[0] == camera]
        if not names:
            raise CamcalError(f"masks given for {camera!r}, which is not a camera of this solve")
        if len(mattes) != len(names):
            raise CamcalError(f"camera {camera!r} has {len(names)} images but {len(mattes)} mattes")
        (mask_dir / camera).mkdir(parents=True)
        for name, matte in zip(names, mattes):
            mask = feature_mask(read_image(matte))
            size = declared_size(image_dir / name)
            if size is not None and size != (mask.shape[1], mask.shape[0]):
                raise CamcalError(f"matte {matte} is {mask.shape[1]}x{mask.shape[0]} px but its image "
                                  f"{staged[name]} is {size[0]}x{size[1]}")
            imwrite(mask_dir / f"{name}.png", mask)
    return mask_dir


def plate_frame_number(path: Path) -> int | None:
    """A plate frame's number: the last number in its file's name (``plate.1001.exr``: 1001), None without one."""
    digits = re.findall(r"\d+", Path(path).stem)
    return int(digits[-1]) if digits else None


def unregistered_line(names: list[str], staged: dict[str, Path]) -> str:
    """One line naming, per camera, the frames (by number: the last number in each file's name) not registered."""
    if not names:
        return ""
    per_camera: dict[str, list] = {}
    for name in names:
        number = plate_frame_number(staged[name])
        per_camera.setdefault(name.split("/")[0], []).append(staged[name].name if number is None else number)
    totals = Counter(name.split("/")[0] for name in staged)
    parts = []
    for camera, frames in per_camera.items():
        numbers = sorted(f for f in frames if isinstance(f, int))
        listed = frame_runs(numbers) + sorted(f for f in frames if not isinstance(f, int))
        parts.append(f"{camera} frames {', '.join(listed)} ({len(frames)} of {totals[camera]})")
    return "not registered: " + "; ".join(parts)
