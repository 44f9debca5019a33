"""Rectification of two and of N views: calibrated, Nozick 2011 N-view, Hartley 1999.

Rectified views share one image plane whose rows are parallel to the line
of camera centres, so a scene point appears on the same row in every view.
camcal stores, per camera, ``rectification = {H, K_rect, image_size}``
where ``H`` maps UNDISTORTED pixels of the original camera to rectified
pixels: a rectified image is sampled at ``distort(H^-1 x_r)``, undistortion
and rectification in ONE ``cv2.remap`` (:class:`RectifyWarper`, built on
:func:`camcal.geometry.remap.build_maps`).

Conventions (DESIGN.md)
-----------------------
- ``x ~ K [R | -R c] X``, ``R`` world -> camera, camera axes x right,
  y down, z forward; pixel (0, 0) is the centre of the top-left pixel.
- Correspondences (:data:`Matches`) map a pair of camera names
  ``(a, b)`` to two arrays of shape (n, 2): the same scene points seen in
  the ORIGINAL (distorted) images of ``a`` and ``b``, in pixels.

Methods
-------
- :func:`rectify_calibrated` (``"camera"``): the centres' line is fitted,
  one common rotation ``R_rect`` (x along the line, the rotation nearest the
  cameras' mean rotation: ``cv2.stereoRectify``'s choice for two cameras)
  and one shared ``K_rect`` (square pixels, the
  cameras' mean focal length, principal point and size chosen by
  ``alpha``), ``H_i = K_rect R_rect R_i^T K_i^-1`` (Fusiello et al. 2000,
  generalised to N cameras as in Nozick 2011).
- :func:`rectify_Nozick2011`: the calibrated start, then a joint
  refinement of every camera's rotation and focal length minimising the
  vertical disparity of every correspondence between all views.
- :func:`rectify_Hartley1999`: two views, no calibration (only K and
  distortion, to undistort): robust F (RANSAC, OpenCV), the second
  epipole sent to infinity along x, and the matching transform of the first
  image that minimises the disparity.

Fisheye lenses (``kannala-brandt``): pixels are taken through their rays
(:meth:`~camcal.model.distortion.Distortion.rays_from_pixels`), so
``H`` acts on ``K r``, defined beyond 90 degrees from the camera's axis.
A pinhole rectified image cannot hold rays near 90 degrees from its axis
(it stretches a ray at ``theta`` by ``1 / cos^2 theta``), so its field of
view is capped, as ``camcal undistort`` caps it: ``max_fov_deg`` (full
angle about the rectified viewing direction; by default 120 degrees when a
camera has a fisheye lens, no cap otherwise). The rotations are those of
``cv2.fisheye.stereoRectify``; its new camera matrix (focal chosen by
``balance`` / ``fov_scale``) differs from ``K_rect`` (mean focal, frame by
``alpha`` inside the cap).

Metrics: vertical disparity RMS and max per pair on correspondences
(:func:`vertical_disparity`), Mallon & Whelan's orthogonality and
aspect-ratio distortion, and the shares of the original image kept and of
the rectified image covered (:func:`image_deformation`).

References
----------
Fusiello, A., Trucco, E. & Verri, A. (2000). A compact algorithm for
rectification of stereo pairs. Machine Vision and Applications 12(1).
Hartley, R. I. (1999). Theory and practice of projective rectification.
International Journal of Computer Vision 35(2), 115-127.
Mallon, J. & Whelan, P. F. (2005). Projective rectification from the
fundamental matrix. Image and Vision Computing 23(7), 643-650.
Nozick, V. (2011). Multiple view image rectification. Proc. IEEE-ISAS
2011, International Symposium on Access Spaces, 277-282.
Markley, F. L., Cheng, Y., Crassidis, J. L. & Oshman, Y. (2007). Averaging
quaternions. Journal of Guidance, Control, and Dynamics 30(4), 1193-1197.
Lowe, D. G. (2004). Distinctive image features from scale-invariant
keypoints. IJCV 60(2) (SIFT and the ratio test).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.remap import RemapMaps, build_maps
from camcal.geometry.undistort import FISHEYE_FOV_DEG
from camcal.io.frames import imread, imwrite
from camcal.model.rig import Camera, Rectification, Rig, make_provenance

__all__ = [
    "METHODS",
    "Matches",
    "CentresOffLineWarning",
    "PairDisparity",
    "ImageDeformation",
    "RectificationResult",
    "rectify",
    "rectify_calibrated",
    "rectify_Nozick2011",
    "rectify_Hartley1999",
    "vertical_disparity",
    "image_deformation",
    "match_images",
    "read_matches_csv",
    "RectifyWarper",
]

#: Method names accepted by :func:`rectify`.
METHODS = ("camera", "Nozick 2011", "Hartley 1999")

#: Pair of camera names -> (points in the first camera, points in the second),
#: each (n, 2) in distorted (original) pixels.
Matches = Mapping[tuple[str, str], tuple[ArrayLike, ArrayLike]]

#: Default warning threshold: a centre this far off the line (relative to the baseline).
MAX_OFFSET_RATIO = 0.01
#: Rectified images are at most this many times the largest original dimension.
MAX_SIZE_FACTOR = 4.0
_BORDER_SAMPLES = 33
_GRID = (64, 48)
_DAMPING = 1e-3


class CentresOffLineWarning(UserWarning):
    """The camera centres are not on one line: rows align only approximately."""


# -- results ------------------------------------------------------------------------


@dataclass(frozen=True)
class PairDisparity:
    """Vertical disparity of one pair's correspondences after rectification.

    Attributes
    ----------
    first, second : str
        Camera names.
    n : int
        Number of correspondences.
    rms_px, max_px : float
        RMS and largest ``|y_first - y_second|`` in rectified pixels.
    """

    first: str
    second: str
    n: int
    rms_px: float
    max_px: float


@dataclass(frozen=True)
class ImageDeformation:
    """How much one rectifying homography deforms and crops its image.

    Attributes
    ----------
    name : str
        Camera name.
    orthogonality_deg : float
        Angle between the images of the two lines joining opposite edge
        midpoints (90 is ideal; Mallon & Whelan 2005).
    aspect_ratio : float
        Ratio of the lengths of the images of the two diagonals (1 is ideal).
    kept_fraction : float
        Share of the original image that lands inside the rectified image.
    valid_fraction : float
        Share of the rectified image that has a source pixel.
    """

    name: str
    orthogonality_deg: float
    aspect_ratio: float
    kept_fraction: float
    valid_fraction: float


@dataclass(frozen=True, eq=False)
class RectificationResult:
    """A rectified rig and the figures that say how good the rectification is.

    Attributes
    ----------
    rig : Rig
        The input rig with ``rectification`` set on the rectified cameras.
    method : str
        One of :data:`METHODS`.
    names : tuple of str
        The rectified cameras.
    K_rect : ndarray, shape (3, 3)
        The shared rectified intrinsics (nominal for Hartley 1999, whose
        rectified views are projective, not metric, cameras).
    image_size : (int, int)
        Rectified (width, height) in pixels.
    R_rect : ndarray, shape (3, 3) or None
        World -> rectified rotation (calibrated methods only).
    line_offset_ratio : float
        Largest distance of a centre to the fitted line of centres divided by
        the baseline (extent of the centres along the line); 0 for two
        cameras, NaN for Hartley 1999.
    deformation : tuple of ImageDeformation
        One per rectified camera.
    disparity : tuple of PairDisparity
        On the correspondences the method was given (empty without).
    n_inliers : int or None
        Hartley 1999: matches consistent with the robust F.
    max_fov_deg : float or None
        The field-of-view cap the frame was fitted under (full angle about
        the rectified viewing direction; about each camera's axis for
        Hartley 1999), None without one.
    """

    rig: Rig
    method: str
    names: tuple[str, ...]
    K_rect: NDArray[np.float64]
    image_size: tuple[int, int]
    R_rect: NDArray[np.float64] | None
    line_offset_ratio: float
    deformation: tuple[ImageDeformation, ...]
    disparity: tuple[PairDisparity, ...]
    n_inliers: int | None = None
    max_fov_deg: float | None = None

    def summary(self) -> str:
        """Readable lines: size, focal length, disparity, deformation."""
        width, height = self.image_size
        lines = [
            f"rectified {len(self.names)} cameras ({self.method}) to {width}x{height} px, "
            f"f {self.K_rect[0, 0]:.2f} px"
        ]
        if math.isfinite(self.line_offset_ratio) and len(self.names) > 2:
            lines.append(f"centres off their line by up to {self.line_offset_ratio:.3%} of the baseline")
        if self.max_fov_deg is not None:
            lines.append(f"field of view capped at {self.max_fov_deg:.4g} deg (a pinhole image cannot hold rays "
                         "near 90 deg; --max-fov)")
        if self.n_inliers is not None:
            lines.append(f"fundamental matrix: {self.n_inliers} inlier matches")
        for pair in self.disparity:
            lines.append(
                f"vertical disparity {pair.first}-{pair.second}: RMS {pair.rms_px:.3f} px "
                f"(worst {pair.max_px:.3f} px, {pair.n} correspondences)"
            )
        for item in self.deformation:
            lines.append(
                f"{item.name}: orthogonality {item.orthogonality_deg:.2f} deg, aspect ratio "
                f"{item.aspect_ratio:.4f}, kept {item.kept_fraction:.1%} of the image, "
                f"{item.valid_fraction:.1%} of the rectified image valid"
            )
        return "\n".join(lines)

    def to_report(self) -> dict:
        """The figures as a JSON-ready dict (``camcal rectify --report``)."""
        return {
            "method": self.method,
            "cameras": list(self.names),
            "image_size": list(self.image_size),
            "K_rect": self.K_rect.tolist(),
            "line_offset_ratio": None if math.isnan(self.line_offset_ratio) else self.line_offset_ratio,
            "n_inliers": self.n_inliers,
            "max_fov_deg": self.max_fov_deg,
            "disparity": [dataclasses.asdict(pair) for pair in self.disparity],
            "deformation": [dataclasses.asdict(item) for item in self.deformation],
        }


# -- small geometry helpers ------------------------------------------------------------


def _apply(H: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Homogeneous map of (n, 2) points; the third coordinate is returned too."""
    mapped = np.column_stack([points, np.ones(len(points))]) @ H.T
    return mapped


def _dehom(mapped: NDArray[np.float64]) -> NDArray[np.float64]:
    with np.errstate(divide="ignore", invalid="ignore"):
        return mapped[:, :2] / mapped[:, 2:3]


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


def _rays(camera: Camera, points: ArrayLike) -> NDArray[np.float64]:
    """Unit rays in the camera frame of distorted pixels (beyond 90 degrees for a fisheye); NaN out of range."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise CamcalError(f"points of camera {camera.name!r} must have shape (n, 2), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise CamcalError(f"points of camera {camera.name!r} contain NaN or infinite values")
    return camera.distortion.rays_from_pixels(points, camera.K)


def _lifted(camera: Camera, points: ArrayLike) -> NDArray[np.float64]:
    """Homogeneous undistorted pixels ``K r`` (n, 3) of distorted pixels, ``r`` their rays.

    For a ray in front of the camera this is its pinhole pixel ``(u, v, 1)``
    up to a positive scale; a fisheye ray at or beyond 90 degrees keeps its
    direction (third coordinate <= 0), which a homography carries on.
    """
    return _rays(camera, points) @ camera.K.T


def _border_rays(camera: Camera, pixels: NDArray[np.float64], half_angle: float | None) -> NDArray[np.float64]:
    """Rays of border pixels; a pixel beyond a fisheye model's range (the black corners of a circular
    fisheye) takes the ray at :attr:`~camcal.model.distortion.Distortion.max_angle_rad` in its
    azimuth, which a cap narrower than that range turns in anyway."""
    rays = _rays(camera, pixels)
    lost = ~np.all(np.isfinite(rays), axis=1)
    if not lost.any():
        return rays
    reach = camera.distortion.max_angle_rad
    if half_angle is None or camera.distortion.model != "kannala-brandt" or half_angle >= reach:
        raise CamcalError(f"camera {camera.name!r}: its {camera.distortion.model} lens model maps part of the "
                          "frame's border to no ray (beyond the model's range); cap the field of view below "
                          f"{math.degrees(2 * reach):.0f} degrees")
    offsets = np.linalg.solve(camera.K, np.column_stack([pixels[lost], np.ones(lost.sum())]).T).T[:, :2]
    azimuth = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    rays[lost] = np.column_stack([math.sin(reach) * azimuth, np.full(lost.sum(), math.cos(reach))])
    return rays


def _in_front(mapped: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Rows of homogeneous points that are finite and in front of the plane (third coordinate > 0)."""
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(mapped), axis=1) & (mapped[:, 2] > 0)


def _capped(rays: NDArray[np.float64], axis: NDArray[np.float64], half_angle: float | None) -> NDArray[np.float64]:
    """Each ray turned towards the unit ``axis`` (in its plane) to at most ``half_angle`` from it."""
    if half_angle is None:
        return rays
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    along = rays @ axis
    across = rays - along[:, None] * axis[None, :]
    norm = np.linalg.norm(across, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        side = np.where(norm > 0.0, across / norm, 0.0)
    theta = np.minimum(np.arccos(np.clip(along, -1.0, 1.0)), half_angle)[:, None]
    return np.cos(theta) * axis[None, :] + np.sin(theta) * side


def _half_angle(cameras: Sequence[Camera], max_fov_deg: float | None) -> float | None:
    """Half the field-of-view cap in radians: ``max_fov_deg``, or FISHEYE_FOV_DEG with a fisheye, or none."""
    if max_fov_deg is None:
        if not any(camera.distortion.model == "kannala-brandt" for camera in cameras):
            return None
        max_fov_deg = FISHEYE_FOV_DEG
    if isinstance(max_fov_deg, bool) or not isinstance(max_fov_deg, (int, float)) or not 0.0 < max_fov_deg < 180.0:
        raise CamcalError(f"the field-of-view cap (max_fov_deg, --max-fov) must be between 0 and 180 degrees, "
                          f"got {max_fov_deg!r}")
    return math.radians(0.5 * max_fov_deg)


def _cameras(rig: Rig, names: Sequence[str] | None) -> list[Camera]:
    names = [camera.name for camera in rig.cameras] if names is None else list(names)
    if len(names) < 2:
        raise CamcalError(f"rectification needs at least 2 cameras, got {len(names)}")
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names to rectify repeat: {', '.join(names)}")
    return [rig.camera(name) for name in names]


def _check_alpha(alpha: float) -> float:
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
            mapped = _capped(rays, axis, half_angle) @ camera.K.T @ frame.T
            if not np.all(_in_front(mapped)):
                raise CamcalError(
                    f"camera {camera.name!r} sees beyond the rectified image plane "
                    "(its field of view reaches 90 degrees from the common viewing direction; "
                    "cap it with max_fov_deg / --max-fov)"
                )
            sides[side] = _dehom(mapped)
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
        if camera.distortion.model == "kannala-brandt":
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


def _mean_focal(cameras: Sequence[Camera]) -> float:
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


def _finish(
    rig: Rig, cameras: Sequence[Camera], frames: Sequence[NDArray[np.float64]], alpha: float,
    method: str, R_rect: NDArray[np.float64] | None, line_offset_ratio: float,
    matches: Matches | None, half_angle: float | None, n_inliers: int | None = None,
) -> RectificationResult:
    """Fit the image frame, store the rectification, measure it."""
    focal = _mean_focal(cameras)
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


# -- calibrated rectification -------------------------------------------------------------


def _calibrated_start(
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


def rectify_calibrated(
    rig: Rig,
    names: Sequence[str] | None = None,
    alpha: float = 0.0,
    matches: Matches | None = None,
    max_offset_ratio: float = MAX_OFFSET_RATIO,
    max_fov_deg: float | None = None,
) -> RectificationResult:
    """Rectify calibrated cameras onto one common image plane.

    Parameters
    ----------
    rig : Rig
        Calibrated cameras (K, distortion, R, c).
    names : sequence of str, optional
        Cameras to rectify (default: all), at least 2.
    alpha : float
        0 keeps only pixels every view sees (no black border), 1 keeps every
        source pixel; in between, linearly.
    matches : Matches, optional
        Correspondences on which to report the vertical disparity.
    max_offset_ratio : float
        Warn (:class:`CentresOffLineWarning`, with the figure) when a centre
        is further than this from the line of centres, relative to the
        baseline.
    max_fov_deg : float, optional
        The widest full angle about the rectified viewing direction (the
        third row of ``R_rect``) that the rectified images hold, in (0, 180)
        degrees; ``None``: :data:`~camcal.geometry.undistort.FISHEYE_FOV_DEG`
        (120) when a camera has a ``kannala-brandt`` lens, no cap otherwise
        (the cap of ``camcal undistort``).

    Returns
    -------
    RectificationResult

    Raises
    ------
    CamcalError
        Fewer than two cameras, coincident centres, a line of centres that
        points into an image (forward motion; for a fisheye, within the
        cap), views with no common area, or a view reaching 90 degrees from
        the rectified viewing direction without a cap.

    Notes
    -----
    With ``d`` the direction of the least-squares line through the centres
    and ``M`` the cameras' mean rotation (chordal L2 mean, Markley et al.
    2007), ``d`` oriented so that ``(M d)_x > 0``, ``R_rect = W M`` where
    ``W`` is the smallest rotation taking ``M d`` onto the x axis: the first row
    of ``R_rect`` is ``d``, and of all rotations with that row ``R_rect`` is
    the nearest to ``M``. For two cameras ``M`` is the midpoint
    ``R^(1/2) R_1`` and ``R_rect R_i^T`` are the ``R1``, ``R2`` that
    ``cv2.stereoRectify`` returns for a horizontal pair. Every
    rectified camera is ``K_rect R_rect [I | -c_i]``; as the centres differ
    only along ``d`` (the rectified x axis), a point projects to the same
    row in all of them. On undistorted pixels
    ``H_i = K_rect R_rect R_i^T K_i^-1``. ``K_rect`` has zero skew, square
    pixels and the cameras' mean focal length ``mean(sqrt(fx fy))`` (one
    original pixel stays about one rectified pixel); its principal point and
    the image size frame the rectangle chosen by ``alpha``.

    Fisheye lenses: a pinhole rectified image holds only rays in front of
    its plane and stretches a ray at ``theta`` from its axis by
    ``1 / cos^2 theta``, so the frame is fitted to each camera's border
    rays (:meth:`~camcal.model.distortion.Distortion.rays_from_pixels`,
    beyond 90 degrees from the camera's own axis included) turned towards
    the rectified axis to at most ``max_fov_deg / 2``. ``H_i`` stays the
    same homography, applied to ``K_i r`` for a ray ``r``; pixels whose
    rays lie beyond the cap fall outside the rectified image or into its
    corners.

    References
    ----------
    Fusiello, Trucco & Verri (2000); Nozick (2011); Markley et al. (2007).

    Examples
    --------
    >>> import numpy as np
    >>> from camcal.synthetic import example_camera
    >>> from camcal.model.rig import Rig
    >>> a = example_camera("a", centre=(0.0, -6.0, 1.4), target=(0.0, 0.0, 1.4))
    >>> b = example_camera("b", centre=(0.5, -6.0, 1.4), target=(0.3, 0.0, 1.4))
    >>> result = rectify_calibrated(Rig((a, b)))
    >>> X = np.array([[0.2, 1.0, 1.1]])
    >>> rows = [result.rig.camera(n).rectification.H @ np.append(result.rig.camera(n).project(X)[0], 1)
    ...         for n in "ab"]
    >>> bool(abs(rows[0][1] / rows[0][2] - rows[1][1] / rows[1][2]) < 1e-9)
    True
    """
    alpha = _check_alpha(alpha)
    cameras = _cameras(rig, names)
    half_angle = _half_angle(cameras, max_fov_deg)
    R_rect, ratio = _calibrated_start(cameras, max_offset_ratio, rig.units, half_angle)
    frames = [R_rect @ camera.R.T @ np.linalg.inv(camera.K) for camera in cameras]
    return _finish(rig, cameras, frames, alpha, "camera", R_rect, ratio, matches, half_angle)


def _pairs(cameras: Sequence[Camera], matches: Matches) -> list[tuple[int, int, NDArray, NDArray]]:
    """Matches as (index a, index b, rays a, rays b) in the cameras' frames, validated; NaN rays out of range."""
    index = {camera.name: i for i, camera in enumerate(cameras)}
    pairs = []
    for key, value in matches.items():
        if not isinstance(key, tuple) or len(key) != 2:
            raise CamcalError(f"matches must be keyed by (camera, camera), got {key!r}")
        a, b = key
        for name in (a, b):
            if name not in index:
                raise CamcalError(f"matches name camera {name!r}, which is not being rectified")
        if a == b:
            raise CamcalError(f"matches pair a camera with itself ({a!r})")
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise CamcalError(f"matches of ({a}, {b}) must be two (n, 2) arrays")
        xa = _rays(cameras[index[a]], value[0])
        xb = _rays(cameras[index[b]], value[1])
        if len(xa) != len(xb):
            raise CamcalError(f"matches of ({a}, {b}) have {len(xa)} and {len(xb)} points")
        if len(xa):
            pairs.append((index[a], index[b], xa, xb))
    return pairs


def _scaled_K(K: NDArray[np.float64], log_scale: float) -> NDArray[np.float64]:
    """K with its focal lengths (and skew) scaled by ``exp(log_scale)``."""
    scaled = K.copy()
    scaled[:2, :2] *= math.exp(log_scale)
    return scaled


def rectify_Nozick2011(
    rig: Rig,
    matches: Matches,
    names: Sequence[str] | None = None,
    alpha: float = 0.0,
    max_offset_ratio: float = MAX_OFFSET_RATIO,
    max_fov_deg: float | None = None,
) -> RectificationResult:
    """N-view rectification refined jointly on every correspondence.

    Parameters
    ----------
    rig : Rig
        Calibrated cameras whose centres lie close to a line.
    matches : Matches
        Correspondences between any pairs of the cameras (distorted pixels);
        the vertical disparity of all of them is minimised together.
    names, alpha, max_offset_ratio, max_fov_deg
        As in :func:`rectify_calibrated`; only correspondences whose rays
        lie within the field-of-view cap (in front of the rectified plane
        without one) in both views take part.

    Returns
    -------
    RectificationResult
        ``disparity`` is measured on ``matches`` (training figures: hold
        some correspondences out and call :func:`vertical_disparity` for an
        independent check).

    Raises
    ------
    CamcalError
        As :func:`rectify_calibrated`, and when no pair has correspondences.

    Notes
    -----
    Start from :func:`rectify_calibrated`'s ``R_rect``; each camera gets a
    small rotation ``Q_i = exp([w_i]_x)`` and a focal scale ``exp(s_i)``:
    ``H_i = K_f R_rect Q_i R_i^T K_i(s_i)^-1`` with ``K_f = diag(f, f, 1)``.
    The parameters minimise, over all pairs (i, j) and their
    correspondences k, ``sum (y(H_i u_ik) - y(H_j u_jk))^2`` (a soft-L1
    loss of scale 1 px keeps stray matches from dominating) plus a light
    damping ``1e-3 f (|w_i|^2 + s_i^2)`` that fixes the motions that leave
    every row alignment unchanged (a common rotation about x). The focal
    scales act relative to their mean (``s_i - mean(s)``): a common zoom
    would shrink every disparity without aligning anything, and on wide
    (fisheye) matches the fit ran off along it. The image
    frame (``K_rect``, size) is chosen afterwards as in
    :func:`rectify_calibrated`. The refinement corrects the homographies,
    not the stored calibration.

    References
    ----------
    Nozick, V. (2011). Multiple view image rectification. IEEE-ISAS.
    """
    alpha = _check_alpha(alpha)
    cameras = _cameras(rig, names)
    half_angle = _half_angle(cameras, max_fov_deg)
    R_rect, ratio = _calibrated_start(cameras, max_offset_ratio, rig.units, half_angle)
    least_cos = 0.0 if half_angle is None else math.cos(half_angle)
    homogeneous = []
    for i, j, ra, rb in _pairs(cameras, matches):
        with np.errstate(invalid="ignore"):
            inside = ((ra @ cameras[i].R @ R_rect[2]) > least_cos) & ((rb @ cameras[j].R @ R_rect[2]) > least_cos)
        if inside.any():
            homogeneous.append((i, j, ra[inside] @ cameras[i].K.T, rb[inside] @ cameras[j].K.T))
    if not homogeneous:
        raise CamcalError("the N-view refinement needs correspondences between at least one pair of cameras "
                          "(within the rectified field of view)")
    focal = _mean_focal(cameras)

    def frames_of(params: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        params = params.reshape(len(cameras), 4)
        scales = params[:, 3] - params[:, 3].mean()  # a common zoom only shrinks every disparity: held out
        return [
            R_rect @ Rotation.from_rotvec(p[:3]).as_matrix() @ camera.R.T @ np.linalg.inv(_scaled_K(camera.K, scale))
            for camera, p, scale in zip(cameras, params, scales)
        ]

    def residuals(params: NDArray[np.float64]) -> NDArray[np.float64]:
        frames = frames_of(params)
        out = []
        for i, j, ua, ub in homogeneous:
            ra = ua @ frames[i].T
            rb = ub @ frames[j].T
            out.append(focal * (ra[:, 1] / ra[:, 2] - rb[:, 1] / rb[:, 2]))
        out.append(_DAMPING * focal * params)
        return np.concatenate(out)

    solution = least_squares(residuals, np.zeros(4 * len(cameras)), loss="soft_l1", f_scale=1.0, x_scale=1e-3)
    frames = frames_of(solution.x)
    return _finish(rig, cameras, frames, alpha, "Nozick 2011", R_rect, ratio, matches, half_angle)


# -- uncalibrated rectification ---------------------------------------------------------------


def _cross_matrix(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _epipole_to_infinity(epipole: NDArray[np.float64], size: tuple[int, int]) -> NDArray[np.float64]:
    """Hartley's ``H' = G R T``: image centre to 0, epipole onto the x axis, then to infinity."""
    width, height = size
    T = np.array([[1.0, 0.0, -(width - 1) / 2], [0.0, 1.0, -(height - 1) / 2], [0.0, 0.0, 1.0]])
    e = T @ epipole
    if e[2] < 0:
        e = -e
    angle = math.atan2(e[1], e[0])
    if abs(angle) > math.pi / 2:  # epipole on the left: turn it to -x, not by half a turn
        angle -= math.copysign(math.pi, angle)
    cos, sin = math.cos(angle), math.sin(angle)
    R = np.array([[cos, sin, 0.0], [-sin, cos, 0.0], [0.0, 0.0, 1.0]])
    e = R @ e
    G = np.eye(3)
    if abs(e[2]) > 1e-12 * abs(e[0]):
        G[2, 0] = -e[2] / e[0]
    return G @ R @ T


def rectify_Hartley1999(
    rig: Rig,
    matches: Matches,
    names: Sequence[str] | None = None,
    alpha: float = 0.0,
    threshold_px: float = 1.0,
    max_fov_deg: float | None = None,
) -> RectificationResult:
    """Two-view projective rectification from point matches, no calibration.

    Parameters
    ----------
    rig : Rig
        Two cameras (or ``names`` picking two); only their K, distortion and
        image size are used (to undistort the matches), not their poses.
    matches : Matches
        Matches between the two cameras (distorted pixels), at least 8;
        outliers are allowed.
    names : sequence of str, optional
        The two cameras, first and second (default: the rig's two cameras).
    alpha : float
        As in :func:`rectify_calibrated`.
    threshold_px : float
        RANSAC inlier threshold on the distance to the epipolar line.
    max_fov_deg : float, optional
        As in :func:`rectify_calibrated`, about each camera's own optical
        axis (a projective rectification has no metric viewing direction);
        only matches within it in both views are used.

    Returns
    -------
    RectificationResult
        ``K_rect`` is nominal (mean focal length, principal point at the
        image of the original centre): the rectified views are projective.
        ``disparity`` is measured on the inlier matches.

    Raises
    ------
    CamcalError
        Not two cameras, fewer than 8 matches or inliers, or an epipole
        inside an image (planar rectification impossible).

    Notes
    -----
    With ``F`` (robust, ``x_2^T F x_1 = 0``) and the second epipole
    ``e_2`` (``F^T e_2 = 0``): ``H_2 = G R T`` moves the image centre to the
    origin, rotates ``e_2`` to ``(f, 0, 1)`` and sends it to infinity with
    ``G = [[1, 0, 0], [0, 1, 0], [-1/f, 0, 1]]``. With
    ``M = [e_2]_x F + e_2 v^T`` (``v = (1, 1, 1)``) the matching transform
    ``H_0 = H_2 M`` puts corresponding points on equal rows, and
    ``H_1 = H_A H_0``, ``H_A = [[a, b, c], [0, 1, 0], [0, 0, 1]]``, with
    ``(a, b, c)`` minimising ``sum (a x^_1 + b y^_1 + c - x^_2)^2`` over the
    inliers (Hartley 1999, section 7). F is fitted by OpenCV
    (``cv2.findFundamentalMat``, RANSAC, then the normalised 8-point
    algorithm on the inliers).

    References
    ----------
    Hartley, R. I. (1999). Theory and practice of projective rectification.
    IJCV 35(2).
    """
    alpha = _check_alpha(alpha)
    cameras = _cameras(rig, names)
    if len(cameras) != 2:
        raise CamcalError(f"Hartley 1999 rectifies two views, got {len(cameras)} cameras (pick two by name)")
    first, second = cameras
    pairs = _pairs(cameras, matches)
    if not pairs:
        raise CamcalError(f"no matches between {first.name!r} and {second.name!r}")
    rays1 = np.vstack([xa if i == 0 else xb for i, _, xa, xb in pairs])
    rays2 = np.vstack([xb if i == 0 else xa for i, _, xa, xb in pairs])
    half_angle = _half_angle(cameras, max_fov_deg)
    least_cos = 0.0 if half_angle is None else math.cos(half_angle)
    with np.errstate(invalid="ignore"):
        inside = (rays1[:, 2] > least_cos) & (rays2[:, 2] > least_cos)
    x1 = _dehom(rays1[inside] @ first.K.T)
    x2 = _dehom(rays2[inside] @ second.K.T)
    if len(x1) < 8:
        raise CamcalError(f"Hartley 1999 needs at least 8 matches, got {len(x1)}")
    F, mask = cv2.findFundamentalMat(x1, x2, cv2.USAC_ACCURATE, threshold_px, 0.999, 10000)
    if F is None or F.shape != (3, 3):
        raise CamcalError("no fundamental matrix fits the matches (degenerate or too few inliers)")
    inliers = mask.ravel().astype(bool)
    if inliers.sum() < 8:
        raise CamcalError(f"only {int(inliers.sum())} matches agree with one fundamental matrix, need 8")
    x1, x2 = x1[inliers], x2[inliers]
    refined, _ = cv2.findFundamentalMat(x1, x2, cv2.FM_8POINT)
    if refined is not None and refined.shape == (3, 3):
        F = refined
    F = F / np.linalg.norm(F)
    for camera, matrix in ((first, F), (second, F.T)):
        _, _, vt = np.linalg.svd(matrix)
        epipole = vt[-1]
        if abs(epipole[2]) > 1e-12:
            u, v = epipole[:2] / epipole[2]
            width, height = camera.image_size
            if -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5:
                raise CamcalError(
                    f"the epipole of camera {camera.name!r} is inside the image at ({u:.1f}, {v:.1f}) px: "
                    "planar rectification is impossible"
                )
    _, _, vt = np.linalg.svd(F.T)
    e2 = vt[-1]
    H2 = _epipole_to_infinity(e2, second.image_size)
    M = _cross_matrix(e2) @ F + np.outer(e2, np.ones(3))
    H0 = H2 @ M
    width, height = first.image_size
    if (H0 @ [(width - 1) / 2, (height - 1) / 2, 1.0])[2] < 0:  # M's sign is arbitrary
        H0 = -H0
    p1 = _dehom(_apply(H0, x1))
    p2 = _dehom(_apply(H2, x2))
    design = np.column_stack([p1, np.ones(len(p1))])
    abc, *_ = np.linalg.lstsq(design, p2[:, 0], rcond=None)
    H_A = np.array([abc, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    H1 = H_A @ H0
    if np.linalg.det(H1) <= 0:
        raise CamcalError("the matches rectify only with a mirrored image: check that the cameras are not swapped")
    inlier_matches = {(first.name, second.name): (first.distortion.distort(x1, first.K),
                                                  second.distortion.distort(x2, second.K))}
    return _finish(rig, cameras, [H1, H2], alpha, "Hartley 1999", None, float("nan"),
                   inlier_matches, half_angle, int(inliers.sum()))


# -- dispatcher -----------------------------------------------------------------------------


def rectify(
    rig: Rig,
    method: str = "camera",
    matches: Matches | None = None,
    names: Sequence[str] | None = None,
    alpha: float = 0.0,
    max_fov_deg: float | None = None,
) -> RectificationResult:
    """Rectify a rig with one of :data:`METHODS`.

    Parameters
    ----------
    rig : Rig
    method : str
        ``"camera"`` (:func:`rectify_calibrated`), ``"Nozick 2011"``
        (:func:`rectify_Nozick2011`, needs ``matches``) or ``"Hartley 1999"``
        (:func:`rectify_Hartley1999`, needs ``matches``).
    matches : Matches, optional
    names : sequence of str, optional
    alpha : float
    max_fov_deg : float, optional
        Field-of-view cap (:func:`rectify_calibrated`; default 120 degrees
        with a ``kannala-brandt`` lens, none otherwise).

    Returns
    -------
    RectificationResult
    """
    if method == "camera":
        return rectify_calibrated(rig, names, alpha, matches, max_fov_deg=max_fov_deg)
    if method not in METHODS:
        raise CamcalError(f"unknown rectification method {method!r}, expected one of: {', '.join(METHODS)}")
    if not matches:
        raise CamcalError(f"rectification method {method!r} needs point matches")
    if method == "Nozick 2011":
        return rectify_Nozick2011(rig, matches, names, alpha, max_fov_deg=max_fov_deg)
    return rectify_Hartley1999(rig, matches, names, alpha, max_fov_deg=max_fov_deg)


# -- metrics ----------------------------------------------------------------------------------


def vertical_disparity(rig: Rig, matches: Matches) -> tuple[PairDisparity, ...]:
    """Vertical disparity of correspondences in the rig's rectified views.

    Parameters
    ----------
    rig : Rig
        Cameras with ``rectification`` set.
    matches : Matches
        Correspondences in the original (distorted) pixels.

    Returns
    -------
    tuple of PairDisparity
        One per pair with at least one correspondence in front of the
        rectified plane in both views (``n`` counts those).

    Notes
    -----
    ``d_k = y(H_a K_a r_ak) - y(H_b K_b r_bk)`` with ``r`` the ray of each
    pixel (``K r`` is the undistorted pixel ``undistort(u)`` up to scale,
    and still defined for a fisheye ray beyond 90 degrees);
    ``rms_px = sqrt(mean d_k^2)``, ``max_px = max |d_k|``.
    """
    out = []
    for (a, b), (xa, xb) in matches.items():
        camera_a, camera_b = rig.camera(a), rig.camera(b)
        for camera in (camera_a, camera_b):
            if camera.rectification is None:
                raise CamcalError(f"camera {camera.name!r} has no rectification")
        ua = _lifted(camera_a, xa) @ camera_a.rectification.H.T
        ub = _lifted(camera_b, xb) @ camera_b.rectification.H.T
        if len(ua) != len(ub):
            raise CamcalError(f"matches of ({a}, {b}) have {len(ua)} and {len(ub)} points")
        seen = _in_front(ua) & _in_front(ub)
        if not seen.any():
            continue
        d = _dehom(ua[seen])[:, 1] - _dehom(ub[seen])[:, 1]
        out.append(PairDisparity(a, b, len(d), float(np.sqrt(np.mean(d**2))), float(np.abs(d).max())))
    return tuple(out)


def image_deformation(camera: Camera) -> ImageDeformation:
    """Mallon & Whelan's distortion figures and the image kept, for one camera.

    Parameters
    ----------
    camera : Camera
        With ``rectification`` set.

    Returns
    -------
    ImageDeformation

    Notes
    -----
    With the original image's edge midpoints ``a`` (top), ``b`` (right),
    ``c`` (bottom), ``d`` (left) mapped by ``H``: orthogonality
    ``E_O = acos(x.y / (|x| |y|))`` with ``x = b^ - d^``, ``y = c^ - a^``
    (ideal 90 deg). With the corners mapped the same way, the aspect ratio
    ``E_A = |x| / |y|`` with ``x``, ``y`` the two diagonals (ideal 1 for any
    image size). Kept and valid shares are measured on a 64 x 48 grid of
    pixels of the original and of the rectified image.

    References
    ----------
    Mallon, J. & Whelan, P. F. (2005). Projective rectification from the
    fundamental matrix. Image and Vision Computing 23(7).
    """
    rect = camera.rectification
    if rect is None:
        raise CamcalError(f"camera {camera.name!r} has no rectification")
    width, height = camera.image_size
    w, h = width - 1.0, height - 1.0
    mid = _dehom(_apply(rect.H, np.array([[w / 2, 0.0], [w, h / 2], [w / 2, h], [0.0, h / 2]])))
    x, y = mid[1] - mid[3], mid[2] - mid[0]
    orthogonality = math.degrees(math.acos(np.clip(x @ y / (np.linalg.norm(x) * np.linalg.norm(y)), -1, 1)))
    corners = _dehom(_apply(rect.H, np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])))
    aspect = float(np.linalg.norm(corners[2] - corners[0]) / np.linalg.norm(corners[3] - corners[1]))

    gx, gy = np.meshgrid(np.linspace(0, w, _GRID[0]), np.linspace(0, h, _GRID[1]))
    source = np.column_stack([gx.ravel(), gy.ravel()])
    mapped = _lifted(camera, source) @ rect.H.T
    rw, rh = rect.image_size
    with np.errstate(invalid="ignore"):
        inside = _in_front(mapped) & _inside(_dehom(mapped), (rw, rh))
    gx, gy = np.meshgrid(np.linspace(0, rw - 1.0, _GRID[0]), np.linspace(0, rh - 1.0, _GRID[1]))
    back = _apply(np.linalg.inv(rect.H), np.column_stack([gx.ravel(), gy.ravel()]))
    with np.errstate(invalid="ignore"):  # a rectified ray behind the camera has no source pixel (as in the maps)
        valid = _in_front(back) & _inside(camera.distortion.distort(_dehom(back), camera.K), (width, height))
    return ImageDeformation(camera.name, orthogonality, aspect, float(inside.mean()), float(valid.mean()))


def _inside(points: NDArray[np.float64], size: tuple[int, int]) -> NDArray[np.bool_]:
    width, height = size
    return (
        np.isfinite(points).all(axis=1)
        & (points[:, 0] >= -0.5) & (points[:, 0] <= width - 0.5)
        & (points[:, 1] >= -0.5) & (points[:, 1] <= height - 0.5)
    )


# -- correspondences from images or a file ----------------------------------------------------------


def _read_grey(path: str | os.PathLike) -> NDArray[np.uint8]:
    return imread(path, cv2.IMREAD_GRAYSCALE)


def match_images(
    rig: Rig, images: Mapping[str, str | os.PathLike], ratio: float = 0.75, threshold_px: float = 1.0
) -> dict[tuple[str, str], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """SIFT matches between every pair of the cameras' images.

    Parameters
    ----------
    rig : Rig
        Gives each camera's K and distortion.
    images : mapping of str to path
        One image per camera (e.g. the first frame of each sequence).
    ratio : float
        Lowe's ratio test threshold.
    threshold_px : float
        Matches farther than this from their epipolar line (robust F on
        undistorted pixels, RANSAC) are dropped.

    Returns
    -------
    dict
        :data:`Matches` in distorted pixels, one entry per pair of cameras.

    Notes
    -----
    SIFT and the ratio test (Lowe 2004) are OpenCV's; the outlier filter is
    ``cv2.findFundamentalMat`` with RANSAC on undistorted pixels. In a
    near-planar scene (a chessboard filling the view) F is weakly
    constrained and wrong matches can pass the filter: on the stereo
    chessboard test pair, 69 % of the kept matches lie within 1 px of their
    calibrated rows. Prefer a matches file or calibration there.
    """
    sift = cv2.SIFT_create()
    features = {}
    for name, path in images.items():
        rig.camera(name)
        features[name] = sift.detectAndCompute(_read_grey(path), None)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    out = {}
    for a, b in itertools.combinations(images, 2):
        (kp_a, desc_a), (kp_b, desc_b) = features[a], features[b]
        if desc_a is None or desc_b is None or len(kp_a) < 2 or len(kp_b) < 2:
            continue
        good = [m for m, n in matcher.knnMatch(desc_a, desc_b, k=2) if m.distance < ratio * n.distance]
        if len(good) < 8:
            continue
        xa = np.array([kp_a[m.queryIdx].pt for m in good], dtype=np.float64)
        xb = np.array([kp_b[m.trainIdx].pt for m in good], dtype=np.float64)
        ua, ub = _lifted(rig.camera(a), xa), _lifted(rig.camera(b), xb)
        pinhole = _in_front(ua) & _in_front(ub)  # a fisheye ray at 90 degrees or beyond has no pinhole pixel
        if pinhole.sum() < 8:
            continue
        xa, xb = xa[pinhole], xb[pinhole]
        _, mask = cv2.findFundamentalMat(_dehom(ua[pinhole]), _dehom(ub[pinhole]), cv2.USAC_ACCURATE, threshold_px,
                                         0.999, 10000)
        if mask is None:
            continue
        keep = mask.ravel().astype(bool)
        out[(a, b)] = (xa[keep], xb[keep])
    return out


def read_matches_csv(path: str | os.PathLike) -> dict[tuple[str, str], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Read matches from a CSV with the header ``camera_a,u_a,v_a,camera_b,u_b,v_b``.

    Pixels are in the original (distorted) images, pixel (0, 0) at the
    centre of the top-left pixel.

    Returns
    -------
    dict
        :data:`Matches`.
    """
    header = ["camera_a", "u_a", "v_a", "camera_b", "u_b", "v_b"]
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise CamcalError(f"cannot read matches file {path}: {error.strerror}") from None
    if not rows or [cell.strip() for cell in rows[0]] != header:
        raise CamcalError(f"{path}: the first line must be {','.join(header)}")
    collected: dict[tuple[str, str], list[list[float]]] = {}
    for number, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != 6:
            raise CamcalError(f"{path}, line {number}: expected 6 fields, got {len(row)}")
        try:
            values = [float(row[1]), float(row[2]), float(row[4]), float(row[5])]
        except ValueError:
            raise CamcalError(f"{path}, line {number}: pixel coordinates must be numbers") from None
        if not all(math.isfinite(v) for v in values):
            raise CamcalError(f"{path}, line {number}: pixel coordinates must be finite")
        collected.setdefault((row[0].strip(), row[3].strip()), []).append(values)
    if not collected:
        raise CamcalError(f"{path}: no matches")
    return {key: (np.array(v)[:, :2], np.array(v)[:, 2:]) for key, v in collected.items()}


# -- writing rectified images ------------------------------------------------------------------------


class RectifyWarper:
    """Writes rectified images: ONE ``cv2.remap`` per image, maps cached per camera.

    Parameters
    ----------
    rig : Rig
        Cameras with ``rectification`` set.

    Notes
    -----
    The maps sample the original image at ``distort(H^-1 x_r)``
    (:func:`camcal.geometry.remap.build_maps`): undistortion and
    rectification in one resampling. They are built on the first image of a
    camera and reused for the rest of its sequence.
    """

    def __init__(self, rig: Rig) -> None:
        self._rig = rig
        self._maps: dict[str, RemapMaps] = {}

    def maps(self, name: str) -> RemapMaps:
        """The (cached) remap maps of camera ``name``."""
        if name not in self._maps:
            camera = self._rig.camera(name)
            if camera.rectification is None:
                raise CamcalError(f"camera {name!r} has no rectification")
            self._maps[name] = build_maps(camera, camera.rectification.H, camera.rectification.image_size)
        return self._maps[name]

    def warp(self, name: str, image: NDArray) -> NDArray:
        """Rectify one image of camera ``name`` (size must match the camera's)."""
        width, height = self._rig.camera(name).image_size
        if image.shape[:2] != (height, width):
            raise CamcalError(
                f"image of camera {name!r} is {image.shape[1]}x{image.shape[0]} px, "
                f"the camera's is {width}x{height} px"
            )
        return self.maps(name).apply(image)

    def write(self, name: str, sources: Sequence[str | os.PathLike], out_dir: str | os.PathLike) -> list[Path]:
        """Rectify image files to ``out_dir/<camera>/<file name>``, each written atomically.

        Returns
        -------
        list of Path
            The written files, in the order of ``sources``.
        """
        written = []
        for source in sources:
            image = imread(source)
            written.append(imwrite(Path(out_dir) / name / Path(source).name, self.warp(name, image)))
        return written
