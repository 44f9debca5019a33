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
from scipy.spatial.transform import Rotation

from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

__all__ = ["example_camera", "example_stereo_rig", "points_in_view", "procedural_texture", "colour_texture", "layered_stereo_pair",
           "room_corner_planes", "orbit_set_planes", "pixel_rays", "render_planes", "render_stereo_sequence", "orbit_rig_poses",
           "lateral_rig_poses", "render_rig_orbit", "render_rig_poses"]


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


def orbit_set_planes(
    rng: np.random.Generator, extent: float = 8.0, wall_height: float = 3.5, n_boxes: int = 3,
) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], ...]:
    """A closed set to orbit: floor ``z = 0`` and four walls of a square room
    (side ``extent``), with ``n_boxes`` boxes (0.5 to 1.3 m, top and four
    sides) near its centre, each face as (origin, axis_s, axis_t).

    The boxes give depth in the foreground, the walls far background: what a
    self-calibration needs to separate focal length from distance.
    """
    e = np.eye(3)
    planes = [(np.zeros(3), e[0] * extent, e[1] * extent)]
    corners = (np.zeros(3), extent * e[0], extent * (e[0] + e[1]), extent * e[1])
    for start, end in zip(corners, corners[1:] + corners[:1]):
        planes.append((start, end - start, e[2] * wall_height))
    centre = np.array([extent / 2, extent / 2, 0.0])
    for k in range(n_boxes):
        angle = 2 * np.pi * k / max(n_boxes, 1) + rng.uniform(-0.3, 0.3)
        size = rng.uniform(0.5, 1.3, 3)
        base = centre + 0.9 * np.array([np.cos(angle), np.sin(angle), 0.0]) - 0.5 * size * [1, 1, 0]
        sx, sy, sz = (e[i] * size[i] for i in range(3))
        planes += [(base + sz, sx, sy), (base, sx, sz), (base + sy, sx, sz), (base, sy, sz), (base + sx, sy, sz)]
    return tuple(planes)


def pixel_rays(camera: Camera) -> NDArray[np.float64]:
    """Unit directions in the camera frame of every pixel of ``camera`` (its distortion included), row by row.

    A plate's lens does not change from frame to frame: these rays, computed
    once (the inverse of the distortion is iterative, the costly part of a
    render), serve every frame through :func:`render_planes`' ``camera_rays``.

    Returns
    -------
    ndarray, shape (H * W, 3)
    """
    width, height = camera.image_size
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return camera.distortion.rays_from_pixels(np.stack([u.ravel(), v.ravel()], axis=1), camera.K)


def render_planes(
    camera: Camera,
    planes: tuple[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], ...],
    textures: tuple[NDArray[np.uint8], ...],
    camera_rays: NDArray[np.float64] | None = None,
) -> NDArray[np.uint8]:
    """Ray-cast textured planar patches through ``camera`` (its distortion included).

    Each plane is ``origin + s axis_s + t axis_t`` for s, t in [0, 1], carrying
    the matching texture (sampled bilinearly at the nearest hit of each
    pixel's ray). Pixel (0, 0) is the centre of the top-left pixel.

    Parameters
    ----------
    camera : Camera
    planes : tuple of (origin, axis_s, axis_t)
    textures : tuple of ndarray
        One square grey texture per plane.
    camera_rays : ndarray, shape (H * W, 3), optional
        :func:`pixel_rays` of ``camera``'s lens, when several frames share it.

    Returns
    -------
    ndarray, shape (H, W), uint8
        The image; 0 where no plane is hit.
    """
    import cv2  # noqa: PLC0415

    width, height = camera.image_size
    rays_camera = pixel_rays(camera) if camera_rays is None else camera_rays
    # world directions of every pixel (wide fisheye rays beyond 90 degrees included)
    rays = rays_camera @ camera.R
    best = np.full(len(rays), np.inf)
    plane_of = np.full(len(rays), -1)
    texture_s = np.zeros(len(rays))
    texture_t = np.zeros(len(rays))
    for index, (origin, axis_s, axis_t) in enumerate(planes):
        normal = np.cross(axis_s, axis_t)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = ((origin - camera.c) @ normal) / (rays @ normal)
        nearer = np.flatnonzero((depth > 0) & (depth < best))
        hits = camera.c + rays[nearer] * depth[nearer, None] - origin
        s = hits @ axis_s / (axis_s @ axis_s)
        t = hits @ axis_t / (axis_t @ axis_t)
        inside = (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
        visible = nearer[inside]
        best[visible] = depth[visible]
        plane_of[visible] = index
        texture_s[visible], texture_t[visible] = s[inside], t[inside]
    image = np.zeros(len(rays), np.float32)
    row = 1024  # cv2.remap takes maps under 32767 columns: the hit pixels as rows of this length
    for index, texture in enumerate(textures):
        seen = np.flatnonzero(plane_of == index)
        if not len(seen):
            continue
        map_s = np.zeros(-(-len(seen) // row) * row, np.float32)
        map_t = np.zeros_like(map_s)
        map_s[:len(seen)] = texture_s[seen] * (texture.shape[0] - 1)
        map_t[:len(seen)] = texture_t[seen] * (texture.shape[0] - 1)
        sampled = cv2.remap(texture.astype(np.float32), map_s.reshape(-1, row), map_t.reshape(-1, row),
                            cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        image[seen] = sampled.ravel()[:len(seen)]
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


def example_stereo_rig(
    image_size: tuple[int, int] = (960, 720),
    f: float = 675.0,
    pp_offsets: ArrayLike = ((6.5, -5.2), (-7.8, 5.6)),
    lam: tuple[float, float] = (-1.2e-7, -1.2e-7),
    rig_euler_deg: ArrayLike = (0.8, -2.0, 0.5),
    baseline: float = 0.3,
    focal_ratio: float = 1.01,
) -> tuple[Camera, Camera]:
    """A stereo rig for self-calibration tests: principal points off the image centre, the right
    focal ``focal_ratio`` times the left, division lenses.

    Parameters
    ----------
    image_size : (int, int)
    f : float
        Left focal length (px).
    pp_offsets : array_like, shape (2, 2)
        Each camera's principal point minus the image centre ``((w - 1) / 2, (h - 1) / 2)``, px.
    lam : (float, float)
        Division lambda of each camera (camcal's pixel units, centred on the principal point).
    rig_euler_deg : array_like, shape (3,)
        The right camera's rotation from the left ("xyz" Euler angles, degrees).
    baseline : float
        Right camera centre ``(baseline, 0.01, -0.005)`` in the left camera's frame (m).
    focal_ratio : float

    Returns
    -------
    (Camera, Camera)
        ``left`` (the rig frame: identity pose) and ``right`` (``cam_from_rig``).
    """
    width, height = image_size
    offsets = np.asarray(pp_offsets, dtype=np.float64)
    cameras = []
    for k, name in enumerate(("left", "right")):
        focal = f * (focal_ratio if k else 1.0)
        K = np.array([[focal, 0.0, (width - 1) / 2 + offsets[k, 0]], [0.0, focal, (height - 1) / 2 + offsets[k, 1]],
                      [0.0, 0.0, 1.0]])
        R = np.eye(3) if k == 0 else Rotation.from_euler("xyz", rig_euler_deg, degrees=True).as_matrix()
        c = np.zeros(3) if k == 0 else np.array([baseline, 0.01, -0.005])
        cameras.append(Camera(name, image_size, K, Distortion("division", {"lambda": lam[k]}), R, c))
    return cameras[0], cameras[1]


def orbit_rig_poses(
    rng: np.random.Generator, n_frames: int = 10, radius: float = 2.8, roll_deg: float = 35.0, extent: float = 8.0,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Rig poses orbiting the centre of a set of side ``extent`` (see :func:`render_rig_orbit`).

    Returns
    -------
    list of (R, c)
        Per position the rotation world -> rig and the rig's centre in the world.
    """
    centre = np.array([extent / 2, extent / 2, 0.8])
    poses = []
    for i in range(n_frames):
        angle = np.radians(-120 + 240 * i / max(n_frames - 1, 1))
        position = centre + [radius * np.cos(angle), radius * np.sin(angle), rng.uniform(0.2, 1.4)]
        target = centre + rng.uniform(-0.6, 0.6, 3) * [1, 1, 0.5]
        roll = rng.uniform(-roll_deg, roll_deg) + (90.0 if i % 4 == 3 else 0.0)
        c_roll, s_roll = np.cos(np.radians(roll)), np.sin(np.radians(roll))
        roll_R = np.array([[c_roll, -s_roll, 0.0], [s_roll, c_roll, 0.0], [0.0, 0.0, 1.0]])
        poses.append((roll_R @ look_at(position, target), position))
    return poses


def render_rig_orbit(
    root: str | os.PathLike,
    cameras: tuple[Camera, ...],
    n_frames: int = 10,
    radius: float = 2.8,
    roll_deg: float = 35.0,
    image_noise: float = 0.0,
    extent: float = 8.0,
    seed: int = 0,
) -> dict[tuple[str, int], Camera]:
    """Render a camera rig orbiting a closed set (:func:`orbit_set_planes`), for self-calibration.

    Parameters
    ----------
    root : path
        Receives ``root/<camera>/0000.png``...
    cameras : tuple of Camera
        The rig: intrinsics, lens and ``cam_from_rig`` (``R``, ``c`` in the
        rig's frame, metres); the rig frame is the first camera's when its
        pose is the identity.
    n_frames : int
        Rig positions, spread over 240 degrees of a circle of ``radius``
        around the set's centre, at heights 1.0 to 2.2 m.
    roll_deg : float
        Each position rolls the rig by a uniform draw in +-``roll_deg``
        about its viewing axis (one position in four by 90 degrees more:
        portrait views), and aims it at a point drawn within 0.6 m of the
        set's centre (yaw and pitch variety).
    image_noise : float
        Standard deviation of Gaussian noise added to every image (grey levels).
    extent : float
        Side of the set (m).
    seed : int

    Returns
    -------
    dict
        ``(camera name, frame) -> Camera`` posed in the world (the truth).
    """
    rng = np.random.default_rng(seed)
    planes = orbit_set_planes(rng, extent)
    textures = tuple(procedural_texture(rng) for _ in planes)
    poses = orbit_rig_poses(rng, n_frames, radius, roll_deg, extent)
    return render_rig_poses(root, cameras, poses, planes, textures, image_noise, rng)


def lateral_rig_poses(
    rng: np.random.Generator, n_frames: int = 7, step: float = 0.25, distance: float = 2.5, jitter_deg: float = 2.0,
    extent: float = 8.0,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Rig poses sliding sideways in front of the centre of a set of side ``extent``: weak self-calibration geometry.

    The rig moves ``step`` metres along the world x axis per position, ``distance``
    metres in front of the set's centre (at 1.4 to 1.6 m height), every view
    looking along +y with only ``jitter_deg`` (uniform) of yaw and pitch and
    no roll: the views differ by translation, so a principal point shift is
    nearly a common rotation of every view and the focal length is fixed
    only by the parallax of the set's depth.

    Returns
    -------
    list of (R, c)
        Per position the rotation world -> rig and the rig's centre in the world.
    """
    centre = np.array([extent / 2, extent / 2, 0.8])
    poses = []
    for i in range(n_frames):
        position = centre + [step * (i - (n_frames - 1) / 2), -distance, rng.uniform(0.6, 0.8)]
        yaw, pitch = np.radians(rng.uniform(-jitter_deg, jitter_deg, 2))
        forward = np.array([np.sin(yaw) * np.cos(pitch), np.cos(yaw) * np.cos(pitch), np.sin(pitch)])
        poses.append((look_at(position, position + forward), position))
    return poses


def render_rig_poses(
    root: str | os.PathLike,
    cameras: tuple[Camera, ...],
    poses: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    planes: tuple[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], ...],
    textures: tuple[NDArray[np.uint8], ...],
    image_noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> dict[tuple[str, int], Camera]:
    """Render a camera rig at the rig poses ``(R world -> rig, centre)`` through textured planes (:func:`render_planes`).

    Writes ``root/<camera>/0000.png``...; ``image_noise`` (grey levels, drawn
    from ``rng``) is added to every image. Returns ``(camera name, frame) ->
    Camera`` posed in the world (the truth).
    """
    root = Path(root)
    rng = rng if rng is not None else np.random.default_rng(0)
    truth = {}
    for i, (rig_R, position) in enumerate(poses):
        for camera in cameras:
            posed = Camera(camera.name, camera.image_size, camera.K, camera.distortion, camera.R @ rig_R,
                           position + rig_R.T @ camera.c)
            image = render_planes(posed, planes, textures)
            if image_noise > 0:
                image = np.clip(image + rng.normal(0.0, image_noise, image.shape), 0, 255).round().astype(np.uint8)
            (root / camera.name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / camera.name / f"{i:04d}.png"), image)
            truth[camera.name, i] = posed
    return truth
