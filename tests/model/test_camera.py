"""Camera model: compose/decompose, OpenCV and COLMAP conversions."""

import cv2
import numpy as np
import pycolmap
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal.base.errors import CamcalError
from camcal.model.camera import (
    K_from_colmap,
    K_to_colmap,
    camera_centre,
    compose_P,
    decompose_P,
    from_colmap,
    from_opencv,
    look_at,
    pixels_from_colmap,
    pixels_to_colmap,
    project_pinhole,
    to_colmap,
    to_opencv,
)

finite = dict(allow_nan=False, allow_infinity=False)


@st.composite
def cameras(draw):
    fx = draw(st.floats(100.0, 8000.0, **finite))
    fy = fx * draw(st.floats(0.8, 1.25, **finite))
    skew = draw(st.floats(-20.0, 20.0, **finite))
    cx = draw(st.floats(-500.0, 4500.0, **finite))
    cy = draw(st.floats(-500.0, 3000.0, **finite))
    K = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    quat = np.array([draw(st.floats(-1.0, 1.0, **finite)) for _ in range(4)])
    if np.linalg.norm(quat) < 0.1:
        quat = np.array([0.0, 0.0, 0.0, 1.0])
    x, y, z, w = quat / np.linalg.norm(quat)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    c = np.array([draw(st.floats(-100.0, 100.0, **finite)) for _ in range(3)])
    return K, R, c


@settings(max_examples=200, deadline=None)
@given(cameras(), st.floats(1e-3, 1e3, **finite), st.booleans())
def test_decompose_inverts_compose_at_any_scale(camera, scale, negative):
    K, R, c = camera
    P = compose_P(K, R, c) * (-scale if negative else scale)
    K2, R2, c2 = decompose_P(P)
    assert np.allclose(K2, K, rtol=1e-9, atol=1e-9 * K[0, 0])
    assert np.allclose(R2, R, atol=1e-9)
    assert np.allclose(c2, c, atol=1e-8 * max(1.0, np.abs(c).max()))
    assert np.linalg.det(R2) == pytest.approx(1.0, abs=1e-12)
    assert K2[0, 0] > 0 and K2[1, 1] > 0
    assert K2[2, 2] == 1.0 and K2[1, 0] == K2[2, 0] == K2[2, 1] == 0.0


@settings(max_examples=100, deadline=None)
@given(cameras())
def test_centre_is_right_null_vector(camera):
    K, R, c = camera
    P = compose_P(K, R, c)
    assert np.allclose(P @ np.append(camera_centre(P), 1.0), 0.0, atol=1e-9 * np.abs(P).max())


def test_decompose_rejects_singular_and_nan():
    with pytest.raises(CamcalError, match="singular"):
        decompose_P(np.hstack([np.ones((3, 3)), np.zeros((3, 1))]))
    P = compose_P(np.eye(3), np.eye(3), np.zeros(3))
    P[0, 0] = np.nan
    with pytest.raises(CamcalError, match="NaN"):
        decompose_P(P)
    with pytest.raises(CamcalError, match="shape"):
        decompose_P(np.eye(3))


@settings(max_examples=100, deadline=None)
@given(cameras(), st.integers(0, 2**32 - 1))
def test_opencv_round_trip_and_projection_agree(camera, seed):
    K, R, c = camera
    K[0, 1] = 0.0  # cv2.projectPoints ignores the skew entry of K
    rvec, tvec = to_opencv(R, c)
    R2, c2 = from_opencv(rvec, tvec)
    assert np.allclose(R2, R, atol=1e-9)
    assert np.allclose(c2, c, atol=1e-9 * max(1.0, np.abs(c).max()))
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1.0, 50.0, 30)
    cam_points = np.column_stack([rng.uniform(-0.8, 0.8, (30, 2)) * depth[:, None], depth])
    X = cam_points @ R + c
    ours = project_pinhole(K, R, c, X)
    theirs, _ = cv2.projectPoints(X, rvec, tvec, K, None)
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-9


@settings(max_examples=50, deadline=None)
@given(cameras(), st.integers(0, 2**32 - 1))
def test_colmap_conversion_agrees_with_pycolmap(camera, seed):
    K, R, c = camera
    K[0, 1] = 0.0  # COLMAP's models have no skew
    quat, t = to_colmap(R, c)
    R2, c2 = from_colmap(quat, t)
    assert np.allclose(R2, R, atol=1e-9) and np.allclose(c2, c, atol=1e-9 * max(1.0, np.abs(c).max()))
    cam_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(quat), t)
    assert np.allclose(cam_from_world.rotation.matrix(), R, atol=1e-9)
    K_colmap = K_to_colmap(K)
    colmap_camera = pycolmap.Camera(
        model="PINHOLE",
        width=4000,
        height=3000,
        params=[K_colmap[0, 0], K_colmap[1, 1], K_colmap[0, 2], K_colmap[1, 2]],
    )
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1.0, 50.0, 20)
    cam_points = np.column_stack([rng.uniform(-0.8, 0.8, (20, 2)) * depth[:, None], depth])
    X = cam_points @ R + c
    colmap_cam_points = np.array([cam_from_world * p for p in X])
    colmap_pixels = colmap_camera.img_from_cam(colmap_cam_points)
    ours = project_pinhole(K, R, c, X)
    # COLMAP's pixel centre is at 0.5: the same ray lands half a pixel further.
    assert np.abs(pixels_from_colmap(colmap_pixels) - ours).max() < 1e-8
    assert np.abs(colmap_pixels - pixels_to_colmap(ours)).max() < 1e-8
    assert np.allclose(K_from_colmap(K_colmap), K)


def test_colmap_half_pixel_on_a_known_ray():
    """The optical axis hits camcal's (cx, cy) and COLMAP's (cx + 0.5, cy + 0.5)."""
    K = np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 479.5], [0.0, 0.0, 1.0]])
    colmap_camera = pycolmap.Camera(model="PINHOLE", width=1280, height=960, params=[1000.0, 1000.0, 640.0, 480.0])
    assert np.allclose(K_to_colmap(K)[:2, 2], [640.0, 480.0])
    assert np.allclose(colmap_camera.img_from_cam(np.array([[0.0, 0.0, 1.0]])), [[640.0, 480.0]])
    assert np.allclose(project_pinhole(K, np.eye(3), np.zeros(3), [[0.0, 0.0, 3.0]]), [[639.5, 479.5]])


def test_project_behind_camera_is_nan():
    pixels = project_pinhole(np.eye(3), np.eye(3), np.zeros(3), [[0.0, 0.0, -1.0], [0.0, 0.0, 2.0]])
    assert np.all(np.isnan(pixels[0])) and np.all(np.isfinite(pixels[1]))


def test_look_at_axes():
    R = look_at([0.0, -5.0, 0.0], [0.0, 0.0, 0.0], up=[0.0, 0.0, 1.0])
    assert np.allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # x right, y down, z forward
    assert np.linalg.det(R) == pytest.approx(1.0)
    with pytest.raises(CamcalError, match="parallel"):
        look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], up=[0.0, 0.0, 1.0])


def test_similarity_Umeyama1991_recovers_a_known_similarity():
    from camcal.model.camera import random_rotation, rotation_angle_deg, similarity_Umeyama1991

    rng = np.random.default_rng(7)
    R_true, s_true, t_true = random_rotation(rng), 2.5, np.array([0.3, -1.0, 4.0])
    source = rng.normal(size=(40, 3))
    noise = 1e-3
    target = s_true * source @ R_true.T + t_true + rng.normal(0, noise, (40, 3))
    s, R, t = similarity_Umeyama1991(source, target)
    # the noise is 1e-3 on points of spread ~2.5: errors of order noise / sqrt(N) relative
    assert abs(s / s_true - 1) < 5 * noise and rotation_angle_deg(R @ R_true.T) < 0.05
    np.testing.assert_allclose(t, t_true, atol=5 * noise)
    assert np.linalg.det(R) > 0


def test_chordal_mean_rotation_is_the_svd_projection_and_recovers_the_centre():
    from scipy.spatial.transform import Rotation

    from camcal.model.camera import chordal_mean_rotation, random_rotation, rotation_angle_deg

    rng = np.random.default_rng(7)
    R_true = random_rotation(rng)
    noise_rad, count = 0.05, 400
    rotations = (Rotation.from_rotvec(rng.normal(0.0, noise_rad, (count, 3))) * Rotation.from_matrix(R_true)).as_matrix()
    mean = chordal_mean_rotation(rotations)
    U, _, Vt = np.linalg.svd(rotations.sum(axis=0))
    assert np.allclose(mean, U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, atol=1e-12)
    # the error of a mean of `count` draws is about noise * sqrt(3 / count) rad; allow 4 sigma
    assert rotation_angle_deg(mean @ R_true.T) < np.degrees(4 * noise_rad * np.sqrt(3 / count))
    with pytest.raises(CamcalError, match="shape"):
        chordal_mean_rotation(np.eye(3))
