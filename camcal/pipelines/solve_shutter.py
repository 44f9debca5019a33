"""The rolling shutter's effect on each solved frame (``solve --readout-ms``): flagged frames, in the rig.

After the solve, each camera's frames (in the order of their plate frame
numbers, the last number in each image's name; the rig's frame order when
a name has none or two share one, said) are timed at ``number * frame_interval`` and their velocities
taken from their solved neighbours; the points each image observes (its
COLMAP observations) give the displacement
(:func:`camcal.geometry.rolling_shutter.rolling_shutter_frames`). Each frame
of the rig then carries, per camera, the largest displacement and whether it
passed the threshold (:class:`camcal.model.rig_frames.ShutterCheck`), and
the rig's provenance the readout time, frame rate and threshold.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import frame_runs
from camcal.geometry.rolling_shutter import rolling_shutter_frames
from camcal.model.rig import Rig
from camcal.model.rig_frames import ShutterCheck
from camcal.pipelines.solve_inputs import plate_frame_number

__all__ = ["DEFAULT_FPS", "DEFAULT_THRESHOLD_PX", "TYPICAL_READOUT_MS", "ShutterSpec", "check_rolling_shutter",
           "shutter_spec"]

#: a consumer camera's readout time (ms), top row to bottom row, taken when asked for ``typical``.
TYPICAL_READOUT_MS = 30.0
#: a frame is flagged when its points move more than this many pixels during the readout.
DEFAULT_THRESHOLD_PX = 1.0
#: the frame rate of a plate (an image sequence) when none is given.
DEFAULT_FPS = 24.0


@dataclass(frozen=True)
class ShutterSpec:
    """A readout time to check the solved frames with.

    Attributes
    ----------
    readout_ms : float
        Top row to bottom row, in milliseconds.
    threshold_px : float
        Frames whose points move more than this are flagged.
    fps : float or None
        The plate's frame rate (None: a movie's own, else :data:`DEFAULT_FPS`).
    """

    readout_ms: float
    threshold_px: float = DEFAULT_THRESHOLD_PX
    fps: float | None = None


def shutter_spec(readout_ms: float | str | None, threshold_px: float = DEFAULT_THRESHOLD_PX,
                 fps: float | None = None) -> ShutterSpec | None:
    """The check a solve is asked for: ``readout_ms`` in ms, or ``"typical"`` (:data:`TYPICAL_READOUT_MS`); None
    without one. Bad values are one error each."""
    if readout_ms is None:
        return None
    if isinstance(readout_ms, str):
        if readout_ms.strip().lower() == "typical":
            readout_ms = TYPICAL_READOUT_MS
        else:
            try:
                readout_ms = float(readout_ms)
            except ValueError:
                raise CamcalError(f"the readout time must be a number of milliseconds or 'typical', got "
                                  f"{readout_ms!r}") from None
    if not np.isfinite(readout_ms) or readout_ms <= 0:
        raise CamcalError(f"the readout time must be a positive number of milliseconds, got {readout_ms}")
    if not np.isfinite(threshold_px) or threshold_px <= 0:
        raise CamcalError(f"the rolling-shutter threshold must be a positive number of pixels, got {threshold_px}")
    if fps is not None and (not np.isfinite(fps) or fps <= 0):
        raise CamcalError(f"the frame rate must be a positive number of frames per second, got {fps}")
    return ShutterSpec(float(readout_ms), float(threshold_px), None if fps is None else float(fps))


def check_rolling_shutter(reconstruction, rig: Rig, colmap_names: dict[str, str], spec: ShutterSpec,
                          frame_interval_s: float, fps: float) -> tuple[Rig, list[str]]:
    """Each solved frame's rolling-shutter displacement per camera, in the rig's frames, and what to say.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        The solved model (its observations give each image's points), in the rig's world.
    rig : Rig
        The solved rig (its frames name their images as ``colmap_names``' keys).
    colmap_names : dict of str to str
        Each frame image's path as the rig has it -> COLMAP's image name.
    spec : ShutterSpec
    frame_interval_s : float
        Seconds between consecutive frame numbers (``every / fps`` for a movie's kept frames).
    fps : float
        The frame rate the interval came from (recorded).
    """
    checks: dict[int, dict[str, ShutterCheck]] = {frame.index: {} for frame in rig.frames}
    flagged: dict[str, list[int]] = {}
    largest = (0.0, "", 0)
    untimed: list[str] = []
    for camera in rig.cameras:
        mine = [frame for frame in rig.frames if camera.name in frame.images]
        numbers = [plate_frame_number(Path(frame.images[camera.name])) for frame in mine]
        if None in numbers or len(set(numbers)) != len(numbers):  # no frame numbers to time by: the rig's order
            numbers = [frame.index for frame in mine]
            untimed.append(camera.name)
        timed = sorted((number, frame.index, colmap_names[frame.images[camera.name]])
                       for number, frame in zip(numbers, mine))
        if not timed:
            continue
        posed = [rig.camera_at_frame(camera.name, index) for _, index, _ in timed]
        points = [_observed_points(reconstruction, name) for _, _, name in timed]
        results = rolling_shutter_frames(np.array([c.K for c in posed]), camera.image_size[1],
                                         np.array([c.R for c in posed]), np.array([c.c for c in posed]),
                                         np.array([number for number, _, _ in timed], dtype=float) * frame_interval_s,
                                         points, spec.readout_ms / 1000.0, spec.threshold_px)
        for (number, index, _), result in zip(timed, results):
            checks[index][camera.name] = ShutterCheck(result.displacement_px, result.flagged)
            if result.flagged:
                flagged.setdefault(camera.name, []).append(number)
            largest = max(largest, (result.displacement_px, camera.name, number))
    frames = tuple(dataclasses.replace(frame, rolling_shutter=checks[frame.index]) for frame in rig.frames)
    provenance = {**rig.provenance, "rolling_shutter": {"readout_ms": spec.readout_ms, "fps": fps,
                                                        "threshold_px": spec.threshold_px}}
    head = f"rolling shutter (readout {spec.readout_ms:g} ms at {fps:g} fps, threshold {spec.threshold_px:g} px)"
    worst = f"largest {largest[0]:.2f} px ({largest[1]} frame {largest[2]})" if largest[1] else "no points"
    if not flagged:
        line = f"{head}: no frame flagged; {worst}"
    else:
        parts = [f"{name} frames {', '.join(frame_runs(sorted(numbers)))} ({len(numbers)})"
                 for name, numbers in flagged.items()]
        line = f"{head}: flagged {'; '.join(parts)}; {worst}"
    if untimed:
        line += (f" ({', '.join(untimed)}: the image names carry no distinct frame numbers, so the frames were timed "
                 "by their order, one frame interval apart)")
    return dataclasses.replace(rig, frames=frames, provenance=provenance), [line]


def _observed_points(reconstruction, name: str) -> np.ndarray:
    """The 3D points COLMAP image ``name`` observes, shape (N, 3)."""
    image = reconstruction.find_image_with_name(name)
    if image is None:
        return np.zeros((0, 3))
    ids = [point.point3D_id for point in image.points2D if point.has_point3D()]
    return np.array([reconstruction.points3D[i].xyz for i in ids]).reshape(-1, 3)
