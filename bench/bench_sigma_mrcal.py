"""Projection uncertainty beside mrcal's on the same rendered corners: coverage of the true error.

Over seeded scenes rendered as images (``tests/geometry/test_uncertainty.py``'s
``rendered_scene``: a division lens, 12 board views detected by camcal), the
same corners go to camcal's board calibration (division model) and to
mrcal 2.2's ``mrcal-calibrate-cameras`` (LENSMODEL_OPENCV4, no board warp,
no outlier rejection), run by the system python3 in a subprocess
(``bench/mrcal_sigma_driver.py``; Debian's ``python3-mrcal``). For each, the
true projection error of rays at infinity at 9 x 7 pixels in mrcal 2.2's
board gauge (the chordal mean of ``R_true_i R_est_i^T`` over the board
poses: camcal's views posed with its intrinsics held, mrcal's its own
``frames_rt_toref``) against each tool's worst-direction sigma. Prints per
scene and pooled: share within 2 sigma (the must-show asks >= 90 %) and the
median error / sigma, and the ratio of camcal's coverage to mrcal's.

The scenes' lens is a division lens, which camcal fits and no mrcal model
is: mrcal's model error at the frame's edges counts against its coverage
(``--lensmodel LENSMODEL_OPENCV8`` gives it a richer model). ``--seeds N``
(default 20). Skips with the reason when mrcal is not installed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.geometry.uncertainty import projection_sigma  # noqa: E402
from camcal.geometry.zhang import calibrate_board  # noqa: E402
from camcal.model.camera import chordal_mean_rotation  # noqa: E402
from tests.geometry.test_uncertainty import BOARD, board_gauge_error, rendered_scene  # noqa: E402

DRIVER = Path(__file__).resolve().parent / "mrcal_sigma_driver.py"
SYSTEM_PYTHON = "/usr/bin/python3"


def mrcal_available() -> str:
    """'' when the system python3 imports mrcal, else the reason."""
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import mrcal"], capture_output=True, text=True)
    return "" if probe.returncode == 0 else "mrcal not installed (apt-get install mrcal python3-mrcal)"


def mrcal_solution(truth, detections, pixels, lensmodel="LENSMODEL_OPENCV4") -> dict:
    """mrcal's calibration of the detections' corners and its projection sigma at ``pixels``."""
    spec = {"size": list(truth.image_size), "spacing": BOARD.square, "width_n": BOARD.columns,
            "height_n": BOARD.rows, "lensmodel": lensmodel, "focal": float(truth.K[0, 0]),
            "views": [d.corners_px[np.argsort(d.ids)].tolist() for d in detections], "pixels": pixels.tolist()}
    run = subprocess.run([SYSTEM_PYTHON, str(DRIVER)], input=json.dumps(spec), capture_output=True, text=True,
                         check=True)
    return json.loads(run.stdout)


def scene_figures(seed: int, n_views: int = 12, lensmodel: str = "LENSMODEL_OPENCV4") -> dict:
    """error / sigma at 63 pixels for camcal and mrcal on one rendered scene, and both RMS."""
    truth, detections, poses = rendered_scene(seed, n_views)
    gx, gy = np.meshgrid(np.linspace(0, truth.image_size[0] - 1, 9), np.linspace(0, truth.image_size[1] - 1, 7))
    pixels = np.column_stack([gx.ravel(), gy.ravel()])
    result = calibrate_board(BOARD, {"cam": detections}, model="division")
    camera = result.rig.cameras[0]
    ours = board_gauge_error(camera, truth, detections, poses, pixels) / projection_sigma(camera, pixels)
    peer = mrcal_solution(truth, detections, pixels, lensmodel)
    R_gauge = chordal_mean_rotation(np.array([R_true @ np.array(R_est).T for (R_true, _), R_est
                                              in zip(poses, peer["R_camera_board"])]))
    rays = np.array(peer["rays"]) @ R_gauge.T
    error = np.linalg.norm(truth.distortion.project_rays(rays, truth.K) - pixels, axis=1)
    return {"camcal": ours, "mrcal": error / np.array(peer["sigma_px"]), "camcal_rms_px": result.rms_px,
            "mrcal_rms_px": peer["rms_px"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--lensmodel", default="LENSMODEL_OPENCV4",
                        help="mrcal's lens model (the scenes' lens is a division lens, which no mrcal model is: "
                             "OPENCV4's model error at the edges counts against mrcal's coverage)")
    args = parser.parse_args()
    reason = mrcal_available()
    if reason:
        print(f"skipped: {reason}")
        return
    pooled = {"camcal": [], "mrcal": []}
    for seed in range(args.seeds):
        figures = scene_figures(seed, lensmodel=args.lensmodel)
        for tool in pooled:
            pooled[tool].append(figures[tool])
        print(f"seed {seed}: RMS camcal {figures['camcal_rms_px']:.3f} px, mrcal {figures['mrcal_rms_px']:.3f} px; "
              + "; ".join(f"{tool} within 2 sigma {100 * np.mean(figures[tool] < 2):.0f} %, median error/sigma "
                          f"{np.median(figures[tool]):.2f}" for tool in pooled), flush=True)
    inside = {tool: float(np.mean(np.concatenate(v) < 2.0)) for tool, v in pooled.items()}
    for tool, values in pooled.items():
        ratios = np.concatenate(values)
        print(f"{tool}: {100 * inside[tool]:.1f} % of {len(ratios)} pixels within 2 sigma, median error/sigma "
              f"{np.median(ratios):.2f}")
    print(f"coverage within 2 sigma: ours {100 * inside['camcal']:.1f} %, peer (mrcal 2.2) {100 * inside['mrcal']:.1f} %, "
          f"ratio {inside['camcal'] / max(inside['mrcal'], 1e-9):.3f}")


if __name__ == "__main__":
    main()
