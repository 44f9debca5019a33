"""Square pixels in self-calibration: whether the motion determines ``fx - fy``, and the spread when it is held.

:func:`aspect_visibility` measures how far a change of ``fx - fy`` by the
square-pixel prior's sigma moves the images once everything else
re-adjusts; where that is below a feature error every image shares
(:data:`FEATURE_BIAS_PX`), :func:`camcal.geometry.selfcal.self_calibrate`
holds square pixels (:data:`ASPECT_HELD`) and
:func:`spread_with_aspect_free` carries the prior's spread of ``fx - fy``
into the held fit's covariance (Sturm, P. (1997). Critical Motion Sequences
for Monocular Self-Calibration and Uncalibrated Euclidean Reconstruction. CVPR).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleResult, with_covariance
from camcal.geometry.bundle.prior import ASPECT_PRIOR, mean_focal

__all__ = ["ASPECT_HELD", "FEATURE_BIAS_PX", "SQUARE_PIXELS_HELD", "aspect_visibility", "spread_with_aspect_free"]

#: systematic error of feature positions shared by every image (px): the part of a detector's or a lens model's
#: misfit that does not average out over observations. DoG / SIFT keypoints are located to about a tenth of a
#: pixel (Lowe, D. G. (2004). Distinctive Image Features from Scale-Invariant Keypoints. IJCV: a quadratic fit
#: of the scale-space extremum). A property of features, not fitted to a data set: a change of ``fx - fy`` by
#: the square-pixel prior's sigma that moves the images by less than this could be such an error
#: (:func:`aspect_visibility`). Rendered features carry less (a rendered arc recovers fy / fx to 0.02 % with
#: the aspect free, where holding it costs 0.09 %); real ones carry it (Strecha's scenes: fy 0.2-0.45 % off).
FEATURE_BIAS_PX = 0.1
#: sigma of ``(fx - fy) / f`` of the prior that holds square pixels where the motion does not determine the aspect.
ASPECT_HELD = 1e-6
#: the source of the prior that holds square pixels (:func:`camcal.geometry.selfcal.self_calibrate`).
SQUARE_PIXELS_HELD = "square pixels held: the motion does not determine fx - fy"


def aspect_visibility(result: BundleResult, camera: int) -> float:
    """RMS image displacement (px) of a change of ``fx - fy`` by the square-pixel prior's sigma, the rest re-adjusted.

    The images' own information on ``z = fx - fy``, every other parameter
    (poses, points, the other intrinsics) marginalised, is the posterior's
    minus the priors' on ``z``: ``1 / s_z^2 = 1 / (a^T C a) - sum 1 /
    sigma_prior^2`` (a prior on ``z`` alone adds its precision to ``z``'s
    marginal). It is ``sum_i |g_i|^2 / s^2`` with ``g_i`` the displacement of
    observation ``i`` per pixel of ``z`` after the best compensation and
    ``s`` the per-axis noise of the covariance (residuals over their degrees
    of freedom), so ``dz sqrt(sum |g_i|^2 / N)`` is the RMS
    displacement of a change ``dz``. Motion about one axis makes a stretch
    of the scene along it trade against fy with no displacement at all
    (Sturm, P. (1997). Critical Motion Sequences for Monocular
    Self-Calibration and Uncalibrated Euclidean Reconstruction. CVPR); near
    it, a feature error shared by every image of that size moves ``z`` by
    ``dz`` (:data:`FEATURE_BIAS_PX`). NaN without a covariance or ``fx``, ``fy``.
    """
    state, name = result.state, result.state.camera_names[camera]
    keys = (f"{name}.fx", f"{name}.fy")
    if not all(key in result.covariance_names for key in keys):
        return float("nan")
    rows = [result.covariance_names.index(key) for key in keys]
    a = np.array([1.0, -1.0])
    posterior = float(a @ result.covariance[np.ix_(rows, rows)] @ a)
    names = state.param_names(camera)
    pair = {names.index("fx"): 1.0, names.index("fy"): -1.0}
    prior_precision = sum(1.0 / prior.sigma ** 2 for prior in result.priors if prior.camera == camera and
                          dict(zip(prior.indices, prior.coefficients)) in (pair, {i: -c for i, c in pair.items()}))
    if not posterior > 0:
        return float("nan")
    precision = max(1.0 / posterior - prior_precision, 0.0)
    n, dof = int(np.sum(state.obs_camera == camera)), result.n_residuals - result.n_parameters
    if dof <= 0:
        return float("nan")
    noise2 = 2.0 * result.final_cost / dof  # the covariance's own per-axis noise (the priors' few rows included)
    return float(ASPECT_PRIOR * mean_focal(state, camera) * np.sqrt(noise2 * precision / max(n, 1)))


def spread_with_aspect_free(free: BundleResult, held: BundleResult, cameras: tuple[str, ...]) -> BundleResult:
    """The held fit with its covariance: the free fit's with the hold's information added, widened by the
    square-pixel prior's spread of ``z = fx - fy``, carried to every parameter that re-adjusts with it.

    Holding ``z`` at 0 guards the estimate against a feature error the motion
    cannot tell from an aspect. The hold is a prior ``a^T x ~ N(0, sigma_h^2)``
    (``a``: ``z``'s row), so it adds ``a a^T / sigma_h^2`` to the free fit's
    information ``C^-1`` and, by the Sherman-Morrison identity, the held fit's
    covariance is ``C_h = C - C a a^T C / (sigma_h^2 + a^T C a)``, one camera
    after another (``C``: the free fit's covariance, at its solution: the held
    solution differs from it by the aspect's move, a fraction of a sigma, and
    the free fit's noise weighs both, as it weighs the held fit's priors). ``z``
    is then known only to the prior's ``s = ASPECT_PRIOR f``. Each parameter
    moves with ``z`` by the regression ``g = C a / (a^T C a)`` of the fit with
    the prior alone, so the covariance gains ``s^2 g g^T`` (fx, fy: ``g =
    +-1/2``, the mean focal unchanged; the principal point along fy's weak
    direction too).

    Parameters
    ----------
    free : BundleResult
        The fit with the aspect under its prior, with its covariance.
    held : BundleResult
        The fit from its solution with square pixels held (:data:`SQUARE_PIXELS_HELD` priors); its covariance is
        not needed.
    cameras : tuple of str
        The cameras held.
    """
    names = free.covariance_names
    if not names:
        raise CamcalError("the fit with the aspect free has no covariance to hold square pixels in")
    state = held.state

    def row(camera: int, coefficients: dict[str, float]) -> NDArray[np.float64]:
        a = np.zeros(len(names))
        for parameter, value in coefficients.items():
            a[names.index(f"{state.camera_names[camera]}.{parameter}")] += value
        return a

    covariance = free.covariance.copy()
    for prior in held.priors:
        if prior.spec.source == SQUARE_PIXELS_HELD:
            params = state.param_names(prior.camera)
            a = row(prior.camera, {params[i]: c for i, c in zip(prior.indices, prior.coefficients)})
            Ca = covariance @ a
            covariance -= np.outer(Ca, Ca) / (prior.sigma ** 2 + float(a @ Ca))
    widened = covariance.copy()
    for camera in cameras:
        index = state.camera_names.index(camera)
        a = row(index, {"fx": 1.0, "fy": -1.0})
        g = free.covariance @ a / float(a @ free.covariance @ a)
        s = ASPECT_PRIOR * mean_focal(state, index)
        widened += s * s * np.outer(g, g)
    result = with_covariance(held, covariance, names, free.n_points_out_of_covariance)
    variance = dict(zip(names, np.diag(widened)))
    sigmas = {key: float(np.sqrt(variance[key])) if key in variance else value for key, value in result.sigmas.items()}
    return dataclasses.replace(result, covariance=widened, sigmas=sigmas)
