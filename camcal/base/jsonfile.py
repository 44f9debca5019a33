"""JSON files as camcal writes and reads them.

Writing: 2-space indentation with arrays of numbers kept on one line (a
3x3 matrix reads as three rows), floats at ``repr`` precision so that files
round-trip exactly, NaN and infinity refused. Reading: one-line errors that
name the file (missing, unreadable, malformed JSON, NaN/Infinity literals).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Any

from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_write_text

__all__ = ["dumps", "read_json", "utc_timestamp", "write_json"]


def utc_timestamp() -> str:
    """The current UTC time as written in camcal files' provenance: ``YYYY-MM-DDTHH:MM:SSZ``."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


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


def _reject_constant(name: str) -> None:
    raise CamcalError(f"non-finite number {name} in JSON")


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """Parse a JSON file, raising one-line :class:`CamcalError` on any problem.

    Parameters
    ----------
    path : path
    what : str
        What the file is, for messages (``"rig file"``, ``"lines file"``).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CamcalError(f"{what} not found: {path}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise CamcalError(f"cannot read {what} {path}: {error}") from None
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as error:
        raise CamcalError(
            f"{path}: not valid JSON ({error.msg} at line {error.lineno}, column {error.colno})"
        ) from None
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None
