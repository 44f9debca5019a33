"""The synthetic renderer: a pixel shows the texture where the camera's forward projection puts the plane's point."""

import numpy as np

from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from camcal.synthetic import pixel_rays, render_planes

RAMP = np.tile(np.arange(256, dtype=np.uint8), (256, 1))  # texture value = 255 s along the plane's s axis
FLAT = np.full((256, 256), 7, np.uint8)


def _camera():
    centre = np.array([0.3, -2.0, 0.4])
    K = np.array([[140.0, 0.0, 81.0], [0.0, 141.0, 58.5], [0.0, 0.0, 1.0]])
    lens = Distortion("polynomial", {"k1": -0.12, "k2": 0.02})
    return Camera("cam", (160, 120), K, lens, look_at(centre, [0.5, 0.0, 0.5]), centre)


def test_a_rendered_pixel_holds_the_texture_of_the_plane_point_projected_there_and_the_nearer_plane_hides():
    """A ramp plane (wall y = 0) seen through a distorted lens: at the forward projection (``Camera.project``) of
    its points the image holds 255 s to a grey level; a flat plane in front of part of it shows its own value
    there; the rays computed once give the same image."""
    camera = _camera()
    wall = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    board = (np.array([0.05, -0.5, 0.05]), np.array([0.2, 0.0, 0.0]), np.array([0.0, 0.0, 0.2]))
    image = render_planes(camera, (wall, board), (RAMP, FLAT))
    np.testing.assert_array_equal(render_planes(camera, (wall, board), (RAMP, FLAT), pixel_rays(camera)), image)
    rng = np.random.default_rng(3)
    s, t = rng.uniform(0.35, 0.95, 40), rng.uniform(0.35, 0.95, 40)
    pixels = np.round(camera.project(np.stack([s, np.zeros(40), t], axis=1))).astype(int)
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < 160) & (pixels[:, 1] >= 0) & (pixels[:, 1] < 120)
    assert inside.sum() >= 30
    # the grey level moves 255 / W_plane-px per pixel: rounding the pixel moves it by up to ~1.4 levels
    seen = image[pixels[inside, 1], pixels[inside, 0]].astype(float)
    np.testing.assert_allclose(seen, 255 * s[inside], atol=2.5)
    corner = np.round(camera.project([[0.15, -0.5, 0.15]])[0]).astype(int)
    assert image[corner[1], corner[0]] == 7
