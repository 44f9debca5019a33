"""A 2x anamorphic lens (fx = 2 fy) rendered as chessboard images, calibrated by ``camcal calibrate board``.

Issue 27's must-show: fx / fy recovered within 0.05 % with the division and opencv models. The images are
rendered through the true lens (each pixel's ray met with the board's plane, 3 x 3 samples per pixel, a
little blur and noise); the corners are camcal's own detections.
"""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.cli import main
from camcal.geometry.board import Board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

BOARD = Board("chessboard", 9, 6, 0.04)
SIZE = (1280, 720)
K = np.array([[1400.0, 0.0, 641.3], [0.0, 700.0, 357.8], [0.0, 0.0, 1.0]])  # fx = 2 fy
LENSES = {
    # the division lens round in normalised coordinates: its radius in x pixels, aspect = fx / fy
    "division": Distortion("division", {"lambda": -1.5e-7, "aspect": 2.0}),
    "opencv": Distortion("opencv", {"k1": -0.1, "k2": 0.02, "p1": 3e-4, "p2": -2e-4, "k3": 0.0}),
}


def pixel_rays(camera: Camera, samples: int = 3) -> list[np.ndarray]:
    """The rays of ``samples x samples`` points in every pixel (the same for every pose)."""
    width, height = camera.image_size
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return [camera.distortion.rays_from_pixels(np.column_stack([(u + dx).ravel(), (v + dy).ravel()]), camera.K)
            for dy in offsets for dx in offsets]


def render(camera: Camera, rays: list[np.ndarray], R: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """8-bit image of the board at ``cam_from_board = (R, t)``: white margin of one square, box-filtered samples."""
    width, height = camera.image_size
    value = np.zeros(width * height)
    origin = -R.T @ t
    s = BOARD.square
    for sample in rays:
        board_rays = sample @ R  # in the board's frame
        depth = -origin[2] / board_rays[:, 2]
        X = origin[0] + depth * board_rays[:, 0]
        Y = origin[1] + depth * board_rays[:, 1]
        inside = (X > -s) & (X < BOARD.columns * s) & (Y > -s) & (Y < BOARD.rows * s) & (depth > 0)
        dark = ((np.floor(X / s) + np.floor(Y / s)) % 2 == 0) & inside
        value += np.where(dark, 0.1, 0.9)
    value = value.reshape(height, width) / len(rays)
    value = cv2.GaussianBlur(value, (0, 0), 0.6) + rng.normal(0.0, 0.01, value.shape)
    return np.clip(np.round(value * 255.0), 0, 255).astype(np.uint8)


def board_poses(camera: Camera, n_views: int, rng: np.random.Generator):
    """Tilted board poses whose corners (and a square of margin) lie well inside the frame."""
    centre = np.array([(BOARD.columns - 1) / 2, (BOARD.rows - 1) / 2, 0.0]) * BOARD.square
    s = BOARD.square
    outline = np.array([[-s, -s, 0], [BOARD.columns * s, -s, 0], [-s, BOARD.rows * s, 0],
                        [BOARD.columns * s, BOARD.rows * s, 0]]) - centre
    poses = []
    while len(poses) < n_views:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.5], degrees=True).as_matrix()
        position = rng.uniform([-0.12, -0.12, 0.55], [0.12, 0.12, 0.8])
        pixels = camera.distortion.distort(
            ((outline @ R.T + position) @ camera.K.T)[:, :2] / (outline @ R.T + position)[:, 2:], camera.K)
        if np.all((pixels > 10) & (pixels < np.array(camera.image_size) - 10)):
            poses.append((R, position - R @ centre))
    return poses


# opencv is slow (about two minutes): division stays in `make test`, the same render, detection and fit of fx = 2 fy,
# plus the division lens' own aspect
@pytest.mark.parametrize("model", ["division", pytest.param("opencv", marks=pytest.mark.slow)])
def test_anamorphic_squeeze_recovered_through_calibrate_board(model, tmp_path, capsys):
    truth = Camera("ana", SIZE, K, LENSES[model], np.eye(3), np.zeros(3))
    rng = np.random.default_rng(27)
    rays = pixel_rays(truth)
    for n, (R, t) in enumerate(board_poses(truth, 14, rng)):
        cv2.imwrite(str(tmp_path / f"ana_{n:03d}.png"), render(truth, rays, R, t, rng))
    out = tmp_path / "ana.rig.json"
    code = main(["calibrate", "board", "--board", BOARD.spec(), "--images", f"ana={tmp_path / 'ana_*.png'}",
                 "--model", model, "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed
    camera = Rig.load(out).cameras[0]
    ratio = camera.K[0, 0] / camera.K[1, 1]
    print(f"{model}: fx {camera.K[0, 0]:.3f} fy {camera.K[1, 1]:.3f} fx/fy {ratio:.6f} "
          f"(truth 2, error {100 * (ratio / 2.0 - 1.0):+.4f} %), RMS {camera.quality['rms_px']:.4f} px")
    assert abs(ratio / 2.0 - 1.0) < 5e-4
    if model == "division":
        assert camera.distortion.params["aspect"] == pytest.approx(ratio, rel=1e-12)
