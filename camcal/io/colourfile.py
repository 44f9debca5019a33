"""Colour files ``*.colour.json``: read (any kind, validated) and written atomically.

The records are :class:`camcal.colour.fit.record.ColourFit` (kind
``characterisation``) and :class:`camcal.colour.match.record.ColourMatch`
(kind ``match``); the format is documented in :mod:`camcal.colour.fit.record`.
Every kind is listed explicitly in :data:`FILE_KINDS` with the class whose
``from_dict`` reads it: nothing registers itself as a side effect of an import.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

from camcal.base.errors import CamcalError
from camcal.base.jsonfile import read_json, write_json
from camcal.colour.fit.record import ColourFit, LinearisedModel, check_header
from camcal.colour.match.record import ColourMatch

__all__ = [
    "FILE_KINDS",
    "reader_of",
    "read_colour_dict",
    "load_colour_file",
    "load_fit",
    "load_match",
    "save_colour_file",
]

#: Every kind of ``*.colour.json``: kind -> the class whose ``from_dict`` reads it.
FILE_KINDS: Mapping[str, type] = MappingProxyType({
    "characterisation": ColourFit,
    "match": ColourMatch,
})


def reader_of(kind: str) -> Callable[[dict], Any]:
    """The ``from_dict`` of the class that reads files of ``kind`` (see :data:`FILE_KINDS`)."""
    return FILE_KINDS[kind].from_dict


def read_colour_dict(path: str | os.PathLike) -> dict:
    """The JSON object of a ``*.colour.json`` file (parsed, not validated)."""
    return read_json(path, "colour fit file")


def load_colour_file(path: str | os.PathLike, kind: str | None = None) -> Any:
    """Load a ``*.colour.json`` of any kind (dispatching on ``kind`` in the file).

    Parameters
    ----------
    path
        The file.
    kind
        When given, the file must be of this kind.

    Raises
    ------
    CamcalError
        ``"<path>: <field>: <what is wrong>"`` for a bad file.
    """
    data = read_colour_dict(path)
    try:
        found = check_header(data, kind)
        return reader_of(found)(data)
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None


def load_fit(path: str | os.PathLike) -> ColourFit:
    """Load and validate a characterisation ``*.colour.json``.

    Returns
    -------
    ColourFit
        ``.apply(RGB_linear)`` gives XYZ (white Y = 1); ``.linearise(codes)``
        gives linear RGB from code values.

    Raises
    ------
    CamcalError
        ``"<path>: <field>: <what is wrong>"`` for a bad file.
    """
    return load_colour_file(path, "characterisation")


def load_match(path: str | os.PathLike) -> ColourMatch:
    """Load and validate a ``*.colour.json`` of kind ``match``.

    Raises
    ------
    CamcalError
        ``"<path>: <field>: <what is wrong>"`` for a bad file.
    """
    return load_colour_file(path, "match")


def save_colour_file(record: LinearisedModel, path: str | os.PathLike) -> Path:
    """Write a colour record (a fit or a match) atomically; returns the path."""
    return write_json(path, record.to_dict())  # type: ignore[attr-defined]
