"""A lens profile as OpenTrackIO lens samples (JSON): one per lens state, encoders normalised 0-1.

SMPTE RIS OpenTrackIO (its reference implementation, camdkit, and the
OpenLensIO lens model v1.0.1 it carries) describes a lens at one state in
a sample's ``lens`` object, and the camera's sensor in ``static.camera``.
camcal writes a lens profile as those objects, one sample per lens state
of a grid of encoder values, in a small camcal container::

    {
      "format": "camcal.opentrackio_lens", "version": 1,
      "static": {"camera": {"activeSensorPhysicalDimensions": {"width": 36.0, "height": 20.25},
                            "activeSensorResolution": {"width": 1920, "height": 1080}},
                 "lens": {"make": "camcal", "model": "zoom", "distortionOverscanMax": 1.04}},
      "encoderRanges": {"zoom": {"0": 24.0, "1": 70.0, "unit": "mm", "mapping": "linear"},
                        "focus": {"0": "inf", "1": 0.5, "unit": "m", "mapping": "linear in 1 / distance"}},
      "samples": [{"lens": {"encoders": {"zoom": 0.0, "focus": 0.0}, "pinholeFocalLength": 24.3,
                            "projectionOffset": {"x": 0.01, "y": -0.02},
                            "distortionOffset": {"x": 0.0, "y": 0.0},
                            "distortion": [{"model": "Brown-Conrady U-D", "radial": [k1, k2, k3, k4, k5, k6],
                                            "tangential": [p1, p2], "overscan": 1.03}]}}, ...]
    }

``focusDistance`` (m) is written where the state's focus is finite (OpenTrackIO's
field is a positive number; the focus encoder 0 is infinity). The field names
are OpenTrackIO's; the container around them is camcal's (OpenTrackIO itself
streams one sample per frame, and holds no encoder ranges).

The model (OpenLensIO, section 4.1; the projection matrix characterisation of
section 2): screen coordinates ``eps`` in mm on the sensor, origin at its
centre, x right, y down; the pinhole ``eps_u = F (x, y)_u + dP``; the lens
``eps_d = D(eps_u - dP) + dP`` (``dC = 0``: camcal's lens centre is the
principal point), with the Brown-Conrady form of OpenLensIO's equation (16),
``r`` in mm::

    R = (1 + k1 r^2 + k3 r^4 + k5 r^6) / (1 + k2 r^2 + k4 r^4 + k6 r^6)
    D_x = x R + 2 p1 x y + p2 (r^2 + 2 x^2),   D_y = y R + 2 p2 x y + p1 (r^2 + 2 y^2)

(numerator and denominator coefficients alternate, ``radial = [k1..k6]``).
OpenLensIO defines this form as the undistortion ``U`` (``Brown-Conrady
D-U``, distorted to undistorted); camcal writes it in the other direction its
``model`` names, ``Brown-Conrady U-D`` (undistorted to distorted), which is
OpenCV's, so that camcal's ``opencv`` and ``polynomial`` lenses go exactly:
with ``F`` in mm, ``k1 = k1_cv / F^2``, ``k2 = k4_cv / F^2``, ``k3 =
k2_cv / F^4``, ``k4 = k5_cv / F^4``, ``k5 = k3_cv / F^6``, ``k6 =
k6_cv / F^6``, and ``p = p_cv / F`` (the formula makes ``p1 x y`` a length,
so ``p`` is per mm; OpenLensIO's unit note says per mm squared). Any other
lens (thin prism, fisheye, division, 3DE, a correction field) is refitted to
OpenCV's ``k1 k2 p1 p2 k3`` by camcal's one conversion core
(:func:`camcal.io.conversion.nearest_camera`), its residual printed.

Pixels and millimetres: ``F = fx w / W`` (``w`` the sensor width in mm, ``W``
the image width in pixels), ``dP = (cx - (W - 1) / 2) w / W`` (camcal's pixel
(0, 0) is the centre of the top-left pixel: the sensor's centre is pixel
``(W - 1) / 2``), the same in y with the sensor height ``h``. The file has one
sensor, so one pixel aspect: ``h`` is the one that makes ``F = fy h / H`` at
the profile's mean ``fy / fx``; a state whose ``fy / fx`` differs lands off by
that difference (included in the residual printed). ``overscan`` is
OpenLensIO's (its appendix A.1): the factor by which the pinhole image must
grow about the sensor's centre to hold the undistorted frame, at least 1;
``distortionOverscanMax`` the largest over the states.

References
----------
SMPTE RIS OSVP, OpenTrackIO and camdkit (``lens_types.py``: ``Lens``,
``Distortion``, ``FizEncoders``; ``camera_types.py``: ``StaticCamera``), and
"OpenLensIO mathematical lens model" v1.0.1, equations (3)-(5), (16)-(17),
(21)-(24).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.jsonfile import dumps, read_json
from camcal.io.conversion import ExportResult, ImportResult, LensConversion, max_pixel_residual, nearest_camera
from camcal.model.distortion import Distortion, frame_grid
from camcal.model.rig import Camera, Frame, Lens, Rig, make_provenance

__all__ = ["OPENTRACKIO_FORMAT", "MODEL_NAME", "LensSample", "load", "overscan", "write_opentrackio_lens"]

OPENTRACKIO_FORMAT = "camcal.opentrackio_lens"
#: The distortion model camcal writes and reads (OpenTrackIO's name for the undistorted -> distorted direction).
MODEL_NAME = "Brown-Conrady U-D"
#: camcal's opencv coefficients in OpenLensIO's radial order (numerator and denominator alternating), with the
#: power of F (mm) each is divided by.
_RADIAL = (("k1", 2), ("k4", 2), ("k2", 4), ("k5", 4), ("k3", 6), ("k6", 6))
_TANGENTIAL = (("p1", 1), ("p2", 1))
_THIN_PRISM = ("s1", "s2", "s3", "s4")


@dataclass(frozen=True)
class LensSample:
    """One lens state to write: its encoders, its state and the profile's camera there."""

    zoom: float
    focus: float
    focal_mm: float
    focus_m: float
    camera: Camera


def _holds(distortion: Distortion) -> bool:
    """True when Brown-Conrady (OpenCV's radial and tangential terms) holds the lens exactly."""
    if distortion.model not in ("none", "polynomial", "opencv") or distortion.has_correction:
        return False
    return all(distortion.params.get(name, 0.0) == 0.0 for name in _THIN_PRISM)


def _distance(focus_m: float) -> float | str:
    return "inf" if math.isinf(focus_m) else focus_m


def _sensor_centre(size: tuple[int, int]) -> NDArray[np.float64]:
    return (np.asarray(size, dtype=np.float64) - 1.0) / 2.0


def _lens_object(camera: Camera, sample: LensSample, pitch: NDArray[np.float64]) -> dict:
    """The sample's OpenTrackIO ``lens``: ``camera`` holds a Brown-Conrady lens (opencv / polynomial / none)."""
    F = float(camera.K[0, 0] * pitch[0])
    offset = (camera.K[:2, 2] - _sensor_centre(camera.image_size)) * pitch
    params = camera.distortion.params
    lens = {"encoders": {"zoom": sample.zoom, "focus": sample.focus}, "pinholeFocalLength": F,
            "projectionOffset": {"x": float(offset[0]), "y": float(offset[1])},
            "distortionOffset": {"x": 0.0, "y": 0.0},
            "distortion": [{"model": MODEL_NAME,
                            "radial": [params.get(name, 0.0) / F**power for name, power in _RADIAL],
                            "tangential": [params.get(name, 0.0) / F**power for name, power in _TANGENTIAL],
                            "overscan": overscan(camera)}]}
    if not math.isinf(sample.focus_m):
        lens["focusDistance"] = sample.focus_m
    return lens


def overscan(camera: Camera) -> float:
    """OpenLensIO's overscan of ``camera`` (its appendix A.1, in pixels): ``max(1, max(2 |x_u| / W, 2 |y_u| / H))``
    over the frame's pixels (edges included) undistorted, ``x_u``, ``y_u`` measured from the sensor's centre."""
    width, height = camera.image_size
    centre = _sensor_centre(camera.image_size)
    # the frame's pixel centres stretched to its edges (pixel -0.5 to W - 0.5), about the sensor's centre
    grid = centre + (frame_grid(camera.image_size, max(camera.image_size) / 64.0) - centre) * [
        width / (width - 1), height / (height - 1)]
    ideal = camera.distortion.undistort(grid, camera.K) - centre
    reach = np.nanmax(np.maximum(np.abs(ideal[:, 0]) / (width / 2.0), np.abs(ideal[:, 1]) / (height / 2.0)))
    return float(max(1.0, reach))


def _camera_of(lens: dict, size: tuple[int, int], pitch: NDArray[np.float64], name: str) -> Camera:
    """The camcal camera of one sample's ``lens`` (OpenCV's model, the module docstring's conversion)."""
    F = float(lens["pinholeFocalLength"])
    offset = np.array([lens["projectionOffset"]["x"], lens["projectionOffset"]["y"]], dtype=np.float64)
    centre = _sensor_centre(size) + offset / pitch
    K = np.array([[F / pitch[0], 0.0, centre[0]], [0.0, F / pitch[1], centre[1]], [0.0, 0.0, 1.0]])
    [distortion] = lens["distortion"]
    coefficients = {**dict(zip([key for key, _ in _RADIAL], distortion["radial"])),
                    **dict(zip([key for key, _ in _TANGENTIAL], distortion.get("tangential") or []))}
    params = {key: float(coefficients.get(key, 0.0)) * F**power for key, power in (*_RADIAL, *_TANGENTIAL)}
    if all(params[key] == 0.0 for key in ("k4", "k5", "k6")):
        params = {key: value for key, value in params.items() if key not in ("k4", "k5", "k6")}
    return Camera(name, size, K, Distortion("opencv", params), np.eye(3), np.zeros(3))


def write_opentrackio_lens(out: Path, samples: Sequence[LensSample], *, name: str, sensor_width_mm: float,
                           focal_range: tuple[float, float], focus_range: tuple[float, float]) -> ExportResult:
    """Write lens states as OpenTrackIO lens samples (the module docstring's file), atomically.

    Parameters
    ----------
    out : Path
        The ``.json`` file.
    samples : sequence of LensSample
        The states, each with its encoders (0-1) and the profile's camera there; all of one image size.
    name : str
        The lens' ``model``.
    sensor_width_mm : float
        The sensor's active width in mm (the image's width on it).
    focal_range, focus_range : (float, float)
        The calibrated ranges the encoders run over (mm; m, nearest first, ``inf`` possible).

    Returns
    -------
    ExportResult
        One conversion: the worst state's residual (the Brown-Conrady refit, when the lens needs one, and the
        sensor's one pixel aspect), measured on the camera read back from the numbers written.
    """
    if out.suffix.lower() != ".json":
        raise CamcalError(f"an OpenTrackIO lens file is a .json file, got {out.name!r}")
    if not samples:
        raise CamcalError("an OpenTrackIO lens file needs at least one lens state")
    if not (isinstance(sensor_width_mm, (int, float)) and math.isfinite(sensor_width_mm) and sensor_width_mm > 0):
        raise CamcalError(f"the sensor width must be a positive number of mm, got {sensor_width_mm!r}")
    size = samples[0].camera.image_size
    aspect = float(np.mean([s.camera.K[1, 1] / s.camera.K[0, 0] for s in samples]))  # fy / fx
    pitch = np.array([sensor_width_mm / size[0], sensor_width_mm / size[0] / aspect])  # mm per pixel
    lenses, worst, refits = [], None, []
    for sample in samples:
        converted, conversion = nearest_camera(sample.camera, _holds, "opencv", MODEL_NAME)
        lens = _lens_object(converted, sample, pitch)
        lenses.append(lens)
        read = _camera_of(lens, size, pitch, sample.camera.name)
        residual = max_pixel_residual(sample.camera, read)
        refits.append(conversion.refit)
        if worst is None or residual > worst[0]:
            worst = (residual, sample, conversion)
    near, far = focus_range
    document = {
        "format": OPENTRACKIO_FORMAT, "version": 1,
        "static": {"camera": {"activeSensorPhysicalDimensions": {"width": float(sensor_width_mm),
                                                                 "height": float(pitch[1] * size[1])},
                              "activeSensorResolution": {"width": size[0], "height": size[1]}},
                   "lens": {"make": "camcal", "model": name,
                            "distortionOverscanMax": max(lens["distortion"][0]["overscan"] for lens in lenses)}},
        "encoderRanges": {
            "zoom": {"0": focal_range[0], "1": focal_range[1], "unit": "mm", "mapping": "linear"},
            "focus": {"0": _distance(far), "1": _distance(near), "unit": "m", "mapping": "linear in 1 / distance"},
        },
        "samples": [{"lens": lens} for lens in lenses],
    }
    atomic_write_text(out, dumps(document))
    residual, sample, conversion = worst
    source = samples[0].camera.distortion.model
    exact = residual < 1e-6 and all(refit is None for refit in refits)
    refit = max((r for r in refits if r is not None), key=lambda r: r.max_px, default=None)
    focus = "infinity" if math.isinf(sample.focus_m) else f"{sample.focus_m:g} m"
    notes = [f"{len(samples)} lens states; the worst, {sample.focal_mm:g} mm focused at {focus}, lands "
             f"{residual:.3g} px from the profile's camera (read back from the file)",
             f"the sensor {sensor_width_mm:g} x {pitch[1] * size[1]:.4g} mm, its pixel aspect the states' mean fy / fx "
             f"({aspect:.6f})"]
    return ExportResult((out,), (LensConversion(sample.camera.name, source, f"OpenTrackIO {MODEL_NAME}", exact,
                                                residual, "refit" if refit is not None else "one pixel aspect",
                                                refit),), tuple(notes))


def _state(encoders: dict, ranges: dict, where: str) -> tuple[float, float]:
    """The lens state ``(focal_mm, focus_m)`` of a sample's encoders over the file's encoder ranges."""
    try:
        zoom, focus = float(encoders["zoom"]), float(encoders["focus"])
        low, high = float(ranges["zoom"]["0"]), float(ranges["zoom"]["1"])
        far, near = (math.inf if v == "inf" else float(v) for v in (ranges["focus"]["0"], ranges["focus"]["1"]))
    except (KeyError, TypeError, ValueError) as error:
        raise CamcalError(f"{where}: the encoders or encoderRanges lack a number ({error})") from None
    if not (0.0 <= zoom <= 1.0 and 0.0 <= focus <= 1.0):
        raise CamcalError(f"{where}: encoders run from 0 to 1, got zoom {zoom:g}, focus {focus:g}")
    vergence = (1.0 - focus) / far + focus / near
    return low + zoom * (high - low), (math.inf if vergence == 0.0 else 1.0 / vergence)


def load(path: Path) -> ImportResult:
    """Read a file :func:`write_opentrackio_lens` wrote: one camera (the first sample) and a frame per sample, each
    with its lens and lens state (:attr:`camcal.model.rig.Frame.lenses`).

    Raises
    ------
    CamcalError
        Not such a file, a distortion other than one ``Brown-Conrady U-D``, a distortion offset (camcal's lens
        centre is the principal point), or a missing field, in one line.
    """
    data = read_json(path, "OpenTrackIO lens file")
    if not isinstance(data, dict) or data.get("format") != OPENTRACKIO_FORMAT:
        raise CamcalError(f"not a camcal OpenTrackIO lens file (format {OPENTRACKIO_FORMAT!r})")
    try:
        sensor = data["static"]["camera"]
        width_mm = float(sensor["activeSensorPhysicalDimensions"]["width"])
        height_mm = float(sensor["activeSensorPhysicalDimensions"]["height"])
        size = (int(sensor["activeSensorResolution"]["width"]), int(sensor["activeSensorResolution"]["height"]))
        samples, ranges = data["samples"], data["encoderRanges"]
    except (KeyError, TypeError, ValueError) as error:
        raise CamcalError(f"the static camera or the samples lack a field ({error})") from None
    if not (width_mm > 0 and height_mm > 0 and min(size) > 0 and isinstance(samples, list) and samples):
        raise CamcalError("the sensor's size and resolution must be positive and the samples not empty")
    pitch = np.array([width_mm / size[0], height_mm / size[1]])
    frames, cameras = [], []
    for index, sample in enumerate(samples):
        where = f"samples[{index}]"
        lens = sample.get("lens") if isinstance(sample, dict) else None
        if not isinstance(lens, dict):
            raise CamcalError(f"{where}: no lens object")
        distortions = lens.get("distortion")
        if not (isinstance(distortions, list) and len(distortions) == 1 and isinstance(distortions[0], dict)
                and distortions[0].get("model", "Brown-Conrady D-U") == MODEL_NAME):
            raise CamcalError(f"{where}: camcal reads one {MODEL_NAME!r} distortion (undistorted to distorted), the "
                              "direction it writes")
        offset = lens.get("distortionOffset", {})
        if not isinstance(offset, dict) or offset.get("x", 0.0) != 0.0 or offset.get("y", 0.0) != 0.0:
            raise CamcalError(f"{where}: a distortion offset (the distortion centre off the principal point) has no "
                              "camcal lens model")
        try:
            camera = _camera_of(lens, size, pitch, "camera")
        except (KeyError, TypeError, ValueError) as error:
            raise CamcalError(f"{where}: a lens field is missing or not a number ({error})") from None
        focal_mm, focus_m = _state(lens.get("encoders", {}), ranges, where)
        cameras.append(camera)
        frames.append(Frame(index, np.eye(3), np.zeros(3), lenses={camera.name: Lens(
            camera.K, camera.distortion, focal_mm, None if math.isinf(focus_m) else focus_m)}))
    rig = Rig((cameras[0],), units="unknown", frames=tuple(frames), provenance=make_provenance("import"))
    conversion = LensConversion("camera", MODEL_NAME, "opencv", True)
    return ImportResult(rig, (conversion,), (f"{len(frames)} lens states, one frame each (frame i: sample i)",))
