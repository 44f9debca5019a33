"""``solve --intrinsics shot.rig.json`` on a zoom: each plate frame held at its frame's lens, the lenses in the rig."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.model.camera import look_at
from camcal.model.colmap import camera_to_colmap
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from camcal.model.rig_frames import Frame, Lens
from camcal.pipelines.solve import solve_sfm
from camcal.pipelines.solve_lens import grid_lens, hold_in_database
from camcal.synthetic import procedural_texture, render_planes, room_corner_planes

WIDTH, HEIGHT = 256, 192
FIRST = 1001
LENS = Distortion("polynomial", {"k1": -0.08, "k2": 0.01})


def _zoom_lens(k: int, scale: float = 1.0) -> Lens:
    """The zoom at its ``k``-th frame: fx 200 px zooming 4 % a frame, the principal point drifting; ``scale``: the
    image scaled by it (u' = s (u + 0.5) - 0.5)."""
    f, cx, cy = 200.0 * 1.04 ** k, 127.5 + 0.8 * k, 95.5 - 0.5 * k
    K = np.array([[scale * f, 0, scale * (cx + 0.5) - 0.5], [0, scale * f, scale * (cy + 0.5) - 0.5], [0, 0, 1]])
    return Lens(K, LENS, focal_mm=24.0 * 1.04 ** k)


def _shot_rig(frames, size=(WIDTH, HEIGHT)) -> Rig:
    """What ``camcal lens --metadata`` gives for the zoom: camera ``cam``, a lens at each frame of ``frames``."""
    s = size[0] / WIDTH
    camera = Camera("cam", size, _zoom_lens(0, s).K, LENS, np.eye(3), np.zeros(3))
    rig = Rig((camera,), frames=tuple(Frame(index, np.eye(3), np.zeros(3)) for index in frames))
    return rig.with_camera(camera, {index: _zoom_lens(index - FIRST, s) for index in frames})


def test_each_plate_frame_takes_its_frame_s_lens_and_missing_frames_are_named():
    images = {f"plate/{k:06d}.png": FIRST + k for k in range(4)}
    lens = grid_lens(_shot_rig(range(FIRST, FIRST + 6), (2 * WIDTH, 2 * HEIGHT)), {"plate": (WIDTH, HEIGHT)},
                     source="shot.rig.json", frame_numbers=images)
    for image, number in images.items():  # the frame of the same number, at the plate's half size
        np.testing.assert_allclose(lens.lenses[image].K, _zoom_lens(number - FIRST, 1.0).K, atol=1e-12)
        assert lens.lenses[image].focal_mm == pytest.approx(24.0 * 1.04 ** (number - FIRST))
        assert lens.camera_of(image).name == "plate"
        np.testing.assert_allclose(lens.camera_of(image).K, lens.lenses[image].K)
    assert len({lens.lenses[image].K[0, 0] for image in images}) == 4
    with pytest.raises(CamcalError, match=r"shot.rig.json has no lens of camera 'cam' for plate frames 1004-1005, "
                                          r"1009 \(it has frames 1001-1003\)"):
        grid_lens(_shot_rig(range(FIRST, FIRST + 3)), {"plate": (WIDTH, HEIGHT)}, source="shot.rig.json",
                  frame_numbers={**images, "plate/a.png": 1005, "plate/b.png": 1009})
    with pytest.raises(CamcalError, match=r"can only be held \(--intrinsics-mode fixed\), on a one-camera solve"):
        grid_lens(_shot_rig(range(FIRST, FIRST + 6)), {"plate": (WIDTH, HEIGHT)}, "prior", frame_numbers=images)
    with pytest.raises(CamcalError, match=r"plate image 'plate/000000.png' has no frame number in its name"):
        grid_lens(_shot_rig(range(FIRST, FIRST + 6)), {"plate": (WIDTH, HEIGHT)}, frame_numbers={"plate/000000.png": None})


def test_each_colmap_camera_is_held_at_its_image_s_lens(tmp_path):
    """One COLMAP camera per image, each given its frame's lens (model, parameters, a prior focal length)."""
    pycolmap = require("pycolmap")
    rng = np.random.default_rng(0)
    (tmp_path / "images" / "plate").mkdir(parents=True)
    images = {f"plate/{k:06d}.png": FIRST + 2 * k for k in range(3)}
    for image in images:
        cv2.imwrite(str(tmp_path / "images" / image), rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8))
    lens = grid_lens(_shot_rig(range(FIRST, FIRST + 6)), {"plate": (WIDTH, HEIGHT)}, frame_numbers=images)
    database = tmp_path / "database.db"
    pycolmap.extract_features(database, tmp_path / "images", image_names=list(images),
                              camera_mode=pycolmap.CameraMode.PER_IMAGE, device=pycolmap.Device.cpu)
    hold_in_database(pycolmap, database, lens)
    db = pycolmap.Database.open(database)
    try:
        camera_of = {image.name: image.camera_id for image in db.read_all_images()}
        cameras = {camera.camera_id: camera for camera in db.read_all_cameras()}
    finally:
        db.close()
    assert len(set(camera_of.values())) == 3 == len(cameras)
    for image, number in images.items():
        held = cameras[camera_of[image]]
        expected = camera_to_colmap(Camera("plate", (WIDTH, HEIGHT), _zoom_lens(number - FIRST).K, LENS, np.eye(3),
                                           np.zeros(3)))
        assert held.model.name == expected.model and held.has_prior_focal_length
        np.testing.assert_allclose(held.params, expected.params, atol=1e-9)


def _zoom_plate(folder, n_frames):
    """A dolly along the room corner's wall while zooming in (:func:`_zoom_lens`), ``plate.1001.png``...: the truth."""
    rng = np.random.default_rng(3)
    planes = room_corner_planes()
    textures = tuple(procedural_texture(rng) for _ in planes)
    folder.mkdir()
    truth = {}
    for k in range(n_frames):
        centre = np.array([5.0 + 0.12 * k, 4.2 - 0.05 * k, 1.5])
        lens = _zoom_lens(k)
        camera = Camera("plate", (WIDTH, HEIGHT), lens.K, lens.distortion, look_at(centre, np.array([1.0, 1.0, 1.0])),
                        centre)
        cv2.imwrite(str(folder / f"plate.{FIRST + k}.png"), render_planes(camera, planes, textures))
        truth[k] = camera
    return truth


def _centre_errors(rig: Rig, truth: dict[int, Camera]) -> np.ndarray:
    """Each solved frame's camera centre against the truth after the best similarity (Umeyama), in metres."""
    keys = sorted(truth)
    solved = np.array([rig.camera_at_frame("plate", k).c for k in keys])
    true = np.array([truth[k].c for k in keys])
    a, b = solved - solved.mean(axis=0), true - true.mean(axis=0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / np.sum(a * a)
    return np.linalg.norm(s * a @ R.T - b, axis=1)


@pytest.mark.slow
def test_a_zoom_plate_solved_with_each_frame_s_lens_held_finds_the_camera_path(tmp_path):
    """8 frames zooming 4 % each (a 1 m dolly): held at their lenses, every centre within 3 mm of the truth and
    0.2 px RMS (measured 0.8 mm, 0.07 px; the first frame's lens held on all: 24 mm, 0.50 px); the rig's frames
    carry the lenses exactly."""
    truth = _zoom_plate(tmp_path / "plate", 8)
    result = solve_sfm({"plate": tmp_path / "plate"}, tmp_path / "out", max_num_features=1024, num_threads=1,
                       intrinsics=_shot_rig(range(FIRST, FIRST + 8)), intrinsics_source="shot.rig.json")
    assert result.n_registered == 8 and result.rms_px < 0.2
    for frame in result.rig.frames:  # solved frames are 0..7, the plate's 1001..1008
        np.testing.assert_allclose(frame.lenses["plate"].K, _zoom_lens(frame.index).K, atol=1e-12)
    errors = _centre_errors(result.rig, truth)
    assert errors.max() < 0.003, errors
