"""The board images of each lens state of a lens profile, from folder names, the images' EXIF or a CSV
(``calibrate profile --states-from folders DIR | exif GLOB | csv FILE``).

- ``folders DIR``: each sub-folder of ``DIR`` is a lens state named as ``--state`` names one
  (:func:`camcal.model.lens_profile.parse_state`: ``24mm@1.2m``, ``35mm@120cm``, ``50mm@inf``), or with ``_``
  for the ``@`` (``24mm_1.2m``, ``50mm_inf``); its images (:data:`IMAGE_SUFFIXES`) are the state's. Files
  directly in ``DIR`` and hidden sub-folders are not read.
- ``exif GLOB``: the images grouped by the focal length and focus distance their EXIF records
  (:func:`camcal.io.lens_metadata.read_exif_lens_state`: ``FocalLength``, ``SubjectDistance``).
- ``csv FILE``: a CSV ``image,focal_mm,focus_m`` (:func:`camcal.io.lens_metadata.read_image_lens_states`).

Every state must have at least :data:`camcal.geometry.zhang.MIN_IMAGES` images (a board calibration's
minimum). A folder's state is labelled by its name (``_`` read as ``@``); the states of EXIF and a CSV as
``24mm@1.2m`` (:func:`camcal.model.lens_profile.format_state`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from camcal.base.errors import CamcalError
from camcal.base.globs import expand_glob
from camcal.geometry.zhang_starts import MIN_IMAGES
from camcal.io.lens_metadata import read_exif_lens_state, read_image_lens_states
from camcal.model.lens_profile import format_state, parse_state
from camcal.pipelines.solve_inputs import IMAGE_SUFFIXES

__all__ = ["STATE_SOURCES", "folder_state_label", "states_from"]

#: Where ``--states-from`` reads the lens states: sub-folder names, the images' EXIF, a CSV.
STATE_SOURCES = ("folders", "exif", "csv")
#: At most this many files are named in an error.
_NAMED = 5


def _named(paths: Iterable[Path | str]) -> str:
    names = [Path(path).name for path in paths]
    return ", ".join(names[:_NAMED]) + (f" and {len(names) - _NAMED} more" if len(names) > _NAMED else "")


def folder_state_label(name: str) -> str:
    """The ``--state`` label of a state folder's name: ``24mm@1.2m`` as it is, ``24mm_1.2m`` as ``24mm@1.2m``.

    Raises
    ------
    CamcalError
        A name that is not a lens state (:func:`camcal.model.lens_profile.parse_state`'s message).

    Examples
    --------
    >>> folder_state_label("24mm_1.2m"), folder_state_label("50mm@inf")
    ('24mm@1.2m', '50mm@inf')
    """
    label = name if "@" in name else name.replace("_", "@", 1)
    parse_state(label)
    return label


def _from_folders(root: Path) -> dict[str, list[Path]]:
    if not root.is_dir():
        raise CamcalError(f"--states-from folders: not a folder: {root}")
    folders = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not folders:
        raise CamcalError(f"--states-from folders: {root} has no sub-folders (one per lens state, named like "
                          "24mm@1.2m or 24mm_1.2m)")
    labels, unparsable = {}, []
    for folder in folders:
        try:
            labels[folder] = folder_state_label(folder.name)
        except CamcalError:
            unparsable.append(folder.name)
    if unparsable:
        raise CamcalError(f"--states-from folders: sub-folder names that are not lens states: {_named(unparsable)} "
                          "(expected FOCALmm@FOCUSm or FOCALmm_FOCUSm, e.g. 24mm@1.2m, 35mm_120cm, 50mm_inf)")
    states: dict[str, list[Path]] = {}
    seen: dict[tuple[float, float], str] = {}
    for folder, label in labels.items():
        key = parse_state(label)
        if key in seen:
            raise CamcalError(f"--states-from folders: {seen[key]} and {folder.name} are the same lens state")
        seen[key] = folder.name
        states[label] = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    return states


def _grouped(rows: Iterable[tuple[Path, float, float]]) -> dict[str, list[Path]]:
    states: dict[str, list[Path]] = {}
    for path, focal, focus in rows:
        states.setdefault(format_state(focal, focus), []).append(path)
    return {label: sorted(paths) for label, paths in states.items()}


def _from_exif(pattern: str) -> dict[str, list[Path]]:
    files = [Path(path) for path in expand_glob("--states-from", "exif", pattern)]
    rows, lacking = [], {}
    for path in files:
        focal, focus = read_exif_lens_state(path)
        missing = [tag for tag, value in (("FocalLength", focal), ("SubjectDistance", focus)) if value is None]
        if missing:
            lacking[path] = missing
        else:
            rows.append((path, focal, focus))
    if lacking:
        tags = sorted({tag for missing in lacking.values() for tag in missing})
        raise CamcalError(f"--states-from exif: {len(lacking)} of {len(files)} images lack the EXIF "
                          f"{' and '.join(tags)} of their lens state: {_named(lacking)} (give the states with "
                          "--states-from csv or --state)")
    return _grouped(rows)


def states_from(source: str, where: str | os.PathLike) -> dict[str, tuple[Path, ...]]:
    """The board images of each lens state (see the module docstring), by state label, in focal-then-focus order.

    Parameters
    ----------
    source : str
        One of :data:`STATE_SOURCES`.
    where : path or glob
        The folder of state folders (``folders``), the glob of the images (``exif``), the CSV (``csv``).

    Raises
    ------
    CamcalError
        One line: an unknown source, a folder name that is not a lens state (every such name listed), two
        folders of one state, images lacking the EXIF tags (named), a bad CSV (its line), or a state with fewer
        than :data:`~camcal.geometry.zhang.MIN_IMAGES` images (every such state named).
    """
    if source not in STATE_SOURCES:
        raise CamcalError(f"--states-from: unknown source {source!r}, expected one of: {', '.join(STATE_SOURCES)}")
    if source == "folders":
        states = _from_folders(Path(where))
    elif source == "exif":
        states = _from_exif(os.fspath(where))
    else:
        states = _grouped(read_image_lens_states(where))
    few = {label: paths for label, paths in states.items() if len(paths) < MIN_IMAGES}
    if few:
        listed = "; ".join(f"{label} {len(paths)}" + (f" ({_named(paths)})" if paths else "")
                           for label, paths in few.items())
        raise CamcalError(f"--states-from {source}: a lens state needs at least {MIN_IMAGES} board images, "
                          f"{'these have' if len(few) > 1 else 'this has'} fewer: {listed}")
    return {label: tuple(states[label]) for label in sorted(states, key=parse_state)}
