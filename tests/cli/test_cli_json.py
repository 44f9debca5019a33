"""``--json``: one versioned object on stdout, the human summary on stderr, figures checked."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.cli.summary import SUMMARY_FORMAT, SUMMARY_VERSION
from camcal.io.colourfile import load_fit
from camcal.colour.chart.patches import PatchSet
from camcal.io.patches import write_patch_csv
from camcal.model.rig import Rig
from camcal.synthetic import example_camera


def run_json(argv, capsys):
    code = main([*argv, "--json"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)  # stdout holds exactly one JSON object
    assert summary["format"] == SUMMARY_FORMAT and summary["version"] == SUMMARY_VERSION
    assert summary["exit_code"] == code and "error" not in summary, captured.err
    return code, summary, captured.err


def test_calibrate_board(real_pair_shots, tmp_path, capsys):
    folder = real_pair_shots
    out = tmp_path / "stereo.rig.json"
    code, summary, human = run_json(["calibrate", "board", "--board", "chessboard:9x6:1", "--units", "squares",
                                     "--images", f"left={folder}/left*.jpg", f"right={folder}/right*.jpg",
                                     "--out", str(out)], capsys)
    assert code == 0 and summary["verb"] == "calibrate board" and "RMS reprojection error" in human
    rig = Rig.load(out)
    assert summary["files"] == [{"path": str(out), "kind": "rig"}]
    for camera in rig.cameras:
        figures = summary["figures"]["cameras"][camera.name]
        assert figures["quality"] == camera.quality.to_dict()
        np.testing.assert_array_equal(figures["K"], camera.K)
    assert summary["figures"]["detections"] == {"left": 6, "right": 6}


def test_calibrate_board_suggest(real_pair_shots, tmp_path, capsys):
    """--suggest 2: a shot list of two views, each lowering the expected worst sigma, drawn on a frame-sized PNG."""
    folder = real_pair_shots
    out = tmp_path / "left.rig.json"
    code, summary, human = run_json(["calibrate", "board", "--board", "chessboard:9x6:1", "--units", "squares",
                                     "--images", f"left={folder}/left*.jpg", "--model", "polynomial",
                                     "--suggest", "2", "--out", str(out)], capsys)
    preview = tmp_path / "left.suggest.png"
    assert code == 0 and {"path": str(preview), "kind": "suggest"} in summary["files"] and "next views" in human
    camera = Rig.load(out).cameras[0]
    sigmas = [camera.quality["worst_projection_sigma_px"]] + [s["worst_sigma_px"] for s in summary["figures"]["suggested"]]
    assert len(sigmas) == 3 and sigmas[0] > sigmas[1] > sigmas[2]
    image = cv2.imread(str(preview))
    assert image.shape[:2] == camera.image_size[::-1] and image.max() > 40


@pytest.fixture
def small_rig(tmp_path):
    size = (320, 240)
    left = example_camera("left", image_size=size, fx=300, fy=300, principal_point=(159.5, 119.5))
    right = example_camera("right", image_size=size, fx=300, fy=300, principal_point=(159.5, 119.5),
                           centre=(0.7, -6.0, 1.4))
    rng = np.random.default_rng(0)
    for name in ("left", "right"):
        (tmp_path / name).mkdir()
        cv2.imwrite(str(tmp_path / name / f"{name}_0.png"), rng.integers(0, 255, (240, 320), np.uint8))
    return Rig((left, right)).save(tmp_path / "rig.rig.json")


def test_rectify(small_rig, tmp_path, capsys):
    out = tmp_path / "r.rig.json"
    code, summary, _ = run_json(["rectify", str(small_rig), "--images", f"left={tmp_path}/left/*.png",
                                 f"right={tmp_path}/right/*.png", "--write", str(tmp_path / "w"),
                                 "--out", str(out)], capsys)
    assert code == 0 and summary["figures"]["cameras"] == ["left", "right"]
    rig = Rig.load(out)
    np.testing.assert_allclose(summary["figures"]["K_rect"], rig.camera("left").rectification.K_rect)
    kinds = sorted(f["kind"] for f in summary["files"])
    assert kinds == ["image", "image", "rig"]


@pytest.fixture
def patch_csvs(tmp_path, sim):
    train, test = tmp_path / "train.csv", tmp_path / "test.csv"
    write_patch_csv(train, PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train))
    write_patch_csv(test, PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test))
    return train, test


def test_colour_fit_then_export(patch_csvs, tmp_path, capsys):
    train, test = patch_csvs
    fit_path = tmp_path / "nikon.colour.json"
    code, summary, human = run_json(["colour", "fit", "--patches", str(train), "--test-patches", str(test),
                                     "--illuminant", "D65", "--model", "matrix3x3", "--camera-name", "nikon",
                                     "--out", str(fit_path)], capsys)
    assert code == 0 and "CIEDE2000 independent" in human
    fit = load_fit(fit_path)
    for name in ("train", "loo", "test"):
        assert summary["figures"]["delta_E2000"][name]["mean"] == pytest.approx(fit.evaluation[name]["mean"])
    assert summary["figures"]["delta_E2000"]["test"]["n"] == 190
    assert summary["files"] == [{"path": str(fit_path), "kind": "colour fit"}]

    ocio = tmp_path / "ocio"
    code, summary, _ = run_json(["colour", "export", str(fit_path), "--ocio", str(ocio), "--base", "camcal"], capsys)
    assert code == 0 and summary["verb"] == "colour export"
    [space] = summary["figures"]["spaces"]
    assert space["camera"] == "nikon" and space["kind"] == "matrix" and space["bake_error_delta_E2000"] is None
    assert {"path": str(ocio / "config.ocio"), "kind": "ocio config"} in summary["files"]
    assert (ocio / "config.ocio").is_file()


@pytest.fixture
def spectral_inputs(tmp_path):
    """A ColorChecker's spectral patch CSV and patch CSV under D65, and the true curves (Nikon 5100)."""
    from camcal.colour.spectral.data import camera_sensitivities, reflectance_set
    from camcal.colour.spectral.sensitivities import Sensitivities
    from camcal.io.ssf import write_sensitivities

    wl = np.arange(400.0, 701.0, 10.0)
    true = Sensitivities(wl, camera_sensitivities("Nikon 5100 (NPL)", wl)[1], camera="nikon")
    names, R = reflectance_set("BabelColor Average", wl)
    camera = true.camera_under("D65")
    RGB = camera.RGB(R, noise=0.002, seed=3)
    rows = [",".join([n, *(repr(float(v)) for v in (*rgb, *r))]) for n, rgb, r in zip(names, RGB, R)]
    spectral = tmp_path / "chart_spectral.csv"
    spectral.write_text("\n".join(["name,R,G,B," + ",".join(f"{w:g}" for w in wl), *rows]) + "\n")
    chart = tmp_path / "chart.csv"
    write_patch_csv(chart, PatchSet(tuple(names), RGB, camera.XYZ(R)))
    return true, write_sensitivities(tmp_path / "true.ssf.json", true)[0], spectral, chart


def test_colour_sensitivities(spectral_inputs, tmp_path, capsys):
    from camcal.io.ssf import load_sensitivities

    true, true_path, spectral, _ = spectral_inputs
    out = tmp_path / "est.ssf.json"
    code, summary, human = run_json(["colour", "sensitivities", "--patches", f"D65={spectral}", "--compare",
                                     str(true_path), "--out", str(out), "--report", str(tmp_path / "r")], capsys)
    assert code == 0 and summary["verb"] == "colour sensitivities" and "mu-factor (Vora-Trussell)" in human
    est = load_sensitivities(out)
    figures = summary["figures"]
    assert figures["mu_factor"] == pytest.approx(est.mu_factor()) and figures["source"] == "estimated"
    assert figures["compare"]["mu_factor"] == pytest.approx(true.mu_factor())
    assert figures["estimation"]["captures"][0]["n_patches"] == 24
    assert [f["kind"] for f in summary["files"]] == ["sensitivities", "sensitivities csv", "report"]
    assert all(Path(f["path"]).is_file() for f in summary["files"])


def test_colour_fit_for_illuminant(spectral_inputs, tmp_path, capsys):
    _, true_path, _, chart = spectral_inputs
    out = tmp_path / "a.colour.json"
    code, summary, human = run_json(["colour", "fit", "--patches", str(chart), "--illuminant", "D65",
                                     "--for-illuminant", "A", "--sensitivities", str(true_path),
                                     "--model", "matrix3x3", "--out", str(out)], capsys)
    assert code == 0 and summary["verb"] == "colour fit" and "picked" in human
    fit = load_fit(out)
    figures = summary["figures"]
    assert figures["route"] == fit.illuminant_change["route"] and figures["for_illuminant"] == "A"
    assert set(figures["delta_E2000_validation"]) == {"spectral", "CAT02", "Bradford"}
    assert figures["delta_E2000_validation"][figures["route"]]["mean"] == pytest.approx(fit.evaluation["test"]["mean"])
    assert summary["files"] == [{"path": str(out), "kind": "colour fit"}]
