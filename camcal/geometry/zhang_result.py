"""A board calibration's result, a lens model's held-out score, and the quality gate a calibration must pass.

:class:`CalibrationResult` is what :func:`camcal.geometry.zhang.calibrate_board` returns; :class:`ModelScore` one
lens model's cross-validated error in its ``model="auto"`` ranking; :func:`quality_problems` and
:func:`fold_radius_px` say what makes a calibration unusable by its own figures (the gate the command line applies
before writing, and the ranking before taking a model).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.board_shape import BoardShape
from camcal.model.rig import Camera, Rig

__all__ = ["MAX_RMS_PX", "MAX_FOCAL_SIGMA_REL", "ModelScore", "ranking_lines", "CalibrationResult",
           "quality_problems", "fold_radius_px"]

#: Quality gate (:func:`quality_problems`): a calibration beyond these is not written without --force.
MAX_RMS_PX = 1.5


MAX_FOCAL_SIGMA_REL = 0.05


@dataclass(frozen=True)
class ModelScore:
    """One lens model's cross-validated error in ``model="auto"``.

    Attributes
    ----------
    model : str
        A name of :data:`MODELS`.
    rms_px : float or None
        RMS over every held-out view of every fold (each view posed by PnP
        with the fold's intrinsics held), in pixels; None when ranked out.
    n_params : int
        Lens parameters (focal lengths, principal point, distortion).
    reason : str
        Why the model was ranked out (empty when scored).
    estimate_px : float or None
        The leave-one-view-out RMS estimated from the model's one fit on every training view
        (:mod:`camcal.geometry.zhang_loo`), when the ranking screened the model with it; a model it screened
        out has this and no ``rms_px``; the default ranking (:mod:`camcal.geometry.zhang_quick`) scores by it
        (``rms_px`` equal to it).
    """

    model: str
    rms_px: float | None
    n_params: int
    reason: str = ""
    estimate_px: float | None = None

    @property
    def estimated(self) -> bool:
        """True when ``rms_px`` is the one-fit leave-one-view-out estimate itself (the default ``auto``'s
        ranking, :mod:`camcal.geometry.zhang_quick`), not the folds' figure."""
        return self.rms_px is not None and self.rms_px == self.estimate_px

    @property
    def screened_out(self) -> bool:
        """True when the one-fit estimate left the model out of the exact folds (it was fitted, not refused)."""
        return self.rms_px is None and self.estimate_px is not None

    def describe(self) -> str:
        """``opencv-rational  0.3821 px  (12 parameters)`` or ``... ranked out: <reason>``."""
        if self.rms_px is None:
            return f"{self.model}: ranked out: {self.reason}"
        how = "estimated leave one view out" if self.estimated else "held out"
        return f"{self.model}: {self.rms_px:.4f} px {how} ({self.n_params} parameters)"


def ranking_lines(scores: Sequence[ModelScore]) -> list[str]:
    """:meth:`ModelScore.describe` of each score in order, the models ranked out for the same reason on one line.

    ``none, division: ranked out: <reason>`` at the place of the first of them: a reason several models share
    (a missing extra refuses every fit on the Ceres engine) is said once.
    """
    shared: dict[str, list[str]] = {}
    for score in scores:
        if score.rms_px is None:
            shared.setdefault(score.reason, []).append(score.model)
    lines = []
    for score in scores:
        if score.rms_px is not None:
            lines.append(score.describe())
        elif shared[score.reason][0] == score.model:
            lines.append(f"{', '.join(shared[score.reason])}: ranked out: {score.reason}")
    return lines


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated camera or rig with its residuals and uncertainty.

    Attributes
    ----------
    rig : Rig
        The cameras; the first is the reference (``R = I``, ``c = 0``),
        lengths in the board's units. Each camera's ``quality`` holds
        ``rms_px``, ``worst_px``, ``n_views``, ``n_observations``,
        ``heldout_rms_px`` (with held-out views) and ``sigma`` (one-sigma of
        fx, fy, cx, cy, the distortion parameters and, for the other
        cameras, ``rotation_deg``, ``baseline_rel`` and
        ``baseline_direction_deg`` from the reference; see
        :mod:`camcal.model.quality`).
    residuals_px : ndarray, shape (M, 2)
        ``projected - detected`` for every corner kept, in pixels.
    points_px : ndarray, shape (M, 2)
        The detected corners of those residuals.
    camera_of_point, image_of_point : ndarray of int, shape (M,)
        Index into ``rig.cameras`` and into :attr:`images` of each corner.
    images : tuple of (str, str)
        ``(camera name, image name)`` of every image kept.
    rms_px, worst_px : float
        RMS and largest reprojection error (per-corner norm), in pixels.
    outliers : tuple of (str, str)
        ``(camera name, image name)`` of the images dropped as outliers.
    covariance : ndarray, shape (P, P)
        ``sigma^2 (J^T J)^-1`` of the camera parameters named in
        :attr:`parameter_names` (board poses marginalised out); rotations
        are rotation vectors in radians, translations in board units.
    parameter_names : tuple of str
        ``"<camera>.<name>"``, e.g. ``left.fx``, ``right.k1``, ``right.rx``, ``right.tx``
        (``cam_from_reference``: rotation vector applied on the left, and translation).
    model : str
        The distortion model fitted (the one chosen when ``model="auto"``).
    heldout_rms_px : float or None
        RMS over the held-out views (PnP with the intrinsics held), in pixels.
    heldout_images : tuple of (str, str)
        ``(camera name, image name)`` of the held-out views.
    heldout_view_rms_px : tuple of float
        The RMS of each held-out view, in the order of :attr:`heldout_images`.
    model_heldout_rms_px : dict of str to float
        ``model="auto"``: the cross-validated RMS of every model that could
        be fitted (:func:`rank_models`).
    model_ranking : tuple of ModelScore
        ``model="auto"``: every model, best first, those ranked out last
        with their reason (:meth:`ModelScore.describe` prints one line each).
    relabelled : tuple of (str, str)
        Views whose corner labelling was turned by a half turn or mirrored
        (seen from the back) to agree with the rig (symmetric or two-sided
        chessboards only; :attr:`notes` says which).
    dropped : tuple of (str, str)
        Views dropped because no labelling agreed with the rig.
    notes : tuple of str
        Constraints the fit imposed beyond the model's definition.
    board_poses : tuple of (int, ndarray, ndarray)
        ``(frame, R, t)`` of every frame solved: ``reference_from_board``
        (a board point ``X`` is at ``R X + t`` in the reference camera's
        coordinates), in the board's units.
    heldout_residuals_px, heldout_points_px : ndarray, shape (H, 2)
        ``projected - detected`` and the detected corners of the held-out views.
    heldout_camera_of_point : ndarray of int, shape (H,)
        Index into ``rig.cameras`` of each held-out corner.
    board_shape : BoardShape or None
        The board's fitted surface (:mod:`camcal.geometry.board_shape`); None for a flat board. The held-out
        views are posed against it; the rig's ``provenance.board_shape`` stores it.
    shape_ranking : tuple of ModelScore
        ``board_shape="auto"``: the flat board and every shape scored (``<model>@board-<shape>``), best first,
        scored on the same folds as the lens models.
    """

    rig: Rig
    residuals_px: NDArray[np.float64]
    points_px: NDArray[np.float64]
    camera_of_point: NDArray[np.int64]
    image_of_point: NDArray[np.int64]
    images: tuple[tuple[str, str], ...]
    rms_px: float
    worst_px: float
    outliers: tuple[tuple[str, str], ...]
    covariance: NDArray[np.float64]
    parameter_names: tuple[str, ...]
    model: str = "polynomial"
    heldout_rms_px: float | None = None
    heldout_images: tuple[tuple[str, str], ...] = ()
    heldout_view_rms_px: tuple[float, ...] = ()
    model_heldout_rms_px: Mapping[str, float] = field(default_factory=dict)
    model_ranking: tuple[ModelScore, ...] = ()
    relabelled: tuple[tuple[str, str], ...] = ()
    dropped: tuple[tuple[str, str], ...] = ()
    notes: tuple[str, ...] = ()
    board_poses: tuple[tuple[int, NDArray[np.float64], NDArray[np.float64]], ...] = ()
    heldout_residuals_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    heldout_points_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    heldout_camera_of_point: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    board_shape: BoardShape | None = None
    shape_ranking: tuple[ModelScore, ...] = ()

    @property
    def n_outliers(self) -> int:
        """Number of images dropped as outliers."""
        return len(self.outliers)

    @property
    def per_image_rms_px(self) -> dict[tuple[str, str], float]:
        """RMS reprojection error of each kept image, in pixels."""
        squared = np.sum(self.residuals_px**2, axis=1)
        sums = np.bincount(self.image_of_point, squared, minlength=len(self.images))
        counts = np.bincount(self.image_of_point, minlength=len(self.images))
        return {key: float(np.sqrt(s / n)) for key, s, n in zip(self.images, sums, counts)}

    def summary(self) -> str:
        """``RMS reprojection error: 0.19 px (worst 0.84 px, 3 outliers of 50 images)``, held-out RMS beside."""
        text = (
            f"RMS reprojection error: {self.rms_px:.3f} px (worst {self.worst_px:.3f} px, "
            f"{self.n_outliers} outlier images of {len(self.images) + self.n_outliers}, "
            f"{len(self.residuals_px)} corners)"
        )
        if self.heldout_rms_px is not None:
            text += f"; held-out RMS {self.heldout_rms_px:.4f} px over {len(self.heldout_images)} views (training {self.rms_px:.4f} px)"
        return text


def quality_problems(result: CalibrationResult) -> list[str]:
    """What makes a calibration unusable by its own figures (empty when it looks sound).

    A camera is refused when its principal point lies outside the image,
    its RMS exceeds :data:`MAX_RMS_PX`, or its focal length's one-sigma
    exceeds :data:`MAX_FOCAL_SIGMA_REL` of the focal length.
    """
    problems = []
    for camera in result.rig.cameras:
        width, height = camera.image_size
        cx, cy = camera.K[0, 2], camera.K[1, 2]
        if not (0 <= cx <= width - 1 and 0 <= cy <= height - 1):
            problems.append(f"{camera.name}: principal point ({cx:.0f}, {cy:.0f}) outside the {width}x{height} image")
        rms = camera.quality.get("rms_px", 0.0)
        if rms > MAX_RMS_PX:
            problems.append(f"{camera.name}: RMS {rms:.2f} px > {MAX_RMS_PX} px")
        sigma_fx = camera.quality.get("sigma", {}).get("fx", 0.0)
        if sigma_fx > MAX_FOCAL_SIGMA_REL * abs(camera.K[0, 0]):
            problems.append(f"{camera.name}: fx {camera.K[0, 0]:.0f} +/- {sigma_fx:.0f} px "
                            f"(> {100 * MAX_FOCAL_SIGMA_REL:.0f} %)")
    return problems


#: Directions from the principal point along which :func:`fold_radius_px` follows the lens, and its step in pixels.
_FOLD_DIRECTIONS = 72


_FOLD_STEP_PX = 1.0


def fold_radius_px(camera: Camera) -> float | None:
    """Distance from the principal point at which the lens stops mapping the image one-to-one, within the largest
    circle about the principal point that the image holds (None when it does not fold there).

    Along :data:`_FOLD_DIRECTIONS` lines out of the principal point, every :data:`_FOLD_STEP_PX` pixels, the ray of
    each pixel (:meth:`Distortion.rays_from_pixels`) must exist and its angle from the optical axis must grow: a
    lens whose angle stops growing (or has no ray) there maps two parts of the image onto one field, and every
    point it would have to project beyond that radius is lost. Polynomial radial models fitted on views that leave
    the image's rim empty can turn over before the rim (Kannala & Brandt 2006 discuss the same for their
    polynomial in the angle); a held-out view out there is then posed far off.
    """
    width, height = camera.image_size
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    radius = min(cx, cy, width - 1 - cx, height - 1 - cy)
    if radius <= _FOLD_STEP_PX:
        return None
    steps = np.arange(_FOLD_STEP_PX, radius + _FOLD_STEP_PX, _FOLD_STEP_PX)
    angles = np.linspace(0.0, 2.0 * np.pi, _FOLD_DIRECTIONS, endpoint=False)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    pixels = np.array([cx, cy]) + (steps[None, :, None] * directions[:, None, :]).reshape(-1, 2)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        rays = camera.distortion.rays_from_pixels(pixels, camera.K).reshape(len(angles), len(steps), 3)
        theta = np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2])
    bad = ~np.isfinite(theta)
    bad[:, 1:] |= ~(np.diff(theta, axis=1) > 0.0)
    if not bad.any():
        return None
    return float(steps[np.argmax(bad, axis=1)[bad.any(axis=1)].min()])
