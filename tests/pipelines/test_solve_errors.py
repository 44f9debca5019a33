"""Bad input to ``camcal solve``: one line naming the problem, a non-zero exit, nothing written."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
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
