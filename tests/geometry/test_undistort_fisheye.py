"""Fisheye (Kannala-Brandt) plates: undistortion to a pinhole view and ST-maps both ways."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.stmap import make_stmaps, pixels_from_st
from camcal.geometry.undistort import FISHEYE_FOV_DEG, _border, make_undistorter, undistorted_view
from camcal.model.rig import Camera
from camcal.synthetic import procedural_texture, render_planes

W, H = 480, 360
#: about 190 degrees across the diagonal
K = np.array([[137.0, 0.0, 241.3], [0.0, 136.2, 178.6], [0.0, 0.0, 1.0]])
LENS = Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021})
CAMERA = Camera("fish", (W, H), K, LENS, np.eye(3), np.zeros(3))
#: the same lens with COLMAP's RAD_TAN_THIN_PRISM_FISHEYE terms (k5, k6, tangential, thin prism)
LENS_TP = Distortion("kannala-brandt-thin-prism", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021,
                                                   "k5": 2e-5, "k6": -1e-6, "p1": 4e-4, "p2": -3e-4,
                                                   "s1": 5e-4, "s2": -1e-4, "s3": -4e-4, "s4": 1e-4})
CAMERA_TP = Camera("fish-tp", (W, H), K, LENS_TP, np.eye(3), np.zeros(3))


def angle_deg(camera, pixels):
    rays = camera.distortion.rays_from_pixels(pixels, camera.K)
    return np.degrees(np.arccos(np.clip(rays[:, 2], -1.0, 1.0)))


def test_the_lens_sees_beyond_90_degrees():
    corners = np.array([[0.0, 0.0], [W - 1.0, H - 1.0]])
    assert np.all(angle_deg(CAMERA, corners) > 90.0)


@pytest.mark.parametrize("camera", [CAMERA, CAMERA_TP], ids=["kannala-brandt", "kannala-brandt-thin-prism"])
def test_crop_default_field_of_view_and_no_black_border(camera):
    view = undistorted_view(camera, "crop")
    border = _border(view.image_size)
    # the widest output ray is at half the default field of view
    ideal = Camera("u", view.image_size, view.K_new, Distortion.none(), np.eye(3), np.zeros(3))
    assert angle_deg(ideal, border).max() == pytest.approx(FISHEYE_FOV_DEG / 2, abs=1e-6)
    # and every output pixel samples inside the plate
    maps = make_undistorter(camera, "crop").maps
    assert maps.map_x.min() >= -0.5 and maps.map_x.max() <= W - 0.5
    assert maps.map_y.min() >= -0.5 and maps.map_y.max() <= H - 0.5
    if camera is not CAMERA:
        return
    # a wider cap is limited by the plate's frame instead
    wide = undistorted_view(CAMERA, "crop", max_fov_deg=170.0)
    assert wide.K_new[0, 0] < view.K_new[0, 0]
    # the output frame's edge, mapped to the plate, touches the plate's edge (bisection to 1e-6)
    ideal = (border - K[:2, 2]) * (K[0, 0] / wide.K_new[0, 0]) + K[:2, 2]
    source = LENS.distort(ideal, K)
    gaps = np.concatenate([source.min(axis=0) + 0.5, np.array([W, H]) - 0.5 - source.max(axis=0)])
    assert gaps.min() > -1e-6 and gaps.min() < 1e-3


def test_keep_holds_every_plate_pixel_inside_the_field_of_view():
    view = undistorted_view(CAMERA, "keep")
    assert np.allclose(view.K_new[:2, :2], K[:2, :2])
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    plate = np.column_stack([u.ravel(), v.ravel()])
    inside_fov = angle_deg(CAMERA, plate) < FISHEYE_FOV_DEG / 2 - 1e-9
    ideal = LENS.undistort(plate[inside_fov], K) - K[:2, 2] + view.K_new[:2, 2]
    width, height = view.image_size
    assert ideal.min() >= -0.5 - 1e-9
    assert np.all(ideal.max(axis=0) <= np.array([width, height]) - 0.5 + 1e-9)
    with pytest.raises(CamcalError, match="between 0 and 180"):
        undistorted_view(CAMERA, "keep", max_fov_deg=180.0)


def test_undistorted_image_matches_a_pinhole_render():
    """Render a textured scene through the fisheye, undistort it, compare with the same scene seen by K_new."""
    rng = np.random.default_rng(7)
    textures = tuple(procedural_texture(rng, 512) for _ in range(3))
    # three planes boxing the camera in front and below
    planes = (
        (np.array([-6.0, -6.0, 4.0]), np.array([12.0, 0.0, 0.0]), np.array([0.0, 12.0, 0.0])),
        (np.array([-6.0, 1.5, -2.0]), np.array([12.0, 0.0, 0.0]), np.array([0.0, 0.0, 6.0])),
        (np.array([-3.0, -6.0, -2.0]), np.array([0.0, 12.0, 0.0]), np.array([0.0, 0.0, 6.0])),
    )
    plate = render_planes(CAMERA, planes, textures)
    undistorter = make_undistorter(CAMERA, "crop")
    pinhole = render_planes(undistorter.undistorted_camera(), planes, textures).astype(np.float64)
    undistorted = undistorter.apply(plate).astype(np.float64)
    valid = (pinhole > 0) & (undistorted > 0)
    assert valid.mean() > 0.9
    difference = np.abs(undistorted - pinhole)[valid]
    # bilinear resampling twice over a textured scene: a few grey levels, no systematic shift
    assert np.median(difference) < 3.0
    assert abs(np.mean(undistorted[valid] - pinhole[valid])) < 1.0


@pytest.mark.parametrize("camera", [CAMERA, CAMERA_TP], ids=["kannala-brandt", "kannala-brandt-thin-prism"])
def test_stmaps_undistort_and_redistort_are_inverse(camera):
    maps = make_stmaps(camera, overscan=1.5)
    width_u, height_u = maps.undistorted.image_size
    # redistort: plate pixel -> undistorted pixel; undistort: undistorted pixel -> plate pixel
    x_u, y_u = pixels_from_st(maps.redistort, camera.image_size)  # in the undistorted image's format (the plate's)
    x_u, y_u = x_u + maps.border[0], y_u + maps.border[1]  # in its data window, the canvas
    x_p, y_p = pixels_from_st(maps.undistort, camera.image_size)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    on_canvas = (x_u >= 0) & (x_u <= width_u - 1) & (y_u >= 0) & (y_u <= height_u - 1)
    assert on_canvas.mean() > 0.3
    # sample the undistort map at the redistorted positions (bilinear, in float64) and come back to the plate pixel;
    # not cv2.remap: OpenCV 4's quantises the bilinear weights to 1/32 (about 0.017 px here at the 99th percentile)
    from scipy.ndimage import map_coordinates

    back_x = map_coordinates(x_p, [y_u, x_u], order=1, mode="nearest")
    back_y = map_coordinates(y_p, [y_u, x_u], order=1, mode="nearest")
    error = np.hypot(back_x - u, back_y - v)[on_canvas]
    # bilinear interpolation of a smooth map at a 1 px grid: well under a hundredth of a pixel here
    assert np.percentile(error, 99) < 0.01
    # plate pixels beyond 90 degrees have no undistorted position: the sentinel, outside [0, 1]
    beyond = angle_deg(camera, np.column_stack([u.ravel(), v.ravel()])).reshape(H, W) >= 90.0
    assert beyond.any()
    assert np.all((maps.redistort[beyond][:, 0] < 0) | (maps.redistort[beyond][:, 0] > 1))


def test_cli_undistorts_a_fisheye_plate_with_a_chosen_field_of_view(tmp_path, capsys):
    import cv2

    from camcal.cli import main
    from camcal.model.rig import Rig

    rig_path = Rig((CAMERA,)).save(tmp_path / "fish.rig.json")
    plate = tmp_path / "plate.png"
    cv2.imwrite(str(plate), procedural_texture(np.random.default_rng(8), 512)[:H, :W])
    out = tmp_path / "out"
    assert main(["undistort", str(rig_path), "--camera", "fish", "--images", str(plate), "--mode", "crop",
                 "--max-fov", "100", "--out", str(out)]) == 0
    camera = Rig.load(out / "undistorted.rig.json").camera("fish")
    assert camera.distortion.model == "none"
    expected = undistorted_view(CAMERA, "crop", max_fov_deg=100.0)
    assert np.allclose(camera.K, expected.K_new)
    assert cv2.imread(str(out / "plate.png")).shape[:2] == (H, W)
    # out of range: one line, exit 2, nothing written
    capsys.readouterr()
    bad = tmp_path / "bad"
    assert main(["undistort", str(rig_path), "--camera", "fish", "--images", str(plate), "--max-fov", "200", "--out", str(bad)]) == 2
    assert "must be between 0 and 180 degrees, got 200" in capsys.readouterr().err
    assert not bad.exists()
