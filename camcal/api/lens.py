"""``camcal.lens_rig``: a camera at a lens state of a lens profile, or per frame from lens metadata, as ``lens``.

The profile (``camcal calibrate profile``) gives every parameter at any
focal length and focus distance (:func:`camcal.geometry.lens_profile.camera_at`);
this function checks the states asked for against the calibrated range and
writes a one-camera rig, with a lens per frame when given a metadata CSV.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.model.lens_profile import LensProfile
    from camcal.model.rig import Rig

__all__ = ["LensRig", "lens_rig"]

#: How far (relative) a state may sit outside the calibrated range and still count as inside it (rounding).
_RANGE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class LensRig:
    """What :func:`lens_rig` made and wrote.

    Attributes
    ----------
    rig : Rig
        One camera at the (first) lens state; with metadata, a frame per row, each with its lens.
    states : tuple of (int or None, float, float)
        ``(frame, focal_mm, focus_m)`` of every lens made (frame None for a single state).
    extrapolated : tuple of int or None
        The frames (None: the single state) outside the calibrated range, made with ``extrapolate``.
    worst_sigma_px : float
        The largest worst-direction projection sigma over the image at those states.
    files : tuple of (Path, str)
    """

    rig: Rig
    states: tuple[tuple[int | None, float, float], ...]
    extrapolated: tuple[int | None, ...]
    worst_sigma_px: float
    files: tuple[tuple[Path, str], ...] = ()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig file (atomically) and return its path."""
        return self.rig.save(path)

    def lines(self) -> list[str]:
        """What ``camcal lens`` prints."""
        camera = self.rig.cameras[0]
        K, sigma = camera.K, camera.quality.sigma
        lines = []
        if self.rig.frames:
            first, last = self.states[0], self.states[-1]
            lines.append(f"{len(self.states)} frames ({first[0]}-{last[0]}): focal {min(s[1] for s in self.states):g}"
                         f"-{max(s[1] for s in self.states):g} mm, focus {_distance(min(s[2] for s in self.states))}"
                         f" to {_distance(max(s[2] for s in self.states))}")
        lines.append(f"{camera.name} at {self.states[0][1]:g} mm, focus {_distance(self.states[0][2])}: "
                     f"fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  principal point "
                     f"({K[0, 2]:.2f}, {K[1, 2]:.2f}) +/- ({sigma['cx']:.2f}, {sigma['cy']:.2f}) px  "
                     + "  ".join(f"{k} {v:.6g}" for k, v in camera.distortion.params.items()))
        lines.append(f"worst projection sigma over the image: {self.worst_sigma_px:.3g} px")
        if self.extrapolated:
            which = "the state" if self.extrapolated == (None,) else \
                f"{len(self.extrapolated)} frames ({', '.join(str(f) for f in self.extrapolated[:8])}" \
                + (", ...)" if len(self.extrapolated) > 8 else ")")
            lines.append(f"extrapolated beyond the calibrated range (--extrapolate): {which}; its sigma does not "
                         "cover how far the lens departs from the surfaces there")
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``camcal lens --json``."""
        camera = self.rig.cameras[0]
        return {"K": camera.K, "distortion": camera.distortion.to_dict(), "sigma": dict(camera.quality.sigma),
                "worst_sigma_px": self.worst_sigma_px, "frames": len(self.rig.frames),
                "extrapolated": [f for f in self.extrapolated if f is not None] if self.rig.frames
                else bool(self.extrapolated)}


def _distance(focus_m: float) -> str:
    return "inf" if math.isinf(focus_m) else f"{focus_m:g} m"


def _outside(profile: LensProfile, focal_mm: np.ndarray, focus_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which states lie outside the calibrated focal range, and which outside the focus range."""
    (f_low, f_high), (v_low, v_high) = profile.focal_range, profile.vergence_range
    vergence = 1.0 / focus_m
    tolerance_f, tolerance_v = _RANGE_TOLERANCE * f_high, _RANGE_TOLERANCE * max(v_high, 1.0)
    return ((focal_mm < f_low - tolerance_f) | (focal_mm > f_high + tolerance_f),
            (vergence < v_low - tolerance_v) | (vergence > v_high + tolerance_v))


def _range_text(profile: LensProfile) -> str:
    near, far = profile.focus_range
    return f"{profile.focal_range[0]:g}-{profile.focal_range[1]:g} mm, focus {_distance(near)} to {_distance(far)}"


def lens_rig(
    profile: str | os.PathLike | LensProfile,
    focal_mm: float | None = None,
    focus_m: float | None = None,
    *,
    metadata: str | os.PathLike | None = None,
    encoders: bool = False,
    extrapolate: bool = False,
    name: str = "camera",
    out: str | os.PathLike | None = None,
) -> LensRig:
    """A one-camera rig at a lens state of a profile, or with a lens per frame (``camcal lens``).

    Parameters
    ----------
    profile : path or LensProfile
        A ``*.profile.json`` (``camcal calibrate profile``).
    focal_mm, focus_m : float, optional
        The lens state: focal length in mm, focus distance in m (``math.inf``: infinity); or, with
        ``encoders``, encoder values from 0 to 1 (:meth:`camcal.model.lens_profile.LensProfile.from_encoders`).
    metadata : path, optional
        Instead of one state: a CSV of each frame's state (:mod:`camcal.io.lens_metadata`); the rig gets a
        frame per row (``R = I``, ``c = 0``) holding that frame's lens, and its camera is the first frame's.
    encoders : bool
        The values (or the CSV's ``focal,focus`` columns) are encoder readings from 0 to 1.
    extrapolate : bool
        Allow states outside the calibrated range (said in :meth:`LensRig.lines`).
    name : str
        The camera's name.
    out : path, optional
        The ``*.rig.json`` to write.

    Returns
    -------
    LensRig

    Raises
    ------
    CamcalError
        Neither a state nor metadata (or both), an encoder value outside 0-1, a state outside the calibrated
        range without ``extrapolate``, or a bad metadata CSV; nothing is written then.

    Examples
    --------
    >>> import camcal  # doctest: +SKIP
    >>> camcal.lens_rig("lens.profile.json", 32, 2.5, out="cam.rig.json").rig.cameras[0].K  # doctest: +SKIP
    """
    from camcal.geometry.lens_profile import camera_at
    from camcal.model.lens_profile import LensProfile
    from camcal.model.rig import Frame, Lens, Rig, make_provenance

    if not isinstance(profile, LensProfile):
        source = os.fspath(profile)
        profile = LensProfile.load(profile)
    else:
        source = "the given profile"
    single = focal_mm is not None or focus_m is not None
    if single == (metadata is not None):
        raise CamcalError("give a lens state (--focal MM --focus M) or per-frame metadata (--metadata FILE.csv), "
                          "not both" if single else "give a lens state (--focal MM --focus M) or per-frame metadata "
                          "(--metadata FILE.csv)")
    if single and (focal_mm is None or focus_m is None):
        raise CamcalError("a lens state needs both --focal (mm) and --focus (m, or inf)")
    if metadata is not None:
        from camcal.io.lens_metadata import read_lens_metadata

        table = read_lens_metadata(metadata, encoders=encoders)
        frames, focal, focus = table.frames, table.focal, table.focus
        where = [f"{metadata}: frame {int(f)}" for f in frames]
    else:
        frames = np.array([-1])
        focal, focus = np.array([float(focal_mm)]), np.array([float(focus_m)])
        where = ["--focal/--focus" if not encoders else "the encoders"]
    if not encoders and not (np.all(np.isfinite(focal)) and np.all(focal > 0) and np.all(focus > 0)):
        raise CamcalError("the focal length and the focus distance must be positive")
    if encoders:
        bad = (focal < 0) | (focal > 1) | (focus < 0) | (focus > 1)
        if np.any(bad) and not extrapolate:
            k = int(np.argmax(bad))
            raise CamcalError(f"{where[k]}: encoder values run from 0 to 1, got focal {focal[k]:g}, focus "
                              f"{focus[k]:g} (--extrapolate to go beyond the calibrated range)")
        focal, focus = profile.from_encoders(focal, focus)
    off_focal, off_focus = _outside(profile, focal, focus)
    outside = off_focal | off_focus
    if np.any(outside) and not extrapolate:
        k = int(np.argmax(outside))
        what = (f"focal length {focal[k]:g} mm" if off_focal[k] else f"focus distance {_distance(focus[k])}")
        raise CamcalError(f"{where[k]}: {what} is outside the profile's calibrated range ({_range_text(profile)}); "
                          "--extrapolate to go beyond it")
    cameras = [camera_at(profile, float(f), float(d), name) for f, d in zip(focal, focus)]
    worst = max(float(camera.quality.worst_projection_sigma_px) for camera in cameras)
    provenance = make_provenance("lens", profile=source)
    if metadata is None:
        rig = Rig((cameras[0],), units="unknown", provenance=provenance)
        states = ((None, float(focal[0]), float(focus[0])),)
        extrapolated = (None,) if outside[0] else ()
    else:
        frame_list = tuple(Frame(int(index), np.eye(3), np.zeros(3), lenses={name: Lens(
            camera.K, camera.distortion, float(f), None if math.isinf(d) else float(d))})
            for index, camera, f, d in zip(frames, cameras, focal, focus))
        rig = Rig((cameras[0],), units="unknown", frames=frame_list, provenance=provenance)
        states = tuple((int(i), float(f), float(d)) for i, f, d in zip(frames, focal, focus))
        extrapolated = tuple(int(i) for i, o in zip(frames, outside) if o)
    files = () if out is None else ((rig.save(out), "rig"),)
    return LensRig(rig, states, extrapolated, worst, files)
