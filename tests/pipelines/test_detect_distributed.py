"""Board detection on Dask (frame ranges decoded in worker processes) against the in-process path, frame for frame."""

import sys
from pathlib import Path

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.board import parse_board
from camcal.pipelines.board import detect_in_video
from camcal.pipelines.distributed import dask_client, detect_in_videos

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import make_volume, write_videos  # noqa: E402
from dask_faults import workers_elsewhere  # noqa: E402

SPEC = "charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided"


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    """Three cameras of a rendered capture volume, 16 frames each: an mp4 (MPEG-4 part 2) and two MJPEG avi."""
    folder = tmp_path_factory.mktemp("ranges")
    board = parse_board(SPEC)
    volume = make_volume(6, 16, radius=0.85)
    volume.cameras = volume.cameras[:3]
    mp4, _ = write_videos(board, volume, folder)
    avi, _ = write_videos(board, volume, folder, fourcc="MJPG", suffix=".avi")
    return board, {"cam0": mp4[0], "cam1": mp4[1], "cam2": avi[2]}


@pytest.fixture(scope="module")
def client():
    with dask_client(2, None) as client:
        yield client


def same_reports(ours, theirs):
    assert ours.skipped == theirs.skipped
    assert [d.image for d in ours.detections] == [d.image for d in theirs.detections]
    for a, b in zip(ours.detections, theirs.detections):
        assert a.detector == b.detector and a.image_size == b.image_size
        assert np.array_equal(a.ids, b.ids) and np.array_equal(a.corners_px, b.corners_px)  # bit for bit


@pytest.mark.parametrize("every", [pytest.param(1, marks=pytest.mark.slow), 3])
def test_dask_ranges_give_the_in_process_corners(videos, client, every):
    """Ranges of 5 frames (seeks into the middle of each group of pictures) give identical corners and skips."""
    board, paths = videos
    progress = []
    reports = detect_in_videos(board, paths, every=every, client=client, chunk_frames=5,
                               progress=lambda done, total: progress.append((done, total)))
    n_found = 0
    for name, path in paths.items():
        same_reports(reports[name], detect_in_video(board, path, every=every))
        n_found += len(reports[name].detections)
    assert n_found > 5 * len(paths) / every
    assert progress[-1][0] == progress[-1][1] == sum(len(range(0, 16, every)) for _ in paths)
    assert all(a[0] <= b[0] for a, b in zip(progress, progress[1:]))


def test_cache_is_shared_with_the_in_process_path(videos, client, tmp_path):
    """Corners detected on Dask are read back by the in-process path (nothing decoded: the video is gone)."""
    board, paths = videos
    copy = tmp_path / "cam0.mp4"
    copy.write_bytes(Path(paths["cam0"]).read_bytes())
    reports = detect_in_videos(board, {"cam0": copy}, client=client, chunk_frames=6, cache=tmp_path / "cache")
    same_reports(reports["cam0"], detect_in_video(board, copy, cache=tmp_path / "cache"))
    again = detect_in_videos(board, {"cam0": copy}, client=client, cache=tmp_path / "cache")  # no task
    same_reports(again["cam0"], reports["cam0"])


def test_relative_video_paths_reach_workers_in_another_working_directory(videos, client, monkeypatch, tmp_path):
    """A farm's workers do not share the client's working directory: a path relative to the client's still opens,
    and the detections keep the name the user gave (the in-process path's)."""
    board, paths = videos
    monkeypatch.chdir(Path(paths["cam2"]).parent)
    relative = Path(paths["cam2"]).name
    with workers_elsewhere(client, tmp_path / "worker"):
        reports = detect_in_videos(board, {"cam2": relative}, every=3, client=client, chunk_frames=8)
    same_reports(reports["cam2"], detect_in_video(board, relative, every=3))
    assert reports["cam2"].detections and all(d.image.startswith(relative + "#") for d in reports["cam2"].detections)


def test_bad_input_is_one_error(videos, client, tmp_path):
    board, _ = videos
    (tmp_path / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    with pytest.raises(CamcalError, match="broken.mp4: cannot be decoded"):
        detect_in_videos(board, {"cam0": tmp_path / "broken.mp4"}, client=client)
    with pytest.raises(CamcalError, match="chunk_frames"):
        detect_in_videos(board, {"cam0": tmp_path / "broken.mp4"}, client=client, chunk_frames=0)


@pytest.mark.slow
def test_calibrate_board_on_a_scheduler_with_max_views(videos, client, tmp_path, capsys):
    """`calibrate board --scheduler ADDRESS --max-views 8` detects on that cluster, solves on 8 frames chosen by
    coverage, holds out the others and writes the rig of every camera."""
    from camcal.cli import main
    from camcal.model.rig import Rig

    board, paths = videos
    volume = make_volume(6, 16, radius=0.85)
    Rig(tuple(volume.cameras[:3])).save(tmp_path / "intr.rig.json")
    argv = ["calibrate", "board", "--board", SPEC, *[f"--images={name}={path}" for name, path in paths.items()],
            "--intrinsics", str(tmp_path / "intr.rig.json"), "--scheduler", client.scheduler.address,
            "--max-views", "8", "--no-cache", "--out", str(tmp_path / "rig.rig.json")]
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    assert "on Dask" in captured.err
    rig = Rig.load(tmp_path / "rig.rig.json")
    assert [c.name for c in rig.cameras] == list(paths)
    frames = {int(d.image.split("#")[1]) for path in paths.values() for d in detect_in_video(board, path).detections}
    assert f"solving on 8 of {len(frames)} frames, chosen for coverage" in captured.out
    assert all(0 < c.quality["heldout_rms_px"] < 1.0 for c in rig.cameras)
    for name, path in paths.items():
        found = len(detect_in_video(board, path).detections)
        assert f"{name}: board found in {found} / 16 frames" in captured.out


def test_bad_max_views_is_one_line_before_any_work(videos, tmp_path, capsys):
    from camcal.cli import main

    _, paths = videos
    code = main(["calibrate", "board", "--board", SPEC, f"--images=cam0={paths['cam0']}", "--max-views", "0",
                 "--out", str(tmp_path / "rig.rig.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == "camcal: error: --max-views must be 1 or more, got 0"
    assert not list(tmp_path.iterdir())
