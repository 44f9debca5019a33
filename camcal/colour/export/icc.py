"""ICC camera (input) profiles of colour fits, written byte by byte with ``struct``.

There is no maintained Python ICC writer, so this module writes the few
structures a camera profile needs, following the ICC specifications:
ICC.1:2010 (profile version 4.3) by default and ICC.1:2001-04 (version 2.4)
with ``version=2``. The profile is of class ``scnr`` (input device), data
colour space ``RGB ``, PCS ``XYZ `` (D50); its device values are the
camera's code values in [0, 1], and it maps them to PCS XYZ relative to the
media white (relative colorimetric, PCS white Y = 1).

- A ``matrix3x3`` fit gives a matrix/TRC profile (ICC.1:2010 §8.3.3 /
  ICC.1:2001-04 §6.3.1.2): ``rTRC gTRC bTRC`` are the linearisation (scaled
  by ``1 / s`` so they end at most at 1) and ``rXYZ gXYZ bXYZ`` the columns
  of ``s * chad @ M``. ``gamma-offset`` curves are a ``parametricCurveType``
  (function type 1, §10.16) in v4 and a 4096-entry ``curveType`` in v2.
- Other fits, version 4: ``D2B0`` and ``D2B1`` tags (one
  ``multiProcessElementsType``, §10.14, 32-bit float, shared by both:
  LittleCMS takes the float tag of the intent asked, ``D2B1`` for relative
  colorimetric, in preference to ``A2Bx``) holding the same baked transform as the OCIO
  export (:func:`camcal.colour.export.ocio_fit.bake_fit`): per-channel curves
  (linearisation and log2 shaper, sampled), the matrix to log-chromaticity
  coordinates, the float CLUT (the OCIO Lut3D's table), the inverse log2
  shaper as formula segments and the matrix (with ``chad``) to PCS XYZ. It
  is held within CIEDE2000 0.2 over the chart gamut and plausible surface
  colours, as the OCIO transform is. An ``A2B0`` is written as well, for
  readers without ``D2B0`` (its own, larger, error is reported).
- The ``A2B0`` of other fits. Version 4: ``lutAtoBType`` (``mAB``,
  §10.10) with A curves (linearisation and a log2 input shaper), a CLUT
  storing the shaped residual of the least-squares matrix, M curves (the
  inverse output shaper), the matrix and identity B curves. Version 2:
  ``lut16Type`` (``mft2``, ICC.1:2001-04 §6.5.8) with input tables, a CLUT
  of shaped PCS XYZ and output tables undoing the shaper.
- ``chad`` (§9.2.11, ``s15Fixed16ArrayType``): the Bradford adaptation from
  the fit's target white to D50 (ICC.1:2010 Annex E); ``wtpt`` (§9.2.36):
  D50, the PCS white the XYZ were adapted to (also in v2, so absolute and
  relative colorimetric agree: a camera has no media white). v2 has no
  ``chad`` tag; it is written too and v2 readers skip unknown tags.
- ``desc`` and ``cprt``: ``multiLocalizedUnicodeType`` (§10.13) in v4,
  ``textDescriptionType`` / ``textType`` (ICC.1:2001-04 §6.5.17, §6.5.18)
  in v2.
- Profile ID (v4, §7.2.18): MD5 of the profile with the flags, rendering
  intent and profile ID fields set to zero. In v2 those bytes are reserved
  (zero).

PCS XYZ in LUT-based tags is the 16-bit encoding of ICC.1:2010 §6.3.4.2
(``0x8000`` = 1.0): a table value ``v`` in [0, 1] means
``XYZ = v * 65535 / 32768``.

Every profile is checked before it is written (:func:`check_icc`: size
field, 4-byte alignment, tag table bounds, tag types, profile ID; then
:func:`camcal.io.icc.write_icc` writes it atomically): no truncated or
corrupt profile reaches the disk.

References
----------
- International Color Consortium (2010). ICC.1:2010 (Profile version
  4.3.0.0), Image technology colour management - Architecture, profile
  format, and data structure.
- International Color Consortium (2001). ICC.1:2001-04, File Format for
  Color Profiles (version 2.4.0).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.bake.transforms import LUT_SIZES, BakedTransform, LogShaper
from camcal.colour.chart.linearise import ChannelCurve
from camcal.colour.difference import DeltaEStats, delta_E
from camcal.colour.export.ocio_fit import bake_fit, chart_gamut_samples
from camcal.colour.fit.record import ColourFit

__all__ = [
    "D50_XYZ",
    "ICC_VERSIONS",
    "ICCProfile",
    "ICCInfo",
    "icc_profile_from_fit",
    "check_icc",
]

# ICC.1:2010 §7.2.16: the PCS illuminant, as encoded in s15Fixed16.
D50_XYZ = (0.9642, 1.0, 0.8249)
ICC_VERSIONS = {4: 0x04300000, 2: 0x02400000}
CURVE_ENTRIES = 4096
_XYZ_SCALE = 32768.0 / 65535.0  # PCS XYZ value -> [0, 1] table value
_KNOWN_TYPES = {b"XYZ ", b"sf32", b"mluc", b"desc", b"text", b"curv", b"para", b"mAB ", b"mft2", b"mpet"}
#: Samples of the D2B0 input curves (code value -> shaped linear value) over [0, 1].
FLOAT_CURVE_ENTRIES = 4096
#: The D2B0 output curves' linear segment holds for shaped values down to -_TOE_REACH.
_TOE_REACH = 16.0


# --------------------------------------------------------------------------
# Encodings and tag types.


def _s15f16(values: Any) -> bytes:
    """s15Fixed16Number (§4.6): signed, 16 fractional bits."""
    v = np.round(np.asarray(values, dtype=np.float64).ravel() * 65536.0)
    if np.any(np.abs(v) >= 2**31):
        raise CamcalError("a value does not fit the ICC s15Fixed16 range (-32768 .. 32767.99998)")
    return struct.pack(f">{v.size}i", *v.astype(np.int64))


def _u16(values: Any) -> bytes:
    v = np.round(np.clip(np.asarray(values, dtype=np.float64).ravel(), 0.0, 1.0) * 65535.0).astype(np.int64)
    return struct.pack(f">{v.size}H", *v)


def _pad4(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def _xyz_type(XYZ: Any) -> bytes:
    """XYZType (§10.28)."""
    return b"XYZ " + b"\0" * 4 + _s15f16(XYZ)


def _sf32_type(values: Any) -> bytes:
    """s15Fixed16ArrayType (§10.18)."""
    return b"sf32" + b"\0" * 4 + _s15f16(values)


def _mluc_type(text: str) -> bytes:
    """multiLocalizedUnicodeType (§10.13): one en-US record, UTF-16BE."""
    body = text.encode("utf-16-be")
    return b"mluc" + b"\0" * 4 + struct.pack(">II2s2sII", 1, 12, b"en", b"US", len(body), 28) + body


def _desc_type(text: str) -> bytes:
    """textDescriptionType (ICC.1:2001-04 §6.5.17): ASCII, empty Unicode and ScriptCode parts."""
    ascii_text = text.encode("ascii", "replace") + b"\0"
    return (b"desc" + b"\0" * 4 + struct.pack(">I", len(ascii_text)) + ascii_text
            + struct.pack(">II", 0, 0) + struct.pack(">HB", 0, 0) + b"\0" * 67)


def _text_type(text: str) -> bytes:
    """textType (ICC.1:2001-04 §6.5.18): NUL-terminated ASCII."""
    return b"text" + b"\0" * 4 + text.encode("ascii", "replace") + b"\0"


def _curv_type(table: Any | None) -> bytes:
    """curveType (§10.5): ``None`` is the identity (count 0); else samples in [0, 1]."""
    if table is None:
        return b"curv" + b"\0" * 4 + struct.pack(">I", 0)
    table = np.asarray(table, dtype=np.float64)
    return b"curv" + b"\0" * 4 + struct.pack(">I", table.size) + _u16(table)


def _para_type(gamma: float, a: float, b: float) -> bytes:
    """parametricCurveType (§10.16) function type 1: ``Y = (aX + b)^g`` for ``X >= -b/a``, else 0."""
    return b"para" + b"\0" * 4 + struct.pack(">HH", 1, 0) + _s15f16([gamma, a, b])


def _clut_values(values: np.ndarray) -> bytes:
    """A CLUT's 16-bit values (``(n, n, n, 3)``, first input channel slowest)."""
    return _u16(values.reshape(-1))


def _mab_type(a_curves: Sequence[np.ndarray], clut: np.ndarray, m_curves: Sequence[np.ndarray],
              matrix: np.ndarray, offset: np.ndarray) -> bytes:
    """lutAtoBType (§10.10): A curves, CLUT, M curves, matrix, identity B curves."""
    n = clut.shape[0]
    header_size = 32
    b_curves = b"".join(_pad4(_curv_type(None)) for _ in range(3))
    mat = _pad4(_s15f16(np.concatenate([np.asarray(matrix).ravel(), np.asarray(offset).ravel()])))
    m_bytes = b"".join(_pad4(_curv_type(c)) for c in m_curves)
    grid = bytes([n, n, n] + [0] * 13) + bytes([2, 0, 0, 0])
    clut_bytes = _pad4(grid + _clut_values(clut))
    a_bytes = b"".join(_pad4(_curv_type(c)) for c in a_curves)
    parts: list[tuple[str, bytes]] = [("B", b_curves), ("matrix", mat), ("M", m_bytes), ("CLUT", clut_bytes), ("A", a_bytes)]
    offsets: dict[str, int] = {}
    position = header_size
    for name, data in parts:
        offsets[name] = position
        position += len(data)
    header = (b"mAB " + b"\0" * 4 + struct.pack(">BBH", 3, 3, 0)
              + struct.pack(">5I", offsets["B"], offsets["matrix"], offsets["M"], offsets["CLUT"], offsets["A"]))
    return header + b"".join(data for _, data in parts)


def _mft2_type(in_tables: Sequence[np.ndarray], clut: np.ndarray, out_tables: Sequence[np.ndarray]) -> bytes:
    """lut16Type (ICC.1:2001-04 §6.5.8): identity matrix, input tables, CLUT, output tables."""
    n = clut.shape[0]
    n_in, n_out = len(in_tables[0]), len(out_tables[0])
    return (b"mft2" + b"\0" * 4 + struct.pack(">BBBB", 3, 3, n, 0) + _s15f16(np.eye(3))
            + struct.pack(">HH", n_in, n_out) + b"".join(_u16(t) for t in in_tables)
            + _clut_values(clut) + b"".join(_u16(t) for t in out_tables))


def _f32(values: Any) -> bytes:
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).ravel(), dtype=">f4").tobytes()


def _parf(function: int, params: Sequence[float]) -> bytes:
    """formulaCurveSegment (§11.2.10): type 0 ``(aX + b)^g + c`` or type 2 ``a b^(cX + d) + e``."""
    return b"parf" + b"\0" * 4 + struct.pack(">HH", function, 0) + _f32(params)


def _samf(values: Any) -> bytes:
    """sampledCurveSegment (§11.2.11): values after the segment's first breakpoint, evenly spaced."""
    values = np.asarray(values, dtype=np.float64)
    return b"samf" + b"\0" * 4 + struct.pack(">I", values.size) + _f32(values)


def _curf(breakpoints: Sequence[float], segments: Sequence[bytes]) -> bytes:
    """segmentedCurve (§11.2.9)."""
    return (b"curf" + b"\0" * 4 + struct.pack(">HH", len(segments), 0) + _f32(breakpoints)
            + b"".join(_pad4(seg) for seg in segments))


def _element_with_table(header: bytes, parts: Sequence[bytes]) -> bytes:
    """An element whose parts follow a position table (offset, size) relative to the element's start."""
    position = len(header) + 8 * len(parts)
    table, body = b"", b""
    for part in parts:
        part = _pad4(part)
        table += struct.pack(">II", position, len(part))
        body += part
        position += len(part)
    return header + table + body


def _cvst(curves: Sequence[bytes]) -> bytes:
    """curveSetElement (§11.2.3)."""
    return _element_with_table(b"cvst" + b"\0" * 4 + struct.pack(">HH", len(curves), len(curves)), curves)


def _matf(matrix: Any, offset: Any) -> bytes:
    """matrixElement (§11.2.5): 3 in, 3 out; the matrix row by row (output row), then the offsets."""
    return b"matf" + b"\0" * 4 + struct.pack(">HH", 3, 3) + _f32(matrix) + _f32(offset)


def _clut_element(table: np.ndarray) -> bytes:
    """CLutElement (§11.2.4): float32 values, the first input channel slowest."""
    n = table.shape[0]
    return b"clut" + b"\0" * 4 + struct.pack(">HH", 3, 3) + bytes([n, n, n] + [0] * 13) + _f32(table)


def _mpet(elements: Sequence[bytes]) -> bytes:
    """multiProcessElementsType (§10.14), 3 in and 3 out."""
    return _element_with_table(b"mpet" + b"\0" * 4 + struct.pack(">HHI", 3, 3, len(elements)), elements)


def _input_curve(values: np.ndarray) -> bytes:
    """Code value in [0, 1] -> shaped value: constant below 0, ``values`` sampled on (0, 1], constant above."""
    return _curf([0.0, 1.0], [_parf(0, [1.0, 0.0, 0.0, values[0]]), _samf(values[1:]),
                              _parf(0, [1.0, 0.0, 0.0, values[-1]])])


def _inverse_shaper_curve(shaper: LogShaper) -> bytes:
    """``LogShaper.decode`` exactly: the linear toe (type 0) below the break, ``2**(span t + low)`` (type 2) above."""
    span = shaper.high_stop - shaper.low_stop
    b = 2.0**shaper.break_stop
    s_b = (shaper.break_stop - shaper.low_stop) / span
    slope = 1.0 / (span * b * np.log(2.0))
    # toe x = b + (t - s_b) / slope, written (t / slope + q)^1 + (c) with q >= 0 for t >= -_TOE_REACH
    q = _TOE_REACH / slope
    toe = _parf(0, [1.0, 1.0 / slope, q, b - s_b / slope - q])
    return _curf([s_b], [toe, _parf(2, [1.0, 2.0, span, shaper.low_stop, 0.0])])


def _d2b0(fit: ColourFit, baked: BakedTransform, chad: np.ndarray) -> bytes:
    """The D2B0 of a baked fit: curves, log-chromaticity matrix, float CLUT, inverse shaper, matrix to PCS."""
    coordinates, shaper = baked.coordinates, baked.shaper
    codes = np.linspace(0.0, 1.0, FLOAT_CURVE_ENTRIES)
    shaped = coordinates.shaper.encode(fit.linearise(np.repeat(codes[:, None], 3, axis=1)))
    curves_in = _cvst([_input_curve(shaped[:, i]) for i in range(3)])
    curves_out = _cvst([_inverse_shaper_curve(shaper)] * 3)
    return _mpet([curves_in, _matf(coordinates.matrix, coordinates.offset), _clut_element(baked.table),
                  curves_out, _matf(chad @ baked.matrix, np.zeros(3))])


def _assemble(version: int, tags: list[tuple[bytes, bytes]], created: _dt.datetime) -> bytes:
    """Header (§7.2), tag table (§7.3) and 4-byte aligned tag data; profile ID in v4."""
    table_size = 4 + 12 * len(tags)
    position = 128 + table_size
    entries, blobs = [], []
    shared: dict[int, int] = {}  # the same data object under two signatures is stored once (§7.3.1)
    for signature, data in tags:
        if id(data) in shared:
            entries.append(struct.pack(">4sII", signature, shared[id(data)], len(data)))
            continue
        shared[id(data)] = position
        entries.append(struct.pack(">4sII", signature, position, len(data)))
        padded = _pad4(data)
        blobs.append(padded)
        position += len(padded)
    size = position
    header = struct.pack(
        ">I4sI4s4s4s6H4s4sI4s4sQI12s4s16s28s",
        size, b"\0\0\0\0", ICC_VERSIONS[version], b"scnr", b"RGB ", b"XYZ ",
        created.year, created.month, created.day, created.hour, created.minute, created.second,
        b"acsp", b"\0\0\0\0", 0, b"\0\0\0\0", b"\0\0\0\0", 0, 0, _s15f16(D50_XYZ), b"ccal", b"\0" * 16, b"\0" * 28,
    )
    profile = bytearray(header + struct.pack(">I", len(tags)) + b"".join(entries) + b"".join(blobs))
    if version == 4:
        profile[84:100] = _profile_id(bytes(profile))
    return bytes(profile)


def _profile_id(profile: bytes) -> bytes:
    """MD5 with flags (44-47), rendering intent (64-67) and profile ID (84-99) zeroed (§7.2.18)."""
    data = bytearray(profile)
    data[44:48] = b"\0" * 4
    data[64:68] = b"\0" * 4
    data[84:100] = b"\0" * 16
    return hashlib.md5(bytes(data)).digest()


# --------------------------------------------------------------------------
# Checking bytes.


@dataclass(frozen=True)
class ICCInfo:
    """What :func:`check_icc` read back from a profile."""

    size: int
    version: int
    device_class: str
    colour_space: str
    pcs: str
    tags: dict

    @property
    def version_major(self) -> int:
        return self.version >> 24


def check_icc(data: bytes) -> ICCInfo:
    """Check a profile's structure and parse its header and tag table.

    Checks: at least a header and tag count; the size field equals the
    length and is a multiple of 4; ``acsp`` signature (§7.2.9); every tag's
    offset 4-byte aligned, after the tag table and inside the profile
    (§7.3); known tag type signatures; the v4 profile ID (§7.2.18).

    Returns
    -------
    ICCInfo
        ``tags``: ``{signature: (offset, size, type signature)}``.

    Raises
    ------
    CamcalError
        Naming the first problem.
    """
    if len(data) < 132:
        raise CamcalError(f"ICC profile too short: {len(data)} bytes")
    size, version = struct.unpack(">I4xI", data[:12])
    if size != len(data) or size % 4:
        raise CamcalError(f"ICC size field {size} does not match the {len(data)} bytes (or is not 4-aligned)")
    if data[36:40] != b"acsp":
        raise CamcalError("ICC profile lacks the 'acsp' signature")
    (count,) = struct.unpack(">I", data[128:132])
    table_end = 132 + 12 * count
    if table_end > size:
        raise CamcalError(f"ICC tag table of {count} tags runs past the end")
    tags = {}
    for i in range(count):
        signature, offset, length = struct.unpack(">4sII", data[132 + 12 * i: 144 + 12 * i])
        if offset % 4 or offset < table_end or offset + length > size or length < 8:
            raise CamcalError(f"ICC tag {signature!r}: offset {offset} / size {length} out of bounds or unaligned")
        kind = data[offset:offset + 4]
        if kind not in _KNOWN_TYPES:
            raise CamcalError(f"ICC tag {signature!r} has an unknown type {kind!r}")
        tags[signature.decode("latin-1")] = (offset, length, kind.decode("latin-1"))
    if version >> 24 >= 4 and data[84:100] != _profile_id(data):
        raise CamcalError("ICC profile ID (MD5) does not match the profile")
    return ICCInfo(size, version, data[12:16].decode("latin-1"), data[16:20].decode("latin-1"),
                   data[20:24].decode("latin-1"), tags)


# --------------------------------------------------------------------------
# From a fit.


def _bradford_to_D50(white_XYZ: Any) -> np.ndarray:
    colour = require("colour")

    return colour.adaptation.matrix_chromatic_adaptation_VonKries(
        np.asarray(white_XYZ, dtype=np.float64), np.asarray(D50_XYZ), transform="Bradford")


def _trc(curve: ChannelCurve, scale: float, version: int) -> bytes:
    """One channel's TRC: ``L(V) / scale``."""
    if curve.kind == "none" and scale == 1.0:
        return _curv_type(None)
    if curve.kind == "gamma-offset" and version == 4:
        g, o, k = curve.params["gamma"], curve.params["offset"], curve.params["gain"]
        a = (k / scale) ** (1.0 / g)
        return _para_type(g, a, -o * a)
    if curve.kind == "lut1d":
        return _curv_type(np.asarray(curve.params["samples"]) / scale)
    return _curv_type(curve.apply(np.linspace(0.0, 1.0, CURVE_ENTRIES)) / scale)


@dataclass(frozen=True, eq=False)
class ICCProfile:
    """A camera profile's bytes and how it was built.

    ``kind``: ``"matrix-trc"`` or ``"lut"``; ``clut_size`` the A2B0 CLUT
    edge; ``bake_error``: CIEDE2000 between the A2B0 pipeline (evaluated in
    numpy from the quantised tables, trilinear) and the fit over the chart
    gamut, in PCS XYZ D50 (``None`` for matrix/TRC); ``float_clut_size`` and
    ``float_bake_error``: the D2B0's CLUT edge and its CIEDE2000 over the
    chart gamut and plausible surface colours (the OCIO bake's, same table;
    ``None`` without a D2B0: matrix/TRC and v2).
    """

    data: bytes
    version: int
    kind: str
    clut_size: int | None = None
    bake_error: DeltaEStats | None = None
    float_clut_size: int | None = None
    float_bake_error: DeltaEStats | None = None

    def summary(self) -> str:
        """How the model is stored, with its bake errors."""
        if self.kind == "matrix-trc":
            return "matrix/TRC"
        text = (f"A2B0 {self.clut_size}^3 CLUT, bake error CIEDE2000 max {self.bake_error.max:.3f} over the "
                "chart gamut")
        if self.float_clut_size is not None:
            text = (f"D2B0/D2B1 {self.float_clut_size}^3 float CLUT, bake error CIEDE2000 max "
                    f"{self.float_bake_error.max:.3f} over the chart gamut and plausible surfaces; " + text)
        return text


def _interp_curves(tables: Sequence[np.ndarray], x: np.ndarray) -> np.ndarray:
    grid = np.linspace(0.0, 1.0, len(tables[0]))
    return np.stack([np.interp(np.clip(x[:, i], 0, 1), grid, tables[i]) for i in range(3)], axis=-1)


def _quantised(values: np.ndarray) -> np.ndarray:
    return np.round(np.clip(values, 0.0, 1.0) * 65535.0) / 65535.0


class _LutBuilder:
    """Tables of an A2B0 for a fit: A curves, CLUT, output curves and (v4) matrix."""

    def __init__(self, fit: ColourFit, version: int, shaper: LogShaper) -> None:
        self.fit, self.version, self.shaper = fit, version, shaper
        self.chad = _bradford_to_D50(fit.target_white_XYZ)
        codes = np.linspace(0.0, 1.0, CURVE_ENTRIES)
        L = fit.linearise(np.repeat(codes[:, None], 3, axis=1))
        self.L_max = float(max(L.max(), 1e-6))
        self.e0, self.e1 = shaper.encode(min(float(L.min()), 0.0)), shaper.encode(self.L_max)
        self.a_curves = [_quantised((shaper.encode(L[:, i]) - self.e0) / (self.e1 - self.e0)) for i in range(3)]
        self.samples = chart_gamut_samples(fit)
        enc = self.pcs(self.samples)
        if version == 4:
            self.M = np.linalg.lstsq(self.samples, enc, rcond=None)[0].T
        else:
            self.M = np.eye(3)

    def pcs(self, RGB: np.ndarray) -> np.ndarray:
        """Linear RGB -> PCS XYZ (D50) table values."""
        return self.fit.apply(RGB) @ self.chad.T * _XYZ_SCALE

    def build(self, n: int) -> tuple[bytes, DeltaEStats]:
        shaper = self.shaper
        u = np.linspace(0.0, 1.0, n)
        grid = np.stack(np.meshgrid(u, u, u, indexing="ij"), axis=-1).reshape(-1, 3)
        x = shaper.decode(grid * (self.e1 - self.e0) + self.e0)
        g = self.pcs(x) @ np.linalg.inv(self.M).T
        if self.version == 4:
            g0, g1 = np.minimum(g.min(axis=0), 0.0), g.max(axis=0)
        else:
            g0, g1 = np.zeros(3), np.ones(3)
        f0, f1 = shaper.encode(g0), shaper.encode(g1)
        clut = _quantised((shaper.encode(g) - f0) / (f1 - f0)).reshape(n, n, n, 3)
        t = np.linspace(0.0, 1.0, CURVE_ENTRIES)
        out_curves = [_quantised((shaper.decode(t * (f1[i] - f0[i]) + f0[i]) - g0[i]) / (g1[i] - g0[i]))
                      for i in range(3)]
        matrix, offset = self.M * (g1 - g0)[None, :], self.M @ g0
        if self.version == 4:
            tag = _mab_type(self.a_curves, clut, out_curves, matrix, offset)
        else:
            tag = _mft2_type(self.a_curves, clut, out_curves)
        error = self._error(clut, out_curves, matrix, offset)
        return tag, error

    def _error(self, clut, out_curves, matrix, offset) -> DeltaEStats:
        from scipy.interpolate import RegularGridInterpolator

        n = clut.shape[0]
        axis = np.linspace(0.0, 1.0, n)
        # the fit's code values of the samples are not needed: A curves act on codes, so feed the
        # shaped linear values the A curves would give (the linearisation is evaluated exactly).
        u = (self.shaper.encode(self.samples) - self.e0) / (self.e1 - self.e0)
        c = RegularGridInterpolator((axis, axis, axis), clut)(np.clip(u, 0, 1))
        g = _interp_curves(out_curves, c)
        enc = g @ matrix.T + offset if self.version == 4 else g
        XYZ = np.clip(enc, 0.0, 1.0) / _XYZ_SCALE
        truth = self.fit.apply(self.samples) @ self.chad.T
        return DeltaEStats.from_values(delta_E(XYZ, truth, D50_XYZ))


def icc_profile_from_fit(
    fit: ColourFit,
    camera: str,
    *,
    version: int = 4,
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    copyright: str = "No copyright, use freely",
    created: _dt.datetime | None = None,
) -> ICCProfile:
    """Build (in memory, checked) the ICC input profile of a characterisation.

    Parameters
    ----------
    fit
        The characterisation (code values -> XYZ under its target white).
    camera
        Name for the description.
    version
        4 (ICC.1:2010, default) or 2 (ICC.1:2001-04).
    max_delta_E, lut_sizes
        For a LUT profile: v4 bakes the D2B0 as the OCIO export does
        (:func:`camcal.colour.export.ocio_fit.bake_fit`: the smallest size within
        ``max_delta_E`` CIEDE2000 over the chart gamut and plausible surface
        colours, else refused) and writes the A2B0 at the smallest size within
        ``max_delta_E`` over the chart gamut (the largest when none is); v2
        (A2B0 only) needs its A2B0 within ``max_delta_E`` over the chart
        gamut.
    copyright
        ``cprt`` text.
    created
        Header date (UTC now by default).

    Returns
    -------
    ICCProfile
    """
    if version not in ICC_VERSIONS:
        raise CamcalError(f"ICC version must be 4 or 2, got {version!r}")
    created = created or _dt.datetime.now(_dt.timezone.utc)
    chad = _bradford_to_D50(fit.target_white_XYZ)
    model = fit.model
    description = f"camcal {camera}: {model.label}, linearisation {fit.linearisation.label}"
    text = _mluc_type if version == 4 else _desc_type
    tags: list[tuple[bytes, bytes]] = [
        (b"desc", text(description)),
        (b"cprt", _mluc_type(copyright) if version == 4 else _text_type(copyright)),
        (b"wtpt", _xyz_type(D50_XYZ)),
        (b"chad", _sf32_type(chad)),
    ]
    if model.kind == "matrix3x3":
        L1 = fit.linearise(np.ones((1, 3)))[0]
        scale = float(max(L1.max(), 1e-6))
        M = scale * chad @ model.M
        for i, name in enumerate((b"r", b"g", b"b")):
            tags.append((name + b"XYZ", _xyz_type(M[:, i])))
        for i, name in enumerate((b"r", b"g", b"b")):
            tags.append((name + b"TRC", _trc(fit.linearisation.channels[i], scale, version)))
        data = _assemble(version, tags, created)
        check_icc(data)
        return ICCProfile(data, version, "matrix-trc")
    sizes = sorted(int(v) for v in lut_sizes)
    for n in sizes:
        if not 2 <= n <= 129:
            raise CamcalError(f"CLUT sizes must lie in 2..129, got {n}")
    builder = _LutBuilder(fit, version, LogShaper())
    if version == 4:
        baked = bake_fit(fit, max_delta_E=max_delta_E, lut_sizes=sizes)  # refuses as the OCIO export does
        for n in sizes:
            tag, error = builder.build(n)
            if error.max <= max_delta_E:
                break
        d2b = _d2b0(fit, baked, chad)
        tags += [(b"A2B0", tag), (b"D2B0", d2b), (b"D2B1", d2b)]
        data = _assemble(version, tags, created)
        check_icc(data)
        return ICCProfile(data, version, "lut", n, error, baked.lut_size, baked.bake_error)
    error = None
    for n in sizes:
        tag, error = builder.build(n)
        if error.max <= max_delta_E:
            data = _assemble(version, tags + [(b"A2B0", tag)], created)
            check_icc(data)
            return ICCProfile(data, version, "lut", n, error)
    raise CamcalError(
        f"a {n}^3 CLUT still leaves CIEDE2000 up to {error.max:.3f} over the chart gamut "
        f"(allowed {max_delta_E:g}); allow a larger bake error or refit with a smoother model"
    )
