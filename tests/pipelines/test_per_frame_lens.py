"""A zoom's plates: undistort, stmap and batch take each frame's lens (``frames[i].lenses``).

The peer of every output is the same command on a rig whose camera has that frame's lens and no frames: a zoom's
frame must come out exactly as a fixed lens in that state would.
"""

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.api.undistortion import undistort
from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.stmap import read_exr
from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Frame, Lens, Rectification, Rig
from camcal.pipelines.batch import make_job, process_frame, run_batch
from camcal.pipelines.undistort import image_frame

SIZE = (96, 64)
FRAMES = (7, 8, 9)


def zoom_rig() -> Rig:
    """Frame 7 the camera's own lens; 8 and 9 zoomed in with less barrel and a drifting principal point."""
    K = np.array([[90.0, 0.0, 47.8], [0.0, 90.0, 31.6], [0.0, 0.0, 1.0]])
    camera = Camera("cam", SIZE, K, Distortion("division", {"lambda": -2.5e-5}), np.eye(3), np.zeros(3))
    frames = []
    for i, index in enumerate(FRAMES):
        zoom = 1.0 + 0.25 * i
        K_frame = K.copy()
        K_frame[:2, :2] *= zoom
        K_frame[:2, 2] += (0.7 * i, -0.4 * i)
        lenses = {} if i == 0 else {"cam": Lens(K_frame, Distortion("division", {"lambda": -2.5e-5 / zoom ** 2}),
                                                focal_mm=20.0 * zoom, focus_m=3.0)}
        frames.append(Frame(index, look_at([0.1 * i, -3, 1], [0, 2, 1]), [0.1 * i, -3, 1], lenses=lenses))
    return Rig((camera,), frames=tuple(frames))


def static_rig(rig: Rig, index: int) -> Rig:
    """The camera with frame ``index``'s lens, alone: what a fixed lens in that state is."""
    at = rig.camera_at_frame("cam", index)
    return Rig((dataclasses.replace(rig.camera("cam"), K=at.K, distortion=at.distortion),))


def write_plates(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    v, u = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    paths = []
    for index in FRAMES:
        image = (127 + 120 * np.sin(u / (3.0 + index)) * np.cos(v / 4.0)).astype(np.uint8)
        paths.append(folder / f"plate.{index:04d}.png")
        cv2.imwrite(str(paths[-1]), np.dstack([image, image[::-1], image[:, ::-1]]))
    return paths


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("zoom")
    rig = zoom_rig()
    return rig, rig.save(folder / "zoom.rig.json"), write_plates(folder / "plates"), folder


@pytest.mark.parametrize("mode", ["crop", "overscan"])
def test_undistort_takes_each_frames_lens(shot, mode):
    rig, rig_path, plates, folder = shot
    result = undistort(rig_path, "cam", [str(p) for p in plates], folder / f"out_{mode}", mode=mode)
    for index, plate, output in zip(FRAMES, plates, result.images):
        peer = undistort(static_rig(rig, index), "cam", [str(plate)], folder / f"peer_{mode}_{index}", mode=mode)
        assert np.array_equal(cv2.imread(str(output)), cv2.imread(str(peer.images[0])))
        assert np.array_equal(result.rig.camera_at_frame("cam", index).K, peer.camera.K)
        assert result.rig.camera_at_frame("cam", index).distortion.model == "none"
    undistorted = Rig.load(result.rig_path)
    assert [f.lenses["cam"].focal_mm for f in undistorted.frames[1:]] == [25.0, 30.0]  # the lens state kept
    # the zoom really changes the output: frames differ from the camera's own lens' undistortion
    own = undistort(Rig((rig.camera("cam"),)), "cam", [str(plates[2])], folder / f"own_{mode}", mode=mode)
    assert not np.array_equal(cv2.imread(str(result.images[2])), cv2.imread(str(own.images[0])))


def test_images_map_to_frames_by_the_rigs_list_or_their_number(shot, tmp_path):
    rig, _, plates, folder = shot
    listed = dataclasses.replace(rig, frames=tuple(dataclasses.replace(f, images={"cam": f"shots/take_{k}.png"})
                                                  for k, f in zip("abc", rig.frames)))
    assert image_frame(listed, "cam", folder / "shots" / "take_b.png", folder) == 8
    assert image_frame(listed, "cam", "elsewhere/take_c.png") == 9  # no rig folder: by file name
    assert image_frame(rig, "cam", plates[1]) == 8  # plate.0008.png
    with pytest.raises(CamcalError, match="not one of a frame's images, nor numbered like one"):
        image_frame(rig, "cam", tmp_path / "plate.0042.png")
    (tmp_path / "still.png").write_bytes(Path(plates[0]).read_bytes())
    with pytest.raises(CamcalError, match="not one of a frame's images") as info:
        undistort(rig, "cam", [str(plates[0]), str(tmp_path / "still.png")], tmp_path / "out")
    assert "\n" not in str(info.value) and not (tmp_path / "out").exists()


def test_keep_mode_refuses_a_canvas_that_changes_with_the_lens(shot, tmp_path):
    rig, rig_path, plates, _ = shot
    with pytest.raises(CamcalError, match="needs a fixed output size"):
        undistort(rig_path, "cam", [str(p) for p in plates], tmp_path / "keep", mode="keep")
    assert not (tmp_path / "keep").exists()


def test_stmap_writes_a_pair_per_frame(shot, capsys):
    rig, rig_path, _, folder = shot
    assert main(["stmap", str(rig_path), "--camera", "cam", "--out", str(folder / "maps")]) == 0
    assert "one pair per frame" in capsys.readouterr().out
    for index in FRAMES:
        assert main(["stmap", str(static_rig(rig, index).save(folder / f"s{index}.rig.json")), "--camera", "cam",
                     "--out", str(folder / f"maps{index}")]) == 0
        for kind in ("undistort", "redistort"):
            ours = read_exr(folder / "maps" / f"cam_{kind}.{index:04d}.exr")
            assert np.array_equal(ours, read_exr(folder / f"maps{index}" / f"cam_{kind}.exr"))
    assert main(["stmap", str(rig_path), "--camera", "cam", "--sigma", "--out", str(folder / "sigma")]) != 0
    assert "--sigma maps one lens" in capsys.readouterr().err and not (folder / "sigma").exists()


def test_batch_remaps_each_frame_with_its_lens(shot):
    rig, rig_path, plates, folder = shot
    pattern = str(plates[0]).replace("0007", "%04d")
    job = make_job(rig_path, "cam", pattern, str(folder / "batch" / "plate.%04d.png"), "undistort")
    assert sorted(job.lenses) == list(FRAMES)
    for index, plate in zip(FRAMES, plates):
        ours = cv2.imread(process_frame(index, job).output, cv2.IMREAD_UNCHANGED)
        peer = undistort(static_rig(rig, index), "cam", [str(plate)], folder / f"batch_peer_{index}")
        assert np.array_equal(ours, cv2.imread(str(peer.images[0]), cv2.IMREAD_UNCHANGED))
    fixed = make_job(static_rig(rig, 8), "cam", pattern, str(folder / "fixed" / "plate.%04d.png"), "undistort")
    assert fixed.lenses == {} and fixed.key != job.key
    with pytest.raises(CamcalError, match=r"frame\(s\) 10 are not in the rig"):
        run_batch(job, [9, 10], progress=False)
    camera = rig.camera("cam")
    rectified = Rig((dataclasses.replace(camera, rectification=Rectification(np.eye(3), camera.K, SIZE)),),
                    frames=rig.frames)
    with pytest.raises(CamcalError, match="its rectification holds one lens"):
        make_job(rectified, "cam", pattern, str(folder / "rect" / "plate.%04d.png"), "rectify")
