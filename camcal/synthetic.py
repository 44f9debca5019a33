"""Synthetic cameras and scenes with known ground truth, for tests and the demo.

Everything here is seeded (``numpy.random.Generator``) so a run can be
repeated exactly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.camera import look_at
from camcal.geometry.distortion import Distortion
from camcal.rig import Camera

__all__ = ["example_camera", "points_in_view"]


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
