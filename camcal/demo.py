"""``camcal demo``: the whole pipeline on a stereo rig it renders itself.

The demo makes a known stereo rig (two 640x480 cameras with division-model
lens distortion, 0.1 m apart, toed in by 2 degrees), renders with Blender
(Cycles, CPU, in a subprocess: :mod:`camcal.demo_blender`) what a crew
would shoot with it - a chessboard at several poses, a textured room corner
seen from seven rig positions, a ColorChecker under a known light, a
coloured scene for colour matching - and runs camcal's verbs on those
images: ``calibrate board``, ``distortion fit``, ``stmap``, ``rectify``,
``solve``, ``colour fit``, ``colour match``, ``colour export`` and
``blender import``. Each stage compares what it recovered with the truth,
against the tolerance its issue set, and adds sections to
``DIR/report.html``.

Stages are an ordered list (:data:`STAGES`): a name and a function
``DemoContext -> StageResult`` (rows of recovered vs true values, output
files, report sections). Later stages read what earlier ones left in
``DemoContext.artifacts``; a new stage is added by inserting a
:class:`Stage` into the list; colour exports go in the report section
:data:`COLOUR_EXPORTS_SECTION`.

How the truth is made (stated in the report too):

- Geometry: Cycles has no lens distortion for perspective cameras, so each
  view is rendered by the undistorted camera on an overscan canvas
  (``camcal.geometry.undistort``, factor :data:`OVERSCAN`), and the rig's
  known distortion is then applied with camcal's own exact mapping (the
  redistort map of ``camcal.geometry.stmap.make_stmaps``: plate pixel ``x_d``
  samples the render at ``K_os K^-1 undistort(x_d)``), one cubic remap.
  Blender cameras are set by the add-on's mapping, exact to < 1e-3 px.
- Colour: Blender renders RGB, not spectra. Each camera's sensor is a
  measured one from colour-science (left: Nikon 5100, right: Sigma SDMerill)
  under CIE D65: the chart's patches (ISO 17321-1 ColorChecker spectra) get
  as diffuse albedo that sensor's linear RGB for the patch
  (``SimulatedCamera.RGB``), times one scale per camera. A sun of
  irradiance pi W/m^2 along the chart's normal makes Cycles' radiance
  ``albedo E / pi = albedo``: the rendered linear RGB is the simulated
  camera RGB, and the true XYZ are the spectra integrated under D65 with the
  CIE 1931 observer (:func:`reference_XYZ`, as the chart reference is). The
  independent set (190 RAW-to-ACES reflectances) goes through the same
  sensors and scale, without Blender.
- Colour match: the match scene's surfaces are mosaics of real surface
  colours; the right camera sees texture ``T``, the left one ``T N^T`` with
  ``N`` the least-squares 3x3 between the two sensors (:func:`true_match_matrix`),
  so the true right -> left match is ``N``; it is judged on the 190
  independent colours, which the fit never saw.
"""

from __future__ import annotations

import dataclasses
import html
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.errors import CamcalError
from camcal.geometry.camera import look_at
from camcal.geometry.distortion import Distortion
from camcal.rig import Camera, Frame, Rig, make_provenance

__all__ = [
    "COLOUR_EXPORTS_SECTION",
    "DemoConfig",
    "DemoContext",
    "DemoReport",
    "DemoRow",
    "DemoTruth",
    "FULL",
    "QUICK",
    "ReportSection",
    "STAGES",
    "Stage",
    "StageResult",
    "make_truth",
    "reference_XYZ",
    "run_demo",
    "true_match_matrix",
    "write_html",
]

#: Undistorted render canvas as a multiple of the plate (covers the barrel corners).
OVERSCAN = 1.15
#: Report section (``id``) where the colour export stage links its OCIO config and ICC profiles.
COLOUR_EXPORTS_SECTION = "colour-exports"
#: colour-science's methods compared with ``colour fit`` (issue 12: the best is an oracle
#: pick, on the independent set itself).
_COLOUR_SCIENCE = (
    [("Cheung 2004", {"terms": t}) for t in (3, 5, 7, 8, 10, 11, 14, 16, 17, 19, 20, 22)]
    + [("Finlayson 2015", {"degree": d}) for d in (1, 2, 3)]
    + [("Vandermonde", {"degree": d}) for d in (1, 2, 3)]
)


# -- results ---------------------------------------------------------------------------


@dataclass(frozen=True)
class DemoRow:
    """One recovered-vs-true comparison and the tolerance it must meet.

    ``error`` is what the tolerance bounds (``ok`` when ``|error| <=
    tolerance``); ``source`` names where the tolerance comes from.
    """

    stage: str
    quantity: str
    true: float
    recovered: float
    error: float
    tolerance: float
    unit: str
    source: str

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.error)) and abs(self.error) <= self.tolerance


@dataclass(frozen=True)
class ReportSection:
    """A titled piece of the HTML report; ``body`` is HTML (images by relative path)."""

    title: str
    body: str
    anchor: str = ""


@dataclass(frozen=True)
class StageResult:
    """What one stage measured, wrote and shows."""

    rows: tuple[DemoRow, ...] = ()
    outputs: tuple[tuple[str, Path], ...] = ()
    sections: tuple[ReportSection, ...] = ()


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo run.

    ``stages`` names the stages to run (in :data:`STAGES` order); a stage
    that needs an artifact of a skipped one fails with a clear error.
    """

    image_size: tuple[int, int] = (640, 480)
    n_board_views: int = 12
    n_scene_positions: int = 7
    samples: int = 32
    colour_model: str = "auto"
    seed: int = 0
    stages: tuple[str, ...] | None = None


#: What ``make demo`` runs.
FULL = DemoConfig()
#: A small real run for the fast tests: 6 board views, 8 samples, no SfM. Its renders are
#: noisier and its views fewer than the tolerances of the issues assume: the calibration rows
#: of a QUICK run may miss them (the tests check those that hold; ``make demo`` runs FULL).
QUICK = DemoConfig(n_board_views=6, samples=8,
                   stages=("render", "calibrate board", "distortion fit", "rectify", "colour fit", "colour match",
                           "colour export", "blender import"))


@dataclass(frozen=True)
class DemoTruth:
    """The known rig and scene.

    Attributes
    ----------
    rig : Rig
        The true cameras (left is the reference) with their distortion;
        ``frames`` are the rig's poses in the room (``rig_from_world``).
    board_spec : str
        The chessboard (``chessboard:9x6:0.04``, metres).
    board_poses : list of (R, t)
        ``X_rig = R X_board + t`` for each chessboard view.
    chart_pose : (R, t)
        The ColorChecker's pose, the same way.
    sensors : dict
        Camera name -> colour-science camera whose sensitivities it has.
    illuminant : str
        The light's CIE name.
    room_extent_m : float
        Side of the room corner's planes (the scene size for ``solve``).
    """

    rig: Rig
    board_spec: str
    board_poses: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    chart_pose: tuple[NDArray[np.float64], NDArray[np.float64]]
    sensors: dict[str, str]
    illuminant: str = "D65"
    room_extent_m: float = 2.5


@dataclass
class DemoContext:
    """Shared state of one run: where to write, the truth, and what stages produced.

    ``artifacts`` maps names (``"board_rig"``, ``"chart_images"``...) to what a
    stage wrote for the following ones.
    """

    out_dir: Path
    config: DemoConfig
    truth: DemoTruth
    artifacts: dict[str, Any] = field(default_factory=dict)

    def path(self, *parts: str) -> Path:
        """A path under the output folder (its parent created)."""
        path = self.out_dir.joinpath(*parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def need(self, name: str, stage: str) -> Any:
        if name not in self.artifacts:
            raise CamcalError(f"demo stage {stage!r} needs {name!r}, made by an earlier stage that did not run")
        return self.artifacts[name]


@dataclass(frozen=True)
class Stage:
    """One step of the demo: ``run(context) -> StageResult``."""

    name: str
    run: Callable[[DemoContext], StageResult]


@dataclass(frozen=True)
class DemoReport:
    """The whole run: rows, outputs, sections and seconds per stage."""

    rows: tuple[DemoRow, ...]
    outputs: tuple[tuple[str, Path], ...]
    sections: tuple[ReportSection, ...]
    seconds: tuple[tuple[str, float], ...]
    report: Path | None = None

    @property
    def failed(self) -> tuple[DemoRow, ...]:
        return tuple(row for row in self.rows if not row.ok)

    def table(self) -> str:
        """The recovered-vs-true table as aligned text."""
        header = (f"{'stage':<16}{'quantity':<44}{'true':>12}{'recovered':>12}{'error':>11}"
                  f"{'tolerance':>11}  {'unit':<7}{'ok':<4}source")
        lines = [header, "-" * len(header)]
        for row in self.rows:
            lines.append(
                f"{row.stage:<16}{row.quantity:<44}{_num(row.true):>12}{_num(row.recovered):>12}"
                f"{_num(row.error):>11}{_num(row.tolerance):>11}  {row.unit:<7}{'yes' if row.ok else 'NO':<4}{row.source}"
            )
        return "\n".join(lines)


def _num(value: float) -> str:
    value = float(value)
    if not np.isfinite(value):
        return str(value)
    if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e5):
        return f"{value:.3e}"
    return f"{value:.4f}"


# -- the known rig -------------------------------------------------------------------------


def _rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> NDArray[np.float64]:
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    return Rotation.from_euler("yxz", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()


def make_truth(config: DemoConfig = FULL) -> DemoTruth:
    """The known rig, board poses, chart pose and room trajectory of a run.

    Parameters
    ----------
    config : DemoConfig
        Image size (focal lengths and lambda scale with the width), number
        of board views and rig positions, and the seed of the board poses.

    Returns
    -------
    DemoTruth

    Notes
    -----
    Board poses are drawn (tilts up to 35 deg, 0.38 to 0.75 m away) until
    ``n_board_views`` show the whole printed board inside both distorted
    images. The principal points sit at the image centre because COLMAP holds the
    principal point there (``solve`` could not recover another); the
    division model is centred on the principal point (what ``calibrate
    board --model division`` and COLMAP's SIMPLE_DIVISION assume).
    """
    from camcal.geometry.board import parse_board  # noqa: PLC0415

    width, height = config.image_size
    centre = ((width - 1) / 2.0, (height - 1) / 2.0)
    scale = width / 640.0

    def camera(name, f, lam, R, c):
        K = np.array([[f * scale, 0.0, centre[0]], [0.0, f * scale, centre[1]], [0.0, 0.0, 1.0]])
        return Camera(name, (width, height), K, Distortion("division", {"lambda": lam / scale**2}),
                      np.asarray(R, dtype=np.float64), np.asarray(c, dtype=np.float64))

    left = camera("left", 500.0, -3.5e-7, np.eye(3), np.zeros(3))
    right = camera("right", 510.0, -3.0e-7, _rotation(-2.0, 0.3, 0.2), [0.1, 0.002, -0.003])
    # the rig moving through the room corner (cf. tests/geometry/test_sfm.py, scaled to a 2.5 m room)
    extent = 2.5
    k = extent / 8.0
    frames = []
    for i in range(config.n_scene_positions):
        c = k * np.array([5.5 - 0.4 * i, 4.0 + 0.3 * i, 1.6 + 0.05 * i])
        frames.append(Frame(i, look_at(c, k * np.array([1.5 + 0.1 * i, 1.5, 1.0])), c, {}))
    rig = Rig((left, right), units="m", frames=tuple(frames), provenance=make_provenance("demo truth"))
    board_spec = "chessboard:9x6:0.04"
    board = parse_board(board_spec)
    rng = np.random.default_rng(config.seed)
    poses = []
    outline = _board_outline(board)
    while len(poses) < config.n_board_views:
        R = _rotation(*rng.uniform([-35, -35, -15], [35, 35, 15]))
        t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(0.38, 0.75)])
        X = outline @ R.T + t - R @ _board_centre(board)
        if all(_inside(rig.camera(n).project(X), rig.camera(n).image_size, 8) for n in ("left", "right")):
            poses.append((R, t - R @ _board_centre(board)))
    chart_R = _rotation(4.0, -6.0, 2.0)
    chart_t = np.array([0.04, 0.0, 0.6]) - chart_R @ np.array([0.155, 0.105, 0.0])
    return DemoTruth(rig, board_spec, tuple(poses), (chart_R, chart_t),
                     {"left": "Nikon 5100 (NPL)", "right": "Sigma SDMerill (NPL)"}, "D65", extent)


def _board_centre(board) -> NDArray[np.float64]:
    return np.array([(board.columns - 1) * board.square / 2.0, (board.rows - 1) * board.square / 2.0, 0.0])


def _board_outline(board) -> NDArray[np.float64]:
    """The printed board's corners (the squares plus one white square of margin)."""
    s = board.square
    x0, y0, x1, y1 = -2 * s, -2 * s, (board.columns + 1) * s, (board.rows + 1) * s
    return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def _inside(pixels: NDArray, size: tuple[int, int], margin: float) -> bool:
    width, height = size
    return bool(np.all(np.isfinite(pixels)) and np.all(pixels >= margin)
                and np.all(pixels[:, 0] <= width - 1 - margin) and np.all(pixels[:, 1] <= height - 1 - margin))


def _board_corners(board, R, t) -> NDArray[np.float64]:
    """Inner corners of a chessboard view in rig coordinates, in board id order."""
    ids = np.arange(board.columns * board.rows)
    X = np.column_stack([(ids % board.columns) * board.square, (ids // board.columns) * board.square, np.zeros(len(ids))])
    return X @ R.T + t


def _angle_deg(R: NDArray[np.float64]) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


# -- stage: render -----------------------------------------------------------------------


def _chessboard_texture(board, path: Path, px: int = 64) -> Path:
    import cv2  # noqa: PLC0415

    cols, rows = board.columns + 1, board.rows + 1
    image = np.full(((rows + 2) * px, (cols + 2) * px), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                image[(r + 1) * px:(r + 2) * px, (c + 1) * px:(c + 2) * px] = 0
    cv2.imwrite(str(path), image)
    return path


def reference_XYZ(reflectances: str, illuminant: str) -> NDArray[np.float64]:
    """True XYZ (perfect white Y = 1) of a colour-science reflectance set under a CIE illuminant.

    Integrated exactly as ``camcal.colour.chart.reference_chart`` integrates
    the spectral charts (CIE 1931 2 degree observer, 380 to 780 nm every 5 nm),
    so that training and independent references agree whatever a camera's
    own spectral range (the Sigma's data stop at 400-680 nm).

    Notes
    -----
    ``XYZ = k sum_l R(l) S(l) xyz(l)`` with ``k = 1 / sum_l S(l) y(l)``.
    """
    import colour  # noqa: PLC0415

    from camcal.colour.spectral import reflectance_set  # noqa: PLC0415

    shape = colour.SpectralShape(380, 780, 5)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values
    S = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape).values
    _, R = reflectance_set(reflectances, shape.wavelengths)
    return (R * S) @ cmfs / float(S @ cmfs[:, 1])


def _chart_albedos(truth: DemoTruth) -> dict[str, tuple[NDArray, NDArray, NDArray]]:
    """Per camera: the chart's albedos, and the independent set's camera RGB (same scale) and true XYZ.

    The albedo of a patch is the camera's linear RGB for it under the light,
    ``SimulatedCamera.RGB`` (white G = 1), times ``0.8 / max(RGB_white)`` so
    that the perfect white would render at 0.8 at most.
    """
    from camcal.colour.spectral import SimulatedCamera, reflectance_set  # noqa: PLC0415

    test_XYZ = reference_XYZ("rawtoaces 190", truth.illuminant)
    out = {}
    for name, sensor in truth.sensors.items():
        sim = SimulatedCamera.from_colour(sensor, truth.illuminant)
        _, chart = reflectance_set("ISO 17321-1", sim.wavelengths)
        _, test = reflectance_set("rawtoaces 190", sim.wavelengths)
        scale = 0.8 / float(np.max(sim.RGB_white))
        out[name] = (sim.RGB(chart) * scale, sim.RGB(test) * scale, test_XYZ)
    return out


def _chart_quads(truth: DemoTruth, albedos: dict) -> tuple[list[dict], dict[str, list[str]], NDArray]:
    """Patch quads per camera (its own sensor's albedos), the chart body and a grey wall.

    Returns the quads, the quad names each camera sees, and the grid corners
    (top-left, top-right, bottom-right, bottom-left of the patch grid) in rig coordinates.
    """
    R, t = truth.chart_pose
    patch, gap = 0.04, 0.01
    cell = patch + gap

    def world(points):
        return (np.asarray(points, dtype=np.float64) @ R.T + t).tolist()

    def rect(x0, y0, x1, y1, z=0.0):
        return world([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])

    quads = [
        {"name": "chart_body", "corners": rect(-0.015, -0.015, 6 * cell + 0.015, 4 * cell + 0.015, 0.001),
         "colour": [0.02, 0.02, 0.02], "shader": "diffuse"},
        {"name": "chart_wall", "corners": rect(-0.5, -0.4, 0.8, 0.6, 0.05), "colour": [0.25, 0.25, 0.25],
         "shader": "diffuse"},
    ]
    seen = {}
    for name, (chart_rgb, *_rest) in albedos.items():
        seen[name] = ["chart_body", "chart_wall"]
        for i, rgb in enumerate(chart_rgb):
            r, c = divmod(i, 6)
            x0, y0 = c * cell + gap / 2, r * cell + gap / 2
            quads.append({"name": f"chart_{name}_{i:02d}", "corners": rect(x0, y0, x0 + patch, y0 + patch),
                          "colour": [float(v) for v in rgb], "shader": "diffuse"})
            seen[name].append(quads[-1]["name"])
    grid = np.array(world([[0, 0, 0], [6 * cell, 0, 0], [6 * cell, 4 * cell, 0], [0, 4 * cell, 0]]))
    return quads, seen, grid


def _room_quads(truth: DemoTruth, textures_dir: Path, rng: np.random.Generator) -> list[dict]:
    import cv2  # noqa: PLC0415

    from camcal.synthetic import procedural_texture, room_corner_planes  # noqa: PLC0415

    quads = []
    for i, (origin, axis_s, axis_t) in enumerate(room_corner_planes(truth.room_extent_m)):
        path = textures_dir / f"room_{i}.png"
        cv2.imwrite(str(path), procedural_texture(rng))
        corners = [origin, origin + axis_s, origin + axis_s + axis_t, origin + axis_t]
        quads.append({"name": f"room_{i}", "corners": [list(map(float, p)) for p in corners],
                      "texture": str(path), "shader": "emission", "interpolation": "Linear"})
    return quads


def true_match_matrix(albedos: dict) -> NDArray[np.float64]:
    """The match scene's right -> left 3x3 ``N`` (``RGB_left = N RGB_right``).

    The least-squares matrix between the two sensors' RGB of the 190
    independent reflectances: the match scene's surfaces are built so that the
    sensors relate exactly by it (see :func:`_match_quads`).
    """
    left, right = albedos["left"][1], albedos["right"][1]
    N, *_ = np.linalg.lstsq(right, left, rcond=None)
    return N.T


def _match_quads(truth: DemoTruth, albedos: dict, N: NDArray, textures_dir: Path,
                 rng: np.random.Generator) -> tuple[list[dict], dict[str, list[str]]]:
    """A coloured slanted wall and a box face in front of it, per camera (emissive).

    Each surface is a mosaic of real surface colours (the right sensor's RGB
    of the chart and independent reflectances whose left image ``N rgb`` is
    positive) shaded by grey noise for stereo texture: the right camera's
    texture is ``T``, the left one's ``T N^T`` (16-bit linear PNGs), so the
    true right -> left colour match is ``N`` at every pixel.
    """
    import cv2  # noqa: PLC0415

    from camcal.synthetic import procedural_texture  # noqa: PLC0415

    right = np.vstack([albedos["right"][0], albedos["right"][1]])
    palette = right[np.all(right @ N.T > 0.01, axis=1) & np.all(right > 0.01, axis=1)]
    surfaces = {  # name: (corners in rig coordinates TL, TR, BR, BL; mosaic cells)
        "match_wall": ([[-1.25, -1.0, 1.2], [1.25, -1.0, 1.9], [1.25, 1.0, 1.9], [-1.25, 1.0, 1.2]], 16),
        "match_box": ([[-0.3, -0.15, 0.95], [0.12, -0.15, 0.9], [0.12, 0.3, 0.9], [-0.3, 0.3, 0.95]], 6),
    }
    quads, seen = [], {name: [] for name in albedos}
    for surface, (corners, cells) in surfaces.items():
        index = cv2.resize(rng.integers(0, len(palette), (cells, cells)).astype(np.float32), (512, 512),
                           interpolation=cv2.INTER_NEAREST).astype(int)
        shading = 0.55 + 0.45 * procedural_texture(rng, 512).astype(np.float64) / 255.0
        texture = {"right": palette[index] * shading[..., None]}
        texture["left"] = texture["right"] @ N.T
        for name in albedos:
            path = textures_dir / f"{surface}_{name}.png"
            codes = np.round(np.clip(texture[name], 0.0, 1.0) * 65535).astype(np.uint16)
            if not cv2.imwrite(str(path), np.ascontiguousarray(codes[..., ::-1])):
                raise CamcalError(f"cannot write {path}")
            quads.append({"name": f"{surface}_{name}", "corners": corners, "texture": str(path),
                          "shader": "emission", "interpolation": "Linear"})
            seen[name].append(quads[-1]["name"])
    return quads, seen


def _shot(camera: Camera, quads: Sequence[str], out: Path) -> dict:
    """A Blender shot of the undistorted overscan camera of ``camera``."""
    from camcal.geometry.undistort import undistorted_view  # noqa: PLC0415

    view = undistorted_view(camera, "overscan", OVERSCAN)
    return {"camera": {"K": view.K_new.tolist(), "R": camera.R.tolist(), "c": camera.c.tolist(),
                       "image_size": list(view.image_size)},
            "quads": list(quads), "out": str(out)}


def _redistort_maps(camera: Camera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Plate pixel -> overscan render pixel (camcal's exact redistort mapping)."""
    from camcal.geometry.stmap import make_stmaps, pixels_from_st  # noqa: PLC0415

    maps = make_stmaps(camera, OVERSCAN)
    x, y = pixels_from_st(maps.redistort, maps.undistorted.image_size)
    return x.astype(np.float32), y.astype(np.float32)


def _write_plate(render: Path, maps, out: Path, bits: int) -> Path:
    """Apply the lens to a render and write it as a linear 8- or 16-bit PNG."""
    import cv2  # noqa: PLC0415

    from camcal.geometry.stmap import read_exr  # noqa: PLC0415
    from camcal.io.atomic import atomic_path  # noqa: PLC0415

    rgb = read_exr(render)[..., :3]
    plate = np.clip(cv2.remap(rgb, maps[0], maps[1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT), 0.0, 1.0)
    top = 255 if bits == 8 else 65535
    codes = np.round(plate * top).astype(np.uint8 if bits == 8 else np.uint16)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(codes[..., ::-1])):
            raise CamcalError(f"cannot write {out}")
    return out


def _stage_render(ctx: DemoContext) -> StageResult:
    from camcal.demo_blender import render_shots  # noqa: PLC0415
    from camcal.geometry.board import parse_board  # noqa: PLC0415

    truth, config = ctx.truth, ctx.config
    board = parse_board(truth.board_spec)
    renders = ctx.out_dir / "renders"
    renders.mkdir(parents=True, exist_ok=True)
    texture = _chessboard_texture(board, renders / "chessboard.png")
    outline = _board_outline(board)
    quads, shots, plates = [], [], []
    names = [camera.name for camera in truth.rig.cameras]
    for k, (R, t) in enumerate(truth.board_poses):
        quads.append({"name": f"board_{k:02d}", "corners": (outline @ R.T + t).tolist(), "texture": str(texture),
                      "shader": "emission", "interpolation": "Closest"})
        for name in names:
            shots.append(_shot(truth.rig.camera(name), [f"board_{k:02d}"], renders / f"board_{name}_{k:02d}.exr"))
            plates.append((name, ctx.path("images", "board", name, f"{name}_{k + 1:02d}.png"), 8))
    run_solve = config.stages is None or "solve" in config.stages
    if run_solve:
        room = _room_quads(truth, renders, np.random.default_rng(config.seed))
        quads += room
        for frame in truth.rig.frames:
            for name in names:
                shots.append(_shot(truth.rig.camera_at_frame(name, frame.index), [q["name"] for q in room],
                                   renders / f"room_{name}_{frame.index:02d}.exr"))
                plates.append((name, ctx.path("images", "room", name, f"{frame.index:04d}.png"), 8))
    albedos = _chart_albedos(truth)
    chart_quads, seen, grid = _chart_quads(truth, albedos)
    quads += chart_quads
    for name in names:
        shots.append(_shot(truth.rig.camera(name), seen[name], renders / f"chart_{name}.exr"))
        plates.append((name, ctx.path("images", "chart", f"{name}.png"), 16))
    run_match = config.stages is None or "colour match" in config.stages
    if run_match:
        N = true_match_matrix(albedos)
        match_quads, match_seen = _match_quads(truth, albedos, N, renders, np.random.default_rng(config.seed + 1))
        quads += match_quads
        for name in names:
            shots.append(_shot(truth.rig.camera(name), match_seen[name], renders / f"match_{name}.exr"))
            plates.append((name, ctx.path("images", "match", f"{name}.png"), 16))
        ctx.artifacts["match_images"] = {n: ctx.out_dir / "images" / "match" / f"{n}.png" for n in names}
        ctx.artifacts["match_truth"] = N
    R_chart = truth.chart_pose[0]
    job = {"samples": config.samples, "seed": config.seed, "quads": quads, "shots": shots,
           # irradiance pi along the chart's normal: radiance = albedo (Lambertian, albedo E / pi)
           "suns": [{"direction": (R_chart @ [0.0, 0.0, 1.0]).tolist(), "strength": float(np.pi)}]}
    exrs = render_shots(job, renders)
    maps = {name: _redistort_maps(truth.rig.camera(name)) for name in names}
    for exr, (name, plate, bits) in zip(exrs, plates):
        _write_plate(exr, maps[name], plate, bits)
    ctx.artifacts["board_images"] = {n: sorted(str(p) for c, p, _ in plates if c == n and "board" in p.parts)
                                     for n in names}
    if run_solve:
        ctx.artifacts["room_dirs"] = [ctx.out_dir / "images" / "room" / n for n in names]
    ctx.artifacts["chart_images"] = {n: ctx.out_dir / "images" / "chart" / f"{n}.png" for n in names}
    ctx.artifacts["chart_truth"] = albedos
    ctx.artifacts["chart_grid"] = {n: truth.rig.camera(n).project(grid) for n in names}
    truth.rig.save(ctx.path("truth.rig.json"))
    board_pair = [ctx.artifacts["board_images"][n][0] for n in names]
    chart_pair = [str(ctx.artifacts["chart_images"][n]) for n in names]
    figure = _plot_images(ctx.path("plots", "renders.png"), board_pair + chart_pair,
                          [f"{n}: chessboard" for n in names] + [f"{n}: chart (linear, {truth.sensors[n]})" for n in names],
                          columns=2)
    match_note = ("<p>Colour match scene: a slanted wall and a box in front of it, emissive mosaics of real "
                  "surface colours shaded by grey noise. The right camera's textures are <i>T</i>, the left "
                  "one's <i>T N</i><sup>T</sup>, with <i>N</i> the least-squares 3x3 between the two sensors "
                  "over the 190 reflectances: the true right-to-left match is <i>N</i> at every pixel.</p>"
                  if run_match else "")
    room_note = (f"{len(truth.rig.frames)} rig positions in a {truth.room_extent_m:g} m room corner, "
                 if run_solve else "")
    body = (
        f"<p>{len(shots)} Cycles renders ({config.samples} samples, seed {config.seed}, CPU): "
        f"{len(truth.board_poses)} chessboard poses, {room_note}a ColorChecker per camera. "
        f"Cycles has no lens distortion for perspective cameras: each view is rendered undistorted on a "
        f"{OVERSCAN:g}x overscan canvas, then the rig's known division-model distortion is applied with "
        f"camcal's exact redistort mapping (<code>camcal.geometry.stmap.make_stmaps</code>, one cubic remap).</p>"
        f"<p>Colour truth: Blender renders RGB, not spectra. Each camera's sensor is a measured one "
        f"(left {html.escape(truth.sensors['left'])}, right {html.escape(truth.sensors['right'])}) under CIE "
        f"{truth.illuminant}; the patches' diffuse albedos are that sensor's linear RGB for the ISO 17321-1 "
        f"ColorChecker spectra, and a sun of irradiance &pi; W/m&sup2; along the chart's normal makes the "
        f"rendered radiance equal to the albedo. The true XYZ are the spectra under {truth.illuminant} (CIE 1931 observer, 380-780 nm), "
        f"for the chart and for the independent set of 190 RAW-to-ACES reflectances alike.</p>"
        f"{match_note}{_img(ctx, figure)}"
    )
    return StageResult(
        outputs=(("true rig (truth.rig.json)", ctx.out_dir / "truth.rig.json"),
                 ("Blender render job", renders / "render_job.json")),
        sections=(ReportSection("Rendered plates", body, "renders"),),
    )


# -- stage: calibrate board ----------------------------------------------------------------


def _stage_calibrate_board(ctx: DemoContext) -> StageResult:
    from camcal.geometry.board import detect_in_images, parse_board  # noqa: PLC0415
    from camcal.geometry.zhang import calibrate_board, write_report  # noqa: PLC0415

    truth = ctx.truth
    images = ctx.need("board_images", "calibrate board")
    board = parse_board(truth.board_spec)
    detections = {name: detect_in_images(board, files).detections for name, files in images.items()}
    result = calibrate_board(board, detections, model="division", units="m")
    rig_path = result.rig.save(ctx.path("calibrate", "board.rig.json"))
    plots = write_report(result, ctx.out_dir / "calibrate")
    ctx.artifacts["board_rig"] = rig_path
    rows = []
    stage = "calibrate board"
    for camera in result.rig.cameras:
        true = truth.rig.camera(camera.name)
        for i, name in ((0, "fx"), (1, "fy")):
            t_, r_ = true.K[i, i], camera.K[i, i]
            rows.append(DemoRow(stage, f"{camera.name} {name} error", t_, r_, 100 * (r_ - t_) / t_, 0.1, "%", "issue 3"))
        for i, name in ((0, "cx"), (1, "cy")):
            t_, r_ = true.K[i, 2], camera.K[i, 2]
            rows.append(DemoRow(stage, f"{camera.name} {name}", t_, r_, r_ - t_, 0.3, "px", "issue 3"))
        t_, r_ = true.distortion.params["lambda"], camera.distortion.params["lambda"]
        rows.append(DemoRow(stage, f"{camera.name} division lambda", t_, r_, 100 * (r_ - t_) / t_, 2.0, "%", "issue 4"))
    left_t, right_t = truth.rig.camera("left"), truth.rig.camera("right")
    left_r, right_r = result.rig.camera("left"), result.rig.camera("right")
    baseline_t = float(np.linalg.norm(right_t.c - left_t.c))
    baseline_r = float(np.linalg.norm(right_r.c - left_r.c))
    rows.append(DemoRow(stage, "baseline length error", baseline_t, baseline_r,
                        100 * (baseline_r - baseline_t) / baseline_t, 0.1, "%", "issue 3"))
    relative_t, relative_r = right_t.R @ left_t.R.T, right_r.R @ left_r.R.T
    rows.append(DemoRow(stage, "relative rotation error", 0.0, _angle_deg(relative_r @ relative_t.T),
                        _angle_deg(relative_r @ relative_t.T), 0.02, "deg", "issue 3"))
    residual_plot = _plot_residuals(ctx.path("plots", "board_residuals.png"), result.rig.cameras,
                                    result.camera_of_point, result.points_px, result.residuals_px)
    command = (f"camcal calibrate board --board {truth.board_spec} --camera left='images/board/left/*.png' "
               f"--camera right='images/board/right/*.png' --model division --out calibrate/board.rig.json "
               f"--report calibrate")
    body = (f"<pre>{html.escape(command)}</pre><pre>{html.escape(result.summary())}</pre>"
            f"{_img(ctx, residual_plot)}"
            + "".join(_img(ctx, p, width=320) for p in plots))
    return StageResult(tuple(rows), (("board calibration (board.rig.json)", rig_path),),
                       (ReportSection("Chessboard calibration", body, "calibrate-board"),))


# -- stage: distortion fit (+ ST-maps) ----------------------------------------------------


def _stage_distortion_fit(ctx: DemoContext) -> StageResult:
    from camcal.io.jsonfile import read_json  # noqa: PLC0415

    stage = "distortion fit"
    images = ctx.need("board_images", stage)["left"]
    lens = ctx.path("distortion", "left.lens.json")
    argv = ["distortion", "fit", *images, "--pattern", "9x6", "--model", "division", "--fit-centre",
            "--out", str(lens), "--report", str(ctx.out_dir / "distortion")]
    _run_cli(argv, stage)
    fitted = read_json(lens, "lens file")
    distortion = Distortion.from_dict(fitted["distortion"])
    true = ctx.truth.rig.camera("left")
    lam_t, lam_r = true.distortion.params["lambda"], distortion.params["lambda"]
    centre_t = true.K[:2, 2]
    centre_r = np.asarray(distortion.center if distortion.center is not None else centre_t)
    rows = [
        DemoRow(stage, "left division lambda (plumb-line)", lam_t, lam_r, 100 * (lam_r - lam_t) / lam_t, 2.0, "%", "issue 4"),
        DemoRow(stage, "left distortion centre (plumb-line)", 0.0, float(np.linalg.norm(centre_r - centre_t)),
                float(np.linalg.norm(centre_r - centre_t)), 3.0, "px", "issue 4"),
        DemoRow(stage, "left straightness after correction", 0.0, float(fitted["straightness_rms_px"]),
                float(fitted["straightness_rms_px"]), 0.15, "px", "issue 4"),
    ]
    board_rig = ctx.need("board_rig", stage)
    stmap_dir = ctx.out_dir / "stmap"
    _run_cli(["stmap", str(board_rig), "--camera", "left", "--out", str(stmap_dir)], stage)
    outputs = (("plumb-line lens (left.lens.json)", lens),
               ("ST-map undistort, left (EXR)", stmap_dir / "left_undistort.exr"),
               ("ST-map redistort, left (EXR)", stmap_dir / "left_redistort.exr"))
    shown = ["distortion", "fit", str(Path(images[0]).parent / "*.png"), *argv[2 + len(images):]]
    body = (f"<pre>{html.escape(_command(shown, ctx))}</pre>"
            f"<p>Plumb-line fit on the rows and columns of the left camera's chessboard views: lambda "
            f"{lam_r:.4e} (true {lam_t:.4e}), centre ({centre_r[0]:.2f}, {centre_r[1]:.2f}) px (true "
            f"({centre_t[0]:.2f}, {centre_t[1]:.2f})). ST-maps of the board calibration's left camera for comp "
            f"packages (Nuke STMap):</p><pre>{html.escape(_command(['stmap', str(board_rig), '--camera', 'left', '--out', str(stmap_dir)], ctx))}</pre>")
    return StageResult(tuple(rows), outputs, (ReportSection("Lens distortion (plumb-line) and ST-maps", body, "distortion"),))


# -- stage: rectify --------------------------------------------------------------------------


def _stage_rectify(ctx: DemoContext) -> StageResult:
    import cv2  # noqa: PLC0415

    from camcal.geometry.board import detect_board, parse_board  # noqa: PLC0415
    from camcal.geometry.rectify import vertical_disparity  # noqa: PLC0415

    stage = "rectify"
    truth = ctx.truth
    board_rig = ctx.need("board_rig", stage)
    images = ctx.need("board_images", stage)
    pair_dir = ctx.out_dir / "rectify" / "input"
    chosen = {}
    for name in ("left", "right"):
        sources = [images[name][0]]
        if "room_dirs" in ctx.artifacts:
            sources.append(str(ctx.out_dir / "images" / "room" / name / "0003.png"))
        (pair_dir / name).mkdir(parents=True, exist_ok=True)
        for source in sources:
            shutil.copyfile(source, pair_dir / name / f"{Path(source).parent.parent.name}_{Path(source).name}")
        chosen[name] = sorted(str(p) for p in (pair_dir / name).iterdir())
    rect_path = ctx.path("rectify", "rectified.rig.json")
    written_dir = ctx.out_dir / "rectify" / "images"
    argv = ["rectify", str(board_rig), "--images", f"left={pair_dir / 'left'}/*.png", f"right={pair_dir / 'right'}/*.png",
            "--out", str(rect_path), "--write", str(written_dir), "--report", str(ctx.out_dir / "rectify")]
    _run_cli(argv, stage)
    ctx.artifacts["rectified_rig"] = rect_path
    rig = Rig.load(rect_path)
    board = parse_board(truth.board_spec)
    # held-out truth: every board corner of every view, projected by the TRUE cameras
    xl, xr = [], []
    for R, t in truth.board_poses:
        X = _board_corners(board, R, t)
        xl.append(truth.rig.camera("left").project(X))
        xr.append(truth.rig.camera("right").project(X))
    truth_disparity = vertical_disparity(rig, {("left", "right"): (np.vstack(xl), np.vstack(xr))})[0]
    # the written rectified board pair: corners detected in the images themselves
    board_name = Path(chosen["left"][0]).name
    found = [detect_board(board, cv2.imread(str(written_dir / n / Path(chosen[n][0]).name), cv2.IMREAD_GRAYSCALE), n)
             for n in ("left", "right")]
    rows = [DemoRow(stage, "vertical disparity RMS, true corners", 0.0, truth_disparity.rms_px,
                    truth_disparity.rms_px, 0.3, "px", "issue 6")]
    if all(d is not None for d in found):
        ids_l, ids_r = list(found[0].ids), list(found[1].ids)
        common = [i for i in ids_l if i in ids_r]
        dy = np.array([found[0].corners_px[ids_l.index(i), 1] - found[1].corners_px[ids_r.index(i), 1] for i in common])
        rms = float(np.sqrt(np.mean(dy**2)))
        rows.append(DemoRow(stage, "vertical disparity RMS, detected in written pair", 0.0, rms, rms, 0.3, "px", "issue 6"))
    else:
        rows.append(DemoRow(stage, "vertical disparity RMS, detected in written pair", 0.0, float("nan"),
                            float("nan"), 0.3, "px", "issue 6"))
    figures = [_plot_epipolar(ctx.path("plots", f"rectified_{Path(chosen['left'][i]).stem}.png"),
                              written_dir / "left" / Path(chosen["left"][i]).name,
                              written_dir / "right" / Path(chosen["right"][i]).name)
               for i in range(len(chosen["left"]))]
    body = (f"<pre>{html.escape(_command(argv, ctx))}</pre>"
            f"<p>Calibrated (camera-based) rectification of the board calibration. The vertical disparity is "
            f"measured on every chessboard corner projected by the true cameras ({truth_disparity.n} "
            f"correspondences) and on the corners detected in the written rectified pair "
            f"<code>{html.escape(board_name)}</code>. Horizontal lines are epipolar lines after rectification.</p>"
            + "".join(_img(ctx, f) for f in figures))
    return StageResult(tuple(rows), (("rectified rig (rectified.rig.json)", rect_path),
                                     ("rectified images", written_dir)),
                       (ReportSection("Rectification", body, "rectify"),))


# -- stage: solve ------------------------------------------------------------------------------


def _similarity(source: NDArray, target: NDArray) -> tuple[float, NDArray, NDArray]:
    """Umeyama (1991): ``s, R, t`` minimising ``|target - (s R source + t)|``."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    u, d, vt = np.linalg.svd(cov)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / np.mean(np.sum((source - mu_s) ** 2, axis=1)))
    return scale, R, mu_t - scale * R @ mu_s


def _sfm_residuals(model_dir: Path, camera_names: list[str]) -> tuple[NDArray, NDArray, NDArray]:
    """Camera index, observed pixel and residual (observed - projected) of every observation of the
    refined COLMAP model ``solve`` wrote (image names are ``camera/file``)."""
    import pycolmap  # noqa: PLC0415

    reconstruction = pycolmap.Reconstruction(str(model_dir))
    cameras, points, residuals = [], [], []
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        index = camera_names.index(image.name.split("/", 1)[0])
        for point in image.get_observation_points2D():
            projected = image.project_point(reconstruction.points3D[point.point3D_id].xyz)
            if projected is not None:
                cameras.append(index)
                points.append(point.xy)
                residuals.append(point.xy - projected)
    return np.asarray(cameras), np.asarray(points), np.asarray(residuals)


def _stage_solve(ctx: DemoContext) -> StageResult:
    stage = "solve"
    truth = ctx.truth
    folders = ctx.need("room_dirs", stage)
    out = ctx.out_dir / "solve"
    # COLMAP's INFO log (thousands of lines) would drown the demo's output; warnings still show
    os.environ.setdefault("GLOG_minloglevel", "1")
    argv = ["solve", *map(str, folders), "--out", str(out), "--model", "division", "--seed", str(ctx.config.seed)]
    _run_cli(argv, stage)
    rig = Rig.load(out / "solve.rig.json")
    ctx.artifacts["solve_rig"] = out / "solve.rig.json"
    n_images = 2 * len(truth.rig.frames)
    solved = {(name, frame.index): rig.camera_at_frame(name, frame.index) for frame in rig.frames for name in frame.images}
    registered = len(solved)
    rows = [DemoRow(stage, "images registered", n_images, registered, n_images - registered, 0, "images", "issue 5")]
    for camera in rig.cameras:
        f_t, f_r = truth.rig.camera(camera.name).K[0, 0], camera.K[0, 0]
        rows.append(DemoRow(stage, f"{camera.name} focal error", f_t, f_r, 100 * (f_r - f_t) / f_t, 0.5, "%", "issue 5"))
    # frames are numbered in order of the registered frames: match them by image name
    index_of = {frame.index: int(Path(next(iter(frame.images.values()))).stem) for frame in rig.frames}
    keys = sorted(solved)
    true_cams = {k: truth.rig.camera_at_frame(k[0], index_of[k[1]]) for k in keys}
    s, R_align, t = _similarity(np.array([solved[k].c for k in keys]), np.array([true_cams[k].c for k in keys]))
    centre_err = max(float(np.linalg.norm(s * R_align @ solved[k].c + t - true_cams[k].c)) for k in keys)
    rot_err = max(_angle_deg(true_cams[k].R @ (solved[k].R @ R_align.T).T) for k in keys)
    size = truth.room_extent_m
    rows.append(DemoRow(stage, "worst camera rotation error", 0.0, rot_err, rot_err, 0.1, "deg", "issue 5"))
    rows.append(DemoRow(stage, "worst camera centre error (% of scene)", 0.0, 100 * centre_err / size,
                        100 * centre_err / size, 0.5, "%", "issue 5"))
    right_t, right_r = truth.rig.camera("right"), rig.camera("right")
    d_t, d_r = right_t.c / np.linalg.norm(right_t.c), right_r.c / np.linalg.norm(right_r.c)
    angle = float(np.degrees(np.arccos(np.clip(d_t @ d_r, -1.0, 1.0))))
    rows.append(DemoRow(stage, "baseline direction error (rig constraint)", 0.0, angle, angle, 0.1, "deg", "issue 5"))
    quality = ", ".join(f"{c.name} {c.quality['rms_px']:.3f} px" for c in rig.cameras)
    residual_plot = _plot_residuals(ctx.path("plots", "solve_residuals.png"), rig.cameras,
                                    *_sfm_residuals(out / "sparse" / "best", [c.name for c in rig.cameras]),
                                    what="feature")
    body = (f"<pre>{html.escape(_command(argv, ctx))}</pre><p>pycolmap SIFT + incremental mapping with the rig "
            f"constraint (division lens: COLMAP's SIMPLE_DIVISION), then camcal's bundle adjustment; RMS reprojection error through camcal's rig: "
            f"{quality}. Poses compared after a similarity (Umeyama 1991) to the true ones; "
            f"scene size {size:g} m.</p>{_img(ctx, residual_plot)}")
    return StageResult(tuple(rows), (("SfM rig (solve.rig.json)", out / "solve.rig.json"), ("sparse points (points.ply)", out / "points.ply")),
                       (ReportSection("Structure from motion", body, "solve"),))


# -- stage: colour fit -------------------------------------------------------------------------


def _colour_science_best(train, test, white) -> tuple[float, str]:
    """colour-science's best ``matrix_colour_correction`` on the independent set (oracle pick)."""
    from colour.characterisation import apply_matrix_colour_correction, matrix_colour_correction  # noqa: PLC0415

    from camcal.colour.evaluate import delta_E  # noqa: PLC0415

    best = []
    for method, kw in _COLOUR_SCIENCE:
        M = matrix_colour_correction(train.RGB, train.XYZ, method=method, **kw)
        pred = apply_matrix_colour_correction(test.RGB, M, method=method, **kw)
        label = f"{method} " + ", ".join(f"{k}={v}" for k, v in kw.items())
        best.append((float(np.mean(delta_E(pred, test.XYZ, white))), label))
    return min(best)


def _colour_fit_argv(ctx: DemoContext, name: str, model: str, out: Path) -> list[str]:
    """``camcal colour fit`` of camera ``name``'s rendered chart, judged on its independent patches."""
    return ["colour", "fit", "--chart", str(ctx.need("chart_images", "colour fit")[name]),
            "--reference", "ISO 17321-1", "--illuminant", ctx.truth.illuminant, "--linearise", "none",
            "--model", model, "--test-patches", str(_independent_csv(ctx, name)), "--camera", name, "--out", str(out)]


def _independent_csv(ctx: DemoContext, name: str) -> Path:
    """Where the colour fit stage writes camera ``name``'s independent patches (the 190 reflectances)."""
    return ctx.path("colour", f"{name}_independent.csv")


def _stage_colour_fit(ctx: DemoContext) -> StageResult:
    from camcal.colour.characterise import patches_from_chart  # noqa: PLC0415
    from camcal.colour.fitfile import load_fit  # noqa: PLC0415
    from camcal.colour.patches import PatchSet, read_patch_csv, write_patch_csv  # noqa: PLC0415

    stage = "colour fit"
    truth = ctx.truth
    charts = ctx.need("chart_images", stage)
    albedos = ctx.need("chart_truth", stage)
    rows, outputs, body = [], [], ""
    fits, detected, tests = {}, {}, {}
    for name, chart in charts.items():
        chart_rgb, test_rgb, test_xyz = albedos[name]
        test_csv = _independent_csv(ctx, name)
        write_patch_csv(test_csv, PatchSet(tuple(f"rawtoaces{i:03d}" for i in range(len(test_rgb))), test_rgb, test_xyz))
        tests[name] = test_csv
        fit_path = ctx.path("colour", f"{name}.colour.json")
        report_dir = ctx.out_dir / "colour" / name
        argv = _colour_fit_argv(ctx, name, ctx.config.colour_model, fit_path) + ["--report", str(report_dir)]
        _run_cli(argv, stage)
        fits[name] = fit_path
        found = patches_from_chart(chart, "ISO 17321-1", illuminant=truth.illuminant)
        detected[name] = found.patches
        kept = [found.reference.patch_names.index(n) for n in found.patches.names]
        relative = np.abs(found.patches.RGB / chart_rgb[kept] - 1.0)
        rows.append(DemoRow(stage, f"{name} chart RGB vs simulated sensor (worst)", 0.0, 100 * float(relative.max()),
                            100 * float(relative.max()), 0.2, "%", "issue 12 noise"))
        test = read_patch_csv(test_csv)
        peer, label = _colour_science_best(found.patches, test, found.reference.white_XYZ)
        ours = float(load_fit(fit_path).evaluation["test"]["mean"])
        rows.append(DemoRow(stage, f"{name} independent mean dE2000 (vs colour-science)", 0.0, ours, ours, peer,
                            "dE00", "issue 12"))
        outputs.append((f"{name} colour fit ({name}.colour.json)", fit_path))
        summary = (report_dir / "summary.txt").read_text()
        body += (f"<h3>{html.escape(name)}: {html.escape(truth.sensors[name])} under {truth.illuminant}</h3>"
                 f"<pre>{html.escape(_command(argv, ctx))}</pre><pre>{html.escape(summary)}</pre>"
                 f"<p>colour-science's best on the same patches (picked on the independent set itself): "
                 f"{html.escape(label)}, mean CIEDE2000 {peer:.3f}.</p>"
                 f"{_img(ctx, report_dir / 'train' / 'swatches.png', width=480)}"
                 f"{_img(ctx, report_dir / 'test' / 'delta_E_histogram.png', width=420)}"
                 f"{_img(ctx, report_dir / 'test' / 'ab_errors.png', width=420)}")
    ctx.artifacts["colour_fits"] = fits
    ctx.artifacts["independent_patches"] = tests
    # the patches both cameras' charts gave (what the chart route of ``colour match`` reads)
    common = [n for n in detected["left"].names if all(n in d.names for d in detected.values())]
    chart_csvs = {}
    for name, patches in detected.items():
        chart_csvs[name] = ctx.path("colour", f"{name}_chart.csv")
        write_patch_csv(chart_csvs[name], patches.subset([patches.names.index(n) for n in common]))
    ctx.artifacts["chart_patches"] = chart_csvs
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Colour characterisation", body, "colour-fit"),))


# -- stage: colour match --------------------------------------------------------------------------


def _stage_colour_match(ctx: DemoContext) -> StageResult:
    from camcal.colour.evaluate import delta_E  # noqa: PLC0415
    from camcal.colour.fitfile import load_fit  # noqa: PLC0415
    from camcal.colour.match import load_match  # noqa: PLC0415

    stage = "colour match"
    fits = ctx.need("colour_fits", stage)
    images = ctx.need("match_images", stage)
    N = ctx.need("match_truth", stage)
    albedos = ctx.need("chart_truth", stage)
    board_rig = ctx.need("board_rig", stage)
    rows, outputs = [], []
    # image route: the stereo pair of the match scene, rectified with the board calibration
    image_match = ctx.path("colour", "match_right_to_left.colour.json")
    report_dir = ctx.out_dir / "colour" / "match"
    argv = ["colour", "match", str(board_rig), "--images", f"left={images['left']}", f"right={images['right']}",
            "--fits", f"left={fits['left']}", f"right={fits['right']}", "--model", "matrix3x3",
            "--out", str(image_match), "--report", str(report_dir)]
    _run_cli(argv, stage)
    match = load_match(image_match)
    left_fit = load_fit(fits["left"])
    # held-out colours: the 190 independent reflectances as the right camera sees them
    right_rgb = albedos["right"][1]
    dE = delta_E(left_fit.apply(match.apply(right_rgb)), left_fit.apply(right_rgb @ N.T), left_fit.target_white_XYZ)
    rows.append(DemoRow(stage, "match (image route) vs true N, mean dE00", 0.0, float(dE.mean()),
                        float(dE.mean()), 0.5, "dE00", "issue 8"))
    outputs.append(("camera match right -> left, image route (match_right_to_left.colour.json)", image_match))
    ctx.artifacts["colour_match"] = image_match
    # chart route: both characterisations on the same chart, judged on the independent set
    chart_match = ctx.path("colour", "match_chart.colour.json")
    patches = ctx.need("chart_patches", stage)
    tests = ctx.need("independent_patches", stage)
    chart_argv = ["colour", "match", "--fits", f"left={fits['left']}", f"right={fits['right']}",
                  "--patches", f"left={patches['left']}", f"right={patches['right']}",
                  "--test-patches", f"left={tests['left']}", f"right={tests['right']}",
                  "--model", "root-polynomial:2", "--out", str(chart_match)]
    _run_cli(chart_argv, stage)
    chart = load_match(chart_match)
    own = sum(float(load_fit(fits[n]).evaluation["test"]["mean"]) for n in ("left", "right"))
    after = float(chart.evaluation["test"]["mean"])
    rows.append(DemoRow(stage, "match (chart route) camera-to-camera dE00", 0.0, after, after, own,
                        "dE00", "issue 8: < sum of own errors"))
    outputs.append(("camera match right -> left, chart route (match_chart.colour.json)", chart_match))
    before = chart.evaluation["before"]["mean"]
    pictures = [report_dir / f for f in ("target.png", "source_before.png", "source_after.png",
                                         "delta_E_before.png", "delta_E_after.png", "valid.png")]
    body = (f"<pre>{html.escape(_command(argv, ctx))}</pre><pre>{html.escape(match.summary())}</pre>"
            f"<p>Image route: the match scene rendered by both cameras, rectified with the board calibration, "
            f"SGBM correspondences with a left-right check, robust fit (LMedS + IRLS). Judged against the true "
            f"matrix <i>N</i> on colours the fit never saw (the right sensor's RGB of the 190 independent "
            f"reflectances), in CIEDE2000 through the left camera's characterisation: mean {dE.mean():.3f}, "
            f"max {dE.max():.3f}.</p>"
            + "".join(_img(ctx, p, width=320) for p in pictures if p.is_file())
            + f"<pre>{html.escape(_command(chart_argv, ctx))}</pre><pre>{html.escape(chart.summary())}</pre>"
            f"<p>Chart route: both cameras to XYZ through their characterisations; camera-to-camera CIEDE2000 on "
            f"the independent set {before:.2f} before, {after:.2f} after the match (issue 8 asks for less than "
            f"the sum of the two cameras' own errors, {own:.2f}).</p>")
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Colour match between the cameras", body, "colour-match"),))


# -- stage: colour export -------------------------------------------------------------------------

#: OCIO's XYZ space in camcal's base config (and in the ACES studio config).
_OCIO_XYZ_D65 = "CIE XYZ-D65 - Scene-referred"


def _ocio_apply(processor, RGB: NDArray) -> NDArray[np.float64]:
    """OCIO's CPU processor without its fast approximations (lossless optimisation)."""
    import PyOpenColorIO as ocio  # noqa: PLC0415

    from camcal.colour.export_ocio import _apply_cpu  # noqa: PLC0415

    return _apply_cpu(processor.getOptimizedCPUProcessor(ocio.OPTIMIZATION_LOSSLESS), RGB)


def _exportable_fits(ctx: DemoContext, stage: str) -> tuple[dict[str, Path], dict[str, tuple[str, str]], list]:
    """Each camera's fit, or its 3x3 matrix fit where the exporter refuses to bake the chosen one.

    A strongly non-linear fit (e.g. a root-polynomial with large cancelling
    coefficients, which ``auto`` can pick for a sensor far from the CIE
    observer) may not fit in a 65^3 Lut3D / CLUT within CIEDE2000 0.2; the
    exporter then refuses, as it would for a user, and the demo refits the
    camera with ``--model matrix3x3``. Returns the fits, the refusals
    (camera -> (model, reason)) and the refit commands.
    """
    from camcal.colour.export_icc import icc_profile_from_fit  # noqa: PLC0415
    from camcal.colour.export_ocio import CAMCAL_BASE, colour_space_from_fit, load_base_config  # noqa: PLC0415
    from camcal.colour.fitfile import load_fit  # noqa: PLC0415

    base = load_base_config(CAMCAL_BASE)
    fits, refused, commands = {}, {}, []
    for name, path in ctx.need("colour_fits", stage).items():
        fit = load_fit(path)
        try:
            colour_space_from_fit(fit, name, base)
            icc_profile_from_fit(fit, name)
            fits[name] = path
        except CamcalError as error:
            refused[name] = (fit.model.label, str(error))
            fits[name] = ctx.path("colour", f"{name}_matrix.colour.json")
            commands.append(_colour_fit_argv(ctx, name, "matrix3x3", fits[name]))
            _run_cli(commands[-1], stage)
    return fits, refused, commands


def _stage_colour_export(ctx: DemoContext) -> StageResult:
    import PyOpenColorIO as ocio  # noqa: PLC0415

    from camcal.colour.evaluate import delta_E  # noqa: PLC0415
    from camcal.colour.export_icc import D50_XYZ  # noqa: PLC0415
    from camcal.colour.export_ocio import colour_space_name, look_name  # noqa: PLC0415
    from camcal.colour.fitfile import load_fit  # noqa: PLC0415
    from camcal.colour.lcms import lcms_to_XYZ, load_lcms  # noqa: PLC0415
    from camcal.colour.match import load_match  # noqa: PLC0415
    from camcal.colour.patches import read_patch_csv  # noqa: PLC0415
    from camcal.colour.spectral import adapt_XYZ, illuminant_white_XYZ  # noqa: PLC0415

    stage = "colour export"
    fits, refused, commands = _exportable_fits(ctx, stage)
    samples = {name: np.vstack([read_patch_csv(ctx.need("chart_patches", stage)[name]).RGB,
                                read_patch_csv(ctx.need("independent_patches", stage)[name]).RGB])
               for name in fits}
    match_path = ctx.artifacts.get("colour_match")
    ocio_dir = ctx.out_dir / "ocio"
    argv = ["colour", "export", *map(str, fits.values()), *([str(match_path)] if match_path else []),
            "--ocio", str(ocio_dir), "--base", "camcal"]
    _run_cli(argv, stage)
    config = ocio.Config.CreateFromFile(str(ocio_dir / "config.ocio"))
    D65 = illuminant_white_XYZ("D65")
    lcms = load_lcms()
    rows, outputs = [], [("OCIO config (config.ocio)", ocio_dir / "config.ocio")]
    outputs += [(f"{name} matrix fit, exported instead ({fits[name].name})", fits[name]) for name in refused]
    commands.append(argv)
    for name, path in fits.items():
        fit = load_fit(path)
        codes = samples[name]
        expected = fit.apply_codes(codes)
        got = _ocio_apply(config.getProcessor(colour_space_name(name), _OCIO_XYZ_D65), codes)
        truth = adapt_XYZ(expected, fit.target_white_XYZ, D65, "Bradford")
        what = f"{name} OCIO space vs fit"
        if fit.model.kind == "matrix3x3":
            err = float(np.abs(got - truth).max())
            rows.append(DemoRow(stage, what + ", worst |XYZ|", 0.0, err, err, 1e-5, "Y=1", "issue 7"))
        else:
            err = float(delta_E(got, truth, D65).max())
            rows.append(DemoRow(stage, what + ", worst dE00", 0.0, err, err, 0.2, "dE00", "issue 7"))
        icc = ctx.path("icc", f"{name}.icc")
        icc_argv = ["colour", "export", str(path), "--icc", str(icc)]
        _run_cli(icc_argv, stage)
        commands.append(icc_argv)
        outputs.append((f"ICC v4 camera profile, {name} ({name}.icc)", icc))
        err = float("nan")
        if lcms is not None:
            D50 = adapt_XYZ(expected, fit.target_white_XYZ, D50_XYZ, "Bradford")
            keep = D50[:, 1] > 0.01  # CIEDE2000 of near-black says nothing
            err = float(delta_E(lcms_to_XYZ(lcms, icc.read_bytes(), codes)[keep], D50[keep], D50_XYZ).max())
        rows.append(DemoRow(stage, f"{name} ICC (LittleCMS) vs fit, worst dE00", 0.0, err, err, 0.5,
                            "dE00", "issue 7"))
    if match_path:
        match = load_match(match_path)
        look = look_name(match.source, match.target)
        data = config.getRoleColorSpace(ocio.ROLE_DATA)
        rgb = samples[match.source]
        got = _ocio_apply(config.getProcessor(ocio.LookTransform(src=data, dst=data, looks=look)), rgb)
        err = float(np.abs(got - match.apply(rgb)).max())
        rows.append(DemoRow(stage, "match Look vs match file, worst |RGB|", 0.0, err, err, 1e-5, "RGB",
                            "issue 7"))
    clfs = sorted(ocio_dir.rglob("*.clf"))
    outputs += [(f"baked transform ({p.name})", p) for p in clfs]
    spaces = [colour_space_name(name) for name in fits]
    refusals = "".join(
        f"<p>The {html.escape(name)} camera's <code>auto</code> fit ({html.escape(text)}) cannot be baked: "
        f"<code>camcal colour export</code> refuses it ({html.escape(reason)}), so the {html.escape(name)} camera "
        f"is exported with its 3x3 matrix fit (exact in OCIO and ICC).</p>"
        for name, (text, reason) in refused.items())
    body = (refusals + "".join(f"<pre>{html.escape(_command(a, ctx))}</pre>" for a in commands)
            + "<p>The config <a href=\"ocio/config.ocio\">ocio/config.ocio</a> (camcal's base: ACES2065-1 "
              "reference, the roles Blender needs) gains the input spaces "
            + ", ".join(f"<code>{html.escape(n)}</code>" for n in spaces)
            + (f" and the Look <code>{html.escape(look_name(match.source, match.target))}</code> (right camera "
               f"matched to the left, on linear camera values)" if match_path else "")
            + ". Point Blender at it with <code>OCIO=ocio/config.ocio blender</code>. Checked here with OCIO's "
              "own CPU processor against each fit on the chart and independent patches, and each ICC profile "
              "(class scnr, v4) through LittleCMS.</p><ul>"
            + "".join(f'<li><a href="{html.escape(os.path.relpath(p, ctx.out_dir))}">'
                      f"{html.escape(os.path.relpath(p, ctx.out_dir))}</a></li>"
                      for p in [ocio_dir / "config.ocio", *clfs, *(ctx.out_dir / "icc" / f"{n}.icc" for n in fits)])
            + "</ul>")
    return StageResult(tuple(rows), tuple(outputs),
                       (ReportSection("Colour exports: OCIO config and ICC profiles", body, COLOUR_EXPORTS_SECTION),))


# -- stage: blender import ------------------------------------------------------------------------


def _stage_blender_import(ctx: DemoContext) -> StageResult:
    from camcal.demo_blender import project_in_blend  # noqa: PLC0415

    stage = "blender import"
    rig_path = ctx.artifacts.get("rectified_rig") or ctx.need("board_rig", stage)
    blend = ctx.path("blender", "rig.blend")
    argv = ["blender", "import", str(rig_path), "--blend", str(blend)]
    _run_cli(argv, stage)
    outputs = [("Blender scene, board rig (rig.blend)", blend)]
    commands = [argv]
    if "solve_rig" in ctx.artifacts:
        sfm_blend = ctx.path("blender", "sfm.blend")
        sfm_argv = ["blender", "import", str(ctx.artifacts["solve_rig"]), "--blend", str(sfm_blend)]
        _run_cli(sfm_argv, stage)
        outputs.append(("Blender scene, SfM rig with its points (sfm.blend)", sfm_blend))
        commands.append(sfm_argv)
    rig = Rig.load(rig_path)
    rng = np.random.default_rng(ctx.config.seed)
    X = np.column_stack([rng.uniform(-0.4, 0.5, 60), rng.uniform(-0.3, 0.3, 60), rng.uniform(0.4, 2.0, 60)])
    projected = project_in_blend(blend, X, ctx.out_dir / "blender")
    rows = []
    for camera in rig.cameras:
        pinhole = dataclasses.replace(camera, distortion=Distortion.none())
        err = float(np.max(np.linalg.norm(np.asarray(projected[camera.name]) - pinhole.project(X), axis=1)))
        rows.append(DemoRow(stage, f"{camera.name}: Blender projection vs rig (worst)", 0.0, err, err, 1e-3, "px", "issue 9"))
    body = ("".join(f"<pre>{html.escape(_command(a, ctx))}</pre>" for a in commands)
            + "<p>The .blend files hold the rig's cameras (exact intrinsics as lens, shift and pixel aspect), "
              "the lens as a MovieClip with a Movie Distortion compositor, and for the SfM rig the keyframed "
              "rig and its sparse points. The check projects 60 points with Blender's own "
              "<code>calc_matrix_camera</code> in the saved file.</p>")
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Blender", body, "blender"),))


#: The demo's stages, in order. Artifacts stages leave for later ones (``ctx.artifacts``):
#: ``board_images``, ``room_dirs``, ``chart_images``, ``chart_truth``, ``chart_grid``,
#: ``match_images``, ``match_truth`` (render); ``board_rig`` (calibrate board); ``rectified_rig``
#: (rectify); ``solve_rig`` (solve); ``colour_fits``, ``chart_patches``, ``independent_patches``
#: (colour fit); ``colour_match`` (colour match).
STAGES: list[Stage] = [
    Stage("render", _stage_render),
    Stage("calibrate board", _stage_calibrate_board),
    Stage("distortion fit", _stage_distortion_fit),
    Stage("rectify", _stage_rectify),
    Stage("solve", _stage_solve),
    Stage("colour fit", _stage_colour_fit),
    Stage("colour match", _stage_colour_match),
    Stage("colour export", _stage_colour_export),
    Stage("blender import", _stage_blender_import),
]


# -- helpers: CLI, plots, HTML ---------------------------------------------------------------------


def _run_cli(argv: list[str], stage: str) -> None:
    """Run a camcal verb in this process, as a user would on the command line."""
    from camcal.cli import main  # noqa: PLC0415

    print(f"$ camcal {' '.join(argv)}", flush=True)
    code = main(argv)
    if code != 0:
        raise CamcalError(f"demo stage {stage!r}: camcal {argv[0]} exited with code {code}")


def _command(argv: Sequence[str], ctx: DemoContext) -> str:
    """The command line, with paths relative to the output folder."""
    root = str(ctx.out_dir.resolve())
    parts = []
    for arg in argv:
        text = str(arg).replace(root + os.sep, "").replace(str(ctx.out_dir) + os.sep, "")
        parts.append(f"'{text}'" if "*" in text else text)
    return "camcal " + " ".join(parts)


def _img(ctx: DemoContext, path: Path, width: int | None = None) -> str:
    rel = os.path.relpath(Path(path).resolve(), ctx.out_dir.resolve())
    size = f' width="{width}"' if width else ""
    return f'<a href="{html.escape(rel)}"><img src="{html.escape(rel)}" alt="{html.escape(Path(rel).stem)}"{size}></a>'


def _pyplot():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _save(fig, path: Path) -> Path:
    from camcal.io.atomic import atomic_path  # noqa: PLC0415

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    _pyplot().close(fig)
    return path


def _plot_images(path: Path, images: Sequence[str], titles: Sequence[str], columns: int) -> Path:
    import cv2  # noqa: PLC0415

    plt = _pyplot()
    rows = -(-len(images) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for ax, image, title in zip(axes.ravel(), images, titles):
        data = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
        data = data.astype(np.float64) / (65535.0 if data.dtype == np.uint16 else 255.0)
        if data.ndim == 3:
            data = data[..., ::-1]
        ax.imshow(np.clip(data, 0, 1) ** (1 / 2.2) if "linear" in title else data, cmap="gray")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    for ax in axes.ravel()[len(images):]:
        ax.axis("off")
    fig.tight_layout()
    return _save(fig, path)


def _plot_residuals(path: Path, cameras: Sequence[Camera], camera_of_point: NDArray, points_px: NDArray,
                    residuals_px: NDArray, what: str = "corner", max_arrows: int = 3000) -> Path:
    """Reprojection residuals (observed - projected): vectors over each camera's image (at most
    ``max_arrows``, a fixed random subset), and the spread of all of them."""
    plt = _pyplot()
    rng = np.random.default_rng(0)
    fig, axes = plt.subplots(2, len(cameras), figsize=(5.2 * len(cameras), 8.0), squeeze=False)
    for j, camera in enumerate(cameras):
        mine = camera_of_point == j
        points, residuals = points_px[mine], residuals_px[mine]
        width, height = camera.image_size
        ax = axes[0, j]
        gain = 0.03 * width / max(float(np.percentile(np.linalg.norm(residuals, axis=1), 99)), 1e-9)
        shown = np.sort(rng.choice(len(points), min(len(points), max_arrows), replace=False))
        ax.quiver(points[shown, 0], points[shown, 1], residuals[shown, 0], -residuals[shown, 1], color="tab:red",
                  angles="xy", scale_units="xy", scale=1 / gain, width=0.003)
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{camera.name}: residuals x{gain:.0f} (RMS {camera.quality['rms_px']:.3f} px)", fontsize=10)
        ax = axes[1, j]
        ax.scatter(residuals[:, 0], residuals[:, 1], s=3, alpha=0.5)
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_aspect("equal")
        ax.set_xlabel("dx (px)")
        ax.set_ylabel("dy (px)")
        ax.set_title(f"{camera.name}: {len(residuals)} {what} residuals", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _plot_epipolar(path: Path, left: Path, right: Path) -> Path:
    import cv2  # noqa: PLC0415

    plt = _pyplot()
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in (left, right)]
    height = max(image.shape[0] for image in images)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, image, title in zip(axes, images, ("left (rectified)", "right (rectified)")):
        ax.imshow(image, cmap="gray", vmin=0, vmax=255)
        for y in np.linspace(0.05 * height, 0.95 * height, 12):
            ax.axhline(y, color="tab:orange", lw=0.7)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    return _save(fig, path)


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;line-height:1.45;padding:0 1em}
h1{margin-bottom:0}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.88em;width:100%}th,td{padding:.25em .5em;border-bottom:1px solid #e4e4e4}
td.num{text-align:right;font-variant-numeric:tabular-nums}tr.pass td.ok{color:#137333;font-weight:600}
tr.fail{background:#fce8e6}tr.fail td.ok{color:#a50e0e;font-weight:700}
pre{background:#f6f8fa;padding:.6em;overflow-x:auto;font-size:.85em}img{max-width:100%;margin:.3em 0}
.verdict{font-size:1.2em;font-weight:600}.verdict.pass{color:#137333}.verdict.fail{color:#a50e0e}
.placeholder{color:#666;font-style:italic}
"""


def write_html(report: DemoReport, out_dir: str | os.PathLike) -> Path:
    """Write ``out_dir/report.html``: static, offline (inline CSS, images by relative path).

    Sections: verdict, the recovered-vs-true table, each stage's sections,
    the outputs (relative links), the colour exports section
    (:data:`COLOUR_EXPORTS_SECTION`) and the time per stage.
    """
    from camcal import __version__  # noqa: PLC0415
    from camcal.io.atomic import atomic_write_text  # noqa: PLC0415

    out_dir = Path(out_dir)
    n_fail = len(report.failed)
    verdict = (f'<p class="verdict pass" id="verdict">All {len(report.rows)} recovered values are within tolerance.</p>'
               if not n_fail else
               f'<p class="verdict fail" id="verdict">{n_fail} of {len(report.rows)} values are outside tolerance.</p>')
    rows = "".join(
        f'<tr class="{"pass" if row.ok else "fail"}"><td>{html.escape(row.stage)}</td><td>{html.escape(row.quantity)}</td>'
        f'<td class="num">{_num(row.true)}</td><td class="num">{_num(row.recovered)}</td><td class="num">{_num(row.error)}</td>'
        f'<td class="num">{_num(row.tolerance)}</td><td>{html.escape(row.unit)}</td>'
        f'<td class="ok">{"pass" if row.ok else "FAIL"}</td><td>{html.escape(row.source)}</td></tr>'
        for row in report.rows
    )
    table = ('<table id="truth-table"><thead><tr><th>stage</th><th>quantity</th><th>true</th><th>recovered</th>'
             '<th>error</th><th>tolerance</th><th>unit</th><th>ok</th><th>tolerance from</th></tr></thead>'
             f"<tbody>{rows}</tbody></table>")
    sections = "".join(
        f'<section id="{html.escape(s.anchor)}"><h2>{html.escape(s.title)}</h2>{s.body}</section>' for s in report.sections
    )
    links = []
    for label, path in report.outputs:
        rel = os.path.relpath(Path(path).resolve(), out_dir.resolve())
        links.append(f'<li><a href="{html.escape(rel)}">{html.escape(label)}</a> <code>{html.escape(rel)}</code></li>')
    exports = [s for s in report.sections if s.anchor == COLOUR_EXPORTS_SECTION]
    exports_html = "" if exports else (
        f'<section id="{COLOUR_EXPORTS_SECTION}"><h2>Colour exports: OCIO config and ICC profiles</h2>'
        '<p class="placeholder">Not produced by this run: the colour export stage (OCIO colour spaces, '
        'ICC camera profiles) adds its links here.</p></section>')
    timing = "".join(f"<tr><td>{html.escape(n)}</td><td class='num'>{s:.1f}</td></tr>" for n, s in report.seconds)
    stages = ", ".join(n for n, _ in report.seconds)
    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>camcal demo report</title>'
        f"<style>{_CSS}</style></head><body>"
        f"<h1>camcal demo</h1><p>camcal {__version__}: a stereo rig rendered with Blender, calibrated by camcal, "
        f"compared with the truth. Stages: {html.escape(stages)}.</p>"
        f'{verdict}<section id="truth"><h2>Recovered vs true</h2>{table}</section>{sections}{exports_html}'
        f'<section id="outputs"><h2>Outputs</h2><ul>{"".join(links)}</ul></section>'
        f'<section id="timing"><h2>Time per stage (s)</h2><table>{timing}</table></section>'
        "</body></html>\n"
    )
    path = out_dir / "report.html"
    atomic_write_text(path, page)
    return path


def run_demo(out_dir: str | os.PathLike, config: DemoConfig = FULL, stages: Sequence[Stage] | None = None) -> DemoReport:
    """Run the demo's stages into ``out_dir`` and write ``report.html``.

    Parameters
    ----------
    out_dir : path
        Output folder (created).
    config : DemoConfig
        Sizes and the stages to run (:data:`FULL` for ``make demo``).
    stages : sequence of Stage, optional
        The stage list (default :data:`STAGES`).

    Returns
    -------
    DemoReport
        Every row, output and section; ``report`` is the HTML file.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stages = list(stages if stages is not None else STAGES)
    unknown = sorted(set(config.stages or ()) - {stage.name for stage in stages})
    if unknown:
        raise CamcalError(f"unknown demo stage(s) {', '.join(unknown)}; expected: {', '.join(s.name for s in stages)}")
    ctx = DemoContext(out_dir, config, make_truth(config))
    rows, outputs, sections, seconds = [], [], [], []
    for stage in stages:
        if config.stages is not None and stage.name not in config.stages:
            continue
        print(f"camcal demo: {stage.name}", file=sys.stderr, flush=True)
        start = time.perf_counter()
        result = stage.run(ctx)
        seconds.append((stage.name, time.perf_counter() - start))
        rows += result.rows
        outputs += result.outputs
        sections += result.sections
    report = DemoReport(tuple(rows), tuple(outputs), tuple(sections), tuple(seconds))
    path = write_html(report, out_dir)
    return dataclasses.replace(report, report=path)
