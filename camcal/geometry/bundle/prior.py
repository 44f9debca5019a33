"""Gaussian priors on intrinsics: what the sensor and the user know before the images speak.

A prior ``a . x ~ N(mean, sigma^2)`` on a linear combination of one camera's
COLMAP parameters ``x`` enters the Ceres problem as one residual block
``w (a . x - mean)`` with ``w = s / sigma``, where ``s`` is the per-axis
reprojection noise (pixels): with the reprojection residuals weighted
``1 / s`` implicitly, the cost is ``s^2 / 2`` times the negative log
posterior, so the minimum is the maximum a posteriori estimate and
``s^2 (J^T J)^-1`` its posterior covariance (the prior's information
``a a^T / sigma^2`` included). :func:`camcal.geometry.bundle.bundle_adjust`
re-sets ``s`` from the solved residuals before the covariance.

Priors are given in camcal's conventions (:class:`PriorSpec`: ``f``,
``fx``, ``fy``, ``cx``, ``cy`` in pixels with the top-left pixel centre at 0,
``lambda`` of the division model in pixels^-2, ``k1``, ``k2``, ``p1``,
``p2``) and resolved against each camera's COLMAP model when the problem
is built (:func:`resolve_priors`): ``lambda`` becomes COLMAP's ``k =
lambda fx^2`` at the current focal length, ``cx`` gains COLMAP's half pixel;
``f`` on a model with ``fx`` and ``fy`` is their mean.

Default priors (:func:`default_specs`), from sensors and lenses rather than
any data set:

- principal point: the image centre, sigma :data:`PRINCIPAL_POINT_PRIOR`
  (2 %) of the diagonal. Lens-sensor decentring of interchangeable,
  phone and machine-vision cameras is commonly 0.2-1 % of the diagonal
  (camcal's own rendered and real scenes: 5-23 px of 1000-3700); twice the
  largest of those is still a prior, not a hold;
- radial terms: the displacement each term makes at the image corner
  (``k r^2``, ``k2 r^4`` with ``r`` the half diagonal over the focal length,
  normalised) ~ N(0, :data:`RADIAL_PRIOR`) (20 %: rectilinear lenses bend
  the corner by 1-15 %);
- tangential terms ``p1, p2``: ``3 |p| r`` (their relative displacement
  at the corner) ~ N(0, :data:`TANGENTIAL_PRIOR`) (2 %: decentring of
  assembled lenses is a few tenths of a percent);
- aspect, where the model has ``fx`` and ``fy`` (every lens model of the
  self-calibration, :data:`camcal.geometry.selfcal.MODELS`): ``fx - fy`` ~
  N(0, :data:`ASPECT_PRIOR` f) (1 %: square pixels, up to the few tenths of
  a percent by which real cameras' fx and fy differ, e.g. 0.17 % in
  Strecha et al. 2008's; anamorphic lenses need the user's prior).

Skew has no parameter in any of camcal's COLMAP models: it is 0, said in
:meth:`camcal.geometry.selfcal.SelfCalibration.lines`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.geometry.bundle.state import BundleState

__all__ = [
    "ASPECT_PRIOR",
    "PRINCIPAL_POINT_PRIOR",
    "RADIAL_PRIOR",
    "TANGENTIAL_PRIOR",
    "UNDETERMINED_RATIO",
    "Prior",
    "PriorSpec",
    "default_specs",
    "mean_focal",
    "parse_prior",
    "posterior_sigma",
    "prior_weights",
    "resolve_priors",
    "undetermined",
]

#: default sigma of the principal point about the image centre, as a fraction of the image diagonal.
PRINCIPAL_POINT_PRIOR = 0.02
#: default sigma of each radial term's displacement at the image corner (relative to the radius).
RADIAL_PRIOR = 0.2
#: default sigma of the tangential terms' relative displacement at the image corner.
TANGENTIAL_PRIOR = 0.02
#: default sigma of ``(fx - fy) / f``.
ASPECT_PRIOR = 0.01
#: posterior over prior sigma above which the data count as not determining a parameter: beyond
#: ``1 / sqrt(2)`` the prior carries more of the information than the images.
UNDETERMINED_RATIO = 1.0 / np.sqrt(2.0)

_SPEC = re.compile(r"^\s*(?P<camera>[^.=]+?)\s*\.(?P<name>[A-Za-z0-9_]+)\s*=\s*(?P<mean>[^+]+?)\s*\+-\s*(?P<sigma>\S+)\s*$")
_NAMES = ("f", "fx", "fy", "aspect", "cx", "cy", "lambda", "k1", "k2", "p1", "p2")


@dataclass(frozen=True)
class PriorSpec:
    """A Gaussian prior on one intrinsic in camcal's conventions (module docstring).

    Attributes
    ----------
    camera : str
    name : str
        ``f``, ``fx``, ``fy``, ``aspect`` (``fx - fy``, px), ``cx``, ``cy``, ``lambda``, ``k1``, ``k2``,
        ``p1``, ``p2``.
    mean, sigma : float
    source : str
        Where it comes from, for the user ("given", or the default's reason).
    """

    camera: str
    name: str
    mean: float
    sigma: float
    source: str = "given"

    def __post_init__(self) -> None:
        if self.name not in _NAMES:
            raise CamcalError(f"prior on {self.camera}.{self.name}: unknown intrinsic, expected one of: {', '.join(_NAMES)}")
        if not (np.isfinite(self.mean) and np.isfinite(self.sigma) and self.sigma > 0):
            raise CamcalError(f"prior on {self.camera}.{self.name}: mean must be finite and sigma positive, "
                              f"got {self.mean!r} +- {self.sigma!r}")

    @property
    def label(self) -> str:
        return f"{self.camera}.{self.name}"


@dataclass(frozen=True)
class Prior:
    """A prior resolved on a camera's COLMAP parameters: ``sum_i a_i x_i ~ N(mean, sigma^2)``.

    Attributes
    ----------
    camera : int
        Index into the state's cameras.
    indices : tuple of int
        COLMAP parameter indices ``i``.
    coefficients : tuple of float
        ``a_i``.
    mean, sigma : float
        In COLMAP's units and pixel convention.
    spec : PriorSpec
        What the user or the default asked for.
    scale : float
        camcal unit per COLMAP unit of the combination (``1 / f^2`` for
        ``lambda``, 1 otherwise), to report posteriors in the spec's units.
    """

    camera: int
    indices: tuple[int, ...]
    coefficients: tuple[float, ...]
    mean: float
    sigma: float
    spec: PriorSpec
    scale: float = 1.0

    def value(self, params: NDArray[np.float64]) -> float:
        """``a . x`` of a camera's COLMAP parameters."""
        return float(sum(c * params[i] for i, c in zip(self.indices, self.coefficients)))


def parse_prior(text: str) -> PriorSpec:
    """``CAMERA.NAME=MEAN+-SIGMA`` (e.g. ``left.f=1200+-30``) as a :class:`PriorSpec`."""
    match = _SPEC.match(text)
    if match is None:
        raise CamcalError(f"prior {text!r}: expected CAMERA.NAME=MEAN+-SIGMA, e.g. left.f=1200+-30")
    try:
        mean, sigma = float(match["mean"]), float(match["sigma"])
    except ValueError:
        raise CamcalError(f"prior {text!r}: mean and sigma must be numbers") from None
    return PriorSpec(match["camera"], match["name"], mean, sigma)


def _corner_radius(state: BundleState, camera: int, focal: float) -> float:
    """Half the image diagonal over the focal length (normalised radius of the corners)."""
    return 0.5 * float(np.hypot(*state.image_sizes[camera])) / focal


def mean_focal(state: BundleState, camera: int) -> float:
    """Mean of camera ``camera``'s COLMAP focal lengths (``f``, or ``fx`` and ``fy``), px."""
    names = state.param_names(camera)
    return float(np.mean([state.params[camera][names.index(n)] for n in ("f", "fx", "fy") if n in names]))


def default_specs(state: BundleState, camera: int, principal_point: bool = True) -> tuple[PriorSpec, ...]:
    """The default priors (module docstring) on camera ``camera``'s free intrinsics in its current model."""
    names = state.param_names(camera)
    name = state.camera_names[camera]
    width, height = state.image_sizes[camera]
    diagonal = float(np.hypot(width, height))
    focal = mean_focal(state, camera)
    r = _corner_radius(state, camera, focal)
    specs = []
    if principal_point:
        why = f"image centre +- {100 * PRINCIPAL_POINT_PRIOR:g} % of the diagonal"
        specs += [PriorSpec(name, "cx", (width - 1) / 2.0, PRINCIPAL_POINT_PRIOR * diagonal, why),
                  PriorSpec(name, "cy", (height - 1) / 2.0, PRINCIPAL_POINT_PRIOR * diagonal, why)]
    radial = f"{100 * RADIAL_PRIOR:g} % displacement at the corner"
    if "k" in names and state.models[camera] in ("SIMPLE_DIVISION", "DIVISION"):
        # lambda r_px^2 = k r^2: the corner displacement
        specs.append(PriorSpec(name, "lambda", 0.0, RADIAL_PRIOR / (r * focal) ** 2, radial))
    for term, power in (("k", 2), ("k1", 2), ("k2", 4)):
        if term in names and not (term == "k" and state.models[camera] in ("SIMPLE_DIVISION", "DIVISION")):
            specs.append(PriorSpec(name, "k1" if term == "k" else term, 0.0, RADIAL_PRIOR / r ** power, radial))
    for term in ("p1", "p2"):
        if term in names:
            specs.append(PriorSpec(name, term, 0.0, TANGENTIAL_PRIOR / (3.0 * r),
                                   f"{100 * TANGENTIAL_PRIOR:g} % tangential displacement at the corner"))
    return tuple(specs)


def _resolve(state: BundleState, spec: PriorSpec) -> Prior | None:
    """A spec on the state's COLMAP parameters; None when the camera's model has no such parameter."""
    if spec.camera not in state.camera_names:
        raise CamcalError(f"prior on {spec.label}: no camera named {spec.camera!r} "
                          f"(cameras: {', '.join(state.camera_names)})")
    camera = state.camera_names.index(spec.camera)
    names = state.param_names(camera)
    model = state.models[camera]
    params = state.params[camera]
    index = {n: i for i, n in enumerate(names)}
    two_focals = "fx" in index
    if spec.name == "aspect":
        return Prior(camera, (index["fx"], index["fy"]), (1.0, -1.0), spec.mean, spec.sigma, spec) if two_focals else None
    if spec.name in ("f", "fx", "fy"):
        if not two_focals:
            return Prior(camera, (index["f"],), (1.0,), spec.mean, spec.sigma, spec)
        if spec.name == "f":
            return Prior(camera, (index["fx"], index["fy"]), (0.5, 0.5), spec.mean, spec.sigma, spec)
        return Prior(camera, (index[spec.name],), (1.0,), spec.mean, spec.sigma, spec)
    if spec.name in ("cx", "cy"):
        return Prior(camera, (index[spec.name],), (1.0,), spec.mean + 0.5, spec.sigma, spec)  # COLMAP's half pixel
    if spec.name == "lambda":
        if model not in ("SIMPLE_DIVISION", "DIVISION"):
            return None
        focal = float(params[index["f" if "f" in index else "fx"]])  # camcal's lambda is in x pixels: k / fx^2
        return Prior(camera, (index["k"],), (1.0,), spec.mean * focal ** 2, spec.sigma * focal ** 2, spec,
                     scale=1.0 / focal ** 2)
    if model in ("SIMPLE_DIVISION", "DIVISION"):
        return None
    term = "k" if spec.name == "k1" and "k" in index else spec.name
    if term not in index:
        return None
    return Prior(camera, (index[term],), (1.0,), spec.mean, spec.sigma, spec)


def resolve_priors(state: BundleState, specs: tuple[PriorSpec, ...], defaults: bool,
                   free: dict[int, set[int]]) -> tuple[tuple[Prior, ...], tuple[PriorSpec, ...]]:
    """The priors of a bundle adjustment on the state's COLMAP models.

    Parameters
    ----------
    state : BundleState
    specs : tuple of PriorSpec
        Given priors; they replace a default on the same intrinsic.
    defaults : bool
        Add :func:`default_specs` on every camera (the principal point's
        only where it is free), and the aspect prior where a model has
        ``fx`` and ``fy``.
    free : dict of int to set of int
        Camera index -> its free COLMAP parameter indices (a prior on a
        held parameter is dropped: it would be a constant).

    Returns
    -------
    priors : tuple of Prior
    unused : tuple of PriorSpec
        Given priors whose intrinsic the camera's model does not have.
    """
    given = {spec.label for spec in specs}
    wanted = list(specs)
    priors, unused = [], []
    if defaults:
        for camera, name in enumerate(state.camera_names):
            names = state.param_names(camera)
            pp_free = all(names.index(n) in free.get(camera, set()) for n in ("cx", "cy"))
            wanted += [spec for spec in default_specs(state, camera, pp_free) if spec.label not in given]
            if "fx" in names and "fy" in names and f"{name}.aspect" not in given:
                focal = 0.5 * float(state.params[camera][names.index("fx")] + state.params[camera][names.index("fy")])
                wanted.append(PriorSpec(name, "aspect", 0.0, ASPECT_PRIOR * focal,
                                        f"square pixels: fx - fy +- {100 * ASPECT_PRIOR:g} % of f"))
    for spec in wanted:
        prior = _resolve(state, spec)
        if prior is None:
            if spec.source == "given":
                unused.append(spec)
            continue
        priors.append(prior)
    kept = tuple(p for p in priors if any(i in free.get(p.camera, set()) for i in p.indices))
    return kept, tuple(unused)


def prior_weights(priors: tuple[Prior, ...], noise_px: float) -> NDArray[np.float64]:
    """``w = s / sigma`` of each prior's residual for a reprojection noise ``s`` px per axis (module docstring)."""
    return np.array([noise_px / prior.sigma for prior in priors], dtype=np.float64)


def posterior_sigma(prior: Prior, covariance: NDArray[np.float64], names: tuple[str, ...],
                    param_names: tuple[str, ...], camera: str) -> float:
    """Sigma of the prior's combination ``a . x`` under a posterior covariance, in the spec's units (NaN if absent)."""
    rows = []
    for i in prior.indices:
        key = f"{camera}.{param_names[i]}"
        if key not in names:
            return float("nan")
        rows.append(names.index(key))
    a = np.asarray(prior.coefficients)
    block = covariance[np.ix_(rows, rows)]
    return float(np.sqrt(max(a @ block @ a, 0.0))) * prior.scale


def undetermined(priors: tuple[Prior, ...], posterior: tuple[float, ...]) -> list[str]:
    """One line per prior whose posterior sigma is above :data:`UNDETERMINED_RATIO` of its own: the data do not fix it."""
    lines = []
    for prior, sigma in zip(priors, posterior):
        prior_sigma = prior.sigma * prior.scale
        if np.isfinite(sigma) and sigma > UNDETERMINED_RATIO * prior_sigma:
            spec = prior.spec
            lines.append(f"{spec.label}: the images barely determine it: posterior sigma {sigma:.3g} against the "
                         f"prior's {prior_sigma:.3g} ({spec.source}; mean {spec.mean:.6g}): the prior decides")
    return lines
