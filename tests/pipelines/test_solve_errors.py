"""Bad input to ``camcal solve``: one line naming the problem, a non-zero exit, nothing written."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import camcal
from camcal.base.errors import CamcalError
from camcal.cli import build_parser, main
from camcal.geometry.sfm import check_every_camera_registered
from camcal.pipelines.solve import solve_sfm
from camcal.synthetic import render_stereo_sequence


def _reconstruction(registered: dict[str, int], unregistered: dict[str, int]):
    """A reconstruction-like object: ``camera/<k>.png`` images, the first ``registered[camera]`` with a pose."""
    images = {}
    for camera in registered.keys() | unregistered.keys():
        for k in range(registered.get(camera, 0) + unregistered.get(camera, 0)):
            images[len(images) + 1] = SimpleNamespace(name=f"{camera}/{k:06d}.png",
                                                      has_pose=k < registered.get(camera, 0))
    return SimpleNamespace(images=images)


def test_a_camera_with_no_registered_image_is_named_with_its_count():
    counts = {"left": 5, "middle": 5, "right": 4}
    check_every_camera_registered(_reconstruction({"left": 5, "middle": 1, "right": 4}, {"middle": 4}), counts)
    with pytest.raises(CamcalError) as caught:
        check_every_camera_registered(_reconstruction({"left": 5}, {"middle": 5, "right": 4}), counts)
    message = str(caught.value)
    assert "\n" not in message and "'left'" not in message
    assert "'middle' (0 of 5 images)" in message and "'right' (0 of 4 images)" in message
    assert "--mask" in message and "overlap" in message
    # a camera the pass never saw (no feature at all) is as unregistered as one it saw without a pose
    with pytest.raises(CamcalError, match=r"'right' \(0 of 4 images\)"):
        check_every_camera_registered(_reconstruction({"left": 5, "middle": 5}, {}), counts)


def test_a_rig_whose_second_camera_sees_only_noise_stops_before_the_rig_with_nothing_written(tmp_path):
    width = 256
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(tmp_path / "in", n_frames=5, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    rng = np.random.default_rng(0)
    for path in sorted((tmp_path / "in" / "right").iterdir()):  # features, but none shared with any other image
        noise = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        assert cv2.imwrite(str(path), cv2.GaussianBlur(noise, (3, 3), 1.0))
    with pytest.raises(CamcalError, match=r"no image of camera 'right' \(0 of 5 images\)"):
        solve_sfm({"left": tmp_path / "in" / "left", "right": tmp_path / "in" / "right"}, tmp_path / "out",
                  max_num_features=512)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_frames_go_with_a_plate_given_as_folder_or_images_entry():
    parser = build_parser()
    by_folder = parser.parse_args(["solve", "plates/left.%04d.exr", "plates/right.####.dpx", "--frames", "1-3",
                                   "--out", "s"])
    by_images = parser.parse_args(["solve", "plates", "--images", "left=left.%04d.exr", "right=right.%04d.exr",
                                   "--frames", "1-3", "--out", "s"])
    assert by_folder.frames == by_images.frames == "1-3"


def test_api_refuses_frames_without_a_plate(tmp_path):
    (tmp_path / "left").mkdir()
    with pytest.raises(CamcalError, match="frames '1-3' given, but no folder or images entry is a plate"):
        camcal.solve([tmp_path / "left"], tmp_path / "out", frames="1-3")
    with pytest.raises(CamcalError, match="frames '1-3' given, but no folder or images entry is a plate"):
        camcal.solve(tmp_path, tmp_path / "out", images={"left": "*_L.png"}, frames="1-3")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["left"]


def _write(path, size, rng):
    assert cv2.imwrite(str(path), rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))


BROKEN_MOVIE = b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8


def _empty_folder(root, rng):
    (root / "empty").mkdir()
    return ["empty"], "no images (.jpg", "empty"


def _empty_glob(root, rng):
    (root / "flat").mkdir()
    for name in ("a_L.png", "b_L.png"):
        _write(root / "flat" / name, (64, 48), rng)
    return ["flat", "--images", "left=*_L.png", "right=*_R.png"], "--images right=*_R.png: no image matches", "flat"


def _broken_movie(root, rng):
    (root / "flat").mkdir()
    (root / "flat" / "left.mp4").write_bytes(BROKEN_MOVIE)
    (root / "flat" / "right.mp4").write_bytes(BROKEN_MOVIE)
    return ["flat", "--images", "left=left.mp4", "right=right.mp4"], "left.mp4: cannot be decoded as a video", "flat"


def _plate_of_two_sizes(root, rng):
    (root / "plates").mkdir()
    for camera in ("left", "right"):
        for frame in range(1001, 1005):
            _write(root / "plates" / f"{camera}.{frame:04d}.png",
                   (160, 100) if (camera, frame) == ("right", 1003) else (160, 120), rng)
    return (["plates/left.%04d.png", "plates/right.%04d.png", "--features", "200"],
            "camera 'right': plates/right.1003.png is 160x100 but plates/right.1001.png is 160x120", "plates")


@pytest.mark.parametrize("make", [_empty_folder, _empty_glob, _broken_movie, _plate_of_two_sizes],
                         ids=lambda make: make.__name__.strip("_"))
def test_bad_images_are_one_line_exit_2_and_nothing_written(make, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv, reason, given = make(tmp_path, np.random.default_rng(0))
    assert main(["solve", *argv, "--out", "out"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("camcal solve: ")]
    assert len(errors) == 1 and errors[0].startswith("camcal: error: ") and reason in errors[0], errors
    assert sorted(p.name for p in tmp_path.iterdir()) == [given]
