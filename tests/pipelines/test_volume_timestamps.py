"""Cameras that started recording at different times, synchronised by a timestamps CSV: `calibrate board --timestamps`.

Four cameras around a two-sided inverted ChArUco board; camera k starts recording `OFFSETS[k]` frames after the
first and camera 2 loses one frame, so frame k of one video is not frame k of another: matched by index the rig is
wrong, matched by time (the CSV, with a few ms of clock jitter) it is the truth.
"""

import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.board import parse_board
from camcal.model.camera import rotation_angle_deg
from camcal.model.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import board_origin_pose, board_texture, make_volume, render_view  # noqa: E402

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided"
N_TICKS, LENGTH, FPS = 38, 32, 30.0
OFFSETS = (0, 4, 2, 6)
LOST = {2: 10}  # camera 2 loses its 10th frame: its later frames are one tick further on


def ticks_of(k):
    ticks = [OFFSETS[k] + n for n in range(LENGTH + (1 if k in LOST else 0))]
    if k in LOST:
        del ticks[LOST[k]]
    return ticks


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Four mp4 videos of 32 frames, the timestamps CSV, the true rig as intrinsics, the volume."""
    folder = tmp_path_factory.mktemp("offsets")
    board = parse_board(SPEC)
    volume = make_volume(len(OFFSETS), N_TICKS, radius=0.85, seed=6)
    texture = board_texture(board)
    rng = np.random.default_rng(9)
    lines = ["camera,frame,time"]
    for k, camera in enumerate(volume.cameras):
        writer = cv2.VideoWriter(str(folder / f"cam_{k}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), FPS,
                                 camera.image_size, isColor=False)
        for frame, tick in enumerate(ticks_of(k)):
            R_wb, t_wb = board_origin_pose(board, volume.board_R[tick], volume.board_t[tick])
            image = render_view(board, texture, camera, R_wb, t_wb, rng)
            if image is None:
                image = np.clip(150 + rng.normal(0, 2.0, camera.image_size[::-1]), 0, 255).astype(np.uint8)
            writer.write(image)
            lines.append(f"cam{k},{frame},{1000.0 + tick / FPS + rng.uniform(-0.004, 0.004):.6f}")
        writer.release()
    (folder / "ts.csv").write_text("\n".join(lines) + "\n")
    Rig(tuple(volume.cameras)).save(folder / "intr.rig.json")
    return folder, volume


def rig_errors(rig, volume):
    ref = volume.cameras[0]
    rotations = [rotation_angle_deg(c.R @ (t.R @ ref.R.T).T) for c, t in zip(rig.cameras, volume.cameras)]
    centres = [float(np.linalg.norm(c.c - ref.R @ (t.c - ref.c))) for c, t in zip(rig.cameras, volume.cameras)]
    return max(rotations), max(centres)


def command(*extra):
    cameras = [f"--images=cam{k}=cam_{k}.mp4" for k in range(len(OFFSETS))]
    return ["calibrate", "board", "--board", SPEC, *cameras, "--intrinsics", "intr.rig.json", "--out", "rig.rig.json",
            *extra]


@pytest.mark.slow
def test_timestamps_synchronise_cameras_that_started_apart(recording, monkeypatch, capsys):
    folder, volume = recording
    monkeypatch.chdir(folder)
    code = main(command("--timestamps", "ts.csv", "--holdout", "1-31x4"))
    out = capsys.readouterr().out
    assert code == 0, out
    rotation, centre = rig_errors(Rig.load("rig.rig.json"), volume)
    with capsys.disabled():
        print(f"\n{out}by time: worst rotation {rotation:.4f} deg, worst centre {centre * 1e3:.3f} mm "
              f"({100 * centre / volume.size_m:.4f} % of {volume.size_m:.1f} m)")
    assert rotation < 0.05 and centre < 1e-3 * volume.size_m
    # cam1 started 4 frames late: its last 4 frames have no frame of cam0 (which ends at tick 31)
    assert "cam1: " in out and "dropped" in out
    dropped = {line.split(":")[0].strip(): int(line.split("kept, ")[1].split(" dropped")[0])
               for line in out.splitlines() if " views kept, " in line}
    # views dropped are those whose tick cam0 never recorded (the board seen in them)
    assert dropped["cam0"] == 0 and dropped["cam1"] <= OFFSETS[1] and dropped["cam3"] <= OFFSETS[3]
    assert dropped["cam3"] > 0

    # by index, the same videos give a broken rig (or one the quality gate refuses)
    Path("rig.rig.json").unlink()
    code = main(command())
    printed = capsys.readouterr()
    with capsys.disabled():
        print(f"by index: exit {code}, {(printed.err.strip().splitlines() or [''])[-1]}")
    if code == 0:
        rotation_index, _ = rig_errors(Rig.load("rig.rig.json"), volume)
        with capsys.disabled():
            print(f"by index: worst rotation {rotation_index:.2f} deg")
        assert rotation_index > 1.0
        Path("rig.rig.json").unlink()


def run_bad(argv, folder, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    messages = [line for line in err.splitlines() if line.startswith("camcal:")]
    assert code == 2 and len(messages) == 1 and err.splitlines()[-1].startswith("camcal: error: "), err
    assert not (folder / "rig.rig.json").exists()
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == []  # no temporary left
    return messages[0]


def time_of(camera, frame, value):
    """The timestamps text with one time replaced."""
    return lambda text: re.sub(rf"^{camera},{frame},.*$", f"{camera},{frame},{value}", text, flags=re.M)


@pytest.mark.parametrize("edit, message", [
    (lambda text: text.replace("cam3,", "cam7,"), "unknown camera 'cam7'"),
    (lambda text: text + "cam1,32,1099.0\n", "frame 32 is beyond its video cam_1.mp4 (32 frames"),
    (time_of("cam2", 5, "soon"), "the time must be a number"),
    (time_of("cam2", 5, "nan"), "line 71: the time is 'nan', not a finite number"),
    (time_of("cam2", 5, "0.0"), "times of camera 'cam2' do not increase with its frames (frame 4 at"),
    (lambda text: text.replace("camera,frame,time", "camera;frame;time"), "expected the header"),
    (lambda text: "\n".join(line for line in text.splitlines() if not line.startswith("cam2,")) + "\n",
     "no timestamps for camera 'cam2'"),
])
def test_timestamps_that_do_not_match_are_one_line(recording, tmp_path, monkeypatch, capsys, edit, message):
    """A timestamps file that does not match the videos or cannot be read: one line naming it, exit 2, no rig."""
    folder, _ = recording
    for path in folder.glob("*.mp4"):
        (tmp_path / path.name).symlink_to(path)
    (tmp_path / "intr.rig.json").symlink_to(folder / "intr.rig.json")
    (tmp_path / "ts.csv").write_text(edit((folder / "ts.csv").read_text()))
    monkeypatch.chdir(tmp_path)
    line = run_bad(command("--timestamps", "ts.csv"), tmp_path, capsys)
    assert message in line, line


def test_time_tolerance_needs_timestamps(recording, monkeypatch, capsys):
    folder, _ = recording
    monkeypatch.chdir(folder)
    assert "--time-tolerance needs --timestamps" in run_bad(command("--time-tolerance", "0.01"), folder, capsys)


def test_every_keeps_the_views_matched_to_the_first_cameras_kept_frames(tmp_path):
    """--every 2 with cam1 one frame late: cam1's views kept are its odd frames (matched to cam0's even ones)."""
    from camcal.geometry.board import Detection, DetectionReport, frame_number, video_frame_label
    from camcal.io.timestamps import read_timestamps
    from camcal.pipelines.board import synchronise_detections

    (tmp_path / "ts.csv").write_text("camera,frame,time\n" + "".join(
        f"cam{c},{k},{(k + c) / 30:.6f}\n" for c in range(2) for k in range(10)))

    def report(video, frames):
        views = tuple(Detection(video_frame_label(video, k), (64, 48), np.arange(6), np.zeros((6, 2)), "synthetic")
                      for k in frames)
        return DetectionReport(views, (), 10)

    reports = {"cam0": report("a.mp4", range(0, 10, 2)), "cam1": report("b.mp4", range(10))}
    detections, sync, dropped = synchronise_detections(reports, read_timestamps(tmp_path / "ts.csv"), every=2)
    assert [frame_number(d.image) for d in detections["cam0"]] == [0, 2, 4, 6, 8]
    assert [d.image for d in detections["cam1"]] == [f"b.mp4#{k}@{k + 1}" for k in (1, 3, 5, 7)]
    assert dropped == {"cam0": 0, "cam1": 1}  # cam1's frame 9 is at cam0's frame 10, which cam0 never recorded
    assert sync.offsets_s["cam1"] == pytest.approx(0.0, abs=1e-6)


def test_image_cameras_synchronise_by_the_number_in_their_file_names(tmp_path):
    """Images: frame k is the number in the file name; a camera without the board in a frame is no error."""
    from camcal.geometry.board import Detection, DetectionReport, frame_number
    from camcal.io.timestamps import read_timestamps
    from camcal.pipelines.board import synchronise_detections

    (tmp_path / "ts.csv").write_text("camera,frame,time\n" + "".join(
        f"{name},{k},{t0 + k / 24:.6f}\n" for name, t0 in (("left", 0.0), ("right", 0.125)) for k in range(1, 9)))

    def report(prefix, frames):
        return DetectionReport(tuple(Detection(f"{prefix}{k:02d}.png", (64, 48), np.arange(6), np.zeros((6, 2)),
                                               "synthetic") for k in frames), ())

    reports = {"left": report("left", range(1, 9)), "right": report("right", (1, 2, 4, 5))}
    detections, sync, dropped = synchronise_detections(reports, read_timestamps(tmp_path / "ts.csv"))
    # right starts 3 frames (0.125 s) late: its frame k is left's frame k + 3; its frames 6-8 have no match
    assert [(d.image, frame_number(d.image)) for d in detections["right"]] == [
        ("right01.png@4", 4), ("right02.png@5", 5), ("right04.png@7", 7), ("right05.png@8", 8)]
    assert dropped == {"left": 0, "right": 0} and sync.offsets_s["right"] == pytest.approx(0.0, abs=1e-6)
