"""Kannala-Brandt (OpenCV fisheye) distortion: definition, round trips, cv2.fisheye, rays beyond 90 degrees."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion, fit_distortion
from camcal.model.rig import Camera, Rig

W, H = 1600, 1200
#: An action-camera-like lens: about 190 degrees across the diagonal.
K = np.array([[455.0, 0.0, 803.7], [0.0, 452.5, 596.2], [0.0, 0.0, 1.0]])
LENSES = [
    Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}),
    Distortion("kannala-brandt", {"k1": -0.08, "k2": 0.012, "k3": -0.0011, "k4": 0.0}),
    Distortion("kannala-brandt", {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0}),
]
IDS = ["wide", "strong-barrel", "equidistant"]


def coefficients(lens):
    return np.array([lens.params[k] for k in ("k1", "k2", "k3", "k4")])


def random_rays(n, max_angle, rng):
    """Unit rays spread over the cap of half-angle ``max_angle`` about +z."""
    theta = rng.uniform(0.0, max_angle, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def test_definition_on_a_hand_computed_ray():
    """theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8), x_d = theta_d x / r."""
    lens = LENSES[0]
    x, y = 0.6, -0.35
    r = np.hypot(x, y)
    theta = np.arctan(r)
    k1, k2, k3, k4 = coefficients(lens)
    theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    expected = [K[0, 0] * theta_d * x / r + K[0, 2], K[1, 1] * theta_d * y / r + K[1, 2]]
    pixel = K @ [x, y, 1.0]
    assert np.abs(lens.distort(pixel[None, :2], K)[0] - expected).max() < 1e-12


@pytest.mark.parametrize("lens", LENSES, ids=IDS)
def test_matches_cv2_fisheye_project_and_undistort(lens):
    rng = np.random.default_rng(1)
    rays = random_rays(2000, np.radians(85.0), rng)
    ours = lens.project_rays(rays, K)
    theirs = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, coefficients(lens))[0]
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-9
    # pinhole pixels of the same rays
    pinhole = ((rays / rays[:, 2:]) @ K.T)[:, :2]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    theirs_u = cv2.fisheye.undistortPoints(ours.reshape(-1, 1, 2), K, coefficients(lens), P=K, criteria=criteria)
    ours_u = lens.undistort(ours, K)
    scale = np.maximum(1.0, np.abs(pinhole))  # pinhole pixels near 85 deg are ~ 5000 px out
    assert np.max(np.abs(ours_u - pinhole) / scale) < 1e-12
    # OpenCV clamps theta_d to pi / 2 before inverting: compare below that
    inside = lens.theta_d(np.arccos(rays[:, 2])) < 0.5 * np.pi
    assert inside.mean() > 0.9
    assert np.max(np.abs(ours_u - theirs_u.reshape(-1, 2))[inside] / scale[inside]) < 1e-9


@pytest.mark.parametrize("lens", LENSES, ids=IDS)
def test_round_trips_below_1e_8_px(lens):
    # every distorted pixel of the frame whose ray is in front of the camera
    u, v = np.meshgrid(np.arange(0.0, W, 7.0), np.arange(0.0, H, 7.0))
    distorted = np.column_stack([u.ravel(), v.ravel()])
    ideal = lens.undistort(distorted, K)
    front = np.all(np.isfinite(ideal), axis=1)
    assert front.mean() > 0.5
    assert np.abs(lens.distort(ideal[front], K) - distorted[front]).max() < 1e-8
    # and back: undistorted pixels up to 80 degrees off axis
    rays = random_rays(3000, np.radians(80.0), np.random.default_rng(2))
    pinhole = ((rays / rays[:, 2:]) @ K.T)[:, :2]
    back = lens.undistort(lens.distort(pinhole, K), K)
    assert np.max(np.abs(back - pinhole) / np.maximum(1.0, np.abs(pinhole))) < 1e-12


@pytest.mark.parametrize("lens", LENSES[:2], ids=IDS[:2])
def test_rays_beyond_90_degrees(lens):
    """project_rays / rays_from_pixels hold up to max_angle_rad; pinhole undistortion does not pass 90 deg."""
    limit = min(lens.max_angle_rad, np.radians(110.0))
    rays = random_rays(3000, limit, np.random.default_rng(3))
    pixels = lens.project_rays(rays, K)
    assert np.all(np.isfinite(pixels))
    back = lens.rays_from_pixels(pixels, K)
    assert np.abs(back - rays).max() < 1e-12
    # round trip in pixels
    assert np.abs(lens.project_rays(back, K) - pixels).max() < 1e-8
    behind = rays[:, 2] <= 0.0
    assert behind.any()
    assert np.all(np.isnan(lens.undistort(pixels[behind], K)))
    assert np.all(np.isfinite(lens.undistort(pixels[~behind], K)))


def test_max_angle_is_where_theta_d_turns():
    lens = Distortion("kannala-brandt", {"k1": -0.1, "k2": 0.0, "k3": 0.0, "k4": 0.0})
    # d/dtheta theta (1 - 0.1 theta^2) = 1 - 0.3 theta^2 = 0
    assert lens.max_angle_rad == pytest.approx(np.sqrt(1 / 0.3), rel=1e-12)
    beyond = np.array([[np.sin(1.9), 0.0, np.cos(1.9)]])
    assert np.all(np.isnan(lens.project_rays(beyond, K)))
    edge = lens.theta_d(lens.max_angle_rad)
    assert np.all(np.isnan(lens.rays_from_pixels(K[:2, 2] + [[K[0, 0] * edge * 1.001, 0.0]], K)))
    # up to the turning point, where the slope vanishes, the inverse still lands on theta_d
    theta = np.linspace(lens.max_angle_rad - 1e-3, lens.max_angle_rad, 50)
    rays = np.column_stack([np.sin(theta), np.zeros(50), np.cos(theta)])
    back = lens.rays_from_pixels(lens.project_rays(rays, K), K)
    assert np.abs(lens.theta_d(np.arccos(back[:, 2])) - lens.theta_d(theta)).max() < 1e-13
    assert LENSES[2].max_angle_rad == pytest.approx(np.pi)
    assert not LENSES[2].is_identity  # all k = 0 is the equidistant fisheye
    assert Distortion("polynomial", {"k1": 0.1, "k2": 0.0}).max_angle_rad == pytest.approx(np.pi / 2)


def test_camera_projects_points_behind_the_image_plane():
    lens = LENSES[0]
    camera = Camera("fish", (W, H), K, lens, np.eye(3), np.zeros(3))
    X = np.array([[1.0, 0.2, -0.1], [0.0, 0.0, 2.0]])
    projected = camera.project(X)
    assert np.all(np.isfinite(projected))
    assert np.abs(projected[1] - K[:2, 2]).max() < 1e-12
    ray = lens.rays_from_pixels(projected[:1], K)[0]
    assert np.abs(ray - X[0] / np.linalg.norm(X[0])).max() < 1e-12


def test_other_models_rays_agree_with_pinhole_undistortion():
    lens = Distortion("opencv", {"k1": -0.2, "k2": 0.05, "p1": 0.001, "p2": -0.0007, "k3": -0.004})
    rays = random_rays(500, np.radians(40.0), np.random.default_rng(4))
    pixels = lens.project_rays(rays, K)
    assert np.abs(pixels - lens.distort(((rays / rays[:, 2:]) @ K.T)[:, :2], K)).max() < 1e-9
    assert np.abs(lens.rays_from_pixels(pixels, K) - rays).max() < 1e-10
    assert np.all(np.isnan(lens.project_rays(np.array([[0.0, 0.1, -1.0]]), K)))


def test_rig_file_round_trip(tmp_path):
    camera = Camera("fish", (W, H), K, LENSES[0], np.eye(3), np.zeros(3))
    path = Rig((camera,)).save(tmp_path / "fish.rig.json")
    loaded = Rig.load(path).cameras[0]
    assert loaded.distortion == camera.distortion


@pytest.mark.parametrize(
    "params, message",
    [
        ({"k1": 0.1, "k2": 0.0, "k3": 0.0}, "needs parameter"),
        ({"k1": 0.1, "k2": 0.0, "k3": 0.0, "k4": 0.0, "k5": 1.0}, "has no parameter"),
        ({"k1": float("nan"), "k2": 0.0, "k3": 0.0, "k4": 0.0}, "not finite"),
    ],
)
def test_bad_parameters_are_named(params, message):
    with pytest.raises(CamcalError, match=message):
        Distortion("kannala-brandt", params)
    with pytest.raises(CamcalError, match="centred on the principal point"):
        Distortion("kannala-brandt", dict.fromkeys(("k1", "k2", "k3", "k4"), 0.0), center=(1.0, 2.0))


def test_nan_input_stays_nan():
    lens = LENSES[0]
    points = np.array([[np.nan, 3.0], [np.inf, 2.0]])
    assert np.all(np.isnan(lens.undistort(points, K)))
    assert np.all(np.isnan(lens.rays_from_pixels(points, K)))


def test_fit_recovers_kannala_brandt_and_converts_from_it():
    truth = LENSES[0]
    fit = fit_distortion(truth, K, (W, H), "kannala-brandt")
    assert fit.max_px < 1e-6
    assert np.abs(coefficients(fit.distortion) - coefficients(truth)).max() < 1e-6
    # a moderate pinhole lens is a fisheye lens too: polynomial -> Kannala-Brandt and back
    K_narrow = np.array([[1400.0, 0.0, 965.2], [0.0, 1395.0, 538.9], [0.0, 0.0, 1.0]])
    poly = Distortion("polynomial", {"k1": -0.12, "k2": 0.03})
    to_kb = fit_distortion(poly, K_narrow, (1920, 1080), "kannala-brandt")
    assert to_kb.max_px < 0.05
    # the residual reported is the true one over the frame
    u, v = np.meshgrid(np.arange(0.0, 1920, 16.0), np.arange(0.0, 1080, 16.0))
    grid = np.column_stack([u.ravel(), v.ravel()])
    ideal = poly.undistort(grid, K_narrow)
    true_max = np.linalg.norm(to_kb.distortion.distort(ideal, K_narrow) - grid, axis=1).max()
    assert to_kb.max_px == pytest.approx(true_max, rel=0.05, abs=1e-4)
    back = fit_distortion(to_kb.distortion, K_narrow, (1920, 1080), "polynomial", with_k3=True)
    assert back.max_px < 0.05
