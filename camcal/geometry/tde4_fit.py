"""Board calibration with 3DEqualizer's lens models (:mod:`camcal.model.tde4`): the lens and K refined on corners.

COLMAP's bundle adjuster, camcal's engine for its other models, has no 3DE
model, so these are fitted here with ``scipy.optimize.least_squares``, from a
calibration of another model (``opencv``, or ``kannala-brandt`` for the
fisheye):

1. The start lens: the 3DE coefficients whose model function (LDPK's
   ``undistort``) best maps a grid of distorted pixels over the image to
   where the calibrated lens undistorts them (closed form on both sides,
   ``least_squares`` from the identity; rays within 75 degrees of the
   axis, each weighed by ``1 / (1 + tan^2 theta)`` so that an error counts
   as the angle it makes, not as the pinhole pixels it spans at the rim).
2. One joint refinement of ``fx, fy, cx, cy``, the fitted coefficients and
   every view's board pose, minimising the reprojection error in DISTORTED
   pixels ``sum rho(|distort(K (R X + t)) - x|^2)`` (camcal's
   :meth:`~camcal.model.distortion.Distortion.distort`, the Newton inverse
   of LDPK's model), with the Jacobian's sparsity (a pose touches its own
   view's corners only) for the finite differences.

Which coefficients are fitted (:data:`FITTED_PARAMS`): those the corners can
tell from ``K``. The pixel aspect is ``fy / fx`` (a 2x anamorphic squeeze
is ``fy = 2 fx``), so ``squeeze_x``, ``squeeze_y`` and the cylindric
bending, which only rescale the undistorted image along an axis, are held
at their defaults, as are the cylindric direction (held at 0) and the
classic model's ``anamorphic_squeeze`` (held at 1). The anamorphic model's
lens rotation is fitted (from 0): with a pixel aspect ``pa != 1`` its
linear part ``Rot P Rot^-1 P^-1`` shears the image, which no zero-skew
``K`` and no board pose takes up (a 2x lens turned by 0.5 degrees held at
0 leaves 0.4 px RMS and the squeeze 0.09 % off). With square pixels the
rotation only turns the axes of the lens's anisotropic terms, which a
nearly round lens hardly has: the corners then barely determine it (6 +/- 4
degrees on a synthetic square-pixel lens, and on a real action camera the
free fit wandered until corners left the image). So the lens is first
refined with the rotation held at 0; the rotation is freed, from there,
only when its standard error at 0 (the free problem's covariance at the held
solution) is within :data:`MAX_ROTATION_SIGMA_DEG`; :attr:`Tde4Fit.held` says why.

Uncertainty: ``Sigma = sigma^2 (J^T J)^-1`` at the solution with
``sigma^2 = 2 cost / (m - n)``, the board poses marginalised out (sampling
noise of the corners only, as for camcal's other models).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import dataclasses
from dataclasses import dataclass
from types import MappingProxyType

import cv2
import numpy as np
import scipy.optimize
import scipy.sparse
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion, frame_grid
from camcal.model.tde4 import FILMBACK_KEYS, TDE4_MODELS

__all__ = ["FITTED_PARAMS", "MAX_ROTATION_SIGMA_DEG", "Tde4Fit", "fit_tde4_lens", "nearest_tde4_lens"]

#: The coefficients a board calibration fits for each 3DE model (the others held at LDPK's defaults).
FITTED_PARAMS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "3de-classic": ("distortion", "curvature_x", "curvature_y", "quartic_distortion"),
    "3de4-radial-deg4": ("c2", "u2", "v2", "c4", "u4", "v4"),
    "3de4-anamorphic-deg4": (*(f"c{axis}{term}" for term in ("02", "22", "04", "24", "44") for axis in "xy"),
                             "lens_rotation_deg"),
    "3de4-fisheye-deg8": ("c2", "c4", "c6", "c8"),
})
#: The anamorphic lens rotation is held at 0 when its free fit's standard error exceeds this (degrees): a rotation
#: known no better than a degree is the noise turning the lens's anisotropy, not a measurement of the lens.
MAX_ROTATION_SIGMA_DEG = 1.0
#: camcal's robust loss names (Ceres') -> scipy's.
_LOSSES = {"trivial": "linear", "huber": "huber", "soft_l1": "soft_l1", "cauchy": "cauchy"}
#: What a corner the lens cannot image (NaN) costs in the refinement, in pixels.
_LOST_PX = 1e3
#: The start lens is fitted on the pixels whose ray is within this tangent of the axis (75 degrees).
_MAX_START_TAN = 3.7


@dataclass(frozen=True)
class Tde4Fit:
    """A camera's K, 3DE lens and board poses refined on its corners.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Zero skew.
    distortion : Distortion
        The 3DE lens (film back: the image size).
    poses : tuple of (ndarray (3, 3), ndarray (3,))
        ``cam_from_board`` ``(R, t)`` of each view, in the order given.
    residuals_px : ndarray, shape (M, 2)
        ``projected - detected`` of every corner, views in order.
    covariance : ndarray, shape (P, P)
        Of :attr:`parameter_names`, the poses marginalised out.
    parameter_names : tuple of str
        ``fx, fy, cx, cy`` and the fitted coefficients (:data:`FITTED_PARAMS`, but a held lens rotation).
    held : str
        Why the anamorphic lens rotation was held at 0 (empty when fitted or not in the model).
    """

    K: NDArray[np.float64]
    distortion: Distortion
    poses: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    residuals_px: NDArray[np.float64]
    covariance: NDArray[np.float64]
    parameter_names: tuple[str, ...]
    held: str = ""


def nearest_tde4_lens(source: Distortion, K: NDArray[np.float64], image_size: tuple[int, int],
                      model: str, fitted: Sequence[str] | None = None) -> Distortion:
    """The 3DE lens of ``model`` (its ``fitted`` coefficients, default :data:`FITTED_PARAMS`, the rest at LDPK's
    defaults) that undistorts a grid of pixels over the image as ``source`` does, with the same ``K`` (step 1 of
    the module docstring).

    The fit is in the undistorting direction, both sides closed form, on the pixels whose ray ``source`` puts
    within 75 degrees of the axis, each error weighed by ``1 / (1 + tan^2 theta)`` (the angle it makes).

    Examples
    --------
    >>> K = np.array([[1000.0, 0, 639.5], [0, 1000.0, 359.5], [0, 0, 1]])
    >>> lens = nearest_tde4_lens(Distortion("polynomial", {"k1": -0.05, "k2": 0.0}), K, (1280, 720),
    ...                          "3de4-radial-deg4")
    >>> bool(lens.params["c2"] > 0.0)  # barrel in camcal's direction: its undistortion pushes points outward
    True
    """
    if model not in TDE4_MODELS:
        raise CamcalError(f"not a 3DE model: {model!r}, expected one of: {', '.join(TDE4_MODELS)}")
    K = np.asarray(K, dtype=np.float64)
    grid = frame_grid(image_size, max(image_size) / 48.0)
    ideal = source.undistort(grid, K)
    normalised = np.linalg.norm((ideal - K[:2, 2]) / np.diag(K)[:2], axis=1)
    keep = np.all(np.isfinite(ideal), axis=1) & (normalised < _MAX_START_TAN)
    grid, ideal = grid[keep], ideal[keep]
    # pinhole pixels grow as tan(theta): weigh by d(theta)/d(tan theta) so that the rim does not outweigh the rest
    weight = 1.0 / (1.0 + normalised[keep] ** 2)[:, None]
    names = tuple(FITTED_PARAMS[model] if fitted is None else fitted)
    filmback = dict(zip(FILMBACK_KEYS, (float(image_size[0]), float(image_size[1]))))

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        lens = Distortion(model, {**filmback, **dict(zip(names, vector))})
        return np.nan_to_num(weight * (lens.undistort(grid, K) - ideal), nan=_LOST_PX).ravel()

    solution = scipy.optimize.least_squares(residuals, np.zeros(len(names)), method="lm", x_scale="jac")
    return Distortion(model, {**filmback, **dict(zip(names, solution.x))})


def fit_tde4_lens(object_points: NDArray[np.float64], views: Sequence[tuple[NDArray[np.int64], NDArray[np.float64]]],
                  K: NDArray[np.float64], start: Distortion,
                  poses: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]], model: str,
                  image_size: tuple[int, int], loss: str = "trivial", loss_scale: float = 1.0) -> Tde4Fit:
    """Fit a 3DE lens, K and the board poses to the corners of board views (see the module docstring).

    Parameters
    ----------
    object_points : ndarray, shape (C, 3)
        The board's corners in its own frame.
    views : sequence of (ids, corners_px)
        Each view's corner ids (into ``object_points``) and detected
        corners (pixel (0, 0) the centre of the top-left pixel).
    K, start : ndarray (3, 3), Distortion
        A calibration of another model on the same views: the start.
    poses : sequence of (R, t)
        ``cam_from_board`` of each view under that calibration.
    model : str
        One of :data:`~camcal.model.tde4.TDE4_MODELS`.
    image_size : (int, int)
        The camera's (width, height): the lens's film back.
    loss, loss_scale : str, float
        Robust loss on each corner (``trivial``, ``huber``, ``soft_l1``,
        ``cauchy``) and its scale in pixels.

    Returns
    -------
    Tde4Fit
    """
    if model not in TDE4_MODELS:
        raise CamcalError(f"not a 3DE model: {model!r}, expected one of: {', '.join(TDE4_MODELS)}")
    if loss not in _LOSSES:
        raise CamcalError(f"unknown loss {loss!r}, expected one of: {', '.join(_LOSSES)}")
    if len(views) != len(poses):
        raise CamcalError(f"{len(views)} views but {len(poses)} poses")
    K = np.asarray(K, dtype=np.float64)
    names = FITTED_PARAMS[model]
    fixed = (object_points, views, model, loss, loss_scale)
    if "lens_rotation_deg" not in names:
        return _refine(*fixed, names, K, nearest_tde4_lens(start, K, image_size, model), poses)
    held_names = tuple(name for name in names if name != "lens_rotation_deg")
    held = _refine(*fixed, held_names, K, nearest_tde4_lens(start, K, image_size, model, held_names), poses)
    held = dataclasses.replace(held, distortion=Distortion(model, {**held.distortion.params, "lens_rotation_deg": 0.0}))
    try:  # the rotation's standard error at 0: the covariance of the free problem at the held solution
        probe = _refine(*fixed, names, held.K, held.distortion, held.poses, max_nfev=1)
        index = probe.parameter_names.index("lens_rotation_deg")
        sigma = float(np.sqrt(probe.covariance[index, index]))
    except CamcalError:  # singular normal equations: the rotation is not determined at all
        sigma = float("inf")
    if sigma > MAX_ROTATION_SIGMA_DEG:
        return dataclasses.replace(held, held=f"lens rotation held at 0 deg: the corners do not determine it (its "
                                   f"standard error there {sigma:.2g} deg, over {MAX_ROTATION_SIGMA_DEG:g})")
    try:
        return _refine(*fixed, names, held.K, held.distortion, held.poses)
    except CamcalError as error:
        return dataclasses.replace(held, held=f"lens rotation held at 0 deg: its fit failed ({error})")


def _refine(object_points: NDArray[np.float64], views: Sequence[tuple[NDArray[np.int64], NDArray[np.float64]]],
            model: str, loss: str, loss_scale: float, names: tuple[str, ...], K: NDArray[np.float64],
            lens: Distortion, poses: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
            max_nfev: int | None = None) -> Tde4Fit:
    """Step 2 of the module docstring: ``K``, the coefficients ``names`` of ``lens`` (the others held) and the
    poses refined from those given. ``max_nfev=1``: no step taken, the fit's figures at the start."""
    held = {key: value for key, value in lens.params.items() if key not in names}
    n_lens = 4 + len(names)
    points = [np.asarray(object_points, dtype=np.float64)[ids] for ids, _ in views]
    detected = np.concatenate([np.asarray(corners, dtype=np.float64) for _, corners in views])
    sizes = [len(p) for p in points]
    start_vector = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [lens.params[n] for n in names]]
                                  + [np.concatenate([cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel(),
                                                     np.asarray(t, dtype=np.float64)]) for R, t in poses])

    def unpack(vector: NDArray[np.float64]) -> tuple[NDArray[np.float64], Distortion]:
        fx, fy, cx, cy = vector[:4]
        return (np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
                Distortion(model, {**held, **dict(zip(names, vector[4:n_lens]))}))

    def residuals(vector: NDArray[np.float64]) -> NDArray[np.float64]:
        K_v, lens_v = unpack(vector)
        ideal = []
        for n, X in enumerate(points):
            pose = vector[n_lens + 6 * n: n_lens + 6 * n + 6]
            camera = X @ cv2.Rodrigues(pose[:3])[0].T + pose[3:]
            with np.errstate(divide="ignore", invalid="ignore"):
                ideal.append(np.where(camera[:, 2:3] > 0.0, camera[:, :2] / camera[:, 2:3], np.nan))
        normalised = np.concatenate(ideal)
        pixels = normalised @ K_v[:2, :2].T + K_v[:2, 2]
        return np.nan_to_num(lens_v.distort(pixels, K_v) - detected, nan=_LOST_PX).ravel()

    # sparsity: K and the lens touch every corner, a view's pose only its own corners' two rows
    rows = np.repeat(np.arange(len(sizes)), 2 * np.array(sizes))
    pattern = np.zeros((2 * len(detected), len(start_vector)), dtype=np.int8)
    pattern[:, :n_lens] = 1
    for column in range(6):
        pattern[np.arange(len(rows)), n_lens + 6 * rows + column] = 1
    sparsity = scipy.sparse.csr_matrix(pattern)
    solution = scipy.optimize.least_squares(residuals, start_vector, jac_sparsity=sparsity, method="trf",
                                            x_scale="jac", loss=_LOSSES[loss], f_scale=loss_scale, max_nfev=max_nfev)
    K_fit, lens_fit = unpack(solution.x)
    residual = residuals(solution.x).reshape(-1, 2)
    if not np.all(np.abs(residual) < _LOST_PX):
        raise CamcalError(f"the {model} refinement left corners the lens cannot image: check the detections")
    jac = solution.jac.toarray() if scipy.sparse.issparse(solution.jac) else np.asarray(solution.jac)
    dof = max(jac.shape[0] - jac.shape[1], 1)
    sigma2 = 2.0 * solution.cost / dof
    parameter_names = ("fx", "fy", "cx", "cy", *names)
    degenerate = (f"the {model} calibration is degenerate (singular normal equations): vary the board poses more")
    try:
        covariance = sigma2 * np.linalg.inv(jac.T @ jac)[:n_lens, :n_lens]
    except np.linalg.LinAlgError:
        raise CamcalError(degenerate) from None
    variances = np.diag(covariance)
    undetermined = [name for name, value in zip(parameter_names, variances) if not (np.isfinite(value) and value >= 0.0)]
    if undetermined:  # an inverse of near-singular normal equations: rounding gives negative variances
        raise CamcalError(f"{degenerate}; not determined: {', '.join(undetermined)}")
    fitted_poses = tuple((cv2.Rodrigues(solution.x[n_lens + 6 * n: n_lens + 6 * n + 3])[0],
                          solution.x[n_lens + 6 * n + 3: n_lens + 6 * n + 6].copy()) for n in range(len(points)))
    return Tde4Fit(K=K_fit, distortion=lens_fit, poses=fitted_poses, residuals_px=residual, covariance=covariance,
                   parameter_names=parameter_names)
