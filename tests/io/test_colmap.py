"""camcal <-> COLMAP camera models: same pixels as pycolmap, both ways."""

import numpy as np
import pycolmap
import pytest

from camcal.errors import CamcalError
from camcal.geometry.distortion import Distortion
from camcal.io.colmap import camera_from_colmap, camera_to_colmap
from camcal.synthetic import example_camera, points_in_view

CASES = {
    "none square": dict(fx=1500.0, fy=1500.0),
    "none": dict(),
    "polynomial square": dict(fx=1500.0, fy=1500.0, distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02})),
    "polynomial": dict(distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02})),
    "polynomial k3": dict(distortion=Distortion("polynomial", {"k1": -0.11, "k2": 0.02, "k3": -0.003})),
    "opencv": dict(distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 4e-4, "p2": -2e-4, "k3": 0.0})),
    "opencv k3": dict(distortion=Distortion("opencv", {"k1": -0.1, "k2": 0.01, "p1": 4e-4, "p2": -2e-4, "k3": 0.002})),
    "division": dict(fx=1500.0, fy=1500.0, distortion=Distortion("division", {"lambda": -6e-8})),
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


def test_unmappable_cameras_are_refused():
    with pytest.raises(CamcalError, match="skew"):
        camera_to_colmap(example_camera(skew=0.5))
    with pytest.raises(CamcalError, match="fx = fy"):
        camera_to_colmap(example_camera(distortion=Distortion("division", {"lambda": -1e-7})))
    with pytest.raises(CamcalError, match="centred on the principal point"):
        camera_to_colmap(example_camera(fx=1500.0, fy=1500.0, distortion=Distortion("division", {"lambda": -1e-7}, center=(900.0, 500.0))))
    with pytest.raises(CamcalError, match="no camcal counterpart"):
        camera_from_colmap("x", "OPENCV_FISHEYE", (10, 10), [1, 1, 1, 1, 0, 0, 0, 0], np.eye(3), np.zeros(3))
    with pytest.raises(CamcalError, match="takes 4 parameters, got 3"):
        camera_from_colmap("x", "PINHOLE", (10, 10), [1, 1, 1], np.eye(3), np.zeros(3))
