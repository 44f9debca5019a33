"""The known rig and scene of the demo, and the true colours its sensors see."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.demo.core import DemoConfig, DemoTruth, FULL
from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Frame, Rig, make_provenance

__all__ = [
    "board_corners",
    "board_outline",
    "chart_albedos",
    "make_chart_quads",
    "make_match_quads",
    "make_truth",
    "reference_XYZ",
    "room_quads",
    "true_match_matrix",
]


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
    outline = board_outline(board)
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


def board_outline(board) -> NDArray[np.float64]:
    """The printed board's corners (the squares plus one white square of margin)."""
    s = board.square
    x0, y0, x1, y1 = -2 * s, -2 * s, (board.columns + 1) * s, (board.rows + 1) * s
    return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def _inside(pixels: NDArray, size: tuple[int, int], margin: float) -> bool:
    width, height = size
    return bool(np.all(np.isfinite(pixels)) and np.all(pixels >= margin)
                and np.all(pixels[:, 0] <= width - 1 - margin) and np.all(pixels[:, 1] <= height - 1 - margin))


def board_corners(board, R, t) -> NDArray[np.float64]:
    """Inner corners of a chessboard view in rig coordinates, in board id order."""
    ids = np.arange(board.columns * board.rows)
    X = np.column_stack([(ids % board.columns) * board.square, (ids // board.columns) * board.square, np.zeros(len(ids))])
    return X @ R.T + t


def reference_XYZ(reflectances: str, illuminant: str) -> NDArray[np.float64]:
    """True XYZ (perfect white Y = 1) of a colour-science reflectance set under a CIE illuminant.

    Integrated exactly as ``camcal.colour.chart.reference.reference_chart`` integrates
    the spectral charts (CIE 1931 2 degree observer, 380 to 780 nm every 5 nm),
    so that training and independent references agree whatever a camera's
    own spectral range (the Sigma's data stop at 400-680 nm).

    Notes
    -----
    ``XYZ = k sum_l R(l) S(l) xyz(l)`` with ``k = 1 / sum_l S(l) y(l)``.
    """
    from camcal.colour.spectral.data import reflectance_set, reflectance_XYZ  # noqa: PLC0415

    shape = (380.0, 780.0, 5.0)
    _, R = reflectance_set(reflectances, np.arange(shape[0], shape[1] + shape[2], shape[2]))
    return reflectance_XYZ(R, illuminant, shape)[0]


def chart_albedos(truth: DemoTruth) -> dict[str, tuple[NDArray, NDArray, NDArray]]:
    """Per camera: the chart's albedos, and the independent set's camera RGB (same scale) and true XYZ.

    The albedo of a patch is the camera's linear RGB for it under the light,
    ``SimulatedCamera.RGB`` (white G = 1), times ``0.8 / max(RGB_white)`` so
    that the perfect white would render at 0.8 at most.
    """
    from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: PLC0415
    from camcal.colour.spectral.data import reflectance_set  # noqa: PLC0415

    test_XYZ = reference_XYZ("rawtoaces 190", truth.illuminant)
    out = {}
    for name, sensor in truth.sensors.items():
        sim = SimulatedCamera.from_colour(sensor, truth.illuminant)
        _, chart = reflectance_set("ISO 17321-1", sim.wavelengths)
        _, test = reflectance_set("rawtoaces 190", sim.wavelengths)
        scale = 0.8 / float(np.max(sim.RGB_white))
        out[name] = (sim.RGB(chart) * scale, sim.RGB(test) * scale, test_XYZ)
    return out


def make_chart_quads(truth: DemoTruth, albedos: dict) -> tuple[list[dict], dict[str, list[str]], NDArray]:
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


def room_quads(truth: DemoTruth, textures_dir: Path, rng: np.random.Generator) -> list[dict]:
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
    sensors relate exactly by it (see :func:`make_match_quads`).
    """
    left, right = albedos["left"][1], albedos["right"][1]
    N, *_ = np.linalg.lstsq(right, left, rcond=None)
    return N.T


def make_match_quads(truth: DemoTruth, albedos: dict, N: NDArray, textures_dir: Path,
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
