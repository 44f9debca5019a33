"""The ACES hand-off: CLF read back by OpenColorIO, AMF checked (its schema when given), DCTL evaluated and compiled.

Each file, read back, applied to the 24 chart patches, equals the fit (camcal's own ``apply_codes``, taken to
ACES2065-1 by colour-science) within 0.1 CIEDE2000.
"""

import base64
import dataclasses
import hashlib
import os
import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import colour
import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.cli import main  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.aces import clf_text, input_transform  # noqa: E402
from camcal.colour.export.dctl import dctl_text  # noqa: E402
from camcal.io.aces import export_aces  # noqa: E402
from camcal.io.colourfile import save_colour_file  # noqa: E402
import dctl_check  # noqa: E402
from colour_export_helpers import codes_of, make_fit, needs_ocio_writing  # noqa: E402

CLF_NS = "{http://www.smpte-ra.org/ns/2136-1/2024}"


def ocio_release() -> tuple[int, int]:
    """The installed OpenColorIO's (major, minor)."""
    return tuple(int(part) for part in ocio.__version__.split(".")[:2])
AMF_NS = "{urn:ampas:aces:amf:v2.0}"
# the ACES Transform ID specification's form of a vendor's input transform (ACES 2), and the AMF 2.0 schema's
# pattern of an input transform's ID (acesMetadataFile.xsd, tnInputTransform)
TRANSFORM_ID = re.compile(r"urn:ampas:aces:transformId:v2\.0:Input\.camcal\.[A-Za-z0-9_-]+\.a2\.v[0-9]+")
XSD_INPUT_ID = re.compile(r"urn:ampas:aces:transformId:v2.0:(Input\.\S+\.\S+\.a\d+\.v\d+|CSC\.\S+\.a\d+\.v\d+)")
CHART = "ColorChecker24 - After November 2014"


@pytest.fixture(scope="module")
def fits(sim):
    """Matrix fits with each exact linearisation, and a baked (root-polynomial) one, from a raw capture's chart."""
    capture = {"format": "NEF", "make": "NIKON CORPORATION", "model": "D5100"}
    out = {}
    for key, model, linearise in (("matrix gamma-offset", "matrix3x3", "gamma-offset"),
                                  ("matrix lut1d", "matrix3x3", "lut1d"),
                                  ("root-polynomial", "root-polynomial:2", "gamma-offset"),
                                  ("polynomial", "polynomial:10", "lut1d")):
        fit = make_fit(sim, model, linearise=linearise)
        out[key] = dataclasses.replace(fit, capture=capture, reference=CHART)
    return out


@pytest.fixture(scope="module")
def patches(sim):
    return codes_of(sim.RGB_train)


@pytest.fixture(scope="module")
def baked(fits):
    """The root-polynomial fit's input transform: its model baked once (a few seconds)."""
    return input_transform(fits["root-polynomial"], "left")


def aces_of_fit(fit, codes):
    """The fit's XYZ taken to ACES2065-1 by colour-science (Bradford to the ACES white, then AP0)."""
    return colour.XYZ_to_RGB(fit.apply_codes(codes), "ACES2065-1", illuminant=colour.XYZ_to_xy(fit.target_white_XYZ),
                             chromatic_adaptation_transform="Bradford")


def delta_E_aces(fit, aces, codes):
    """CIEDE2000 between ACES2065-1 values and the fit, both read as XYZ under the ACES white."""
    aces_white = colour.RGB_COLOURSPACES["ACES2065-1"].whitepoint
    to_XYZ = colour.RGB_COLOURSPACES["ACES2065-1"].matrix_RGB_to_XYZ
    return delta_E(aces @ to_XYZ.T, aces_of_fit(fit, codes) @ to_XYZ.T, colour.xy_to_XYZ(aces_white))


@pytest.mark.parametrize("key", ["matrix gamma-offset", "matrix lut1d", "root-polynomial"])
def test_clf_read_back_by_opencolorio_equals_the_fit(fits, baked, patches, tmp_path, key):
    fit = fits[key]
    transform = baked if key == "root-polynomial" else input_transform(fit, "left")
    clf = tmp_path / "left.clf"
    clf.write_text(clf_text(transform))
    processor = ocio.Config.CreateRaw().getProcessor(ocio.FileTransform(str(clf), interpolation=ocio.INTERP_TETRAHEDRAL))
    pixels = np.ascontiguousarray(patches, dtype=np.float32)
    processor.getDefaultCPUProcessor().applyRGB(pixels)
    error = delta_E_aces(fit, pixels.astype(np.float64), patches)
    assert error.max() < 0.1, (key, error.max())
    # OCIO reads the ACES transform ID back as the ProcessList's id
    assert processor.getFormatMetadata().getID() == transform.transform_id
    assert transform.kind == ("lut3d" if key == "root-polynomial" else "matrix")


def test_clf_carries_the_aces_transform_id_and_the_fit(fits, tmp_path):
    fit = fits["matrix gamma-offset"]
    transform = export_aces(fit, "left", clf=tmp_path / "left.clf").transform
    root = ET.parse(tmp_path / "left.clf").getroot()
    # SMPTE ST 2136-1's namespace from OpenColorIO 2.6 on; 2.3-2.5 write the Academy's CLF 3 without one
    ns = CLF_NS if ocio_release() >= (2, 6) else ""
    assert root.tag == f"{ns}ProcessList" and root.get("compCLFversion") == "3"
    info = root.find(f"{ns}Info")
    found = {child.tag.removeprefix(ns): child.text for child in info}
    assert root.get("id") == found["ACEStransformID"] == transform.transform_id
    assert TRANSFORM_ID.fullmatch(transform.transform_id) and XSD_INPUT_ID.fullmatch(transform.transform_id)
    # the maker and model first (the creator is not the maker), the light, the target
    assert transform.transform_id.endswith(":Input.camcal.Nikon_D5100_left_D65_to_ACES.a2.v1")
    assert found["ACESuserName"] == root.get("name") == "camcal Nikon D5100 left (D65) to ACES2065-1"
    assert found["Camera"] == "left" and found["CameraMake"] == "NIKON CORPORATION" and found["Chart"] == CHART
    assert found["ShotUnder"] == "D65" and found["Model"] == "matrix3x3" and found["Linearisation"] == "gamma-offset"
    test = fit.evaluation["test"]
    assert found["DeltaE2000Test"].startswith(f"mean {test['mean']:.3f}")
    description = root.find(f"{ns}Description").text
    assert CHART in description and "shot under D65" in description
    assert root.find(f"{ns}OutputDescriptor").text == "ACES2065-1"


def test_acescg_target_is_named_and_applied(fits, patches, tmp_path):
    fit = fits["matrix gamma-offset"]
    transform = input_transform(fit, "left", space="ACEScg")
    assert transform.transform_id.endswith("_to_ACEScg.a2.v1")
    ap1 = colour.RGB_to_RGB(aces_of_fit(fit, patches), "ACES2065-1", "ACEScg")
    np.testing.assert_allclose(transform.apply(patches), ap1, rtol=1e-4, atol=1e-6)  # OCIO: float32, fast pow
    with pytest.raises(CamcalError, match="an AMF input transform converts to ACES2065-1"):
        export_aces(fit, "left", clf=tmp_path / "cg.clf", amf=tmp_path / "cg.amf", space="ACEScg")
    assert not (tmp_path / "cg.clf").exists()


def read_amf(path):
    """The AMF's elements in document order, checked against the AMF 2.0 structure (the schema's sequence)."""
    root = ET.parse(path).getroot()
    assert root.tag == f"{AMF_NS}acesMetadataFile" and root.get("version") == "2.0"

    def names(node):
        return [child.tag.removeprefix(AMF_NS) for child in node]

    assert names(root) == ["amfInfo", "pipeline"]
    info, pipeline = root
    assert names(info) == ["description", "dateTime", "uuid"]
    assert names(pipeline) == ["pipelineInfo", "inputTransform"]
    pipeline_info, step = pipeline
    assert names(pipeline_info) == ["description", "dateTime", "uuid", "systemVersion"]
    for node in (info, pipeline_info):
        assert names(node[1]) == ["creationDateTime", "modificationDateTime"]
        assert all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", t.text) for t in node[1])
        assert re.fullmatch(r"urn:uuid:[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}", node[2].text)
    assert [v.text for v in pipeline_info[3]] == ["2", "0", "0"]
    assert names(step) == ["description", "hash", "file"]
    return step


@pytest.mark.parametrize("applied", [False, True])
def test_amf_names_the_clf_by_path_and_digest(fits, tmp_path, applied):
    fit = fits["matrix lut1d"]
    clf, amf = tmp_path / "luts" / "left cam.clf", tmp_path / "shots" / "A001.amf"
    written = export_aces(fit, "left", clf=clf, amf=amf, applied=applied)
    step = read_amf(amf)
    assert step.get("applied") == ("true" if applied else "false")
    description, digest, file = step
    # the file: the CLF relative to the AMF, as a URI; the hash: SHA-256 of its bytes
    assert file.text == "../luts/left%20cam.clf"
    assert (amf.parent / file.text.replace("%20", " ")).resolve() == clf.resolve()
    assert digest.get("algorithm") == "http://www.w3.org/2001/04/xmlenc#sha256"
    assert base64.b64decode(digest.text) == hashlib.sha256(clf.read_bytes()).digest()
    assert written.transform.transform_id in description.text


def _schema_validator():
    """libxml2's XML Schema validator through ctypes (libxml2 is on every Linux), or None."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("xml2")
    if not name:
        return None
    lib = ctypes.CDLL(name)
    for function, result, arguments in (("xmlSchemaNewParserCtxt", ctypes.c_void_p, [ctypes.c_char_p]),
                                        ("xmlSchemaParse", ctypes.c_void_p, [ctypes.c_void_p]),
                                        ("xmlSchemaNewValidCtxt", ctypes.c_void_p, [ctypes.c_void_p]),
                                        ("xmlSchemaValidateFile", ctypes.c_int,
                                         [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int])):
        getattr(lib, function).restype = result
        getattr(lib, function).argtypes = arguments

    def validate(xsd, document):
        schema = lib.xmlSchemaParse(lib.xmlSchemaNewParserCtxt(os.fsencode(xsd)))
        assert schema, f"libxml2 cannot read the schema {xsd}"
        return lib.xmlSchemaValidateFile(lib.xmlSchemaNewValidCtxt(schema), os.fsencode(document), 0) == 0

    return validate


def test_amf_validates_against_the_amf_schema(fits, tmp_path):
    """The AMF 2.0 schema (acesMetadataFile.xsd and the three schemas it imports, from the schema/ folder of
    github.com/ampas/aces-amf) is not shipped: their licences differ (SMPTE, W3C, ASC). Point CAMCAL_AMF_SCHEMA
    at acesMetadataFile.xsd to run this test; ``read_amf`` checks the same structure always."""
    xsd = os.environ.get("CAMCAL_AMF_SCHEMA")
    if not xsd or not Path(xsd).is_file():
        pytest.skip("set CAMCAL_AMF_SCHEMA to acesMetadataFile.xsd of github.com/ampas/aces-amf (not shipped)")
    validate = _schema_validator()
    if validate is None:
        pytest.skip("libxml2 is not installed")
    amf = tmp_path / "left.amf"
    export_aces(fits["matrix lut1d"], "left", clf=tmp_path / "left.clf", amf=amf)
    assert validate(xsd, amf)
    # the validator can fail: the same AMF without its pipelineInfo does not validate
    broken = tmp_path / "broken.amf"
    broken.write_text(re.sub(r"<aces:pipelineInfo>.*</aces:pipelineInfo>", "", amf.read_text(), flags=re.S))
    assert not validate(xsd, broken)


@pytest.mark.parametrize("key", ["matrix gamma-offset", "matrix lut1d", "root-polynomial", "polynomial"])
def test_dctl_evaluated_equals_the_fit(fits, patches, key):
    """The model's own terms, not baked: also this polynomial fit, which no 97^3 Lut3D holds within CIEDE2000 0.2
    (0.43 over the bake samples: its CLF is refused)."""
    fit = fits[key]
    transform = input_transform(fit, "left", bake=False)
    assert transform.kind == "not baked" and transform.steps == ()
    text = dctl_text(transform)
    assert dctl_check.syntax_problems(text) == []
    program = dctl_check.parse(text)
    assert program.aces_param  # listed by Resolve as an ACES Input Transform
    error = delta_E_aces(fit, dctl_check.evaluate(program, patches), patches)
    assert error.max() < 0.1, (key, error.max())
    # beyond the patches: code values across the cube and a little outside [0, 1] (curves extended linearly)
    grid = np.random.default_rng(1).uniform(-0.02, 1.02, (200, 3))
    np.testing.assert_allclose(dctl_check.evaluate(program, grid), aces_of_fit(fit, grid), rtol=1e-5, atol=1e-6)
    if key == "root-polynomial":  # root terms with the sign-preserving power, no table
        assert "_copysignf(_powf(_fabs(" in text and "__CONSTANT__" not in text


def test_dctl_named_curve_is_sampled(sim, patches):
    fit = make_fit(sim, "matrix3x3", linearise="named:sRGB")
    transform = input_transform(fit, "left")
    program = dctl_check.parse(dctl_text(transform))
    assert {len(a) for a in program.arrays.values()} == {4096}
    assert delta_E_aces(fit, dctl_check.evaluate(program, patches), patches).max() < 0.1


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) to compile the DCTL as C")
@pytest.mark.parametrize("key", ["matrix lut1d", "root-polynomial"])
def test_dctl_compiles_as_c_and_its_numbers_equal_the_fit(fits, patches, tmp_path, key):
    fit = fits[key]
    transform = input_transform(fit, "left", bake=False)
    got = dctl_check.compile_and_run(dctl_text(transform), patches, tmp_path)
    assert delta_E_aces(fit, got, patches).max() < 0.1


def test_dctl_check_catches_what_it_should():
    good = "__DEVICE__ float3 transform(int p_Width, int p_Height, int p_X, int p_Y, float p_R, float p_G, float p_B)\n{\n" \
           "    const float r = 2.0f * p_R;\n    return make_float3(r, p_G, p_B);\n}\n"
    assert dctl_check.syntax_problems(good) == []
    np.testing.assert_allclose(dctl_check.evaluate(dctl_check.parse(good), [[0.25, 0.5, 0.75]]), [[0.5, 0.5, 0.75]])
    assert dctl_check.syntax_problems(good.replace("p_R;", "p_R")) and dctl_check.syntax_problems(good[:-2])
    with pytest.raises(NameError, match="undeclared identifier 'q'"):
        dctl_check.parse(good.replace("2.0f * p_R", "2.0f * q"))
    with pytest.raises(SyntaxError):
        dctl_check.parse(good.replace("const float r = 2.0f * p_R;", "if (p_R > 0) r = 1;"))


def test_dctl_of_an_rbf_model_is_refused(sim, fits):
    transform = input_transform(fits["matrix lut1d"], "left", bake=False)
    with pytest.raises(CamcalError, match="a DCTL holds matrix, polynomial and root-polynomial fits"):
        dctl_text(dataclasses.replace(transform, model=make_fit(sim, "rbf").model))
    with pytest.raises(CamcalError, match="a CLF holds the OCIO transforms"):
        clf_text(transform)


@pytest.fixture(scope="module")
def fit_file(fits, tmp_path_factory):
    return save_colour_file(fits["matrix gamma-offset"], tmp_path_factory.mktemp("fit") / "left.colour.json")


def test_cli_writes_the_three_files(fit_file, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["colour", "export", str(fit_file), "--clf", str(out / "left.clf"), "--amf", str(out / "left.amf"),
                 "--dctl", str(out / "left.dctl"), "--applied"])
    printed = capsys.readouterr().out
    assert code == 0 and "ACES input transform urn:ampas:aces:transformId:v2.0:Input.camcal." in printed
    assert "(AMF 2.0, input transform left.clf, applied)" in printed
    assert read_amf(out / "left.amf").get("applied") == "true"
    assert dctl_check.parse((out / "left.dctl").read_text()).functions


@pytest.mark.parametrize("args, message", [
    (["--amf", "{tmp}/a.amf"], "--amf names the CLF it goes with: give --clf OUT.clf too"),
    (["--clf", "{tmp}/a.clf", "--dctl", "{tmp}/a.clf"], "--clf, --amf and --dctl must name different files"),
    (["{fit}", "--clf", "{tmp}/a.clf"], "write one camera's input transform: give one fit, got 2"),
])
def test_cli_refuses_bad_input_and_writes_nothing(fit_file, tmp_path, capsys, args, message):
    argv = ["colour", "export", str(fit_file), *(a.format(tmp=tmp_path, fit=fit_file) for a in args)]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--clf", "{tmp}/a.clf", "--applied"], "--applied has no effect without --amf"),
    (["--icc", "{tmp}/a.icc", "--aces-space", "ACEScg"], "--aces-space has no effect without --clf or --dctl"),
])
def test_cli_flags_without_their_output_are_usage_errors(fit_file, tmp_path, capsys, args, message):
    assert main(["colour", "export", str(fit_file), *(a.format(tmp=tmp_path) for a in args)]) == 2
    assert message in capsys.readouterr().err and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("version, written", [("2.5", True), ("2.3", False)])
def test_ocio_space_has_a_colour_interop_id_where_the_profile_has_the_field(fits, tmp_path, version, written):
    """From profile 2.5 on, the camera space carries a namespaced Color Interop Forum ID (also an alias, as OCIO
    requires and the ACES studio configs do); a 2.3 config, which has no such field, is written without it."""
    from camcal.io.ocio import export_ocio

    needs_ocio_writing(version)
    result = export_ocio([("nikon (D65)", fits["matrix gamma-offset"])], tmp_path / "cfg", ocio_version=version)
    config = ocio.Config.CreateFromFile(str(result.config_path))
    config.validate()
    space = config.getColorSpace("camcal nikon (D65)")
    assert ("interop_id:" in result.config_path.read_text()) == written
    if written:
        assert space.getInteropID() == "camcal:nikon_d65_scene"
        assert config.getColorSpace("camcal:nikon_d65_scene").getName() == space.getName()
    else:
        assert config.getColorSpace("camcal:nikon_d65_scene") is None
    assert list(space.getAliases())[0] == "camcal_nikon_d65"


@pytest.mark.parametrize("model", ["matrix3x3", "root-polynomial:2"])
def test_real_chart_photo_hand_off(shared_data, tmp_path, model):
    """A real sRGB JPEG of a ColorChecker (no one on the project made it): fitted, exported as CLF, AMF and DCTL;
    the CLF read back by OCIO (exact matrix, or the baked Lut3D) and the DCTL's arithmetic, on the chart's own
    measured patches, saturated ones included, equal the fit."""
    import camcal

    photo = shared_data / "colorchecker_photo" / "img-colorchecker.jpg"
    fitted = camcal.fit_colour(chart=photo, model=model, camera="photo", out=tmp_path / "photo.colour.json")
    codes = fitted.chart.patches.RGB
    outputs = {kind: tmp_path / "aces" / f"photo.{kind}" for kind in ("clf", "amf", "dctl")}
    result = camcal.export_colour([tmp_path / "photo.colour.json"], **outputs)
    processor = ocio.Config.CreateRaw().getProcessor(
        ocio.FileTransform(str(outputs["clf"]), interpolation=ocio.INTERP_TETRAHEDRAL))
    pixels = np.ascontiguousarray(codes, dtype=np.float32)
    processor.getDefaultCPUProcessor().applyRGB(pixels)
    assert delta_E_aces(fitted.fit, pixels.astype(np.float64), codes).max() < 0.1
    program = dctl_check.parse(outputs["dctl"].read_text())
    assert delta_E_aces(fitted.fit, dctl_check.evaluate(program, codes), codes).max() < 0.1
    assert read_amf(outputs["amf"])[2].text == "photo.clf"
    assert result.aces.transform.transform_id.endswith(":Input.camcal.photo_D50_to_ACES.a2.v1")
