"""Uncertainty of a rectified pair: the sigma of its vertical disparity and of the depth, per rectified pixel.

A calibrated rectification (``H_k = K_rect R_rect R_k^T K_k^-1``) is built
from the estimated cameras; the true cameras differ from them by the
calibration's error, so a scene point lands on rows that differ by a
vertical disparity, and the depth triangulated from its horizontal
disparity is off. For the pixel ``x_r`` of the first camera's rectified
image and a depth ``D`` along the rectified axis (or infinity), the scene
point is ``X = c_a + W^T (D K_rect^-1 x_r)`` (``W`` world -> rectified, the
rotation ``K_rect^-1 H_a K_a R_a``); each camera ``k`` of the pair images
it with perturbed parameters ``theta + dtheta`` (its intrinsics; its pose
``cam_from_reference`` as ``R' = exp([rho]x) R``, ``t' = t + tau``, as in
:mod:`camcal.geometry.uncertainty`) and the estimated rectification carries
that pixel to ``x_k = H_k K_k r_k`` (``r_k`` its estimated ray). Then::

    v = y_a - y_b                      (vertical disparity, rectified pixels)
    Z = f_rect B_x / (x_a - x_b)       (B_x: the baseline along the rectified x axis)
    sigma_v^2 = J_v Sigma J_v^T,  sigma_Z^2 = J_Z Sigma J_Z^T

with ``J`` central differences over the parameters of both cameras (each
stepped by 1e-3 of its sigma) and ``Sigma`` their joint covariance: the
later camera's ``quality.covariance`` carries the earlier one's intrinsics
and pose under ``NAME.param`` (``calibrate board`` writes them); without
them the two cameras' blocks are taken as independent and
:attr:`PairSigma.cross_covariance` says so. The board gauge drops out: at
the estimate, moving ``X`` moves both views consistently, so neither ``v``
nor the error of ``Z`` changes to first order. What the figures cover is
the calibration's sampling noise, not model error.

Conventions: pixel (0, 0) is the centre of the top-left pixel; camera axes
+x right, +y down, +z forward; maps are pixel for pixel with the first
camera's rectified image (:class:`~camcal.geometry.rectify.RectifyWarper`).

References
----------
Fusiello, A., Trucco, E. & Verri, A. (2000). A compact algorithm for
rectification of stereo pairs. Machine Vision and Applications 12(1).
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry, 2nd ed.,
section 5.2 (forward propagation of covariance).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.uncertainty import (MAP_STEP_PX, POSE, SigmaSummary, camera_covariance, perturbed_lens,
                                         sigma_grid, summarise_sigma, upsample_grid)
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera

__all__ = ["PairSigma", "pair_covariance", "rectified_pair_sigma", "rectified_world_rotation"]


@dataclass(frozen=True, eq=False)
class PairSigma:
    """Sigma maps of a rectified pair, pixel for pixel with the first camera's rectified image.

    Attributes
    ----------
    first, second : str
        Camera names.
    vertical_px : ndarray, shape (H, W), float32
        Sigma of the vertical disparity (rectified pixels); NaN without a source pixel.
    depth : ndarray or None
        Sigma of the depth (rig units) at :attr:`distance`; None at infinity.
    distance : float or None
        Depth along the rectified axis of the scene points (None: infinity).
    cross_covariance : bool
        False when the rig file holds no covariance between the two cameras (taken as independent).
    units : str
        The rig's length unit.
    """

    first: str
    second: str
    vertical_px: NDArray[np.float32]
    depth: NDArray[np.float32] | None
    distance: float | None
    cross_covariance: bool
    units: str = "m"

    def vertical_summary(self) -> SigmaSummary:
        """Worst / median / corners of :attr:`vertical_px`."""
        return summarise_sigma(self.vertical_px, self.distance, "vertical disparity sigma")

    def depth_summary(self) -> SigmaSummary | None:
        """Worst / median / corners of :attr:`depth` (None at infinity)."""
        if self.depth is None:
            return None
        return summarise_sigma(self.depth, self.distance, "depth sigma", self.units)

    def describe(self) -> str:
        """Readable lines: the pair, each summary, and a note when the cameras are taken as independent."""
        lines = [f"{self.first}-{self.second}: {self.vertical_summary().describe()}"]
        depth = self.depth_summary()
        if depth is not None:
            lines.append(f"{self.first}-{self.second}: {depth.describe()}")
        if not self.cross_covariance:
            lines.append(f"{self.first}-{self.second}: the rig file holds no covariance between the two cameras; "
                         "taken as independent (calibrate the pair again with `camcal calibrate board` to get it)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The figures for ``--json``."""
        depth = self.depth_summary()
        return {"first": self.first, "second": self.second, "vertical_disparity": self.vertical_summary().to_dict(),
                "depth": None if depth is None else depth.to_dict(), "cross_covariance": self.cross_covariance}


def _own(camera: Camera, name: str) -> str | None:
    """``camera``'s parameter behind a name of its own covariance (``fx``), or None for the gauge / other cameras."""
    if "." in name:
        return None
    return None if name.startswith("gauge_") else name


def pair_covariance(first: Camera, second: Camera) -> tuple[ParameterCovariance, bool]:
    """The joint covariance of two cameras' intrinsics and poses, under ``NAME.param`` names.

    Taken from the camera whose ``quality.covariance`` holds the other's
    parameters (module docstring); otherwise the two own blocks side by
    side (no cross terms) and False.
    """
    for holder, other in ((second, first), (first, second)):
        covariance = camera_covariance(holder)
        prefix = f"{other.name}."
        if not any(name.startswith(prefix) for name in covariance.names):
            continue
        keep = [(k, f"{holder.name}.{name}") for k, name in enumerate(covariance.names) if _own(holder, name)]
        keep += [(k, name) for k, name in enumerate(covariance.names) if name.startswith(prefix)]
        index = [k for k, _ in keep]
        return ParameterCovariance(tuple(n for _, n in keep), covariance.array[np.ix_(index, index)]), True
    names, blocks = [], []
    for camera in (first, second):
        covariance = camera_covariance(camera)
        index = [k for k, name in enumerate(covariance.names) if _own(camera, name)]
        names += [f"{camera.name}.{covariance.names[k]}" for k in index]
        blocks.append(covariance.array[np.ix_(index, index)])
    matrix = np.zeros((len(names), len(names)))
    n = len(blocks[0])
    matrix[:n, :n], matrix[n:, n:] = blocks
    return ParameterCovariance(tuple(names), matrix), False


def rectified_world_rotation(camera: Camera) -> NDArray[np.float64]:
    """``W``, world -> rectified: ``K_rect^-1 H K R`` scaled to a rotation; an error when it is none (a projective
    rectification, e.g. Hartley 1999, or one refined with its own focal lengths)."""
    rect = camera.rectification
    if rect is None:
        raise CamcalError(f"camera {camera.name!r} has no rectification: run `camcal rectify` first")
    M = np.linalg.inv(rect.K_rect) @ rect.H @ camera.K
    M = M / np.cbrt(np.linalg.det(M))
    if not np.allclose(M @ M.T, np.eye(3), atol=1e-6):
        raise CamcalError(f"camera {camera.name!r}: its rectification is not a rotation of the calibrated camera "
                          "(sigma needs `camcal rectify --method camera` without --refine)")
    return M @ np.asarray(camera.R, dtype=np.float64)


def _observe(camera: Camera, estimated: Camera, X: NDArray, at_infinity: bool) -> NDArray[np.float64]:
    """Rectified pixels (N, 2) of points ``X`` (directions at infinity) imaged by ``camera``, carried by
    ``estimated``'s lens and rectification."""
    R = np.asarray(camera.R, dtype=np.float64)
    p = X @ R.T if at_infinity else (X - camera.c) @ R.T
    q = camera.distortion.project_rays(p, camera.K)
    rays = estimated.distortion.rays_from_pixels(q, estimated.K)
    mapped = rays @ (estimated.rectification.H @ estimated.K).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return mapped[:, :2] / mapped[:, 2:3]


def _moved(camera: Camera, name: str, step: float) -> Camera:
    """``camera`` with parameter ``name`` (an intrinsic, or its pose ``rx .. tz``) moved by ``step``."""
    if name not in POSE:
        K, distortion = perturbed_lens(camera, name, step)
        return dataclasses.replace(camera, K=K, distortion=distortion)
    R = np.asarray(camera.R, dtype=np.float64)
    t = -R @ np.asarray(camera.c, dtype=np.float64)
    k = POSE.index(name)
    if k < 3:
        R = Rotation.from_rotvec(step * np.eye(3)[k]).as_matrix() @ R
    else:
        t = t + step * np.eye(3)[k - 3]
    return dataclasses.replace(camera, R=R, c=-R.T @ t)


def _has_source(camera: Camera) -> NDArray[np.bool_]:
    """(H, W) of the rectified canvas: True where the rectified pixel samples the camera's image
    (``distort(H^-1 x_r)`` in front and inside, as the rectified image has a value)."""
    rect = camera.rectification
    width, height = rect.image_size
    v, u = np.mgrid[0:height, 0:width]
    back = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]) @ np.linalg.inv(rect.H).T
    with np.errstate(invalid="ignore", divide="ignore"):
        source = camera.distortion.distort(back[:, :2] / back[:, 2:3], camera.K)
        inside = np.all((source >= -0.5) & (source <= np.array(camera.image_size) - 0.5), axis=1)
    return ((back[:, 2] > 0) & inside).reshape(height, width)


def rectified_pair_sigma(first: Camera, second: Camera, distance: float | None = None, step: float = MAP_STEP_PX,
                         units: str = "m") -> PairSigma:
    """Sigma maps of the vertical disparity and (at ``distance``) of the depth of a rectified pair.

    Parameters
    ----------
    first, second : Camera
        Rectified by ``camcal rectify --method camera`` (a rotation and the
        shared ``K_rect``), each with ``quality.covariance``.
    distance : float, optional
        Depth of the scene points along the rectified viewing axis (rig
        units); None (default) is infinity, where the depth has no sigma.
    step : float
        The maps are exact on a grid every ``step`` pixels, bilinear between.
    units : str
        The rig's length unit (for the depth summary).

    Returns
    -------
    PairSigma
        Maps on the first camera's rectified canvas (module docstring).
    """
    if distance is not None and not (np.isfinite(distance) and distance > 0):
        raise CamcalError(f"distance must be a positive number (or infinity), got {distance!r}")
    W = rectified_world_rotation(first)
    rectified_world_rotation(second)
    covariance, cross = pair_covariance(first, second)
    rect = first.rectification
    width, height = rect.image_size
    xs, ys = sigma_grid((width, height), step)
    gx, gy = np.meshgrid(xs, ys)
    rays = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)]) @ np.linalg.inv(rect.K_rect).T
    at_infinity = distance is None
    X = rays @ W if at_infinity else np.asarray(first.c, dtype=np.float64) + distance * (rays @ W)
    f_rect = rect.K_rect[0, 0]
    baseline_x = float((W @ (np.asarray(second.c, float) - np.asarray(first.c, float)))[0])
    cameras = {first.name: first, second.name: second}

    def figures(moved: dict[str, Camera]) -> NDArray[np.float64]:
        a = _observe(moved[first.name], first, X, at_infinity)
        b = _observe(moved[second.name], second, X, at_infinity)
        if at_infinity:  # no depth to triangulate (NaN, unlike inf, differences without a warning)
            depth = np.full(len(a), np.nan)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = f_rect * baseline_x / (a[:, 0] - b[:, 0])
        return np.column_stack([a[:, 1] - b[:, 1], depth])

    sigmas = np.sqrt(np.clip(np.diag(covariance.array), 0.0, None))
    J = np.zeros((len(X), 2, len(covariance.names)))
    for k, label in enumerate(covariance.names):
        owner, _, name = label.partition(".")
        if sigmas[k] == 0.0 or owner not in cameras:
            continue
        h = 1e-3 * sigmas[k]
        plus = figures({**cameras, owner: _moved(cameras[owner], name, h)})
        minus = figures({**cameras, owner: _moved(cameras[owner], name, -h)})
        J[:, :, k] = (plus - minus) / (2.0 * h)
    variance = np.einsum("nip,pq,niq->ni", J, covariance.array, J)
    sigma = np.sqrt(np.clip(variance, 0.0, None)).reshape(len(ys), len(xs), 2)
    missing = ~_has_source(first)
    vertical = upsample_grid(sigma[..., 0], xs, ys, (width, height), missing)
    depth = None if at_infinity else upsample_grid(sigma[..., 1], xs, ys, (width, height), missing)
    return PairSigma(first.name, second.name, vertical, depth, distance, cross, units)
