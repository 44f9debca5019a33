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
principal point's (:class:`camcal.model.tde4.LdpkCamera`). The lens is static
(a camcal camera has one lens): ``DISTORTION_STATIC``, no curve keys. A lens
file holds no image size, which camcal needs: it is written on a line after
``<end_of_file>`` (``# camcal image_size W H``, which 3DE's reader passes
over), and :func:`load` takes it from there or from ``image_size``.

Reading takes a static lens, or a dynamic one whose every keyed curve has a
key at the lens' own focal length (its value there is the lens); a model
name that is not one of the four, a parameter the model does not have, a
missing line or value, and a file without ``<end_of_file>`` are refused in
one line naming the problem.

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
    nearest_family,
    refit_camera,
    select_cameras,
)
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from camcal.model.tde4 import FILMBACK_KEYS, LDPK_MODEL_NAMES, LDPK_PARAMETERS, LdpkCamera

__all__ = ["DEFAULT_FILMBACK_WIDTH_MM", "export", "load"]

#: Film back width of cameras without ``sensor_width_mm``.
DEFAULT_FILMBACK_WIDTH_MM = 36.0

_END = "<end_of_file>"
_SIZE_LINE = "# camcal image_size"
_STATIC = ("DISTORTION_STATIC", "0")


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
    lines = [camera.name,
             " ".join(_number(v) for v in (builtin.filmback_width_cm, builtin.filmback_height_cm,
                                           builtin.focal_length_cm,
                                           builtin.filmback_width_cm / builtin.filmback_height_cm,
                                           builtin.lens_center_offset_x_cm, builtin.lens_center_offset_y_cm,
                                           builtin.pixel_aspect)),
             "DISTORTION_STATIC", LDPK_MODEL_NAMES[family]]
    for parameter in LDPK_PARAMETERS[family]:
        lines += [parameter.ldpk_name, _number(converted.distortion.params.get(parameter.key, parameter.default)), "0"]
    width, height = camera.image_size
    lines += [_END, f"{_SIZE_LINE} {width} {height}"]
    atomic_write_text(out, "\n".join(lines) + "\n")
    source = f"{camera.distortion.model}{' with skew' if camera.K[0, 1] else ''}"
    conversion = LensConversion(camera.name, source, f"3DE {LDPK_MODEL_NAMES[family]}", refit.exact, refit.max_px,
                                "refit", refit)
    notes = ["a 3DE lens file holds no pose: the camera's position and orientation are not written"]
    return ExportResult((out,), (conversion,), tuple(notes))


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
        at_focal = None
        for _ in range(int(n_keys)):
            key_number, key = _next(lines, f"a key of {parameter!r}")
            x, y = _floats(key, 2, key_number, f"a key of {parameter!r}")
            at_focal = y if x == focal else at_focal
        if n_keys and mode not in _STATIC:
            if at_focal is None:
                raise CamcalError(f"line {count_number}: {parameter!r} changes with {mode} and has no key at the "
                                  f"lens' focal length {focal:g} cm; camcal holds one lens per camera")
            params[keys[parameter]] = at_focal
    size = image_size
    for number, rest in lines:
        if rest.startswith(_SIZE_LINE) and size is None:
            width, height = _floats(rest[len(_SIZE_LINE):], 2, number, "the image size")
            size = (int(width), int(height))
    if size is None:
        raise CamcalError("the lens file holds no image size (3DE lens files have none): give it (--image-size)")
    try:
        K = LdpkCamera(focal, fb_w, fb_h, lco_x, lco_y, pixel_aspect).camera_matrix(size)
        lens = Distortion(model, {**params, FILMBACK_KEYS[0]: float(size[0]), FILMBACK_KEYS[1]: float(size[1])})
        camera = Camera(name or "lens", size, K, lens, np.eye(3), np.zeros(3), sensor_width_mm=fb_w * 10.0)
    except CamcalError as error:
        raise CamcalError(f"lens {name!r}: {error}") from None
    return ImportResult(Rig((camera,), units="unknown"), (LensConversion(camera.name, f"3DE {ldpk_name}", model, True),),
                        ("a 3DE lens file holds no pose: the camera is at the origin",))
