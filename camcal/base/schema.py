"""A small JSON Schema validator for the keywords camcal's file schemas use.

camcal publishes the JSON Schema of its rig file (``docs/rig.schema.json``,
built by :mod:`camcal.model.rig_schema`) and checks files against it
(``camcal rig show --validate``) without depending on a JSON Schema package.
This module implements the part of JSON Schema 2020-12 those schemas use and
refuses every other keyword, so a schema never passes for a keyword it ignores.

Supported: ``type`` (one name or a list), ``properties``, ``required``,
``additionalProperties`` (a boolean or a schema), ``items``, ``prefixItems``,
``minItems``, ``maxItems``, ``const``, ``enum``, ``minimum``,
``exclusiveMinimum``, ``minLength``, ``oneOf``, and ``$ref`` to ``#/$defs/NAME``.
Annotations (``$schema``, ``$id``, ``$defs``, ``$comment``, ``title``,
``description``, ``default``, ``examples``, ``deprecated``) are ignored, as the
specification says. As in JSON Schema, ``1`` and ``1.0`` are the same number,
``true`` is not a number, and ``integer`` is any number with no fractional part.

References
----------
JSON Schema: A Media Type for Describing JSON Documents, and JSON Schema
Validation, draft 2020-12 (json-schema.org).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from camcal.base.errors import CamcalError

__all__ = ["schema_errors"]

_ANNOTATIONS = frozenset(
    {"$schema", "$id", "$defs", "$comment", "title", "description", "default", "examples", "deprecated"}
)
_KEYWORDS = frozenset(
    {"type", "properties", "required", "additionalProperties", "items", "prefixItems", "minItems", "maxItems",
     "const", "enum", "minimum", "exclusiveMinimum", "minLength", "oneOf", "$ref"}
)


def schema_errors(instance: Any, schema: Mapping[str, Any]) -> list[str]:
    """Every way ``instance`` breaks ``schema``, each as ``"/json/pointer: what is wrong"``.

    Parameters
    ----------
    instance : object
        A parsed JSON document (dicts, lists, str, int, float, bool, None).
    schema : mapping
        A JSON Schema using the keywords this module supports; its ``$defs``
        are what ``$ref`` names.

    Returns
    -------
    list of str
        Empty when the instance conforms; otherwise one line per violation,
        located by a JSON pointer (RFC 6901; ``/`` is the document itself).

    Raises
    ------
    CamcalError
        The schema uses a keyword this validator does not implement, or a
        ``$ref`` it cannot resolve.

    Examples
    --------
    >>> schema = {"type": "object", "required": ["K"], "properties": {"K": {"type": "number", "minimum": 0}}}
    >>> schema_errors({"K": -1}, schema)
    ['/K: -1 is less than the minimum 0']
    >>> schema_errors({"K": 2}, schema)
    []
    """
    errors: list[str] = []
    _check(instance, schema, "", schema.get("$defs", {}), errors)
    return errors


def _check(value: Any, schema: Mapping[str, Any] | bool, path: str, defs: Mapping[str, Any], errors: list[str]) -> None:
    if schema is True:
        return
    if schema is False:
        errors.append(f"{path or '/'}: no value is allowed here")
        return
    unknown = sorted(set(schema) - _KEYWORDS - _ANNOTATIONS)
    if unknown:
        raise CamcalError(f"schema keyword(s) {', '.join(unknown)} at {path or '/'} are not supported by camcal's validator")
    where = path or "/"
    if "$ref" in schema:
        _check(value, _resolve(schema["$ref"], defs), path, defs, errors)
    if "type" in schema:
        names = [schema["type"]] if isinstance(schema["type"], str) else list(schema["type"])
        if not any(_is_type(value, name) for name in names):
            errors.append(f"{where}: expected {' or '.join(names)}, got {_describe(value)}")
            return
    if "const" in schema and not _equal(value, schema["const"]):
        errors.append(f"{where}: expected {_describe(schema['const'])}, got {_describe(value)}")
    if "enum" in schema and not any(_equal(value, option) for option in schema["enum"]):
        errors.append(f"{where}: {_describe(value)} is not one of {', '.join(map(_describe, schema['enum']))}")
    if _is_number(value):
        if "minimum" in schema and value < schema["minimum"]:
            errors.append(f"{where}: {value!r} is less than the minimum {schema['minimum']!r}")
        if "exclusiveMinimum" in schema and value <= schema["exclusiveMinimum"]:
            errors.append(f"{where}: {value!r} must be greater than {schema['exclusiveMinimum']!r}")
    if isinstance(value, str) and "minLength" in schema and len(value) < schema["minLength"]:
        errors.append(f"{where}: {value!r} is shorter than {schema['minLength']} character(s)")
    if isinstance(value, list):
        _check_array(value, schema, path, defs, errors)
    if isinstance(value, dict):
        _check_object(value, schema, path, defs, errors)
    if "oneOf" in schema:
        _check_one_of(value, schema["oneOf"], path, defs, errors)


def _check_array(value: list, schema: Mapping[str, Any], path: str, defs: Mapping[str, Any], errors: list[str]) -> None:
    where = path or "/"
    if "minItems" in schema and len(value) < schema["minItems"]:
        errors.append(f"{where}: expected at least {schema['minItems']} item(s), got {len(value)}")
    if "maxItems" in schema and len(value) > schema["maxItems"]:
        errors.append(f"{where}: expected at most {schema['maxItems']} item(s), got {len(value)}")
    prefix = schema.get("prefixItems", [])
    for index, (item, item_schema) in enumerate(zip(value, prefix)):
        _check(item, item_schema, f"{path}/{index}", defs, errors)
    if "items" in schema:
        for index in range(len(prefix), len(value)):
            _check(value[index], schema["items"], f"{path}/{index}", defs, errors)


def _check_object(value: dict, schema: Mapping[str, Any], path: str, defs: Mapping[str, Any], errors: list[str]) -> None:
    where = path or "/"
    for key in schema.get("required", []):
        if key not in value:
            errors.append(f"{where}: missing key {key!r}")
    properties = schema.get("properties", {})
    extra = schema.get("additionalProperties", True)
    for key, item in value.items():
        child = f"{path}/{_escape(key)}"
        if key in properties:
            _check(item, properties[key], child, defs, errors)
        elif extra is False:
            errors.append(f"{where}: unknown key {key!r}")
        else:
            _check(item, extra, child, defs, errors)


def _check_one_of(value: Any, options: list, path: str, defs: Mapping[str, Any], errors: list[str]) -> None:
    """Exactly one option must hold; when none does, the errors of the nearest one are given.

    The nearest has the fewest wrong types and constants (a lens file naming ``"model": "division"`` is
    judged by the division alternative), then the fewest errors; a tie says that none matches.
    """
    results = []
    for option in options:
        found: list[str] = []
        _check(value, option, path, defs, found)
        results.append(found)
    passing = sum(not found for found in results)
    if passing == 1:
        return
    where = path or "/"
    if passing > 1:
        errors.append(f"{where}: matches {passing} of the alternatives, expected exactly one")
        return
    scores = [(sum(_is_mismatch(error) for error in found), len(found)) for found in results]
    best = min(scores)
    if scores.count(best) == 1:
        errors.extend(results[scores.index(best)])
    else:
        errors.append(f"{where}: matches none of the {len(options)} alternatives")


def _is_mismatch(error: str) -> bool:
    """A wrong type or constant: the mark of an alternative meant for another kind of value."""
    message = error.split(": ", 1)[-1]
    return message.startswith("expected ") and not message.startswith(("expected at least", "expected at most"))


def _resolve(reference: str, defs: Mapping[str, Any]) -> Mapping[str, Any]:
    prefix = "#/$defs/"
    if not reference.startswith(prefix) or reference[len(prefix):] not in defs:
        raise CamcalError(f"schema $ref {reference!r} does not name an entry of $defs")
    return defs[reference[len(prefix):]]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_type(value: Any, name: str) -> bool:
    checks = {
        "object": lambda v: isinstance(v, dict),
        "array": lambda v: isinstance(v, list),
        "string": lambda v: isinstance(v, str),
        "number": lambda v: _is_number(v) and math.isfinite(v),
        "integer": lambda v: _is_number(v) and math.isfinite(v) and float(v).is_integer(),
        "boolean": lambda v: isinstance(v, bool),
        "null": lambda v: v is None,
    }
    if name not in checks:
        raise CamcalError(f"schema type {name!r} is not a JSON Schema type")
    return checks[name](value)


def _equal(a: Any, b: Any) -> bool:
    """JSON equality: numbers by value (``1 == 1.0``), booleans never numbers, containers item by item."""
    if _is_number(a) and _is_number(b):
        return a == b
    if type(a) is not type(b):
        return False
    if isinstance(a, list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return a == b


def _describe(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return f"an array of {len(value)}"
    return repr(value)[:60]


def _escape(key: str) -> str:
    """A key as a JSON pointer segment (RFC 6901: ``~`` -> ``~0``, ``/`` -> ``~1``)."""
    return str(key).replace("~", "~0").replace("/", "~1")
