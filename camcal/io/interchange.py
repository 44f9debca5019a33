"""Rig interchange: camcal rigs to and from other tools' camera files.

One entry point per direction, :func:`export_rig` and :func:`import_rig`,
over one module per format:

==========  ===================================  =====================================
format      module                               files
==========  ===================================  =====================================
opencv      :mod:`camcal.io.opencv`              FileStorage YAML (.yaml/.yml) or XML
kalibr      :mod:`camcal.io.kalibr`              camchain.yaml
colmap      :mod:`camcal.io.colmap_text`         cameras.txt, images.txt, points3D.txt
usd         :mod:`camcal.io.usd`                 .usda / .usdc / .usd (usd-core)
nuke        :mod:`camcal.io.nuke`                .nk (Camera3, LensDistortion, LDPK, STMap)
3de         :mod:`camcal.io.tde`                 3DEqualizer lens file (.txt)
lensfun     :mod:`camcal.io.lensfun`             Lensfun lens database (.xml, named with --to / --from)
==========  ===================================  =====================================

The format may be left out (None) where the file name says it
(:func:`format_of`: ``.nk``, ``.usda`` / ``.usdc`` / ``.usd``, ``.txt``).

Each format holds a subset of camcal's camera model. When a camera's lens
(or skew) has no exact counterpart, the exporter refits the nearest model
the format holds, every format through the one core
:func:`camcal.io.conversion.refit_camera`, and reports the pixel distance
between where the camcal camera and the exported one put the same rays
(:func:`camcal.io.conversion.max_pixel_residual`, over a 16 px grid of the
whole frame, and the refit's max and RMS inside the image and over a 1.25
overscan border); conversions without loss say so. Which
camcal model each format holds exactly is the one table
:func:`camcal.io.conversion.exactness_table`.

A new format is one module with ``load`` and ``export`` (importing
:mod:`camcal.io.conversion`, never this module) and one row of
:data:`_MODULES`.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType, ModuleType

from camcal.base.errors import CamcalError
from camcal.io.conversion import ExportResult, ImportResult
from camcal.model.rig import Rig

__all__ = ["FORMATS", "export_rig", "format_of", "import_rig"]

#: Format name -> the module that reads and writes it (``load(path, ...)``
#: and ``export(rig, out, ...)``), imported only when the format is used.
#: The format modules never import this one (their shared types live in
#: :mod:`camcal.io.conversion`).
_MODULES: Mapping[str, str] = MappingProxyType({
    "opencv": "camcal.io.opencv",
    "kalibr": "camcal.io.kalibr",
    "colmap": "camcal.io.colmap_text",
    "usd": "camcal.io.usd",
    "nuke": "camcal.io.nuke",
    "3de": "camcal.io.tde",
    "lensfun": "camcal.io.lensfun",
})

#: The formats ``camcal rig export / import`` know.
FORMATS: tuple[str, ...] = tuple(_MODULES)
#: The formats that key a camera's lens per frame (a rig's ``frames[i].lenses``); the others hold its own lens.
_PER_FRAME_LENS_FORMATS = ("nuke", "usd", "3de")

#: File suffixes that name one format (``.yaml`` is OpenCV's or Kalibr's; COLMAP's model is a directory).
_SUFFIXES: Mapping[str, str] = MappingProxyType({
    ".nk": "nuke", ".usda": "usd", ".usdc": "usd", ".usd": "usd", ".txt": "3de",
})


def format_of(path: str | os.PathLike, fmt: str | None = None) -> str:
    """``fmt`` when given, else the format the file name says (``.nk`` nuke, ``.usd*`` usd, ``.txt`` 3de).

    Raises
    ------
    CamcalError
        No format given and the name says none (``.yaml`` may be OpenCV's
        or Kalibr's: name it).
    """
    if fmt is not None:
        return fmt
    suffix = Path(path).suffix.lower()
    if suffix not in _SUFFIXES:
        raise CamcalError(f"cannot tell the format of {Path(path).name!r} from its name; name one of: "
                          f"{', '.join(FORMATS)}")
    return _SUFFIXES[suffix]


def export_rig(
    rig: Rig,
    fmt: str | None,
    out: str | os.PathLike,
    *,
    cameras: Sequence[str] | None = None,
    rig_path: str | os.PathLike | None = None,
    stmaps: bool = False,
) -> ExportResult:
    """Write ``rig`` in another tool's format.

    Parameters
    ----------
    rig : Rig
    fmt : str or None
        One of :data:`FORMATS`; None: from ``out``'s name (:func:`format_of`).
    out : path
        The file to write (a directory for ``colmap``).
    cameras : sequence of str, optional
        Export only these cameras (all by default).
    rig_path : path, optional
        Where ``rig`` was read from: its sparse-points PLY is found beside it.
    stmaps : bool
        ``usd`` only: also write each lens' ST-maps beside the stage and
        reference them from the camera (``nuke`` always writes them).

    Raises
    ------
    CamcalError
        Unknown format, a rig the format cannot hold, or an unwritable
        output; nothing is written then.
    """
    fmt = format_of(out, fmt)
    module = _module(fmt)
    if stmaps and fmt != "usd":
        raise CamcalError(f"stmaps applies to usd only (nuke always writes them), not {fmt}")
    extra = {"stmaps": True} if stmaps else {}
    result = module.export(rig, Path(out), cameras=cameras, rig_path=None if rig_path is None else Path(rig_path),
                           **extra)
    zooming = [name for name in (cameras or [c.name for c in rig.cameras]) if rig.lens_frames(name)] \
        if isinstance(rig, Rig) else []
    if zooming and fmt not in _PER_FRAME_LENS_FORMATS:
        result = dataclasses.replace(result, notes=(*result.notes, (
            f"{fmt} holds one lens per camera: the per-frame lenses of {', '.join(zooming)} are not written (their "
            f"own lens is); {', '.join(_PER_FRAME_LENS_FORMATS)} key them per frame")))
    return result


def import_rig(path: str | os.PathLike, fmt: str | None, *, image_size: tuple[int, int] | None = None) -> ImportResult:
    """Read another tool's camera file as a camcal rig (see :func:`export_rig`).

    Parameters
    ----------
    path : path
    fmt : str or None
        One of :data:`FORMATS`; None: from ``path``'s name (:func:`format_of`).
    image_size : (int, int), optional
        ``usd``, ``3de`` and ``nuke`` only: width and height in pixels of
        the cameras that carry none (plain USD cameras, lens files and LDPK
        nodes 3DEqualizer wrote; the other formats hold the image size).

    Raises
    ------
    CamcalError
        Missing file, wrong format, a file without what a camera needs, or
        non-finite numbers, in one line naming the file.
    """
    fmt = format_of(path, fmt)
    module = _module(fmt)
    path = Path(path)
    extra = {}
    if image_size is not None:
        if fmt not in ("usd", "3de", "nuke"):
            raise CamcalError(f"an image size applies to usd, 3de and nuke only ({fmt} files hold their own)")
        width, height = image_size
        if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (width, height)):
            raise CamcalError(f"the image size must be two positive integers, got {width} {height}")
        extra["image_size"] = (width, height)
    if not path.exists():
        raise CamcalError(f"{fmt} input not found: {path}")
    try:
        return module.load(path, **extra)
    except CamcalError as error:
        message = str(error)
        raise CamcalError(message if message.startswith(str(path)) else f"{path}: {message}") from None


def _module(fmt: str) -> ModuleType:
    if fmt not in _MODULES:
        raise CamcalError(f"unknown format {fmt!r}, expected one of: {', '.join(FORMATS)}")
    return importlib.import_module(_MODULES[fmt])
