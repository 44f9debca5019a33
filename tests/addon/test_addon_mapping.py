"""The intrinsics / axes / lens mapping to Blender (mapping.py, tracking.py), checked without Blender.

``_blender_project`` re-implements Blender's camera projection
(``BKE_camera_params_compute_viewplane``) from its settings, so the mapping
is checked here against an independent model and, in test_addon_importer.py,
against Blender itself.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from addon_helpers import project_ref, rotation
from addon_helpers import addon  # noqa: F401  (fixtures)


def _blender_project(b, Xc):
    """Project Blender-camera-axis points (N, 3; looking down -Z) with Blender's viewplane maths."""
    W, H = b.resolution_x, b.resolution_y
    ycor = b.pixel_aspect_y / b.pixel_aspect_x
    if b.sensor_fit == "AUTO":
        horizontal = W * b.pixel_aspect_x >= H * b.pixel_aspect_y
        sensor = b.sensor_width
    else:
        horizontal = b.sensor_fit == "HORIZONTAL"
        sensor = b.sensor_width if horizontal else b.sensor_height
    viewfac = W if horizontal else ycor * H
    pixsize = sensor / b.lens / viewfac  # at unit distance
    dx, dy = b.shift_x * viewfac, b.shift_y * viewfac
    xmin, ymin = -0.5 * W + dx, -0.5 * ycor * H + dy
    x = Xc[:, 0] / -Xc[:, 2] / pixsize - xmin  # from the left edge, in pixels
    y = Xc[:, 1] / -Xc[:, 2] / pixsize - ymin  # from the bottom edge, in ycor units
    return np.c_[x - 0.5, H - y / ycor - 0.5]


sizes = st.sampled_from([(1920, 1080), (1080, 1920), (1000, 1000), (640, 480), (333, 777)])
fits = st.sampled_from(["AUTO", "HORIZONTAL", "VERTICAL"])


@settings(max_examples=200, deadline=None)
@given(size=sizes, fit=fits, f=st.floats(200, 5000), aspect=st.floats(0.7, 1.4),
       ox=st.floats(-0.2, 0.2), oy=st.floats(-0.2, 0.2), sensor=st.floats(5, 70))
def test_intrinsics_reproduce_K(addon, size, fit, f, aspect, ox, oy, sensor):
    W, H = size
    K = [[f, 0, (W - 1) / 2 + ox * W], [0, f * aspect, (H - 1) / 2 + oy * H], [0, 0, 1]]
    b = addon.mapping.blender_intrinsics(K, size, sensor, fit)
    assert b.sensor_fit == fit and b.effective_fit in ("HORIZONTAL", "VERTICAL")
    assert min(b.pixel_aspect_x, b.pixel_aspect_y) == 1.0
    assert np.allclose(addon.mapping.intrinsics_from_blender(b), K, rtol=1e-12, atol=1e-9)
    rng = np.random.default_rng(0)
    Xcv = np.c_[rng.uniform(-1, 1, (20, 2)), rng.uniform(1, 5, 20)]
    ref = project_ref(K, np.eye(3), [0, 0, 0], Xcv)
    got = _blender_project(b, Xcv * [1, -1, -1])  # camcal camera axes -> Blender camera axes
    assert np.abs(got - ref).max() < 1e-9 * f


def test_intrinsics_formulas_by_hand(addon):
    # 1920x1080, square pixels, horizontal fit: lens = fx * 36 / 1920.
    b = addon.mapping.blender_intrinsics([[1000, 0, 959.5], [0, 1000, 539.5], [0, 0, 1]], (1920, 1080))
    assert b.effective_fit == "HORIZONTAL"
    assert b.lens == pytest.approx(1000 * 36 / 1920)
    assert b.shift_x == 0 and b.shift_y == 0  # centred: (W/2 - (cx + 0.5)) = 0
    # Principal point 10 px right of centre: shift_x = -10 / 1920.
    b = addon.mapping.blender_intrinsics([[1000, 0, 969.5], [0, 1000, 539.5], [0, 0, 1]], (1920, 1080))
    assert b.shift_x == pytest.approx(-10 / 1920)
    # Portrait: AUTO picks the vertical fit, viewfac = H.
    b = addon.mapping.blender_intrinsics([[1000, 0, 539.5], [0, 1000, 959.5], [0, 0, 1]], (1080, 1920))
    assert b.effective_fit == "VERTICAL" and b.lens == pytest.approx(1000 * 36 / 1920)
    # fy > fx: pixels taller than wide in Blender's terms, ax / ay = fy / fx.
    b = addon.mapping.blender_intrinsics([[1000, 0, 99.5], [0, 1100, 99.5], [0, 0, 1]], (200, 200))
    assert (b.pixel_aspect_x, b.pixel_aspect_y) == (pytest.approx(1.1), 1.0)
    with pytest.raises(ValueError, match="sensor_fit: unknown 'WIDE'"):
        addon.mapping.blender_intrinsics([[1, 0, 0], [0, 1, 0], [0, 0, 1]], (2, 2), sensor_fit="WIDE")


def test_axes_and_camera_matrix(addon):
    m = addon.mapping
    R = rotation(0.3, -0.5, 1.1)
    c = np.array([1.0, -2.0, 0.5])
    M = np.array(m.camera_matrix_local(R, c))
    assert np.allclose(M[:3, 3], c)
    Rb = np.array(m.camera_rotation_blender(R))
    assert np.allclose(Rb, np.diag([1, -1, -1]) @ R)
    assert np.allclose(M[:3, :3], Rb.T)
    # A point in front of the camera (camcal +z) is at Blender camera -z.
    X = c + R.T @ [0.2, 0.1, 3.0]
    Xcam = np.linalg.inv(M) @ np.r_[X, 1]
    assert np.allclose(Xcam[:3], [0.2, -0.1, -3.0])
    for axis, up in (("Z", [0, 0, 1]), ("Y", [0, 1, 0]), ("-Y", [0, -1, 0])):
        U = np.array(m.up_axis_matrix(axis))
        assert np.allclose(U[:3, :3] @ up, [0, 0, 1])
        assert np.linalg.det(U[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="up_axis"):
        m.up_axis_matrix("X")


@settings(max_examples=100, deadline=None)
@given(lam=st.floats(-4e-7, 4e-7), x=st.floats(0, 1919), y=st.floats(0, 1079))
def test_division_round_trip(addon, lam, x, y):
    m = addon.tracking
    c = (950.3, 548.1)
    # Distorted pixels over the frame: undistort, then distort back.
    u = m.division_undistort((x, y), c, lam)
    d = m.division_distort(u, c, lam)
    assert math.hypot(d[0] - x, d[1] - y) < 1e-8


@settings(max_examples=100, deadline=None)
@given(k1=st.floats(-0.2, 0.2), k2=st.floats(-0.05, 0.05), x=st.floats(0, 1919), y=st.floats(0, 1079))
def test_polynomial_round_trip(addon, k1, k2, x, y):
    m = addon.tracking
    c, f = (950.3, 548.1), 1500.0
    d = m.polynomial_distort((x, y), c, f, [k1, k2])
    u = m.polynomial_undistort(d, c, f, [k1, k2])
    assert math.hypot(u[0] - x, u[1] - y) < 1e-8


def test_lens_mapping(addon):
    m, Distortion = addon.tracking, addon.rigfile.Distortion
    K = [[1000, 0, 950], [0, 1000, 530], [0, 0, 1]]
    lens = m.blender_lens(Distortion("division", {"lambda": -1.2e-7}, (959.5, 539.5)), K, (1920, 1080))
    assert lens.distortion_model == "NUKE"
    assert lens.params["nuke_k1"] == pytest.approx(-1.2e-7 * 960 ** 2)
    assert lens.principal_point_pixels == (960.0, 540.0)  # centre of the frame, in edge coordinates
    assert lens.calibration_size == (1920, 1080) and lens.exact
    # Overscan margins move the centre and rescale the normalisation radius.
    lens = m.blender_lens(Distortion("division", {"lambda": -1.2e-7}, (959.5, 539.5)), K, (1920, 1080), (96, 54))
    assert lens.calibration_size == (2112, 1188)
    assert lens.principal_point_pixels == (1056.0, 594.0)
    assert lens.params["nuke_k1"] == pytest.approx(-1.2e-7 * 1056 ** 2)
    lens = m.blender_lens(Distortion("polynomial", {"k1": -0.1, "k2": 0.02}, (949.0, 531.0)), K, (1920, 1080))
    assert lens.distortion_model == "POLYNOMIAL" and lens.params == {"k1": -0.1, "k2": 0.02, "k3": 0.0}
    assert lens.focal_length_pixels == 1000 and lens.principal_point_pixels == (949.5, 548.5)
    K2 = [[1000, 0, 950], [0, 1010, 530], [0, 0, 1]]
    assert not m.blender_lens(Distortion("polynomial", {"k1": -0.1}, (949.0, 531.0)), K2, (1920, 1080)).exact
    lens = m.blender_lens(Distortion("opencv", {"k1": 0.1, "k2": 0.0, "p1": 0.01, "p2": 0.02, "k3": 0.0}, (950, 530)), K, (1920, 1080))
    assert lens.distortion_model == "BROWN"
    assert (lens.params["brown_p1"], lens.params["brown_p2"]) == (0.02, -0.01)


def test_opencv_rational_thin_prism_lens_in_blender(addon):
    """The pure-Python OpenCV model equals camcal's (rational and thin prism); BROWN says what it leaves out."""
    from camcal.model.distortion import Distortion as CamcalDistortion

    m, Distortion = addon.tracking, addon.rigfile.Distortion
    params = {"k1": -0.21, "k2": 0.04, "p1": 8e-4, "p2": -1.2e-3, "k3": -0.004, "k4": 0.05, "k5": 0.012,
              "k6": 0.002, "s1": 1.1e-3, "s2": -4e-4, "s3": 1.6e-3, "s4": 2e-4}
    K = np.array([[1000.0, 0, 950.0], [0, 1000.0, 530.0], [0, 0, 1]])
    points = np.random.default_rng(3).uniform([0, 0], [1919, 1079], (200, 2))
    ours = CamcalDistortion("opencv", params).distort(points, K)
    theirs = np.array([m.opencv_distort(p, (950.0, 530.0), 1000.0, params) for p in points])
    assert np.abs(ours - theirs).max() < 1e-9
    lens = m.blender_lens(Distortion("opencv", params), K.tolist(), (1920, 1080))
    assert not lens.exact and "no k4, k5, k6, s1, s2, s3, s4" in lens.note


def test_pixel_conventions_and_margins(addon):
    m = addon.tracking
    assert m.to_blender_pixel((0.0, 0.0), 1080) == (0.5, 1079.5)
    assert m.from_blender_pixel(m.to_blender_pixel((12.25, 7.5), 100), 100) == (12.25, 7.5)
    assert m.overscan_margins((240, 180), 1.1) == (12, 9)
    assert m.overscan_margins((1920, 1080), 1.0) == (0, 0)
    with pytest.raises(ValueError, match="overscan must be >= 1"):
        m.overscan_margins((10, 10), 0.9)


def test_parallel_pairs_and_rectified_rotation(addon):
    m = addon.mapping
    K = ((800.0, 0.0, 400.0), (0.0, 800.0, 300.0), (0.0, 0.0, 1.0))
    R = rotation(0.1, 0.2, -0.3)
    c_left = np.array([0.5, 0.2, -1.0])
    c_right = c_left + R.T @ [0.12, 0, 0]
    ok, baseline = m.is_parallel_pair((K, R, c_left), (K, R, c_right))
    assert ok and baseline == pytest.approx(0.12)
    assert not m.is_parallel_pair((K, R, c_right), (K, R, c_left))[0]  # right of each other
    R2 = rotation(0.1, 0.21, -0.3)
    assert not m.is_parallel_pair((K, R, c_left), (K, R2, c_right))[0]
    # A rectification that rotates the camera by Q: R_rect = Q R.
    Q = rotation(0.02, -0.03, 0.01)
    K_rect = np.array([[820.0, 0, 410], [0, 820.0, 305], [0, 0, 1]])
    Hm = 3.7 * K_rect @ Q @ np.linalg.inv(K)
    rect = addon.rigfile.Rectification(H=Hm.tolist(), K_rect=K_rect.tolist(), image_size=(820, 610))
    K_out, R_rect, size = m.rectified_camera(K, R, rect)
    assert np.allclose(R_rect, Q @ R, atol=1e-12)
    assert size == (820, 610)
