"""Image undistortion: choose the new camera, build the map once, one ``cv2.remap`` per image.

The undistorted image is that of a pinhole camera ``K_new`` (no distortion)
with the source camera's pose. Three ways to choose ``K_new``:

``crop``
    Same image size; focal lengths scaled up about the principal point
    until every output pixel samples inside the source frame (no black
    borders, some source pixels lost at the edges), and, with a
    field-of-view cap (``max_fov_deg``, as for ``keep``), until the output
    frame sees no ray beyond half that angle from the axis.
``keep``
    Same focal lengths; the canvas grows (overscan) until every source
    pixel lands inside it (nothing lost, black corners). A pinhole image
    cannot hold rays at 90 degrees from the axis, so the field of view kept
    is capped at ``max_fov_deg`` (full angle; by default 120 degrees for a
    Kannala-Brandt fisheye, no cap for the other models): source pixels
    beyond it are left out. (A pinhole view of a fisheye stretches its
    edges by ``1 / cos^2`` of the angle: 4x at 60 degrees.)
``overscan``
    Same focal lengths; the canvas is ``overscan`` times the source size,
    centred (the convention of ST-maps for comp packages).

Pixel (0, 0) is the centre of the top-left pixel in every image. The
source pixel of each output pixel is ``distort(K K_new^-1 x_o)``
(:func:`camcal.geometry.remap.build_maps`), float32 maps, bilinear.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.remap import RemapMaps, build_maps, undistort_homography
from camcal.model.rig import Camera, Lens, Rectification, Rig

__all__ = ["MODES", "FISHEYE_FOV_DEG", "UndistortedView", "Undistorter", "undistorted_view", "make_undistorter",
           "undistorted_rig"]

#: How K_new is chosen (see the module docstring).
MODES = ("crop", "keep", "overscan")
#: Full field of view ``crop`` and ``keep`` hold of a Kannala-Brandt lens unless told otherwise, degrees.
FISHEYE_FOV_DEG = 120.0

_BORDER_SAMPLES = 512


@dataclass(frozen=True)
class UndistortedView:
    """The undistorted pinhole camera an undistortion produces.

    Attributes
    ----------
    K_new : ndarray, shape (3, 3)
        Intrinsics of the undistorted image.
    image_size : (int, int)
        (width, height) of the undistorted image.
    """

    K_new: NDArray[np.float64]
    image_size: tuple[int, int]


def _border(image_size: tuple[int, int], n: int = _BORDER_SAMPLES) -> NDArray[np.float64]:
    """Points along the outer edge of the frame (pixel edges, not centres)."""
    width, height = image_size
    x = np.linspace(-0.5, width - 0.5, n)
    y = np.linspace(-0.5, height - 0.5, n)
    return np.concatenate([
        np.stack([x, np.full(n, -0.5)], 1), np.stack([x, np.full(n, height - 0.5)], 1),
        np.stack([np.full(n, -0.5), y], 1), np.stack([np.full(n, width - 0.5), y], 1),
    ])


def undistorted_view(
    camera: Camera, mode: str = "crop", overscan: float = 1.1, max_fov_deg: float | None = None
) -> UndistortedView:
    """Choose ``K_new`` and the output size for undistorting ``camera``'s images.

    Parameters
    ----------
    camera : Camera
        Source camera (K, distortion, image size).
    mode : {"crop", "keep", "overscan"}
        See the module docstring.
    overscan : float
        Canvas factor for ``mode="overscan"`` (>= 1).
    max_fov_deg : float, optional
        ``crop`` and ``keep``: the widest full angle about the optical axis
        the output holds, in (0, 180) degrees; ``None``:
        :data:`FISHEYE_FOV_DEG` for a Kannala-Brandt lens, no cap otherwise.

    Returns
    -------
    UndistortedView

    Notes
    -----
    ``crop``: ``K_new = S K`` with ``S`` scaling by ``s`` about the principal
    point; ``s`` is the smallest scale (bisection, to 1e-6) for which the
    output frame's border, mapped by ``distort(K K_new^-1 x)``, stays inside
    the source frame. ``keep``: the source border undistorted by the model
    bounds the canvas; ``K_new = K`` shifted by the canvas origin. With a
    field-of-view cap, each border pixel's ray
    (:meth:`~camcal.model.distortion.Distortion.rays_from_pixels`) is
    turned towards the axis to at most ``max_fov_deg / 2`` before its
    pinhole pixel is taken.
    """
    if mode not in MODES:
        raise CamcalError(f"unknown undistortion mode {mode!r}, expected one of: {', '.join(MODES)}")
    if max_fov_deg is not None and not (0.0 < max_fov_deg < 180.0):
        raise CamcalError(f"the field-of-view cap (max_fov_deg, --max-fov) must be between 0 and 180 degrees, got {max_fov_deg}")
    width, height = camera.image_size
    K = camera.K
    if mode == "overscan":
        if not math.isfinite(overscan) or overscan < 1.0:
            raise CamcalError(f"overscan must be a number >= 1, got {overscan}")
        new_width, new_height = int(round(width * overscan)), int(round(height * overscan))
        K_new = K.copy()
        K_new[0, 2] += (new_width - width) / 2.0
        K_new[1, 2] += (new_height - height) / 2.0
        return UndistortedView(K_new, (new_width, new_height))
    if max_fov_deg is None and camera.distortion.is_fisheye:
        max_fov_deg = FISHEYE_FOV_DEG
    if mode == "keep":
        if max_fov_deg is None:
            ideal = camera.distortion.undistort(_border(camera.image_size), K)
        else:
            rays = camera.distortion.rays_from_pixels(_border(camera.image_size), K)
            theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0))
            rho = np.hypot(rays[:, 0], rays[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                direction = np.where(rho[:, None] > 0.0, rays[:, :2] / rho[:, None], 0.0)
            ideal = direction * np.tan(np.minimum(theta, np.radians(0.5 * max_fov_deg)))[:, None] @ K[:2, :2].T + K[:2, 2]
        if not np.all(np.isfinite(ideal)):
            raise CamcalError("the distortion model does not map the whole frame to finite points")
        low = np.floor(ideal.min(axis=0) + 0.5)
        high = np.ceil(ideal.max(axis=0) - 0.5)
        K_new = K.copy()
        K_new[:2, 2] -= low
        return UndistortedView(K_new, (int(high[0] - low[0]) + 1, int(high[1] - low[1]) + 1))
    # crop
    output_border = _border(camera.image_size)
    centre = K[:2, 2]

    def inside(scale: float) -> bool:
        ideal = centre + (output_border - centre) / scale
        source = camera.distortion.distort(ideal, K)
        return bool(np.all(np.isfinite(source)) and np.all(source >= -0.5 - 1e-9)
                    and np.all(source <= np.array([width, height]) - 0.5 + 1e-9))

    low, high = 1e-3, 1.0
    while not inside(high):
        high *= 2.0
        if high > 1e3:
            raise CamcalError("no crop of the undistorted image lies inside the source frame")
    if inside(low):
        high = low
    while high - low > 1e-6 * high:
        middle = 0.5 * (low + high)
        if inside(middle):
            high = middle
        else:
            low = middle
    if max_fov_deg is not None:
        # the output border's farthest normalised radius at scale 1, over tan(half angle)
        offsets = np.linalg.solve(K[:2, :2], (output_border - centre).T)
        high = max(high, float(np.hypot(*offsets).max()) / math.tan(math.radians(0.5 * max_fov_deg)))
    K_new = K.copy()
    K_new[0, :2] *= high
    K_new[1, 1] *= high
    return UndistortedView(K_new, camera.image_size)


@dataclass(frozen=True)
class Undistorter:
    """Undistortion of one camera's images: the map is built once, reused per image.

    Attributes
    ----------
    camera : Camera
        The source camera.
    view : UndistortedView
        The undistorted camera ``K_new`` and its image size.
    maps : RemapMaps
        float32 source-pixel maps of :func:`camcal.geometry.remap.build_maps`.
    """

    camera: Camera
    view: UndistortedView
    maps: RemapMaps

    def apply(self, image: NDArray, interpolation: int = cv2.INTER_LINEAR) -> NDArray:
        """Undistort one image (any depth, 1 to 4 channels) by ONE ``cv2.remap``."""
        width, height = self.camera.image_size
        if image.shape[:2] != (height, width):
            raise CamcalError(
                f"image is {image.shape[1]}x{image.shape[0]} px but camera {self.camera.name!r} is {width}x{height}"
            )
        return self.maps.apply(image, interpolation)

    def undistorted_camera(self) -> Camera:
        """The undistorted camera: ``K_new``, no distortion, same pose.

        A rectification carries over as ``H' = H K K_new^-1`` (it maps the
        new camera's pixels, which are undistorted already).
        """
        rect = self.camera.rectification
        if rect is not None:
            rect = Rectification(rect.H @ self.camera.K @ np.linalg.inv(self.view.K_new), rect.K_rect, rect.image_size)
        return dataclasses.replace(
            self.camera, K=self.view.K_new, image_size=self.view.image_size,
            distortion=Distortion.none(), rectification=rect,
        )


def make_undistorter(
    camera: Camera, mode: str = "crop", overscan: float = 1.1, max_fov_deg: float | None = None
) -> Undistorter:
    """Choose ``K_new`` (:func:`undistorted_view`) and build the remap maps once."""
    view = undistorted_view(camera, mode, overscan, max_fov_deg)
    maps = build_maps(camera, undistort_homography(camera, view.K_new), view.image_size)
    return Undistorter(camera, view, maps)


def undistorted_rig(rig: Rig, camera_name: str, view: Callable[[Camera], UndistortedView],
                    provenance: Mapping[str, Any]) -> Rig:
    """The rig with camera ``camera_name`` undistorted: its own lens and, frame by frame, each per-frame lens.

    Parameters
    ----------
    rig : Rig
    camera_name : str
    view : callable
        The undistorted view of a camera (e.g. :func:`undistorted_view`
        with the run's mode), applied to the camera and to the camera with
        each frame's lens (:meth:`camcal.model.rig.Rig.camera_at_frame`).
    provenance : mapping
        The new rig's provenance.

    Returns
    -------
    Rig
        The camera replaced by :meth:`Undistorter.undistorted_camera` of its
        view; each frame with a lens of it gets that lens's undistorted
        ``K_new`` (distortion none, the lens state kept).

    Raises
    ------
    CamcalError
        A frame's view has another image size than the camera's (``keep``
        sizes the canvas by the lens): one rig camera has one image size.
    """
    camera = rig.camera(camera_name)
    base_view = view(camera)
    lenses = {}
    for frame in rig.frames:
        state = frame.lenses.get(camera_name)
        if state is None:
            continue
        frame_view = view(rig.camera_at_frame(camera_name, frame.index))
        if frame_view.image_size != base_view.image_size:
            size, base = frame_view.image_size, base_view.image_size
            raise CamcalError(f"frame {frame.index}'s lens undistorts to {size[0]}x{size[1]} px, camera "
                              f"{camera_name!r}'s own to {base[0]}x{base[1]}: a per-frame lens needs a fixed "
                              "output size (use the crop or overscan mode)")
        lenses[frame.index] = Lens(frame_view.K_new, Distortion.none(), state.focal_mm, state.focus_m)
    base = Undistorter(camera, base_view, maps=None).undistorted_camera()
    return rig.with_camera(base, lenses, provenance=provenance)
