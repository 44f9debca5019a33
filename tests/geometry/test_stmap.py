"""ST-maps: the convention, EXR round trip, a plain bilinear lookup reproduces camcal's warp, CLI."""

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.model.distortion import Distortion
from camcal.geometry.stmap import make_stmaps, pixels_from_st, st_from_pixels
from camcal.io.stmap import read_exr, write_exr
from camcal.geometry.undistort import make_undistorter
from camcal.model.rig import Rig
from camcal.synthetic import example_camera

SIZE = (320, 240)


def camera():
    return example_camera(image_size=SIZE, fx=260.0, fy=259.0, principal_point=(161.3, 118.2),
                          distortion=Distortion("division", {"lambda": -1.6e-6}, center=(158.0, 121.0)))


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Plain numpy bilinear lookup (what a comp package's STMap node does), 0 outside."""
    h, w = image.shape
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    out = np.zeros(x.shape)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            out += np.where(ok, image[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)], 0.0) * wx * wy
    return out


def smooth_image(rng) -> np.ndarray:
    image = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE[1], SIZE[0])).astype(np.float32), (0, 0), 6.0)
    return ((image - image.min()) / np.ptp(image) * 255).astype(np.float32)


def test_convention_of_the_pixel_centres():
    st = st_from_pixels(np.array([[0.0, 319.0]]), np.array([[0.0, 239.0]]), SIZE)
    assert np.allclose(st[0, 0, :2], [0.5 / 320, 1 - 0.5 / 240])
    assert np.allclose(st[0, 1, :2], [319.5 / 320, 0.5 / 240])
    assert np.all(st[..., 2] == 0)
    x, y = pixels_from_st(st, SIZE)
    assert np.allclose(x, [[0, 319]], atol=1e-4) and np.allclose(y, [[0, 239]], atol=1e-4)


def test_exr_round_trip_is_exact(tmp_path):
    rgb = np.random.default_rng(1).uniform(-0.2, 1.2, (7, 9, 3)).astype(np.float32)
    path = write_exr(tmp_path / "a.exr", rgb)
    assert np.array_equal(read_exr(path), rgb)


def test_undistort_stmap_reproduces_camcal_undistortion(tmp_path):
    cam = camera()
    maps = make_stmaps(cam, overscan=1.1)
    path = write_exr(tmp_path / "u.exr", maps.undistort)
    st = read_exr(path)
    image = smooth_image(np.random.default_rng(3))
    x, y = pixels_from_st(st, SIZE)
    via_stmap = bilinear(image.astype(np.float64), x, y)
    camcal = make_undistorter(cam, "overscan", 1.1).apply(image)
    assert via_stmap.shape == camcal.shape == (round(240 * 1.1), round(320 * 1.1))
    # where the undistorted canvas samples inside the plate (1 px margin from its edge)
    inside = (x >= 1) & (x <= SIZE[0] - 2) & (y >= 1) & (y <= SIZE[1] - 2)
    assert inside.mean() > 0.7
    # (1) the ST-map encodes camcal's sampling positions: the same bilinear lookup
    #     at camcal's own float32 maps agrees to < 0.01 grey levels
    undistorter = make_undistorter(cam, "overscan", 1.1)
    exact = bilinear(image.astype(np.float64), undistorter.maps.map_x.astype(np.float64),
                     undistorter.maps.map_y.astype(np.float64))
    encoding = np.abs(via_stmap - exact)[inside]
    assert encoding.max() < 0.01
    # (2) against camcal's image itself: cv2.remap rounds its bilinear weights to
    #     1/32 px, so the difference is bounded by max|grad I| * sqrt(2) / 64
    gy, gx = np.gradient(image.astype(np.float64))
    bound = np.hypot(gx, gy).max() * np.sqrt(2) / 64
    difference = np.abs(via_stmap - camcal)[inside]
    print(f"ST-map lookup vs camcal's maps: max {encoding.max():.5f}; vs camcal's cv2.remap image: "
          f"max {difference.max():.4f} (bound {bound:.4f}), mean {difference.mean():.4f} grey levels")
    assert difference.max() < bound


def test_redistort_stmap_inverts_the_undistort_stmap():
    cam = camera()
    maps = make_stmaps(cam, overscan=1.2)
    undistorted_size = maps.undistorted.image_size
    ux, uy = pixels_from_st(maps.undistort, SIZE)  # plate pixel of each undistorted pixel
    rx, ry = pixels_from_st(maps.redistort, SIZE)  # undistorted pixel of each plate pixel, in its format
    rx, ry = rx + maps.border[0], ry + maps.border[1]  # in its data window
    # follow a plate pixel to the undistorted canvas and back through the undistort map
    back_x = bilinear(ux, rx, ry)
    back_y = bilinear(uy, rx, ry)
    u, v = np.meshgrid(np.arange(SIZE[0]), np.arange(SIZE[1]))
    # the maps are smooth: bilinear interpolation of one evaluated at the other is ~identity
    assert np.abs(back_x - u).max() < 0.02 and np.abs(back_y - v).max() < 0.02
    # overscan 1.2 covers the whole plate under this barrel lens
    assert rx.min() > 0 and ry.min() > 0
    assert rx.max() < undistorted_size[0] - 1 and ry.max() < undistorted_size[1] - 1


def test_undistorted_camera_has_K_new_and_no_distortion():
    cam = camera()
    maps = make_stmaps(cam, overscan=1.1)
    new = maps.undistorted
    assert new.distortion.model == "none" and new.image_size == (352, 264)
    assert np.allclose(new.K[:2, 2], cam.K[:2, 2] + [16.0, 12.0])
    assert np.array_equal(new.K[[0, 1], [0, 1]], cam.K[[0, 1], [0, 1]])


def test_cli_stmap_writes_maps_and_rig(tmp_path):
    rig_path = Rig((camera(),)).save(tmp_path / "in.rig.json")
    out = tmp_path / "maps"
    assert main(["stmap", str(rig_path), "--camera", "cam", "--out", str(out), "--overscan", "1.1"]) == 0
    expected = make_stmaps(camera(), 1.1)
    assert np.array_equal(read_exr(out / "cam_undistort.exr"), expected.undistort)
    assert np.array_equal(read_exr(out / "cam_redistort.exr"), expected.redistort)
    assert Rig.load(out / "cam_undistorted.rig.json").camera("cam") == expected.undistorted


def test_cli_stmap_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["stmap", "--help"])
    assert info.value.code == 0 and "--overscan" in capsys.readouterr().out


def test_cli_stmap_bad_overscan(tmp_path, capsys):
    rig_path = Rig((camera(),)).save(tmp_path / "in.rig.json")
    out = tmp_path / "maps"
    assert main(["stmap", str(rig_path), "--camera", "cam", "--out", str(out), "--overscan", "0.5"]) == 2
    assert "overscan must be a number >= 1" in capsys.readouterr().err
    assert not out.exists()
