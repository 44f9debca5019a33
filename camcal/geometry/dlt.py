"""Camera calibration from 3D-2D correspondences: normalised DLT, then LM.

Conventions: ``x ~ K [R | -R c] X``; pixel (0, 0) is the centre of the
top-left pixel; camera axes x right, y down, z forward.

References
----------
Abdel-Aziz, Y. I. & Karara, H. M. (1971). Direct linear transformation into
object space coordinates in close-range photogrammetry.
Hartley, R. (1997). In defense of the eight-point algorithm. IEEE TPAMI
(normalisation).
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry, 2nd ed.,
algorithm 7.1 (normalised DLT + minimisation of geometric error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.camera import compose_P, decompose_P, project_pinhole
from camcal.model.distortion import Distortion
from camcal.model.quality import Quality
from camcal.model.rig import Camera

__all__ = ["MIN_CORRESPONDENCES", "PARAMETER_NAMES", "DLTResult", "dlt_P", "calibrate_dlt"]

MIN_CORRESPONDENCES = 6
_DEGENERATE_RATIO = 1e-6
#: Order of the refined parameters in :attr:`DLTResult.covariance`.
PARAMETER_NAMES = ("fx", "fy", "s", "cx", "cy", "rx", "ry", "rz", "c_x", "c_y", "c_z")


@dataclass(frozen=True)
class DLTResult:
    """A camera calibrated from 3D-2D correspondences.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
    R : ndarray, shape (3, 3)
        Rotation world -> camera.
    c : ndarray, shape (3,)
        Camera centre in world coordinates.
    residuals_px : ndarray, shape (N, 2)
        Reprojection residuals ``project(X) - x`` in pixels.
    rms_px, worst_px : float
        RMS and largest reprojection error (norm per point), in pixels.
    covariance : ndarray, shape (11, 11)
        ``sigma^2 (J^T J)^-1`` of (fx, fy, s, cx, cy, rotation increment
        (3, radians), c (3)), with ``sigma^2`` estimated from the residuals:
        it measures sampling noise, not model error.
    """

    K: NDArray[np.float64]
    R: NDArray[np.float64]
    c: NDArray[np.float64]
    residuals_px: NDArray[np.float64]
    rms_px: float
    worst_px: float
    covariance: NDArray[np.float64]

    @property
    def P(self) -> NDArray[np.float64]:
        """``K [R | -R c]``."""
        return compose_P(self.K, self.R, self.c)

    def to_camera(self, name: str, image_size: tuple[int, int]) -> Camera:
        """The calibrated camera (no distortion), with its fit quality."""
        return Camera(
            name=name,
            image_size=image_size,
            K=self.K,
            distortion=Distortion.none(),
            R=self.R,
            c=self.c,
            quality=Quality(
                rms_px=self.rms_px,
                worst_px=self.worst_px,
                n_observations=len(self.residuals_px),
                sigma={"skew" if k == "s" else k: v for k, v in self.sigmas.items() if k in ("fx", "fy", "s", "cx", "cy")},
            ),
        )

    @property
    def sigmas(self) -> dict[str, float]:
        """One-sigma uncertainty of each refined parameter, by name."""
        return dict(zip(PARAMETER_NAMES, np.sqrt(np.clip(np.diag(self.covariance), 0.0, None)).tolist()))


def _check_inputs(X: ArrayLike, x: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    X = np.asarray(X, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise CamcalError(f"3D points must have shape (N, 3), got {X.shape}")
    if x.ndim != 2 or x.shape[1] != 2:
        raise CamcalError(f"image points must have shape (N, 2), got {x.shape}")
    if len(X) != len(x):
        raise CamcalError(f"got {len(X)} 3D points but {len(x)} image points")
    if len(X) < MIN_CORRESPONDENCES:
        raise CamcalError(f"need at least {MIN_CORRESPONDENCES} correspondences, got {len(X)}")
    bad = ~(np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(x), axis=1))
    if bad.any():
        rows = ", ".join(str(i) for i in np.flatnonzero(bad)[:5])
        raise CamcalError(f"non-finite coordinates (NaN or inf) in correspondence(s) {rows}")
    spread = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if spread[0] == 0.0 or spread[1] / spread[0] < _DEGENERATE_RATIO:
        raise CamcalError("the 3D points are collinear (or identical): DLT needs points spanning 3D")
    if spread[2] / spread[0] < _DEGENERATE_RATIO:
        raise CamcalError(
            "the 3D points are coplanar: DLT needs points spanning 3D "
            "(calibrate a planar target with `camcal calibrate board`)"
        )
    image_spread = np.linalg.svd(x - x.mean(axis=0), compute_uv=False)
    if image_spread[0] == 0.0 or image_spread[1] / image_spread[0] < _DEGENERATE_RATIO:
        raise CamcalError("the image points are collinear (or identical)")
    return X, x


def _normalising_transform(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Similarity moving the centroid to 0 and the mean distance to sqrt(dim)."""
    dim = points.shape[1]
    centroid = points.mean(axis=0)
    scale = np.sqrt(dim) / np.mean(np.linalg.norm(points - centroid, axis=1))
    T = np.eye(dim + 1)
    T[:dim, :dim] *= scale
    T[:dim, dim] = -scale * centroid
    return T


def dlt_P(X: ArrayLike, x: ArrayLike) -> NDArray[np.float64]:
    """The linear (normalised) DLT estimate of ``P`` from n >= 6 correspondences.

    Parameters
    ----------
    X : array_like, shape (N, 3)
        World points, not all coplanar.
    x : array_like, shape (N, 2)
        Their pixels.

    Returns
    -------
    ndarray, shape (3, 4)
        ``P`` up to scale, ``||P||_F = 1``.

    Notes
    -----
    Each correspondence gives two rows of ``A p = 0``:
    ``[X^T, 0, -u X^T]`` and ``[0, X^T, -v X^T]`` (homogeneous ``X``);
    ``p`` is the right singular vector of the smallest singular value,
    computed on Hartley-normalised coordinates and denormalised by
    ``P = T_2^-1 P_n T_3``.
    """
    X, x = _check_inputs(X, x)
    T3 = _normalising_transform(X)
    T2 = _normalising_transform(x)
    Xn = (np.hstack([X, np.ones((len(X), 1))]) @ T3.T)
    xn = (np.hstack([x, np.ones((len(x), 1))]) @ T2.T)[:, :2]
    n = len(X)
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xn
    A[0::2, 8:12] = -xn[:, 0:1] * Xn
    A[1::2, 4:8] = Xn
    A[1::2, 8:12] = -xn[:, 1:2] * Xn
    _, singular, vt = np.linalg.svd(A)
    if singular[-2] < _DEGENERATE_RATIO * singular[0]:
        raise CamcalError("degenerate configuration: the DLT null space is not one-dimensional")
    P = np.linalg.inv(T2) @ vt[-1].reshape(3, 4) @ T3
    return P / np.linalg.norm(P)


def _camera_from_parameters(params: NDArray[np.float64], R0: NDArray[np.float64]):
    fx, fy, s, cx, cy = params[:5]
    K = np.array([[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    R = Rotation.from_rotvec(params[5:8]).as_matrix() @ R0
    return K, R, params[8:11]


def calibrate_dlt(X: ArrayLike, x: ArrayLike) -> DLTResult:
    """Calibrate K, R, c from 3D-2D correspondences.

    The linear estimate of :func:`dlt_P` is decomposed and refined by
    Levenberg-Marquardt on the reprojection error over (fx, fy, s, cx, cy,
    rotation, centre) (Hartley & Zisserman 2004, algorithm 7.1).

    Parameters
    ----------
    X : array_like, shape (N, 3)
        World points (N >= 6, not coplanar), in the rig's units.
    x : array_like, shape (N, 2)
        Pixels, (0, 0) at the centre of the top-left pixel.

    Returns
    -------
    DLTResult
        K (with skew), R, c, residuals and their RMS, covariance.

    Raises
    ------
    CamcalError
        Fewer than 6 points, NaN / inf, coplanar or collinear 3D points,
        points behind the estimated camera.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    >>> X = rng.uniform(-1, 1, (20, 3)) + [0, 0, 6]
    >>> x = project_pinhole(K, np.eye(3), np.zeros(3), X)
    >>> result = calibrate_dlt(X, x)
    >>> bool(np.allclose(result.K, K, atol=1e-6))
    True
    """
    X, x = _check_inputs(X, x)
    K, R, c = decompose_P(dlt_P(X, x))
    depth = ((X - c) @ R.T)[:, 2]
    if np.count_nonzero(depth > 0) < len(X) / 2:
        raise CamcalError(
            "the solved camera sees the points from behind: are u and v swapped or mirrored?"
        )

    def residuals(params: NDArray[np.float64]) -> NDArray[np.float64]:
        K_, R_, c_ = _camera_from_parameters(params, R)
        return (project_pinhole(K_, R_, c_, X) - x).ravel()

    start = np.concatenate([[K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]], np.zeros(3), c])
    solution = least_squares(residuals, start, method="lm", x_scale="jac")
    params, jacobian = solution.x, solution.jac
    K, R, c = _camera_from_parameters(params, R)
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    # Re-orthonormalise the rotation exactly (from_rotvec composes to ~1e-16).
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    res = (project_pinhole(K, R, c, X) - x)
    dof = max(2 * len(X) - len(params), 1)
    sigma2 = float(np.sum(res**2)) / dof
    covariance = sigma2 * np.linalg.pinv(jacobian.T @ jacobian)
    norms = np.linalg.norm(res, axis=1)
    return DLTResult(
        K=K,
        R=R,
        c=np.asarray(c, dtype=np.float64).copy(),
        residuals_px=res,
        rms_px=float(np.sqrt(np.mean(norms**2))),
        worst_px=float(norms.max()),
        covariance=covariance,
    )
