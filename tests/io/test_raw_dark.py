"""A dim raw chart (3.5 stops under) synthesised from a measured camera: every patch measured, none dropped.

The DNG: colour-science's Nikon 5100 sensitivities under D65 render the
BabelColor ColorChecker 24; the white patch at 2^-3.5 of full scale; an
RGGB Bayer mosaic with a 14-bit black level 512 and white level 16383, shot
noise (Poisson, 2500 electrons at full scale: a 40000-electron sensor at
ISO 1600, as in dim light) and read noise (3 DN, Gaussian), so single
photosites of the dark patches fall below black. Old
rule (pixels at or below 0.5/255 counted as clipped): the dark patches were
dropped. Now all 24 are used, their means unbiased, and the fit judged on
190 independent reflectances through the same camera is better.
"""

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from dng_writer import write_cfa_dng  # noqa: E402

from camcal.cli import main  # noqa: E402
from camcal.colour.chart.detect import sample_patches  # noqa: E402
from camcal.colour.chart.patches import PatchSet  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.fit.characterise import characterise  # noqa: E402
from camcal.colour.spectral.data import reflectance_set  # noqa: E402
from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: E402
from camcal.io.raw import read_raw  # noqa: E402
from camcal.pipelines.colour import patches_from_chart  # noqa: E402

BLACK, WHITE = 512, 16383
FULL_WELL = 2500.0  # electrons at full scale (ISO 1600)
READ_NOISE = 3.0  # DN
STOPS_UNDER = 3.5
MARGIN, CELL = 16, 30  # half-size pixels


@pytest.fixture(scope="module")
def dim_chart(tmp_path_factory):
    warnings.filterwarnings("ignore")
    cam = SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65")
    names, R = reflectance_set("BabelColor Average", cam.wavelengths)
    exposure = 2.0 ** -STOPS_UNDER
    truth = cam.RGB(R) * exposure  # linear, white patch G at ~0.08 of full scale
    height, width = 2 * MARGIN + 4 * CELL, 2 * MARGIN + 6 * CELL
    half = np.full((height, width, 3), 0.02)
    for k, rgb in enumerate(truth):
        r, c = divmod(k, 6)
        half[MARGIN + r * CELL: MARGIN + (r + 1) * CELL, MARGIN + c * CELL: MARGIN + (c + 1) * CELL] = rgb
    signal = np.zeros((2 * height, 2 * width))
    for (i, j), ch in {(0, 0): 0, (0, 1): 1, (1, 0): 1, (1, 1): 2}.items():
        signal[i::2, j::2] = half[:, :, ch]
    rng = np.random.default_rng(7)
    gain = (WHITE - BLACK) / FULL_WELL  # DN per electron
    electrons = rng.poisson(np.clip(signal, 0, None) * FULL_WELL)
    dn = BLACK + electrons * gain + READ_NOISE * rng.standard_normal(signal.shape)
    path = tmp_path_factory.mktemp("dim") / "dim_chart.dng"
    write_cfa_dng(path, np.clip(np.round(dn), 0, WHITE).astype(np.uint16), "RGGB", (BLACK,) * 4, WHITE,
                  "camcal", "synthetic Nikon 5100")
    corners = np.array([[MARGIN, MARGIN], [MARGIN + 6 * CELL, MARGIN], [MARGIN + 6 * CELL, MARGIN + 4 * CELL],
                        [MARGIN, MARGIN + 4 * CELL]], dtype=float) - 0.5
    _, R_ind = reflectance_set("rawtoaces 190", cam.wavelengths)
    return cam, names, R, truth, path, corners, cam.RGB(R_ind) * exposure, cam.XYZ(R_ind)


def test_every_dark_patch_is_measured_unbiased_and_weighted(dim_chart):
    cam, names, R, truth, path, corners, _, _ = dim_chart
    found = patches_from_chart(path, "babel", corners=corners, illuminant="D65")
    assert found.patches.names == tuple(names) and found.excluded == ()
    raw = read_raw(path)
    assert np.any(raw.RGB < 0)  # single pixels below the black level
    old = sample_patches(raw.RGB, found.detection)  # the old rule: a floor at 0.5 / 255
    dropped_before = [n for n, c in zip(names, old.clipped) if c]
    # the real dim DNG of issue 31 lost dark skin, foliage, blue, red, neutral 3.5 and black this way
    assert {"dark skin", "foliage", "blue", "red", "neutral 3.5 (1.05 D)", "black 2 (1.5 D)"} <= set(dropped_before)
    # unbiased: every mean within 4 standard errors of the truth (G: two photosites per pixel)
    noise = np.sqrt(truth * FULL_WELL + (READ_NOISE * FULL_WELL / (WHITE - BLACK)) ** 2) / FULL_WELL
    noise[:, 1] /= np.sqrt(2)
    se = noise / np.sqrt(found.samples.n_pixels[:, None] * 0.8)  # 10 % trimmed at each end
    assert np.all(np.abs(found.patches.RGB - truth) < 4 * se + 1e-12)
    # weighted by signal-to-noise: the black patch counts less than the white one
    w = dict(zip(names, found.patches.weights))
    assert w["black 2 (1.5 D)"] < w["white 9.5 (.05 D)"] and 0 < w["black 2 (1.5 D)"] < 0.5
    assert "black 2 (1.5 D)" in found.too_dark and "white 9.5 (.05 D)" not in found.too_dark


def test_held_out_delta_e_beats_dropping_the_dark_patches(dim_chart):
    cam, names, R, truth, path, corners, RGB_ind, XYZ_ind = dim_chart
    white = cam.white_XYZ
    xy = f"{white[0] / white.sum():.10f},{white[1] / white.sum():.10f}"
    found = patches_from_chart(path, "babel", corners=corners, illuminant="D65")
    old = sample_patches(read_raw(path).RGB, found.detection)
    train = PatchSet(found.patches.names, found.patches.RGB, cam.XYZ(R), found.patches.weights)
    figures = {}
    for label, patches in (("all 24, weighted", train), ("old: dark dropped", train.subset(~old.clipped))):
        out = characterise(patches, white=xy, model="root-polynomial:2", linearise="none", loo=False)
        figures[label] = float(np.mean(delta_E(out.fit.model.apply(RGB_ind), XYZ_ind, white)))
    print(figures)
    assert len(train) == 24 and int(old.clipped.sum()) >= 4
    assert figures["all 24, weighted"] < figures["old: dark dropped"]


def test_cli_uses_all_patches_and_says_too_dark(dim_chart, tmp_path, capsys):
    cam, names, R, truth, path, corners, _, _ = dim_chart
    out = tmp_path / "dim.colour.json"
    assert main(["colour", "fit", "--chart", str(path), "--reference", "babel", "--illuminant", "D65",
                 "--corners", ",".join(str(v) for v in corners.ravel()), "--model", "root-polynomial:2",
                 "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["figures"]["n_train"] == 24 and summary["figures"]["n_dropped"] == 0
    assert main(["colour", "fit", "--chart", str(path), "--reference", "babel", "--illuminant", "D65",
                 "--corners", ",".join(str(v) for v in corners.ravel()), "--model", "root-polynomial:2",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "24 / 24 patches used" in text and "dropped" not in text
    n_dark = summary["figures"]["n_too_dark"]
    assert n_dark > 0 and f"too dark: {n_dark} patch(es) measured and weighted down" in text


def test_auto_with_the_spectral_route_on_the_dim_chart(dim_chart, tmp_path, capsys):
    """End to end: every patch used, auto ranks chart-only and spectral candidates (sensitivities estimated from
    the dim chart itself) and says which it wrote; held out on 190 reflectances, auto on all 24 weighted patches
    beats auto with the dark patches dropped."""
    cam, names, R, truth, path, corners, RGB_ind, XYZ_ind = dim_chart
    out = tmp_path / "dim_auto.colour.json"
    assert main(["colour", "fit", "--chart", str(path), "--reference", "babel", "--illuminant", "D65",
                 "--corners", ",".join(str(v) for v in corners.ravel()), "--objective", "xyz",
                 "--spectra", "BabelColor Average", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "24 / 24 patches used" in text and "spectral route: sensitivities estimated" in text
    assert "written: on the chart's own patches held out" in text and "ranking (best score first):" in text
    white = cam.white_XYZ
    found = patches_from_chart(path, "babel", corners=corners, illuminant="D65")
    old = sample_patches(read_raw(path).RGB, found.detection)
    xy = f"{white[0] / white.sum():.10f},{white[1] / white.sum():.10f}"
    every = PatchSet(found.patches.names, found.patches.RGB, cam.XYZ(R), found.patches.weights)
    figures = {}
    for label, patches, spectra in (("24, spectral route considered", every, "BabelColor Average"),
                                    ("24, chart only", every, None),
                                    (f"{int((~old.clipped).sum())}, dark ones dropped", every.subset(~old.clipped),
                                     None)):
        fit = characterise(patches, white=xy, model="auto", objective="xyz", linearise="none", loo=False,
                           spectra=spectra, illuminant="D65").fit
        figures[label] = float(np.mean(delta_E(fit.model.apply(RGB_ind), XYZ_ind, white)))
    print("auto held out on 190 reflectances:", figures)
    dropped = figures[f"{int((~old.clipped).sum())}, dark ones dropped"]
    # measured here: 0.857 (chart only), 0.889 (spectral route picked by the chart's leave-one-out), 0.890 (dropped):
    # the spectral route's pick is not reliably better on this camera (see issue 31's report)
    assert figures["24, chart only"] < dropped
