"""Nuke script text: node blocks, knob values, constant or keyed per frame (the syntax :mod:`camcal.io.nuke` writes and reads).

A knob of ``n`` values is written constant as ``{v1 ... vn}`` (a scalar as
``v``) or animated with one key per frame as ``{{curve x<f> v x<f'> v'
...} ...}``, one curve per value (a scalar as ``{{curve ...}}``); in a
curve a value without its own ``x<frame>`` is the next frame's, as Nuke
writes runs of consecutive keys.

References
----------
Foundry, Nuke Python developers guide, "Animation curves"; the ``.nk``
file's knob syntax as Nuke writes it.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError

__all__ = ["animated_knob", "blocks", "keyed_knob", "knob_text", "number", "parse_number", "value_at"]


def number(value: float) -> str:
    """A float written so that it reads back bit for bit (``repr``)."""
    return repr(float(value))


def animated_knob(values: ArrayLike, frames: Sequence[int] | None) -> str:
    """A knob's text: constant (``frames`` None, ``values`` one row or a scalar) or one key per frame.

    Parameters
    ----------
    values : array_like, shape (n,), () or (len(frames), n), (len(frames),)
        The knob's values, per frame when ``frames`` is given.
    frames : sequence of int or None

    Returns
    -------
    str
        ``v``, ``{v1 ... vn}``, ``{{curve x<f> v ...}}`` or ``{{curve ...} {curve ...} ...}``.
    """
    array = np.asarray(values, dtype=np.float64)
    if frames is None:
        return number(array) if array.ndim == 0 else "{" + " ".join(number(v) for v in array) + "}"
    array = array.reshape(len(frames), -1)
    curves = ["{curve " + " ".join(f"x{frame} {number(array[i, axis])}" for i, frame in enumerate(frames)) + "}"
              for axis in range(array.shape[1])]
    return "{" + " ".join(curves) + "}"


def keyed_knob(text: str | None, n: int, where: str,
               default: ArrayLike | None = None) -> NDArray[np.float64] | dict[int, NDArray[np.float64]]:
    """Read an ``n``-value knob: its constant values, or frame -> values for a keyed one.

    A value that is constant inside an animated knob (``{{curve ...} 0.5}``)
    holds on every keyed frame. ``default`` stands in for an absent knob.

    Raises
    ------
    CamcalError
        Not ``n`` values or curves, a key without a frame, a value that is not a finite number.
    """
    if text is None:
        if default is None:
            raise CamcalError(f"{where}: missing")
        return np.broadcast_to(np.asarray(default, dtype=np.float64), (n,)).copy()
    if "curve" not in text:
        values = text.strip("{}").split()
        if len(values) != n:
            raise CamcalError(f"{where} must hold {n} number{'s' if n > 1 else ''}")
        return np.array([parse_number(v, where) for v in values])
    inner = text[1:-1].strip() if text.startswith("{") and text.endswith("}") and not text.startswith("{curve") \
        else text
    parts = re.findall(r"\{curve([^{}]*)\}|(\S+)", inner)
    if len(parts) != n:
        raise CamcalError(f"{where}: expected {n} value{'s' if n > 1 else ''} or curve{'s' if n > 1 else ''}")
    keyed: dict[int, dict[int, float]] = {}
    constants: dict[int, float] = {}
    for axis, (curve, constant) in enumerate(parts):
        if constant:
            constants[axis] = parse_number(constant, where)
            continue
        frame = None
        for token in curve.split():
            if token.startswith("x"):
                frame = int(parse_number(token[1:], where))
                continue
            if not re.match(r"[-+.\d]", token):  # an interpolation flag (K, L, C, R, ...)
                continue
            if frame is None:
                raise CamcalError(f"{where}: a key without a frame")
            keyed.setdefault(frame, {})[axis] = parse_number(token, where)
            frame += 1
    if not keyed:
        raise CamcalError(f"{where}: an animated knob with no key")
    out = {}
    for frame, values in keyed.items():
        row = {**constants, **values}
        if len(row) != n:
            raise CamcalError(f"{where}: frame {frame} is not keyed on every value")
        out[frame] = np.array([row[axis] for axis in range(n)])
    return out


def value_at(knob: NDArray[np.float64] | dict[int, NDArray[np.float64]], frame: int | None,
             where: str) -> NDArray[np.float64]:
    """A knob read by :func:`keyed_knob` at ``frame`` (a constant knob: at every frame)."""
    if not isinstance(knob, dict):
        return knob
    if frame not in knob:
        raise CamcalError(f"{where} has no key at frame {frame}")
    return knob[frame]


def knob_text(body: str, name: str) -> str | None:
    """The text of knob ``name`` in a node's body, or None."""
    match = re.search(rf"^\s*{name} (.+)$", body, flags=re.M)
    return None if match is None else match.group(1).strip()


def parse_number(text: str, where: str) -> float:
    """A finite float, or one line naming ``where``."""
    try:
        value = float(text)
    except ValueError:
        raise CamcalError(f"{where}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise CamcalError(f"{where} is not finite")
    return value


def blocks(text: str, classes: str) -> list[tuple[str, str]]:
    """``(class, body)`` of the nodes whose class matches ``classes`` (a regular expression)."""
    bodies = []
    for match in re.finditer(rf"^({classes}) \{{", text, flags=re.M):
        depth, position = 1, match.end()
        while depth and position < len(text):
            depth += {"{": 1, "}": -1}.get(text[position], 0)
            position += 1
        if depth:
            raise CamcalError(f"unbalanced braces in a {match.group(1)} node")
        bodies.append((match.group(1), text[match.end():position - 1]))
    return bodies
