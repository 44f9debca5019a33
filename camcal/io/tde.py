"""3DEqualizer lens files (``.txt``): one camcal camera's lens as 3DE4's Export Lens / Import Lens text.

The file 3DE4's own lens import script reads, line by line (lengths in cm)::

    <lens name>
    <fb width> <fb height> <focal length> <film aspect> <lens centre offset x> <lens centre offset y> <pixel aspect>
    <dynamic distortion mode: DISTORTION_STATIC, DISTORTION_DYNAMIC_FOCAL_LENGTH, ... (or 0 / 1)>
    <LDPK model name, e.g. 3DE4 Anamorphic - Standard, Degree 4>
    <parameter name>            \\
    <value>                      | once per model parameter, in any order
    <number of curve keys n>     |
    <x y t1x t1y t2x t2y MODE>   / n lines: the parameter's curve over focal length (or focus distance)
    <end_of_file>
    [<begin_2dlut_samples> ... <end_2dlut_samples>]

camcal writes one camera, its lens in one of the four 3DE models
(:mod:`camcal.model.tde4`): exactly when it is one of them, else the
nearest one refitted over a dense grid (:func:`camcal.io.conversion.refit_camera`,
residual max / RMS printed over the image and a 1.25 overscan border). The
film back's width is the camera's ``sensor_width_mm`` (36 mm without one),
its height and the pixel aspect ``fy / fx``, the lens-centre offset the
principal point's (:class:`camcal.model.tde4.LdpkCamera`). A camera with one
lens is ``DISTORTION_STATIC``, no curve keys. A lens file holds no image
size, which camcal needs: it is written on a line after ``<end_of_file>``
(``# camcal image_size W H``, which 3DE's reader passes over), and
:func:`load` takes it from there or from ``image_size``.

A camera whose lens changes over the rig's frames (a zoom, a rack focus:
:attr:`camcal.model.rig.Frame.lenses` with their lens state ``focal_mm``,
``focus_m``) is written as 3DE's dynamic distortion: each frame's lens
refitted on the camera's own lens centre and pixel aspect (a 3DE lens has
one; the frame's focal length kept), its parameters keyed over what changes
among the frames' lens states: ``DISTORTION_DYNAMIC_FOCAL_LENGTH`` (a curve
over the focal length in cm per parameter), ``..._FOCUS_DISTANCE`` (over the
focus distance in cm) or, when both change,
``DISTORTION_DYNAMIC_FOCAL_AND_FOCUS_DISTANCE`` as 3DE's 2D LUT after
``<end_of_file>`` (``<begin_2dlut_samples>``, per parameter its name, the
sample count and ``focal focus value`` lines, ``<end_2dlut_samples>``). Keys
are ``x y 0 0 0 0 SMOOTH`` (flat tangents). The parameter's value line holds
the camera's own lens. Each frame's ``K`` and lens state follow as camcal
lines (``# camcal frame INDEX fx skew cx fy cy focal_mm=F focus_m=D``),
from which :func:`load` rebuilds the frames, each lens read from the curves
(linear between keys, exact at one) or the LUT at its state. Frames whose
lens is the camera's own carry no state; lenses that carry none are refused.

Reading a file without camcal's frame lines takes a static lens, or a
dynamic one whose every keyed curve has a key at the lens' own focal length
(its value there is the lens); a model name that is not one of the four, a
parameter the model does not have, a missing line or value, and a file
without ``<end_of_file>`` are refused in one line naming the problem.

References
----------
Science-D-Visions, 3DEqualizer4 Python scripts "Export Lens..." / "Import
Lens..." (``tde4.getLensFBackWidth``, ``getLensLensCenterX``,
``getLensPixelAspect``, ``getLensLDAdjustableParameterCurve``), the format
they write and read.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    FORMAT_FAMILIES,
    ExportResult,
    ImportResult,
    LensConversion,
    Refit,
    nearest_family,
    refit_camera,
    select_cameras,
)
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Frame, Lens, Rig
from camcal.model.tde4 import FILMBACK_KEYS, LDPK_MODEL_NAMES, LDPK_PARAMETERS, LdpkCamera

__all__ = ["DEFAULT_FILMBACK_WIDTH_MM", "export", "load"]

#: Film back width of cameras without ``sensor_width_mm``.
DEFAULT_FILMBACK_WIDTH_MM = 36.0

_END = "<end_of_file>"
_SIZE_LINE = "# camcal image_size"
_FRAME_LINE = "# camcal frame"
_STATIC = ("DISTORTION_STATIC", "0")
_FOCAL = "DISTORTION_DYNAMIC_FOCAL_LENGTH"
_FOCUS = "DISTORTION_DYNAMIC_FOCUS_DISTANCE"
_BOTH = "DISTORTION_DYNAMIC_FOCAL_AND_FOCUS_DISTANCE"
_LUT_BEGIN, _LUT_END = "<begin_2dlut_samples>", "<end_2dlut_samples>"


def _number(value: float) -> str:
    return repr(float(value))


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write one camera's lens as a 3DE4 lens file (see the module docstring)."""
    if out.suffix.lower() != ".txt":
        raise CamcalError(f"a 3DEqualizer lens file must end in .txt, got {out.name!r}")
    chosen = select_cameras(rig, cameras)
    if len(chosen) != 1:
        raise CamcalError(f"a 3DEqualizer lens file holds one lens; the rig has {len(chosen)} cameras "
                          f"({', '.join(c.name for c in chosen)}): name one with --camera")
    [camera] = chosen
    family = nearest_family(camera.distortion, FORMAT_FAMILIES["3de"])
    converted, refit = refit_camera(camera, family)
    builtin = LdpkCamera.from_camera_matrix(converted.K, camera.image_size,
                                            (camera.sensor_width_mm or DEFAULT_FILMBACK_WIDTH_MM) / 10.0)
    mode = _dynamic_mode(camera.name, [(frame.index, frame.lenses[camera.name].focal_mm,
                                        frame.lenses[camera.name].focus_m)
                                       for frame in rig.frames if camera.name in frame.lenses])
    states = _lens_states(rig, camera, family, (converted, refit)) if mode not in _STATIC else []
    lines = [camera.name,
             " ".join(_number(v) for v in (builtin.filmback_width_cm, builtin.filmback_height_cm,
                                           builtin.focal_length_cm,
                                           builtin.filmback_width_cm / builtin.filmback_height_cm,
                                           builtin.lens_center_offset_x_cm, builtin.lens_center_offset_y_cm,
                                           builtin.pixel_aspect)),
             mode, LDPK_MODEL_NAMES[family]]
    samples = _samples(states, mode)  # lens state (x, or (focal, focus) in cm) -> the refitted lens there
    for parameter in LDPK_PARAMETERS[family]:
        lines += [parameter.ldpk_name, _number(converted.distortion.params.get(parameter.key, parameter.default))]
        keys = [] if mode in (*_STATIC, _BOTH) else [
            f"{_number(x)} {_number(lens.params.get(parameter.key, parameter.default))} 0.0 0.0 0.0 0.0 SMOOTH"
            for x, lens in samples.items()]
        lines += [str(len(keys)), *keys]
    lines.append(_END)
    if mode == _BOTH:
        lines.append(_LUT_BEGIN)
        for parameter in LDPK_PARAMETERS[family]:
            lines += [parameter.ldpk_name, str(len(samples)), *(
                f"{_number(focal)} {_number(focus)} {_number(lens.params.get(parameter.key, parameter.default))}"
                for (focal, focus), lens in samples.items())]
        lines.append(_LUT_END)
    width, height = camera.image_size
    lines.append(f"{_SIZE_LINE} {width} {height}")
    lines += _frame_lines(rig, camera.name, states) if states else []
    atomic_write_text(out, "\n".join(lines) + "\n")
    source = f"{camera.distortion.model}{' with skew' if camera.K[0, 1] else ''}"
    worst = max([refit, *(state_refit for *_, state_refit in states)], key=lambda r: r.max_px)
    target = f"3DE {LDPK_MODEL_NAMES[family]}" + (f", {mode} over {len(samples)} lens states" if states else "")
    conversion = LensConversion(camera.name, source, target, worst.exact, worst.max_px, "refit", worst)
    notes = ["a 3DE lens file holds no pose: the camera's position and orientation are not written"]
    if states:
        notes.append("3DE's lens has one lens centre and film back: each lens state is refitted on the camera's own "
                     "principal point (the worst state's residual printed); each frame's K and lens state follow "
                     f"{_END} as camcal lines, which 3DE passes over")
    return ExportResult((out,), (conversion,), tuple(notes))


# -- dynamic distortion: the lens over focal length and / or focus distance (a zoom, a rack focus) -------------


def _lens_states(rig: Rig, camera: Camera, family: str,
                 own: tuple[Camera, Refit]) -> list[tuple[int, float | None, float | None, Camera, Refit]]:
    """``(frame, focal_mm, focus_m, the camera with its 3DE lens, its refit)`` of each frame with a lens of ``camera``.

    Each frame's lens is refitted to ``family`` with the camera's own
    principal point and pixel aspect (a 3DE lens has one lens centre and
    film back) and the frame's focal length; a frame whose lens is the
    camera's own takes ``own``, the camera's refit.
    """
    out = []
    for frame in rig.frames:
        state = frame.lenses.get(camera.name)
        if state is None:
            continue
        at = rig.camera_at_frame(camera.name, frame.index)
        K = camera.K.copy()
        K[0, 1] = 0.0
        K[0, 0], K[1, 1] = at.K[0, 0], at.K[0, 0] * camera.K[1, 1] / camera.K[0, 0]
        same = np.array_equal(K, own[0].K) and np.array_equal(at.K, camera.K) and at.distortion == camera.distortion
        lens_camera, refit = own if same else refit_camera(at, family, K=K)
        out.append((frame.index, state.focal_mm, state.focus_m, lens_camera, refit))
    return out


def _dynamic_mode(name: str, states: Sequence[tuple[int, float | None, float | None]]) -> str:
    """3DE's dynamic distortion mode of the lens states ``(frame, focal_mm, focus_m)``: over what changes among them."""
    if not states:
        return _STATIC[0]
    varying = [len({state[axis] for state in states}) > 1 for axis in (1, 2)]
    if not any(varying):
        raise CamcalError(f"camera {name!r}'s per-frame lenses do not say which lens state they are (focal_mm, "
                          "focus_m differ on no two frames): 3DE's dynamic distortion is a curve over the lens state")
    for axis, key in ((1, "focal_mm"), (2, "focus_m")):
        missing = [state[0] for state in states if varying[axis - 1] and state[axis] is None]
        if missing:
            raise CamcalError(f"camera {name!r}: the lens of frame {missing[0]} has no {key}, which changes over the "
                              "other frames: 3DE's dynamic distortion needs it on every frame")
    return _BOTH if all(varying) else (_FOCAL if varying[0] else _FOCUS)


def _samples(states: Sequence[tuple], mode: str) -> dict:
    """Lens state in 3DE's cm (the focal length, the focus distance, or both) -> the lens there, one per state."""
    out: dict = {}
    for _, focal_mm, focus_m, lens_camera, _ in states:
        focal_cm = None if focal_mm is None else focal_mm / 10.0
        focus_cm = None if focus_m is None else focus_m * 100.0
        out.setdefault({_FOCAL: focal_cm, _FOCUS: focus_cm}.get(mode, (focal_cm, focus_cm)), lens_camera.distortion)
    return dict(sorted(out.items()))


def _frame_lines(rig: Rig, name: str, states: Sequence[tuple]) -> list[str]:
    """``# camcal frame INDEX fx skew cx fy cy [focal_mm=F] [focus_m=D]``: each frame's K (its 3DE lens's) and state."""
    refitted = {index: lens_camera.K for index, *_, lens_camera, _ in states}
    lines = []
    for frame in rig.frames:
        K = refitted.get(frame.index, rig.camera(name).K)
        state = frame.lenses.get(name)
        extra = [] if state is None else [f"{key}={_number(getattr(state, key))}" for key in ("focal_mm", "focus_m")
                                          if getattr(state, key) is not None]
        lines.append(" ".join([_FRAME_LINE, str(frame.index), *(_number(v) for v in (K[0, 0], K[0, 1], K[0, 2],
                                                                                      K[1, 1], K[1, 2])), *extra]))
    return lines


def _lines(text: str) -> Iterator[tuple[int, str]]:
    for number, line in enumerate(text.splitlines(), start=1):
        yield number, line.strip()


def _next(lines: Iterator[tuple[int, str]], what: str) -> tuple[int, str]:
    try:
        return next(lines)
    except StopIteration:
        raise CamcalError(f"truncated 3DE lens file: it ends before {what} (no {_END} line)") from None


def _floats(line: str, count: int, number: int, what: str) -> list[float]:
    tokens = line.split()
    if len(tokens) < count:
        raise CamcalError(f"line {number}: {what} needs {count} numbers, got {line!r}")
    try:
        values = [float(v) for v in tokens[:count]]
    except ValueError:
        raise CamcalError(f"line {number}: {what} must be numbers, got {line!r}") from None
    if not all(np.isfinite(values)):
        raise CamcalError(f"line {number}: {what} is not finite")
    return values


def load(path: Path, *, image_size: tuple[int, int] | None = None) -> ImportResult:
    """Read a 3DE4 lens file as a one-camera rig (see the module docstring)."""
    check_file_size(path, FILE_BYTES, "3DE lens file")
    text = path.read_text(errors="replace")
    lines = _lines(text)
    _, name = _next(lines, "the lens name")
    number, line = _next(lines, "the film back line")
    fb_w, fb_h, focal, _, lco_x, lco_y, pixel_aspect = _floats(line, 7, number, "the film back line")
    number, mode = _next(lines, "the dynamic distortion mode")
    number, ldpk_name = _next(lines, "the lens model name")
    models = {ldpk: model for model, ldpk in LDPK_MODEL_NAMES.items()}
    if ldpk_name not in models:
        raise CamcalError(f"line {number}: unknown 3DE lens model {ldpk_name!r}, expected one of: "
                          + ", ".join(models))
    model = models[ldpk_name]
    keys = {p.ldpk_name: p.key for p in LDPK_PARAMETERS[model]}
    params = {p.key: p.default for p in LDPK_PARAMETERS[model]}
    curves: dict[str, list[tuple[float, float]]] = {}
    curve_lines: dict[str, tuple[int, str]] = {}
    while True:
        number, parameter = _next(lines, "the next parameter")
        if parameter == _END:
            break
        if parameter not in keys:
            raise CamcalError(f"line {number}: {ldpk_name!r} has no parameter {parameter!r}; it has: "
                              + ", ".join(keys))
        value_number, value = _next(lines, f"the value of {parameter!r}")
        [params[keys[parameter]]] = _floats(value, 1, value_number, f"the value of {parameter!r}")
        count_number, count = _next(lines, f"the curve of {parameter!r}")
        [n_keys] = _floats(count, 1, count_number, f"the number of keys of {parameter!r}")
        curve = []
        for _ in range(int(n_keys)):
            key_number, key = _next(lines, f"a key of {parameter!r}")
            curve.append(tuple(_floats(key, 2, key_number, f"a key of {parameter!r}")))
        curves[keys[parameter]] = sorted(curve)
        curve_lines[keys[parameter]] = (count_number, parameter)
    lut: dict[str, dict[tuple[float, float], float]] = {}
    size, frames = image_size, []
    for number, rest in lines:
        if rest == _LUT_BEGIN:
            lut = _read_lut(lines, keys)
        elif rest.startswith(_SIZE_LINE) and size is None:
            width, height = _floats(rest[len(_SIZE_LINE):], 2, number, "the image size")
            size = (int(width), int(height))
        elif rest.startswith(_FRAME_LINE):
            frames.append(_read_frame_line(rest[len(_FRAME_LINE):], number))
    if size is None:
        raise CamcalError("the lens file holds no image size (3DE lens files have none): give it (--image-size)")
    for key, curve in curves.items():
        if curve and not frames and mode not in _STATIC and mode != _FOCUS:  # a 3DE lens: the key at its own focal
            at_focal = [y for x, y in curve if x == focal]
            if not at_focal:
                count_number, parameter = curve_lines[key]
                raise CamcalError(f"line {count_number}: {parameter!r} changes with {mode} and has no key at the "
                                  f"lens' focal length {focal:g} cm; camcal holds one lens per camera")
            params[key] = at_focal[0]
    filmback = {FILMBACK_KEYS[0]: float(size[0]), FILMBACK_KEYS[1]: float(size[1])}
    try:
        K = LdpkCamera(focal, fb_w, fb_h, lco_x, lco_y, pixel_aspect).camera_matrix(size)
        lens = Distortion(model, {**params, **filmback})
        camera = Camera(name or "lens", size, K, lens, np.eye(3), np.zeros(3), sensor_width_mm=fb_w * 10.0)
        rig_frames = tuple(
            Frame(index, np.eye(3), np.zeros(3), lenses={} if state is None else {camera.name: Lens(
                frame_K, Distortion(model, {**_params_at(params, curves, lut, mode, state, index), **filmback}),
                state.get("focal_mm"), state.get("focus_m"))})
            for index, frame_K, state in frames)
        rig = Rig((camera,), units="unknown", frames=rig_frames)
    except CamcalError as error:
        raise CamcalError(f"lens {name!r}: {error}") from None
    notes = ["a 3DE lens file holds no pose: the camera is at the origin"]
    if frames:
        notes.append(f"{len(frames)} frames from the file's camcal lines, each frame's lens from the {mode} curves")
    return ImportResult(rig, (LensConversion(camera.name, f"3DE {ldpk_name}", model, True),), tuple(notes))


def _read_lut(lines: Iterator[tuple[int, str]], keys: dict[str, str]) -> dict[str, dict[tuple[float, float], float]]:
    """The 2D LUT after ``<end_of_file>``: parameter -> (focal cm, focus cm) -> value."""
    lut: dict[str, dict[tuple[float, float], float]] = {}
    while True:
        number, parameter = _next(lines, _LUT_END)
        if parameter == _LUT_END:
            return lut
        if parameter not in keys:
            raise CamcalError(f"line {number}: the 2D LUT names no parameter of the lens: {parameter!r}")
        count_number, count = _next(lines, f"the LUT samples of {parameter!r}")
        [n] = _floats(count, 1, count_number, f"the number of LUT samples of {parameter!r}")
        samples = lut.setdefault(keys[parameter], {})
        for _ in range(int(n)):
            sample_number, sample = _next(lines, f"a LUT sample of {parameter!r}")
            focal, focus, value = _floats(sample, 3, sample_number, f"a LUT sample of {parameter!r}")
            samples[(focal, focus)] = value


def _read_frame_line(text: str, number: int) -> tuple[int, np.ndarray, dict[str, float] | None]:
    """``INDEX fx skew cx fy cy [focal_mm=F] [focus_m=D]`` -> (index, K, lens state or None: the camera's own)."""
    tokens = text.split()
    index, fx, skew, cx, fy, cy = _floats(" ".join(tokens[:6]), 6, number, "a camcal frame line")
    state = {}
    for token in tokens[6:]:
        key, _, value = token.partition("=")
        if key not in ("focal_mm", "focus_m"):
            raise CamcalError(f"line {number}: unknown lens state {key!r} (focal_mm, focus_m)")
        [state[key]] = _floats(value, 1, number, key)
    K = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return int(index), K, (state or None)


def _params_at(params: dict[str, float], curves: dict[str, list[tuple[float, float]]],
               lut: dict[str, dict[tuple[float, float], float]], mode: str, state: dict[str, float],
               index: int) -> dict[str, float]:
    """The lens's parameters at a frame's lens state: its curves (linear between keys, exact at one) or LUT sample."""
    focal_cm = state["focal_mm"] / 10.0 if "focal_mm" in state else None
    focus_cm = state["focus_m"] * 100.0 if "focus_m" in state else None
    out = dict(params)
    for key in out:
        if mode == _BOTH:
            samples = lut.get(key, {})
            if (focal_cm, focus_cm) not in samples:
                raise CamcalError(f"frame {index}: its lens state ({focal_cm} cm, {focus_cm} cm) is no 2D LUT sample")
            out[key] = samples[(focal_cm, focus_cm)]
        elif curves.get(key) and mode in (_FOCAL, _FOCUS):
            x = focal_cm if mode == _FOCAL else focus_cm
            if x is None:
                raise CamcalError(f"frame {index}: no {'focal_mm' if mode == _FOCAL else 'focus_m'} to read {mode} at")
            xs, ys = zip(*curves[key])
            out[key] = float(np.interp(x, xs, ys))
    return out
