"""Checked fields of JSON files: each helper returns the value or names the field path in its error.

``where`` is the field's path in the file (``"model.coefficients[2]"``); the
error is one line ``"<where>: expected ..., got ..."`` (:class:`CamcalError`).
"""

from __future__ import annotations

import math
from typing import Any

from camcal.base.errors import CamcalError

__all__ = ["boolean_field", "integer_field", "keys_field", "matrix_field", "number_field", "string_field",
           "vector_field"]


def keys_field(value: Any, where: str, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict:
    if not isinstance(value, dict):
        raise CamcalError(f"{where}: expected an object, got {type(value).__name__}")
    for key in required:
        if key not in value:
            raise CamcalError(f"{where}: missing key {key!r}")
    allowed = set(required) | set(optional)
    for key in value:
        if key not in allowed:
            raise CamcalError(f"{where}: unknown key {key!r} (allowed: {', '.join(sorted(allowed))})")
    return value


def number_field(value: Any, where: str, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CamcalError(f"{where}: expected a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise CamcalError(f"{where}: must be >= {minimum}, got {value!r}")
    return float(value)


def integer_field(value: Any, where: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise CamcalError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def string_field(value: Any, where: str, choices: tuple[str, ...] | None = None, nullable: bool = False) -> Any:
    if value is None and nullable:
        return None
    if not isinstance(value, str) or (choices is not None and value not in choices):
        allowed = f" (one of: {', '.join(choices)})" if choices else ""
        raise CamcalError(f"{where}: expected a string{allowed}, got {value!r}")
    return value


def boolean_field(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise CamcalError(f"{where}: expected true or false, got {value!r}")
    return value


def vector_field(value: Any, where: str, n: int | None = None) -> list[float]:
    if not isinstance(value, list) or (n is not None and len(value) != n) or not value:
        size = f"{n} numbers" if n is not None else "a non-empty list of numbers"
        raise CamcalError(f"{where}: expected {size}, got {value!r:.80}")
    return [number_field(v, f"{where}[{i}]") for i, v in enumerate(value)]


def matrix_field(value: Any, where: str, rows: int | None = None, columns: int | None = None) -> list[list[float]]:
    if not isinstance(value, list) or not value or (rows is not None and len(value) != rows):
        size = f"{rows} rows" if rows is not None else "a non-empty list of rows"
        raise CamcalError(f"{where}: expected {size}, got {str(value)[:80]}")
    out = [vector_field(row, f"{where}[{i}]", columns) for i, row in enumerate(value)]
    width = len(out[0])
    for i, row in enumerate(out):
        if len(row) != width:
            raise CamcalError(f"{where}[{i}]: expected {width} numbers, got {len(row)}")
    return out
