"""Helpers and fixtures shared by the add-on's tests: synthetic rigs, projections.

Test modules import the fixtures ``addon`` and ``bpy`` from here (a second
``conftest.py`` under tests/ would clash with the top-level one). The add-on
is loaded as package ``camcal_rig`` (as Blender loads it, with relative
imports); ``bpy`` resets Blender to its empty factory state around each test.

Rig files are written by camcal itself (``camcal.model.rig.Rig.save``), and the
reference projection is ``camcal.model.rig.Camera.project``: the add-on must agree
with camcal on both.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

from camcal.blender_bridge import load_addon
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

ADDON_DIR = Path(__file__).resolve().parents[2] / "addon"


@pytest.fixture(scope="session")
def addon():
    """The add-on package with its pure modules imported (usable without bpy)."""
    package = load_addon()
    for name in ("rigfile", "mapping", "tracking", "fisheye", "plyfile", "pngfile"):
        importlib.import_module(f"{package.__name__}.{name}")
    return package


def compositor_tree(addon, scene):
    """The scene's compositor node tree, through the add-on's own version switch (``addon/compositor.py``)."""
    return importlib.import_module(f"{addon.__name__}.compositor").compositor_tree(scene)


@pytest.fixture
def bpy():
    """The bpy module, reset to an empty factory scene for each test."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)


def rotation(rx=0.0, ry=0.0, rz=0.0):
    """A rotation matrix from Euler angles (radians), as nested lists."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def camera_dict(name, size, K, R=None, c=(0.0, 0.0, 0.0), distortion=None, **extra):
    """One camera of a rig file as a dict."""
    R = np.eye(3) if R is None else np.asarray(R)
    cam = {
        "name": name,
        "image_size": list(size),
        "K": np.asarray(K, dtype=float).tolist(),
        "distortion": distortion or {"model": "none", "params": {}},
        "R": R.tolist(),
        "c": [float(v) for v in c],
        "sensor_width_mm": 36.0,
        "quality": {"rms_px": 0.21, "n_views": 18},
    }
    cam.update(extra)
    return cam


def frame(index, R=None, c=(0.0, 0.0, 0.0), images=None, lenses=None):
    """One frame of a rig file: the rig's pose ``rig_from_world``, its plates and per-frame lenses."""
    out = {"index": index, "R": (np.eye(3) if R is None else np.asarray(R)).tolist(), "c": [float(v) for v in c]}
    if images:
        out["images"] = images
    if lenses:
        out["lenses"] = lenses
    return out


def write_rig(path, cameras, frames=None, points=None):
    """Write a rig file with camcal (validated by ``camcal.model.rig``) and return its path."""
    rig = {
        "format": "camcal.rig",
        "version": 1,
        "units": "m",
        "cameras": cameras,
        "frames": frames or [],
        "points": points,
        "provenance": {"tool": "camcal tests", "method": "synthetic", "created": "2026-01-01"},
    }
    return Rig.from_dict(rig).save(path)


def project_ref(K, R, c, X, distortion=None):
    """camcal's projection (``Camera.project``): pixels (N, 2), centres at integers."""
    K = np.asarray(K, dtype=float)
    # the projection does not use the image size: one centred on the principal point keeps K plausible
    size = (int(2 * abs(K[0, 2])) + 2, int(2 * abs(K[1, 2])) + 2)
    camera = Camera(
        name="reference", image_size=size, K=K,
        distortion=Distortion.from_dict(distortion or {"model": "none"}),
        R=np.asarray(R, dtype=float), c=np.asarray(c, dtype=float),
    )
    return camera.project(np.asarray(X, dtype=float))


def blender_project(bpy, obj, scene, X):
    """Blender's own projection (calc_matrix_camera + inverse world matrix) in camcal pixels."""
    render = scene.render
    W, H = render.resolution_x, render.resolution_y
    depsgraph = bpy.context.evaluated_depsgraph_get()
    P = np.array(
        obj.calc_matrix_camera(
            depsgraph, x=W, y=H, scale_x=render.pixel_aspect_x, scale_y=render.pixel_aspect_y
        )
    )
    V = np.array(obj.matrix_world.inverted())
    Xh = np.c_[np.asarray(X, dtype=float), np.ones(len(X))]
    clip = (P @ V @ Xh.T).T
    ndc = clip[:, :3] / clip[:, 3:]
    u = (ndc[:, 0] + 1.0) / 2.0 * W - 0.5
    v = (1.0 - ndc[:, 1]) / 2.0 * H - 0.5
    return np.c_[u, v]


def points_in_view(K, R, c, size, n, rng, depth=(2.0, 8.0)):
    """Random world points that project inside the image, at random depths."""
    K, R, c = (np.asarray(a, dtype=float) for a in (K, R, c))
    W, H = size
    pix = np.c_[rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n), np.ones(n)]
    rays = (np.linalg.inv(K) @ pix.T).T
    z = rng.uniform(*depth, n)
    Xc = rays / rays[:, 2:] * z[:, None]
    return (R.T @ Xc.T).T + c
