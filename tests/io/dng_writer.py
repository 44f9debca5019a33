"""A minimal uncompressed CFA DNG writer for tests (a TIFF with the DNG tags LibRaw needs).

Tags (Adobe DNG 1.4 specification): NewSubFileType, ImageWidth/Length,
BitsPerSample 16, Compression 1, PhotometricInterpretation 32803 (CFA),
Make, Model, StripOffsets, SamplesPerPixel 1, RowsPerStrip, StripByteCounts,
PlanarConfiguration 1, CFARepeatPatternDim 2x2, CFAPattern (0 R, 1 G, 2 B),
DNGVersion 1.4, UniqueCameraModel, BlackLevelRepeatDim 2x2, BlackLevel
(one per CFA position), WhiteLevel, ColorMatrix1 (identity), AsShotNeutral,
CalibrationIlluminant1 (D65).
"""

import struct

import numpy as np

_TYPES = {"BYTE": (1, "B"), "ASCII": (2, "s"), "SHORT": (3, "H"), "LONG": (4, "I"), "RATIONAL": (5, "II"),
          "SRATIONAL": (10, "ii")}


def write_cfa_dng(path, photosites, pattern="RGGB", black=(0, 0, 0, 0), white=65535, make="camcal",
                  model="Test DNG"):
    """Write ``photosites`` (H, W) uint16 as a CFA DNG with a 2x2 ``pattern`` and per-position black levels."""
    data = np.ascontiguousarray(photosites, dtype="<u2")
    height, width = data.shape
    cfa = [{"R": 0, "G": 1, "B": 2}[c] for c in pattern]
    entries = [
        (254, "LONG", [0]), (256, "LONG", [width]), (257, "LONG", [height]), (258, "SHORT", [16]),
        (259, "SHORT", [1]), (262, "SHORT", [32803]), (271, "ASCII", make), (272, "ASCII", model),
        (273, "LONG", [0]), (277, "SHORT", [1]), (278, "LONG", [height]), (279, "LONG", [data.nbytes]),
        (284, "SHORT", [1]), (33421, "SHORT", [2, 2]), (33422, "BYTE", cfa), (50706, "BYTE", [1, 4, 0, 0]),
        (50708, "ASCII", f"{make} {model}"), (50713, "SHORT", [2, 2]), (50714, "LONG", list(black)),
        (50717, "LONG", [white]),
        (50721, "SRATIONAL", [1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1]),
        (50728, "RATIONAL", [1, 1, 1, 1, 1, 1]), (50778, "SHORT", [21]),
    ]
    n = len(entries)
    ifd_offset = 8
    extra_offset = ifd_offset + 2 + 12 * n + 4
    extra = b""
    packed = []
    for tag, kind, values in entries:
        code, fmt = _TYPES[kind]
        if kind == "ASCII":
            payload = values.encode("ascii") + b"\0"
            count = len(payload)
        else:
            payload = struct.pack("<" + fmt[0] * len(values), *values)
            count = len(values) // (2 if kind in ("RATIONAL", "SRATIONAL") else 1)
        packed.append([tag, code, count, payload])
    for item in packed:
        payload = item[3]
        if len(payload) <= 4:
            item[3] = payload.ljust(4, b"\0")
        else:
            offset = extra_offset + len(extra)
            extra += payload + (b"\0" if len(payload) % 2 else b"")
            item[3] = struct.pack("<I", offset)
    strip_offset = extra_offset + len(extra)
    for item in packed:
        if item[0] == 273:
            item[3] = struct.pack("<I", strip_offset)
    out = b"II" + struct.pack("<HI", 42, ifd_offset) + struct.pack("<H", n)
    for tag, code, count, value in packed:
        out += struct.pack("<HHI", tag, code, count) + value
    out += struct.pack("<I", 0) + extra + data.tobytes()
    with open(path, "wb") as handle:
        handle.write(out)
