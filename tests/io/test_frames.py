"""Frame I/O: depth, channels and EXR metadata survive a read-write round trip; corrupt files are named."""

import os

import numpy as np
import OpenEXR
import pytest

from camcal.base.errors import CamcalError
from camcal.io.frames import ImageFrame, read_frame, write_frame

import cv2  # noqa: E402  (after camcal.io.frames, which enables OpenEXR in OpenCV)


def _write_exr(path, planes, **attributes):
    header = {"compression": OpenEXR.PIZ_COMPRESSION, **attributes}
    with OpenEXR.File(header, dict(planes)) as exr:  # the bindings replace the dict's values
        exr.write(str(path))


def test_exr_half_and_float_channels_and_header_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    planes = {
        "R": rng.random((30, 40)).astype(np.float16),
        "G": rng.random((30, 40)).astype(np.float16),
        "B": (rng.random((30, 40)) * 1e4).astype(np.float16),
        "Z": (rng.random((30, 40)) * 1e5).astype(np.float32),
    }
    _write_exr(tmp_path / "in.exr", planes, owner="camcal tests", capDate="2025:01:02 03:04:05",
               framesPerSecond=(24000, 1001), custom_note="keep me")
    frame = read_frame(tmp_path / "in.exr")
    assert frame.pixels.dtype == np.float32 and frame.size == (40, 30)
    assert dict(zip(frame.channels, frame.exr_types)) == {"R": np.float16, "G": np.float16, "B": np.float16, "Z": np.float32}
    write_frame(tmp_path / "out.exr", frame)
    with OpenEXR.File(str(tmp_path / "out.exr"), separate_channels=True) as exr:
        header = dict(exr.header())
        back = {name: channel.pixels.copy() for name, channel in exr.channels().items()}
    for name, plane in planes.items():
        assert back[name].dtype == plane.dtype
        np.testing.assert_array_equal(back[name], plane)  # half -> float32 -> half is exact
    assert header["owner"] == "camcal tests" and header["capDate"] == "2025:01:02 03:04:05"
    assert header["custom_note"] == "keep me" and list(header["framesPerSecond"]) == [24000, 1001]
    assert header["compression"] == OpenEXR.PIZ_COMPRESSION


def test_exr_of_another_size_gets_new_windows(tmp_path):
    plane = np.ones((30, 40), np.float32)
    _write_exr(tmp_path / "in.exr", {"Y": plane})
    frame = read_frame(tmp_path / "in.exr")
    write_frame(tmp_path / "out.exr", frame.with_pixels(np.zeros((50, 70), np.float32)))
    with OpenEXR.File(str(tmp_path / "out.exr")) as exr:
        low, high = (np.asarray(c).tolist() for c in exr.header()["dataWindow"])
    assert (low, high) == ([0, 0], [69, 49])


@pytest.mark.parametrize("suffix,dtype,channels", [
    (".png", np.uint8, 3), (".png", np.uint16, 4), (".png", np.uint16, 1),
    (".tif", np.uint16, 3), (".tif", np.float32, 3), (".jpg", np.uint8, 3),
])
def test_opencv_formats_keep_depth_and_channels(tmp_path, suffix, dtype, channels):
    rng = np.random.default_rng(1)
    top = np.iinfo(dtype).max if np.issubdtype(dtype, np.integer) else 1.0
    image = (rng.random((24, 32, channels)) * top).astype(dtype)
    lossless = [cv2.IMWRITE_TIFF_COMPRESSION, 5] if suffix == ".tif" else []  # not OpenCV's LogLuv for float
    cv2.imwrite(str(tmp_path / f"in{suffix}"), image[:, :, 0] if channels == 1 else image, lossless)
    frame = read_frame(tmp_path / f"in{suffix}")
    assert frame.pixels.dtype == dtype and frame.pixels.shape == (24, 32, channels)
    write_frame(tmp_path / f"out{suffix}", frame)
    again = read_frame(tmp_path / f"out{suffix}")
    assert again.pixels.dtype == dtype and again.channels == frame.channels
    if suffix != ".jpg":  # lossless formats give the pixels back exactly
        np.testing.assert_array_equal(again.pixels, image.reshape(again.pixels.shape))


@pytest.mark.parametrize("content", [b"", b"not an image at all" * 10, "truncated"])
@pytest.mark.parametrize("suffix", [".exr", ".png"])
def test_corrupt_files_raise_one_line_naming_the_file(tmp_path, content, suffix):
    good = tmp_path / f"good{suffix}"
    if suffix == ".exr":
        _write_exr(good, {"Y": np.random.default_rng(2).random((64, 64)).astype(np.float32)})
    else:
        cv2.imwrite(str(good), np.random.default_rng(2).integers(0, 65535, (64, 64), dtype=np.uint16))
    data = good.read_bytes()[: len(good.read_bytes()) // 2] if content == "truncated" else content
    bad = tmp_path / f"bad{suffix}"
    bad.write_bytes(data)
    with pytest.raises(CamcalError, match="bad") as error:
        read_frame(bad)
    assert "\n" not in str(error.value)


def test_refused_inputs(tmp_path):
    with pytest.raises(CamcalError, match="missing input"):
        read_frame(tmp_path / "nothing.exr")
    with pytest.raises(CamcalError, match="unsupported image format"):
        read_frame(tmp_path / "a.gif")
    _write_exr(tmp_path / "uint.exr", {"id": np.zeros((4, 4), np.uint32)})
    with pytest.raises(CamcalError, match="UINT"):
        read_frame(tmp_path / "uint.exr")
    # a float image cannot silently become 8 bit: same depth out or an error
    frame = ImageFrame(np.zeros((4, 4, 3), np.float32), ("B", "G", "R"))
    with pytest.raises(CamcalError, match="cannot be written as PNG"):
        write_frame(tmp_path / "out.png", frame)
    assert not (tmp_path / "out.png").exists()
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".out.png")]
