import json
import subprocess
import sys

import numpy as np
import pytest

from camcal.cli import main
from camcal.io.colourfile import load_fit
from camcal.colour.chart.patches import PatchSet
from camcal.io.patches import read_patch_csv, write_patch_csv


def test_colour_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["colour", "--help"])
    assert info.value.code == 0
    assert "fit" in capsys.readouterr().out
    with pytest.raises(SystemExit) as info:
        main(["colour", "fit", "--help"])
    out = capsys.readouterr().out
    assert info.value.code == 0
    for option in ("--chart", "--patches", "--model", "--objective", "--test-patches", "--report", "--out"):
        assert option in out


def test_colour_needs_a_subverb_and_a_source(capsys):
    assert main(["colour"]) == 2
    assert main(["colour", "fit", "--out", "x.colour.json"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "camcal colour: error: the following arguments are required: SUBVERB", "see 'camcal colour --help'",
        "camcal colour fit: error: one of the arguments --chart --patches is required", "see 'camcal colour fit --help'"]


@pytest.fixture
def csvs(tmp_path, sim):
    train = tmp_path / "train.csv"
    test = tmp_path / "test.csv"
    write_patch_csv(train, PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train))
    write_patch_csv(test, PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test))
    return train, test


def test_fit_from_patch_csv_with_report(tmp_path, csvs, capsys, sim):
    train, test = csvs
    out = tmp_path / "nikon.colour.json"
    code = main(["colour", "fit", "--patches", str(train), "--test-patches", str(test), "--illuminant", "D65",
                 "--model", "root-polynomial:2", "--objective", "de2000", "--out", str(out),
                 "--report", str(tmp_path / "report"), "--camera-name", "nikon"])
    text = capsys.readouterr().out
    assert code == 0
    assert "CIEDE2000 independent" in text and "leave-one-out" in text
    fit = load_fit(out)
    assert fit.camera == "nikon" and fit.model.kind == "root-polynomial" and fit.model.objective == "de2000"
    assert fit.evaluation["test"]["n"] == 190
    names = {p.name for p in (tmp_path / "report").rglob("*") if p.is_file()}
    assert {"train_patches.csv", "loo_patches.csv", "test_patches.csv", "summary.txt", "swatches.png",
            "delta_E_histogram.png", "ab_errors.png"} <= names
    np.testing.assert_allclose(fit.apply(sim.camera.RGB_white[None])[0, 1], 1.0, atol=0.02)


def test_auto_from_cli_says_what_and_why(tmp_path, csvs, capsys):
    train, _ = csvs
    out = tmp_path / "auto.colour.json"
    assert main(["colour", "fit", "--patches", str(train), "--illuminant", "D65", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "auto picked it: simplest of" in text and "leave-one-out mean CIEDE2000" in text
    assert "ranking (best score first):" in text and "<- picked" in text
    data = json.loads(out.read_text())
    assert data["training"]["selection"]["picked"]["model"] in text


def test_patch_csv_without_names_and_with_errors(tmp_path):
    good = tmp_path / "p.csv"
    good.write_text("R,G,B,X,Y,Z\n0.1,0.2,0.3,0.1,0.2,0.3\n# comment\n0.4,0.5,0.6,0.4,0.5,0.6\n")
    patches = read_patch_csv(good)
    assert patches.names == ("patch1", "patch2") and patches.RGB.shape == (2, 3)
    bad = tmp_path / "bad.csv"
    bad.write_text("R,G,B,X,Y\n1,2,3,4,5\n")
    with pytest.raises(Exception, match="header must be R,G,B,X,Y,Z"):
        read_patch_csv(bad)
    bad.write_text("R,G,B,X,Y,Z\n1,2,3,4,5,z\n")
    with pytest.raises(Exception, match="bad.csv:2: not a number"):
        read_patch_csv(bad)


@pytest.mark.parametrize(
    "argv,message",
    [
        (["--patches", "missing.csv"], "patch file not found"),
        (["--chart", "missing.jpg"], "chart image not found"),
        (["--patches", "TRAIN", "--model", "poly"], "unknown model 'poly'"),
        (["--patches", "TRAIN", "--illuminant", "D99"], "unknown illuminant 'D99'"),
        (["--patches", "TRAIN", "--corners", "1,2,3"], "--corners applies to --chart only"),
    ],
)
def test_bad_input_one_line_exit_2(tmp_path, csvs, capsys, argv, message):
    argv = [str(csvs[0]) if a == "TRAIN" else a for a in argv]
    code = main(["colour", "fit", *argv, "--out", str(tmp_path / "x.colour.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("camcal: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "x.colour.json").exists()


def test_chart_absent_error(tmp_path, capsys):
    import cv2

    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((300, 400, 3), 128, np.uint8))
    code = main(["colour", "fit", "--chart", str(blank), "--out", str(tmp_path / "x.colour.json")])
    assert code == 2
    assert "no ColorChecker found in the image" in capsys.readouterr().err


def test_real_photo_through_the_cli(tmp_path, shared_data, capsys):
    photo = shared_data / "colorchecker_photo" / "img-colorchecker.jpg"
    out = tmp_path / "photo.colour.json"
    assert main(["colour", "fit", "--chart", str(photo), "--model", "matrix3x3", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "chart found by segmentation: 22 / 24 patches used (dropped clipped: yellow, cyan)" in text
    fit = load_fit(out)
    assert fit.reference == "ColorChecker24 - After November 2014"
    assert fit.linearisation.channels[0].kind == "lut1d"


def test_python_dash_m_entry():
    result = subprocess.run([sys.executable, "-m", "camcal", "colour", "fit", "--help"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0 and "--patches" in result.stdout
