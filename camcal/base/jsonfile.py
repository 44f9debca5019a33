"""JSON files as camcal writes and reads them.

Writing: 2-space indentation with arrays of numbers kept on one line (a
3x3 matrix reads as three rows), floats at ``repr`` precision so that files
round-trip exactly, NaN and infinity refused. Reading: one-line errors that
name the file (missing, unreadable, malformed JSON, duplicate keys, NaN/Infinity literals
with their field path, and the caps of :mod:`camcal.base.limits`: file size
and nesting depth).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.limits import JSON_BYTES, JSON_DEPTH, check_file_size

__all__ = ["dumps", "parse_json", "read_json", "write_json"]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _encode(value: Any, level: int) -> str:
    pad = "  " * (level + 1)
    end = "  " * level
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{pad}{json.dumps(str(k))}: {_encode(v, level + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + end + "}"
    if isinstance(value, (list, tuple)):
        if all(_is_number(v) for v in value):
            return json.dumps(list(value), allow_nan=False)
        if all(isinstance(v, (list, tuple)) and all(_is_number(x) for x in v) for v in value):
            rows = [pad + json.dumps(list(v), allow_nan=False) for v in value]
            return "[\n" + ",\n".join(rows) + "\n" + end + "]"
        return "[\n" + ",\n".join(pad + _encode(v, level + 1) for v in value) + "\n" + end + "]"
    return json.dumps(value, allow_nan=False)


def dumps(data: Any) -> str:
    """JSON text with numeric arrays on one line; raises ValueError on NaN/inf."""
    return _encode(data, 0) + "\n"


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` as JSON to ``path`` atomically."""
    path = Path(path)
    atomic_write_text(path, dumps(data))
    return path


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's dict, refusing a key given twice (``json`` would keep the last one without a word)."""
    data: dict[str, Any] = {}
    for key, value in pairs:
        if key in data:
            raise CamcalError(f"key {key!r} given twice in one JSON object")
        data[key] = value
    return data


#: Integers past this do not convert to a float (OverflowError); every number camcal reads is used as one.
_FLOAT_MAX = int(sys.float_info.max)


class _NonFinite:
    """What a ``NaN`` / ``Infinity`` literal parses to, found by :func:`_check_tree` with its field path."""

    def __init__(self, name: str) -> None:
        self.name = name


def _field(path: str, key: Any) -> str:
    return f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}" if path else str(key)


def _check_tree(data: Any) -> None:
    """Refuse nesting past :data:`~camcal.base.limits.JSON_DEPTH` and non-finite numbers, naming the field."""
    cap = JSON_DEPTH.value
    stack = [(data, "", 0)]
    while stack:
        value, path, depth = stack.pop()
        if isinstance(value, (dict, list)):
            if depth >= cap:
                raise CamcalError(f"{path or 'the top level'}: nested deeper than {cap} levels, the cap "
                                  f"({JSON_DEPTH.how_to_raise()})")
            items = value.items() if isinstance(value, dict) else enumerate(value)
            stack.extend((item, _field(path, key), depth + 1) for key, item in items)
        elif isinstance(value, _NonFinite):
            raise CamcalError(f"{path or 'the top level'}: non-finite number {value.name} in JSON")
        elif isinstance(value, float) and not math.isfinite(value):
            raise CamcalError(f"{path or 'the top level'}: number out of range (read as {value}) in JSON")
        elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > _FLOAT_MAX:
            raise CamcalError(f"{path or 'the top level'}: integer of {len(str(abs(value)))} digits, out of the "
                              "float range, in JSON")


def parse_json(text: str) -> Any:
    """Parse JSON text within the caps of :mod:`camcal.base.limits`; one-line :class:`CamcalError` otherwise.

    Refused: malformed JSON, a key given twice in one object, nesting
    deeper than ``JSON_DEPTH``, ``NaN`` / ``Infinity`` literals and numbers
    out of the float range (the message names the field, e.g.
    ``cameras[0].K[0][0]``).
    """
    try:
        data = json.loads(text, parse_constant=_NonFinite, object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as error:
        raise CamcalError(f"not valid JSON ({error.msg} at line {error.lineno}, column {error.colno})") from None
    except RecursionError:
        raise CamcalError(f"not readable JSON: nested deeper than {JSON_DEPTH.value} levels, the cap "
                          f"({JSON_DEPTH.how_to_raise()})") from None
    except ValueError as error:  # e.g. an integer past Python's 4300-digit conversion limit
        raise CamcalError(f"not valid JSON ({str(error).splitlines()[0]})") from None
    _check_tree(data)
    return data


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """Parse a JSON file, raising one-line :class:`CamcalError` on any problem.

    The file's size is checked against :data:`~camcal.base.limits.JSON_BYTES`
    before it is read, then :func:`parse_json`.

    Parameters
    ----------
    path : path
    what : str
        What the file is, for messages (``"rig file"``, ``"lines file"``).
    """
    path = Path(path)
    check_file_size(path, JSON_BYTES, what)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CamcalError(f"{what} not found: {path}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise CamcalError(f"cannot read {what} {path}: {error}") from None
    try:
        return parse_json(text)
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None
