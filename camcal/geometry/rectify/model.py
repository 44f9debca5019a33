"""What a rectification is and how good it is: results, homogeneous pixels and rays, disparity, deformation.

Conventions (DESIGN.md): pixel (0, 0) is the centre of the top-left pixel;
camcal stores, per camera, ``rectification = {H, K_rect, image_size}``
where ``H`` maps UNDISTORTED pixels of the original camera to rectified
pixels. Correspondences (:data:`Matches`) map a pair of camera names
``(a, b)`` to two arrays of shape (n, 2): the same scene points seen in the
ORIGINAL (distorted) images of ``a`` and ``b``, in pixels.

Metrics: vertical disparity RMS and max per pair on correspondences
(:func:`vertical_disparity`), Mallon & Whelan's orthogonality and
aspect-ratio distortion, and the shares of the original image kept and of
the rectified image covered (:func:`image_deformation`).

References
----------
Mallon, J. & Whelan, P. F. (2005). Projective rectification from the
fundamental matrix. Image and Vision Computing 23(7), 643-650.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.model.rig import Camera, Rig

__all__ = [
    "MAX_OFFSET_RATIO",
    "MAX_SIZE_FACTOR",
    "METHODS",
    "CentresOffLineWarning",
    "ImageDeformation",
    "Matches",
    "PairDisparity",
    "RectificationResult",
    "apply_homography",
    "dehomogenise",
    "image_deformation",
    "in_front",
    "lifted_pixels",
    "pixel_rays",
    "vertical_disparity",
]

#: Method names accepted by :func:`~camcal.geometry.rectify.methods.rectify`.
METHODS = ("camera", "Nozick 2011", "Hartley 1999")

#: Pair of camera names -> (points in the first camera, points in the second),
#: each (n, 2) in distorted (original) pixels.
Matches = Mapping[tuple[str, str], tuple[ArrayLike, ArrayLike]]

#: Default warning threshold: a centre this far off the line (relative to the baseline).
MAX_OFFSET_RATIO = 0.01
#: Rectified images are at most this many times the largest original dimension.
MAX_SIZE_FACTOR = 4.0
_GRID = (64, 48)


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


def apply_homography(H: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Homogeneous map of (n, 2) points; the third coordinate is returned too."""
    mapped = np.column_stack([points, np.ones(len(points))]) @ H.T
    return mapped


def dehomogenise(mapped: NDArray[np.float64]) -> NDArray[np.float64]:
    with np.errstate(divide="ignore", invalid="ignore"):
        return mapped[:, :2] / mapped[:, 2:3]


def pixel_rays(camera: Camera, points: ArrayLike) -> NDArray[np.float64]:
    """Unit rays in the camera frame of distorted pixels (beyond 90 degrees for a fisheye); NaN out of range."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise CamcalError(f"points of camera {camera.name!r} must have shape (n, 2), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise CamcalError(f"points of camera {camera.name!r} contain NaN or infinite values")
    return camera.distortion.rays_from_pixels(points, camera.K)


def lifted_pixels(camera: Camera, points: ArrayLike) -> NDArray[np.float64]:
    """Homogeneous undistorted pixels ``K r`` (n, 3) of distorted pixels, ``r`` their rays.

    For a ray in front of the camera this is its pinhole pixel ``(u, v, 1)``
    up to a positive scale; a fisheye ray at or beyond 90 degrees keeps its
    direction (third coordinate <= 0), which a homography carries on.
    """
    return pixel_rays(camera, points) @ camera.K.T


def in_front(mapped: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Rows of homogeneous points that are finite and in front of the plane (third coordinate > 0)."""
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(mapped), axis=1) & (mapped[:, 2] > 0)


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
        ua = lifted_pixels(camera_a, xa) @ camera_a.rectification.H.T
        ub = lifted_pixels(camera_b, xb) @ camera_b.rectification.H.T
        if len(ua) != len(ub):
            raise CamcalError(f"matches of ({a}, {b}) have {len(ua)} and {len(ub)} points")
        seen = in_front(ua) & in_front(ub)
        if not seen.any():
            continue
        d = dehomogenise(ua[seen])[:, 1] - dehomogenise(ub[seen])[:, 1]
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
    mid = dehomogenise(apply_homography(rect.H, np.array([[w / 2, 0.0], [w, h / 2], [w / 2, h], [0.0, h / 2]])))
    x, y = mid[1] - mid[3], mid[2] - mid[0]
    orthogonality = math.degrees(math.acos(np.clip(x @ y / (np.linalg.norm(x) * np.linalg.norm(y)), -1, 1)))
    corners = dehomogenise(apply_homography(rect.H, np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])))
    aspect = float(np.linalg.norm(corners[2] - corners[0]) / np.linalg.norm(corners[3] - corners[1]))

    gx, gy = np.meshgrid(np.linspace(0, w, _GRID[0]), np.linspace(0, h, _GRID[1]))
    source = np.column_stack([gx.ravel(), gy.ravel()])
    mapped = lifted_pixels(camera, source) @ rect.H.T
    rw, rh = rect.image_size
    with np.errstate(invalid="ignore"):
        inside = in_front(mapped) & _inside(dehomogenise(mapped), (rw, rh))
    gx, gy = np.meshgrid(np.linspace(0, rw - 1.0, _GRID[0]), np.linspace(0, rh - 1.0, _GRID[1]))
    back = apply_homography(np.linalg.inv(rect.H), np.column_stack([gx.ravel(), gy.ravel()]))
    with np.errstate(invalid="ignore"):  # a rectified ray behind the camera has no source pixel (as in the maps)
        valid = in_front(back) & _inside(camera.distortion.distort(dehomogenise(back), camera.K), (width, height))
    return ImageDeformation(camera.name, orthogonality, aspect, float(inside.mean()), float(valid.mean()))


def _inside(points: NDArray[np.float64], size: tuple[int, int]) -> NDArray[np.bool_]:
    width, height = size
    return (
        np.isfinite(points).all(axis=1)
        & (points[:, 0] >= -0.5) & (points[:, 0] <= width - 0.5)
        & (points[:, 1] >= -0.5) & (points[:, 1] <= height - 0.5)
    )
