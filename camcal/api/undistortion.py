"""``camcal.undistort``: undistorted images (or video frames) of a rig camera and its pinhole rig, as ``undistort``."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.geometry.uncertainty import SigmaSummary
    from camcal.model.rig import Camera, Rig

__all__ = ["Undistortion", "undistort"]


@dataclass(frozen=True)
class Undistortion:
    """What :func:`undistort` wrote.

    Attributes
    ----------
    rig : Rig
        The rig written (``out/undistorted.rig.json``): the camera replaced by its undistorted pinhole camera.
    camera : Camera
        That camera (distortion none, the new K and image size).
    mode : str
    out : str
        The folder written, as given.
    rig_path : Path
    images : tuple of Path
        The undistorted images (of videos: ``clip_00000k.png`` per frame), in order.
    from_video : bool
    sigma : SigmaSummary or None
        With ``sigma=True``: the projection sigma's summary; ``sigma_path`` its EXR.
    sigma_path : Path or None
    """

    rig: Rig
    camera: Camera
    mode: str
    out: str
    rig_path: Path
    images: tuple[Path, ...]
    from_video: bool = False
    sigma: SigmaSummary | None = None
    sigma_path: Path | None = None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the undistorted rig to another file too (atomically); its path."""
        return self.rig.save(path)

    def lines(self) -> list[str]:
        """What ``undistort`` prints: the new camera and the files."""
        width, height = self.camera.image_size
        K = self.camera.K
        what = "frame" if self.from_video else "image"
        lines = [f"undistorted {len(self.images)} {what}(s) of {self.camera.name!r} ({self.mode}): {width}x{height} "
                 f"px, fx {K[0, 0]:.3f} fy {K[1, 1]:.3f} principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f})",
                 f"wrote {self.rig_path} and {len(self.images)} image(s) in {self.out}"]
        if self.sigma is not None:
            lines.append(self.sigma.describe())
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``undistort --json``."""
        figures = dict(camera=self.camera.name, mode=self.mode, image_size=list(self.camera.image_size),
                       K=self.camera.K)
        if self.sigma is not None:
            figures["sigma"] = self.sigma.to_dict()
        return figures


def undistort(
    rig: str | os.PathLike | Rig,
    camera: str,
    images: str | os.PathLike | Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    every: int = 1,
    mode: str = "crop",
    overscan: float = 1.1,
    max_fov_deg: float | None = None,
    sigma: bool = False,
    distance: float | None = None,
) -> Undistortion:
    """Undistort images or videos of one rig camera with one remap each (``camcal undistort``).

    Writes each image under its own name (frame ``k`` of ``clip.mp4`` as
    ``clip_00000k.png``) and ``out/undistorted.rig.json`` with the new K and
    distortion none, in a folder built under a temporary name and renamed at
    the end (:mod:`camcal.pipelines.undistort`).
    A camera whose lens changes over the rig's frames (a zoom) undistorts
    each image with its frame's lens: the frame whose ``images`` names it,
    else the frame number in its name (``plate.1001.exr``;
    :func:`camcal.pipelines.undistort.image_frame`).

    Parameters
    ----------
    rig : path or Rig
    camera : str
        The rig camera the images are of.
    images : path, glob or sequence of paths
        Image files, or videos (``.mp4 .mov .avi .mkv``, streamed); not both. One string is a glob.
    out : path
        The folder to write.
    every : int
        Videos: frames 0, N, 2N...
    mode : {"crop", "keep", "overscan"}
        crop: no black borders; keep: every source pixel kept (bigger canvas); overscan: a canvas ``overscan``
        times the plate.
    overscan : float
        Canvas factor of ``mode="overscan"``.
    max_fov_deg : float, optional
        crop / keep: widest full angle about the axis the pinhole output holds (default: 120 for a
        kannala-brandt fisheye, no cap for the other lenses).
    sigma : bool
        Also write ``out/sigma.exr``: the projection sigma (plate pixels) of the plate pixel each output pixel
        samples.
    distance : float, optional
        With ``sigma``: distance along the rays in the rig's units (default: infinity).

    Returns
    -------
    Undistortion

    Raises
    ------
    CamcalError
        No such camera, images of another size, images and videos mixed, ``every < 1``, a per-frame lens and an
        image of no frame (nothing written).
    """
    from camcal.io.video import is_video
    from camcal.model.rig import Rig
    from camcal.pipelines.undistort import undistort_images, undistort_videos, write_undistorted_sigma

    if every < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    from camcal.base.globs import file_or_glob

    entries = [images] if isinstance(images, (str, os.PathLike)) else images
    images = [path for entry in entries for path in file_or_glob("--images", entry)]
    videos = [path for path in images if is_video(path)]
    if videos and len(videos) != len(images):
        raise CamcalError("give images or videos, not both (undistort them in two runs)")
    rig_dir = None if isinstance(rig, Rig) else Path(rig).parent
    rig = rig if isinstance(rig, Rig) else Rig.load(rig)
    if sigma and rig.lens_frames(camera):
        raise CamcalError(f"camera {camera!r}'s lens changes over the rig's frames: the projection sigma is of one "
                          "lens (undistort without sigma)")
    if videos:
        rig_path, written = undistort_videos(rig, camera, videos, out, every, mode, overscan, max_fov_deg)
    else:
        rig_path, written = undistort_images(rig, camera, images, out, mode, overscan, max_fov_deg, rig_dir)
    undistorted = Rig.load(rig_path)
    summary, sigma_path = None, None
    if sigma:
        sigma_path, summary = write_undistorted_sigma(rig, camera, out, mode, overscan, max_fov_deg, distance)
    return Undistortion(undistorted, undistorted.camera(camera), mode, os.fspath(out), rig_path, tuple(written),
                        bool(videos), summary, sigma_path)

