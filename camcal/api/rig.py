"""Rig files: ``camcal.load_rig``, ``camcal.export_rig`` and ``camcal.import_rig``, as ``rig show | export | import``.

The format of another tool's file is taken from its name when that is
unambiguous (:func:`camcal.io.interchange.format_of`: ``.nk`` Nuke, ``.usda`` /
``.usdc`` / ``.usd`` USD, ``.txt`` a 3DEqualizer lens file); a ``.yaml`` is
OpenCV's or Kalibr's and a COLMAP model is a folder, so those need the format
named.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING


if TYPE_CHECKING:
    from camcal.colour.flatfield import FlatField
    from camcal.io.conversion import ExportResult, ImportResult, LensConversion
    from camcal.model.lens_profile import LensProfile
    from camcal.model.rig import Rig

__all__ = ["RigImport", "export_rig", "import_rig", "load_rig"]


def load_rig(path: str | os.PathLike) -> Rig:
    """Read and validate a ``*.rig.json`` file (:meth:`camcal.model.rig.Rig.load`).

    Raises
    ------
    CamcalError
        Missing or unreadable file, malformed JSON, or an invalid field, in one line starting with the file name.
    """
    from camcal.model.rig import Rig

    return Rig.load(path)


def export_rig(rig: Rig | LensProfile | str | os.PathLike, path: str | os.PathLike, to: str | None = None, *,
               cameras: Sequence[str] | None = None, stmaps: bool = False,
               sensor_width_mm: float | None = None,
               vignetting: Mapping[str, str | os.PathLike | FlatField] | None = None,
               tca: Mapping[str, str | os.PathLike | Sequence[str | os.PathLike]] | None = None) -> ExportResult:
    """Write a rig for another tool (``camcal rig export``).

    opencv: ``.yaml`` / ``.yml`` / ``.xml`` FileStorage (one camera or a stereo
    pair); kalibr: ``camchain.yaml``; colmap: a folder with ``cameras.txt``,
    ``images.txt``, ``points3D.txt``; usd: ``.usda`` / ``.usdc`` / ``.usd``;
    nuke: ``.nk``; 3de: a 3DEqualizer lens file (``.txt``, one camera). A lens or skew the format cannot hold is
    fitted with the
    nearest model it holds and the largest pixel residual is reported
    (:attr:`ExportResult.conversions <camcal.io.conversion.ExportResult>`).

    Parameters
    ----------
    rig : Rig, LensProfile or path
        The rig, or its ``*.rig.json`` (whose sparse-points PLY is found beside it), or a lens profile (or its
        ``*.profile.json``: :func:`camcal.api.profile.export_profile`: lensfun, lens-table, opentrackio, 3de).
    path : path
        The file (a folder for colmap) to write.
    to : str, optional
        The format (:data:`camcal.io.interchange.FORMATS`); default: from ``path``'s name
        (:func:`camcal.io.interchange.format_of`).
    cameras : sequence of str, optional
        Export only these cameras.
    stmaps : bool
        usd: also write each lens' ST-maps beside the stage and reference them from its camera.
    sensor_width_mm : float, optional
        A lens profile's opentrackio (required) and 3de exports: the sensor's active width in mm.
    vignetting : mapping of str to (path or FlatField), optional
        A lens profile's lensfun export: flat fields by the lens state they were shot at
        (``{"24mm@1.2m/f4": "flat24.json"}``, :func:`camcal.api.profile.export_profile`).
    tca : mapping of str to (glob or image files), optional
        A lens profile's lensfun export: colour board images by focal length (``{"24mm": "tca/24/*.png"}``).

    Returns
    -------
    ExportResult
        The files written, each camera's conversion and notes.

    Raises
    ------
    CamcalError
        Unknown format, a rig the format cannot hold, or an unwritable output; nothing is written then.
    """
    from camcal.io.interchange import export_rig as export_as
    from camcal.model.lens_profile import LensProfile
    from camcal.model.rig import Rig

    if isinstance(rig, LensProfile) or (not isinstance(rig, Rig) and os.fspath(rig).endswith(".profile.json")):
        from camcal.api.profile import export_profile

        return export_profile(rig, path, to, sensor_width_mm=sensor_width_mm, vignetting=vignetting, tca=tca)
    from camcal.base.errors import CamcalError

    if vignetting or tca:
        raise CamcalError(f"{'--vignetting' if vignetting else '--tca'} applies to a lens profile's lensfun export "
                          "(*.profile.json), not a rig")

    if to in ("lens-table", "opentrackio"):
        raise CamcalError(f"--to {to} exports a lens profile (*.profile.json, camcal calibrate profile), not a rig")
    if sensor_width_mm is not None:
        raise CamcalError("a sensor width applies to a lens profile's opentrackio and 3de exports (a rig's camera "
                          "carries its own)")
    rig_path = None if isinstance(rig, Rig) else rig
    loaded = rig if isinstance(rig, Rig) else Rig.load(rig)
    return export_as(loaded, to, path, cameras=cameras, rig_path=rig_path, stmaps=stmaps)


@dataclass(frozen=True)
class RigImport:
    """Another tool's camera file read as a rig (:func:`import_rig`).

    Attributes
    ----------
    rig : Rig
        The cameras, with the provenance of the import (format and source).
    format : str
    result : ImportResult
        What the reader found: conversions, notes and the sparse points (COLMAP) if any.
    """

    rig: Rig
    format: str
    result: ImportResult

    @property
    def conversions(self) -> tuple[LensConversion, ...]:
        """Each camera's conversion to camcal's lens models (exact or fitted, with its residual)."""
        return tuple(self.result.conversions)

    @property
    def notes(self) -> tuple[str, ...]:
        """What the reader assumed or left out."""
        return tuple(self.result.notes)

    def save(self, path: str | os.PathLike) -> tuple[tuple[Path, str], ...]:
        """Write the rig file (and its sparse points beside it, ``NAME.points.ply``); ``(path, kind)`` of each."""
        import dataclasses

        from camcal.io.ply import write_points_ply

        rig, files = self.rig, []
        if self.result.points_xyz is not None:
            name = Path(path).name.removesuffix(".json").removesuffix(".rig") + ".points.ply"
            points = write_points_ply(Path(path).with_name(name), self.result.points_xyz, self.result.points_rgb)
            files.append((points, "points"))
            rig = dataclasses.replace(rig, points=points.name)
        files.append((rig.save(path), "rig"))
        return tuple(files)


def import_rig(path: str | os.PathLike, from_: str | None = None, *,
               image_size: tuple[int, int] | None = None) -> RigImport:
    """Read another tool's camera file as a camcal rig (``camcal rig import``; formats as :func:`export_rig`).

    Parameters
    ----------
    path : path
        The file (a folder for colmap).
    from_ : str, optional
        Its format; default: from its name (:func:`camcal.io.interchange.format_of`).
    image_size : (int, int), optional
        usd, 3de, nuke: width and height in pixels of cameras that carry none.

    Returns
    -------
    RigImport
        ``.rig``, and ``.save(path)`` to write it.

    Raises
    ------
    CamcalError
        Missing file, wrong format, a file without what a camera needs, or non-finite numbers, in one line naming
        the file.
    """
    import dataclasses

    from camcal.io.interchange import format_of, import_rig as import_as
    from camcal.model.rig import make_provenance

    if from_ == "opentrackio":
        from pathlib import Path

        from camcal.base.errors import CamcalError
        from camcal.io.opentrackio import load

        if image_size is not None:
            raise CamcalError("an image size applies to usd, 3de and nuke only (opentrackio files hold their own)")
        if not Path(path).is_file():
            raise CamcalError(f"opentrackio input not found: {path}")
        try:
            fmt, result = from_, load(Path(path))
        except CamcalError as error:
            raise CamcalError(f"{path}: {error}") from None
    else:
        fmt = format_of(path, from_)
        result = import_as(path, fmt, image_size=image_size)
    rig = dataclasses.replace(result.rig, provenance=make_provenance("import", format=fmt, source=str(path)))
    return RigImport(rig, fmt, result)
