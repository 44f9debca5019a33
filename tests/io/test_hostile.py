"""Files made to hurt: forged image headers, deep JSON, absurd sizes and values; one line each, nothing written."""

import json
import struct
import zlib

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.frames import imread, imwrite, read_frame
from camcal.io.interchange import import_rig
from camcal.model.rig import Rig
from camcal.synthetic import example_camera


def png_declaring(width, height):
    """A PNG signature and a well-formed IHDR (valid CRC) declaring ``width`` x ``height``, then no pixels."""
    body = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + body + struct.pack(">I", zlib.crc32(body))
    end = struct.pack(">I", 0) + b"IEND" + struct.pack(">I", zlib.crc32(b"IEND"))
    return b"\x89PNG\r\n\x1a\n" + chunk + end


def jpeg_declaring(width, height):
    """SOI, a JFIF APP0, a baseline SOF0 declaring ``width`` x ``height`` (3 components), EOI."""
    app0 = b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, height, width, 3) + b"\x01\x11\x00\x02\x11\x00\x03\x11\x00"
    return b"\xff\xd8" + app0 + sof + b"\xff\xd9"


def tiff_declaring(width, height):
    """A little-endian TIFF whose first IFD holds ImageWidth and ImageLength (LONG) only."""
    entries = struct.pack("<HHII", 256, 4, 1, width) + struct.pack("<HHII", 257, 4, 1, height)
    return b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", 2) + entries + struct.pack("<I", 0)


def one_line(message):
    assert "\n" not in message.strip() and "Traceback" not in message
    return message


@pytest.mark.parametrize("name, content, declared", [
    ("plate.png", png_declaring(200_000, 200_000), "200000x200000"),
    ("plate.jpg", jpeg_declaring(65_500, 65_500), "65500x65500"),
    ("plate.tif", tiff_declaring(100_000, 100_000), "100000x100000"),
])
@pytest.mark.parametrize("reader", [imread, read_frame])
def test_a_forged_header_is_refused_before_decoding(tmp_path, name, content, declared, reader):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(CamcalError) as error:
        reader(path)
    message = one_line(str(error.value))
    assert message.startswith(f"{path}: the header declares {declared} pixels")
    assert "268,435,456" in message and "CAMCAL_MAX_IMAGE_PIXELS" in message


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif", ".exr"])
def test_the_cap_is_raised_and_lowered_by_the_environment(tmp_path, monkeypatch, suffix):
    pixels = np.linspace(0.0, 1.0, 37 * 53 * 3).reshape(37, 53, 3)
    path = imwrite(tmp_path / f"small{suffix}", pixels.astype(np.float32) if suffix == ".exr"
                   else (255 * pixels).astype(np.uint8))
    monkeypatch.setenv("CAMCAL_MAX_IMAGE_PIXELS", str(37 * 53 - 1))
    with pytest.raises(CamcalError, match=r"declares 53x37 pixels \(1,961\), over the cap of 1,960"):
        imread(path)
    monkeypatch.setenv("CAMCAL_MAX_IMAGE_PIXELS", str(37 * 53))
    assert imread(path).shape == (37, 53, 3)
    assert read_frame(path).size == (53, 37)


def test_real_images_still_load(shared_data):
    for path in sorted((shared_data / "stereo_chessboard").glob("left0*.jpg"))[:3]:
        assert imread(path).ndim in (2, 3)
        assert read_frame(path).size[0] > 0
    assert read_frame(shared_data / "colorchecker_photo" / "img-colorchecker.jpg").pixels.dtype == np.uint8


# -- rigs and camera files ----------------------------------------------------------


def rig_data(**camera_fields):
    data = Rig((example_camera("cam"),)).to_dict()
    data["cameras"][0].update(camera_fields)
    return data


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    messages = [line for line in captured.err.splitlines() if line.startswith("camcal:")]
    assert code == 2, captured.err
    assert len(messages) == 1 and captured.err.splitlines()[-1].startswith("camcal: error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    return messages[0]


def test_a_rig_nested_100000_deep(tmp_path, capsys):
    path = tmp_path / "deep.rig.json"
    path.write_text('{"format": "camcal.rig", "version": 1, "cameras": ' + "[" * 100_000 + "]" * 100_000 + "}")
    message = run(["rig", "show", path], capsys)
    assert message.startswith(f"camcal: error: {path}: ") and "nested deeper than 64 levels" in message


@pytest.mark.parametrize("fields, expected", [
    ({"image_size": [10**9, 10**9]},
     "cameras[0] ('cam'): image_size declares 1000000000x1000000000 pixels (1,000,000,000,000,000,000), "
     "over the cap of 268,435,456 image pixels (set CAMCAL_MAX_IMAGE_PIXELS to raise it)"),
    ({"K": [[1e308, 0.0, 959.5], [0.0, 1e308, 539.5], [0.0, 0.0, 1.0]]},
     "cameras[0] ('cam'): K: fx = 1e+308 is not a plausible focal length for a 1920x1080 image "
     "(expected 1.92 <= fx <= 1.92e+06)"),
    ({"K": [[1500.0, 0.0, 959.5], [0.0, 1500.0, -1e7], [0.0, 0.0, 1.0]]},
     "cameras[0] ('cam'): K: cy = -10000000.0 is not a plausible principal point for a 1920x1080 image "
     "(expected -10800 <= cy <= 11880)"),
])
def test_absurd_rig_values_are_refused_naming_the_field(tmp_path, capsys, fields, expected):
    path = tmp_path / "absurd.rig.json"
    path.write_text(json.dumps(rig_data(**fields)))
    with pytest.raises(CamcalError) as error:
        Rig.load(path)
    assert one_line(str(error.value)) == f"{path}: {expected}"
    out = tmp_path / "out"
    out.mkdir()
    message = run(["stmap", path, "--camera", "cam", "--out", out / "s"], capsys)
    assert message == f"camcal: error: {path}: {expected}"
    assert list(out.iterdir()) == []


def test_a_forged_image_stops_undistort_with_nothing_written(tmp_path, capsys):
    rig = tmp_path / "good.rig.json"
    Rig((example_camera("cam"),)).save(rig)
    plate = tmp_path / "plate.png"
    plate.write_bytes(png_declaring(200_000, 200_000))
    out = tmp_path / "out"
    out.mkdir()
    message = run(["undistort", rig, "--camera", "cam", "--images", plate, "--out", out / "u"], capsys)
    assert str(plate) in message and "200000x200000" in message and "CAMCAL_MAX_IMAGE_PIXELS" in message
    assert list(out.iterdir()) == []


BIG_MATRIX_YAML = """%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 100000
   cols: 100000
   dt: d
   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 100000000
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
"""


def test_an_opencv_matrix_declaring_100000_by_100000(tmp_path, capsys):
    path = tmp_path / "big.yaml"
    path.write_text(BIG_MATRIX_YAML)
    out = tmp_path / "out"
    out.mkdir()
    message = run(["rig", "import", path, "--from", "opencv", "--out", out / "a.rig.json"], capsys)
    assert message == (f"camcal: error: {path}: camera 'camera': camera_matrix declares 100000 x 100000 values, "
                       "expected at most 9")
    assert list(out.iterdir()) == []
    path.write_text(BIG_MATRIX_YAML.replace("rows: 100000\n   cols: 100000", "rows: 3\n   cols: 3"))
    with pytest.raises(CamcalError, match="distortion_coefficients declares 1 x 100000000 values, expected at most 14"):
        import_rig(path, "opencv")


def test_camera_files_declaring_a_giant_image(tmp_path):
    colmap = tmp_path / "colmap"
    colmap.mkdir()
    (colmap / "cameras.txt").write_text("1 PINHOLE 1000000000 1000000000 1500 1500 500 500\n")
    (colmap / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    kalibr = tmp_path / "camchain.yaml"
    kalibr.write_text("cam0:\n  camera_model: pinhole\n  intrinsics: [1500, 1500, 500, 500]\n"
                      "  distortion_model: radtan\n  distortion_coeffs: [0, 0, 0, 0]\n"
                      "  resolution: [1000000000, 1000000000]\n")
    nuke = tmp_path / "cam.nk"
    nuke.write_text("Camera3 {\n name cam\n image_width 1e9\n image_height 1e9\n focal 50\n haperture 36\n}\n")
    for path, fmt in ((colmap, "colmap"), (kalibr, "kalibr"), (nuke, "nuke")):
        with pytest.raises(CamcalError) as error:
            import_rig(path, fmt)
        message = one_line(str(error.value))
        assert message.startswith(str(path)) and "1000000000x1000000000 pixels" in message, message


def test_a_camera_file_past_the_size_cap(tmp_path, monkeypatch):
    path = tmp_path / "big.yaml"
    path.write_text(BIG_MATRIX_YAML + "#" * 5000 + "\n")
    monkeypatch.setenv("CAMCAL_MAX_FILE_BYTES", "4096")
    with pytest.raises(CamcalError) as error:
        import_rig(path, "opencv")
    message = one_line(str(error.value))
    assert message.startswith(f"{path}: OpenCV file of ") and "CAMCAL_MAX_FILE_BYTES" in message


def test_a_kalibr_file_nested_deep(tmp_path):
    path = tmp_path / "camchain.yaml"
    path.write_text("cam0: " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(CamcalError) as error:
        import_rig(path, "kalibr")
    assert one_line(str(error.value)).startswith(str(path))
