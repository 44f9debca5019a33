"""Timestamps CSV (camera,frame,time) and the synchronisation of cameras by nearest time."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.timestamps import read_timestamps, synchronise


def write(tmp_path, text, name="ts.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def rows(camera, frames, times):
    return "".join(f"{camera},{k},{float(t)!r}\n" for k, t in zip(frames, times))


def test_offsets_rates_and_drops_against_the_constructed_clock(tmp_path):
    """cam0 at 30 fps from t = 10 s; cam1 starts 7 frames later with 3 ms of jitter and drops a frame;
    cam2 runs at 60 fps: each frame is matched to cam0's frame nearest in time, within half a period."""
    rng = np.random.default_rng(1)
    period = 1 / 30
    t0 = 10 + period * np.arange(40)
    frames1 = [k for k in range(30) if k != 12]  # frame 12 of the recorder lost: numbers jump
    t1 = 10 + period * (7 + np.arange(31))[frames1] + rng.uniform(-0.003, 0.003, len(frames1))
    t2 = 10 - 0.2 + np.arange(100) / 60
    path = write(tmp_path, "camera,frame,time\n" + rows("cam0", range(40), t0)
                 + rows("cam1", range(len(frames1)), t1) + rows("cam2", range(100), t2))
    timestamps = read_timestamps(path)
    assert set(timestamps.times) == {"cam0", "cam1", "cam2"}
    assert timestamps.period("cam0") == pytest.approx(period)
    sync = synchronise(timestamps, ["cam0", "cam1", "cam2"])
    assert sync.reference == "cam0" and sync.tolerance_s == pytest.approx(period / 2)
    assert sync.numbers["cam0"] == {k: k for k in range(40)}
    # cam1's n-th row is its frame n, recorded at cam0's frame 7 + frames1[n]
    assert sync.numbers["cam1"] == {n: 7 + k for n, k in enumerate(frames1)}
    assert sync.offsets_s["cam1"] == pytest.approx(0.0, abs=0.003)
    # cam2 at 60 fps: frame m at 9.8 + m / 60 s = cam0's frame (m - 12) / 2; odd m are halfway between two of
    # cam0's frames (a tie: the earlier) and lose to the even frame on the same cam0 frame
    expected = {m: (m - 12) // 2 for m in range(12, 92, 2)}
    assert sync.numbers["cam2"] == expected
    # a tighter tolerance drops cam1's jittered frames beyond it
    tight = synchronise(timestamps, ["cam0", "cam1", "cam2"], tolerance_s=0.001)
    jitter = np.abs(t1 - (10 + period * (7 + np.array(frames1))))
    assert set(tight.numbers["cam1"]) == {n for n in range(len(frames1)) if jitter[n] <= 0.001}


@pytest.mark.parametrize("text, message", [
    ("", "expected the header camera,frame,time"),
    ("cam,frame,t\ncam0,0,0.0\n", "expected the header"),
    ("camera,frame,time\n", "no timestamps"),
    ("camera,frame,time\ncam0,0\n", "line 2: expected 3 values"),
    ("camera,frame,time\ncam0,0,0.0,1\n", "line 2: expected 3 values"),
    ("camera,frame,time\ncam0,-1,0.0\n", "line 2: the frame must be a whole number"),
    ("camera,frame,time\ncam0,1.5,0.0\n", "line 2: the frame must be a whole number"),
    ("camera,frame,time\ncam0," + "9" * 40 + ",0.0\n", "the frame must be a whole number"),
    ("camera,frame,time\ncam0,0,0.0\ncam0,1,nan\n", "line 3: the time is 'nan'"),
    ("camera,frame,time\ncam0,0,inf\n", "not a finite number"),
    ("camera,frame,time\ncam0,0,soon\n", "the time must be a number"),
    ("camera,frame,time\n,0,0.0\n", "the camera name is empty"),
    ("camera,frame,time\ncam0,0,0.0\ncam0,0,0.1\n", "frame 0 given twice"),
    ("camera,frame,time\ncam0,0,0.0\ncam0,1,0.2\ncam0,2,0.1\n", "do not increase with its frames (frame 1 at 0.2"),
    ("camera,frame,time\ncam0,0,0.0\ncam0,1,0.0\n", "do not increase"),
    ('camera,frame,time\n"cam0,0,0.0\n', "expected 3 values"),
])
def test_bad_files_are_one_line_naming_the_problem(tmp_path, text, message):
    with pytest.raises(CamcalError) as info:
        read_timestamps(write(tmp_path, text))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_bad_bytes_missing_file_and_cameras_that_do_not_match(tmp_path):
    for path, message in ((write(tmp_path, "x", "a.csv").with_name("missing.csv"), "not found"),):
        with pytest.raises(CamcalError, match=message):
            read_timestamps(path)
    bad = tmp_path / "bytes.csv"
    bad.write_bytes(b"camera,frame,time\n\xffcam0,0,0\n")
    with pytest.raises(CamcalError, match="not UTF-8"):
        read_timestamps(bad)
    timestamps = read_timestamps(write(tmp_path, "camera,frame,time\ncam0,0,0\ncam0,1,0.04\ncam9,0,0\ncam9,1,0.04\n"))
    with pytest.raises(CamcalError, match="unknown camera 'cam9'"):
        synchronise(timestamps, ["cam0", "cam1"])
    with pytest.raises(CamcalError, match="no timestamps for camera 'cam1'"):
        synchronise(timestamps, ["cam0", "cam9", "cam1"])
    with pytest.raises(CamcalError, match=r"frame 1 is beyond its video v.mp4 \(1 frames"):
        timestamps.check_frames("cam9", 1, "v.mp4")
    with pytest.raises(CamcalError, match="positive"):
        synchronise(timestamps, ["cam0", "cam9"], tolerance_s=-1.0)


def test_file_size_cap(tmp_path, monkeypatch):
    monkeypatch.setenv("CAMCAL_MAX_FILE_BYTES", "20")
    with pytest.raises(CamcalError, match="over the cap"):
        read_timestamps(write(tmp_path, "camera,frame,time\ncam0,0,0.0\n"))
