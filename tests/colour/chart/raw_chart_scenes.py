"""Raw chart captures synthesised from a measured camera's sensitivities, for detection and fit tests.

A scene (half-size pixels, one per 2x2 Bayer cell) holds a ColorChecker in
perspective on a cluttered background: either the classic chart (its patches
on a black body) or a ColorChecker Passport opened flat (its left page a
"creative enhancement" target of smaller patches, its right page the classic
chart turned a quarter turn, 6 rows of 4). Colours are reflectances through
the camera's sensitivities under the illuminant (:class:`SimulatedCamera`):
the chart's own (BabelColor average), the creative page and the clutter from
the rawtoaces 190 set. The linear scene is scaled ``2**-stops_under`` below a
white patch at full scale, mosaicked (RGGB), and turned into 14-bit counts
with shot noise (Poisson, ``full_well`` electrons at full scale), read noise
(Gaussian, DN), a black level and a white level; :func:`write_raw_chart`
writes it as a DNG (tests/io/dng_writer.py).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "io"))
from dng_writer import write_cfa_dng  # noqa: E402

from camcal.colour.spectral.data import reflectance_set  # noqa: E402
from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: E402

BLACK, WHITE = 512, 16383


@dataclass
class RawChart:
    """A synthesised capture: its file, the true patch centres (half-size pixels), the camera and truth."""

    path: Path
    centres: np.ndarray
    camera: SimulatedCamera
    names: list
    reflectances: np.ndarray
    RGB: np.ndarray  # true linear camera RGB of the 24 patches at the capture's exposure


def _texture_classic(RGB: np.ndarray, cell: int, gap: float, body: float) -> tuple[np.ndarray, np.ndarray]:
    """The classic chart flat: 4 x 6 patches on a black body; returns the texture and patch centres."""
    margin = int(0.4 * cell)
    tex = np.full((4 * cell + 2 * margin, 6 * cell + 2 * margin, 3), body, np.float32)
    centres = []
    for k, rgb in enumerate(RGB):
        r, c = divmod(k, 6)
        g = int(gap * cell / 2)
        tex[margin + r * cell + g: margin + (r + 1) * cell - g, margin + c * cell + g: margin + (c + 1) * cell - g] = rgb
        centres.append((margin + (c + 0.5) * cell - 0.5, margin + (r + 0.5) * cell - 0.5))
    return tex, np.array(centres)


def _texture_passport(RGB: np.ndarray, other: np.ndarray, cell: int, body: float, case: float):
    """A Passport opened flat: the creative page left, the classic chart right in portrait (6 rows x 4)."""
    margin = int(0.5 * cell)
    page_h, page_w = 6 * cell + 2 * margin, 4 * cell + 2 * margin
    tex = np.full((page_h + 2 * margin, 2 * page_w + 3 * margin, 3), case, np.float32)
    x_right = 2 * margin + page_w
    tex[margin: margin + page_h, x_right: x_right + page_w] = body
    tex[margin: margin + page_h, margin: margin + page_w] = body
    centres = np.zeros((24, 2))
    g = int(0.08 * cell)
    for k, rgb in enumerate(RGB):
        r, c = divmod(k, 6)
        # a quarter turn clockwise: chart row r becomes page column 3 - r, chart column c page row c
        pr, pc = c, 3 - r
        y0, x0 = 2 * margin + pr * cell, x_right + margin + pc * cell
        tex[y0 - margin + g: y0 - margin + cell - g, x0 + g: x0 + cell - g] = rgb
        centres[k] = (x0 + cell / 2 - 0.5, y0 - margin + cell / 2 - 0.5)
    # the creative page: a large grey strip and 4 x 8 smaller patches
    small = int(0.55 * cell)
    tex[2 * margin: 2 * margin + cell, 2 * margin: 2 * margin + 3 * cell] = other[0].mean()
    for k in range(32):
        r, c = divmod(k, 4)
        y0, x0 = 2 * margin + int(1.3 * cell) + r * int(small * 1.15), 2 * margin + c * int(small * 1.3)
        if y0 + small < margin + page_h:
            tex[y0: y0 + small, x0: x0 + small] = other[1 + k % (len(other) - 1)]
    return tex, centres


def cluttered_wall(camera: SimulatedCamera, other: np.ndarray, size, rng, n: int = 25) -> np.ndarray:
    """A grey wall (25 % reflectance) with ``n`` random ellipses of the colours ``other``, ``(H, W, 3)`` float32."""
    height, width = size
    scene = np.full((height, width, 3), 0.25, np.float32) * camera.RGB(np.full((1, len(camera.wavelengths)), 1.0))[0]
    for _ in range(n):
        rgb = other[rng.integers(len(other))]
        centre = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
        axes = (int(rng.uniform(15, 90)), int(rng.uniform(15, 90)))
        cv2.ellipse(scene, centre, axes, float(rng.uniform(0, 180)), 0, 360, tuple(float(v) for v in rgb), -1)
    return scene


def render_scene(camera: SimulatedCamera, layout: str = "classic", size=(700, 1000), seed: int = 0,
                 chart_frac: float = 0.45, tilt: float = 0.12, rotation: float = 8.0):
    """Linear camera RGB of a chart scene (half-size) and the true patch centres; white patch G ~ 0.9."""
    rng = np.random.default_rng(seed)
    names, R = reflectance_set("BabelColor Average", camera.wavelengths)
    RGB = camera.RGB(R)
    _, R_other = reflectance_set("rawtoaces 190", camera.wavelengths)
    other = camera.RGB(R_other[rng.permutation(len(R_other))[:40]])
    black_body = float(camera.RGB(np.full((1, len(camera.wavelengths)), 0.03))[0, 1])
    cell = 60
    if layout == "classic":
        tex, centres = _texture_classic(RGB, cell, 0.16, black_body)
    else:
        tex, centres = _texture_passport(RGB, other, cell, black_body, 0.08)
    height, width = size
    scene = cluttered_wall(camera, other, size, rng)
    th, tw = tex.shape[:2]
    scale = chart_frac * width / tw
    src = np.array([[0, 0], [tw, 0], [tw, th], [0, th]], np.float32)
    cx, cy = width * rng.uniform(0.4, 0.6), height * rng.uniform(0.4, 0.6)
    angle = np.radians(rotation)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    dst = (src - [tw / 2, th / 2]) * scale
    dst[[1, 2], 1] *= 1 - tilt  # the right edge further away
    dst = dst @ rot.T + [cx, cy]
    H = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
    warped = cv2.warpPerspective(tex, H, (width, height), flags=cv2.INTER_AREA)
    mask = cv2.warpPerspective(np.ones((th, tw), np.float32), H, (width, height), flags=cv2.INTER_AREA)[:, :, None]
    scene = scene * (1 - mask) + warped * mask
    p = np.column_stack([centres, np.ones(24)]) @ H.T
    return scene.astype(np.float64), p[:, :2] / p[:, 2:], names, R, RGB


def write_raw_chart(path, camera: SimulatedCamera, *, layout: str = "classic", stops_under: float = 0.0,
                    full_well: float = 20000.0, read_noise: float = 3.0, seed: int = 0, size=(700, 1000),
                    model: str = "") -> RawChart:
    """Synthesise and write a raw capture (see the module docstring)."""
    scene, centres, names, R, RGB = render_scene(camera, layout, size, seed)
    exposure = write_raw_scene(path, scene, camera, stops_under=stops_under, full_well=full_well,
                               read_noise=read_noise, seed=seed, model=model)
    return RawChart(Path(path), centres, camera, names, R, RGB * exposure)


def write_raw_scene(path, scene: np.ndarray, camera: SimulatedCamera, *, stops_under: float = 0.0,
                    full_well: float = 20000.0, read_noise: float = 3.0, seed: int = 0, model: str = "") -> float:
    """A half-size linear scene mosaicked (RGGB), with noise, written as a 14-bit DNG; returns the exposure."""
    exposure = 2.0 ** -stops_under
    signal_half = np.clip(scene * exposure, 0, None)
    height, width = signal_half.shape[:2]
    signal = np.zeros((2 * height, 2 * width))
    for (i, j), ch in {(0, 0): 0, (0, 1): 1, (1, 0): 1, (1, 1): 2}.items():
        signal[i::2, j::2] = signal_half[:, :, ch]
    rng = np.random.default_rng(seed + 1)
    gain = (WHITE - BLACK) / full_well
    electrons = rng.poisson(np.minimum(signal, 2.0) * full_well)
    dn = BLACK + electrons * gain + read_noise * rng.standard_normal(signal.shape)
    write_cfa_dng(path, np.clip(np.round(dn), 0, WHITE).astype(np.uint16), "RGGB", (BLACK,) * 4, WHITE,
                  "camcal synthetic", model or camera.name)
    return exposure
