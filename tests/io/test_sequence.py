"""Plates: sequence notation, frames checked whole, pixels read with OpenImageIO equal to what was written."""

import os
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

oiio = pytest.importorskip("OpenImageIO")

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.cli import main  # noqa: E402
from camcal.io.sequence import (  # noqa: E402
    camera_of, feature_image, printf_pattern, read_image, sequence_frames, sequence_paths,
)

SIZE = (24, 16)


def _rgb(frame: int) -> np.ndarray:
    return np.random.default_rng(frame).random((SIZE[1], SIZE[0], 3))


def _write_exr(path: Path, rgb: np.ndarray) -> None:
    half = rgb.astype(np.float16)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION},
                      {name: np.ascontiguousarray(half[..., i]) for i, name in enumerate("RGB")}) as exr:
        exr.write(str(path))


def _write_oiio(path: Path, pixels: np.ndarray, bits: int | None = None) -> None:
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], str(pixels.dtype))
    if bits is not None:
        spec.attribute("oiio:BitsPerSample", bits)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels), out.geterror()
    out.close()


def test_exr_sequence_reads_back_the_half_values_written_in_rgb_order(tmp_path):
    for frame in range(1001, 1004):
        _write_exr(tmp_path / f"plate.{frame:04d}.exr", _rgb(frame))
    paths = sequence_paths(tmp_path / "plate.####.exr", "1001-1003")
    assert paths == sequence_paths(tmp_path / "plate.%04d.exr")  # all on disk, same files
    for frame, path in zip(range(1001, 1004), paths, strict=True):
        pixels = read_image(path)
        assert path.name == f"plate.{frame}.exr" and pixels.dtype == np.float32
        np.testing.assert_array_equal(pixels, _rgb(frame).astype(np.float16).astype(np.float32))


@pytest.mark.parametrize("bits", [10, 12, 16])
def test_dpx_reads_back_the_code_values_written(tmp_path, bits):
    codes = np.random.default_rng(bits).integers(0, 2**bits, (SIZE[1], SIZE[0], 3)).astype(np.uint16)
    path = tmp_path / f"plate.{bits}.dpx"
    _write_oiio(path, (codes.astype(np.float64) * 65535 / (2**bits - 1)).round().astype(np.uint16), bits)
    pixels = read_image(path)
    assert pixels.dtype == np.uint16 and pixels.shape == codes.shape
    np.testing.assert_array_equal(np.rint(pixels * ((2**bits - 1) / 65535)).astype(np.uint16), codes)


@pytest.mark.parametrize("suffix, dtype", [(".png", np.uint8), (".png", np.uint16), (".tif", np.uint16),
                                           (".tif", np.float32), (".jpg", np.uint8)])
def test_opencv_written_images_read_the_same_through_openimageio(tmp_path, suffix, dtype):
    scale = {np.uint8: 255, np.uint16: 65535, np.float32: 1}[dtype]
    bgr = (_rgb(7) * scale).astype(dtype)
    path = tmp_path / f"plate{suffix}"
    # TIFF with LZW as camcal.io.frames.imwrite writes it: OpenCV 4's default for float TIFF is SGILOG (LogLuv,
    # which OpenImageIO decodes to 8 bits), OpenCV 5's is none
    assert cv2.imwrite(str(path), bgr, [cv2.IMWRITE_TIFF_COMPRESSION, 5] if suffix == ".tif" else [])
    expected = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # the decoded JPEG, not the input
    pixels = read_image(path)
    assert pixels.dtype == dtype
    np.testing.assert_array_equal(pixels, expected)


def test_feature_image_is_the_srgb_encoding_of_linear_data_and_scales_codes():
    colour = pytest.importorskip("colour")
    linear = np.linspace(-0.1, 1.2, 3 * 40, dtype=np.float32).reshape(1, 40, 3)
    expected = np.rint(255 * colour.models.eotf_inverse_sRGB(np.clip(linear, 0, 1)))
    np.testing.assert_array_equal(feature_image(linear), expected)
    np.testing.assert_array_equal(feature_image(linear, bgr=True), expected[..., ::-1])
    codes = np.array([[[0, 257, 65535]]], np.uint16)
    np.testing.assert_array_equal(feature_image(codes), [[[0, 1, 255]]])


def test_missing_frames_are_named_in_one_error(tmp_path):
    for frame in (1001, 1002, 1004, 1007):
        _write_exr(tmp_path / f"plate.{frame:04d}.exr", _rgb(frame))
    with pytest.raises(CamcalError) as error:
        sequence_paths(tmp_path / "plate.%04d.exr", "1001-1008")
    message = str(error.value)
    assert "\n" not in message and "4 of 8 frames missing (1001-1008): 1003, 1005-1006, 1008" in message
    assert sequence_frames(tmp_path / "plate.####.exr") == tuple(range(1001, 1008))  # a gap on disk is missing too
    with pytest.raises(CamcalError, match="3 of 7 frames missing"):
        sequence_paths(tmp_path / "plate.####.exr")


def test_notation(tmp_path):
    assert printf_pattern("a/left.####.dpx") == "a/left.%04d.dpx"
    assert printf_pattern("a/left.%d.dpx") == "a/left.%d.dpx"
    for bad in ("a/left.exr", "a/left.%04d.%04d.exr", "a/left.##.%04d.exr", "a%d/left.%04d.exr"):
        with pytest.raises(CamcalError, match="exactly one frame number placeholder"):
            printf_pattern(bad)
    assert camera_of("plates/left.%04d.exr") == "left" and camera_of("shot_010/####.exr") == "shot_010"
    with pytest.raises(CamcalError, match="no frame of sequence"):
        sequence_frames(tmp_path / "none.%04d.exr")


def test_unreadable_frame_is_one_line_naming_the_file(tmp_path):
    path = tmp_path / "plate.1001.exr"
    path.write_bytes(b"not an exr")
    with pytest.raises(CamcalError, match=f"cannot read {path}"):
        read_image(path)


def test_solve_with_a_missing_plate_frame_exits_2_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    os.mkdir("plates")
    for frame in (1001, 1002, 1004):
        _write_exr(tmp_path / "plates" / f"left.{frame:04d}.exr", _rgb(frame))
    assert main(["solve", "plates/left.####.exr", "--frames", "1001-1004", "--out", "out"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "1 of 4 frames missing (1001-1004): 1003" in error
    assert not (tmp_path / "out").exists() and sorted(os.listdir(tmp_path)) == ["plates"]
