"""OpenColorIO files: base configs read, configs with their CLF files written.

:func:`export_ocio` writes ``config.ocio`` (and ``luts/*.clf``) for colour
fits and matches: :func:`load_base_config`, then
:func:`camcal.colour.export.ocio_fit.config_spec_from_fits` (the pure
description), then :func:`write_ocio_config`, at the OCIO profile version
the target hosts load (:mod:`camcal.colour.export.ocio_versions`; 2.3 by
default: Blender 4.2 and later, the VFX Reference Platform CY2024 and later).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from camcal import resources
from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.colour.bake.transforms import LUT_SIZES, ocio_module
from camcal.colour.export.ocio_config import CAMCAL_BASE, STUDIO_CONFIG, ConfigSpec, build_ocio_config
from camcal.colour.export.ocio_fit import SpaceExport, config_spec_from_fits
from camcal.colour.export.ocio_versions import (
    DEFAULT_PROFILE_VERSION,
    builtin_base_for_version,
    parse_profile_version,
    profile_version_of,
)
from camcal.colour.fit.record import ColourFit

__all__ = ["base_config_path", "load_base_config", "write_ocio_config", "OCIOExport", "export_ocio"]


def base_config_path() -> Path:
    """camcal's base config template, ``camcal_base.ocio`` of :func:`camcal.resources.ocio_configs_dir`.

    ``CAMCAL_OCIO_CONFIGS`` overrides the folder.
    """
    override = os.environ.get("CAMCAL_OCIO_CONFIGS")
    folder = Path(override) if override else resources.ocio_configs_dir()
    path = folder / "camcal_base.ocio"
    if not path.is_file():
        raise CamcalError(f"camcal's base OCIO config was not found at {path} (set CAMCAL_OCIO_CONFIGS)")
    return path


def load_base_config(base: str | os.PathLike = STUDIO_CONFIG):
    """Load a base config: ``"camcal"``, an ``ocio://`` built-in name or a ``.ocio`` file.

    Returns
    -------
    PyOpenColorIO.Config
        A new (editable) config.

    Raises
    ------
    CamcalError
        Unknown built-in, missing or unreadable file.
    """
    ocio = ocio_module()
    text = str(base)
    if text == CAMCAL_BASE:
        text = str(base_config_path())
    elif not text.startswith("ocio://") and not Path(text).is_file():
        raise CamcalError(f"base OCIO config not found: {text} (give 'camcal', ocio://NAME or a .ocio file)")
    try:
        return ocio.Config.CreateFromFile(text)
    except ocio.Exception as error:
        raise CamcalError(f"cannot load the base OCIO config {text}: {error}") from None


def write_ocio_config(spec: ConfigSpec, directory: str | os.PathLike, filename: str = "config.ocio") -> Path:
    """Write the config and its files into ``directory``, each atomically, the config last.

    The config is built and validated before anything is written.

    Returns
    -------
    Path
        The config file.
    """
    config = build_ocio_config(spec)
    text = config.serialize()
    directory = Path(directory)
    for relative, content in spec.files.items():
        atomic_write_text(directory / relative, content)
    path = directory / filename
    atomic_write_text(path, text)
    return path


@dataclass(frozen=True)
class OCIOExport:
    """The written config, the base it extends (a built-in alias resolved), its profile version, its spaces."""

    config_path: Path
    base: str
    spaces: tuple[SpaceExport, ...]
    profile_version: str


def export_ocio(
    fits: Sequence[tuple[str, ColourFit]],
    directory: str | os.PathLike,
    *,
    base: str = STUDIO_CONFIG,
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    matches: Sequence = (),
    ocio_version: str = DEFAULT_PROFILE_VERSION,
    family: str | None = None,
    home: str | os.PathLike | None = None,
) -> OCIOExport:
    """Write ``directory/config.ocio`` (+ ``luts/*.clf``): ``base`` plus one space per camera.

    A base ``.ocio`` file in the folder the config goes to is extended in
    place: written back under its own name, its roles, spaces, search paths
    and everything else kept.

    Parameters
    ----------
    fits
        ``(camera name, fit)`` pairs; names must be unique.
    directory
        Output folder.
    base, cat, max_delta_E, lut_sizes, family
        See :class:`ConfigSpec` and :func:`colour_space_from_fit`.
    matches
        Camera matches (kind ``match``), each written as a Look
        (:func:`look_from_match`).
    ocio_version
        The OCIO profile version written, at most (``"2.3"``: OpenColorIO
        2.3 and later load the config; see
        :mod:`camcal.colour.export.ocio_versions`). A base made for a newer
        version is written at this one when it uses nothing newer, else
        refused with the reason; an older base keeps its version.
    home
        The folder the config ends up in when ``directory`` is a staging
        folder renamed there afterwards (default: ``directory``).

    Returns
    -------
    OCIOExport
        ``spaces`` lists the colour spaces, then the Looks.

    Raises
    ------
    CamcalError
        Unknown version, a base that cannot be written at it, or any error
        of :func:`config_spec_from_fits`; nothing is written then.
    """
    version = parse_profile_version(ocio_version)
    base_name = builtin_base_for_version(str(base), version)
    config = load_base_config(base_name)
    spec, reports = config_spec_from_fits(fits, config, cat=cat, max_delta_E=max_delta_E, lut_sizes=lut_sizes,
                                          matches=matches, family=family)
    home = Path(home if home is not None else directory)
    spec = dataclasses.replace(spec, profile_version=version, home=str(home))
    in_place = (base_name != CAMCAL_BASE and Path(base_name).is_file()
                and Path(base_name).resolve().parent == home.resolve())
    path = write_ocio_config(spec, directory, Path(base_name).name if in_place else "config.ocio")
    written = min(profile_version_of(config), version)
    return OCIOExport(path, base_name, reports, f"{written[0]}.{written[1]}")
