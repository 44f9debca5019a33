"""Every chart layout camcal reads, rendered as raw captures (chart_renders.py) and found with all patches in order.

The truth is the renderer's: the patch centres it drew, the mirror it applied,
the IT8.7/2's CGATS file it wrote. Fast tests: one small render per layout
and condition; the slow test: one seed of every layout under every condition
of the bench (bench/bench_chart_layouts.py), >= 95 % found.
"""

import warnings

import numpy as np
import pytest
from chart_renders import CONDITIONS, LAYOUT_ORDER, found_in_order, render_case, render_chart

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.colour.chart.detect import patches_from_image
from camcal.colour.chart.layouts import LAYOUTS, chart_layout, it8_patch_names
from camcal.colour.chart.reference import reference_from_measurements
from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.io.cgats import read_cgats, write_cgats
from camcal.io.raw import read_raw
from camcal.pipelines.colour import chart_references, patches_from_chart

SMALL = (360, 540)


@pytest.fixture(scope="module")
def camera():
    warnings.filterwarnings("ignore")
    return SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65")


@pytest.mark.parametrize("layout, kwargs", [
    ("mini", dict(tilt_deg=35.0, share=0.3, turn_deg=180.0)),
    ("nano", dict(tilt_deg=20.0, share=0.3, mirrored=True)),
    ("digital-sg", dict(tilt_deg=30.0, share=0.4, turn_deg=170.0, stops_under=3.0, mirrored=True)),
    ("it8", dict(tilt_deg=30.0, share=0.5, turn_deg=185.0)),
])
def test_a_rendered_chart_is_found_with_every_patch_in_order(camera, tmp_path, layout, kwargs):
    """The chart type detected (an IT8.7/2 by its CGATS file), every patch in order, the mirror seen."""
    render = render_chart(tmp_path / f"{layout}.dng", camera, layout, size=SMALL, seed=3, **kwargs)
    found = patches_from_chart(render.path, tmp_path / f"{layout}.it8.txt" if layout == "it8" else None)
    assert chart_layout(found.reference.layout).family == chart_layout(layout).family
    assert found.reference.patch_names == render.reference.patch_names
    np.testing.assert_allclose(found.reference.XYZ, render.reference.XYZ, atol=1e-6)
    ok, error = found_in_order(found.detection.patch_centres(), render.centres)
    assert ok, f"worst patch centre {error:.1f} px from the truth"
    assert found.detection.mirrored == render.mirrored
    # the patches read are the rendered ones: chromaticities of the sampled means against the truth
    sampled = found.samples.RGB / found.samples.RGB.sum(axis=1, keepdims=True)
    truth = render.RGB / render.RGB.sum(axis=1, keepdims=True)
    assert np.abs(sampled - truth).max() < 0.03


def test_colour_fit_names_the_chart_and_the_mirror(camera, tmp_path, capsys):
    render = render_chart(tmp_path / "nano.dng", camera, "nano", size=SMALL, share=0.3, seed=5, mirrored=True)
    out = tmp_path / "nano.colour.json"
    assert main(["colour", "fit", "--chart", str(render.path), "--chart-type", "nano", "--model", "matrix3x3",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "chart found by segmentation: 24 / 24 patches used" in printed
    assert ("chart type: ColorChecker Nano, reference ColorChecker24 - After November 2014; seen mirrored, "
            "patches in chart order") in printed
    assert main(["colour", "fit", "--chart", str(render.path), "--chart-type", "it8", "--out", str(out)]) == 2
    assert "give its CGATS file with --reference FILE" in capsys.readouterr().err


def test_cgats_files(tmp_path):
    names = it8_patch_names()
    XYZ = np.random.default_rng(0).uniform(0.01, 0.9, (len(names), 3))
    path = write_cgats(tmp_path / "r.txt", names, XYZ, identifier="IT8.7/2")
    data = read_cgats(path)
    assert data.identifier == "IT8.7/2" and data.names == names
    np.testing.assert_allclose(data.XYZ, XYZ, atol=5e-7)
    # Lab only (D50), zero-padded names, shuffled, comments: the same patches in chart order
    import colour

    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D50"]
    Lab = colour.XYZ_to_Lab(XYZ, white)
    order = np.random.default_rng(1).permutation(len(names))
    padded = [n[0] + n[1:].zfill(2) if not n.startswith("GS") else "GS" + n[2:].zfill(2) for n in names]
    lines = ['IT8.7/2', 'ORIGINATOR "lab # not a comment"', "BEGIN_DATA_FORMAT", "SAMPLE_ID LAB_L LAB_A LAB_B",
             "END_DATA_FORMAT", "BEGIN_DATA"]
    lines += [f"{padded[k]} {Lab[k, 0]:.5f} {Lab[k, 1]:.5f} {Lab[k, 2]:.5f}  # patch" for k in order] + ["END_DATA"]
    (tmp_path / "lab.txt").write_text("\n".join(lines))
    lab = read_cgats(tmp_path / "lab.txt")
    assert lab.keywords["ORIGINATOR"] == "lab # not a comment"
    chart = reference_from_measurements("lab.txt", lab.names, lab.XYZ, "it8")
    # the file's Lab are relative to ISO 13655's D50 white (0.96422, 1, 0.82521), colour-science's to its xy
    np.testing.assert_allclose(chart.XYZ, XYZ / colour.xy_to_XYZ(white) * [0.96422, 1.0, 0.82521], atol=1e-6)
    (tmp_path / "short.txt").write_text("\n".join(lines[:-3] + ["END_DATA"]))
    with pytest.raises(CamcalError, match="lack 2 patch"):
        chart_references(tmp_path / "short.txt", "it8")
    (tmp_path / "bad.txt").write_text("CGATS.17\nBEGIN_DATA_FORMAT\nSAMPLE_ID RGB_R\nEND_DATA_FORMAT\nBEGIN_DATA\nA1 3\n"
                                      "END_DATA\n")
    with pytest.raises(CamcalError, match="no XYZ_X/XYZ_Y/XYZ_Z or LAB_L/LAB_A/LAB_B fields"):
        read_cgats(tmp_path / "bad.txt")
    (tmp_path / "ragged.txt").write_text("CGATS.17\nBEGIN_DATA_FORMAT\nSAMPLE_ID XYZ_X XYZ_Y XYZ_Z\nEND_DATA_FORMAT\n"
                                         "BEGIN_DATA\nA1 3 4\nEND_DATA\n")
    with pytest.raises(CamcalError, match="has 3 values, the format 4"):
        read_cgats(tmp_path / "ragged.txt")


def test_chart_references():
    auto = chart_references()
    assert [c.layout for c in auto] == ["digital-sg", "classic"] and [len(c.XYZ) for c in auto] == [140, 24]
    assert chart_references(None, "nano")[0].layout == "nano"
    assert chart_references("babel", "mini")[0].layout == "mini"
    with pytest.raises(CamcalError, match="has 140 patches in 10 x 14, the ColorChecker Mini 24 in 4 x 6"):
        chart_references("sg", "mini")
    with pytest.raises(CamcalError, match="unknown chart type 'hexagon'"):
        chart_references(None, "hexagon")
    assert set(LAYOUTS) == set(LAYOUT_ORDER)


@pytest.mark.slow
def test_every_layout_under_every_condition(tmp_path):
    """One seed of the bench's test set (36 renders): >= 95 % found with every patch in order and the mirror right."""
    warnings.filterwarnings("ignore")
    cameras, found, misses = {}, 0, []
    for layout in LAYOUT_ORDER:
        for condition in CONDITIONS:
            render = render_case(tmp_path, layout, condition, 0, cameras)
            try:
                result = patches_from_image(read_raw(render.path).RGB, render.reference, linear=True)
                ok = (found_in_order(result.detection.patch_centres(), render.centres)[0]
                      and result.detection.mirrored == render.mirrored)
            except CamcalError:
                ok = False
            found += ok
            if not ok:
                misses.append(f"{layout} {condition}")
    total = len(LAYOUT_ORDER) * len(CONDITIONS)
    assert found >= 0.95 * total, f"found {found} / {total}, missed: {', '.join(misses)}"
