"""Synthetic cameras and scenes with known ground truth, for tests and the demo.

Everything here is seeded (``numpy.random.Generator``) so a run can be
repeated exactly.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.geometry.camera import look_at
from camcal.geometry.distortion import Distortion
from camcal.rig import Camera

__all__ = ["example_camera", "points_in_view", "procedural_texture", "colour_texture", "layered_stereo_pair",
           "room_corner_planes", "render_planes", "render_stereo_sequence"]


def example_camera(
    name: str = "cam",
    image_size: tuple[int, int] = (1920, 1080),
    fx: float = 1500.0,
    fy: float = 1490.0,
    skew: float = 0.0,
    principal_point: tuple[float, float] = (971.3, 533.8),
    centre: tuple[float, float, float] = (0.6, -6.0, 1.4),
    target: tuple[float, float, float] = (0.0, 0.0, 0.5),
    distortion: Distortion | None = None,
) -> Camera:
    """A plausible HD camera looking at ``target`` from ``centre`` (world z up)."""
    K = np.array([[fx, skew, principal_point[0]], [0.0, fy, principal_point[1]], [0.0, 0.0, 1.0]])
    return Camera(
        name=name,
        image_size=image_size,
        K=K,
        distortion=distortion or Distortion.none(),
        R=look_at(centre, target),
        c=np.asarray(centre, dtype=np.float64),
    )


def points_in_view(
    camera: Camera,
    n: int,
    rng: np.random.Generator,
    depth_range: tuple[float, float] = (4.0, 9.0),
    margin: float = 0.05,
) -> NDArray[np.float64]:
    """``n`` world points seen by ``camera``: uniform over the image (inside
    a margin, as a fraction of the size) and over the depth range.

    Returns
    -------
    ndarray, shape (n, 3)
    """
    width, height = camera.image_size
    u = rng.uniform(margin * width, (1 - margin) * width, n)
    v = rng.uniform(margin * height, (1 - margin) * height, n)
    depth = rng.uniform(*depth_range, n)
    pixels = np.stack([u, v, np.ones(n)], axis=1)
    rays = pixels @ np.linalg.inv(camera.K).T
    points_cam = rays * depth[:, None]
    return points_cam @ camera.R + camera.c


def procedural_texture(rng: np.random.Generator, size: int = 1024) -> NDArray[np.uint8]:
    """A grey texture with detail at every scale (noise octaves), for feature matching."""
    import cv2  # noqa: PLC0415 - only the renderers need OpenCV

    texture = np.zeros((size, size), np.float32)
    for cells in (4, 16, 64, 256):
        noise = rng.uniform(0.0, 1.0, (cells, cells)).astype(np.float32)
        texture += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC) * (cells ** -0.3)
    texture -= texture.min()
    return (255.0 * texture / texture.max()).astype(np.uint8)


def colour_texture(rng: np.random.Generator, size: int = 512, low: float = 0.03, high: float = 0.9) -> NDArray[np.float64]:
    """A colourful linear RGB texture ``(size, size, 3)`` in ``[low, high]``: one
    :func:`procedural_texture` per channel, so hues and saturations vary at every scale."""
    channels = [procedural_texture(rng, size).astype(np.float64) / 255.0 for _ in range(3)]
    return low + (high - low) * np.stack(channels, axis=2)


def layered_stereo_pair(
    rng: np.random.Generator,
    width: int = 320,
    height: int = 240,
    background: tuple[int, int] = (8, 16),
    foreground: int = 28,
    box: tuple[float, float, float, float] = (0.4, 0.3, 0.3, 0.4),
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """A rectified stereo pair of a textured slanted background and a textured box in front.

    The background's disparity grows row by row from ``background[0]`` (top)
    to ``background[1]`` (bottom), whole pixels per row; the foreground
    rectangle (``box`` = x, y, width, height as fractions of the left image)
    has disparity ``foreground``. A point at column ``x`` of the left view
    is at ``x - d`` in the right view (rows aligned, pixel centres at
    integers), so the right view is the left's layers shifted exactly, with
    no resampling.

    Returns
    -------
    left, right : ndarray, shape (height, width, 3)
        Linear RGB (:func:`colour_texture` values).
    disparity : ndarray, shape (height, width)
        True disparity of each left pixel.
    occluded : ndarray, shape (height, width), bool
        Left pixels the right view does not see (hidden by the box or out
        of its frame).
    """
    margin = max(background[1], foreground) + 1
    size = max(width + 2 * margin, height)
    back = colour_texture(rng, size)[:height]
    front = colour_texture(rng, size)[:height]
    x0, y0 = int(box[0] * width), int(box[1] * height)
    x1, y1 = x0 + int(box[2] * width), y0 + int(box[3] * height)
    ys = np.arange(height)[:, None]
    xs = np.arange(width)[None, :]
    d_back = np.round(background[0] + (background[1] - background[0]) * ys / max(height - 1, 1)).astype(int)
    in_box_rows = (ys >= y0) & (ys < y1)
    left_front = in_box_rows & (xs >= x0) & (xs < x1)
    x_back = np.broadcast_to(xs, (height, width))
    left = np.where(left_front[..., None], front[ys, xs + margin], back[ys, x_back + margin])
    right_front = in_box_rows & (xs + foreground >= x0) & (xs + foreground < x1)
    right = np.where(right_front[..., None], front[ys, xs + foreground + margin], back[ys, xs + d_back + margin])
    disparity = np.where(left_front, float(foreground), d_back.astype(np.float64) + 0 * xs)
    x_right = xs - disparity.astype(int)
    hidden = in_box_rows & (x_right + foreground >= x0) & (x_right + foreground < x1) & ~left_front
    occluded = hidden | (x_right < 0)
    return left, right, disparity, occluded


def room_corner_planes(extent: float = 8.0) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], ...]:
    """Three textured planes meeting at the world origin: floor z = 0 and walls
    x = 0, y = 0, each as (origin, axis_s, axis_t) spanning ``extent`` metres."""
    e = np.eye(3)
    return (
        (np.zeros(3), e[0] * extent, e[1] * extent),  # floor
        (np.zeros(3), e[0] * extent, e[2] * extent),  # wall y = 0
        (np.zeros(3), e[1] * extent, e[2] * extent),  # wall x = 0
    )


def render_planes(
    camera: Camera,
    planes: tuple[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], ...],
    textures: tuple[NDArray[np.uint8], ...],
) -> NDArray[np.uint8]:
    """Ray-cast textured planar patches through ``camera`` (its distortion included).

    Each plane is ``origin + s axis_s + t axis_t`` for s, t in [0, 1], carrying
    the matching texture. Pixel (0, 0) is the centre of the top-left pixel.

    Returns
    -------
    ndarray, shape (H, W), uint8
        The image; 0 where no plane is hit.
    """
    import cv2  # noqa: PLC0415

    width, height = camera.image_size
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    # world directions of every pixel (wide fisheye rays beyond 90 degrees included)
    rays = camera.distortion.rays_from_pixels(np.stack([u.ravel(), v.ravel()], axis=1), camera.K) @ camera.R
    best = np.full(len(rays), np.inf)
    map_s = np.full(len(rays), -1.0, np.float32)
    map_t = np.full(len(rays), -1.0, np.float32)
    image = np.zeros(len(rays), np.float32)
    for (origin, axis_s, axis_t), texture in zip(planes, textures):
        normal = np.cross(axis_s, axis_t)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = ((origin - camera.c) @ normal) / (rays @ normal)
        hits = camera.c + rays * depth[:, None] - origin
        s = hits @ axis_s / (axis_s @ axis_s)
        t = hits @ axis_t / (axis_t @ axis_t)
        visible = (depth > 0) & (depth < best) & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
        best[visible] = depth[visible]
        size = texture.shape[0] - 1
        map_s[:] = -1.0
        map_t[:] = -1.0
        map_s[visible] = s[visible] * size
        map_t[visible] = t[visible] * size
        sampled = cv2.remap(texture.astype(np.float32), map_s.reshape(height, width), map_t.reshape(height, width),
                            cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).ravel()
        image[visible] = sampled[visible]
    return np.clip(image, 0, 255).round().astype(np.uint8).reshape(height, width)


def render_stereo_sequence(
    root: str | os.PathLike,
    n_frames: int = 7,
    K: ArrayLike = ((500.0, 0.0, 319.5), (0.0, 500.0, 239.5), (0.0, 0.0, 1.0)),
    image_size: tuple[int, int] = (640, 480),
    baseline: float = 0.3,
    distortion: Distortion | None = None,
    seed: int = 0,
) -> dict[tuple[str, int], Camera]:
    """Render a stereo rig moving through the textured room corner, for SfM.

    Writes ``root/left/0000.png``, ``root/right/0000.png``... The rig's
    right camera sits ``baseline`` along the left camera's x axis; the rig
    moves along an arc looking at the corner.

    Returns
    -------
    dict
        ``(camera name, frame) -> Camera``: the ground truth (world poses).
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    textures = tuple(procedural_texture(rng) for _ in range(3))
    lens = distortion if distortion is not None else Distortion("polynomial", {"k1": -0.05, "k2": 0.0})
    truth = {}
    for i in range(n_frames):
        centre = np.array([5.5 - 0.4 * i, 4.0 + 0.3 * i, 1.6 + 0.05 * i])
        R = look_at(centre, [1.5 + 0.1 * i, 1.5, 1.0])
        for name, offset in (("left", 0.0), ("right", baseline)):
            camera = Camera(name, image_size, np.asarray(K, dtype=np.float64), lens, R, centre + R[0] * offset)
            (root / name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / name / f"{i:04d}.png"), render_planes(camera, room_corner_planes(), textures))
            truth[name, i] = camera
    return truth
