"""The exported config loads where it goes: OpenColorIO 2.3, 2.4, 2.5 (side by side) and 2.6, and Blender.

Each release runs in its own subprocess with ``PYTHONPATH`` set to its
folder (``ocio_releases.py``, installed by ``make test``); it loads the
config written by default (the ACES studio config for profile 2.3),
validates it and converts the chart's colours through the camera spaces.
The peer is the fit itself: its XYZ against OpenColorIO's ACES2065-1 taken
back to XYZ by colour-science (Bradford, as the export adapts).
"""

import copy

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")
import colour  # noqa: E402

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.io.ocio import export_ocio  # noqa: E402
from colour_export_helpers import (  # noqa: E402
    ACES_to_XYZ,
    blender_reads,
    codes_of,
    load_in_release,
    make_fit,
    needs_ocio_writing,
    releases,
)
from ocio_releases import RELEASES  # noqa: E402

SPACES = {"camcal nikon": "matrix3x3", "camcal nikon rp": "root-polynomial:2"}


@pytest.fixture(scope="module")
def exported(tmp_path_factory, sim):
    """The default export (base ocio://studio-config-latest, default version) of a matrix and a baked fit."""
    fits = [(name.removeprefix("camcal "), make_fit(sim, model)) for name, model in SPACES.items()]
    folder = tmp_path_factory.mktemp("ocio_versions")
    result = export_ocio(fits, folder / "cfg")
    codes = np.concatenate([codes_of(sim.RGB_train), codes_of(sim.RGB_test)])
    return result, dict(fits), codes


def test_default_export_is_profile_2_3_of_the_aces_studio_config(exported):
    result, _, _ = exported
    text = result.config_path.read_text()
    assert result.profile_version == "2.3" and "ocio_profile_version: 2.3\n" in text
    assert result.base == "ocio://studio-config-v2.1.0_aces-v1.3_ocio-v2.3"
    assert "studio-config-v2.1.0_aces-v1.3_ocio-v2.3" in text


@pytest.mark.parametrize("minor", [*RELEASES, "2.6"])
def test_each_release_loads_and_converts_as_the_fit(exported, minor):
    result, fits, codes = exported
    loaded = load_in_release(minor, result.config_path, codes, SPACES)
    assert "error" not in loaded, loaded.get("error")
    assert loaded["release"] == (RELEASES[minor] if minor in RELEASES else ocio.__version__)
    assert loaded["profile"] == [2, 3]
    for name, fit in fits.items():
        space = loaded["spaces"][f"camcal {name}"]
        assert space["family"] == "Input/camcal"
        XYZ = ACES_to_XYZ(np.asarray(space["aces"]).reshape(-1, 3), fit.target_white_XYZ)
        dE = delta_E(XYZ, fit.apply_codes(codes), fit.target_white_XYZ)
        print(f"OpenColorIO {loaded['release']}, {name}: CIEDE2000 mean {dE.mean():.4f}, max {dE.max():.4f}")
        assert dE.max() <= 0.1, (name, minor, dE.max())


def test_a_newer_profile_is_refused_by_the_older_release(tmp_path, sim):
    """The harness can fail: the same fit at profile 2.5 (the ACES 2 studio config) loads in 2.5, not in 2.4."""
    needs_ocio_writing("2.5")
    releases()
    result = export_ocio([("nikon", make_fit(sim, "matrix3x3"))], tmp_path / "cfg", ocio_version="2.5")
    assert result.base == "ocio://studio-config-v4.0.0_aces-v2.0_ocio-v2.5"
    codes = codes_of(sim.RGB_train)
    assert "error" not in load_in_release("2.5", result.config_path, codes, ["camcal nikon"])
    refused = load_in_release("2.4", result.config_path, codes, ["camcal nikon"])
    assert "not able to load that config version" in refused["error"]


def test_a_newer_base_with_newer_transforms_is_refused_in_one_error(tmp_path, sim):
    needs_ocio_writing("2.6")  # the base is OpenColorIO 2.6's built-in studio config
    fit = make_fit(sim, "matrix3x3")
    refused = r"profile 2\.6\) cannot be written at profile 2\.3: Only config version 2\.[4-6] \(or higher\)"
    with pytest.raises(CamcalError, match=refused):
        export_ocio([("nikon", fit)], tmp_path / "cfg", base="ocio://studio-config-v5.0.0_aces-v2.1_ocio-v2.6")
    assert not (tmp_path / "cfg").exists()


def test_a_newer_base_without_newer_features_is_written_at_the_chosen_version(tmp_path, sim):
    """A studio's own config saved at 2.6 that uses nothing newer than 2.3 loads in OpenColorIO 2.3."""
    needs_ocio_writing("2.6")
    studio = ocio.Config.CreateFromFile("ocio://studio-config-v2.1.0_aces-v1.3_ocio-v2.3")
    newer = copy.deepcopy(studio)
    newer.setVersion(2, 6)
    (tmp_path / "studio.ocio").write_text(newer.serialize())
    result = export_ocio([("nikon", make_fit(sim, "matrix3x3"))], tmp_path / "cfg", base=str(tmp_path / "studio.ocio"))
    assert result.profile_version == "2.3"
    loaded = load_in_release("2.3", result.config_path, codes_of(sim.RGB_train), ["camcal nikon"])
    assert "error" not in loaded and loaded["profile"] == [2, 3]


def test_an_unknown_version_is_one_error(tmp_path, sim):
    with pytest.raises(CamcalError, match="unknown OCIO profile version '2.9'"):
        export_ocio([("nikon", make_fit(sim, "matrix3x3"))], tmp_path / "cfg", ocio_version="2.9")


def test_blender_loads_the_default_export(exported, tmp_path):
    pytest.importorskip("bpy")  # bpy runs in a subprocess: $OCIO is read when it starts
    result, fits, codes = exported
    grid = codes[:24].reshape(4, 6, 3)
    listed, pixels = blender_reads(result.config_path, "camcal nikon", grid, tmp_path)
    # the config's spaces (ADX16: the ACES studio config's film scan space, not in Blender's own config)
    assert {"camcal nikon", "camcal nikon rp", "ADX16"} <= set(listed)
    fit = fits["nikon"]
    # Blender's scene linear is the config's scene_linear role: ACEScg (AP1, ACES white)
    XYZ = colour.RGB_to_XYZ(pixels, colour.RGB_COLOURSPACES["ACEScg"], colour.XYZ_to_xy(fit.target_white_XYZ),
                            chromatic_adaptation_transform="Bradford")
    dE = delta_E(XYZ, fit.apply_codes(grid.reshape(-1, 3)), fit.target_white_XYZ)
    print(f"Blender: CIEDE2000 mean {dE.mean():.4f}, max {dE.max():.4f}")
    assert dE.max() <= 0.1, dE.max()


def test_cli_ocio_version(tmp_path, sim, capsys):
    from camcal.cli import main
    from camcal.io.colourfile import save_colour_file

    fit = save_colour_file(make_fit(sim, "matrix3x3", camera="left"), tmp_path / "left.colour.json")
    code = main(["colour", "export", str(fit), "--ocio", str(tmp_path / "cfg"), "--ocio-version", "2.4"])
    assert code == 0
    assert "OCIO profile 2.4, base ocio://studio-config-v2.2.0_aces-v1.3_ocio-v2.4" in capsys.readouterr().out
    assert "ocio_profile_version: 2.4\n" in (tmp_path / "cfg" / "config.ocio").read_text()
    for bad, message in ((["--ocio", str(tmp_path / "bad"), "--ocio-version", "3.0"], "unknown OCIO profile version"),
                         (["--icc", str(tmp_path / "bad" / "x.icc"), "--ocio-version", "2.3"], "give --ocio OUTDIR")):
        assert main(["colour", "export", str(fit), *bad]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "bad").exists()
