"""OCIO export: the exported colour spaces reproduce the fits (OCIO's CPU processor as the peer)."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")
import colour  # noqa: E402

from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.ocio_config import ConfigSpec, LookSpec, build_ocio_config, linearisation_transforms
from camcal.colour.bake.transforms import LogShaper, transform_from_callable
from camcal.colour.export.ocio_fit import bake_samples, chart_gamut_samples
from camcal.io.ocio import base_config_path, export_ocio, load_base_config, write_ocio_config
from camcal.colour.chart.linearise import fit_linearisation  # noqa: E402
from camcal.base.errors import CamcalError  # noqa: E402
from camcal.colour.export.ocio_fit import fit_processor
from colour_export_helpers import code_grid, codes_of, make_fit, needs_ocio_writing  # noqa: E402

XYZ_D65 = "CIE XYZ-D65 - Scene-referred"  # in camcal's base and in the ACES studio config
D65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def _apply(config, src, dst, codes, lossless=False):
    """OCIO's CPU processor; ``lossless`` turns off its fast pow/log/exp (about 2e-5 relative)."""
    processor = config.getProcessor(src, dst)
    cpu = (processor.getOptimizedCPUProcessor(ocio.OPTIMIZATION_LOSSLESS) if lossless
           else processor.getDefaultCPUProcessor())
    pixels = np.ascontiguousarray(codes, dtype=np.float32)
    cpu.applyRGB(pixels)
    return pixels.astype(np.float64)


def _expected_D65(fit, codes):
    """fit.apply_codes, adapted from the fit's white to D65 with Bradford by colour-science."""
    return colour.chromatic_adaptation(fit.apply_codes(codes), np.asarray(fit.target_white_XYZ), D65,
                                       method="Von Kries", transform="Bradford")


def test_shaper_matches_ocio_log_camera():
    shaper = LogShaper()
    x = np.concatenate([np.linspace(-0.005, 0.02, 50), np.geomspace(0.02, 8.0, 50)])
    cpu = ocio.Config.CreateRaw().getProcessor(shaper.transform()).getDefaultCPUProcessor()
    got = np.ascontiguousarray(np.repeat(x[:, None], 3, axis=1), dtype=np.float32)
    cpu.applyRGB(got)
    np.testing.assert_allclose(got[:, 0], shaper.encode(x), atol=2e-6)
    np.testing.assert_allclose(shaper.decode(shaper.encode(x)), x, rtol=1e-12, atol=1e-15)
    low, high = shaper.domain
    assert low < 0 and high == pytest.approx(8.0)


def test_base_config_validates_and_agrees_with_the_studio_config():
    config = ocio.Config.CreateFromFile(str(base_config_path()))
    config.validate()
    for role in ("scene_linear", "data", "color_picking", "default", "default_byte", "default_float",
                 "texture_paint", "aces_interchange", "cie_xyz_d65_interchange", "rendering"):
        assert config.getColorSpace(config.getRoleColorSpace(role)) is not None, role
    studio = ocio.Config.CreateFromFile("ocio://studio-config-latest")
    rgb = np.random.default_rng(3).uniform(0.0, 1.0, (200, 3))
    for space in ("ACEScg", "ACEScct", "Linear Rec.709 (sRGB)", "sRGB Encoded Rec.709 (sRGB)", XYZ_D65):
        np.testing.assert_allclose(_apply(config, "ACES2065-1", space, rgb),
                                   _apply(studio, "ACES2065-1", space, rgb), atol=2e-5, err_msg=space)


def test_ociocheck_accepts_the_base_config():
    tool = shutil.which("ociocheck") or str(Path(__import__("sys").executable).parent / "ociocheck")
    if not Path(tool).exists():
        pytest.skip("ociocheck (OpenColorIO's command-line tools) is not installed")
    proc = subprocess.run([tool, "--iconfig", str(base_config_path())], capture_output=True, text=True)
    # "** Validation **" then "passed" (OpenColorIO 2.4) or "Validation: passed" (2.6)
    passed = re.search(r"^\*\* Validation \*\*\n(Validation: )?passed$", proc.stdout, re.MULTILINE)
    assert proc.returncode == 0 and passed, proc.stdout + proc.stderr


# the newest studio config (profile 2.6) has a scene-referred CIE XYZ-D65 space; the one for 2.3 has not
@pytest.mark.parametrize("base, version", [("camcal", "2.3"), ("ocio://studio-config-latest", "2.6")])
def test_matrix_fit_is_exact(tmp_path, sim, base, version):
    needs_ocio_writing(version)
    fit = make_fit(sim, "matrix3x3", target_white="D50")  # D50 target: the Bradford step matters
    result = export_ocio([("nikon", fit)], tmp_path, base=base, ocio_version=version)
    assert result.spaces[0].kind == "matrix" and result.spaces[0].clf is None
    config = ocio.Config.CreateFromFile(str(result.config_path))
    config.validate()
    space = config.getColorSpace("camcal nikon")
    assert space.getFamily() == "Input/camcal" and space.getEncoding() == "scene-linear"
    assert f"n = {len(sim.names_test)}" in space.getDescription()  # the held-out figures
    for codes in (codes_of(sim.RGB_train), codes_of(sim.RGB_test), code_grid(17)):
        expected = _expected_D65(fit, codes)
        np.testing.assert_allclose(_apply(config, "camcal nikon", XYZ_D65, codes, lossless=True), expected,
                                   atol=1e-5)
        # the default processor's fast pow (gamma-offset curve) costs about 2.3e-5 relative
        assert np.abs(_apply(config, "camcal nikon", XYZ_D65, codes) - expected).max() < 5e-5


def test_matrix_fit_into_blenders_config(tmp_path, sim):
    """Blender's config has a CIE XYZ E reference: the aces_interchange matrix places the camera."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None:
        pytest.skip("bpy is not installed (its config is the base here)")
    cfg = next(Path(p) for p in spec.submodule_search_locations).glob("*/datafiles/colormanagement/config.ocio")
    cfg = next(cfg, None)
    if cfg is None:
        pytest.skip("Blender's config.ocio not found in the bpy package")
    fit = make_fit(sim, "matrix3x3")
    # Blender 5.2's config is profile 2.5 (ACES 2 views): written for the OCIO 2.5 it links
    needs_ocio_writing("2.5")
    result = export_ocio([("nikon", fit)], tmp_path, base=str(cfg), ocio_version="2.5")
    config = ocio.Config.CreateFromFile(str(result.config_path))
    codes = codes_of(sim.RGB_test)
    got = _apply(config, "camcal nikon", "Linear CIE-XYZ D65", codes, lossless=True)
    np.testing.assert_allclose(got, _expected_D65(fit, codes), atol=1e-5)


@pytest.mark.parametrize("model", ["root-polynomial:2", "polynomial:7"])
def test_baked_fits_within_delta_E(tmp_path, sim, model):
    fit = make_fit(sim, model)
    result = export_ocio([("nikon", fit)], tmp_path, base="camcal")
    report = result.spaces[0]
    assert report.kind == "lut3d" and report.bake_error.max <= 0.2
    clf = tmp_path / report.clf
    assert clf.is_file() and "<LUT3D" in clf.read_text() and "<Log" in clf.read_text()
    config = ocio.Config.CreateFromFile(str(result.config_path))
    white = fit.target_white_XYZ

    def dE(codes):
        return delta_E(_apply(config, "camcal nikon", XYZ_D65, codes), _expected_D65(fit, codes), D65)

    assert dE(codes_of(sim.RGB_train)).max() < 0.2
    # independent patches (190 reflectances no step saw), inside and outside the chart gamut: below 0.2
    test = dE(codes_of(sim.RGB_test))
    gamut = chart_gamut_samples(fit)
    from scipy.spatial import Delaunay

    hull = Delaunay(np.vstack([gamut, np.zeros((1, 3))]))
    inside = hull.find_simplex(fit.linearise(codes_of(sim.RGB_test))) >= 0
    assert inside.sum() > 50 and (~inside).sum() > 20
    assert test.max() < 0.2
    # dense grid of code values whose linear RGB lies in the chart gamut (two stops darker to the chart)
    grid = code_grid(25)
    lin = fit.linearise(grid)
    keep = Delaunay(np.vstack([gamut])).find_simplex(lin) >= 0
    assert keep.sum() > 200
    assert dE(grid[keep]).max() < 0.2
    # the CLF on its own reproduces the model (linear RGB -> XYZ) as the report says, over the bake samples
    samples = bake_samples(fit)
    cpu = ocio.Config.CreateRaw().getProcessor(ocio.FileTransform(str(clf))).getDefaultCPUProcessor()
    pixels = np.ascontiguousarray(samples, dtype=np.float32)
    cpu.applyRGB(pixels)
    np.testing.assert_allclose(delta_E(pixels, fit.apply(samples), white).max(), report.bake_error.max, rtol=1e-3)


def test_a_model_that_cannot_bake_is_refused_with_the_error_reached(tmp_path, sim):
    """polynomial:10 bends too sharply on saturated surfaces for a 97^3 grid: refused, nothing written."""
    fit = make_fit(sim, "polynomial:10")
    with pytest.raises(CamcalError, match=r"97\^3 Lut3D still leaves CIEDE2000 up to [0-9.]+"):
        export_ocio([("nikon", fit)], tmp_path / "out", base="camcal")
    assert not (tmp_path / "out").exists()


def test_linearisations_lut1d_exact_named_sampled(sim):
    from camcal.colour.fit.characterise import neutral_indices

    Y = sim.XYZ_train[:, 1]
    neutral = neutral_indices(sim.XYZ_train, sim.white)
    codes = codes_of(sim.RGB_train)
    probe = np.repeat(np.linspace(0.0, 1.0, 1001)[:, None], 3, axis=1)
    for kind, tol in (("lut1d", 1e-6), ("named:sRGB", 1e-4)):
        lin = fit_linearisation(codes[neutral], Y[neutral], kind)
        transforms, error = linearisation_transforms(lin)
        cpu = ocio.Config.CreateRaw().getProcessor(ocio.GroupTransform(transforms)).getDefaultCPUProcessor()
        got = np.ascontiguousarray(probe, dtype=np.float32)
        cpu.applyRGB(got)
        truth = lin.apply(probe)
        measured = np.max(np.abs(got - truth) / np.abs(truth[-1]))
        assert measured < tol, kind
        assert (error == 0.0) == (kind == "lut1d")
        if kind != "lut1d":
            assert error == pytest.approx(measured, rel=0.5, abs=2e-6)


def test_generic_look_from_a_callable(tmp_path):
    """An RGB -> RGB function (as a camera match would be) baked and added as a Look."""
    M = np.array([[0.9, 0.08, 0.02], [0.05, 0.9, 0.05], [0.01, 0.09, 0.9]])

    def match(rgb):
        return (np.sign(rgb) * np.abs(rgb) ** 1.02) @ M.T

    rng = np.random.default_rng(5)
    samples = rng.uniform(0.02, 0.9, (400, 3))
    to_XYZ = colour.RGB_COLOURSPACES["ACEScg"].matrix_RGB_to_XYZ
    baked = transform_from_callable(match, samples=samples, white_XYZ=colour.xy_to_XYZ(
        colour.RGB_COLOURSPACES["ACEScg"].whitepoint), to_XYZ=lambda v: v @ to_XYZ.T)
    assert baked.kind == "lut3d" and baked.bake_error.max <= 0.2
    files = {"luts/match.clf": baked.clf_text("camcal:match")}
    look = LookSpec("camcal match", "ACEScg", ocio.FileTransform("match.clf"), "test match", files)
    path = write_ocio_config(ConfigSpec(base=load_base_config("camcal"), looks=(look,)), tmp_path)
    config = ocio.Config.CreateFromFile(str(path))
    transform = ocio.LookTransform(src="ACEScg", dst="ACEScg", looks="camcal match")
    cpu = config.getProcessor(transform).getDefaultCPUProcessor()
    pixels = np.ascontiguousarray(samples, dtype=np.float32)
    cpu.applyRGB(pixels)
    np.testing.assert_allclose(pixels, match(samples), atol=2e-3)
    # exact matrices stay exact
    exact = transform_from_callable(lambda v: v @ M.T, matrix=M)
    cpu = ocio.Config.CreateRaw().getProcessor(exact.transform).getDefaultCPUProcessor()
    pixels = np.ascontiguousarray(samples, dtype=np.float32)
    cpu.applyRGB(pixels)
    np.testing.assert_allclose(pixels, samples @ M.T, atol=1e-6)


def test_errors_leave_no_output(tmp_path, sim):
    fit = make_fit(sim, "root-polynomial:2")
    out = tmp_path / "out"
    with pytest.raises(CamcalError, match=r"5\^3 Lut3D still leaves"):
        export_ocio([("nikon", fit)], out, base="camcal", lut_sizes=(5,))
    with pytest.raises(CamcalError, match="unique"):
        export_ocio([("a", fit), ("a", fit)], out, base="camcal")
    with pytest.raises(CamcalError, match="not found"):
        export_ocio([("a", fit)], out, base=str(tmp_path / "missing.ocio"))
    with pytest.raises(CamcalError, match="already exists"):
        build_ocio_config(ConfigSpec(base=load_base_config("camcal"), looks=(LookSpec("x", "ACEScg", ocio.MatrixTransform()),
                                                             LookSpec("x", "ACEScg", ocio.MatrixTransform()))))
    assert not out.exists()


def test_inverse_of_a_sigma_root_polynomial_is_the_cameras_own_rgb():
    """A root-polynomial fit of the Sigma SDMerill (large cancelling coefficients) maps several RGB to
    one XYZ; inverting it must give back the camera's non-negative RGB of each patch."""
    from camcal.colour.fit.characterise import characterise
    from camcal.colour.bake.samples import invert_model
    from camcal.colour.chart.patches import PatchSet
    from camcal.colour.spectral.simulate import SimulatedCamera
    from camcal.colour.spectral.data import reflectance_set

    camera = SimulatedCamera.from_colour("Sigma SDMerill (NPL)", "D65")
    names, chart = reflectance_set("ISO 17321-1", camera.wavelengths)
    RGB = camera.RGB(chart) * 0.8 / float(np.max(camera.RGB_white))
    fit = characterise(PatchSet(tuple(names), RGB, camera.XYZ(chart)), white="D65", model="root-polynomial:2",
                       objective="de2000", linearise="none", loo=False).fit
    assert np.abs(np.asarray(fit.model.to_dict()["coefficients"])).max() > 5  # the hard case
    found = invert_model(fit.apply, fit.apply(RGB))
    np.testing.assert_allclose(found, RGB, atol=1e-6)


@pytest.mark.parametrize("space", ["ACES2065-1", "ACEScg", "lin Rec.709", "CIE XYZ"])
def test_library_apply_is_the_exported_transform_in_the_chosen_space(sim, space):
    """fit_processor(fit, space): a matrix fit through OCIO equals numpy + colour-science's conversion (Bradford)."""
    fit = make_fit(sim, "matrix3x3")
    processor = fit_processor(fit, space)
    assert processor.kind == "matrix" and processor.bake_error is None
    codes = codes_of(sim.RGB_test).reshape(10, 19, 3)
    got = processor.apply(codes)
    assert got.dtype == np.float32 and got.shape == codes.shape
    XYZ = fit.apply_codes(codes.reshape(-1, 3))
    if space == "CIE XYZ":
        expected = XYZ
    else:
        name = {"ACES2065-1": "ACES2065-1", "ACEScg": "ACEScg", "lin Rec.709": "ITU-R BT.709"}[space]
        expected = colour.XYZ_to_RGB(XYZ, name, illuminant=colour.XYZ_to_xy(fit.target_white_XYZ),
                                     chromatic_adaptation_transform="Bradford")
    # OCIO's fast pow in the gamma-offset linearisation: about 2e-5 relative per camera channel, which the
    # output matrix mixes into small outputs: 5e-5 of white absolute
    np.testing.assert_allclose(got.reshape(-1, 3), expected, rtol=1e-4, atol=5e-5)
    frame = codes.astype(np.float32)
    assert processor.apply(frame, in_place=True) is frame
    with pytest.raises(CamcalError, match="unknown output space 'sRGB'"):
        fit_processor(fit, "sRGB")
