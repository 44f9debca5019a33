"""Videos wherever a verb takes a camera's images: undistort, distortion fit, rectify (streamed, --every N).

The peer is the same verb on the same frames given as image files (decoded by OpenCV and written losslessly):
the outputs must be the same pixels and the same fitted lens; the lens also against the truth it was rendered with.
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.board import parse_board
from camcal.io.video import frame_file_name
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig
from camcal.synthetic import example_camera

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import make_volume, write_videos  # noqa: E402

LAMBDA = -8e-7  # division model, 1/px^2


def decoded(video):
    """Every frame of a video as OpenCV decodes it (BGR)."""
    capture = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(frame)


@pytest.fixture(scope="module")
def chessboard_videos(tmp_path_factory):
    """Two cameras with a division lens around a moving 9x6 chessboard (MJPG .avi), the rig, the frames as PNGs."""
    folder = tmp_path_factory.mktemp("video_verbs")
    board = parse_board("chessboard:9x6:0.04")
    volume = make_volume(4, 12, radius=0.8, seed=2, distortion=Distortion("division", {"lambda": LAMBDA}))
    volume.cameras = volume.cameras[:2]
    paths, seen = write_videos(board, volume, folder, fourcc="MJPG", suffix=".avi")
    Rig(tuple(volume.cameras)).save(folder / "rig.rig.json")
    for path in paths:
        (folder / "png" / path.stem).mkdir(parents=True)
        (folder / "grey" / path.stem).mkdir(parents=True)
        for k, frame in enumerate(decoded(path)):
            cv2.imwrite(str(folder / "png" / path.stem / frame_file_name(path, k)), frame)
            cv2.imwrite(str(folder / "grey" / path.stem / frame_file_name(path, k)),
                        cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    return folder, paths, seen


def test_undistort_a_video_as_its_frames(chessboard_videos, capsys):
    folder, paths, _ = chessboard_videos
    rig = str(folder / "rig.rig.json")
    out_video, out_images = folder / "u_video", folder / "u_images"
    assert main(["undistort", rig, "--camera", "cam0", "--images", str(paths[0]), "--every", "3", "--out", str(out_video)]) == 0
    frames = [folder / "png" / "cam_0" / frame_file_name(paths[0], k) for k in range(0, 12, 3)]
    assert main(["undistort", rig, "--camera", "cam0", "--images", *map(str, frames), "--out", str(out_images)]) == 0
    assert "undistorted 4 frame(s)" in capsys.readouterr().out
    written = sorted(p.name for p in out_video.glob("*.png"))
    assert written == [p.name for p in frames]
    for name in written:
        assert np.array_equal(cv2.imread(str(out_video / name), cv2.IMREAD_UNCHANGED),
                              cv2.imread(str(out_images / name), cv2.IMREAD_UNCHANGED))
    from_video, from_images = Rig.load(out_video / "undistorted.rig.json"), Rig.load(out_images / "undistorted.rig.json")
    assert from_video.cameras == from_images.cameras
    # the provenance's time stamp is the one thing that varies between runs
    assert {**from_video.provenance, "created": None} == {**from_images.provenance, "created": None}
    # images and videos are not mixed; a bad --every is one line
    assert main(["undistort", rig, "--camera", "cam0", "--images", str(paths[0]), str(frames[0]), "--out", str(folder / "x")]) == 2
    assert main(["undistort", rig, "--camera", "cam0", "--images", str(paths[0]), "--every", "0", "--out", str(folder / "x")]) == 2
    assert not (folder / "x").exists()


def test_distortion_fit_from_a_video_as_from_its_frames(chessboard_videos, capsys):
    folder, paths, seen = chessboard_videos
    out_video, out_images = folder / "lens_video.json", folder / "lens_images.json"
    assert main(["distortion", "fit", "--images", str(paths[1]), "--board", "chessboard:9x6", "--out", str(out_video)]) == 0
    from_video = capsys.readouterr().out
    frames = sorted((folder / "grey" / "cam_1").glob("*.png"))
    assert main(["distortion", "fit", "--images", *map(str, frames), "--board", "chessboard:9x6", "--out", str(out_images)]) == 0
    capsys.readouterr()
    video_lens, image_lens = json.loads(out_video.read_text()), json.loads(out_images.read_text())
    assert video_lens == image_lens
    found = sum(seen["cam1", f] for f in range(12))
    assert f"board found in {found} / 12 images" in from_video and "cam_1.avi#" in from_video  # frames skipped
    fitted = video_lens["distortion"]["params"]["lambda"]
    print(f"\nlambda from the video {fitted:.4g} (truth {LAMBDA:.4g}) over {found} frames with the board")
    assert fitted == pytest.approx(LAMBDA, rel=0.1)


@pytest.fixture(scope="module")
def stereo_videos(tmp_path_factory):
    """A stereo rig (320x180) and three textured frames per camera as MJPG videos."""
    folder = tmp_path_factory.mktemp("rectify_videos")
    scale = 1 / 6
    left = example_camera("left", (320, 180), 1500 * scale, 1490 * scale, principal_point=(161.0, 89.0))
    right = example_camera("right", (320, 180), 1500 * scale, 1490 * scale, principal_point=(158.0, 91.0),
                           centre=(0.9, -6.0, 1.4))
    Rig((left, right)).save(folder / "rig.rig.json")
    rng = np.random.default_rng(4)
    for camera in (left, right):
        writer = cv2.VideoWriter(str(folder / f"{camera.name}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25,
                                 camera.image_size)
        (folder / camera.name).mkdir()
        for _ in range(3):
            writer.write(cv2.GaussianBlur(rng.integers(0, 255, (180, 320, 3), dtype=np.uint8), (0, 0), 2))
        writer.release()
        for k, frame in enumerate(decoded(folder / f"{camera.name}.avi")):
            cv2.imwrite(str(folder / camera.name / frame_file_name(f"{camera.name}.avi", k)), frame)
    return folder


def test_rectify_videos_as_their_frames(stereo_videos, capsys):
    folder = stereo_videos
    rig = str(folder / "rig.rig.json")
    assert main(["rectify", rig, "--images", f"left={folder}/left.avi", f"right={folder}/right.avi", "--every", "2",
                 "--write", str(folder / "w_video"), "--out", str(folder / "video.rig.json")]) == 0
    assert main(["rectify", rig, "--images", f"left={folder}/left/left_00000[02].png",
                 f"right={folder}/right/right_00000[02].png", "--write", str(folder / "w_images"),
                 "--out", str(folder / "images.rig.json")]) == 0
    capsys.readouterr()
    for name in ("left", "right"):
        written = sorted(p.name for p in (folder / "w_video" / name).glob("*.png"))
        assert written == [f"{name}_000000.png", f"{name}_000002.png"]
        for file in written:
            assert np.array_equal(cv2.imread(str(folder / "w_video" / name / file), cv2.IMREAD_UNCHANGED),
                                  cv2.imread(str(folder / "w_images" / name / file), cv2.IMREAD_UNCHANGED))
    # the same cameras (the provenance stamps the second each file was written)
    assert Rig.load(folder / "video.rig.json").cameras == Rig.load(folder / "images.rig.json").cameras
    # a video that cannot be decoded: one line, exit 2, nothing written
    (folder / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    assert main(["rectify", rig, "--images", f"left={folder}/left.avi", f"right={folder}/broken.mp4",
                 "--write", str(folder / "w_bad"), "--out", str(folder / "bad.rig.json")]) == 2
    assert "broken.mp4" in capsys.readouterr().err
    assert not (folder / "w_bad").exists() and not (folder / "bad.rig.json").exists()


@pytest.mark.slow
def test_solve_on_videos_as_on_their_frames(tmp_path, capsys):
    """SfM on two lossless videos (FFV1) of a rendered stereo sequence = SfM on the same frames as PNG folders."""
    from camcal.synthetic import render_stereo_sequence

    render_stereo_sequence(tmp_path / "in")
    for name in ("left", "right"):
        frames = sorted((tmp_path / "in" / name).glob("*.png"))
        first = cv2.imread(str(frames[0]))
        writer = cv2.VideoWriter(str(tmp_path / "in" / f"{name}.mkv"), cv2.VideoWriter_fourcc(*"FFV1"), 10,
                                 (first.shape[1], first.shape[0]))
        for frame in frames:
            writer.write(cv2.imread(str(frame)))
        writer.release()
    assert main(["solve", str(tmp_path / "in"), "--images", "left=left.mkv", "right=right.mkv", "--out",
                 str(tmp_path / "video")]) == 0
    from_video = capsys.readouterr().out
    assert main(["solve", str(tmp_path / "in/left"), str(tmp_path / "in/right"), "--out", str(tmp_path / "png")]) == 0
    from_png = capsys.readouterr().out
    assert "registered 14 / 14 images" in from_video
    video, png = Rig.load(tmp_path / "video/solve.rig.json"), Rig.load(tmp_path / "png/solve.rig.json")
    for a, b in zip(video.cameras, png.cameras):
        assert a.name == b.name and np.allclose(a.K, b.K, rtol=1e-6) and np.allclose(a.c, b.c, atol=1e-6)
    print(f"\n{from_video.splitlines()[1]}\n{from_png.splitlines()[1]}")


def test_distortion_fit_expands_a_quoted_glob(tmp_path, capsys):
    """``--images 'shots/*.png'`` (quoted: the shell leaves the glob to camcal) names the same images as the files
    the shell would list: the same lens; a glob that matches nothing and a missing file are one line each."""
    import cv2

    from camcal.base.errors import CamcalError
    from camcal.base.globs import file_or_glob
    from camcal.cli import main
    from camcal.synthetic_boards import board_homography, render_board_view

    rng = np.random.default_rng(3)
    shots = tmp_path / "shots"
    shots.mkdir()
    for number, tilt in enumerate((0.0, 25.0, -25.0), start=1):
        H = board_homography((640, 480), 9, 6, 38.0, tilt_deg=tilt, tilt_axis_deg=30.0 * number, roll_deg=5.0,
                             centre_px=(320.0, 240.0), focal_px=500.0)
        view = render_board_view(rng, (640, 480), H, 9, 6, 0.7, distortion=-8e-7, distortion_centre=(320.0, 240.0),
                                 jpeg_quality=None)
        cv2.imwrite(str(shots / f"s{number}.png"), view.image)
    listed = sorted(str(path) for path in shots.glob("*.png"))
    assert file_or_glob("--images", str(shots / "*.png")) == listed
    lenses = {}
    for name, images in (("glob", [str(shots / "*.png")]), ("files", listed)):
        out = tmp_path / f"{name}.lens.json"
        assert main(["distortion", "fit", "--images", *images, "--board", "chessboard:9x6", "--out", str(out)]) == 0
        lenses[name] = json.loads(out.read_text())["distortion"]
    assert lenses["glob"] == lenses["files"] and lenses["glob"]["params"]["lambda"] < 0
    with pytest.raises(CamcalError, match=r"--images .*nothing\*\.png: no image or video matches"):
        file_or_glob("--images", str(shots / "nothing*.png"))
    with pytest.raises(CamcalError, match=r"cannot read .*gone\.png \(missing file\)"):
        file_or_glob("--images", str(shots / "gone.png"))
