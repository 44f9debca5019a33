"""camcal <-> COLMAP camera models: same pixels as pycolmap, both ways."""

import numpy as np
import pycolmap
import pytest

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.model.colmap import camera_from_colmap, camera_to_colmap
from camcal.synthetic import example_camera, points_in_view

CASES = {
    "none square": dict(fx=1500.0, fy=1500.0),
    "none": dict(),
    "polynomial square": dict(fx=1500.0, fy=1500.0, distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02})),
    "polynomial": dict(distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02})),
    "polynomial k3": dict(distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02, "k3": -0.003})),
    "opencv": dict(distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 4e-4, "p2": -2e-4, "k3": 0.0})),
    "opencv k3": dict(distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 4e-4, "p2": -2e-4, "k3": 0.002})),
    "opencv rational": dict(distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 4e-4, "p2": -2e-4, "k3": 0.002,
                                                           "k4": 0.05, "k5": 0.01, "k6": -0.002})),
    "division": dict(fx=1500.0, fy=1500.0, distortion=Distortion("division", {"lambda": -6e-8})),
    "kannala-brandt": dict(fx=520.0, fy=517.0, distortion=Distortion(
        "kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021})),
}


def colmap_pixels(camera, X):
    colmap = camera_to_colmap(camera)
    pc = pycolmap.Camera(model=colmap.model, width=colmap.width, height=colmap.height, params=list(colmap.params))
    cam_points = (X - camera.c) @ camera.R.T
    return colmap, pc.img_from_cam(cam_points)


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_colmap_projects_like_camcal(case):
    camera = example_camera(**CASES[case])
    X = points_in_view(camera, 200, np.random.default_rng(0))
    colmap, theirs = colmap_pixels(camera, X)
    # COLMAP's top-left pixel centre is at (0.5, 0.5)
    assert np.abs(theirs - 0.5 - camera.project(X)).max() < 1e-8
    back = camera_from_colmap("back", colmap.model, camera.image_size, colmap.params, camera.R, camera.c)
    assert np.abs(back.project(X) - camera.project(X)).max() < 1e-8


def test_division_parameter_scaling_on_a_known_point():
    """k = lambda f^2: one corner pixel, computed by hand from both definitions."""
    f, lam = 1000.0, -1e-7
    camera = example_camera(fx=f, fy=f, principal_point=(639.5, 479.5), image_size=(1280, 960),
                            distortion=Distortion("division", {"lambda": lam}))
    colmap = camera_to_colmap(camera)
    assert colmap.model == "SIMPLE_DIVISION"
    assert colmap.params == (f, 640.0, 480.0, lam * f * f)


def test_division_with_two_focals_is_colmap_division():
    """fx != fy: the division lens with aspect fx / fy is COLMAP's DIVISION, k = lambda fx^2; another aspect is refused."""
    with pytest.raises(CamcalError, match="aspect = fx / fy"):
        camera_to_colmap(example_camera(fx=1600.0, fy=800.0, distortion=Distortion("division", {"lambda": -1e-7})))
    camera = example_camera(fx=1600.0, fy=800.0, principal_point=(639.5, 479.5), image_size=(1280, 960),
                            distortion=Distortion("division", {"lambda": -1e-7, "aspect": 2.0}))
    colmap = camera_to_colmap(camera)
    assert colmap.model == "DIVISION"
    assert colmap.params == (1600.0, 800.0, 640.0, 480.0, -1e-7 * 1600.0**2)
    X = points_in_view(camera, 200, np.random.default_rng(1))
    _, theirs = colmap_pixels(camera, X)
    assert np.abs(theirs - 0.5 - camera.project(X)).max() < 1e-8
    back = camera_from_colmap("back", colmap.model, camera.image_size, colmap.params, camera.R, camera.c)
    assert np.abs(back.project(X) - camera.project(X)).max() < 1e-8
    assert back.distortion.params["aspect"] == 2.0


def test_rad_tan_thin_prism_fisheye_both_ways():
    """kannala-brandt-thin-prism is RAD_TAN_THIN_PRISM_FISHEYE (COLMAP's p0 is OpenCV's p2) to 1e-8 px."""
    names = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "s1", "s2", "s3", "s4")
    values = (0.02, -0.01, 0.003, -5e-4, 1e-4, -1e-5, 3e-4, -2e-4, 1e-4, -5e-5, 2e-4, 3e-5)
    lens = Distortion("kannala-brandt-thin-prism", dict(zip(names, values)))
    camera = example_camera(fx=455.0, fy=452.5, principal_point=(803.7, 596.2), image_size=(1600, 1200),
                            distortion=lens)
    colmap = camera_to_colmap(camera)
    assert colmap.model == "RAD_TAN_THIN_PRISM_FISHEYE"
    assert colmap.params[10:12] == (-2e-4, 3e-4)
    pc = pycolmap.Camera(model=colmap.model, width=colmap.width, height=colmap.height, params=list(colmap.params))
    rng = np.random.default_rng(7)
    theta, phi = rng.uniform(0.0, np.radians(85.0), 2000), rng.uniform(-np.pi, np.pi, 2000)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    ours = lens.project_rays(rays, camera.K)
    assert np.abs(pc.img_from_cam(rays) - 0.5 - ours).max() < 1e-8
    assert np.abs(lens.rays_from_pixels(ours, camera.K) - rays).max() < 1e-10
    back = camera_from_colmap("back", colmap.model, camera.image_size, colmap.params, camera.R, camera.c)
    assert back.distortion == lens


def test_unmappable_cameras_are_refused():
    with pytest.raises(CamcalError, match="skew"):
        camera_to_colmap(example_camera(skew=0.5))
    with pytest.raises(CamcalError, match="centred on the principal point"):
        camera_to_colmap(example_camera(fx=1500.0, fy=1500.0, distortion=Distortion("division", {"lambda": -1e-7}, center=(900.0, 500.0))))
    with pytest.raises(CamcalError, match="no thin-prism terms"):
        camera_to_colmap(example_camera(distortion=Distortion.from_opencv_coefficients([0.1] * 4 + [0.0] * 7 + [1e-3])))
    with pytest.raises(CamcalError, match="no camcal counterpart"):
        camera_from_colmap("x", "THIN_PRISM_FISHEYE", (10, 10), [1, 1, 1, 1] + [0] * 8, np.eye(3), np.zeros(3))
    with pytest.raises(CamcalError, match="takes 4 parameters, got 3"):
        camera_from_colmap("x", "PINHOLE", (10, 10), [1, 1, 1], np.eye(3), np.zeros(3))


def test_opencv_fisheye_both_ways_on_wide_rays():
    """OPENCV_FISHEYE: img_from_cam and cam_from_img agree with camcal to 1e-8 px up to 85 degrees off axis."""
    lens = Distortion("kannala-brandt", {"k1": -0.08, "k2": 0.012, "k3": -0.0011, "k4": 0.0002})
    camera = example_camera(fx=455.0, fy=452.5, principal_point=(803.7, 596.2), image_size=(1600, 1200),
                            distortion=lens)
    colmap = camera_to_colmap(camera)
    assert colmap.model == "OPENCV_FISHEYE"
    assert colmap.params == (455.0, 452.5, 804.2, 596.7, -0.08, 0.012, -0.0011, 0.0002)
    pc = pycolmap.Camera(model=colmap.model, width=colmap.width, height=colmap.height, params=list(colmap.params))
    rng = np.random.default_rng(5)
    theta, phi = rng.uniform(0.0, np.radians(85.0), 2000), rng.uniform(-np.pi, np.pi, 2000)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    ours = lens.project_rays(rays, camera.K)
    assert np.abs(pc.img_from_cam(rays) - 0.5 - ours).max() < 1e-8
    # cam_from_img gives x / z, y / z (an iterative inverse): its rays land within 1e-8 px of the pixel
    theirs = pc.cam_from_img(ours + 0.5) @ camera.K[:2, :2].T + camera.K[:2, 2]
    assert np.abs(lens.distort(theirs, camera.K) - ours).max() < 1e-8
    pinhole = camera.distortion.undistort(ours, camera.K)
    assert np.max(np.abs(theirs - pinhole) / np.maximum(1.0, np.abs(pinhole))) < 1e-8
    # COLMAP refuses rays behind the camera; camcal images them up to max_angle_rad
    behind = np.array([[0.9, 0.1, -0.2]])
    assert np.all(np.isnan(pc.img_from_cam(behind)))
    assert np.all(np.isfinite(lens.project_rays(behind, camera.K)))


@pytest.mark.parametrize(
    "model, params",
    [
        ("SIMPLE_FISHEYE", [480.0, 400.5, 300.5]),
        ("FISHEYE", [480.0, 476.0, 400.5, 300.5]),
        ("SIMPLE_RADIAL_FISHEYE", [480.0, 400.5, 300.5, 0.03]),
        ("RADIAL_FISHEYE", [480.0, 400.5, 300.5, 0.03, -0.004]),
        ("OPENCV_FISHEYE", [480.0, 476.0, 400.5, 300.5, 0.03, -0.004, 0.001, -0.0002]),
    ],
)
def test_colmap_fisheye_family_reads_as_kannala_brandt(model, params):
    pc = pycolmap.Camera(model=model, width=800, height=600, params=params)
    camera = camera_from_colmap("fish", model, (800, 600), params, np.eye(3), np.zeros(3))
    assert camera.distortion.model == "kannala-brandt"
    rng = np.random.default_rng(6)
    X = np.column_stack([rng.uniform(-1, 1, (500, 2)), rng.uniform(0.1, 1.0, 500)])
    assert np.abs(pc.img_from_cam(X) - 0.5 - camera.project(X)).max() < 1e-8
