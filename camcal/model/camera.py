"""The pinhole camera ``P = K [R | -R c]`` and its conversions.

Conventions (DESIGN.md)
-----------------------
- ``x ~ P X``: ``R`` rotates world to camera (``cam_from_world``), ``c`` is
  the camera centre in world coordinates, so ``t = -R c``.
- Camera axes as OpenCV and COLMAP: +x right, +y down, +z forward.
- Pixel (0, 0) is the centre of the top-left pixel (OpenCV). COLMAP puts
  that centre at (0.5, 0.5): :func:`to_colmap` / :func:`from_colmap` and
  :func:`pixels_to_colmap` / :func:`pixels_from_colmap` convert.
- ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.

References
----------
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry in Computer
Vision, 2nd ed., sections 6.1-6.2 (camera matrix, decomposition by RQ).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError

__all__ = [
    "compose_P",
    "decompose_P",
    "camera_centre",
    "project_pinhole",
    "to_opencv",
    "from_opencv",
    "to_colmap",
    "from_colmap",
    "pixels_to_colmap",
    "pixels_from_colmap",
    "K_to_colmap",
    "K_from_colmap",
    "look_at",
    "random_rotation",
    "rotation_angle_deg",
    "chordal_mean_rotation",
    "similarity_Umeyama1991",
]


def compose_P(K: ArrayLike, R: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """The 3x4 projection matrix ``P = K [R | -R c]``.

    Parameters
    ----------
    K : array_like, shape (3, 3)
        Intrinsic matrix in pixels.
    R : array_like, shape (3, 3)
        Rotation world -> camera.
    c : array_like, shape (3,)
        Camera centre in world coordinates.

    Returns
    -------
    ndarray, shape (3, 4)

    Examples
    --------
    >>> import numpy as np
    >>> P = compose_P(np.eye(3), np.eye(3), [0.0, 0.0, -2.0])
    >>> P[:, 3].tolist()
    [0.0, 0.0, 2.0]
    """
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64).reshape(3)
    return K @ np.hstack([R, (-R @ c)[:, None]])


def camera_centre(P: ArrayLike) -> NDArray[np.float64]:
    """The camera centre: the right null vector of ``P``, dehomogenised.

    Raises
    ------
    CamcalError
        When the centre is at infinity (an affine camera).
    """
    P = _as_P(P)
    _, _, vt = np.linalg.svd(P)
    null = vt[-1]
    if abs(null[3]) < 1e-12 * np.linalg.norm(null[:3]):
        raise CamcalError("the camera centre is at infinity (affine camera): P[:, :3] is singular")
    return null[:3] / null[3]


def decompose_P(P: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Split ``P`` into ``K``, ``R``, ``c`` with ``fx, fy > 0`` and ``det(R) = +1``.

    ``P`` may carry any non-zero scale, negative included.

    Parameters
    ----------
    P : array_like, shape (3, 4)

    Returns
    -------
    K : ndarray, shape (3, 3)
        Upper triangular, positive diagonal, ``K[2, 2] = 1`` exactly.
    R : ndarray, shape (3, 3)
        Rotation world -> camera, ``det(R) = +1``.
    c : ndarray, shape (3,)
        Camera centre (right null vector of ``P``).

    Notes
    -----
    With ``M = P[:, :3]`` scaled so that ``det(M) > 0``, the RQ
    decomposition ``M = K R`` with the signs of K's diagonal made positive
    gives ``det(R) = +1`` (Hartley & Zisserman 2004, section 6.2.4).
    """
    P = _as_P(P)
    M = P[:, :3]
    det = np.linalg.det(M)
    if not np.isfinite(det) or abs(det) < 1e-12 * np.linalg.norm(M) ** 3:
        raise CamcalError("P[:, :3] is singular: not a finite projective camera")
    if det < 0:
        P = -P
        M = -M
    upper, ortho = scipy.linalg.rq(M)
    signs = np.sign(np.diag(upper))
    K = upper * signs[None, :]
    R = signs[:, None] * ortho
    K = K / K[2, 2]
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    K[2, 2] = 1.0
    return K, R, camera_centre(P)


def project_pinhole(K: ArrayLike, R: ArrayLike, c: ArrayLike, X: ArrayLike) -> NDArray[np.float64]:
    """Project world points without distortion: ``u ~ K R (X - c)``.

    Parameters
    ----------
    K, R, c : camera (see :func:`compose_P`).
    X : array_like, shape (N, 3)
        World points.

    Returns
    -------
    ndarray, shape (N, 2)
        Pixels; NaN for points on or behind the camera plane (depth <= 0).
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise CamcalError(f"world points must have shape (N, 3), got {X.shape}")
    cam = (X - np.asarray(c, dtype=np.float64).reshape(1, 3)) @ np.asarray(R, dtype=np.float64).T
    depth = cam[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        normalised = np.where(depth > 0, cam / depth, np.nan)
    pixels = normalised @ np.asarray(K, dtype=np.float64).T
    return pixels[:, :2]


def to_opencv(R: ArrayLike, c: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """OpenCV's ``(rvec, tvec)``: ``rvec`` = Rodrigues(R), ``tvec = -R c``.

    The rotation vector comes from SciPy, which stays accurate near a half
    turn where ``cv2.Rodrigues(R)`` loses digits.
    """
    R = np.asarray(R, dtype=np.float64)
    rvec = Rotation.from_matrix(R).as_rotvec()
    return rvec, -R @ np.asarray(c, dtype=np.float64).reshape(3)


def from_opencv(rvec: ArrayLike, tvec: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`to_opencv`: ``R`` = Rodrigues(rvec), ``c = -R^T tvec``."""
    R = Rotation.from_rotvec(np.asarray(rvec, dtype=np.float64).reshape(3)).as_matrix()
    return R, -R.T @ np.asarray(tvec, dtype=np.float64).reshape(3)


def to_colmap(R: ArrayLike, c: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """COLMAP's ``cam_from_world`` as (quaternion xyzw, translation).

    The quaternion is in Eigen's (x, y, z, w) order, as
    ``pycolmap.Rotation3d(quat_xyzw)`` takes it; ``t = -R c``.
    """
    R = np.asarray(R, dtype=np.float64)
    quat = Rotation.from_matrix(R).as_quat()
    return quat, -R @ np.asarray(c, dtype=np.float64).reshape(3)


def from_colmap(quat_xyzw: ArrayLike, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`to_colmap`: returns ``(R, c)``."""
    R = Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix()
    return R, -R.T @ np.asarray(t, dtype=np.float64).reshape(3)


def pixels_to_colmap(points: ArrayLike) -> NDArray[np.float64]:
    """camcal pixels (centre of top-left pixel at 0) -> COLMAP's (at 0.5)."""
    return np.asarray(points, dtype=np.float64) + 0.5


def pixels_from_colmap(points: ArrayLike) -> NDArray[np.float64]:
    """COLMAP pixels (centre of top-left pixel at 0.5) -> camcal's (at 0)."""
    return np.asarray(points, dtype=np.float64) - 0.5


def K_to_colmap(K: ArrayLike) -> NDArray[np.float64]:
    """The same camera's K in COLMAP's pixel convention (principal point + 0.5)."""
    K = np.array(K, dtype=np.float64)
    K[:2, 2] += 0.5
    return K


def K_from_colmap(K: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`K_to_colmap`."""
    K = np.array(K, dtype=np.float64)
    K[:2, 2] -= 0.5
    return K


def look_at(centre: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> NDArray[np.float64]:
    """The rotation world -> camera of a camera at ``centre`` looking at ``target``.

    Rows of ``R`` are the camera axes in world coordinates: +z towards the
    target, +y down (against ``up``), +x = y x z to the right.
    """
    centre = np.asarray(centre, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - centre
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise CamcalError("look_at: target coincides with the camera centre")
    z = forward / norm
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-12:
        raise CamcalError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.vstack([x, y, z])


def random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    """A rotation drawn uniformly from SO(3)."""
    return Rotation.random(random_state=rng).as_matrix()


def rotation_angle_deg(R: ArrayLike) -> float:
    """The angle of a rotation matrix in degrees, in [0, 180].

    Notes
    -----
    ``theta = arccos((trace(R) - 1) / 2)`` (the trace is clipped to the valid
    range against rounding).

    Examples
    --------
    >>> round(rotation_angle_deg(Rotation.from_euler("z", 30, degrees=True).as_matrix()), 9)
    30.0
    """
    R = np.asarray(R, dtype=np.float64)
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def chordal_mean_rotation(rotations: ArrayLike) -> NDArray[np.float64]:
    """The chordal L2 mean of rotation matrices (K, 3, 3).

    Notes
    -----
    The rotation nearest (Frobenius) to the arithmetic mean of the
    matrices, ``argmin_R sum_k |R - R_k|_F^2`` (Hartley, Trumpf, Dai & Li
    2013, "Rotation averaging", IJCV 103(3)): the projection of
    ``sum_k R_k = U S V^T`` onto SO(3), ``U diag(1, 1, det(U V^T)) V^T``.
    SciPy's ``Rotation.mean`` computes it (from quaternions).

    Examples
    --------
    >>> a, b = (Rotation.from_euler("z", d, degrees=True).as_matrix() for d in (10, 30))
    >>> round(rotation_angle_deg(chordal_mean_rotation([a, b])), 9)
    20.0
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    if rotations.ndim != 3 or rotations.shape[1:] != (3, 3) or len(rotations) == 0:
        raise CamcalError(f"rotations must have shape (K, 3, 3) with K >= 1, got {rotations.shape}")
    return Rotation.from_matrix(rotations).mean().as_matrix()


def similarity_Umeyama1991(source: ArrayLike, target: ArrayLike) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """The similarity ``s, R, t`` minimising ``sum |target - (s R source + t)|^2``.

    Parameters
    ----------
    source, target : array_like, shape (N, 3)
        Corresponding points, N >= 3 not collinear.

    Returns
    -------
    s : float
    R : ndarray, shape (3, 3)
        A proper rotation (det +1).
    t : ndarray, shape (3,)

    References
    ----------
    S. Umeyama, "Least-squares estimation of transformation parameters
    between two point patterns", IEEE TPAMI 13(4), 1991.
    """
    source, target = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    mu_s, mu_t = source.mean(0), target.mean(0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    u, d, vt = np.linalg.svd(cov)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / np.mean(np.sum((source - mu_s) ** 2, axis=1)))
    return scale, R, mu_t - scale * R @ mu_s


def _as_P(P: ArrayLike) -> NDArray[np.float64]:
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 4):
        raise CamcalError(f"P must have shape (3, 4), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise CamcalError("P contains NaN or infinite values")
    return P
