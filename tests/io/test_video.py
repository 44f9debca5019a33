"""Video frames streamed by OpenCV's FFmpeg backend: numbering, --every, undecodable files."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.video import is_video, iter_frames, video_info


@pytest.fixture
def counter_video(tmp_path):
    """Ten MJPG frames whose grey level is 20 x the frame number."""
    path = tmp_path / "count.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48), isColor=False)
    for k in range(10):
        writer.write(np.full((48, 64), 20 * k, np.uint8))
    writer.release()
    return path


def test_frames_numbered_from_zero_and_every(counter_video):
    frames = list(iter_frames(counter_video))
    assert [k for k, _ in frames] == list(range(10))
    assert all(image.shape == (48, 64) and abs(float(image.mean()) - 20 * k) < 2 for k, image in frames)
    assert [k for k, _ in iter_frames(counter_video, every=3)] == [0, 3, 6, 9]
    assert [k for k, _ in iter_frames(counter_video, wanted=lambda k: k > 6)] == [7, 8, 9]
    asked = []
    list(iter_frames(counter_video, wanted=lambda k: asked.append(k) or False))
    assert asked == list(range(10))  # only frames that exist (the count of a video is the last asked + 1)
    info = video_info(counter_video)
    assert info.size == (64, 48) and info.frame_count == 10 and info.fps == 25


def test_undecodable_and_missing_videos_are_one_line(tmp_path):
    assert is_video("a.MP4") and is_video("b.mkv") and not is_video("c.png")
    bad = tmp_path / "bad.mov"
    bad.write_bytes(b"not a video at all" * 50)
    for path in (bad, tmp_path / "missing.mp4"):
        with pytest.raises(CamcalError) as info:
            list(iter_frames(path))
        assert "\n" not in str(info.value) and path.name in str(info.value)
    with pytest.raises(CamcalError):
        list(iter_frames(bad, every=0))
