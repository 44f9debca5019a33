"""Camera spaces as studios name them, and a studio's own config extended in place.

The studio's config here is the ACES studio config (profile 2.3) saved as a
file with one space of its own that reads a LUT from its own relative
folder. camcal writes its camera space into that folder: the file keeps
every line of the original (as OpenColorIO writes it), every original
space converts as before, OpenColorIO validates it, and
OpenColorIO 2.3 loads it and converts the camera space as the fit does.
"""

import copy
import dataclasses
import difflib

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.ocio_fit import maker_family, space_encoding  # noqa: E402
from camcal.io.ocio import export_ocio  # noqa: E402
from colour_export_helpers import ACES_to_XYZ, codes_of, load_in_release, make_fit  # noqa: E402

SPI1D = "Version 1\nFrom 0.0 1.0\nLength 3\nComponents 1\n{\n0.0\n0.18\n1.0\n}\n"


def _studio_config(folder):
    """``folder/studio.ocio``: the ACES studio config for 2.3 plus 'Studio Plate' reading studio_luts/plate.spi1d."""
    config = copy.deepcopy(ocio.Config.CreateFromFile("ocio://studio-config-v2.1.0_aces-v1.3_ocio-v2.3"))
    config.setName("studio-show-config")
    config.addSearchPath("studio_luts")
    plate = ocio.ColorSpace(name="Studio Plate", family="Input/Studio", encoding="log", categories=["file-io"])
    plate.setTransform(ocio.FileTransform("plate.spi1d"), ocio.COLORSPACE_DIR_TO_REFERENCE)
    config.addColorSpace(plate)
    (folder / "studio_luts").mkdir(parents=True)
    (folder / "studio_luts" / "plate.spi1d").write_text(SPI1D)
    (folder / "studio.ocio").write_text(config.serialize())
    return folder / "studio.ocio"


def _all_spaces(config):
    return list(config.getColorSpaces(ocio.SEARCH_REFERENCE_SPACE_ALL, ocio.COLORSPACE_ALL))


def _converted(config, name, rgb):
    try:
        cpu = config.getProcessor(name, "ACES2065-1").getDefaultCPUProcessor()
    except ocio.Exception as error:
        return str(error)
    pixels = np.ascontiguousarray(rgb, dtype=np.float32)
    cpu.applyRGB(pixels)
    return pixels


def test_studio_config_extended_in_place(tmp_path, sim):
    path = _studio_config(tmp_path / "show")
    before = ocio.Config.CreateFromFile(str(path))
    before_text = before.serialize()  # OpenColorIO's own form of it (the file is rewritten by OpenColorIO)
    fit = make_fit(sim, "root-polynomial:2")
    result = export_ocio([("witness", fit)], tmp_path / "show", base=str(path), family="Input/Studio")
    assert result.config_path == path and not (tmp_path / "show" / "config.ocio").exists()
    assert (tmp_path / "show" / "luts" / "camcal_witness.clf").is_file()
    after_text = path.read_text()
    removed = [line for line in difflib.ndiff(before_text.splitlines(), after_text.splitlines())
               if line.startswith("- ")]
    # nothing of the original changed but its one search path, now a list with luts/ added
    assert removed == ["- search_path: studio_luts"], removed
    after = ocio.Config.CreateFromFile(str(path))
    after.validate()
    assert list(after.getSearchPaths()) == [*before.getSearchPaths(), "luts"]
    assert dict(after.getRoles()) == dict(before.getRoles()) and after.getName() == "studio-show-config"
    assert list(after.getDisplays()) == list(before.getDisplays())
    rgb = np.random.default_rng(7).uniform(0.0, 1.0, (64, 3))
    for space in _all_spaces(before):
        kept = after.getColorSpace(space.getName())
        assert (kept.getFamily(), list(kept.getAliases()), kept.getDescription()) == (
            space.getFamily(), list(space.getAliases()), space.getDescription())
        old, new = _converted(before, space.getName(), rgb), _converted(after, space.getName(), rgb)
        assert (old == new) if isinstance(old, str) else np.array_equal(old, new), space.getName()
    added = {space.getName() for space in _all_spaces(after)} - {space.getName() for space in _all_spaces(before)}
    assert added == {"camcal witness"}
    camera = after.getColorSpace("camcal witness")
    assert camera.getFamily() == "Input/Studio" and list(camera.getAliases()) == ["camcal_witness"]
    # the studio's OCIO 2.3 hosts load it and convert as the fit does
    codes = codes_of(sim.RGB_test)
    loaded = load_in_release("2.3", path, codes, ["camcal witness", "Studio Plate"])
    assert "error" not in loaded, loaded.get("error")
    XYZ = ACES_to_XYZ(np.asarray(loaded["spaces"]["camcal witness"]["aces"]).reshape(-1, 3), fit.target_white_XYZ)
    assert delta_E(XYZ, fit.apply_codes(codes), fit.target_white_XYZ).max() <= 0.1


def test_camera_space_named_as_studios_name_them(tmp_path, sim):
    fit = dataclasses.replace(make_fit(sim, "matrix3x3", linearise="none"),
                              capture={"format": "NEF", "make": "NIKON CORPORATION", "model": "NIKON D5100"},
                              reference="ColorChecker 24")
    assert maker_family(fit) == "Input/Nikon" and space_encoding(fit) == "scene-linear"
    result = export_ocio([("nikon (D65)", fit)], tmp_path / "cfg", base="camcal")
    config = ocio.Config.CreateFromFile(str(result.config_path))
    space = config.getColorSpace("camcal_nikon_d65")  # found by its alias
    assert space.getName() == "camcal nikon (D65)"
    assert space.getFamily() == "Input/Nikon" and list(space.getCategories()) == ["file-io"]
    assert space.getEncoding() == "scene-linear"
    description = space.getDescription()
    for part in ("NIKON D5100", "the ColorChecker 24 chart", "shot under D65", "matrix3x3", "held-out CIEDE2000"):
        assert part in description, part
    log = make_fit(sim, "matrix3x3", linearise="named:S-Log3")  # a camera log curve: the studio configs' "log"
    assert space_encoding(log) == "log" and maker_family(log) == "Input/camcal"


def test_cli_extends_a_studio_config_in_place(tmp_path, sim, capsys):
    from camcal.cli import main
    from camcal.io.colourfile import save_colour_file

    path = _studio_config(tmp_path / "show")
    fit = save_colour_file(make_fit(sim, "matrix3x3", camera="witness"), tmp_path / "witness.colour.json")
    code = main(["colour", "export", str(fit), "--ocio", str(tmp_path / "show"), "--base", str(path),
                 "--family", "Input/Studio"])
    assert code == 0
    assert f"wrote {path} (OCIO profile 2.3, base {path}" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "show").iterdir()) == ["studio.ocio", "studio_luts"]
    config = ocio.Config.CreateFromFile(str(path))
    config.validate()
    assert config.getColorSpace("camcal witness").getFamily() == "Input/Studio"
    assert config.getColorSpace("Studio Plate") is not None and list(config.getSearchPaths()) == ["studio_luts"]
    # a second run finds its space there already: one error, the file as it was
    before = path.read_text()
    assert main(["colour", "export", str(fit), "--ocio", str(tmp_path / "show"), "--base", str(path)]) == 2
    assert "'camcal witness' already exists" in capsys.readouterr().err and path.read_text() == before


def test_two_cameras_with_one_alias_is_one_error(tmp_path, sim):
    fit = make_fit(sim, "matrix3x3")
    with pytest.raises(CamcalError, match="alias 'camcal_a_cam' of colour space 'camcal a cam' already names"):
        export_ocio([("a-cam", fit), ("a cam", fit)], tmp_path / "cfg", base="camcal")
    assert not (tmp_path / "cfg").exists()
