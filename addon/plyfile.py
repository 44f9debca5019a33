"""Reading sparse point clouds from PLY files, in plain Python.

Supports ``format ascii 1.0`` and ``format binary_little_endian 1.0`` with a
``vertex`` element holding ``x y z`` and optionally ``red green blue``
(uchar 0-255, or float 0-1). Other elements are skipped when they come after
the vertices, or when they have no list properties.
"""

from __future__ import annotations

import os
import struct

__all__ = ["PlyError", "read_ply_points"]

_TYPES = {
    "char": "b", "int8": "b", "uchar": "B", "uint8": "B",
    "short": "h", "int16": "h", "ushort": "H", "uint16": "H",
    "int": "i", "int32": "i", "uint": "I", "uint32": "I",
    "float": "f", "float32": "f", "double": "d", "float64": "d",
}


class PlyError(Exception):
    """A PLY file the importer cannot read; the message says why."""


def read_ply_points(path):
    """Points and colours of a PLY file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    points : list of (x, y, z) floats
    colours : list of (r, g, b) floats in 0-1, or None when the file has none
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as error:
        raise PlyError(f"cannot read point cloud {path}: {error.strerror or error}") from None
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise PlyError(f"{path}: not a PLY file")
    newline = data.find(b"\n", end)
    body = data[newline + 1:] if newline >= 0 else b""
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt = None
    elements = []  # [name, count, [(name, type or ('list', count_t, item_t))]]
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else None
        elif words[0] == "element":
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[4], ("list", words[2], words[3])))
            else:
                elements[-1][2].append((words[2], words[1]))
    if fmt not in ("ascii", "binary_little_endian"):
        raise PlyError(f"{path}: unsupported PLY format {fmt!r} (ascii or binary_little_endian)")
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise PlyError(f"{path}: no vertex element")
    for name, count, props in elements:
        for prop, kind in props:
            if not isinstance(kind, tuple) and kind not in _TYPES:
                raise PlyError(f"{path}: unknown property type {kind!r} of {name}.{prop}")
    vertex = elements[names.index("vertex")]
    props = [p for p, _ in vertex[2]]
    for axis in ("x", "y", "z"):
        if axis not in props:
            raise PlyError(f"{path}: vertex has no {axis!r} property")
    rows = _read_ascii(body, elements, path) if fmt == "ascii" else _read_binary(body, elements, path)
    ix, iy, iz = props.index("x"), props.index("y"), props.index("z")
    points = [(float(r[ix]), float(r[iy]), float(r[iz])) for r in rows]
    colours = None
    if all(c in props for c in ("red", "green", "blue")):
        idx = [props.index(c) for c in ("red", "green", "blue")]
        kind = dict(vertex[2])["red"]
        scale = 255.0 if _TYPES.get(kind) in ("B", "b", "H", "h", "I", "i") else 1.0
        colours = [tuple(float(r[i]) / scale for i in idx) for r in rows]
    return points, colours


def _read_ascii(body, elements, path):
    lines = body.decode("ascii", "replace").splitlines()
    pos = 0
    for name, count, props in elements:
        if name == "vertex":
            rows = [line.split() for line in lines[pos:pos + count]]
            if len(rows) < count or any(len(r) < len(props) for r in rows):
                raise PlyError(f"{path}: truncated vertex data")
            return rows
        pos += count
    raise PlyError(f"{path}: no vertex element")  # unreachable: checked by the caller


def _read_binary(body, elements, path):
    offset = 0
    for name, count, props in elements:
        if any(isinstance(kind, tuple) for _, kind in props):
            if name == "vertex":
                raise PlyError(f"{path}: list properties in vertices are not supported")
            raise PlyError(f"{path}: element {name!r} with list properties before the vertices")
        fmt = "<" + "".join(_TYPES[kind] for _, kind in props)
        size = struct.calcsize(fmt)
        if name == "vertex":
            if len(body) < offset + size * count:
                raise PlyError(f"{path}: truncated vertex data")
            return [row for row in struct.iter_unpack(fmt, body[offset:offset + size * count])]
        offset += size * count
    raise PlyError(f"{path}: no vertex element")  # unreachable: checked by the caller
