"""Image undistortion: K_new for crop / keep / overscan, one remap, peer cv2.undistort, CLI."""

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.undistort import make_undistorter, undistorted_view
from camcal.model.rig import Rig
from camcal.synthetic import example_camera

SIZE = (640, 480)
LENSES = {
    "barrel": Distortion("division", {"lambda": -4e-7}, center=(322.0, 236.0)),
    "pincushion": Distortion("polynomial", {"k1": 0.06, "k2": 0.01}),
    "opencv": Distortion("opencv", {"k1": -0.18, "k2": 0.04, "p1": 0.001, "p2": -0.0008, "k3": 0.0}),
}


def camera(lens: Distortion):
    return example_camera(image_size=SIZE, fx=520.0, fy=518.0, principal_point=(318.7, 241.2), distortion=lens)


def all_pixels(size):
    u, v = np.meshgrid(np.arange(size[0], dtype=float), np.arange(size[1], dtype=float))
    return np.stack([u.ravel(), v.ravel()], 1)


@pytest.mark.parametrize("name", LENSES)
def test_crop_samples_only_inside_and_is_the_widest_such_view(name):
    cam = camera(LENSES[name])
    view = undistorted_view(cam, "crop")
    assert view.image_size == SIZE
    maps = make_undistorter(cam, "crop").maps
    w, h = SIZE
    assert maps.map_x.min() >= -0.5 and maps.map_x.max() <= w - 0.5
    assert maps.map_y.min() >= -0.5 and maps.map_y.max() <= h - 0.5
    # 0.1 % wider and the output frame's edge would sample outside the source frame
    wider = view.K_new.copy()
    wider[0, :2] *= 0.999
    wider[1, 1] *= 0.999
    edge = all_pixels((w + 1, h + 1)) - 0.5
    edge = edge[(edge[:, 0] == -0.5) | (edge[:, 0] == w - 0.5) | (edge[:, 1] == -0.5) | (edge[:, 1] == h - 0.5)]
    ideal = np.column_stack([edge, np.ones(len(edge))]) @ (cam.K @ np.linalg.inv(wider)).T
    border = cam.distortion.distort(ideal[:, :2], cam.K)
    assert np.any((border < -0.5) | (border > np.array(SIZE) - 0.5))


@pytest.mark.parametrize("name", LENSES)
def test_keep_puts_every_source_pixel_on_the_canvas(name):
    cam = camera(LENSES[name])
    view = undistorted_view(cam, "keep")
    assert np.allclose(view.K_new[[0, 1], [0, 1]], cam.K[[0, 1], [0, 1]])
    ideal = cam.distortion.undistort(all_pixels(SIZE), cam.K)
    landed = ideal + (view.K_new[:2, 2] - cam.K[:2, 2])
    assert landed.min() >= -0.5 and np.all(landed.max(axis=0) <= np.array(view.image_size) - 0.5)
    # and the canvas is tight: the outermost source pixel centres are within 1.5 px of its edge
    assert np.all(landed.min(axis=0) < 1.0)
    assert np.all(landed.max(axis=0) > np.array(view.image_size) - 2.5)


def test_a_dot_lands_at_its_pinhole_position_in_K_new():
    cam = camera(LENSES["barrel"])
    undistorter = make_undistorter(cam, "keep")
    ideal = np.array([[560.0, 60.0]])
    distorted = cam.distortion.distort(ideal, cam.K)[0]
    v, u = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    image = np.exp(-((u - distorted[0]) ** 2 + (v - distorted[1]) ** 2) / (2 * 1.5**2)).astype(np.float32)
    out = undistorter.apply(image)
    v, u = np.mgrid[0 : out.shape[0], 0 : out.shape[1]]
    weights = out / out.sum()
    centroid = np.array([(weights * u).sum(), (weights * v).sum()])
    expected = ideal[0] + undistorter.view.K_new[:2, 2] - cam.K[:2, 2]
    assert np.abs(centroid - expected).max() < 0.05
    assert np.linalg.norm(distorted - ideal[0]) > 5.0


def test_matches_cv2_undistort_on_the_same_K_new():
    lens = LENSES["opencv"]
    cam = camera(lens)
    rng = np.random.default_rng(2)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE[1], SIZE[0])).astype(np.float32), (0, 0), 4.0)
    image = (image - image.min()) / np.ptp(image) * 255
    undistorter = make_undistorter(cam, "crop")
    ours = undistorter.apply(image)
    p = lens.params
    peer = cv2.undistort(image, cam.K, np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"]]), None, undistorter.view.K_new)
    inner = (slice(5, -5), slice(5, -5))
    # OpenCV's undistort quantises its maps to 1/32 px: allow that much motion times the gradient
    gy, gx = np.gradient(image)
    tolerance = np.hypot(gx, gy).max() / 32 * np.sqrt(2)
    assert np.abs(ours[inner] - peer[inner]).max() < tolerance
    # Without the quantisation: OpenCV's own float maps (initUndistortRectifyMap, CV_32FC1)
    # resampled by exact bilinear interpolation. OpenCV 4's remap quantised float maps to
    # 1/32 px like cv2.undistort (mean difference to cv2.undistort 1e-4); OpenCV 5's remap
    # interpolates them exactly, so compare with an exact bilinear resampling instead.
    from scipy.ndimage import map_coordinates

    coeffs = np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"]])
    map_x, map_y = cv2.initUndistortRectifyMap(cam.K, coeffs, None, undistorter.view.K_new, SIZE, cv2.CV_32FC1)
    exact = map_coordinates(image.astype(np.float64), [map_y, map_x], order=1)
    if int(cv2.__version__.split(".")[0]) >= 5:
        assert np.abs(ours[inner] - exact[inner]).max() < 1e-3
    else:  # camcal remaps with OpenCV too: on 4.x both quantise the same way
        assert np.abs(ours[inner] - peer[inner]).mean() < 0.05


def test_undistorted_camera_and_size_check():
    cam = camera(LENSES["barrel"])
    undistorter = make_undistorter(cam, "crop")
    new = undistorter.undistorted_camera()
    assert new.distortion.is_identity and new.distortion.model == "none"
    assert np.array_equal(new.K, undistorter.view.K_new) and np.array_equal(new.R, cam.R)
    with pytest.raises(CamcalError, match="is 100x80 px"):
        undistorter.apply(np.zeros((80, 100), np.uint8))
    with pytest.raises(CamcalError, match="unknown undistortion mode"):
        undistorted_view(cam, "fit")


# -- CLI --------------------------------------------------------------------------------


@pytest.fixture
def rig_and_images(tmp_path):
    cam = camera(LENSES["barrel"])
    rig_path = Rig((cam,)).save(tmp_path / "in.rig.json")
    rng = np.random.default_rng(0)
    paths = []
    for k in range(2):
        path = tmp_path / f"plate{k}.png"
        cv2.imwrite(str(path), rng.integers(0, 255, (SIZE[1], SIZE[0]), dtype=np.uint8))
        paths.append(path)
    return cam, rig_path, paths


def test_cli_undistort_writes_images_and_rig(rig_and_images, tmp_path):
    cam, rig_path, paths = rig_and_images
    out = tmp_path / "out"
    assert main(["undistort", str(rig_path), "--camera", "cam", "--images", *map(str, paths), "--mode", "keep", "--out", str(out)]) == 0
    new = Rig.load(out / "undistorted.rig.json").camera("cam")
    undistorter = make_undistorter(cam, "keep")
    assert np.array_equal(new.K, undistorter.view.K_new) and new.distortion.model == "none"
    written = cv2.imread(str(out / "plate1.png"), cv2.IMREAD_UNCHANGED)
    assert written.shape == (new.image_size[1], new.image_size[0])
    assert np.array_equal(written, undistorter.apply(cv2.imread(str(paths[1]), cv2.IMREAD_UNCHANGED)))


def test_cli_undistort_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["undistort", "--help"])
    assert info.value.code == 0 and "--mode" in capsys.readouterr().out


def test_cli_undistort_bad_input(rig_and_images, tmp_path, capsys):
    _, rig_path, paths = rig_and_images
    out = tmp_path / "out"
    bad = tmp_path / "small.png"
    cv2.imwrite(str(bad), np.zeros((10, 10), np.uint8))
    assert main(["undistort", str(rig_path), "--camera", "cam", "--images", str(paths[0]), str(bad), "--out", str(out)]) == 2
    assert "small.png is 10x10 px" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
    assert main(["undistort", str(rig_path), "--camera", "nope", "--images", str(paths[0]), "--out", str(out)]) == 2
    assert "no camera 'nope'" in capsys.readouterr().err
