"""The steps every rectification method shares: cameras and options checked, the line of centres, the
common rotation, the field-of-view cap and the rectified image frame fitted around the views.

``H_i = A F_i`` with ``F_i`` a method's map of camera i's undistorted pixels
onto the common plane and ``A`` the affine frame fitted here
(:func:`finish_rectification`): from the largest rectangle every view sees
(``alpha = 0``) to the bounding box of every view (``alpha = 1``). Fisheye
rays beyond 90 degrees cannot be held by a pinhole rectified image, so the
frame is fitted inside a field-of-view cap (:func:`fov_half_angle`).

References
----------
Fusiello, A., Trucco, E. & Verri, A. (2000). A compact algorithm for
rectification of stereo pairs. Machine Vision and Applications 12(1).
Markley, F. L., Cheng, Y., Crassidis, J. L. & Oshman, Y. (2007). Averaging
quaternions. Journal of Guidance, Control, and Dynamics 30(4), 1193-1197.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.rectify.model import (
    MAX_SIZE_FACTOR,
    CentresOffLineWarning,
    Matches,
    RectificationResult,
    dehomogenise,
    image_deformation,
    in_front,
    pixel_rays,
    vertical_disparity,
)
from camcal.geometry.undistort import FISHEYE_FOV_DEG
from camcal.model.distortion import capped_rays
from camcal.model.rig import Camera, Rectification, Rig, make_provenance

__all__ = [
    "calibrated_start",
    "cameras_to_rectify",
    "check_alpha",
    "finish_rectification",
    "fov_half_angle",
    "mean_focal",
]

_BORDER_SAMPLES = 33


def _border(size: tuple[int, int], n: int = _BORDER_SAMPLES) -> dict[str, NDArray[np.float64]]:
    """Pixels along the four edges of an image (pixel centres 0..W-1, 0..H-1)."""
    width, height = size
    xs = np.linspace(0.0, width - 1.0, n)
    ys = np.linspace(0.0, height - 1.0, n)
    return {
        "left": np.column_stack([np.zeros(n), ys]),
        "right": np.column_stack([np.full(n, width - 1.0), ys]),
        "top": np.column_stack([xs, np.zeros(n)]),
        "bottom": np.column_stack([xs, np.full(n, height - 1.0)]),
    }


def _border_rays(camera: Camera, pixels: NDArray[np.float64], half_angle: float | None) -> NDArray[np.float64]:
    """Rays of border pixels; a pixel beyond a fisheye model's range (the black corners of a circular
    fisheye) takes the ray at :attr:`~camcal.model.distortion.Distortion.max_angle_rad` in its
    azimuth, which a cap narrower than that range turns in anyway."""
    rays = pixel_rays(camera, pixels)
    lost = ~np.all(np.isfinite(rays), axis=1)
    if not lost.any():
        return rays
    reach = camera.distortion.max_angle_rad
    if half_angle is None or not camera.distortion.is_fisheye or half_angle >= reach:
        raise CamcalError(f"camera {camera.name!r}: its {camera.distortion.model} lens model maps part of the "
                          "frame's border to no ray (beyond the model's range); cap the field of view below "
                          f"{math.degrees(2 * reach):.0f} degrees")
    offsets = np.linalg.solve(camera.K, np.column_stack([pixels[lost], np.ones(lost.sum())]).T).T[:, :2]
    azimuth = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    rays[lost] = np.column_stack([math.sin(reach) * azimuth, np.full(lost.sum(), math.cos(reach))])
    return rays


def fov_half_angle(cameras: Sequence[Camera], max_fov_deg: float | None) -> float | None:
    """Half the field-of-view cap in radians: ``max_fov_deg``, or FISHEYE_FOV_DEG with a fisheye, or none."""
    if max_fov_deg is None:
        if not any(camera.distortion.is_fisheye for camera in cameras):
            return None
        max_fov_deg = FISHEYE_FOV_DEG
    if isinstance(max_fov_deg, bool) or not isinstance(max_fov_deg, (int, float)) or not 0.0 < max_fov_deg < 180.0:
        raise CamcalError(f"the field-of-view cap (max_fov_deg, --max-fov) must be between 0 and 180 degrees, "
                          f"got {max_fov_deg!r}")
    return math.radians(0.5 * max_fov_deg)


def cameras_to_rectify(rig: Rig, names: Sequence[str] | None) -> list[Camera]:
    names = [camera.name for camera in rig.cameras] if names is None else list(names)
    if len(names) < 2:
        raise CamcalError(f"rectification needs at least 2 cameras, got {len(names)}")
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names to rectify repeat: {', '.join(names)}")
    return [rig.camera(name) for name in names]


def check_alpha(alpha: float) -> float:
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0.0 <= alpha <= 1.0:
        raise CamcalError(f"alpha must be a number in [0, 1], got {alpha!r}")
    return float(alpha)


def _fit_frame(
    cameras: Sequence[Camera], frames: Sequence[NDArray[np.float64]], alpha: float, scale: float,
    axes: Sequence[NDArray[np.float64]], half_angle: float | None,
) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """The affine ``A = [[s, 0, -s x0], [0, s, -s y0], [0, 0, 1]]`` and image size.

    ``frames[i]`` maps undistorted pixels of camera i to a common plane. The
    rectangle kept on that plane runs from the largest rectangle seen by
    every camera (``alpha = 0``: no invalid pixel) to the bounding box of
    all the cameras' images (``alpha = 1``: no source pixel lost), linearly.
    With a field-of-view cap, each border pixel's ray is first turned
    towards ``axes[i]`` (the viewing direction, in camera i's frame) to at
    most ``half_angle``: the frame then holds no ray beyond it.
    """
    inner = [-np.inf, np.inf, -np.inf, np.inf]  # x_lo, x_hi, y_lo, y_hi
    outer = [np.inf, -np.inf, np.inf, -np.inf]
    for camera, frame, axis in zip(cameras, frames, axes):
        sides = {}
        for side, pixels in _border(camera.image_size).items():
            rays = _border_rays(camera, pixels, half_angle)
            mapped = capped_rays(rays, axis, half_angle) @ camera.K.T @ frame.T
            if not np.all(in_front(mapped)):
                raise CamcalError(
                    f"camera {camera.name!r} sees beyond the rectified image plane "
                    "(its field of view reaches 90 degrees from the common viewing direction; "
                    "cap it with max_fov_deg / --max-fov)"
                )
            sides[side] = dehomogenise(mapped)
        inner = [
            max(inner[0], sides["left"][:, 0].max()),
            min(inner[1], sides["right"][:, 0].min()),
            max(inner[2], sides["top"][:, 1].max()),
            min(inner[3], sides["bottom"][:, 1].min()),
        ]
        everything = np.vstack(list(sides.values()))
        outer = [
            min(outer[0], everything[:, 0].min()),
            max(outer[1], everything[:, 0].max()),
            min(outer[2], everything[:, 1].min()),
            max(outer[3], everything[:, 1].max()),
        ]
    if alpha < 1.0 and (inner[0] >= inner[1] or inner[2] >= inner[3]):
        raise CamcalError("the rectified views share no common area (use alpha = 1 to keep every image)")
    if alpha == 1.0 or inner[0] >= inner[1] or inner[2] >= inner[3]:
        rect = np.array(outer)
    else:
        rect = (1.0 - alpha) * np.array(inner) + alpha * np.array(outer)
    limit = MAX_SIZE_FACTOR * max(max(camera.image_size) for camera in cameras) / scale
    for lo, hi in ((0, 1), (2, 3)):
        if rect[hi] - rect[lo] > limit:
            middle = 0.5 * (rect[lo] + rect[hi])
            rect[lo], rect[hi] = middle - 0.5 * limit, middle + 0.5 * limit
    width = int(math.floor((rect[1] - rect[0]) * scale)) + 1
    height = int(math.floor((rect[3] - rect[2]) * scale)) + 1
    A = np.array([[scale, 0.0, -scale * rect[0]], [0.0, scale, -scale * rect[2]], [0.0, 0.0, 1.0]])
    return A, (width, height)


def _line_of_centres(
    cameras: Sequence[Camera],
) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """Direction of the least-squares line of centres, baseline, distances to it."""
    centres = np.array([camera.c for camera in cameras])
    mean = centres.mean(axis=0)
    offsets = centres - mean
    _, _, vt = np.linalg.svd(offsets)
    direction = vt[0]
    along = offsets @ direction
    baseline = float(along.max() - along.min())
    scale = max(1.0, float(np.abs(centres).max()))
    if baseline <= 1e-9 * scale:
        raise CamcalError("the camera centres coincide (baseline 0): rectification needs a baseline")
    distances = np.linalg.norm(offsets - along[:, None] * direction[None, :], axis=1)
    return direction, baseline, distances


def _check_epipole_outside(camera: Camera, direction: NDArray[np.float64], half_angle: float | None) -> None:
    """Refuse when the line of centres points into the camera's image (within the field-of-view cap)."""
    for sign in (1.0, -1.0):
        ray = camera.R @ (sign * direction)
        reach = min(half_angle if half_angle is not None else np.pi, camera.distortion.max_angle_rad)
        if not math.acos(np.clip(ray[2], -1.0, 1.0)) < reach:
            continue
        if camera.distortion.is_fisheye:
            u, v = camera.distortion.project_rays(ray[None, :], camera.K)[0]
        else:
            u, v = (camera.K @ ray)[:2] / (camera.K @ ray)[2]
        width, height = camera.image_size
        if -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5:
            raise CamcalError(
                f"the line of centres points into camera {camera.name!r}'s view (epipole at "
                f"({u:.1f}, {v:.1f}) px inside the image): planar rectification is impossible"
            )


def _common_rotation(cameras: Sequence[Camera], direction: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation with x along the line of centres closest to the cameras' mean rotation.

    ``M`` is the chordal L2 mean of the cameras' rotations (Markley et al.
    2007; for two cameras the geodesic midpoint, ``cv2.stereoRectify``'s
    half rotation ``R^(1/2)``). The line direction ``d``, oriented so that
    seen from ``M`` it points right (``t = M d``, ``t_x > 0``), is turned
    onto the x axis by the smallest rotation ``W`` (about ``t x e_x`` by
    ``angle(t, e_x)``): ``R_rect = W M``. Any rotation taking ``t`` to ``e_x`` turns by at least
    that angle, so ``R_rect`` is the rectifying rotation nearest ``M``; for
    two cameras it is the one ``cv2.stereoRectify`` chooses for a horizontal
    pair.
    """
    mean = Rotation.from_matrix(np.array([camera.R for camera in cameras])).mean().as_matrix()
    d = direction / np.linalg.norm(direction)
    if (mean @ d)[0] < 0:
        d = -d
    t = mean @ d
    z = mean[2] - (mean[2] @ d) * d
    if np.linalg.norm(z) < 1e-6:
        raise CamcalError("the cameras look along their line of centres: planar rectification is impossible")
    axis = np.cross(t, [1.0, 0.0, 0.0])
    sine = float(np.linalg.norm(axis))
    if sine == 0.0:
        return mean
    turn = Rotation.from_rotvec(axis / sine * math.atan2(sine, t[0])).as_matrix()
    return turn @ mean


def mean_focal(cameras: Sequence[Camera]) -> float:
    return float(np.mean([math.sqrt(camera.K[0, 0] * camera.K[1, 1]) for camera in cameras]))


def _rectified_rig(
    rig: Rig, cameras: Sequence[Camera], homographies: Sequence[NDArray[np.float64]],
    K_rect: NDArray[np.float64], size: tuple[int, int], method: str,
) -> Rig:
    rectified = {
        camera.name: dataclasses.replace(camera, rectification=Rectification(H, K_rect, size))
        for camera, H in zip(cameras, homographies)
    }
    provenance = dict(rig.provenance)
    provenance["rectification"] = make_provenance(method)
    return dataclasses.replace(
        rig, cameras=tuple(rectified.get(camera.name, camera) for camera in rig.cameras), provenance=provenance
    )


def finish_rectification(
    rig: Rig, cameras: Sequence[Camera], frames: Sequence[NDArray[np.float64]], alpha: float,
    method: str, R_rect: NDArray[np.float64] | None, line_offset_ratio: float,
    matches: Matches | None, half_angle: float | None, n_inliers: int | None = None,
) -> RectificationResult:
    """Fit the image frame, store the rectification, measure it."""
    focal = mean_focal(cameras)
    if R_rect is None:  # Hartley: the common plane is already in pixels; cap about each camera's own axis
        A, size = _fit_frame(cameras, frames, alpha, 1.0, [np.array([0.0, 0.0, 1.0])] * len(cameras), half_angle)
        K_rect = np.array([[focal, 0.0, A[0, 2]], [0.0, focal, A[1, 2]], [0.0, 0.0, 1.0]])
    else:  # cap about the rectified viewing direction, seen from each camera: K^-1 frame^-1 e_z
        axes = [np.linalg.solve(camera.K, np.linalg.solve(frame, [0.0, 0.0, 1.0])) for camera, frame in zip(cameras, frames)]
        A, size = _fit_frame(cameras, frames, alpha, focal, [axis / np.linalg.norm(axis) for axis in axes], half_angle)
        K_rect = A
    homographies = [A @ frame for frame in frames]
    homographies = [H / np.linalg.norm(H) for H in homographies]
    out = _rectified_rig(rig, cameras, homographies, K_rect, size, method)
    names = tuple(camera.name for camera in cameras)
    rectified = [out.camera(name) for name in names]
    return RectificationResult(
        rig=out,
        method=method,
        names=names,
        K_rect=K_rect,
        image_size=size,
        R_rect=R_rect,
        line_offset_ratio=line_offset_ratio,
        deformation=tuple(image_deformation(camera) for camera in rectified),
        disparity=() if matches is None else vertical_disparity(out, matches),
        n_inliers=n_inliers,
        max_fov_deg=None if half_angle is None else math.degrees(2.0 * half_angle),
    )


def calibrated_start(
    cameras: Sequence[Camera], max_offset_ratio: float, units: str, half_angle: float | None
) -> tuple[NDArray[np.float64], float]:
    """Common rotation and the centres' offset ratio, warning when it is large."""
    direction, baseline, distances = _line_of_centres(cameras)
    for camera in cameras:
        _check_epipole_outside(camera, direction, half_angle)
    ratio = float(distances.max() / baseline)
    if ratio > max_offset_ratio:
        worst = int(np.argmax(distances))
        warnings.warn(
            f"camera centres are off their common line by up to {ratio:.3%} of the baseline "
            f"(camera {cameras[worst].name!r} is {distances[worst]:.4g} {units} from the line, "
            f"baseline {baseline:.4g} {units}): rows align exactly only at infinity",
            CentresOffLineWarning,
            stacklevel=3,
        )
    return _common_rotation(cameras, direction), ratio
