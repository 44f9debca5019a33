"""One-remap warps: a synthetic image of known content lands where the model says."""

import numpy as np

from camcal.model.distortion import Distortion
from camcal.geometry.remap import build_maps, undistort_homography
from camcal.synthetic import example_camera


def test_undistort_map_moves_a_dot_to_its_ideal_position():
    camera = example_camera(image_size=(320, 240), fx=300.0, fy=300.0, principal_point=(161.0, 118.5),
                            distortion=Distortion("division", {"lambda": -2e-6}))
    ideal = np.array([[280.0, 40.0]])
    distorted = camera.distortion.distort(ideal, camera.K)[0]
    # a Gaussian dot at the distorted position in the source image
    v, u = np.mgrid[0:240, 0:320]
    source = np.exp(-((u - distorted[0]) ** 2 + (v - distorted[1]) ** 2) / (2 * 1.5**2)).astype(np.float32)
    maps = build_maps(camera, undistort_homography(camera, camera.K), camera.image_size)
    out = maps.apply(source)
    weights = out / out.sum()
    centroid = np.array([(weights * u).sum(), (weights * v).sum()])
    assert np.abs(centroid - ideal[0]).max() < 0.05
    assert np.linalg.norm(distorted - ideal[0]) > 5.0  # the lens moved it noticeably


# -- the fast map paths equal the point-by-point reference ------------------------------

import pytest  # noqa: E402

from camcal.geometry.remap import build_maps_reference  # noqa: E402

FAST_LENSES = {
    "none": Distortion.none(),
    "polynomial": Distortion("polynomial", {"k1": 0.06, "k2": 0.01, "k3": -0.002}),
    "opencv": Distortion("opencv", {"k1": -0.18, "k2": 0.04, "p1": 0.001, "p2": -0.0008, "k3": 0.01}),
    "division": Distortion("division", {"lambda": -4e-7}, center=(322.0, 236.0)),
    "division-past-range": Distortion("division", {"lambda": 3e-6}),
    "division-aspect": Distortion("division", {"lambda": -4e-7, "aspect": 520.0 / 518.0}),
    "kannala-brandt": Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}),
    # one-to-one only up to 37 degrees: the reference path, NaN beyond
    "kannala-brandt-past-range": Distortion("kannala-brandt", {"k1": -0.9, "k2": 0.0, "k3": 0.0, "k4": 0.0}),
    # no fast path: the reference itself (the test checks that the dispatch reaches it)
    "kannala-brandt-thin-prism": Distortion("kannala-brandt-thin-prism", {
        "k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021, "k5": 2e-5, "k6": -1e-6, "p1": 4e-4,
        "p2": -3e-4, "s1": 5e-4, "s2": -1e-4, "s3": -4e-4, "s4": 1e-4}),
}


@pytest.mark.parametrize("name", FAST_LENSES)
@pytest.mark.parametrize("skew", [0.0, 1.5])
def test_fast_maps_equal_the_reference_to_a_thousandth_of_a_pixel(name, skew):
    camera = example_camera(image_size=(640, 480), fx=520.0, fy=518.0, skew=skew,
                            principal_point=(318.7, 241.2), distortion=FAST_LENSES[name])
    # a projective H (rectification-like) on a canvas larger than the plate
    K_new = camera.K.copy()
    K_new[:2, :2] *= 0.8
    H = np.array([[1.0, 0.02, 5.0], [-0.01, 0.99, -3.0], [2e-5, -1e-5, 1.0]]) @ undistort_homography(camera, K_new)
    fast = build_maps(camera, H, (700, 520))
    reference = build_maps_reference(camera, H, (700, 520))
    no_source = reference.map_x == -1.0
    if name.endswith("past-range"):
        assert no_source.any()  # the corners lie beyond the model's range
    assert np.array_equal(fast.map_x == -1.0, no_source)
    assert np.abs(fast.map_x - reference.map_x).max() < 1e-3
    assert np.abs(fast.map_y - reference.map_y).max() < 1e-3

