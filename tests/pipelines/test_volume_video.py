"""A capture volume recorded as video: six cameras around a two-sided inverted ChArUco board, `calibrate board`.

The must-show command of issue 29 runs exactly as a user types it, in the folder of the rendered videos:
relative rotations and centres against the truth, held-out per-frame RMS against the detector's own error
(the noise floor, measured on the same frames against the true corner projections), and OpenCV 5's
``cv2.calibrateMultiview`` on the same corners.
"""

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.board import frame_number, parse_board
from camcal.model.camera import rotation_angle_deg
from camcal.model.rig import Rig
from camcal.pipelines.board import default_cache_dir, detect_in_video

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import board_origin_pose, make_volume, true_corners, write_videos  # noqa: E402

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided"
N_CAMERAS, N_FRAMES = 6, 48


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Six mp4 videos of 48 frames (640x480) in one folder, the truth, and an intrinsics rig of the true lenses."""
    folder = tmp_path_factory.mktemp("volume")
    board = parse_board(SPEC)
    volume = make_volume(N_CAMERAS, N_FRAMES, radius=0.85)
    paths, seen = write_videos(board, volume, folder)
    Rig(tuple(volume.cameras)).save(folder / "intr.rig.json")
    return folder, board, volume, paths, seen


def test_must_show_command_against_truth_and_calibrate_multiview(recording, monkeypatch, capsys):
    folder, board, volume, paths, seen = recording
    assert all(any(seen[c.name, f] for c in volume.cameras) for f in range(N_FRAMES))
    monkeypatch.chdir(folder)
    cameras = [f"--images=cam{k}=cam_{k}.mp4" for k in range(N_CAMERAS)]
    argv = ["calibrate", "board", "--board", SPEC, *cameras, "--intrinsics", "intr.rig.json",
            "--holdout", "1-47x2", "--out", "rig.rig.json"]
    code = main(argv)
    out = capsys.readouterr().out
    assert code == 0, out
    rig = Rig.load(folder / "rig.rig.json")
    ref = volume.cameras[0]
    rotation_errors, centre_errors = [], []
    for camera, true in zip(rig.cameras, volume.cameras):
        assert camera.name == true.name and np.allclose(camera.K, true.K)  # held
        rotation_errors.append(rotation_angle_deg(camera.R @ (true.R @ ref.R.T).T))
        centre_errors.append(np.linalg.norm(camera.c - ref.R @ (true.c - ref.c)))
    print(f"\nworst rotation error {max(rotation_errors):.4f} deg, worst centre error {max(centre_errors) * 1e3:.3f} mm "
          f"({100 * max(centre_errors) / volume.size_m:.4f} % of the {volume.size_m:.1f} m volume)")
    assert max(rotation_errors) < 0.05
    assert max(centre_errors) < 1e-3 * volume.size_m

    # the noise floor: the detector's error on the held-out frames, against the true projections
    # the command's own corners, from its cache (conftest keeps it in a temporary folder)
    detections = {c.name: detect_in_video(board, p, cache=default_cache_dir()) for c, p in zip(volume.cameras, paths)}
    floors = []
    for camera in volume.cameras:
        errors = []
        for d in detections[camera.name].detections:
            f = frame_number(d.image)
            if f % 2 == 1:
                R_wb, t_wb = board_origin_pose(board, volume.board_R[f], volume.board_t[f])
                errors.append(d.corners_px - true_corners(board, camera, R_wb, t_wb)[d.ids])
        floors.append(float(np.sqrt(np.mean(np.sum(np.concatenate(errors) ** 2, axis=1)))))
    heldout = [camera.quality["heldout_rms_px"] for camera in rig.cameras]
    print(f"held-out RMS per camera {np.round(heldout, 4).tolist()} px; each camera's detector error on those "
          f"frames (its noise floor) {np.round(floors, 4).tolist()} px")
    # each held-out view is posed by PnP (6 unknowns from 12-24 coordinates): at or below its camera's floor
    assert all(h < 1.1 * floor for h, floor in zip(heldout, floors))

    # the peer on the same corners: views with every corner (calibrateMultiview wants whole boards)
    if not hasattr(cv2, "calibrateMultiview"):
        pytest.skip(f"the peer cv2.calibrateMultiview needs OpenCV 5 (checked against the truth above); "
                    f"installed: {cv2.__version__}")
    obj = np.asarray(board.object_points, np.float32)
    frames = sorted({frame_number(d.image) for c in volume.cameras for d in detections[c.name].detections
                     if len(d.ids) == board.n_corners and frame_number(d.image) % 2 == 0})
    mask = np.zeros((N_CAMERAS, len(frames)), np.uint8)
    points = [[np.zeros((board.n_corners, 2), np.float32) for _ in frames] for _ in volume.cameras]
    for i, camera in enumerate(volume.cameras):
        for d in detections[camera.name].detections:
            f = frame_number(d.image)
            if f in frames and len(d.ids) == board.n_corners:
                mask[i, frames.index(f)] = 1
                points[i][frames.index(f)] = d.corners_px.astype(np.float32)
    # OpenCV 5.0's binding refuses given intrinsics (CALIB_USE_INTRINSIC_GUESS: "the camera matrix is not 3x3"
    # for any K passed): the peer fits its own, with the true lens model (no distortion)
    pinhole = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    _, _, _, rvecs, tvecs = cv2.calibrateMultiview([obj] * len(frames), points, [c.image_size for c in volume.cameras],
                                                   mask, np.zeros(N_CAMERAS, np.uint8), None, None, None, None,
                                                   flagsForIntrinsics=np.full(N_CAMERAS, pinhole, np.int32))
    peer_rot, peer_centre = [], []
    for i, true in enumerate(volume.cameras):
        R = cv2.Rodrigues(np.asarray(rvecs[i], np.float64).reshape(3, 1))[0]
        c = -R.T @ np.asarray(tvecs[i], np.float64).reshape(3)
        peer_rot.append(rotation_angle_deg(R @ (true.R @ ref.R.T).T))
        peer_centre.append(np.linalg.norm(c - ref.R @ (true.c - ref.c)))
    print(f"calibrateMultiview on the same corners ({int(mask.sum())} whole views): worst rotation "
          f"{max(peer_rot):.4f} deg, worst centre {max(peer_centre) * 1e3:.3f} mm; ratio peer/ours "
          f"{max(peer_rot) / max(rotation_errors):.3g} (rotation), {max(peer_centre) / max(centre_errors):.3g} (centre)")


def blank_frames(n, size=(640, 480)):
    return [np.full(size[::-1], 150, np.uint8) for _ in range(n)]


def write_avi(path, frames):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (frames[0].shape[1], frames[0].shape[0]),
                             isColor=False)
    for frame in frames:
        writer.write(frame)
    writer.release()


def read_all(path):
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))


def run_bad(argv, folder, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    messages = [line for line in err.splitlines() if line.startswith("camcal:")]  # beside the progress bars
    assert code == 2 and len(messages) == 1 and err.splitlines()[-1].startswith("camcal: error: "), err
    assert not (folder / "rig.rig.json").exists()
    return messages[0]


def test_bad_input_unlinked_cameras_and_undecodable_video(recording, tmp_path, monkeypatch, capsys):
    """Two cameras that never see the board in the same frame; a video FFmpeg cannot decode: one line, exit 2."""
    folder, board, volume, paths, seen = recording
    half = N_FRAMES // 2
    write_avi(tmp_path / "a.avi", read_all(paths[0])[:half] + blank_frames(N_FRAMES - half))
    write_avi(tmp_path / "b.avi", blank_frames(half) + read_all(paths[1])[half:])
    (tmp_path / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    monkeypatch.chdir(tmp_path)
    base = ["calibrate", "board", "--board", SPEC, "--intrinsics", str(folder / "intr.rig.json"),
            "--out", "rig.rig.json"]
    err = run_bad(base + ["--images", "cam0=a.avi", "--images", "cam1=b.avi"], tmp_path, capsys)
    assert "not linked" in err and "cam0 | cam1" in err
    err = run_bad(base + ["--images", "cam0=a.avi", "--images", "cam1=broken.mp4"], tmp_path, capsys)
    assert "broken.mp4" in err and "cannot be decoded" in err
