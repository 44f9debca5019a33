"""ST-maps: the convention, EXR round trip, a plain bilinear lookup reproduces camcal's warp, CLI."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.model.distortion import Distortion
from camcal.geometry.stmap import make_stmaps, pixels_from_st, st_from_pixels
from camcal.io.stmap import read_exr, read_exr_window, write_exr
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


# -- overscan as a border, the EXR's data window, the round trip --------------------------------------------------

ROUND_TRIP_LENSES = {
    "opencv": (Distortion("opencv", {"k1": -0.28, "k2": 0.09, "p1": 8e-4, "p2": -6e-4, "k3": -0.012}), 300.0),
    "kannala-brandt": (Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}),
                       150.0),
    "division": (Distortion("division", {"lambda": -2.2e-6}, center=(163.0, 116.0)), 300.0),
}


def lens_camera(name: str):
    lens, focal = ROUND_TRIP_LENSES[name]
    return example_camera(image_size=SIZE, fx=focal, fy=focal * 0.998, principal_point=(161.3, 118.2),
                          distortion=lens)


@pytest.mark.parametrize("name", list(ROUND_TRIP_LENSES))
def test_undistort_with_1_25_overscan_then_redistort_is_the_identity(name):
    """Each plate pixel, sent through the redistort map into the undistorted image and back through the undistort
    map (bilinear, as a comp package's STMap node reads it), lands on itself within 0.01 px."""
    cam = lens_camera(name)
    maps = make_stmaps(cam, overscan=1.25)
    bx, by = maps.border
    assert maps.border == (round(0.125 * SIZE[0]), round(0.125 * SIZE[1]))
    assert maps.undistort.shape == (SIZE[1] + 2 * by, SIZE[0] + 2 * bx, 3)
    px, py = pixels_from_st(maps.undistort, SIZE)  # plate pixel of each undistorted pixel (data window)
    ux, uy = pixels_from_st(maps.redistort, SIZE)  # undistorted pixel (its format) of each plate pixel
    canvas_x, canvas_y = ux + bx, uy + by
    height, width = px.shape
    inside = (canvas_x >= 0) & (canvas_x <= width - 1) & (canvas_y >= 0) & (canvas_y <= height - 1)
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=float), np.arange(SIZE[1], dtype=float))
    back_x, back_y = bilinear(px, canvas_x, canvas_y), bilinear(py, canvas_x, canvas_y)
    error = np.hypot(back_x - u, back_y - v)[inside]
    moved = np.hypot(ux - u, uy - v)[inside].max()
    print(f"{name}: plate -> undistorted (1.25 overscan) -> plate: max {error.max():.5f} px over {inside.sum()} "
          f"pixels ({inside.mean():.1%} of the frame); the lens moves pixels up to {moved:.1f} px")
    assert moved > 5.0 and inside.mean() > (0.6 if name == "kannala-brandt" else 0.999)
    assert error.max() < 0.01


@pytest.mark.parametrize("name", list(ROUND_TRIP_LENSES) + ["polynomial", "opencv-rational", "none", "3de4-radial"])
def test_vectorised_maps_equal_the_lens_model(name):
    """The fast grid paths equal camcal's own Distortion.distort / undistort on every pixel (the first in float32);
    3DE's lenses take the generic path."""
    from camcal.geometry.stmap import undistorted_grid, st_of_distorted_grid

    lenses = {"polynomial": Distortion("polynomial", {"k1": -0.2, "k2": 0.05, "k3": -0.01}),
              "opencv-rational": Distortion("opencv", {"k1": -0.2, "k2": 0.05, "p1": 1e-3, "p2": -2e-3, "k3": 0.0,
                                                       "k4": 0.1, "s1": 2e-3, "s4": -1e-3}),
              "none": Distortion.none(),
              "3de4-radial": Distortion("3de4-radial-deg4", {"c2": -0.05, "u2": 0.01, "c4": 0.01,
                                                            "filmback_width_px": float(SIZE[0]),
                                                            "filmback_height_px": float(SIZE[1])})}
    cam = lens_camera(name) if name in ROUND_TRIP_LENSES else example_camera(
        image_size=SIZE, fx=300.0, fy=297.0, principal_point=(161.3, 118.2), distortion=lenses[name])
    xs, ys = np.arange(-40.0, SIZE[0] + 40), np.arange(-30.0, SIZE[1] + 30)
    x, y = pixels_from_st(st_of_distorted_grid(cam.distortion, cam.K, xs, ys, SIZE), SIZE)
    u, v = np.meshgrid(xs, ys)
    reference = cam.distortion.distort(np.column_stack([u.ravel(), v.ravel()]), cam.K)
    forward = np.hypot(x.ravel() - reference[:, 0], y.ravel() - reference[:, 1])
    X, Y = undistorted_grid(cam.distortion, cam.K, SIZE)
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=float), np.arange(SIZE[1], dtype=float))
    reference = cam.distortion.undistort(np.column_stack([u.ravel(), v.ravel()]), cam.K)
    inverse = np.hypot(X.ravel() - reference[:, 0], Y.ravel() - reference[:, 1])
    finite = np.isfinite(reference).all(axis=1)
    assert np.array_equal(np.isfinite(X.ravel()), finite)
    assert forward[np.isfinite(forward)].max() < 2e-4 and inverse[finite].max() < 1e-8


def test_overscan_factor_or_border():
    from camcal.geometry.stmap import overscan_border

    assert overscan_border((1920, 1080), 1.25) == (240, 135)
    assert overscan_border((1920, 1080), border=32) == (32, 32)
    assert overscan_border((1920, 1080), border=(40, 20)) == (40, 20)
    cam = camera()
    by_factor, by_border = make_stmaps(cam, overscan=1.25), make_stmaps(cam, border=(40, 30))
    assert by_factor.border == by_border.border == (40, 30)
    assert np.array_equal(by_factor.undistort, by_border.undistort)
    assert np.array_equal(by_factor.redistort, by_border.redistort)
    assert by_border.undistorted.image_size == (400, 300)
    for bad, message in (({"overscan": 1.2, "border": 4}, "not both"), ({"border": -1}, "whole pixels >= 0"),
                         ({"border": (1.5, 2)}, "whole pixels >= 0"), ({"overscan": 0.9}, "overscan must be")):
        with pytest.raises(CamcalError, match=message):
            make_stmaps(cam, **bad)


def test_exr_data_window_beyond_the_display_window(tmp_path):
    """The undistort map's EXR: display window = the plate's format from (0, 0), data window = format + border."""
    import OpenEXR

    rig_path = Rig((camera(),)).save(tmp_path / "in.rig.json")
    out = tmp_path / "maps"
    assert main(["stmap", str(rig_path), "--camera", "cam", "--out", str(out), "--border", "24", "10"]) == 0
    with OpenEXR.File(str(out / "cam_undistort.exr")) as exr:
        header = exr.header()
        data = [np.asarray(c).tolist() for c in header["dataWindow"]]
        display = [np.asarray(c).tolist() for c in header["displayWindow"]]
        types = {name: channel.pixels.dtype for name, channel in exr.channels().items()}
    assert data == [[-24, -10], [SIZE[0] + 23, SIZE[1] + 9]] and display == [[0, 0], [SIZE[0] - 1, SIZE[1] - 1]]
    assert set(types.values()) == {np.dtype(np.float32)}
    pixels, border = read_exr_window(out / "cam_undistort.exr")
    maps = make_stmaps(camera(), border=(24, 10))
    assert border == (24, 10) and np.array_equal(pixels, maps.undistort)
    redistort, border = read_exr_window(out / "cam_redistort.exr")
    assert border == (0, 0) and np.array_equal(redistort, maps.redistort)
    undistorted = Rig.load(out / "cam_undistorted.rig.json").camera("cam")
    assert undistorted.image_size == (SIZE[0] + 48, SIZE[1] + 20)
    assert np.allclose(undistorted.K[:2, 2], camera().K[:2, 2] + [24, 10])
    assert main(["stmap", str(rig_path), "--camera", "cam", "--out", str(tmp_path / "x"), "--border", "1", "2",
                 "3"]) == 2
    assert not (tmp_path / "x").exists()


def test_cli_stmap_help_states_the_pixel_centre_convention(capsys):
    with pytest.raises(SystemExit):
        main(["stmap", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "pixel (0, 0) at the centre of the top-left pixel" in text and "--border" in text
