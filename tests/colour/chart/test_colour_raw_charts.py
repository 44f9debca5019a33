"""Raw ColorChecker captures through chart detection and ``colour fit`` without ``--corners``.

The captures are synthesised from measured sensitivities (raw_chart_scenes.py):
14-bit RGGB DNGs with black and white levels, shot and read noise, the chart in
perspective on a cluttered background, the classic chart or a ColorChecker
Passport opened flat (the classic page turned a quarter turn beside the
creative page). No public raw file of a ColorChecker small enough for the
repository was found (see README, "Raw charts"); real ones placed in
/work/data/raw_charts run in test_colour_raw_real_files.py.
"""

import json
import warnings

import numpy as np
import pytest
from raw_chart_peers import colour_science_raw, cv2_ccm_raw
from raw_chart_scenes import write_raw_chart

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.colour.chart.detect import detect_chart, reference_linear_RGB, sample_patches
from camcal.colour.chart.reference import reference_chart
from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.io.raw import read_raw
from camcal.pipelines.colour import patches_from_chart

#: (camera, illuminant, layout, stops under, electrons at full scale, seed)
CAPTURES = {
    "nikon-classic-3.5-under": ("Nikon 5100 (NPL)", "D65", "classic", 3.5, 2500.0, 3),
    "nikon-passport-5-under": ("Nikon 5100 (NPL)", "D65", "passport", 5.0, 2500.0, 5),
    "sigma-passport-A-1-under": ("Sigma SDMerill (NPL)", "A", "passport", 1.0, 20000.0, 4),
}


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    warnings.filterwarnings("ignore")
    folder = tmp_path_factory.mktemp("raw_charts")
    out = {}
    for key, (camera, illuminant, layout, stops, full_well, seed) in CAPTURES.items():
        cam = SimulatedCamera.from_colour(camera, illuminant)
        out[key] = (write_raw_chart(folder / f"{key}.dng", cam, layout=layout, stops_under=stops,
                                    full_well=full_well, seed=seed), illuminant)
    return out


def _pitch(centres):
    return float(np.median(np.linalg.norm(np.diff(centres.reshape(4, 6, 2), axis=1), axis=2)))


@pytest.mark.parametrize("key", list(CAPTURES))
def test_every_patch_found_on_dim_raws_and_passports(captures, key):
    chart, illuminant = captures[key]
    found = patches_from_chart(chart.path, "babel", illuminant=illuminant)
    assert found.detection.method == "segmentation"
    assert found.patches.names == tuple(chart.names) and found.excluded == ()
    error = np.abs(found.detection.patch_centres() - chart.centres).max()
    print(f"{key}: worst patch centre {error:.2f} px (pitch {_pitch(chart.centres):.0f} px)")
    assert error < 0.1 * _pitch(chart.centres)
    # the white patch sits 1 to 5 stops below full scale: dim, yet every patch is measured
    assert found.patches.RGB[18, 1] < 2.0 ** -(CAPTURES[key][3] - 0.5)


def test_segmentation_finds_what_cv2_mcc_misses(tmp_path):
    """Sigma under A, the classic chart 3.5 stops under: cv2.mcc finds no chart in the right place (bench:
    8 of 36 such raws), camcal's segmentation finds every patch, and auto uses it."""
    chart = write_raw_chart(tmp_path / "sigma.dng", SimulatedCamera.from_colour("Sigma SDMerill (NPL)", "A"),
                            stops_under=3.5, seed=0)
    image = read_raw(chart.path).RGB
    reference = reference_linear_RGB(reference_chart("babel", "A"))
    pitch = _pitch(chart.centres)
    try:
        mcc = detect_chart(image, linear=True, reference_RGB=reference, detector="cv2.mcc")
        assert np.abs(mcc.patch_centres() - chart.centres).max() > 0.25 * pitch
    except CamcalError as error:
        assert "no ColorChecker found in the image (cv2.mcc)" in str(error)
    auto = detect_chart(image, linear=True, reference_RGB=reference)
    assert auto.method == "segmentation" and np.abs(auto.patch_centres() - chart.centres).max() < 0.1 * pitch


def test_saturated_patches_are_the_only_ones_dropped(tmp_path, capsys):
    """One stop over: the white and the light patches clip at the white level; those alone are dropped, and
    said to be saturated."""
    chart = write_raw_chart(tmp_path / "over.dng", SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65"),
                            stops_under=-1.0, seed=2)
    found = patches_from_chart(chart.path, "babel", illuminant="D65")
    saturated = {n for n, rgb in zip(chart.names, chart.RGB) if rgb.max() >= 1.0}
    assert "white 9.5 (.05 D)" in saturated and set(found.excluded) == saturated
    assert len(found.patches) == 24 - len(saturated)
    out = tmp_path / "over.colour.json"
    assert main(["colour", "fit", "--chart", str(chart.path), "--reference", "babel", "--illuminant", "D65",
                 "--model", "root-polynomial:2", "--out", str(out)]) == 0
    assert f"{24 - len(saturated)} / 24 patches used (dropped saturated:" in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.parametrize("key", ["nikon-classic-3.5-under", "sigma-passport-A-1-under"])
def test_colour_fit_end_to_end_without_corners_beside_peers(captures, key, tmp_path, capsys):
    """``colour fit --chart RAW`` (auto) without --corners, then ``colour export --ocio``: 24 of 24 patches,
    leave-one-out CIEDE2000 beside cv2.ccm and colour-science on the same patches (README, "Raw charts")."""
    chart, illuminant = captures[key]
    out = tmp_path / f"{key}.colour.json"
    assert main(["colour", "fit", "--chart", str(chart.path), "--reference", "babel", "--illuminant", illuminant,
                 "--out", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)["figures"]
    assert figures["n_train"] == 24 and figures["n_dropped"] == 0
    ours = figures["delta_E2000"]["loo"]["mean"]
    found = patches_from_chart(chart.path, "babel", illuminant=illuminant)
    P, white = found.patches, found.reference.white_XYZ
    peers = {**cv2_ccm_raw(P.RGB, P.XYZ, white), **colour_science_raw(P.RGB, P.XYZ, white)}
    print(f"\n{key}: camcal auto {figures['model']}: train {figures['delta_E2000']['train']['mean']:.2f} "
          f"leave-one-out {ours:.2f}")
    for label, (train, loo) in peers.items():
        print(f"  {label}: train {train:.2f} leave-one-out {loo:.2f}")
    # the peers' usual defaults on linear RGB: OpenCV's matrices, colour-science's Cheung 3x3
    assert ours < min(peers["cv2.ccm 3x3 identity"][1], peers["cv2.ccm 4x3 identity"][1])
    assert ours < peers["Cheung 2004 terms=3"][1]
    ocio = tmp_path / "ocio"
    assert main(["colour", "export", str(out), "--ocio", str(ocio), "--base", "camcal"]) == 0
    assert (ocio / "config.ocio").is_file()


@pytest.mark.parametrize("stops", [3.0, 5.0])
def test_a_real_chart_underexposed_into_a_raw_file(shared_data, tmp_path, stops):
    """The real photo's chart (../shared/data) as a raw capture `stops` under: its sRGB decoded to linear, scaled,
    mosaicked (RGGB), shot and read noise, a DNG. The chart is found without corners, every patch in the
    place found on the photo itself (half-size pixels), and the patches read from the dim raw keep the photo's
    linear colours (their chromaticities)."""
    import colour
    from dng_writer import write_cfa_dng

    from camcal.io.colourimage import read_image

    photo = read_image(shared_data / "colorchecker_photo" / "img-colorchecker.jpg")
    on_photo = patches_from_chart(shared_data / "colorchecker_photo" / "img-colorchecker.jpg")
    linear = np.asarray(colour.cctf_decoding(photo, function="sRGB")) * 2.0 ** -stops
    height, width = (linear.shape[0] // 2) * 2, (linear.shape[1] // 2) * 2
    signal = np.zeros((height, width))
    for (i, j), ch in {(0, 0): 0, (0, 1): 1, (1, 0): 1, (1, 1): 2}.items():
        signal[i::2, j::2] = linear[i:height:2, j:width:2, ch]
    rng = np.random.default_rng(11)
    full_well, black, white = 2500.0, 512, 16383
    dn = black + rng.poisson(signal * full_well) * (white - black) / full_well + 3.0 * rng.standard_normal(signal.shape)
    path = tmp_path / "real_chart_dim.dng"
    write_cfa_dng(path, np.clip(np.round(dn), 0, white).astype(np.uint16), "RGGB", (black,) * 4, white, "camcal",
                  "real photo under")
    found = patches_from_chart(path)
    assert found.detection.method == "segmentation" and len(found.patches) + len(found.excluded) == 24
    assert found.excluded == ()  # nothing saturates 3 stops under; the photo's clipped yellow and cyan are kept
    half = (on_photo.detection.patch_centres() - 0.5) / 2.0  # photo pixel -> half-size raw pixel
    # within 0.15 pitch, as cv2.mcc and the segmentation agree on the photo itself (the sampled square
    # reaches 0.25 pitch from the centre); measured 5 stops under: 3.2 px of 25
    assert np.abs(found.detection.patch_centres() - half).max() < 0.15 * _pitch(half)
    # the photo's own linear patches (its detection, the same sampling) at the same exposure
    truth = sample_patches(linear, on_photo.detection, clip_low=None).RGB
    chroma = found.patches.RGB / found.patches.RGB.sum(axis=1, keepdims=True)
    chroma_truth = truth / truth.sum(axis=1, keepdims=True)
    # each patch's chromaticity within 4 of its standard errors (its pixels' spread over their count, through
    # chromaticity's Jacobian), plus 0.005 for the photo's and the mosaic's different pixels
    RGB = found.patches.RGB
    se = found.samples.std / np.sqrt(found.samples.n_pixels[:, None])
    S = RGB.sum(axis=1, keepdims=True)
    J = (np.eye(3)[None] * S[:, :, None] - RGB[:, :, None]) / S[:, :, None] ** 2  # d chroma_c / d RGB_k
    se_chroma = np.sqrt(np.einsum("nck,nk->nc", J**2, se**2))
    diff = np.abs(chroma - chroma_truth)
    print(f"{stops} stops under: worst chromaticity difference {diff.max():.4f}, "
          f"worst in standard errors {(diff / se_chroma).max():.1f}")
    assert np.all(diff < 4 * se_chroma + 0.005)


def test_detector_option(captures, tmp_path, capsys):
    chart, illuminant = captures["sigma-passport-A-1-under"]
    out = tmp_path / "sigma.colour.json"
    for detector in ("segmentation", "cv2.mcc"):
        assert main(["colour", "fit", "--chart", str(chart.path), "--reference", "babel", "--illuminant", illuminant,
                     "--detector", detector, "--model", "matrix3x3", "--out", str(out)]) == 0
        assert f"chart found by {detector}: 24 / 24 patches used" in capsys.readouterr().out
    patches = tmp_path / "p.csv"
    patches.write_text("R,G,B,X,Y,Z\n" + "\n".join("0.1,0.2,0.3,0.1,0.2,0.3" for _ in range(12)))
    assert main(["colour", "fit", "--patches", str(patches), "--detector", "cv2.mcc", "--out", str(out)]) == 2
    assert "--detector applies to --chart only" in capsys.readouterr().err
