"""``solve`` on plates (an EXR and a DPX sequence) gives the rig it gives on the same pixels as PNG folders."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

oiio = pytest.importorskip("OpenImageIO")
colour = pytest.importorskip("colour")

from camcal.base.atomic import TEMPORARY_TAG  # noqa: E402
from camcal.cli import main  # noqa: E402
from camcal.pipelines.solve import collect_images, solve_sfm  # noqa: E402
from camcal.synthetic import render_stereo_sequence  # noqa: E402

FIRST = 1001
ROOT = Path(__file__).resolve().parents[2]


def _numbers(value, key=""):
    if isinstance(value, dict):
        for name, item in value.items():
            yield from _numbers(item, f"{key}.{name}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _numbers(item, f"{key}[{index}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield key, value


def _to_plates(folder, plates):
    """left: scene-linear float EXR (the sRGB decoding of the 8-bit codes); right: 16-bit DPX (codes x 257)."""
    plates.mkdir()
    for index, png in enumerate(sorted((folder / "left").iterdir())):
        codes = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        linear = np.ascontiguousarray(colour.models.eotf_sRGB(codes / 255.0).astype(np.float32))
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"Y": linear}) as exr:
            exr.write(str(plates / f"left.{FIRST + index:04d}.exr"))
    for index, png in enumerate(sorted((folder / "right").iterdir())):
        codes = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        path = str(plates / f"right.{FIRST + index:04d}.dpx")
        out = oiio.ImageOutput.create(path)
        assert out.open(path, oiio.ImageSpec(codes.shape[1], codes.shape[0], 1, "uint16"))
        assert out.write_image((codes.astype(np.uint16) * 257)[:, :, None])
        out.close()


def _rendered_plates(tmp_path, n_frames):
    """A rendered stereo sequence (256 px wide, PNG under ``in/``) and its plates (``plates/``): (width, height)."""
    width = 256
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(tmp_path / "in", n_frames=n_frames, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    _to_plates(tmp_path / "in", tmp_path / "plates")
    return width, height


@pytest.mark.slow
def test_plates_solve_to_the_rig_of_the_same_pixels_as_png(tmp_path):
    """Two solves; the fast sibling below solves a plate through the command line."""
    _rendered_plates(tmp_path, 5)
    last = f"{FIRST}-{FIRST + 4}"
    plates = collect_images([tmp_path / "plates" / "left.%04d.exr", tmp_path / "plates" / "right.####.dpx"], frames=last)
    assert list(plates) == ["left", "right"] and [p.name for p in plates["right"]][-1] == f"right.{FIRST + 4}.dpx"
    solve_sfm(plates, tmp_path / "from_plates", max_num_features=512)
    solve_sfm({"left": tmp_path / "in/left", "right": tmp_path / "in/right"}, tmp_path / "from_png",
              max_num_features=512)
    staged = sorted((tmp_path / "from_plates" / "images" / "left").iterdir())
    assert [p.suffix for p in staged] == [".png"] * 5  # decoded, not linked
    for staged_png, png in zip(staged, sorted((tmp_path / "in" / "left").iterdir())):
        np.testing.assert_array_equal(cv2.imread(str(staged_png), cv2.IMREAD_UNCHANGED),
                                      cv2.imread(str(png), cv2.IMREAD_UNCHANGED))
    a = dict(_numbers(json.loads((tmp_path / "from_plates/solve.rig.json").read_text())))
    b = dict(_numbers(json.loads((tmp_path / "from_png/solve.rig.json").read_text())))
    assert set(a) == set(b) and any(".K" in key or "fx" in key for key in a)
    for key in a:
        assert abs(a[key] - b[key]) <= 1e-9 * max(1.0, abs(a[key]), abs(b[key])), (key, a[key], b[key])
    frames = json.loads((tmp_path / "from_plates/solve.rig.json").read_text())["frames"]
    assert any("left.1001.exr" in json.dumps(frame) for frame in frames)  # the rig points at the plate's files


def test_solve_cli_takes_a_plate_by_camera_and_frame_range(tmp_path, monkeypatch, capsys):
    """--images NAME=PATTERN with --frames: the frames outside the range are not used, the staged frames hold
    the pixels the EXR's linear values encode."""
    monkeypatch.chdir(tmp_path)
    _rendered_plates(tmp_path, 4)
    code = main(["solve", "plates", "--images", "left=left.####.exr", "--frames", f"{FIRST}-{FIRST + 2}",
                 "--features", "512", "--no-refine", "--out", "out"])
    assert code == 0, capsys.readouterr().err
    assert "registered 3 / 3 images" in capsys.readouterr().out
    staged = sorted((tmp_path / "out" / "images" / "left").iterdir())
    for staged_png, png in zip(staged, sorted((tmp_path / "in" / "left").iterdir())[:3], strict=True):
        np.testing.assert_array_equal(cv2.imread(str(staged_png), cv2.IMREAD_UNCHANGED),
                                      cv2.imread(str(png), cv2.IMREAD_UNCHANGED))


def _keypoint_x(database_path):
    import pycolmap

    database = pycolmap.Database.open(database_path)
    try:
        return {image.name: database.read_keypoints(image.image_id)[:, 0] for image in database.read_all_images()}
    finally:
        database.close()


def test_mattes_keep_features_out_of_their_white_part(tmp_path, monkeypatch, capsys):
    """A matte sequence white over the left 40 % of the frames: no feature is taken there, while the same
    solve without it has features across the whole width."""
    monkeypatch.chdir(tmp_path)
    width, height = _rendered_plates(tmp_path, 4)
    (tmp_path / "mattes").mkdir()
    edge = int(0.4 * width)
    for frame in range(FIRST, FIRST + 4):
        matte = np.zeros((height, width, 4), np.float32)
        matte[:, :edge, 3] = 1.0  # alpha on: an actor over the left part
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION},
                          {name: np.ascontiguousarray(matte[..., i]) for i, name in enumerate("RGBA")}) as exr:
            exr.write(str(tmp_path / "mattes" / f"left.{frame}.exr"))
    command = ["solve", "plates/left.####.exr", "--frames", f"{FIRST}-{FIRST + 3}", "--features", "512", "--no-refine"]
    for out, mask in (("masked", ["--mask", "left=mattes/left.####.exr"]), ("unmasked", [])):
        assert main(command + mask + ["--out", out]) == 0, capsys.readouterr().err
    masked, unmasked = _keypoint_x(tmp_path / "masked" / "database.db"), _keypoint_x(tmp_path / "unmasked" / "database.db")
    assert len(masked) == len(unmasked) == 4
    for name, x in masked.items():  # COLMAP's keypoints: x = 0 at the left edge of the first pixel column
        assert len(x) > 50 and x.min() >= edge, (name, x.min())
        assert unmasked[name].min() < 0.5 * edge, (name, unmasked[name].min())


@pytest.mark.parametrize("problem", ["count", "size"])
def test_mattes_that_do_not_fit_the_images_are_one_error_and_nothing_is_written(tmp_path, problem):
    from camcal.base.errors import CamcalError

    render_stereo_sequence(tmp_path / "in", n_frames=3, image_size=(96, 72),
                           K=((75.0, 0.0, 47.5), (0.0, 75.0, 35.5), (0.0, 0.0, 1.0)))
    images = sorted((tmp_path / "in" / "left").iterdir())
    mattes = []
    for index in range(2 if problem == "count" else 3):
        mattes.append(tmp_path / f"matte.{index}.png")
        cv2.imwrite(str(mattes[-1]), np.zeros((72, 96 if problem == "count" else 95), np.uint8))
    stale = tmp_path / f".out.{TEMPORARY_TAG}.k1ll3d00"  # what a killed solve left: its staging folder
    (stale / "images").mkdir(parents=True)
    (stale / "database.db").write_bytes(b"partial")
    (tmp_path / ".out.notes").write_text("not camcal's")
    message = "has 3 images but 2 mattes" if problem == "count" else r"is 95x72 px but its image .* is 96x72"
    with pytest.raises(CamcalError, match=message):
        solve_sfm({"left": images}, tmp_path / "out", masks={"left": mattes})
    assert not (tmp_path / "out").exists() and sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["in", ".out.notes"] + [p.name for p in mattes])


@pytest.mark.slow
def test_solve_killed_mid_run_then_rerun_leaves_the_uninterrupted_result(tmp_path):
    """SIGKILL during feature extraction leaves the staging folder; the rerun removes it and writes what an
    uninterrupted run writes (the slow sibling of the stale-folder check above)."""
    _rendered_plates(tmp_path, 5)
    command = [sys.executable, "-m", "camcal", "solve", "plates/left.####.exr", "--features", "512",
               "--out", "out"]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    process = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not list(tmp_path.glob(f".out.{TEMPORARY_TAG}.*/images/left/*.png")):
            assert process.poll() is None, "the solve ended before it was killed"
            time.sleep(0.01)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
    assert not (tmp_path / "out").exists() and len(list(tmp_path.glob(f".out.{TEMPORARY_TAG}.*"))) == 1
    subprocess.run(command, cwd=tmp_path, env=env, check=True, capture_output=True)
    subprocess.run(command[:-1] + ["uninterrupted"], cwd=tmp_path, env=env, check=True, capture_output=True)
    assert not [p for p in tmp_path.iterdir() if TEMPORARY_TAG in p.name]
    a = dict(_numbers(json.loads((tmp_path / "out/solve.rig.json").read_text())))
    b = dict(_numbers(json.loads((tmp_path / "uninterrupted/solve.rig.json").read_text())))
    assert set(a) == set(b) and all(abs(a[k] - b[k]) <= 1e-9 * max(1.0, abs(a[k]), abs(b[k])) for k in a)
