"""Rectification on image arrays: the one-remap warp of each view and SIFT matches between views.

The maps sample the original image at ``distort(H^-1 x_r)``
(:func:`camcal.geometry.remap.build_maps`): undistortion and rectification
in ONE ``cv2.remap`` (:class:`RectifyWarper`).

References
----------
Lowe, D. G. (2004). Distinctive image features from scale-invariant
keypoints. IJCV 60(2) (SIFT and the ratio test).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.rectify.model import dehomogenise, in_front, lifted_pixels
from camcal.geometry.remap import RemapMaps, build_maps
from camcal.model.rig import Rig

__all__ = ["RectifyWarper", "match_images"]


def match_images(
    rig: Rig, images: Mapping[str, NDArray], ratio: float = 0.75, threshold_px: float = 1.0
) -> dict[tuple[str, str], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """SIFT matches between every pair of the cameras' images.

    Parameters
    ----------
    rig : Rig
        Gives each camera's K and distortion.
    images : mapping of str to ndarray
        One image per camera (e.g. the first frame of each sequence), grey
        (H, W) or BGR (H, W, 3), 8 bit.
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
    for name, image in images.items():
        rig.camera(name)
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        features[name] = sift.detectAndCompute(grey, None)
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
        ua, ub = lifted_pixels(rig.camera(a), xa), lifted_pixels(rig.camera(b), xb)
        pinhole = in_front(ua) & in_front(ub)  # a fisheye ray at 90 degrees or beyond has no pinhole pixel
        if pinhole.sum() < 8:
            continue
        xa, xb = xa[pinhole], xb[pinhole]
        _, mask = cv2.findFundamentalMat(dehomogenise(ua[pinhole]), dehomogenise(ub[pinhole]), cv2.USAC_ACCURATE, threshold_px,
                                         0.999, 10000)
        if mask is None:
            continue
        keep = mask.ravel().astype(bool)
        out[(a, b)] = (xa[keep], xb[keep])
    return out


class RectifyWarper:
    """Rectifies images: ONE ``cv2.remap`` per image, maps cached per camera.

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
