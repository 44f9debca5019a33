"""Projection uncertainty: the per-pixel sigma of where a camera images the ray through each pixel.

For a pixel ``q`` of a calibrated camera, the ray through it (at a
distance ``d`` along the ray, or at infinity) is projected again with
perturbed parameters; the 2x2 covariance of that projection, propagated to
first order from the calibration's covariance, is the projection
uncertainty, and its worst-direction standard deviation (the square root
of its largest eigenvalue) is what the maps hold.

The gauge is handled as mrcal does (Kogan, mrcal 2.x, "Projection
uncertainty"): the point is unprojected with the estimated intrinsics,
carried into the board (reference) frame through the MEAN of the board
poses and back with their perturbed values, and reprojected with the
perturbed intrinsics, so the uncertainty of the camera's frame relative to
the boards' is part of it. To first order the mean of the perturbed board
poses moves a reference-frame point ``p`` to ``p + delta_bar x p +
epsilon`` (:func:`camcal.geometry.bundle.solve._gauge_rows`), and a rig
camera's own pose ``cam_from_reference`` perturbs it by ``rho x (R p_ref) +
tau``. With ``theta`` the intrinsics::

    p_ref = R^T (p - t)                       (p = d v / |v|, v = unproject(q))
    p'    = p + rho x (p - t) + tau + R (delta_bar x p_ref + epsilon)
    q'    = project(theta + dtheta, p')
    J     = [dq/dtheta, dq/dp dp/d(rho, tau), dq/dp dp/d(delta_bar, epsilon)]
    Sigma_q = J Sigma J^T,   sigma_worst = sqrt(lambda_max(Sigma_q))

A solve (structure from motion) has no board: its covariance carries
the scene gauge instead, the common turn of the camera frame over the
frames once the world's own turn is taken out (:func:`scene_gauge_rows`,
rotation only), under the same names; the truth's counterpart is
:func:`scene_gauge_rotation`.

At infinity ``p`` is the unit ray and the translations drop out (``dq/dp``
scales as ``1/d`` while ``dp/dtau`` stays bounded). ``dq/dtheta`` and
``dq/dp`` are central differences of camcal's own projection
(:meth:`camcal.model.distortion.Distortion.project_rays`), each parameter
stepped by 1e-3 of its own sigma. What the figures cover is the sampling
noise of the corners the calibration saw, not model error.

Conventions: pixel (0, 0) is the centre of the top-left pixel; camera axes
+x right, +y down, +z forward; ``R, t`` is ``cam_from_reference``
(``t = -R c``).

References
----------
Kogan, D. mrcal 2.x documentation: "Projection uncertainty"
(https://mrcal.secretsauce.net/uncertainty.html), 2022.
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry, 2nd ed.,
section 5.2 (forward propagation of covariance, ``J Sigma J^T``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError
from camcal.model.camera import chordal_mean_rotation
from camcal.model.colmap import camera_from_colmap
from camcal.model.distortion import Distortion
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera

__all__ = ["GAUGE", "MIN_SCENE_GAUGE_SPREAD", "POSE", "SigmaSummary", "camera_covariance", "covariance_from_colmap",
           "perturbed_lens", "projection_covariance", "projection_jacobian", "projection_sigma", "projection_sigma_map",
           "scene_gauge_rotation", "scene_gauge_rows", "shrunk_design_effect", "sigma_grid", "summarise_sigma", "upsample_grid"]

#: Names of the board gauge in a camera's covariance (module docstring).
GAUGE = ("gauge_rx", "gauge_ry", "gauge_rz", "gauge_tx", "gauge_ty", "gauge_tz")
#: Names of a rig camera's pose ``cam_from_reference`` in its covariance.
POSE = ("rx", "ry", "rz", "tx", "ty", "tz")
_K_ENTRIES = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2), "skew": (0, 1)}
#: The scene gauge needs the frames turned about more than one axis: ``1 - s_max(mean_i R_i)``, the smallest
#: eigenvalue of its normal equations per frame (:func:`scene_gauge_rows`), at least this (an RMS spread of the
#: frames' rotations of about 8 degrees about every axis: ``1 - cos 8 deg``).
MIN_SCENE_GAUGE_SPREAD = 0.01
#: Grid step (pixels) of a sigma map; the map between grid points is bilinear (sigma is smooth over the frame).
MAP_STEP_PX = 8


def camera_covariance(camera: Camera) -> ParameterCovariance:
    """The camera's ``quality.covariance``, or a one-line error saying how to get one."""
    covariance = camera.quality.covariance
    if covariance is None:
        raise CamcalError(f"camera {camera.name!r} has no covariance in its rig file (quality.covariance): "
                          "calibrate it again with `camcal calibrate board` to get projection uncertainty")
    return covariance


def _camcal_values(camera: Camera, model: str, params: NDArray[np.float64]) -> NDArray[np.float64]:
    """``fx, fy, cx, cy`` and ``camera``'s distortion parameters of the camcal camera of COLMAP ``params``."""
    lens = camera_from_colmap(camera.name, model, camera.image_size, params, np.eye(3), np.zeros(3))
    return np.r_[lens.K[0, 0], lens.K[1, 1], lens.K[0, 2], lens.K[1, 2],
                 [lens.distortion.params.get(key, 0.0) for key in camera.distortion.params]]


def covariance_from_colmap(cameras: Sequence[Camera], models: Sequence[str], params: Sequence[ArrayLike],
                           colmap_names: Sequence[Sequence[str]], names: Sequence[str], matrix: ArrayLike,
                           index: int) -> ParameterCovariance | None:
    """Camera ``index``'s ``quality.covariance`` from a bundle adjustment's covariance over COLMAP's parameters.

    ``names`` / ``matrix``: :attr:`camcal.geometry.bundle.BundleResult.covariance` and its names
    (``CAMERA.f``, ``CAMERA.k``, ``CAMERA.rx`` ...). Each camera's free COLMAP parameters ``p`` are carried
    to camcal's ``theta = (fx, fy, cx, cy, distortion)`` of :func:`camcal.model.colmap.camera_from_colmap` by
    ``A = dtheta/dp`` (central differences), ``Sigma_theta = A Sigma_p A^T``; the rig pose ``rx .. tz``
    (rotation vector on the left of ``cam_from_reference``, translation) is kept as it is. The camera's own
    parameters take their plain names; the earlier cameras' (``cameras[:index]``) keep ``NAME.param``, the
    cross-covariance a pair's figures use; the gauge ``gauge.rx`` ... (the scene gauge of a solve,
    :func:`scene_gauge_rows`) becomes :data:`GAUGE`'s ``gauge_rx`` .... None when the camera has no free
    parameter in it.
    """
    names = list(names)
    matrix = np.asarray(matrix, dtype=np.float64)
    rows, out_names = [], []
    for j in range(index + 1):
        camera = cameras[j]
        prefix = "" if j == index else f"{camera.name}."
        p0 = np.asarray(params[j], dtype=np.float64)
        free = [(k, names.index(f"{camera.name}.{n}")) for k, n in enumerate(colmap_names[j])
                if f"{camera.name}.{n}" in names]
        labels = [prefix + n for n in ("fx", "fy", "cx", "cy", *camera.distortion.params)]
        if free:
            A = np.zeros((len(labels), len(free)))
            for c, (k, _) in enumerate(free):
                h = 1e-6 * max(abs(p0[k]), 1e-3)
                step = np.zeros_like(p0)
                step[k] = h
                A[:, c] = (_camcal_values(camera, models[j], p0 + step)
                           - _camcal_values(camera, models[j], p0 - step)) / (2.0 * h)
            rows.append((A, [m for _, m in free]))
            out_names += labels
        pose = [names.index(f"{camera.name}.{axis}") for axis in POSE if f"{camera.name}.{axis}" in names]
        if pose:
            rows.append((np.eye(len(pose)), pose))
            out_names += [prefix + axis for axis in POSE if f"{camera.name}.{axis}" in names]
    if not any(name in out_names for name in ("fx", "rx")):
        return None
    gauge = [(names.index(f"gauge.{axis[6:]}"), axis) for axis in GAUGE if f"gauge.{axis[6:]}" in names]
    if gauge:  # the board or scene gauge, shared by every camera: its plain names
        rows.append((np.eye(len(gauge)), [k for k, _ in gauge]))
        out_names += [axis for _, axis in gauge]
    T = np.zeros((len(out_names), len(names)))
    r = 0
    for A, source in rows:
        T[r:r + A.shape[0], source] = A
        r += A.shape[0]
    covariance = T @ matrix @ T.T
    covariance = 0.5 * (covariance + covariance.T)
    # T M T^T of a positive semi-definite M has a non-negative diagonal; where a row of T is orthogonal to M's
    # range (a held camera's division aspect fx / fy when fx and fy move alike) rounding leaves -1e-22: zero
    rounding = 64.0 * np.finfo(np.float64).eps * np.einsum("ij,jk,ik->i", np.abs(T), np.abs(matrix), np.abs(T))
    diagonal = np.diag(covariance)
    np.fill_diagonal(covariance, np.where((diagonal < 0) & (diagonal >= -rounding), 0.0, diagonal))
    return ParameterCovariance(tuple(out_names), covariance)


def _spread(rotations: NDArray[np.float64]) -> float:
    """``1 - s_max(mean_i R_i)``: 0 when every frame is turned alike about some axis
    (:data:`MIN_SCENE_GAUGE_SPREAD`)."""
    return float(1.0 - np.linalg.svd(rotations.mean(axis=0), compute_uv=False)[0])


def scene_gauge_rows(rotations: ArrayLike) -> NDArray[np.float64] | None:
    """The 3 x 3N rows mapping the frames' rotation perturbations to the scene gauge ``g`` of a solve.

    A solve has no board: its world is fixed only up to a similarity, so the
    rotation between the true and the estimated camera frames, averaged over
    the frames (mrcal 2.2's gauge, :func:`camcal.geometry.bundle.solve._gauge_rows`
    for boards), is taken after the rotation of the world that best agrees.
    With the frames' poses ``rig_from_world`` perturbed as ``R_i' =
    exp(delta_i) R_i``, a common turn ``g`` of the camera frame and a turn
    ``W = exp(-w)`` of the world give ``delta_i = g + R_i w`` to first order;
    ``(g, w)`` are the least squares solution of those ``3N`` equations::

        [N I      sum R_i ] [g]   [sum delta_i      ]
        [sum R_i^T  N I   ] [w] = [sum R_i^T delta_i]

    and ``g`` is linear in the ``delta_i``: the first three rows of the
    inverse times the right-hand side's matrix. ``g`` does not change when
    the ``delta_i`` change by a turn of the world (``R_i w'``), so it does
    not depend on how the solve fixed its gauge. The system is singular when
    every frame is turned alike about one axis (``R_i a`` the same for all
    ``i``: a camera dollied without turning, or turned about one axis only):
    then ``g`` about that axis is a turn of the world, and None is returned
    (below :data:`MIN_SCENE_GAUGE_SPREAD`).

    Parameters
    ----------
    rotations : array_like, shape (N, 3, 3)
        ``rig_from_world`` rotation of each frame.

    Returns
    -------
    ndarray, shape (3, 3N), or None
        ``g = rows @ concatenate(delta_i)``.
    """
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    n = len(R)
    if n < 2 or _spread(R) < MIN_SCENE_GAUGE_SPREAD:
        return None
    M = np.block([[n * np.eye(3), R.sum(axis=0)], [R.sum(axis=0).T, n * np.eye(3)]])
    B = np.vstack([np.tile(np.eye(3), (1, n)), np.hstack(list(np.transpose(R, (0, 2, 1))))])
    return np.linalg.solve(M, B)[:3]


def scene_gauge_rotation(true_rotations: ArrayLike, estimated_rotations: ArrayLike,
                         max_iterations: int = 10000) -> NDArray[np.float64]:
    """The rotation carrying a solve's estimated camera (rig) frame into the true one, in the scene gauge.

    The rotations ``G`` (estimated -> true camera frame) and ``A``
    (estimated -> true world) minimising ``sum_i |R_true_i A R_est_i^T -
    G|_F^2`` over the frames (``R``: ``rig_from_world``), found by
    alternating their chordal means (each step the exact minimiser of one
    given the other, so the sum never grows): to first order the ``g`` of
    :func:`scene_gauge_rows` (``G = exp(-g)``), as the board gauge's
    chordal mean of ``R_true_i R_est_i^T`` is mrcal's mean of the board
    poses.

    Raises
    ------
    CamcalError
        Fewer than 2 frames, different counts, or the true frames turned
        alike about one axis (the gauge is then undetermined; :func:`scene_gauge_rows`).
    """
    true = np.asarray(true_rotations, dtype=np.float64).reshape(-1, 3, 3)
    estimated = np.asarray(estimated_rotations, dtype=np.float64).reshape(-1, 3, 3)
    if len(true) != len(estimated) or len(true) < 2:
        raise CamcalError(f"need the same number (2 or more) of true and estimated frames, got {len(true)} and "
                          f"{len(estimated)}")
    spread = _spread(true)
    if spread < MIN_SCENE_GAUGE_SPREAD:
        raise CamcalError(f"the frames are turned alike about one axis (spread {spread:.2g} < "
                          f"{MIN_SCENE_GAUGE_SPREAD}): the scene gauge is undetermined")
    A = chordal_mean_rotation(np.transpose(true, (0, 2, 1)) @ estimated)
    G = np.eye(3)
    for _ in range(max_iterations):
        G_next = chordal_mean_rotation(true @ A @ np.transpose(estimated, (0, 2, 1)))
        A = chordal_mean_rotation(np.transpose(true, (0, 2, 1)) @ G_next @ estimated)
        done = np.max(np.abs(G_next - G)) < 1e-14
        G = G_next
        if done:
            break
    return G


def shrunk_design_effect(model_variance: float, contributions: ArrayLike) -> float:
    """The design effect of a camera's projection from a delete-one-frame jackknife, shrunk toward 1 as far as
    the jackknife's own spread says it is unsure (Kish 1965; Ledoit & Wolf 2004).

    ``contributions`` are the frames' terms ``c_k = (n - 1) / n |J (d_k - mean d)|^2`` (``d_k``: the move
    of the parameters and the gauge when frame ``k`` is left out, ``J`` the projection Jacobian, pooled over
    the frame's pixels) whose sum is the jackknife's projection variance ``v`` (Efron & Stein 1981); the
    model's is ``m = model_variance`` (``sigma^2 (J^T J)^-1`` projected alike). With only 6-12 frames one
    frame can carry most of ``v`` (it alone fixes a turn of the scene), and ``v`` is then a noisy, inflated
    figure. Ledoit and Wolf's shrinkage toward the model takes the intensity
    ``delta = min(1, var(v) / (v - m)^2)`` with ``var(v) = n var(c_k)`` (the sum of ``n`` terms), so that
    the estimate ``delta m + (1 - delta) v`` leans on the model where the frames disagree about the
    excess, on the jackknife where they agree. Returned as the ratio to ``m``, never below 1 (independent
    features are the least the error can be).

    References
    ----------
    Kish, L. (1965). Survey Sampling. Wiley (the design effect).
    Efron, B. & Stein, C. (1981). The jackknife estimate of variance. Annals of Statistics 9.
    Ledoit, O. & Wolf, M. (2004). A well-conditioned estimator for large-dimensional covariance matrices.
    Journal of Multivariate Analysis 88 (the shrinkage intensity).
    """
    c = np.asarray(contributions, dtype=np.float64).ravel()
    if len(c) < 2 or not np.all(np.isfinite(c)) or not model_variance > 0:
        return 1.0
    v = float(c.sum())
    spread = len(c) * float(np.var(c, ddof=1))
    gap = (v - model_variance) ** 2
    delta = 1.0 if gap <= 0 else min(1.0, spread / gap)
    return max(1.0, (delta * model_variance + (1.0 - delta) * v) / model_variance)


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``[v]x`` for each row of ``v`` (N, 3) -> (N, 3, 3)."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def perturbed_lens(camera: Camera, name: str, step: float) -> tuple[NDArray[np.float64], Distortion]:
    """K and distortion with intrinsic ``name`` moved by ``step``; a distortion centre stored at the principal
    point (COLMAP's division cameras) is the principal point and moves with it."""
    K = np.array(camera.K, dtype=np.float64)
    if name in _K_ENTRIES:
        K[_K_ENTRIES[name]] += step
        centre = camera.distortion.center
        if name in ("cx", "cy") and centre is not None and np.allclose(centre, camera.K[:2, 2], rtol=0, atol=1e-9):
            return K, dataclasses.replace(camera.distortion, center=(K[0, 2], K[1, 2]))
        return K, camera.distortion
    params = dict(camera.distortion.params)
    params[name] += step
    return K, dataclasses.replace(camera.distortion, params=params)


def projection_covariance(camera: Camera, pixels_px: ArrayLike, distance: float | None = None,
                          covariance: ParameterCovariance | None = None) -> NDArray[np.float64]:
    """The 2x2 covariance of the projection of the ray through each pixel (module docstring).

    ``J Sigma J^T`` with ``J`` of :func:`projection_jacobian`.

    Parameters
    ----------
    camera : Camera
        The calibrated camera (its ``R, c`` relative to the reference camera).
    pixels_px : array_like, shape (N, 2)
        Distorted pixels (pixel (0, 0) at the centre of the top-left pixel).
    distance : float, optional
        Distance along the ray in the rig's units; None (default) is
        infinity.
    covariance : ParameterCovariance, optional
        Defaults to ``camera.quality.covariance``. Names it lacks (no
        gauge, no pose) contribute nothing, nor do other cameras'
        parameters ``NAME.param`` (the cross-covariance a pair's figures
        use, :mod:`camcal.geometry.rectify.sigma`); any other name that is
        neither the camera's intrinsics, :data:`POSE` nor :data:`GAUGE` is
        an error.

    Returns
    -------
    ndarray, shape (N, 2, 2)
        In pixels squared; NaN for pixels without a ray.
    """
    covariance = camera_covariance(camera) if covariance is None else covariance
    J = projection_jacobian(camera, pixels_px, distance, covariance)
    return np.einsum("nip,pq,njq->nij", J, covariance.array, J)


def projection_jacobian(camera: Camera, pixels_px: ArrayLike, distance: float | None,
                        covariance: ParameterCovariance) -> NDArray[np.float64]:
    """``dq/d(parameters)`` (N, 2, P) of the reprojected ray through each pixel, over ``covariance.names``
    (module docstring; each intrinsic stepped by 1e-3 of its sigma in ``covariance``)."""
    if distance is not None and not (np.isfinite(distance) and distance > 0):
        raise CamcalError(f"distance must be a positive number (or infinity), got {distance!r}")
    pixels = np.asarray(pixels_px, dtype=np.float64).reshape(-1, 2)
    names, C = covariance.names, covariance.array
    intrinsic = set(_K_ENTRIES) | set(camera.distortion.params)
    unknown = [n for n in names if n not in intrinsic and n not in POSE and n not in GAUGE and "." not in n]
    if unknown:
        raise CamcalError(f"camera {camera.name!r}: covariance names {', '.join(unknown)} are not parameters of its "
                          f"{camera.distortion.model} lens, its pose or the gauge")
    v = camera.distortion.rays_from_pixels(pixels, camera.K)
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    R = np.asarray(camera.R, dtype=np.float64)
    t = -R @ np.asarray(camera.c, dtype=np.float64)
    at_infinity = distance is None
    p = v if at_infinity else v * distance
    sigmas = np.sqrt(np.clip(np.diag(C), 0.0, None))
    J = np.zeros((len(p), 2, len(names)))
    # dq/dtheta: central differences, each intrinsic stepped by 1e-3 of its sigma
    for k, name in enumerate(names):
        if name not in intrinsic or sigmas[k] == 0.0:
            continue
        h = 1e-3 * sigmas[k]
        K_p, d_p = perturbed_lens(camera, name, h)
        K_m, d_m = perturbed_lens(camera, name, -h)
        J[:, :, k] = (d_p.project_rays(p, K_p) - d_m.project_rays(p, K_m)) / (2.0 * h)
    # dq/dp: central differences along the camera axes
    h = 1e-6 * np.linalg.norm(p, axis=1, keepdims=True)
    J_p = np.stack([(camera.distortion.project_rays(p + h * e, camera.K)
                     - camera.distortion.project_rays(p - h * e, camera.K)) / (2.0 * h) for e in np.eye(3)], axis=2)
    # dp/d(pose) and dp/d(gauge), first order (module docstring); at infinity the translations drop out
    relative = p if at_infinity else p - t  # R p_ref
    p_ref = relative @ R  # R^T (p - t), rows
    columns = {}
    for e, axis in enumerate("xyz"):
        columns[f"r{axis}"] = -_skew(relative)[:, :, e]                # dp/drho = -[p - t]x
        columns[f"gauge_r{axis}"] = -(R @ _skew(p_ref))[:, :, e]       # dp/ddelta_bar = -R [p_ref]x
        if not at_infinity:
            columns[f"t{axis}"] = np.broadcast_to(np.eye(3)[e], p.shape)  # dp/dtau = I
            columns[f"gauge_t{axis}"] = np.broadcast_to(R[:, e], p.shape)  # dp/depsilon = R
    for k, name in enumerate(names):
        if name in columns:
            J[:, :, k] = np.einsum("nij,nj->ni", J_p, columns[name])
    return J


def projection_sigma(camera: Camera, pixels_px: ArrayLike, distance: float | None = None,
                     covariance: ParameterCovariance | None = None) -> NDArray[np.float64]:
    """Worst-direction standard deviation (pixels) of the projection of the ray through each pixel.

    ``sqrt(lambda_max)`` of :func:`projection_covariance`'s 2x2 matrix
    ``[[a, b], [b, c]]``: ``lambda_max = (a + c) / 2 + sqrt(((a - c) / 2)^2
    + b^2)``. Shape (N,); NaN for pixels without a ray.
    """
    S = projection_covariance(camera, pixels_px, distance, covariance)
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    return np.sqrt(np.clip(0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b**2), 0.0, None))


def sigma_grid(size: tuple[int, int], step: float = MAP_STEP_PX) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel coordinates of a map's grid: every ``step`` pixels from 0, the last row and column included."""
    width, height = size
    xs = np.unique(np.r_[np.arange(0.0, width - 1, step), width - 1.0])
    ys = np.unique(np.r_[np.arange(0.0, height - 1, step), height - 1.0])
    return xs, ys


def projection_sigma_map(camera: Camera, distance: float | None = None, source_px: NDArray | None = None,
                         step: float = MAP_STEP_PX, covariance: ParameterCovariance | None = None,
                         ) -> NDArray[np.float32]:
    """A per-pixel sigma image: exact on a grid every ``step`` pixels, bilinear between.

    Parameters
    ----------
    camera : Camera
    distance : float, optional
        Distance along the rays (rig units); None is infinity.
    source_px : ndarray, shape (H, W, 2), optional
        For a map on another canvas (an undistorted image, an ST-map's
        output): the camera pixel each output pixel looks up (NaN: none).
        Default: the camera's own image, pixel for pixel (a plate-sized
        map, aligned with the redistort ST-map).
    step : float
        Grid step in output pixels.

    Returns
    -------
    ndarray, shape (H, W), float32
        Worst-direction sigma in pixels of the camera's image; NaN where
        an output pixel has no source pixel or ray.
    """
    if source_px is None:
        width, height = camera.image_size
    else:
        height, width = source_px.shape[:2]
    xs, ys = sigma_grid((width, height), step)
    gx, gy = np.meshgrid(xs, ys)
    if source_px is None:
        at = np.column_stack([gx.ravel(), gy.ravel()])
    else:
        at = np.asarray(source_px, dtype=np.float64)[np.ix_(ys.astype(int), xs.astype(int))].reshape(-1, 2)
    sigma = np.full(len(at), np.nan)
    ok = np.all(np.isfinite(at), axis=1)
    if ok.any():
        sigma[ok] = projection_sigma(camera, at[ok], distance, covariance)
    missing = None if source_px is None else ~np.all(np.isfinite(source_px), axis=-1)
    return upsample_grid(sigma.reshape(len(ys), len(xs)), xs, ys, (width, height), missing)


def upsample_grid(values: NDArray, xs: NDArray, ys: NDArray, size: tuple[int, int],
                  missing: NDArray | None = None) -> NDArray[np.float32]:
    """A (H, W) float32 image from values on the grid ``xs, ys`` (:func:`sigma_grid`): bilinear between grid
    points, a NaN grid value replaced by its nearest finite one (so NaN does not spread by a cell), NaN where
    ``missing`` (H, W) is True."""
    import scipy.interpolate  # noqa: PLC0415
    import scipy.ndimage  # noqa: PLC0415

    width, height = size
    sigma = np.asarray(values, dtype=np.float64)
    absent = ~np.isfinite(sigma)
    if absent.all():
        return np.full((height, width), np.nan, dtype=np.float32)
    if absent.any():
        nearest = scipy.ndimage.distance_transform_edt(absent, return_distances=False, return_indices=True)
        sigma = sigma[tuple(nearest)]
    grid = scipy.interpolate.RegularGridInterpolator((ys, xs), sigma)
    v, u = np.mgrid[0:height, 0:width]
    out = grid((v.ravel().astype(float), u.ravel().astype(float))).reshape(height, width)
    if missing is not None:
        out[missing] = np.nan
    return out.astype(np.float32)


@dataclass(frozen=True)
class SigmaSummary:
    """Worst and median sigma of a map, in the frame and at its four corners (pixels unless ``unit`` says).

    Attributes
    ----------
    worst_px, median_px : float
        Over every pixel with a value.
    corners_px : tuple of float
        Top-left, top-right, bottom-left, bottom-right pixels.
    distance : float or None
        The distance of the rays (None: infinity).
    """

    worst_px: float
    median_px: float
    corners_px: tuple[float, float, float, float]
    distance: float | None = None
    label: str = "projection sigma"
    unit: str = "px"

    def describe(self) -> str:
        """``projection sigma at infinity: worst 0.21 px, median 0.05 px; corners 0.2 / 0.19 / 0.21 / 0.18 px``."""
        where = "at infinity" if self.distance is None else f"at distance {self.distance:g}"
        corners = " / ".join(f"{c:.3g}" for c in self.corners_px)
        return (f"{self.label} {where}: worst {self.worst_px:.3g} {self.unit}, median {self.median_px:.3g} "
                f"{self.unit}; corners (TL / TR / BL / BR) {corners} {self.unit}")

    def to_dict(self) -> dict:
        """The figures for ``--json`` (keys ``worst_px``..., or ``worst_m``... for a figure in metres)."""
        unit = self.unit
        return {f"worst_{unit}": self.worst_px, f"median_{unit}": self.median_px,
                f"corners_{unit}": [c if np.isfinite(c) else None for c in self.corners_px], "distance": self.distance}


def summarise_sigma(sigma_map: NDArray, distance: float | None = None, label: str = "projection sigma",
                    unit: str = "px") -> SigmaSummary:
    """:class:`SigmaSummary` of a sigma map (NaN pixels ignored)."""
    values = np.asarray(sigma_map, dtype=np.float64)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        raise CamcalError("the sigma map has no finite value")
    corners = tuple(float(values[i, j]) for i, j in ((0, 0), (0, -1), (-1, 0), (-1, -1)))  # NaN: no source pixel
    return SigmaSummary(float(finite.max()), float(np.median(finite)), corners, distance, label, unit)
