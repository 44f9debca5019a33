"""Rig-aware bundle adjustment on Ceres: camcal's one nonlinear calibration engine.

- :mod:`~camcal.geometry.bundle.state`: what is refined (:class:`BundleState`,
  :class:`BoardObservations`), how (:class:`BundleOptions`), what it measured
  (:class:`BundleResult`), the cost (:func:`robust_cost`, :func:`residuals`)
  and the anchors of the gauge (:func:`hold_rig`, :func:`attach_board`);
- :mod:`~camcal.geometry.bundle.reconstruction`: a state from and into a
  pycolmap ``Reconstruction``;
- :mod:`~camcal.geometry.bundle.solve`: :func:`bundle_adjust`, pycolmap's Ceres
  bundle adjuster on the state;
- :mod:`~camcal.geometry.bundle.covariance`: the marginal covariance of the
  intrinsics and rig poses (:func:`marginal_covariance`);
- :mod:`~camcal.geometry.bundle.prior`: Gaussian priors on intrinsics
  (:class:`PriorSpec`, :func:`parse_prior`, the sensor's defaults);
- :mod:`~camcal.geometry.bundle.deletion`: the solution without groups of
  frames by one Gauss-Newton step (the jackknife's replicates);
- :mod:`~camcal.geometry.bundle.influences`: each group of frames'
  influence on the intrinsics, rig poses and scene gauge (the projection
  sigma's design effect).

References
----------
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR (COLMAP).
Agarwal, S., Mierle, K. et al. Ceres Solver: loss functions, manifolds,
covariance estimation.
"""

from camcal.geometry.bundle.covariance import MIN_POINT_SINGULAR_RATIO, ceres_covariance, marginal_covariance
from camcal.geometry.bundle.prior import PriorSpec, parse_prior
from camcal.geometry.bundle.reconstruction import (observations_to_reconstruction, state_from_reconstruction, state_images,
                                                   state_to_reconstruction)
from camcal.geometry.bundle.solve import bundle_adjust, with_covariance
from camcal.geometry.bundle.state import (
    LOSSES,
    WARM_START_RADIUS,
    BoardObservations,
    BundleOptions,
    BundleResult,
    BundleState,
    attach_board,
    hold_rig,
    residuals,
    robust_cost,
)

__all__ = [
    "LOSSES",
    "MIN_POINT_SINGULAR_RATIO",
    "WARM_START_RADIUS",
    "BoardObservations",
    "BundleOptions",
    "BundleResult",
    "BundleState",
    "PriorSpec",
    "attach_board",
    "bundle_adjust",
    "ceres_covariance",
    "hold_rig",
    "marginal_covariance",
    "observations_to_reconstruction",
    "parse_prior",
    "residuals",
    "robust_cost",
    "state_from_reconstruction",
    "state_images",
    "state_to_reconstruction",
    "with_covariance",
]
