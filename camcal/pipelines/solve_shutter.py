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

Asked to estimate the readout (``--readout-ms estimate``), each camera's
solved frames first go through a rolling-shutter bundle adjustment
(:func:`camcal.geometry.rolling_shutter_ba.estimate_readout`: its
observations undistorted through the solved lens, its poses and points
refined with one readout time): where the plate's motion determines it, the
estimate and its standard deviation (the larger of the observations' noise's
and a jackknife's over blocks of frames) are recorded (provenance
``rolling_shutter.estimate``) and the frames are checked with it; where it
does not (a camera moving straight or sideways at a constant speed), one
line says so and that camera's frames are not checked.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import frame_runs
from camcal.geometry.rolling_shutter import rolling_shutter_frames
from camcal.geometry.rolling_shutter_ba import ReadoutEstimate, estimate_readout
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
    readout_ms : float or None
        Top row to bottom row, in milliseconds; None: estimated from the solved plate.
    threshold_px : float
        Frames whose points move more than this are flagged.
    fps : float or None
        The plate's frame rate (None: a movie's own, else :data:`DEFAULT_FPS`).
    """

    readout_ms: float | None
    threshold_px: float = DEFAULT_THRESHOLD_PX
    fps: float | None = None


def shutter_spec(readout_ms: float | str | None, threshold_px: float = DEFAULT_THRESHOLD_PX,
                 fps: float | None = None) -> ShutterSpec | None:
    """The check a solve is asked for: ``readout_ms`` in ms, ``"typical"`` (:data:`TYPICAL_READOUT_MS`) or
    ``"estimate"`` (from the solved plate); None without one. Bad values are one error each."""
    if readout_ms is None:
        return None
    if isinstance(readout_ms, str) and readout_ms.strip().lower() == "estimate":
        readout_ms = None
    elif isinstance(readout_ms, str):
        if readout_ms.strip().lower() == "typical":
            readout_ms = TYPICAL_READOUT_MS
        else:
            try:
                readout_ms = float(readout_ms)
            except ValueError:
                raise CamcalError(f"the readout time must be a number of milliseconds, 'typical' or 'estimate', got "
                                  f"{readout_ms!r}") from None
    if readout_ms is not None and (not np.isfinite(readout_ms) or readout_ms <= 0):
        raise CamcalError(f"the readout time must be a positive number of milliseconds, got {readout_ms}")
    if not np.isfinite(threshold_px) or threshold_px <= 0:
        raise CamcalError(f"the rolling-shutter threshold must be a positive number of pixels, got {threshold_px}")
    if fps is not None and (not np.isfinite(fps) or fps <= 0):
        raise CamcalError(f"the frame rate must be a positive number of frames per second, got {fps}")
    return ShutterSpec(None if readout_ms is None else float(readout_ms), float(threshold_px),
                       None if fps is None else float(fps))


def check_rolling_shutter(reconstruction, rig: Rig, colmap_names: dict[str, str], spec: ShutterSpec,
                          frame_interval_s: float, fps: float, seed: int = 0) -> tuple[Rig, list[str]]:
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
        Its readout None: estimated per camera from the plate (module notes).
    frame_interval_s : float
        Seconds between consecutive frame numbers (``every / fps`` for a movie's kept frames).
    fps : float
        The frame rate the interval came from (recorded).
    seed : int
        Seeds the estimate's choice of points.
    """
    checks: dict[int, dict[str, ShutterCheck]] = {frame.index: {} for frame in rig.frames}
    flagged: dict[str, list[int]] = {}
    largest = (0.0, "", 0)
    untimed: list[str] = []
    estimates: dict[str, dict] = {}
    lines: list[str] = []
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
        times = np.array([number for number, _, _ in timed], dtype=float) * frame_interval_s
        readout_ms = spec.readout_ms
        if readout_ms is None:
            try:
                estimate = _estimate(reconstruction, camera.image_size[1], posed, times, [n for _, _, n in timed],
                                     seed)
            except CamcalError as problem:  # too little to estimate from: said, like an undetermined readout
                estimates[camera.name] = {"determined": False, "reason": str(problem)}
                lines.append(f"rolling-shutter readout of {camera.name}: cannot be estimated ({problem}), so its "
                             "frames are not checked; give --readout-ms")
                continue
            estimates[camera.name] = _estimate_record(estimate)
            lines.append(_estimate_line(camera.name, estimate))
            if not estimate.determined:
                continue
            readout_ms = abs(estimate.readout_s) * 1000.0  # a bottom-to-top readout moves the points as far
        points = [_observed_points(reconstruction, name) for _, _, name in timed]
        results = rolling_shutter_frames(np.array([c.K for c in posed]), camera.image_size[1],
                                         np.array([c.R for c in posed]), np.array([c.c for c in posed]), times,
                                         points, readout_ms / 1000.0, spec.threshold_px)
        for (number, index, _), result in zip(timed, results):
            checks[index][camera.name] = ShutterCheck(result.displacement_px, result.flagged)
            if result.flagged:
                flagged.setdefault(camera.name, []).append(number)
            largest = max(largest, (result.displacement_px, camera.name, number))
    frames = tuple(dataclasses.replace(frame, rolling_shutter=checks[frame.index]) for frame in rig.frames)
    if spec.readout_ms is None:
        record: dict = {"estimate": estimates}
        head = f"rolling shutter (estimated readout at {fps:g} fps, threshold {spec.threshold_px:g} px)"
    else:
        record = {"readout_ms": spec.readout_ms}
        head = f"rolling shutter (readout {spec.readout_ms:g} ms at {fps:g} fps, threshold {spec.threshold_px:g} px)"
    provenance = {**rig.provenance, "rolling_shutter": {**record, "fps": fps, "threshold_px": spec.threshold_px}}
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
    if spec.readout_ms is not None or any(entry["determined"] for entry in estimates.values()):
        lines.append(line)
    return dataclasses.replace(rig, frames=frames, provenance=provenance), lines


def _estimate(reconstruction, height: int, posed, times: np.ndarray, names: list[str], seed: int) -> ReadoutEstimate:
    """One camera's readout from its solved frames (in time order): their observations undistorted through the
    solved lens into each frame's pinhole pixels (COLMAP's pixel centres at 0.5 moved to 0), rows as observed."""
    frame_of, point_ids, pixels, rows = [], [], [], []
    for k, (camera, name) in enumerate(zip(posed, names)):
        image = reconstruction.find_image_with_name(name)
        observed = [] if image is None else [point for point in image.points2D if point.has_point3D()]
        if not observed:
            continue
        xy = np.array([point.xy for point in observed], dtype=np.float64).reshape(-1, 2)
        normalised = np.asarray(reconstruction.cameras[image.camera_id].cam_from_img(xy), dtype=np.float64)
        frame_of += [k] * len(observed)
        point_ids += [point.point3D_id for point in observed]
        pixels.append(normalised[:, :2] @ camera.K[:2, :2].T + camera.K[:2, 2])
        rows.append(xy[:, 1] - 0.5)
    if not pixels:
        raise CamcalError("no solved frame observes a point")
    ids, point_of = np.unique(point_ids, return_inverse=True)
    xyz = np.array([reconstruction.points3D[int(i)].xyz for i in ids]).reshape(-1, 3)
    return estimate_readout(np.array([c.K for c in posed]), height, np.array([c.R for c in posed]),
                            np.array([c.c for c in posed]), times, xyz, frame_of, point_of, np.concatenate(pixels),
                            np.concatenate(rows), seed=seed)


def _estimate_record(estimate: ReadoutEstimate) -> dict:
    """A camera's entry in the provenance's ``rolling_shutter.estimate`` (the readout only when determined)."""
    record = {"readout_ms": estimate.readout_s * 1000.0} if estimate.determined else {}
    sigmas = [value * 1000.0 if np.isfinite(value) else None  # None: nothing determines it
              for value in (estimate.sigma_s, estimate.noise_sigma_s, estimate.jackknife_sigma_s)]
    return {**record, "sigma_ms": sigmas[0], "noise_sigma_ms": sigmas[1], "jackknife_sigma_ms": sigmas[2],
            "determined": estimate.determined,
            "limit_ms": estimate.limit_s * 1000.0, "rms_px": estimate.rms_px, "frames": estimate.n_frames,
            "points": estimate.n_points, "observations": estimate.n_observations}


def _estimate_line(name: str, estimate: ReadoutEstimate) -> str:
    """What the estimate says in one line: the readout and its standard deviation, or that the data do not tell."""
    used = f"{estimate.n_frames} frames, {estimate.n_points} points, {estimate.n_observations} observations"
    if estimate.determined:
        return (f"rolling-shutter readout of {name} estimated from the plate: {estimate.readout_s * 1000:.2f} +- "
                f"{estimate.sigma_s * 1000:.2f} ms ({used}, {estimate.rms_px:.2f} px RMS; the sigma the larger of the "
                f"observations' noise, {estimate.noise_sigma_s * 1000:.2f} ms, and a jackknife over blocks of frames, "
                f"{estimate.jackknife_sigma_s * 1000:.2f} ms, which also sees the model's misfit; an error every frame "
                "shares alike is in neither)")
    return (f"rolling-shutter readout of {name}: the plate's motion does not determine it (its standard deviation "
            f"{estimate.sigma_s * 1000:.3g} ms is over {estimate.limit_s * 1000:.2g} ms: a camera moving straight or "
            "sideways at a constant speed sees the same with any readout), so its frames are not checked; give "
            "--readout-ms")


def _observed_points(reconstruction, name: str) -> np.ndarray:
    """The 3D points COLMAP image ``name`` observes, shape (N, 3)."""
    image = reconstruction.find_image_with_name(name)
    if image is None:
        return np.zeros((0, 3))
    ids = [point.point3D_id for point in image.points2D if point.has_point3D()]
    return np.array([reconstruction.points3D[i].xyz for i in ids]).reshape(-1, 3)
