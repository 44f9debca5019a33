"""Raw input: DNG files the test writes (known CFA, black and white levels) come back exactly."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from dng_writer import write_cfa_dng  # noqa: E402

from camcal.cli import main  # noqa: E402
from camcal.pipelines.colour import patches_from_chart  # noqa: E402
from camcal.base.errors import CamcalError  # noqa: E402
from camcal.io.raw import read_raw, read_raw_mosaic  # noqa: E402

BLACK = (510, 512, 514, 516)  # per CFA position, row by row
WHITE = 15800


def levels_for(pattern, shape):
    return np.tile(np.array(BLACK, dtype=float).reshape(2, 2), (shape[0] // 2, shape[1] // 2))


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_mosaic_values_come_back_exactly(tmp_path, pattern):
    rng = np.random.default_rng(1)
    linear = rng.uniform(0.0, 0.98, (64, 96))
    black = levels_for(pattern, linear.shape)
    photosites = np.round(black + linear * (WHITE - black)).astype(np.uint16)
    photosites[5, 7] = WHITE  # one saturated photosite
    write_cfa_dng(tmp_path / "t.dng", photosites, pattern, BLACK, WHITE, "Acme", "Model 7")
    mosaic = read_raw_mosaic(tmp_path / "t.dng")
    expected = (photosites - black) / (WHITE - black)  # the linear values it was made from, as quantised
    np.testing.assert_array_equal(mosaic.values, expected)
    assert np.abs(mosaic.values - linear)[photosites != WHITE].max() <= 0.5 / (WHITE - 516)
    colour = np.array(["RGB".index(c) for c in pattern]).reshape(2, 2)
    np.testing.assert_array_equal(mosaic.colour[:2, :2], colour)
    assert mosaic.saturated.sum() == 1 and mosaic.saturated[5, 7]
    meta = mosaic.metadata
    assert (meta.make, meta.model, meta.cfa_pattern, meta.white_level) == ("Acme", "Model 7", pattern, WHITE)
    # half size: each 2x2 cell's R, mean G, B, exactly; the saturated cell flagged and set to 1
    half = read_raw(tmp_path / "t.dng", "half")
    cells = expected.reshape(32, 2, 48, 2).transpose(0, 2, 1, 3).reshape(32, 48, 4)
    kinds = colour.ravel()
    manual = np.stack([cells[:, :, kinds == c].mean(axis=2) for c in range(3)], axis=2)
    manual[2, 3] = 1.0
    np.testing.assert_array_equal(half.RGB, manual)
    assert half.saturated.sum() == 1 and half.saturated[2, 3]


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_bilinear_demosaic_of_a_flat_colour(tmp_path, pattern):
    value = {"R": 0.8, "G": 0.5, "B": 0.2}
    photosites = np.zeros((64, 96))
    for i in range(2):
        for j in range(2):
            photosites[i::2, j::2] = 1000 + value[pattern[2 * i + j]] * 14000
    write_cfa_dng(tmp_path / "f.dng", photosites.astype(np.uint16), pattern, (1000,) * 4, 15000)
    image = read_raw(tmp_path / "f.dng", "bilinear")
    assert image.RGB.shape == (64, 96, 3)
    np.testing.assert_allclose(image.RGB[2:-2, 2:-2], np.broadcast_to([0.8, 0.5, 0.2], (60, 92, 3)), atol=1e-4)


def _chart_dng(path, patch_rgb, margin=20, cell=40):
    """A 6x4 chart of flat linear patches, mosaiced RGGB at twice the half-size grid."""
    height, width = 2 * (2 * margin + 4 * cell), 2 * (2 * margin + 6 * cell)
    half = np.full((height // 2, width // 2, 3), 0.3)
    for k, rgb in enumerate(patch_rgb):
        r, c = divmod(k, 6)
        half[margin + r * cell: margin + (r + 1) * cell, margin + c * cell: margin + (c + 1) * cell] = rgb
    photosites = np.zeros((height, width))
    for (i, j), ch in {(0, 0): 0, (0, 1): 1, (1, 0): 1, (1, 1): 2}.items():
        photosites[i::2, j::2] = np.round(BLACK[2 * i + j] + half[:, :, ch] * (WHITE - BLACK[2 * i + j]))
    write_cfa_dng(path, photosites.astype(np.uint16), "RGGB", BLACK, WHITE, "Acme", "Model 7")
    corners = [margin - 0.5, margin - 0.5, margin + 6 * cell - 0.5, margin - 0.5,
               margin + 6 * cell - 0.5, margin + 4 * cell - 0.5, margin - 0.5, margin + 4 * cell - 0.5]
    return corners


def test_chart_from_a_dng_and_the_fit_records_the_capture(tmp_path):
    rng = np.random.default_rng(3)
    truth = rng.uniform(0.05, 0.9, (24, 3))
    truth[18] = [0.9, 0.9, 0.9]  # a white-ish neutral
    corners = _chart_dng(tmp_path / "chart.dng", truth)
    found = patches_from_chart(tmp_path / "chart.dng", corners=np.reshape(corners, (4, 2)))
    quantised = np.array([[np.round(BLACK[k] + v * (WHITE - BLACK[k])) - BLACK[k] for k, v in
                           zip((0, 1, 3), rgb)] for rgb in truth]) / (WHITE - np.array([BLACK[0], BLACK[1], BLACK[3]]))
    # G is the mean of the two G photosites (black 512 and 514): compare to 1e-4 of white
    np.testing.assert_allclose(found.patches.RGB, quantised, atol=1e-4)
    out = tmp_path / "fit.colour.json"
    assert main(["colour", "fit", "--chart", str(tmp_path / "chart.dng"), "--corners",
                 ",".join(str(v) for v in corners), "--model", "matrix3x3", "--out", str(out)]) == 0
    capture = json.loads(out.read_text())["capture"]
    assert capture["make"] == "Acme" and capture["model"] == "Model 7" and capture["white_level"] == WHITE
    assert sorted(capture["black_level"]) == sorted(float(b) for b in BLACK) and capture["cfa_pattern"] == "RGGB"
    assert json.loads(out.read_text())["linearisation"]["channels"][0] == {"kind": "none"}


@pytest.mark.parametrize("suffix", [".dng", ".cr2", ".nef", ".arw"])
def test_bad_raw_file_one_line_exit_2(tmp_path, capsys, suffix):
    bad = tmp_path / f"bad{suffix}"
    bad.write_bytes(b"II*\0" + bytes(200))
    with pytest.raises(CamcalError, match="cannot read raw file"):
        read_raw(bad)
    out = tmp_path / "fit.colour.json"
    for args in (["colour", "fit", "--chart", str(bad), "--out", str(out)],
                 ["colour", "sensitivities", "--chart", f"D65={bad}", "--out", str(tmp_path / "s.ssf.json")]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.startswith("camcal: error: cannot read raw file") and err.count("\n") == 1
    assert not out.exists() and not (tmp_path / "s.ssf.json").exists()
    with pytest.raises(CamcalError, match="unknown demosaic"):
        read_raw(bad, "ahd")
