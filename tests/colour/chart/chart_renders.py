"""Rendered raw captures of every chart layout camcal reads, for the detection tests and bench.

Not Blender: camcal's raw synthesiser (raw_chart_scenes.py) with the chart
placed by a pinhole camera. The flat chart (its texture: patches at the
layout's places, :mod:`camcal.colour.chart.layouts`) is turned in its
plane, tilted about a random in-plane axis by up to 45 degrees, seen from a
distance of twice its width (so the far side is visibly smaller: true
perspective, not an affine skew), scaled so that it covers a given share
of the frame's area and placed at a random spot inside it, optionally seen
in a mirror (the texture flipped). For a flat chart this is the image a
renderer's pinhole camera makes; lighting is uniform. The scene (half-size
pixels, on the cluttered wall of raw_chart_scenes) is blurred a little (the
lens, Gaussian sigma 0.6 px), then written as a 14-bit RGGB DNG with shot
and read noise (:func:`raw_chart_scenes.write_raw_scene`), ``stops_under``
below a white patch at full scale.

Colours, as the camera sees them under the illuminant: the 24-patch charts
from BabelColor's average reflectances; the Digital SG from X-Rite's XYZ
(colour-science, D50) adapted to the illuminant and taken to camera RGB by
the 3x3 matrix that best maps the rawtoaces 190 reflectances' XYZ to their
camera RGB; the IT8.7/2 from reflectances (264 of rawtoaces 190 and the
CIE 2017 colour fidelity samples, 24 flat greys from 90 % to 3 %), whose D50 XYZ are
written as the chart's CGATS reference file beside the DNG.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from raw_chart_scenes import _texture_passport, cluttered_wall, write_raw_scene

from camcal.colour.chart.layouts import chart_layout, it8_patch_names
from camcal.colour.chart.reference import ReferenceChart, reference_chart, reference_from_measurements
from camcal.colour.spectral.data import adapt_XYZ, reflectance_set, resample_spectral
from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.io.cgats import read_cgats, write_cgats

SIZE = (800, 1200)  # half-size pixels: a 2400 x 1600 raw


@dataclass
class Render:
    """A rendered capture: its DNG, the layout, true patch centres (half-size px, chart order), reference."""

    path: Path
    layout: str
    centres: np.ndarray
    reference: ReferenceChart
    RGB: np.ndarray  # true linear camera RGB of every patch at the capture's exposure
    share: float  # the chart's share of the frame's area
    mirrored: bool


_CACHE: dict = {}


def _reflectances(name: str, camera: SimulatedCamera) -> np.ndarray:
    """A reflectance set on the camera's grid (kept: every render reads the same few)."""
    key = (name, camera.wavelengths.tobytes())
    if key not in _CACHE:
        _CACHE[key] = reflectance_set(name, camera.wavelengths)[1]
    return _CACHE[key]


def _camera_matrix(camera: SimulatedCamera) -> np.ndarray:
    """The 3x3 ``M`` with camera RGB ~ XYZ @ M over the rawtoaces 190 set (least squares)."""
    R = _reflectances("rawtoaces 190", camera)
    return np.linalg.lstsq(camera.XYZ(R), camera.RGB(R), rcond=None)[0]


def _it8_reflectances(camera: SimulatedCamera, rng) -> np.ndarray:
    a = _reflectances("rawtoaces 190", camera)
    b = _reflectances("CIE 2017 TCS", camera)
    pool = np.vstack([a, b])
    colours = pool[rng.permutation(len(pool))[:264]]
    greys = np.geomspace(0.9, 0.03, 24)[:, None] * np.ones((1, len(camera.wavelengths)))
    return np.vstack([colours, greys])


def _patch_colours(camera: SimulatedCamera, layout: str, folder: Path, stem: str, rng):
    """Camera RGB of every patch and the reference chart camcal is given."""
    chart = chart_layout(layout)
    if chart.family == "24":
        return camera.RGB(_reflectances("BabelColor Average", camera)), reference_chart(chart.reference, "D50")
    if layout == "digital-sg":
        reference = reference_chart(chart.reference, "D50")
        XYZ = adapt_XYZ(reference.XYZ, reference.white_XYZ, camera.white_XYZ, "CAT02")
        return np.clip(XYZ @ _camera_matrix(camera), 1e-4, None), reference
    R = _it8_reflectances(camera, rng)
    import colour

    D50 = resample_spectral(colour.SDS_ILLUMINANTS["D50"], camera.wavelengths)
    XYZ = (R * D50) @ camera.cmfs / float(D50 @ camera.cmfs[:, 1])  # on the camera's grid, white Y = 1
    path = write_cgats(folder / f"{stem}.it8.txt", it8_patch_names(), XYZ, identifier="IT8.7/2")
    data = read_cgats(path)
    return camera.RGB(R), reference_from_measurements(path.name, data.names, data.XYZ, "it8")


def _texture(layout: str, RGB: np.ndarray, camera: SimulatedCamera, rng):
    """The flat chart and its patch centres (texture pixels, chart order)."""
    chart = chart_layout(layout)
    grey = camera.RGB(np.full((1, len(camera.wavelengths)), 1.0))[0]
    if layout == "passport":
        R_other = _reflectances("rawtoaces 190", camera)
        other = camera.RGB(R_other[rng.permutation(len(R_other))[:40]])
        return _texture_passport(RGB, other, 48, float(0.03 * grey[1]), 0.08)
    cell = {"24": 48, "digital-sg": 30, "it8": 22}[chart.family]
    margin = int(0.5 * cell)
    body = 0.03 * grey if layout != "it8" else 0.55 * grey  # black card; IT8 on light paper
    extra = 1.5 * cell if chart.grey_scale else 0.0
    height, width = int(chart.rows * cell + extra) + 2 * margin, chart.columns * cell + 2 * margin
    tex = np.empty((height, width, 3), np.float32)
    tex[:] = body
    grid = np.array([chart.columns * cell, chart.rows * cell], dtype=np.float64)
    uv, half = chart.patch_uv(), chart.patch_half_size()
    for rgb, centre, h in zip(RGB, uv * grid + margin, half * grid):
        x0, y0 = np.round(centre - h).astype(int)
        x1, y1 = np.round(centre + h).astype(int)
        tex[y0:y1, x0:x1] = rgb
    return tex, uv * grid + margin - 0.5


def _placement(tex_size, size, rng, tilt_deg: float, share: float, turn_deg: float, mirrored: bool):
    """Homography texture -> image (see the module docstring) and the chart's share of the frame."""
    th, tw = tex_size
    height, width = size
    src = np.array([[0, 0], [tw, 0], [tw, th], [0, th]], np.float64)
    X = np.column_stack([(src - [tw / 2, th / 2]) / tw, np.zeros(4)])
    if mirrored:
        X[:, 0] *= -1
    turn = np.radians(turn_deg)
    Rz = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    axis = rng.uniform(0, np.pi)
    k = np.array([np.cos(axis), np.sin(axis), 0.0])
    Rt = cv2.Rodrigues(k * np.radians(tilt_deg))[0]
    P = X @ (Rt @ Rz).T + [0, 0, 2.0]
    quad = P[:, :2] / P[:, 2:3]
    area = 0.5 * abs(np.dot(quad[:, 0], np.roll(quad[:, 1], 1)) - np.dot(quad[:, 1], np.roll(quad[:, 0], 1)))
    scale = np.sqrt(share * width * height / area)
    quad = (quad - quad.mean(axis=0)) * scale
    span = quad.max(axis=0) - quad.min(axis=0)
    fit = min(1.0, 0.98 * width / span[0], 0.98 * height / span[1])
    quad *= fit
    lo, hi = -quad.min(axis=0), np.array([width, height]) - quad.max(axis=0)
    quad += rng.uniform(lo, np.maximum(lo, hi))
    return cv2.getPerspectiveTransform(src.astype(np.float32), quad.astype(np.float32)), share * fit**2


def render_chart(path, camera: SimulatedCamera, layout: str, *, tilt_deg: float = 20.0, share: float = 0.25,
                 turn_deg: float = 0.0, mirrored: bool = False, stops_under: float = 0.0, seed: int = 0,
                 size=SIZE, full_well: float = 20000.0) -> Render:
    """Render one capture of ``layout`` and write its DNG (and an IT8's CGATS file) at ``path``."""
    path = Path(path)
    rng = np.random.default_rng(seed)
    RGB, reference = _patch_colours(camera, layout, path.parent, path.stem, rng)
    tex, centres = _texture(layout, RGB, camera, rng)
    R_other = _reflectances("rawtoaces 190", camera)
    scene = cluttered_wall(camera, camera.RGB(R_other[rng.permutation(len(R_other))[:40]]), size, rng)
    H, actual = _placement(tex.shape[:2], size, rng, tilt_deg, share, turn_deg, mirrored)
    height, width = size
    warped = cv2.warpPerspective(tex, H, (width, height), flags=cv2.INTER_LINEAR)
    mask = cv2.warpPerspective(np.ones(tex.shape[:2], np.float32), H, (width, height), flags=cv2.INTER_LINEAR)
    scene = scene * (1 - mask[:, :, None]) + warped * mask[:, :, None]
    scene = cv2.GaussianBlur(scene, (0, 0), 0.6)
    exposure = write_raw_scene(path, scene.astype(np.float64), camera, stops_under=stops_under,
                               full_well=full_well, seed=seed)
    p = np.column_stack([centres, np.ones(len(centres))]) @ H.T
    return Render(path, layout, p[:, :2] / p[:, 2:], reference, RGB * exposure, actual, mirrored)


#: The conditions of the rendered test set: name -> how a seed's parameters are drawn.
CONDITIONS = {
    "perspective 45 deg": lambda rng: dict(tilt_deg=45.0, share=0.25, turn_deg=rng.uniform(-20, 20)),
    "5 % of the frame": lambda rng: dict(tilt_deg=rng.uniform(0, 30), share=0.05, turn_deg=rng.uniform(-20, 20)),
    "60 % of the frame": lambda rng: dict(tilt_deg=rng.uniform(0, 15), share=0.6, turn_deg=rng.uniform(-5, 5)),
    "rotated 180 deg": lambda rng: dict(tilt_deg=rng.uniform(0, 30), share=0.25, turn_deg=180 + rng.uniform(-10, 10)),
    "mirrored": lambda rng: dict(tilt_deg=rng.uniform(0, 30), share=0.25, turn_deg=rng.uniform(-20, 20),
                                 mirrored=True),
    "3 stops under": lambda rng: dict(tilt_deg=rng.uniform(0, 30), share=0.25, turn_deg=rng.uniform(-20, 20),
                                      stops_under=3.0),
}
LAYOUT_ORDER = ("classic", "passport", "mini", "nano", "digital-sg", "it8")
CAMERAS = (("Nikon 5100 (NPL)", "D65"), ("Sigma SDMerill (NPL)", "A"))


def render_case(folder, layout: str, condition: str, seed: int, cameras: dict) -> Render:
    """One capture of the test set: ``layout`` under ``condition``, parameters drawn from ``seed``; the camera
    alternates by seed (Nikon 5100 under D65, Sigma SD Merrill under A); ``cameras`` caches them."""
    name, illuminant = CAMERAS[seed % 2]
    if name not in cameras:
        cameras[name] = SimulatedCamera.from_colour(name, illuminant)
    rng = np.random.default_rng([seed, LAYOUT_ORDER.index(layout), list(CONDITIONS).index(condition)])
    stem = f"{layout}_{condition.split()[0]}_{seed}"
    return render_chart(Path(folder) / f"{stem}.dng", cameras[name], layout, seed=seed + 100 * LAYOUT_ORDER.index(layout),
                        **CONDITIONS[condition](rng))


def found_in_order(centres: np.ndarray, truth: np.ndarray) -> tuple[bool, float]:
    """Every patch centre within a quarter of the patch pitch of the truth, in chart order; the worst error (px)."""
    d = np.linalg.norm(truth[:, None] - truth[None], axis=2)
    np.fill_diagonal(d, np.inf)
    pitch = float(np.median(d.min(axis=1)))
    error = float(np.linalg.norm(np.asarray(centres) - truth, axis=1).max())
    return error < 0.25 * pitch, error
