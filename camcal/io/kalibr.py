"""Kalibr camchain YAML (``camchain.yaml``), written and read with PyYAML.

Kalibr's documented format (wiki "Yaml formats"), one entry per camera
``cam0, cam1, ...``::

    cam0:
      camera_model: pinhole
      intrinsics: [fu, fv, pu, pv]
      distortion_model: radtan          # k1 k2 r1 r2
      distortion_coeffs: [k1, k2, r1, r2]
      resolution: [width, height]
      rostopic: /cam0/image_raw
    cam1:
      T_cn_cnm1: 4x4                    # camera n-1 -> camera n
      cam_overlaps: [0]
      ...

``radtan`` is OpenCV's model without ``k3`` (``r1, r2`` are ``p1, p2``);
Kalibr's pixels are OpenCV's (pixel (0, 0) at the centre of the top-left
pixel). camcal cameras with ``none``, ``polynomial`` (k3 = 0) or ``opencv``
(k3 = 0) lenses go exactly; others (k3, division) are fitted with the
nearest radtan lens and skew is dropped, with the max pixel residual
reported. ``T_cn_cnm1`` is ``[[R_n R_{n-1}^T, R_n (c_{n-1} - c_n)], [0, 0,
0, 1]]``. ``pinhole-equi`` (``distortion_model: equidistant``, Kalibr's
Kannala-Brandt model ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3
theta^6 + k4 theta^8)``, the same as ``cv2.fisheye``) holds camcal's
``kannala-brandt`` lens exactly, coefficients ``[k1, k2, k3, k4]``; a
``kannala-brandt-thin-prism`` lens goes as the nearest equidistant one
(k1..k4 fitted over the frame, max residual reported).

Kalibr has no world frame: imported rigs put cam0 at the origin; a rig's
frames and points are not written.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_write_text
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import ExportResult, ImportResult, LensConversion, nearest_camera, select_cameras
from camcal.model.rig import Camera, Rig

__all__ = ["export", "load"]

_KANNALA_BRANDT = "kannala-brandt"


def _holds(distortion: Distortion) -> bool:
    if distortion.model in ("none", _KANNALA_BRANDT):
        return True
    return (distortion.model in ("polynomial", "opencv") and distortion.params.get("k3", 0.0) == 0.0
            and distortion.opencv_terms == 5)  # radtan: k1 k2 p1 p2, no rational or thin-prism terms


def _camera_entry(camera: Camera) -> dict:
    K, p = camera.K, camera.distortion.params
    if camera.distortion.model == _KANNALA_BRANDT:
        model, coeffs = "equidistant", [p["k1"], p["k2"], p["k3"], p["k4"]]
    else:
        model, coeffs = "radtan", [p.get("k1", 0.0), p.get("k2", 0.0), p.get("p1", 0.0), p.get("p2", 0.0)]
    return {
        "camera_model": "pinhole",
        "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
        "distortion_model": model,
        "distortion_coeffs": [float(v) for v in coeffs],
        "resolution": [int(v) for v in camera.image_size],
    }


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write ``camchain.yaml`` (see the module docstring)."""
    import yaml

    if out.suffix.lower() not in (".yaml", ".yml"):
        raise CamcalError(f"a Kalibr camchain must end in .yaml or .yml, got {out.name!r}")
    chain, conversions = {}, []
    previous = None
    for index, camera in enumerate(select_cameras(rig, cameras)):
        # a thin-prism fisheye goes as the nearest equidistant lens (k1..k4), its residual printed
        fisheye = camera.distortion.is_fisheye
        converted, conversion = nearest_camera(camera, _holds, _KANNALA_BRANDT if fisheye else "opencv",
                                               "pinhole-equi" if fisheye else "pinhole-radtan",
                                               with_k3=None if fisheye else False)
        conversions.append(conversion)
        entry = _camera_entry(converted)
        if previous is not None:
            T = np.eye(4)
            T[:3, :3] = camera.R @ previous.R.T
            T[:3, 3] = camera.R @ (previous.c - camera.c)
            entry["T_cn_cnm1"] = T.tolist()
            entry["cam_overlaps"] = [index - 1]
        entry["rostopic"] = f"/{camera.name}/image_raw"
        chain[f"cam{index}"] = entry
        previous = camera
    notes = []
    if rig.frames:
        notes.append(f"the rig's {len(rig.frames)} frame pose(s) are not written (a camchain is one static rig)")
    # repr-precision floats: PyYAML writes Python floats with repr, so the file round-trips exactly
    atomic_write_text(out, yaml.safe_dump(chain, sort_keys=False, default_flow_style=None))
    return ExportResult((out,), tuple(conversions), tuple(notes))


def _numbers(entry: dict, key: str, count: int, where: str) -> list[float]:
    value = entry.get(key)
    if not isinstance(value, list) or len(value) != count or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise CamcalError(f"{where}.{key} must be a list of {count} numbers, got {value!r:.80}")
    try:
        numbers = [float(v) for v in value]
    except OverflowError:
        raise CamcalError(f"{where}.{key} holds an integer out of the float range") from None
    if not all(np.isfinite(numbers)):
        raise CamcalError(f"{where}.{key} contains NaN or infinite values")
    return numbers


def load(path: Path) -> ImportResult:
    """Read a Kalibr camchain (see the module docstring)."""
    import yaml

    check_file_size(path, FILE_BYTES, "Kalibr camchain")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise CamcalError(f"not a YAML file ({str(error).splitlines()[0]})") from None
    except RecursionError:
        raise CamcalError("not a Kalibr camchain: nested too deep to read") from None
    if not isinstance(data, dict) or not data or not all(isinstance(k, str) and k.startswith("cam") for k in data):
        raise CamcalError("not a Kalibr camchain: expected top-level keys cam0, cam1, ...")
    names = sorted(data, key=lambda key: int(key[3:]) if key[3:].isdigit() else -1)
    if [int(key[3:]) if key[3:].isdigit() else -1 for key in names] != list(range(len(names))):
        raise CamcalError(f"camchain keys must be cam0 .. cam{len(names) - 1}, got {', '.join(names)}")
    cameras = []
    R_prev, c_prev = np.eye(3), np.zeros(3)
    for index, key in enumerate(names):
        entry = data[key]
        if not isinstance(entry, dict):
            raise CamcalError(f"{key} must be a mapping")
        if entry.get("camera_model") != "pinhole":
            raise CamcalError(f"{key}.camera_model {entry.get('camera_model')!r} is not supported (only pinhole)")
        fu, fv, pu, pv = _numbers(entry, "intrinsics", 4, key)
        width, height = _numbers(entry, "resolution", 2, key)
        model = entry.get("distortion_model")
        if model == "radtan":
            k1, k2, p1, p2 = _numbers(entry, "distortion_coeffs", 4, key)
            distortion = Distortion("opencv", {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": 0.0})
        elif model == "equidistant":
            k1, k2, k3, k4 = _numbers(entry, "distortion_coeffs", 4, key)
            distortion = Distortion(_KANNALA_BRANDT, {"k1": k1, "k2": k2, "k3": k3, "k4": k4})
        elif model == "none":
            distortion = Distortion.none()
        else:
            raise CamcalError(f"{key}.distortion_model {model!r} is not supported (radtan, equidistant, none)")
        if index == 0:
            R, c = np.eye(3), np.zeros(3)
        else:
            T = np.asarray(entry.get("T_cn_cnm1"), dtype=object)
            if T.shape != (4, 4):
                raise CamcalError(f"{key}.T_cn_cnm1 must be a 4x4 matrix")
            try:
                T = np.array(T, dtype=np.float64)
            except (TypeError, ValueError):
                raise CamcalError(f"{key}.T_cn_cnm1 must hold numbers") from None
            if not np.all(np.isfinite(T)):
                raise CamcalError(f"{key}.T_cn_cnm1 contains NaN or infinite values")
            R = T[:3, :3] @ R_prev
            c = c_prev - R.T @ T[:3, 3]
        if int(width) != width or int(height) != height:
            raise CamcalError(f"{key}.resolution must be integers")
        topic = entry.get("rostopic")
        name = topic.strip("/").split("/")[0] if isinstance(topic, str) and topic.strip("/") else key
        if name in {camera.name for camera in cameras}:
            name = key
        try:
            cameras.append(Camera(name, (int(width), int(height)), [[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]],
                                  distortion, R, c))
        except CamcalError as error:
            raise CamcalError(f"{key}: {error}") from None
        R_prev, c_prev = R, c
    conversions = tuple(LensConversion(c.name, f"pinhole-{data[key]['distortion_model']}", c.distortion.model, True)
                        for c, key in zip(cameras, names))
    return ImportResult(Rig(tuple(cameras), units="m"), conversions, ("cam0 is the origin; Kalibr's units are metres",))
