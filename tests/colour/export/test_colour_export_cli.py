"""`camcal colour export`: help, outputs, bad input (exit 2, nothing written)."""

import pytest

from camcal.cli import main
from camcal.colour.export.icc import check_icc
from camcal.io.colourfile import save_colour_file
from colour_export_helpers import make_fit


@pytest.fixture(scope="module")
def fit_files(sim, tmp_path_factory):
    folder = tmp_path_factory.mktemp("fits")
    matrix = save_colour_file(make_fit(sim, "matrix3x3", camera="left"), folder / "left.colour.json")
    baked = save_colour_file(make_fit(sim, "root-polynomial:2", camera=None), folder / "right.colour.json")
    return matrix, baked


def test_export_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["colour", "export", "--help"])
    out = capsys.readouterr().out
    assert info.value.code == 0
    for option in ("--camera-name", "--ocio", "--base", "--icc", "--icc-version", "--max-bake-error"):
        assert option in out


def test_export_ocio_and_icc(tmp_path, fit_files, capsys):
    ocio = pytest.importorskip("PyOpenColorIO")
    matrix, baked = fit_files
    code = main(["colour", "export", str(matrix), str(baked), "--ocio", str(tmp_path / "cfg"), "--base", "camcal"])
    out = capsys.readouterr().out
    assert code == 0 and "camcal left: matrix3x3, exact MatrixTransform" in out
    assert "camcal right: root-polynomial:2" in out and "bake error" in out  # name from the file name
    config = ocio.Config.CreateFromFile(str(tmp_path / "cfg" / "config.ocio"))
    assert {"camcal left", "camcal right"} <= {cs.getName() for cs in config.getColorSpaces()}
    assert (tmp_path / "cfg" / "luts" / "camcal_right.clf").is_file()
    code = main(["colour", "export", str(baked), "--camera-name", "B cam", "--icc", str(tmp_path / "b.icc"),
                 "--icc-version", "2"])
    assert code == 0 and "ICC v2, A2B0" in capsys.readouterr().out
    info = check_icc((tmp_path / "b.icc").read_bytes())
    assert info.version_major == 2 and "A2B0" in info.tags


@pytest.mark.parametrize("extra", [
    ["--ocio", "OUT"],                                   # missing fit file
    ["--icc", "OUT/x.icc", "--max-bake-error", "1e-9"],  # bake cannot meet the bound
    [],                                                  # nothing to write
])
def test_export_bad_input_exit_2_nothing_written(tmp_path, fit_files, capsys, extra):
    matrix, baked = fit_files
    source = str(tmp_path / "missing.colour.json") if extra[:2] == ["--ocio", "OUT"] else str(baked)
    extra = [e.replace("OUT", str(tmp_path / "out")) for e in extra]
    code = main(["colour", "export", source, *extra])
    assert code == 2
    assert capsys.readouterr().err.startswith("camcal: error: ")
    assert not (tmp_path / "out").exists()


def test_export_camera_name_needs_one_fit(tmp_path, fit_files, capsys):
    code = main(["colour", "export", *map(str, fit_files), "--camera-name", "x", "--ocio", str(tmp_path / "o")])
    assert code == 2 and "exactly one fit" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
