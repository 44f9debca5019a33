"""Every chart layout rendered in Blender (Cycles) and turned into camera raw, for the detection tests and bench.

The scene of a capture: the chart, a flat textured plane (the layout's
texture of chart_renders.py: patches at the layout's places on its black
card, the IT8.7/2 on light paper, the Passport opened flat in its case;
mirrored for a print seen from behind), lying on a table (a plane twenty
chart widths square, a grey of 25 % reflectance with ellipses of rawtoaces
reflectances: clutter), both diffuse. Lit by a point lamp (radius 0) above
and beside the chart, one and a half chart widths up and out, whose light
falls off across the chart (inverse square and cosine), and a sun straight
down as fill (a quarter of the light where the chart is brightest). The
camera is a pinhole (the demo's renderer,
:func:`camcal.demo.blender_scene.render_shots`: the add-on's intrinsics
mapping) looking at the chart from up to 45 degrees off its normal, from a
distance at which the chart covers the condition's share of the frame,
rolled about its axis (up to 20 degrees, or 180), turned so that the chart
sits at a random spot inside the frame. The conditions and their draws are
chart_renders.CONDITIONS': ``tilt_deg`` is the angle between the chart's
normal and the ray to its centre, ``turn_deg`` the camera's roll.

Colours as Blender sees them: the textures hold the patches' linear camera
RGB under the illuminant (chart_renders' colours: the camera's
sensitivities through :class:`~camcal.colour.spectral.simulate.SimulatedCamera`),
read as data (no colour conversion), the lamps white, Cycles' view
transform Standard and the output float EXR, so a rendered pixel is camera
RGB times the light's shading. Cycles: 8 samples a pixel, no denoising, no
bounces (direct light only), so the lamps add no sampling noise: a
patch's rendered value is its albedo times the shading at its centre
(:func:`shading`, the lamps' formula, checked against the render). The
render (half-size pixels, one per 2x2 Bayer cell) becomes a 14-bit RGGB DNG with
shot and read noise by the same step as chart_renders
(:func:`raw_chart_scenes.write_raw_scene`), ``stops_under`` below the
chart's brightest light at full scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from chart_renders import CAMERAS, CONDITIONS, LAYOUT_ORDER, Render, _patch_colours, _reflectances, _texture
from raw_chart_scenes import cluttered_wall, write_raw_scene

from camcal.colour.spectral.simulate import SimulatedCamera
from camcal.demo.blender_scene import render_shots
from camcal.io.stmap import read_exr, write_exr

SIZE = (600, 900)  # half-size pixels: a 1800 x 1200 raw
#: The charts' published widths (metres; their heights follow the texture).
WIDTH_M = {"classic": 0.279, "passport": 0.19, "mini": 0.108, "nano": 0.04, "digital-sg": 0.279, "it8": 0.178}
TABLE_WIDTHS = 20.0  # the table's side in chart widths
KEY_HEIGHT, KEY_OUT = 1.5, 1.5  # the point lamp: chart widths above the table, out from the chart's centre
FILL = 0.25  # the sun's share of the light where the chart is brightest
SAMPLES = 8


@dataclass
class BlenderCase:
    """One capture to render: where its files go, its camera, truth and the pieces of the Blender job."""

    stem: str
    layout: str
    condition: str
    camera: SimulatedCamera
    K: np.ndarray
    R: np.ndarray
    c: np.ndarray
    chart_corners: np.ndarray  # (4, 3) world: the texture's top-left, top-right, bottom-right, bottom-left
    centres_world: np.ndarray  # (n, 3) patch centres, chart order
    albedo_RGB: np.ndarray  # (n, 3) the patches' camera RGB (reflectance through the sensitivities)
    reference: object
    lamp: np.ndarray  # the point lamp's position
    key: float  # its radiance factor straight under it (see :func:`shading`)
    share: float
    mirrored: bool
    stops_under: float
    seed: int


def shading(X: np.ndarray, lamp: np.ndarray, key: float) -> np.ndarray:
    """The light's factor on the table's plane (``z = 0``, normal ``+z``): rendered radiance over albedo.

    The point lamp at ``lamp`` (height ``h`` above the plane) gives
    ``key (h / r)^3`` at distance ``r`` (inverse square times the cosine of
    incidence ``h / r``, ``key`` straight under it); the sun straight down
    adds :data:`FILL` everywhere.
    """
    X = np.asarray(X, float)
    r = np.linalg.norm(X - lamp, axis=-1)
    return key * ((lamp[2] - X[..., 2]) / r) ** 3 + FILL


def _look_at(c: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-camera rotation of a camera at ``c`` looking at ``target``, image up towards ``up``."""
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def _project(K, R, c, X) -> np.ndarray:
    x = (np.asarray(X, float) - c) @ R.T @ K.T
    return x[:, :2] / x[:, 2:]


def _area(quad: np.ndarray) -> float:
    return 0.5 * abs(np.dot(quad[:, 0], np.roll(quad[:, 1], 1)) - np.dot(quad[:, 1], np.roll(quad[:, 0], 1)))


def _placement(corners: np.ndarray, rng, tilt_deg: float, share: float, turn_deg: float):
    """``K, R, c`` of a camera seeing the chart (``corners``, centred on the origin) as the module docstring says,
    and the chart's actual share of the frame."""
    height, width = SIZE
    f = 0.9 * width
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    axis = rng.uniform(0, np.pi)
    k = np.array([np.cos(axis), np.sin(axis), 0.0])
    view = cv2.Rodrigues(k * np.radians(tilt_deg))[0] @ [0, 0, 1.0]
    roll = np.radians(turn_deg)
    up = np.array([-np.sin(roll), np.cos(roll), 0.0])  # the chart's up (texture top: +y) turned by the roll
    d = 1.0
    for _ in range(4):  # the distance at which the chart covers the share (a few fixed-point steps)
        c = d * view
        R = _look_at(c, np.zeros(3), up)
        quad = _project(K, R, c, corners)
        span = quad.max(axis=0) - quad.min(axis=0)
        d *= max(np.sqrt(_area(quad) / (share * width * height)), span[0] / (0.96 * width), span[1] / (0.96 * height))
    c = d * view
    R = _look_at(c, np.zeros(3), up)
    quad = _project(K, R, c, corners)
    # pan: the chart's centre to a random spot that keeps the chart inside the frame
    lo, hi = -quad.min(axis=0) + 4, np.array([width, height]) - 5 - quad.max(axis=0)
    offset = rng.uniform(np.minimum(lo, 0), np.maximum(hi, 0))
    for _ in range(20):
        ray = np.linalg.solve(K, [*(K[:2, 2] + offset), 1.0])
        pan = cv2.Rodrigues(np.cross([0, 0, 1.0], ray / np.linalg.norm(ray)))[0]
        Rp = pan @ R
        quad = _project(K, Rp, c, corners)
        if quad.min() >= 2 and np.all(quad.max(axis=0) <= [width - 3, height - 3]):
            break
        offset *= 0.8
    return K, Rp, c, _area(quad) / (width * height)


def blender_case(folder: Path, layout: str, condition: str, seed: int, cameras: dict) -> BlenderCase:
    """One capture of the test set (as chart_renders.render_case: the camera alternating by seed, parameters drawn
    from the seed), its chart texture written to ``folder`` (and an IT8's CGATS file)."""
    name, illuminant = CAMERAS[seed % 2]
    if name not in cameras:
        cameras[name] = SimulatedCamera.from_colour(name, illuminant)
    camera = cameras[name]
    params = CONDITIONS[condition](np.random.default_rng([seed, LAYOUT_ORDER.index(layout),
                                                          list(CONDITIONS).index(condition)]))
    stem = f"{layout}_{condition.split()[0]}_{seed}"
    rng = np.random.default_rng(seed + 100 * LAYOUT_ORDER.index(layout))
    RGB, reference = _patch_colours(camera, layout, folder, stem, rng)
    tex, centres = _texture(layout, RGB, camera, rng)
    mirrored = bool(params.get("mirrored", False))
    th, tw = tex.shape[:2]
    if mirrored:  # the print seen from behind: the texture flipped left to right
        tex, centres = tex[:, ::-1], np.column_stack([tw - 1 - centres[:, 0], centres[:, 1]])
    write_exr(folder / f"{stem}.chart.exr", np.ascontiguousarray(tex))
    width = WIDTH_M[layout]
    height = width * th / tw
    lift = 0.002 * width  # above the table
    corners = np.array([[-width / 2, height / 2, lift], [width / 2, height / 2, lift], [width / 2, -height / 2, lift],
                        [-width / 2, -height / 2, lift]])
    s = (centres + 0.5) / [tw, th]  # texture pixel centres -> fractions of the chart from its top-left
    centres_world = np.column_stack([(s[:, 0] - 0.5) * width, (0.5 - s[:, 1]) * height, np.full(len(s), lift)])
    K, R, c, share = _placement(corners, rng, params["tilt_deg"], params["share"], params["turn_deg"])
    bearing = rng.uniform(0, 2 * np.pi)
    lamp = np.array([KEY_OUT * width * np.cos(bearing), KEY_OUT * width * np.sin(bearing), KEY_HEIGHT * width])
    # the brightest point of the chart: its point nearest the lamp's foot
    nearest = np.clip(lamp[:2], corners[2, :2] * [-1, 1], corners[2, :2] * [1, -1])
    key = (1.0 - FILL) / (shading([*nearest, lift], lamp, 1.0) - FILL)
    return BlenderCase(stem, layout, condition, camera, K, R, c, corners, centres_world, RGB, reference, lamp, key, share,
                       mirrored, float(params.get("stops_under", 0.0)), seed)


def _tables(folder: Path, cameras: dict, seeds) -> dict:
    """One cluttered table texture per seed (its camera's colours), shared by that seed's captures."""
    tables = {}
    for seed in seeds:
        camera = cameras[CAMERAS[seed % 2][0]]
        R_other = _reflectances("rawtoaces 190", camera)
        rng = np.random.default_rng(1000 + seed)
        other = camera.RGB(R_other[rng.permutation(len(R_other))[:40]])
        path = folder / f"table_{seed}.exr"
        write_exr(path, cluttered_wall(camera, other, (2048, 2048), rng, n=500))
        tables[seed] = path
    return tables


def blender_job(folder: Path, cases: list[BlenderCase], cameras: dict) -> dict:
    """The Blender job (:func:`render_shots`) rendering every case on its own table with its own lamps."""
    tables = _tables(folder, cameras, sorted({case.seed for case in cases}))
    quads, points, suns, shots = [], [], [], []
    for case in cases:
        width = WIDTH_M[case.layout]
        rng = np.random.default_rng([case.seed, LAYOUT_ORDER.index(case.layout), list(CONDITIONS).index(case.condition),
                                     1])
        # every case's chart at the origin, its table turned and shifted (a shot sees its own quads and lamps only)
        theta = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
        half = TABLE_WIDTHS * width / 2
        table = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]]) @ rot.T
        table[:, :2] += rng.uniform(-0.3, 0.3, 2) * half
        quads += [{"name": f"chart_{case.stem}", "corners": case.chart_corners.tolist(),
                   "texture": str(folder / f"{case.stem}.chart.exr"), "shader": "diffuse", "interpolation": "Linear"},
                  {"name": f"table_{case.stem}", "corners": table.tolist(), "texture": str(tables[case.seed]),
                   "shader": "diffuse", "interpolation": "Linear"}]
        points.append({"name": f"key_{case.stem}", "position": case.lamp.tolist(),
                       "power": case.key * 4 * np.pi**2 * case.lamp[2] ** 2})
        suns.append({"name": f"fill_{case.stem}", "direction": [0.0, 0.0, -1.0], "strength": FILL * np.pi})
        height, width_px = SIZE
        shots.append({"camera": {"K": case.K.tolist(), "R": case.R.tolist(), "c": case.c.tolist(),
                                 "image_size": [width_px, height]},
                      "quads": [f"chart_{case.stem}", f"table_{case.stem}"],
                      "lights": [f"key_{case.stem}", f"fill_{case.stem}"], "out": str(folder / f"{case.stem}.exr")})
    return {"samples": SAMPLES, "seed": 0, "quads": quads, "points": points, "suns": suns, "shots": shots}


def render_cases(folder, cases: list[BlenderCase], cameras: dict, threads: int = 0) -> list[Path]:
    """Render every case's EXR with Cycles (one Blender subprocess); EXRs already there are kept."""
    folder = Path(folder)
    todo = [case for case in cases if not (folder / f"{case.stem}.exr").is_file()]
    if todo:
        job = blender_job(folder, todo, cameras)
        render_shots(job, folder / "blender", threads=threads)
    return [folder / f"{case.stem}.exr" for case in cases]


def raw_capture(folder, case: BlenderCase) -> Render:
    """The rendered EXR of ``case`` written as a DNG (mosaic, noise, ``stops_under``), with the capture's truth."""
    folder = Path(folder)
    scene = read_exr(folder / f"{case.stem}.exr")[..., :3].astype(np.float64)
    path = folder / f"{case.stem}.dng"
    exposure = write_raw_scene(path, scene, case.camera, stops_under=case.stops_under, seed=case.seed)
    centres = _project(case.K, case.R, case.c, case.centres_world)
    RGB = case.albedo_RGB * shading(case.centres_world, case.lamp, case.key)[:, None] * exposure
    return Render(path, case.layout, centres, case.reference, RGB, case.share, case.mirrored)
