"""One OCIO config holding a camera's input spaces for D65, A and a measured light (``--by-illuminant``).

The camera: colour-science's measured Nikon 5100 sensitivities; the chart:
the BabelColor ColorChecker 24 rendered under each light (the measured
light: CIE LED-B3 written as a spectrometer's CSV). Each fit is made on its
own light's chart; the config is loaded with PyOpenColorIO and every space
processes its chart to CIE XYZ D65, compared with the fit's own prediction
(colour-science's Bradford adaptation from the fit's white to D65).
"""

import json
import warnings

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")
import colour  # noqa: E402

from camcal.cli import main  # noqa: E402
from camcal.colour.chart.patches import PatchSet  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.fit.characterise import characterise  # noqa: E402
from camcal.colour.spectral.data import reflectance_set, resample_spectral  # noqa: E402
from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: E402
from camcal.io.colourfile import save_colour_file  # noqa: E402

XYZ_D65 = "CIE XYZ-D65 - Scene-referred"
D65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
LIGHTS = {"D65": "matrix3x3", "A": "matrix3x3", "studio LED": "matrix3x3"}


@pytest.fixture(scope="module", params=["matrix3x3", pytest.param("root-polynomial:2", marks=pytest.mark.slow)])
def fits(request, tmp_path_factory):
    """The three fits; A's model is the parameter (a baked space, 22 s, in the slow run)."""
    warnings.filterwarnings("ignore")
    folder = tmp_path_factory.mktemp("lights")
    nikon = SimulatedCamera.from_colour("Nikon 5100 (NPL)", "D65")
    led = resample_spectral(colour.SDS_ILLUMINANTS["LED-B3"], nikon.wavelengths)
    # a spectrometer's floor: SimulatedCamera.XYZ divides by the light's power (zero below 390 nm gives NaN)
    led = np.maximum(led, 1e-3 * led.max())
    np.savetxt(folder / "studio LED.csv", np.column_stack([nikon.wavelengths, led]), delimiter=",",
               header="wavelength,power", comments="")
    cameras = {"D65": nikon, "A": SimulatedCamera.from_colour("Nikon 5100 (NPL)", "A"),
               "studio LED": SimulatedCamera(nikon.wavelengths, nikon.sensitivities, led, nikon.cmfs, nikon.name,
                                             "studio LED")}
    names, R = reflectance_set("BabelColor Average", nikon.wavelengths)
    out = {}
    for light, model in {**LIGHTS, "A": request.param}.items():
        cam = cameras[light]
        white = cam.white_XYZ
        xy = light if light != "studio LED" else f"{white[0] / white.sum():.10f},{white[1] / white.sum():.10f}"
        RGB, XYZ = cam.RGB(R), cam.XYZ(R)
        fit = characterise(PatchSet(tuple(names), RGB, XYZ), white=xy, model=model, linearise="none",
                           camera="nikon", loo=False).fit
        path = save_colour_file(fit, folder / f"nikon_{light.replace(' ', '_')}.colour.json")
        out[light] = (path, fit, RGB, XYZ, white, model)
    return folder, out


def _to_D65(fit, XYZ):
    return colour.chromatic_adaptation(XYZ, np.asarray(fit.target_white_XYZ), D65, method="Von Kries",
                                       transform="Bradford")


def test_one_config_with_a_space_per_light(fits, tmp_path, capsys):
    folder, out = fits
    ocio_dir = tmp_path / "ocio"
    args = ["colour", "export", str(out["D65"][0]), str(out["A"][0]), f"studio LED={out['studio LED'][0]}",
            "--by-illuminant", "--ocio", str(ocio_dir), "--base", "camcal", "--json"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    names = [space["name"] for space in summary["figures"]["spaces"]]
    assert names == ["camcal nikon (D65)", "camcal nikon (A)", "camcal nikon (studio LED)"]
    config = ocio.Config.CreateFromFile(str(ocio_dir / "config.ocio"))
    config.validate()
    got = {}
    for light, (path, fit, RGB, XYZ, white, model) in out.items():
        space = f"camcal nikon ({light})"
        assert config.getColorSpace(space).getFamily() == "Input/camcal"
        cpu = config.getProcessor(space, XYZ_D65).getOptimizedCPUProcessor(ocio.OPTIMIZATION_LOSSLESS)
        pixels = np.ascontiguousarray(RGB, dtype=np.float32)
        cpu.applyRGB(pixels)
        got[light] = pixels.astype(np.float64)
        expected = _to_D65(fit, fit.apply(RGB))
        if model == "matrix3x3":
            np.testing.assert_allclose(got[light], expected, atol=1e-5)
        else:  # baked: within the bake check's CIEDE2000 0.2
            assert delta_E(got[light], expected, D65).max() < 0.2
        # and each space's chart lands near the chart's own colorimetry under that light
        error = delta_E(got[light], _to_D65(fit, XYZ), D65)
        print(f"{space}: the chart through OCIO, mean CIEDE2000 {error.mean():.2f} to the reference")
        assert error.mean() < 2.0
    # the spaces are not one space three times: the D65 chart's RGB read as if under A is far off
    cpu = config.getProcessor("camcal nikon (A)", XYZ_D65).getOptimizedCPUProcessor(ocio.OPTIMIZATION_LOSSLESS)
    pixels = np.ascontiguousarray(out["D65"][2], dtype=np.float32)
    cpu.applyRGB(pixels)
    assert delta_E(pixels.astype(np.float64), got["D65"], D65).mean() > 5.0


def test_light_names_and_errors(fits, tmp_path, capsys):
    folder, out = fits
    # a light given as a file: the fit's own illuminant label is the file's name
    assert main(["colour", "export", str(out["D65"][0]), f"LED={out['studio LED'][0]}", "--by-illuminant", "--ocio",
                 str(tmp_path / "two"), "--base", "camcal", "--camera-name", "D5100"]) == 0
    assert "camcal D5100 (D65)" in capsys.readouterr().out
    code = main(["colour", "export", str(out["D65"][0]), f"D65={out['studio LED'][0]}", "--by-illuminant",
                 "--ocio", str(tmp_path / "dup"), "--base", "camcal"])
    assert code == 2 and "two fits for the same camera and light: nikon (D65)" in capsys.readouterr().err
    assert not (tmp_path / "dup").exists()
    code = main(["colour", "export", str(out["D65"][0]), "--by-illuminant", "--icc", str(tmp_path / "x.icc")])
    assert code == 2 and "--by-illuminant names OCIO colour spaces" in capsys.readouterr().err


def test_raw_charts_under_two_lights_to_one_config(tmp_path, capsys):
    """End to end from raw files: the Nikon's chart synthesised as a DNG under D65 (3.5 stops under) and under A
    (a Passport, 1 stop under), each through ``colour fit --chart`` without corners, then one config whose spaces
    are named by the lights the fits record."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "chart"))
    from raw_chart_scenes import write_raw_chart

    from camcal.io.colourfile import load_colour_file
    from camcal.pipelines.colour import patches_from_chart

    fits = []
    for light, layout, stops in (("D65", "classic", 3.5), ("A", "passport", 1.0)):
        chart = write_raw_chart(tmp_path / f"{light}.dng", SimulatedCamera.from_colour("Nikon 5100 (NPL)", light),
                                layout=layout, stops_under=stops, full_well=2500.0, seed=6)
        fit_path = tmp_path / f"{light}.colour.json"
        assert main(["colour", "fit", "--chart", str(chart.path), "--reference", "babel", "--illuminant", light,
                     "--model", "matrix3x3", "--camera-name", "D5100", "--out", str(fit_path)]) == 0
        assert "24 / 24 patches used" in capsys.readouterr().out
        fits.append((light, fit_path, patches_from_chart(chart.path, "babel", illuminant=light)))
    assert main(["colour", "export", *[str(p) for _, p, _ in fits], "--by-illuminant", "--ocio", str(tmp_path / "o"),
                 "--base", "camcal"]) == 0
    config = ocio.Config.CreateFromFile(str(tmp_path / "o" / "config.ocio"))
    for light, fit_path, found in fits:
        fit = load_colour_file(fit_path)
        cpu = config.getProcessor(f"camcal D5100 ({light})", XYZ_D65).getOptimizedCPUProcessor(
            ocio.OPTIMIZATION_LOSSLESS)
        pixels = np.ascontiguousarray(found.patches.RGB, dtype=np.float32)
        cpu.applyRGB(pixels)
        np.testing.assert_allclose(pixels, _to_D65(fit, fit.apply(found.patches.RGB)), rtol=1e-4, atol=1e-6)
