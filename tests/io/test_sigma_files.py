"""Sigma EXRs beside ST-maps and undistorted images: OpenEXR opens them, they line up pixel for pixel."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.stmap import pixels_from_st
from camcal.geometry.uncertainty import projection_sigma
from camcal.geometry.zhang import calibrate_board
from camcal.io.frames import imwrite
from camcal.io.stmap import read_exr, read_sigma_map
from camcal.model.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from test_uncertainty import BOARD, rendered_scene  # noqa: E402


@pytest.fixture(scope="module")
def rig_file(tmp_path_factory):
    """A camera calibrated from 10 views of corners with independent noise, saved as a rig file."""
    _, detections, _ = rendered_scene(3, 10, size=(320, 240), rendered=False)
    path = tmp_path_factory.mktemp("rig") / "cam.rig.json"
    calibrate_board(BOARD, {"cam": detections}, model="division").rig.save(path)
    return path


def test_rig_keeps_covariance_and_worst_sigma_and_old_rigs_load(rig_file, tmp_path):
    rig = Rig.load(rig_file)
    quality = rig.cameras[0].quality
    assert quality.covariance.names[:4] == ("fx", "fy", "cx", "cy") and quality.covariance.names[-1] == "gauge_tz"
    assert 0 < quality.worst_projection_sigma_px < 5
    assert Rig.load(rig.save(tmp_path / "again.rig.json")) == rig
    data = json.loads(rig_file.read_text())
    del data["cameras"][0]["quality"]["covariance"], data["cameras"][0]["quality"]["worst_projection_sigma_px"]
    (tmp_path / "old.rig.json").write_text(json.dumps(data))
    assert Rig.load(tmp_path / "old.rig.json").cameras[0].quality.covariance is None
    data["cameras"][0]["quality"]["covariance"] = {"names": ["fx"], "matrix": [[1.0, 2.0]]}
    (tmp_path / "bad.rig.json").write_text(json.dumps(data))
    with pytest.raises(Exception, match="covariance.matrix must be 1x1"):
        Rig.load(tmp_path / "bad.rig.json")


def test_sigma_verb_writes_a_one_channel_exr(rig_file, tmp_path, capsys):
    import OpenEXR

    out = tmp_path / "sigma.exr"
    assert main(["sigma", str(rig_file), "--camera", "cam", "--distance", "0.5", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    with OpenEXR.File(str(out)) as exr:
        channels = exr.channels()
        assert list(channels) == ["Y"] and channels["Y"].pixels.shape == (240, 320)
        assert channels["Y"].pixels.dtype == np.float32
    sigma = read_sigma_map(out)
    camera = Rig.load(rig_file).cameras[0]
    assert sigma[17, 33] == pytest.approx(projection_sigma(camera, [[33, 17]], 0.5)[0], rel=1e-3, abs=1e-6)
    assert summary["figures"]["sigma"]["worst_px"] == pytest.approx(float(sigma.max()), rel=1e-6)


def test_stmap_sigma_lines_up_with_the_stmaps(rig_file, tmp_path, capsys):
    """The plate-sized map has the redistort map's pixels; the undistort-side map holds, at each pixel, the
    sigma of the plate pixel the undistort ST-map samples there."""
    assert main(["stmap", str(rig_file), "--camera", "cam", "--out", str(tmp_path), "--sigma"]) == 0
    text = capsys.readouterr().out
    assert "worst" in text and "median" in text and "corners" in text
    camera = Rig.load(rig_file).cameras[0]
    undistort, redistort = read_exr(tmp_path / "cam_undistort.exr"), read_exr(tmp_path / "cam_redistort.exr")
    plate, canvas = read_sigma_map(tmp_path / "cam_sigma.exr"), read_sigma_map(tmp_path / "cam_undistort_sigma.exr")
    assert plate.shape == redistort.shape[:2] and canvas.shape == undistort.shape[:2]
    x, y = pixels_from_st(undistort, camera.image_size)
    for row, col in ((0, 0), (40, 64), (canvas.shape[0] // 2, canvas.shape[1] // 2), (200, 300)):
        source = [[x[row, col], y[row, col]]]
        if not (0 <= source[0][0] <= 319 and 0 <= source[0][1] <= 239):
            continue
        assert canvas[row, col] == pytest.approx(projection_sigma(camera, source)[0], rel=2e-2)
    assert plate[5, 7] == pytest.approx(projection_sigma(camera, [[7, 5]])[0], rel=1e-3)


def test_undistort_sigma_has_the_undistorted_images_size(rig_file, tmp_path):
    imwrite(tmp_path / "cam_000.png", np.zeros((240, 320), np.uint8))
    out = tmp_path / "out"
    assert main(["undistort", str(rig_file), "--camera", "cam", "--images", str(tmp_path / "cam_000.png"), "--out", str(out),
                 "--sigma", "--mode", "keep"]) == 0
    image = read_sigma_map(out / "sigma.exr")
    undistorted = Rig.load(out / "undistorted.rig.json").cameras[0]
    assert image.shape == (undistorted.image_size[1], undistorted.image_size[0])


def test_sigma_verb_help_and_bad_input(rig_file, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["sigma", "--help"])
    assert exit_.value.code == 0
    data = json.loads(rig_file.read_text())
    del data["cameras"][0]["quality"]["covariance"]
    (tmp_path / "old.rig.json").write_text(json.dumps(data))
    assert main(["sigma", str(tmp_path / "old.rig.json"), "--camera", "cam", "--out", str(tmp_path / "s.exr")]) == 2
    assert "no covariance" in capsys.readouterr().err
    assert not (tmp_path / "s.exr").exists()


def test_stmap_report_draws_the_sigma_maps_as_heat_maps(rig_file, tmp_path, capsys):
    """The heat maps are the maps: the colour of a pixel follows its sigma (viridis, 0 at the darkest)."""
    import cv2

    out, report = tmp_path / "maps", tmp_path / "report"
    assert main(["stmap", str(rig_file), "--camera", "cam", "--out", str(out), "--sigma", "--report", str(report),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    plots = [report / "sigma_cam.png", report / "undistort_sigma_cam.png"]
    assert {"path": str(plots[0]), "kind": "report"} in summary["files"]
    for plot in plots:
        image = cv2.imread(str(plot))
        assert image is not None and image.shape[0] > 200 and image.std() > 10
    assert main(["stmap", str(rig_file), "--camera", "cam", "--out", str(tmp_path / "x"), "--report",
                 str(tmp_path / "r")]) == 2
    assert "give --sigma too" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_heat_map_follows_the_values(tmp_path):
    """A ramp drawn as a heat map: the image's brightness rises along the ramp (viridis is ordered in lightness)."""
    import cv2

    from camcal.report.sigma import plot_sigma_map

    ramp = np.tile(np.linspace(0.0, 1.0, 200, dtype=np.float32), (100, 1))
    ramp[:, :20] = np.nan
    image = cv2.imread(str(plot_sigma_map(ramp, tmp_path / "ramp.png", "ramp")), cv2.IMREAD_GRAYSCALE)
    row = image[image.shape[0] // 2].astype(float)
    dark = np.argmin(row[: image.shape[1] // 2])
    assert row[dark] < 80 and row.max() > 180


def test_sigma_verb_heatmap_is_pixel_for_pixel(rig_file, tmp_path, capsys):
    import cv2

    from camcal.report.sigma import heatmap_image

    out, png = tmp_path / "sigma.exr", tmp_path / "sigma.png"
    assert main(["sigma", str(rig_file), "--camera", "cam", "--out", str(out), "--heatmap", str(png), "--json"]) == 0
    assert {"path": str(png), "kind": "heatmap"} in json.loads(capsys.readouterr().out)["files"]
    rgb = cv2.imread(str(png))[..., ::-1]
    assert rgb.shape == (240, 320, 3)
    assert np.array_equal(rgb, heatmap_image(read_sigma_map(out)))
