"""Rolling shutter: the displacement formula against points projected at their rows' times."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.rolling_shutter import camera_velocities, readout_displacements, rolling_shutter_frames
from camcal.model.camera import look_at, project_pinhole

K = np.array([[700.0, 0.0, 610.0], [0.0, 700.0, 185.0], [0.0, 0.0, 1.0]])
HEIGHT = 370
OMEGA = np.radians([4.0, 25.0, -6.0])  # rad/s in the camera's axes: a pan, some tilt and roll
VELOCITY = np.array([1.5, 0.2, 12.0])  # m/s in the world: driving forward
R0 = look_at(np.zeros(3), [0.0, 0.0, 1.0], up=(0.0, -1.0, 0.0))


def _pose(t: float) -> tuple[np.ndarray, np.ndarray]:
    """The constant-velocity camera at time ``t``: ``R(t) = exp(t [omega]_x) R0``, ``c(t) = t v``."""
    return Rotation.from_rotvec(t * OMEGA).as_matrix() @ R0, t * VELOCITY


def _points(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """World points seen by the camera at time 0, 4-60 m deep, spread over the image."""
    pixels = rng.uniform([0, 0], [1225, HEIGHT - 1], (n, 2))
    depth = rng.uniform(4.0, 60.0, n)
    rays = np.linalg.solve(K, np.c_[pixels, np.ones(n)].T).T * depth[:, None]
    R, c = _pose(0.0)
    return rays @ R + c


def _row_time_projection(points: np.ndarray, readout: float) -> np.ndarray:
    """Each point imaged by a rolling shutter: the row ``y`` whose time ``tau(y)`` puts the point on row ``y``
    (fixed point), the pixel there."""
    pixels = project_pinhole(K, *_pose(0.0), points)
    for _ in range(30):
        tau = readout * (pixels[:, 1] / (HEIGHT - 1) - 0.5)
        R = Rotation.from_rotvec(tau[:, None] * OMEGA).as_matrix() @ R0
        x = np.einsum("nij,nj->ni", R, points - tau[:, None] * VELOCITY)
        pixels = (x / x[:, 2:]) @ K[:2].T
    return pixels


def test_velocities_of_constant_motion_are_recovered():
    times = np.array([0.0, 1 / 24, 2 / 24, 4 / 24])  # a frame missing: its neighbours' times still count
    poses = [_pose(t) for t in times]
    omega, velocity = camera_velocities([R for R, _ in poses], [c for _, c in poses], times)
    np.testing.assert_allclose(omega, np.tile(OMEGA, (4, 1)), atol=1e-9)
    np.testing.assert_allclose(velocity, np.tile(VELOCITY, (4, 1)), atol=1e-9)


def test_fourth_order_velocities_follow_an_oscillating_motion_closer():
    """A pan and a dolly oscillating at 3 Hz, sampled at 30 fps: the central differences slow them by
    ``(2 pi f dt)^2 / 6`` (6.6 %); the fourth-order ones (Richardson) by ``(2 pi f dt)^4 / 30`` (0.5 %) in the
    frames two or more from either end, and are the central ones elsewhere; anything but 2 or 4 refused."""
    frequency, times = 3.0, np.arange(12) / 30.0
    phase = 2 * np.pi * frequency * times
    rotations = Rotation.from_rotvec(0.05 * np.sin(phase)[:, None] * [0.0, 1.0, 0.0]).as_matrix() @ R0
    centres = np.c_[0.2 * np.sin(phase), np.zeros((12, 2))]
    true_turn, true_speed = 0.05 * 2 * np.pi * frequency * np.cos(phase), 0.2 * 2 * np.pi * frequency * np.cos(phase)
    inner = (np.abs(np.cos(phase)) > 0.5) & (np.arange(12) >= 2) & (np.arange(12) < 10)
    step = 2 * np.pi * frequency / 30.0
    for order, slowed in ((2, step ** 2 / 6), (4, step ** 4 / 30)):
        omega, velocity = camera_velocities(rotations, centres, times, order=order)
        np.testing.assert_allclose(velocity[inner, 0] / true_speed[inner], 1.0 - slowed, atol=2e-3)
        np.testing.assert_allclose(np.linalg.norm(omega[inner], axis=1) / np.abs(true_turn[inner]), 1.0 - slowed,
                                   atol=2e-3)
    second, fourth = camera_velocities(rotations, centres, times), camera_velocities(rotations, centres, times, order=4)
    np.testing.assert_allclose(fourth[1][[0, 1, 10, 11]], second[1][[0, 1, 10, 11]])
    with pytest.raises(CamcalError, match="order must be 2 or 4, got 3"):
        camera_velocities(rotations, centres, times, order=3)


@pytest.mark.parametrize("readout", [0.010, 0.033])
def test_displacement_matches_projection_at_row_times(readout):
    points = _points(np.random.default_rng(3))
    R, c = _pose(0.0)
    exact = _row_time_projection(points, readout) - project_pinhole(K, R, c, points)
    formula = readout_displacements(K, HEIGHT, R, c, OMEGA, VELOCITY, points, readout)
    size = np.linalg.norm(exact, axis=1)
    assert size.max() > 3.0  # the motion makes the shutter matter
    # first order in the readout: the error is a small fraction of the largest displacement
    assert np.abs(formula - exact).max() < 0.05 * size.max()
    assert np.linalg.norm(formula, axis=1).max() == pytest.approx(size.max(), rel=0.05)


def test_frames_flagged_above_threshold_only_where_the_camera_moves():
    times = np.arange(6) / 24.0
    poses = [_pose(t) if k < 3 else _pose(times[2]) for k, t in enumerate(times)]  # moves, then stands still
    rng = np.random.default_rng(5)
    points = [_points(rng) + (c - _pose(0.0)[1]) for _, c in poses]
    frames = rolling_shutter_frames(K, HEIGHT, [R for R, _ in poses], [c for _, c in poses], times, points,
                                    readout_s=0.03, threshold_px=1.0)
    assert [frame.flagged for frame in frames] == [True, True, True, False, False, False]
    assert frames[0].rotation_deg_per_s == pytest.approx(np.degrees(np.linalg.norm(OMEGA)))
    assert frames[0].speed == pytest.approx(np.linalg.norm(VELOCITY))
    assert frames[4].displacement_px == 0.0
    no_readout = rolling_shutter_frames(K, HEIGHT, [R for R, _ in poses], [c for _, c in poses], times, points,
                                        readout_s=0.0, threshold_px=1.0)
    assert not any(frame.flagged for frame in no_readout)


def test_bad_readout_and_times_are_refused():
    R, c = _pose(0.0)
    with pytest.raises(CamcalError, match="readout"):
        rolling_shutter_frames(K, HEIGHT, [R], [c], [0.0], [np.zeros((0, 3))], readout_s=-1.0, threshold_px=1.0)
    with pytest.raises(CamcalError, match="increase"):
        camera_velocities([R, R], [c, c], [0.0, 0.0])
