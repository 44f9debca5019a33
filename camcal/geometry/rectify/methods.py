"""Rectification methods: calibrated, Nozick 2011 N-view, Hartley 1999; :func:`rectify` dispatches.

Each method is described in the package docstring (:mod:`camcal.geometry.rectify`).

References
----------
Fusiello, A., Trucco, E. & Verri, A. (2000). A compact algorithm for
rectification of stereo pairs. Machine Vision and Applications 12(1).
Hartley, R. I. (1999). Theory and practice of projective rectification.
International Journal of Computer Vision 35(2), 115-127.
Nozick, V. (2011). Multiple view image rectification. Proc. IEEE-ISAS
2011, International Symposium on Access Spaces, 277-282.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.rectify.frame import (
    calibrated_start,
    cameras_to_rectify,
    check_alpha,
    finish_rectification,
    fov_half_angle,
    mean_focal,
)
from camcal.geometry.rectify.model import (
    MAX_OFFSET_RATIO,
    METHODS,
    Matches,
    RectificationResult,
    apply_homography,
    dehomogenise,
    pixel_rays,
)
from camcal.model.rig import Camera, Rig

__all__ = ["rectify", "rectify_Hartley1999", "rectify_Nozick2011", "rectify_calibrated"]

_DAMPING = 1e-3


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
    alpha = check_alpha(alpha)
    cameras = cameras_to_rectify(rig, names)
    half_angle = fov_half_angle(cameras, max_fov_deg)
    R_rect, ratio = calibrated_start(cameras, max_offset_ratio, rig.units, half_angle)
    frames = [R_rect @ camera.R.T @ np.linalg.inv(camera.K) for camera in cameras]
    return finish_rectification(rig, cameras, frames, alpha, "camera", R_rect, ratio, matches, half_angle)


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
        xa = pixel_rays(cameras[index[a]], value[0])
        xb = pixel_rays(cameras[index[b]], value[1])
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
    alpha = check_alpha(alpha)
    cameras = cameras_to_rectify(rig, names)
    half_angle = fov_half_angle(cameras, max_fov_deg)
    R_rect, ratio = calibrated_start(cameras, max_offset_ratio, rig.units, half_angle)
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
    focal = mean_focal(cameras)

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
    return finish_rectification(rig, cameras, frames, alpha, "Nozick 2011", R_rect, ratio, matches, half_angle)


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
    alpha = check_alpha(alpha)
    cameras = cameras_to_rectify(rig, names)
    if len(cameras) != 2:
        raise CamcalError(f"Hartley 1999 rectifies two views, got {len(cameras)} cameras (pick two by name)")
    first, second = cameras
    pairs = _pairs(cameras, matches)
    if not pairs:
        raise CamcalError(f"no matches between {first.name!r} and {second.name!r}")
    rays1 = np.vstack([xa if i == 0 else xb for i, _, xa, xb in pairs])
    rays2 = np.vstack([xb if i == 0 else xa for i, _, xa, xb in pairs])
    half_angle = fov_half_angle(cameras, max_fov_deg)
    least_cos = 0.0 if half_angle is None else math.cos(half_angle)
    with np.errstate(invalid="ignore"):
        inside = (rays1[:, 2] > least_cos) & (rays2[:, 2] > least_cos)
    x1 = dehomogenise(rays1[inside] @ first.K.T)
    x2 = dehomogenise(rays2[inside] @ second.K.T)
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
    p1 = dehomogenise(apply_homography(H0, x1))
    p2 = dehomogenise(apply_homography(H2, x2))
    design = np.column_stack([p1, np.ones(len(p1))])
    abc, *_ = np.linalg.lstsq(design, p2[:, 0], rcond=None)
    H_A = np.array([abc, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    H1 = H_A @ H0
    if np.linalg.det(H1) <= 0:
        raise CamcalError("the matches rectify only with a mirrored image: check that the cameras are not swapped")
    inlier_matches = {(first.name, second.name): (first.distortion.distort(x1, first.K),
                                                  second.distortion.distort(x2, second.K))}
    return finish_rectification(rig, cameras, [H1, H2], alpha, "Hartley 1999", None, float("nan"),
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
