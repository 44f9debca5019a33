"""`camcal colour match`: help, bad input, the image route (rectified pair; rig + rectification) and the chart route."""

import re

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.io.colourfile import load_colour_file, save_colour_file
from camcal.colour.fit.characterise import characterise
from camcal.pipelines.colour import match_image_files
from camcal.colour.match.record import ColourMatch
from camcal.colour.chart.patches import PatchSet
from camcal.io.patches import write_patch_csv
from camcal.base.errors import CamcalError
from camcal.model.rig import Rig
from camcal.synthetic import example_camera, layered_stereo_pair, procedural_texture, render_planes

M_TRUE = np.array([[1.10, -0.08, 0.03], [0.05, 0.93, 0.04], [-0.02, 0.09, 0.88]])


def _save16(path, RGB):
    """Linear RGB in [0, 1] as a 16-bit PNG (OpenCV writes BGR)."""
    assert cv2.imwrite(str(path), np.round(np.clip(RGB, 0, 1) * 65535).astype(np.uint16)[..., ::-1])
    return path


def test_match_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["colour", "match", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in ("--images", "--rectified", "--model", "--fits", "--patches", "--report", "--out", "RIG"):
        assert option in out


def test_match_bad_input_exits_2_without_output(tmp_path, capsys):
    out = tmp_path / "m.colour.json"
    a = _save16(tmp_path / "a.png", np.full((40, 64, 3), 0.5))
    cases = [
        ["colour", "match", "--out", str(out)],
        ["colour", "match", "--images", f"a={a}", f"b={a}", "--out", str(out)],  # no rig, not rectified
        ["colour", "match", "--images", f"a={a}", "--rectified", "--out", str(out)],  # one camera
        ["colour", "match", "--images", f"a={a}", f"b={tmp_path / 'missing.png'}", "--rectified", "--out", str(out)],
        ["colour", "match", "--images", f"a={a}", f"b={a}", "--rectified", "--model", "rbf", "--out", str(out)],
        ["colour", "match", "--images", "a", "--out", str(out)],
    ]
    for argv in cases:
        code = main(argv)  # camcal's own errors and malformed command lines: returns 2
        assert code == 2, argv
        assert re.search(r"^camcal( colour match)?: error:", capsys.readouterr().err, re.MULTILINE)
        assert not out.exists()


def test_rectified_pair_from_files_with_report(tmp_path, capsys):
    rng = np.random.default_rng(4)
    left, right, _, _ = layered_stereo_pair(rng)
    a = _save16(tmp_path / "left.png", left @ M_TRUE.T)
    b = _save16(tmp_path / "right.png", right)
    out = tmp_path / "right_to_left.colour.json"
    code = main(["colour", "match", "--images", f"left={a}", f"right={b}", "--rectified",
                 "--out", str(out), "--report", str(tmp_path / "report")])
    text = capsys.readouterr().out
    assert code == 0
    assert "match right -> left: matrix3x3" in text and "correspondences:" in text
    match = load_colour_file(out)
    assert isinstance(match, ColourMatch) and match.source == "right" and match.target == "left"
    np.testing.assert_allclose(match.matrix, M_TRUE, atol=2e-3)  # 16-bit quantisation only
    assert (tmp_path / "report" / "delta_E_after.png").is_file()


def _colour_render(camera, planes, textures):
    return np.stack([render_planes(camera, planes, tex) for tex in textures], axis=2).astype(np.float64) / 255.0


def test_rig_route_rectifies_then_matches(tmp_path, capsys):
    """Two toed-in cameras of a rig look at a textured wall and a panel in front of it; the
    unrectified images are rectified with the rig before matching."""
    common = dict(image_size=(320, 240), fx=300.0, fy=300.0, principal_point=(159.5, 119.5))
    a = example_camera("a", centre=(0.0, -6.0, 1.4), target=(0.1, 0.0, 1.4), **common)
    b = example_camera("b", centre=(0.4, -6.0, 1.4), target=(0.25, 0.0, 1.9), **common)  # pitched up ~5 deg
    rig_path = Rig((a, b)).save(tmp_path / "pair.rig.json")
    planes = (
        (np.array([-6.0, 0.0, -3.0]), np.array([12.0, 0.0, 0.0]), np.array([0.0, 0.0, 9.0])),
        (np.array([-0.4, -2.0, 0.9]), np.array([0.9, 0.0, 0.0]), np.array([0.0, 0.0, 0.9])),
    )
    rng = np.random.default_rng(7)
    channels = [tuple(procedural_texture(rng, 512) for _ in planes) for _ in range(3)]
    scene = {cam.name: 0.03 + 0.87 * _colour_render(cam, planes, channels) for cam in (a, b)}
    A = _save16(tmp_path / "a.png", scene["a"] @ M_TRUE.T)
    B = _save16(tmp_path / "b.png", scene["b"])
    out = tmp_path / "b_to_a.colour.json"
    code = main(["colour", "match", str(rig_path), "--images", f"a={A}", f"b={B}", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    match = load_colour_file(out)
    np.testing.assert_allclose(match.matrix, M_TRUE, atol=5e-3)
    assert match.evaluation["test"]["mean"] < 0.5
    # the rows only line up after rectification: unrectified, SGBM keeps far fewer pixels
    kept = int(text.split("correspondences: ")[1].split()[0])
    try:
        unrectified = match_image_files({"a": A, "b": B}, rectified=True).correspondences.counts["valid"]
    except CamcalError:  # too few to fit at all
        unrectified = 0
    assert unrectified < 0.5 * kept


def test_chart_route_from_fits_and_patches(tmp_path, capsys, sim_factory):
    nikon, sigma = sim_factory("Nikon 5100 (NPL)", "D65", 0), sim_factory("Sigma SDMerill (NPL)", "D65", 1)
    files = {}
    for name, sim in (("nikon", nikon), ("sigma", sigma)):
        patches = PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train)
        save_colour_file(characterise(patches, white="D65", model="matrix3x3", camera=name, loo=False).fit,
                         tmp_path / f"{name}.colour.json")
        write_patch_csv(tmp_path / f"{name}.csv", patches)
        write_patch_csv(tmp_path / f"{name}_test.csv", PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test))
        files[name] = name
    out = tmp_path / "sigma_to_nikon.colour.json"
    code = main(["colour", "match",
                 "--fits", f"sigma={tmp_path / 'sigma.colour.json'}", f"nikon={tmp_path / 'nikon.colour.json'}",
                 "--patches", f"nikon={tmp_path / 'nikon.csv'}", f"sigma={tmp_path / 'sigma.csv'}",
                 "--test-patches", f"nikon={tmp_path / 'nikon_test.csv'}", f"sigma={tmp_path / 'sigma_test.csv'}",
                 "--out", str(out), "--report", str(tmp_path / "report")])
    text = capsys.readouterr().out
    assert code == 0
    assert "camera-to-camera via XYZ" in text
    match = load_colour_file(out)
    assert match.source == "sigma" and match.target == "nikon"
    fit_A = load_colour_file(tmp_path / "nikon.colour.json")
    fit_B = load_colour_file(tmp_path / "sigma.colour.json")
    np.testing.assert_allclose(match.matrix, np.linalg.inv(fit_A.model.M) @ fit_B.model.M, atol=1e-10)
    assert match.evaluation["test"]["n"] == 190
    assert (tmp_path / "report" / "swatches.png").is_file()
