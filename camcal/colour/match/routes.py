"""Camera-to-camera colour matching: make camera B's colours match camera A's.

The same object seen by two cameras of a rig does not get the same RGB. A
*match* is a transform ``f`` from LINEAR camera-B RGB to LINEAR camera-A RGB
(``A ≈ f(B)``), fitted by one of two routes:

chart route (:func:`match_charts`)
    both cameras characterised on the same chart (``*.colour.json`` of kind
    ``characterisation``). Each maps its camera RGB to the common reference
    (CIE XYZ); the residual camera-to-camera CIEDE2000 on the patches,
    ``ΔE(fit_A(A), fit_B(B))``, is what the two characterisations still
    disagree on. The match is fitted to map B's RGB to the camera-A RGB that
    A's characterisation sends to B's XYZ: ``f ≈ fit_A^-1 ∘ fit_B`` (exact,
    ``M_A^-1 M_B``, when both fits and the match are 3x3 matrices).
image route (:func:`match_images`)
    no chart: a rectified stereo pair. Disparity from ``cv2.StereoSGBM`` in
    both directions with a left-right consistency check; pixels kept when
    the disparity is reliable (consistent, away from depth edges, so not
    occluded), and both colours are unsaturated and above the noise floor.
    ``f`` is fitted robustly (:func:`fit_match_model`: least median of
    squares start, then iteratively reweighted least squares with Tukey's
    biweight) against speculars, occlusions and mismatches, and evaluated on
    image tiles held out from the fit.

Models (``MATCH_MODELS``): ``matrix3x3`` (``A = M B``), ``root-polynomial:D``
(*Finlayson et al. 2015*, exposure invariant), ``polynomial:N`` (*Cheung et
al. 2004*), and ``lut3d[:N]``: a smooth 3D lookup table, ``N^3`` nodes over a
box ``[domain_min, domain_max]`` of camera-B RGB, trilinear interpolation,
inputs clamped to the box (as OpenColorIO's Lut3D does), fitted by lattice
regression (*Garcia & Gupta 2009*) with a second-difference smoothness
penalty that extends the table smoothly where the data do not reach.

File: a ``*.colour.json`` of kind ``match`` (:mod:`camcal.colour.match.record`,
listed in :data:`camcal.colour.fit.record.KINDS`)::

    {
      "format": "camcal.colour", "version": 1, "kind": "match",
      "source": "B" | null,          # camera whose RGB goes in
      "target": "A" | null,          # camera whose RGB comes out
      "linearisation": {"channels": [CURVE, CURVE, CURVE]},  # source codes -> linear
      "model": MATCH_MODEL,          # linear source RGB -> linear target RGB
      "fit": {"route": "chart" | "image",
              "robust": "lmeds-irls" | "irls" | "none",
              "n_fit": 12000, "n_inliers": 10890,
              "inlier_threshold": 0.021 | null},  # relative residual (see fit_match_model)
      "evaluation": {
        "metric": "CIE 2000",
        "space": "...",              # how target RGB was turned into XYZ for Delta E
        "train": STATS, "test": STATS | null, "before": STATS | null,
        "n_test_outliers": 40 | null,
        "chart": null | {"common_reference": STATS, "source_vs_reference": STATS | null,
                         "target_vs_reference": STATS | null}
      },
      "provenance": {"tool": "camcal 0.1.0", "created": "...", "source": "..."}
    }

``MATCH_MODEL``: ``{"kind": "matrix3x3" | "polynomial" | "root-polynomial",
"terms": [...], "coefficients": [[...T...] x 3]}`` (rows R, G, B of the
target, ``A = coefficients @ terms(B)``; terms as in
:mod:`camcal.colour.fit.models`), or ``{"kind": "lut3d", "size": N,
"domain_min": [3], "domain_max": [3], "smoothing": s, "table": [[R, G, B] x
N^3]}`` with the table in CLF order: the red index varies slowest, blue
fastest, ``table[(i N + j) N + k]`` is the output at input
``domain_min + (i, j, k) / (N - 1) * (domain_max - domain_min)``.

Evaluation: ``train`` is CIEDE2000 between ``f(B)`` and A on the fit data
(the inliers for a robust fit); ``test`` on held-out data (image route:
held-out tiles, inliers by the fit's threshold, outliers counted in
``n_test_outliers``; chart route: an independent patch set); ``before`` the
same held-out set (or the training set) with B left unmatched. Target RGB
becomes XYZ through camera A's characterisation when one is given, else as
linear Rec. 709 / sRGB primaries with D65 white (``space`` says which).

References
----------
- Hirschmuller, H. (2008). Stereo processing by semiglobal matching and
  mutual information. IEEE TPAMI 30(2), 328-341 (SGBM, left-right check).
- Rousseeuw, P. J. (1984). Least median of squares regression. JASA 79.
- Holland, P. W., Welsch, R. E. (1977). Robust regression using
  iteratively reweighted least-squares. Comm. Statist. 6(9), 813-827.
- Beaton, A. E., Tukey, J. W. (1974). The fitting of power series...
  Technometrics 16(2), 147-185 (the biweight).
- Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction
  using root-polynomial regression. IEEE TIP 24(5), 1460-1470.
- Garcia, E., Gupta, M. R. (2009). Lattice regression. NeurIPS 22.

Modules: :mod:`camcal.colour.match.models` (Lut3D, the model parser),
:mod:`camcal.colour.match.robust` (LMedS + IRLS), :mod:`camcal.colour.match.record`
(the file kind), :mod:`camcal.report.colour_match` (the report); this
module holds the two routes on arrays. The stereo correspondences come from
:func:`camcal.geometry.correspondence.stereo_correspondences`, called by
:func:`camcal.pipelines.colour.match_images`; the file-level pipelines are
:func:`camcal.pipelines.colour.match_image_files` and
:func:`camcal.pipelines.colour.match_patch_files`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.chart.linearise import ChannelCurve, Linearisation, named_function
from camcal.colour.difference import DeltaEStats, delta_E
from camcal.colour.fit.record import ColourFit
from camcal.colour.match.models import LUT_SMOOTHING
from camcal.colour.match.record import ColourMatch, match_provenance
from camcal.colour.match.robust import RobustFit, fit_match_model
from camcal.colour.spectral.data import adapt_XYZ

__all__ = [
    "REC709_SPACE",
    "rec709_XYZ",
    "target_space",
    "MatchResult",
    "match_correspondences",
    "match_charts",
    "encoding_linearisation",
]


REC709_SPACE = "target RGB as linear Rec. 709 primaries, D65 white"


# --------------------------------------------------------------------------
# Colour differences in the target camera's space


def rec709_XYZ(RGB: Any) -> np.ndarray:
    """XYZ (white Y = 1, D65) of RGB read as linear Rec. 709 / sRGB primaries, ``(..., 3)``.

    The Delta E space of a match when the target camera has no
    characterisation (see :data:`REC709_SPACE`).
    """
    colour = require("colour")

    return np.asarray(RGB, dtype=np.float64) @ colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ.T


def target_space(fit_target: ColourFit | None):
    """``(to_XYZ, white_XYZ, description)`` for Delta E of target-camera RGB."""
    if fit_target is None:
        colour = require("colour")

        white = colour.xy_to_XYZ(colour.RGB_COLOURSPACES["sRGB"].whitepoint)
        return rec709_XYZ, np.asarray(white, dtype=np.float64), REC709_SPACE
    name = fit_target.camera or "target"
    return fit_target.apply, np.asarray(fit_target.target_white_XYZ), f"XYZ through the characterisation of {name}"


def _stats(values: np.ndarray) -> dict | None:
    return None if values.size == 0 else DeltaEStats.from_values(values).to_dict()


@dataclass(frozen=True, eq=False)
class MatchResult:
    """A fitted match with the data behind its figures.

    Attributes
    ----------
    match
        The :class:`ColourMatch` (what the file holds).
    fit
        The :class:`RobustFit` on the training samples.
    train_source, train_target
        ``(N, 3)`` training samples (linear B and A RGB).
    test_source, test_target
        ``(M, 3)`` held-out samples (image tiles or independent patches),
        or ``None``.
    test_inliers
        ``(M,)`` held-out samples within the fit's threshold, or ``None``.
    correspondences
        Image route: the stereo correspondences
        (:class:`camcal.geometry.correspondence.Correspondences`, set by
        :func:`camcal.pipelines.colour.match_images`); ``None`` for charts.
    fit_target
        Camera A's characterisation used for Delta E, or ``None``.
    """

    match: ColourMatch
    fit: RobustFit
    train_source: np.ndarray
    train_target: np.ndarray
    test_source: np.ndarray | None = None
    test_target: np.ndarray | None = None
    test_inliers: np.ndarray | None = None
    correspondences: Any = None
    fit_target: ColourFit | None = None


def _tile_split(shape: tuple[int, int], tile: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean ``(H, W)``: pixels of the randomly held-out ``tile`` x ``tile`` tiles."""
    height, width = shape
    rows, cols = -(-height // tile), -(-width // tile)
    held = rng.random((rows, cols)) < fraction
    return np.repeat(np.repeat(held, tile, axis=0), tile, axis=1)[:height, :width]


def match_correspondences(
    RGB_source: Any,
    RGB_target: Any,
    valid: Any,
    *,
    counts: dict | None = None,
    model: str = "matrix3x3",
    robust: str = "lmeds-irls",
    fit_target: ColourFit | None = None,
    source: str | None = None,
    target: str | None = None,
    linearisation: Linearisation | None = None,
    test_fraction: float = 0.25,
    tile_px: int = 16,
    max_samples: int = 40000,
    smoothing: float = LUT_SMOOTHING,
    seed: int = 0,
    provenance_source: str | None = None,
) -> MatchResult:
    """Fit a camera B -> camera A colour match from dense correspondences of a rectified stereo pair.

    Parameters
    ----------
    RGB_source, RGB_target
        ``(H, W, 3)`` LINEAR RGB of camera B (source) sampled at the
        correspondences and of camera A (target), on A's pixel grid (as
        :func:`camcal.geometry.correspondence.stereo_correspondences` gives).
    valid
        ``(H, W)`` bool: the pixels whose correspondence is reliable.
    counts
        Pixel counts ``total``, ``disparity``, ``consistent``, ``valid``
        quoted when too few correspondences remain (``None``: the valid
        count only).
    model, robust, smoothing
        See :func:`fit_match_model`.
    fit_target
        Camera A's characterisation, for Delta E in XYZ; ``None`` reads A's
        RGB as linear Rec. 709 (see the module docstring).
    source, target
        Camera names recorded in the file.
    linearisation
        Camera B's code-value linearisation recorded in the file (identity
        when ``None``).
    test_fraction, tile_px
        Share of ``tile_px`` square image tiles held out from the fit.
    max_samples
        At most this many training pixels (a random subset) enter the fit.
    seed
        Random seed (split, subset, LMedS).

    Returns
    -------
    MatchResult
        ``correspondences`` is ``None`` (the caller that made them sets it).
    """
    if not 0.0 < test_fraction < 1.0:
        raise CamcalError(f"test_fraction must be between 0 and 1, got {test_fraction}")
    valid = np.asarray(valid, dtype=bool)
    rng = np.random.default_rng(seed)
    held = _tile_split(valid.shape, tile_px, test_fraction, rng)
    train_idx = np.flatnonzero(valid & ~held)
    test_idx = np.flatnonzero(valid & held)
    need = 200
    if train_idx.size < need or test_idx.size < 20:
        if counts is None:
            raise CamcalError(f"too few reliable correspondences: {int(valid.sum())} of {valid.size} pixels; "
                              f"need {need} for the fit")
        raise CamcalError(f"too few reliable correspondences: {counts['valid']} of {counts['total']} "
                          f"pixels (disparity {counts['disparity']}, left-right consistent "
                          f"{counts['consistent']}); need {need} for the fit")
    if train_idx.size > max_samples:
        train_idx = np.sort(rng.choice(train_idx, max_samples, replace=False))
    src = np.asarray(RGB_source, dtype=np.float64).reshape(-1, 3)
    tgt = np.asarray(RGB_target, dtype=np.float64).reshape(-1, 3)
    fit = fit_match_model(src[train_idx], tgt[train_idx], model, robust=robust, smoothing=smoothing, seed=seed)
    to_XYZ, white, space = target_space(fit_target)
    test_B, test_A = src[test_idx], tgt[test_idx]
    inliers = fit.is_inlier(test_B, test_A)
    train_B, train_A = src[train_idx], tgt[train_idx]
    train_keep = fit.inliers

    def dE(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
        return delta_E(to_XYZ(pred), to_XYZ(ref), white)

    evaluation = {
        "metric": "CIE 2000",
        "space": space,
        "train": _stats(dE(fit.model.apply(train_B[train_keep]), train_A[train_keep])),
        "test": _stats(dE(fit.model.apply(test_B[inliers]), test_A[inliers])),
        "before": _stats(dE(test_B[inliers], test_A[inliers])),
        "n_test_outliers": int(np.sum(~inliers)),
        "chart": None,
    }
    match = ColourMatch(
        model=fit.model, evaluation=evaluation,
        fit={"route": "image", "robust": robust, "n_fit": int(train_idx.size), "n_inliers": int(train_keep.sum()),
             "inlier_threshold": fit.threshold},
        source=source, target=target, linearisation=linearisation or Linearisation.identity(),
        provenance=match_provenance(provenance_source),
    )
    return MatchResult(match, fit, train_B, train_A, test_B, test_A, inliers, None, fit_target)


# --------------------------------------------------------------------------
# Chart route


def _invert(fit: ColourFit, XYZ: np.ndarray, start: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Linear RGB that ``fit`` maps to ``XYZ``: batched Newton steps, forward-difference Jacobians."""
    x = np.array(start, dtype=np.float64)
    h = 1e-6
    for _ in range(iterations):
        y = fit.apply(x)
        step = y - XYZ
        if np.max(np.abs(step)) < 1e-12:
            break
        J = np.stack([(fit.apply(x + h * np.eye(3)[k]) - y) / h for k in range(3)], axis=2)  # (N, 3, 3)
        x = x - np.linalg.solve(J, step[..., None])[..., 0]
    return x


def match_charts(
    fit_source: ColourFit,
    fit_target: ColourFit,
    codes_source: Any,
    codes_target: Any,
    *,
    XYZ_reference: Any = None,
    test: tuple[Any, Any] | None = None,
    model: str = "matrix3x3",
    robust: str = "none",
    source: str | None = None,
    target: str | None = None,
    provenance_source: str | None = None,
) -> MatchResult:
    """Match camera B to camera A through their characterisations on one chart.

    Parameters
    ----------
    fit_source, fit_target
        Characterisations of B (source) and A (target) on the same chart.
    codes_source, codes_target
        ``(N, 3)`` code values of the same N patches in B and in A (in each
        fit's encoding: its ``linearise`` is applied).
    XYZ_reference
        ``(N, 3)`` reference XYZ of the patches in A's target white, to
        report each camera's own characterisation error; optional.
    test
        ``(codes_source, codes_target)`` of independent patches, optional.
    model, robust
        The match model and fitting (see :func:`fit_match_model`).
    source, target
        Camera names (default: the fits' ``camera``).

    Returns
    -------
    MatchResult

    Notes
    -----
    Both cameras go to XYZ: ``X_A = fit_A(lin_A)``, ``X_B = fit_B(lin_B)``
    (adapted to A's target white with CAT02 when the whites differ). The
    camera-to-camera residual on the common reference is
    ``ΔE2000(X_A, X_B)``. The training target of the match is
    ``fit_A^-1(X_B)`` (batched Newton, started from ``lin_A``), so that
    ``fit_A(f(lin_B)) ≈ fit_B(lin_B)``; ``train`` / ``test`` report
    ``ΔE2000(fit_A(f(lin_B)), X_A)``, the camera-to-camera difference
    after matching, and ``before`` the same with ``f`` the identity.
    """
    to_XYZ, white, space = target_space(fit_target)
    source_white = np.asarray(fit_source.target_white_XYZ)

    def prepare(codes_B: Any, codes_A: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lin_B = fit_source.linearise(np.asarray(codes_B, dtype=np.float64))
        lin_A = fit_target.linearise(np.asarray(codes_A, dtype=np.float64))
        if lin_B.ndim != 2 or lin_B.shape != lin_A.shape:
            raise CamcalError(f"source and target patches must both be (N, 3), got {lin_B.shape} and {lin_A.shape}")
        X_B = fit_source.apply(lin_B)
        if not np.allclose(source_white, white, atol=1e-6):
            X_B = adapt_XYZ(X_B, source_white, white, "CAT02")
        return lin_B, lin_A, X_B, to_XYZ(lin_A)

    lin_B, lin_A, X_B, X_A = prepare(codes_source, codes_target)
    goal = _invert(fit_target, X_B, lin_A)
    fit = fit_match_model(lin_B, goal, model, robust=robust)
    common = delta_E(X_B, X_A, white)
    chart = {"common_reference": DeltaEStats.from_values(common).to_dict(),
             "source_vs_reference": None, "target_vs_reference": None}
    if XYZ_reference is not None:
        ref = np.asarray(XYZ_reference, dtype=np.float64)
        if ref.shape != X_A.shape:
            raise CamcalError(f"reference XYZ must be {X_A.shape}, got {ref.shape}")
        chart["source_vs_reference"] = _stats(delta_E(X_B, ref, white))
        chart["target_vs_reference"] = _stats(delta_E(X_A, ref, white))
    test_B = test_A = None
    test_stats = None
    if test is not None:
        test_B, test_A, _, X_A_test = prepare(*test)
        test_stats = _stats(delta_E(to_XYZ(fit.model.apply(test_B)), X_A_test, white))
    before_B, before_A = (lin_B, lin_A) if test is None else (test_B, test_A)
    evaluation = {
        "metric": "CIE 2000",
        "space": space,
        "train": _stats(delta_E(to_XYZ(fit.model.apply(lin_B)), X_A, white)),
        "test": test_stats,
        "before": _stats(delta_E(to_XYZ(before_B), to_XYZ(before_A), white)),
        "n_test_outliers": None,
        "chart": chart,
    }
    match = ColourMatch(
        model=fit.model, evaluation=evaluation,
        fit={"route": "chart", "robust": robust, "n_fit": int(lin_B.shape[0]), "n_inliers": int(fit.inliers.sum()),
             "inlier_threshold": fit.threshold},
        source=source if source is not None else fit_source.camera,
        target=target if target is not None else fit_target.camera,
        linearisation=fit_source.linearisation, provenance=match_provenance(provenance_source),
    )
    inliers = None if test_B is None else np.ones(test_B.shape[0], dtype=bool)
    return MatchResult(match, fit, lin_B, lin_A, test_B, test_A, inliers, None, fit_target)


def encoding_linearisation(name: str) -> Linearisation:
    """Linearisation of a named encoding: ``linear`` or a colour-science transfer function."""
    if name == "linear":
        return Linearisation.identity()
    return Linearisation((ChannelCurve("named", {"function": named_function(name), "scale": 1.0}),) * 3)
