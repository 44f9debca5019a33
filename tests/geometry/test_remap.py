"""One-remap warps: a synthetic image of known content lands where the model says."""

import numpy as np

from camcal.geometry.distortion import Distortion
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
