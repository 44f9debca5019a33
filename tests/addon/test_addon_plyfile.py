"""Point clouds (PLY) and the blank lens frame (PNG), without bpy."""

import struct
import zlib

import pytest

from addon_helpers import addon  # noqa: F401  (fixtures)


def test_ascii_ply_with_colours(addon, tmp_path):
    path = tmp_path / "p.ply"
    path.write_text(
        "ply\nformat ascii 1.0\ncomment made by a test\nelement vertex 2\nproperty float x\n"
        "property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
        "property uchar blue\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
        "1 2 3 255 0 51\n-1.5 0.25 4e-3 0 255 0\n"
    )
    points, colours = addon.plyfile.read_ply_points(path)
    assert points == [(1.0, 2.0, 3.0), (-1.5, 0.25, 0.004)]
    assert colours == [(1.0, 0.0, 0.2), (0.0, 1.0, 0.0)]


def test_binary_ply_without_colours(addon, tmp_path):
    pts = [(0.1, 0.2, 0.3), (1e3, -2e3, 3.5)]
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nend_header\n"
    body = b"".join(struct.pack("<dddf", *p, 0.0) for p in pts)
    path = tmp_path / "b.ply"
    path.write_bytes(header + body)
    points, colours = addon.plyfile.read_ply_points(path)
    assert points == pts and colours is None


@pytest.mark.parametrize(
    "content, message",
    [
        (b"not a ply", "not a PLY file"),
        (b"ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n", "unsupported PLY format"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "no 'z'"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n", "truncated"),
    ],
)
def test_bad_ply(addon, tmp_path, content, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(addon.plyfile.PlyError, match=message):
        addon.plyfile.read_ply_points(path)


def test_grid_png_is_valid(addon, tmp_path):
    path = addon.pngfile.write_grid_png(tmp_path / "sub" / "g.png", 130, 70, step=64)
    data = path.read_bytes() if hasattr(path, "read_bytes") else open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (130, 70)
    idat = data.index(b"IDAT")
    length = struct.unpack(">I", data[idat - 4:idat])[0]
    raw = zlib.decompress(data[idat + 4: idat + 4 + length])
    assert len(raw) == 70 * (130 + 1)
    row1 = raw[131:262]
    assert row1[0] == 0 and row1[1] == 160 and row1[2] == 96 and row1[65] == 160
