"""Track refinement: observations aligned to their track's reference land on the true correspondences."""

import cv2
import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import BundleState
from camcal.geometry.track_refine import MAX_SHIFT_PX, refine_tracks
from camcal.synthetic import procedural_texture

SIZE = 320


def _views(rng: np.random.Generator, n_views: int = 5):
    """A smooth texture seen through ``n_views`` homographies (scale, turn, shear, perspective), images exact."""
    texture = cv2.GaussianBlur(procedural_texture(rng, 2 * SIZE).astype(np.float64), (0, 0), 1.2)
    homographies, images = [], []
    for k in range(n_views):
        angle = np.radians(rng.uniform(-6, 6))
        scale = 0.5 * rng.uniform(0.9, 1.1)  # the texture at twice the views' size
        H = np.array([[scale * np.cos(angle), -scale * np.sin(angle), rng.uniform(-8, 8)],
                      [scale * np.sin(angle) * 1.03, scale * np.cos(angle), rng.uniform(-8, 8)],
                      [rng.uniform(-2e-4, 2e-4), rng.uniform(-2e-4, 2e-4), 1.0]])
        homographies.append(H)
        images.append(cv2.warpPerspective(texture, H, (SIZE, SIZE), flags=cv2.INTER_CUBIC))
    return homographies, images


def _tracks(rng, homographies, n_points: int = 150):
    """Texture points seen in every view: their true pixels (n_points, n_views, 2)."""
    source = rng.uniform(0.25 * 2 * SIZE, 0.75 * 2 * SIZE, (n_points, 2))
    true = []
    for H in homographies:
        p = np.c_[source, np.ones(n_points)] @ H.T
        true.append(p[:, :2] / p[:, 2:])
    return np.stack(true, axis=1)


def _state(xy: np.ndarray) -> BundleState:
    """Observations only (the refinement reads nothing else): point-major, one camera, frame = view."""
    n_points, n_views, _ = xy.shape
    return BundleState(
        camera_names=("plate",), models=("SIMPLE_PINHOLE",), image_sizes=((SIZE, SIZE),),
        params=(np.array([300.0, SIZE / 2, SIZE / 2]),), sensor_R=np.eye(3)[None], sensor_t=np.zeros((1, 3)),
        frame_R=np.repeat(np.eye(3)[None], n_views, axis=0), frame_t=np.zeros((n_views, 3)),
        frame_ids=tuple(range(n_views)), points=np.zeros((n_points, 3)), point_ids=tuple(range(n_points)),
        obs_camera=np.zeros(n_points * n_views, np.int64), obs_frame=np.tile(np.arange(n_views), n_points),
        obs_point=np.repeat(np.arange(n_points), n_views), obs_xy=xy.reshape(-1, 2).copy())


def test_refined_observations_land_on_the_points_their_reference_sees():
    """Detected positions off by a shared 0.25 px plus 0.1 px noise (the middle view's exact): the refined
    observations lie within 0.03 px RMS of where the reference's point truly is, its track's correspondence
    (an affine warp's limit under perspective that changes the scale by 6 % across a view: 0.019 px here,
    0.012 px without the perspective)."""
    rng = np.random.default_rng(3)
    homographies, images = _views(rng)
    true = _tracks(rng, homographies)
    detected = true + [0.25, -0.15] + rng.normal(0, 0.1, true.shape)
    middle = true.shape[1] // 2
    detected[:, middle] = true[:, middle]
    refinement = refine_tracks(_state(detected), lambda camera, frame: images[frame])
    refined = refinement.state.obs_xy.reshape(true.shape)
    others = np.ones(true.shape[1], dtype=bool)
    others[middle] = False
    moved = refinement.refined.reshape(true.shape[:2])
    assert not moved[:, middle].any() and refinement.n_references == len(true)
    assert moved[:, others].mean() > 0.95
    error = np.linalg.norm(refined - true, axis=2)[moved]
    assert np.sqrt(np.mean(error ** 2)) < 0.03
    assert np.sqrt(np.mean(np.linalg.norm(detected - true, axis=2)[:, others] ** 2)) > 0.25
    assert refinement.line().startswith(f"tracks refined: {int(moved.sum())} of {true.size // 2} observations")


def test_a_mismatched_observation_keeps_its_detected_position():
    """An observation on another part of the texture (a wrong match) is not moved onto anything."""
    rng = np.random.default_rng(4)
    homographies, images = _views(rng, 3)
    true = _tracks(rng, homographies, 40)
    detected = true.copy()
    detected[:, 0] += [9.0, -7.0]  # every first view's observation is elsewhere
    refinement = refine_tracks(_state(detected), lambda camera, frame: images[frame])
    moved = refinement.refined.reshape(true.shape[:2])
    assert not moved[:, 0].any()
    assert np.array_equal(refinement.state.obs_xy.reshape(true.shape)[:, 0], detected[:, 0])
    assert np.all(np.linalg.norm(refinement.state.obs_xy - _state(detected).obs_xy, axis=1) < MAX_SHIFT_PX)


def test_the_result_does_not_depend_on_the_threads():
    rng = np.random.default_rng(5)
    homographies, images = _views(rng, 4)
    detected = _tracks(rng, homographies, 60) + rng.normal(0, 0.2, (60, 4, 2))
    one = refine_tracks(_state(detected), lambda camera, frame: images[frame], threads=1)
    two = refine_tracks(_state(detected), lambda camera, frame: images[frame], threads=2)
    assert np.array_equal(one.state.obs_xy, two.state.obs_xy) and np.array_equal(one.refined, two.refined)


def test_an_even_or_tiny_patch_is_refused():
    state = _state(np.zeros((2, 2, 2)))
    with pytest.raises(CamcalError, match="odd number of pixels of at least 5, got 8"):
        refine_tracks(state, lambda camera, frame: np.zeros((8, 8)), patch=8)
