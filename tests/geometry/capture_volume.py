"""A rendered capture volume: cameras on a ring facing inward, a two-sided ChArUco board moving in the middle.

The board's texture at board point ``(X, Y)`` is the same on both sides
(the back is printed as the mirror image with every corner at the same
board point), so a view from either side is the same homography of the
texture: ``x ~ K [r1 r2 t] (X, Y, 1)``; a camera behind the board sees it
mirrored. World: z up, the volume centred on the origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from camcal.geometry.board import Board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

#: Texture pixels per board unit (metre) and the texture's margin in pixels.
_PX_PER_M, _MARGIN = 4000, 40


def board_extent(board: Board) -> np.ndarray:
    """The printed squares' corners ``(x0, y0), (x1, y1)`` in board coordinates (a chessboard's reach one square
    beyond its outer inner corners)."""
    if board.kind == "charuco":
        return np.array([[0.0, 0.0], [board.columns, board.rows]]) * board.square
    return np.array([[-1.0, -1.0], [board.columns, board.rows]]) * board.square


def board_texture(board: Board) -> np.ndarray:
    """The printed board (white markers on black when inverted), :data:`_PX_PER_M` px per metre from its
    :func:`board_extent`; a chessboard's first interior square (corners 0, 1, W, W + 1) is black."""
    (x0, y0), (x1, y1) = board_extent(board)
    size = (round((x1 - x0) * _PX_PER_M) + 2 * _MARGIN, round((y1 - y0) * _PX_PER_M) + 2 * _MARGIN)
    if board.kind == "chessboard":
        u, v = np.meshgrid(np.arange(size[0]), np.arange(size[1]))
        i = np.floor((u + 0.5 - _MARGIN) / (board.square * _PX_PER_M)).astype(int)
        j = np.floor((v + 0.5 - _MARGIN) / (board.square * _PX_PER_M)).astype(int)
        inside = (i >= 0) & (j >= 0) & (i <= board.columns) & (j <= board.rows)
        return np.where(inside & ((i + j) % 2 == 0), 0, 255).astype(np.uint8)
    image = board.charuco_board().generateImage(size, marginSize=_MARGIN)
    return 255 - image if board.inverted else image


def look_at(c: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World -> camera rotation of a camera at ``c`` looking at ``target``, level (+y down, world z up)."""
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.array([x, np.cross(z, x), z])


@dataclass
class Volume:
    cameras: list[Camera]
    board_R: list[np.ndarray]  # world_from_board per frame
    board_t: list[np.ndarray]
    size_m: float  # the ring's diameter


def make_volume(n_cameras: int, n_frames: int, image_size=(640, 480), radius: float = 1.1, seed: int = 3,
                distortion: Distortion | None = None) -> Volume:
    """``n_cameras`` on a ring of ``radius`` m at varied heights facing the centre; the board turning about z."""
    rng = np.random.default_rng(seed)
    width, height = image_size
    cameras = []
    for k in range(n_cameras):
        angle = 2 * np.pi * k / n_cameras + rng.uniform(-0.1, 0.1)
        c = np.array([radius * np.cos(angle), radius * np.sin(angle), rng.uniform(-0.15, 0.25)])
        f = rng.uniform(0.95, 1.1) * 0.9 * width
        K = np.array([[f, 0, (width - 1) / 2 + rng.uniform(-8, 8)], [0, f, (height - 1) / 2 + rng.uniform(-6, 6)],
                      [0, 0, 1]])
        R = look_at(c, rng.uniform(-0.05, 0.05, 3))
        cameras.append(Camera(f"cam{k}", image_size, K, distortion or Distortion("none", {}), R, c))
    board_R, board_t = [], []
    for f in range(n_frames):
        yaw = 2 * np.pi * f / n_frames * 1.5 + rng.uniform(-0.2, 0.2)  # one and a half turns: both sides to all
        normal = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        R_wb = np.stack([np.cross(down, normal), down, normal], axis=1)
        tilt = Rotation.from_rotvec(rng.uniform(-0.45, 0.45, 3)).as_matrix()
        R_wb = tilt @ R_wb
        centre = rng.uniform([-0.15, -0.15, -0.1], [0.15, 0.15, 0.15])
        board_R.append(R_wb)
        board_t.append(centre)
    return Volume(cameras, board_R, board_t, 2 * radius)


def board_origin_pose(board: Board, R_wb: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """world_from_board with the board's centre at ``centre``."""
    middle = np.append(board_extent(board).mean(axis=0), 0.0)
    return R_wb, centre - R_wb @ middle


def board_seen(board: Board, camera: Camera, R_wb: np.ndarray, t_wb: np.ndarray) -> bool:
    """Whether the camera sees the board whole (8 px inside the image), in front, at < 70 deg."""
    R_cb = camera.R @ R_wb
    t_cb = camera.R @ (t_wb - camera.c)
    (x0, y0), (x1, y1) = board_extent(board)
    outline = np.array([[x0, y0, 0], [x1, y0, 0], [x0, y1, 0], [x1, y1, 0]])
    X = outline @ R_cb.T + t_cb
    if np.any(X[:, 2] <= 0.1):
        return False
    ray = X.mean(axis=0) / np.linalg.norm(X.mean(axis=0))
    if abs(ray @ R_cb[:, 2]) < np.cos(np.radians(70)):
        return False
    corners = camera.project(outline @ R_wb.T + t_wb)
    width, height = camera.image_size
    return not (np.any(corners < 8) or np.any(corners > np.array([width, height]) - 9))


def render_view(board: Board, texture: np.ndarray, camera: Camera, R_wb: np.ndarray, t_wb: np.ndarray,
                rng: np.random.Generator, noise: float = 2.0) -> np.ndarray | None:
    """The camera's 8-bit grey image of the board, or None when the board is not seen whole at < 70 deg."""
    if not board_seen(board, camera, R_wb, t_wb):
        return None
    R_cb = camera.R @ R_wb
    t_cb = camera.R @ (t_wb - camera.c)
    width, height = camera.image_size
    (x0, y0), _ = board_extent(board)
    # texture pixel (u, v) is board point ((u + 0.5 - margin) / ppm, ...); pinhole image, then the lens by remap
    A = np.array([[1 / _PX_PER_M, 0, (0.5 - _MARGIN) / _PX_PER_M + x0],
                  [0, 1 / _PX_PER_M, (0.5 - _MARGIN) / _PX_PER_M + y0], [0, 0, 1]])
    H = camera.K @ np.column_stack([R_cb[:, 0], R_cb[:, 1], t_cb]) @ A
    scale = 2  # supersampled, then averaged down: no aliasing of the small squares
    S = np.diag([scale, scale, 1.0]) @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    S[:2, 2] -= 0.5
    big = cv2.warpPerspective(texture, S @ H, (width * scale, height * scale), flags=cv2.INTER_LINEAR,
                              borderValue=150)
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    if camera.distortion.model != "none":
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        ideal = camera.distortion.undistort(np.stack([u.ravel(), v.ravel()], axis=1), camera.K)
        maps = ideal.reshape(height, width, 2).astype(np.float32)
        image = cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderValue=150)
    image = cv2.GaussianBlur(image, (0, 0), 0.6).astype(np.float64)
    image += rng.normal(0.0, noise, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def true_corners(board: Board, camera: Camera, R_wb: np.ndarray, t_wb: np.ndarray) -> np.ndarray:
    """Pixels of every board corner in the camera (pixel (0, 0) at the centre of the top-left pixel)."""
    return camera.project(board.object_points @ R_wb.T + t_wb)


def write_videos(board: Board, volume: Volume, folder, fourcc: str = "mp4v", suffix: str = ".mp4",
                 seed: int = 7) -> tuple[list, dict]:
    """One video per camera (``cam_K.mp4``); a frame where a camera does not see the board is the bare background.

    Returns the video paths and ``{(camera, frame): seen}``.
    """
    rng = np.random.default_rng(seed)
    texture = board_texture(board)
    paths, seen = [], {}
    for k, camera in enumerate(volume.cameras):
        path = folder / f"cam_{k}{suffix}"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 30, camera.image_size, isColor=False)
        assert writer.isOpened(), f"no {fourcc} writer"
        for f, (R_wb, centre) in enumerate(zip(volume.board_R, volume.board_t)):
            R_wb, t_wb = board_origin_pose(board, R_wb, centre)
            image = render_view(board, texture, camera, R_wb, t_wb, rng)
            seen[camera.name, f] = image is not None
            if image is None:
                image = np.clip(150 + rng.normal(0, 2.0, camera.image_size[::-1]), 0, 255).astype(np.uint8)
            writer.write(image)
        writer.release()
        paths.append(path)
    return paths, seen
