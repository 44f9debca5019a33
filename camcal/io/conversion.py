"""Lens conversions between camcal cameras and other formats' models, and what exporters and importers return.

The shared vocabulary of the interchange formats (:mod:`camcal.io.opencv`,
:mod:`camcal.io.kalibr`, :mod:`camcal.io.colmap_text`, :mod:`camcal.io.usd`,
:mod:`camcal.io.nuke`): each imports this module and nothing of
:mod:`camcal.io.interchange`, which finds them by name.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion, fit_distortion, frame_grid
from camcal.model.rig import Camera, Rig

__all__ = [
    "LensConversion",
    "ExportResult",
    "ImportResult",
    "max_pixel_residual",
    "nearest_camera",
    "select_cameras",
]

_GRID_STEP_PX = 16.0


@dataclass(frozen=True)
class LensConversion:
    """How one camera's projection went into (or came from) another format.

    Attributes
    ----------
    camera : str
        Camera name.
    source, target : str
        The model on each side, e.g. ``"division"`` and ``"radtan"``.
    exact : bool
        True when the target projects exactly like the source.
    max_px : float
        Largest distance in pixels between the two projections of the same
        rays over the frame (0.0 when exact).
    loss : str
        What makes it inexact (``"nearest fit"``, or e.g. the format's
        32-bit float attributes).
    """

    camera: str
    source: str
    target: str
    exact: bool
    max_px: float = 0.0
    loss: str = "nearest fit"

    def describe(self) -> str:
        """One line for the command's summary."""
        if self.exact:
            return f"camera {self.camera!r}: {self.source} -> {self.target}: exact"
        return (f"camera {self.camera!r}: {self.source} -> {self.target}: {self.loss}, "
                f"max residual {self.max_px:.3g} px")


@dataclass(frozen=True)
class ExportResult:
    """What an exporter wrote.

    Attributes
    ----------
    paths : tuple of Path
        The files written.
    conversions : tuple of LensConversion
        One per exported camera.
    notes : tuple of str
        What the format does not hold (dropped frames, world pose, ...).
    """

    paths: tuple[Path, ...]
    conversions: tuple[LensConversion, ...]
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class ImportResult:
    """A rig read from another tool's file, with how each camera was converted.

    Attributes
    ----------
    rig : Rig
    conversions : tuple of LensConversion
    notes : tuple of str
    points_xyz : ndarray, shape (N, 3), optional
        Sparse points the file holds (world coordinates), to be written
        beside the rig (:func:`camcal.io.ply.write_points_ply`).
    points_rgb : ndarray, shape (N, 3), uint8, optional
    """

    rig: Rig
    conversions: tuple[LensConversion, ...]
    notes: tuple[str, ...] = ()
    points_xyz: NDArray[np.float64] | None = None
    points_rgb: NDArray[np.uint8] | None = None


def max_pixel_residual(source: Camera, target: Camera, *, lens: bool = True) -> float:
    """Largest pixel distance between two cameras' projections of the same rays.

    For every pixel ``x`` of a 16 px grid over ``source``'s frame (edges
    included), the ray ``r = K_s^-1 undistort_s(x)`` is projected by
    ``target``: ``x' = distort_t(K_t r)``; the result is ``max |x' - x|``.
    With ``lens=False`` both sides are pinholes (for formats without a lens
    model): ``max |K_t r - K_s r|`` over the same rays. Only the intrinsics
    matter (both cameras share the pose).
    """
    distorted = frame_grid(source.image_size, _GRID_STEP_PX)
    ideal = source.distortion.undistort(distorted, source.K)
    rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(source.K).T
    mapped = rays @ target.K.T
    projected = mapped[:, :2] / mapped[:, 2:]
    if lens:
        projected = target.distortion.distort(projected, target.K)
    distance = np.linalg.norm(projected - (distorted if lens else ideal), axis=1)
    distance = distance[np.isfinite(distance)]
    if len(distance) == 0:
        raise CamcalError(f"camera {source.name!r}: no ray of the frame projects through the converted camera")
    return float(distance.max())


def _describe_model(camera: Camera) -> str:
    skew = " with skew" if camera.K[0, 1] != 0.0 else ""
    return f"{camera.distortion.model}{skew}"


def nearest_camera(
    camera: Camera,
    holds: Callable[[Distortion], bool],
    fit_model: str,
    target_name: str,
    *,
    skew: bool = False,
    with_k3: bool | None = None,
) -> tuple[Camera, LensConversion]:
    """``camera`` itself when the format holds its lens (and skew), else the nearest one it holds.

    Parameters
    ----------
    camera : Camera
    holds : callable
        True when the format holds a distortion exactly.
    fit_model : str
        The camcal model to fit when it does not (``opencv``,
        ``polynomial``; see :func:`~camcal.model.distortion.fit_distortion`).
    target_name : str
        The format's name for its model (reported).
    skew : bool
        Whether the format holds ``K[0, 1]``; when not, it is set to 0.
    with_k3 : bool, optional
        Passed to :func:`~camcal.model.distortion.fit_distortion`.

    Returns
    -------
    (Camera, LensConversion)
    """
    has_skew = camera.K[0, 1] != 0.0
    if not camera.distortion.has_correction and holds(camera.distortion) and (skew or not has_skew):
        return camera, LensConversion(camera.name, _describe_model(camera), target_name, True)
    K = camera.K.copy()
    if not skew:
        K[0, 1] = 0.0
    distortion = camera.distortion
    if distortion.has_correction or not holds(distortion):  # no format holds a correction field: its nearest fit
        distortion = fit_distortion(distortion, camera.K, camera.image_size, fit_model, with_k3=with_k3).distortion
    converted = replace(camera, K=K, distortion=distortion)
    residual = max_pixel_residual(camera, converted)
    return converted, LensConversion(camera.name, _describe_model(camera), target_name, False, residual)


def select_cameras(rig: Rig, names: Sequence[str] | None) -> tuple[Camera, ...]:
    """The rig's cameras named in ``names`` (all when None), in that order."""
    if not names:
        return rig.cameras
    return tuple(rig.camera(name) for name in names)
