"""mrcal as a peer of bench/bench_lens_models.py: run with the system python3 (Debian's python3-mrcal).

Reads one JSON object on stdin: ``columns``, ``rows`` (inner corners), ``image_size`` [W, H], ``focal`` (the
seed focal length in pixels, as a user gives ``--focal``), ``lensmodel`` (e.g. ``LENSMODEL_OPENCV8``),
``train`` and ``held`` (image name -> corners, row-major, ``columns`` per row, square = 1). Runs
``mrcal-calibrate-cameras`` on the training corners (its own seeding, staged solves, outlier rejection and
regularisation; flat board: ``--skip-calobject-warp-solve``, unless ``warp`` is true: then mrcal solves its
two-parameter parabolic ``calobject_warp`` with the lens), then poses every view with the fitted intrinsics held
(``mrcal.optimize`` over that view's board pose alone, against mrcal's own board: flat, or warped by the solved
``calobject_warp``) and writes one JSON object on stdout: ``train_rms_px``, ``heldout_rms_px``, ``intrinsics``,
``calobject_warp``.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import mrcal
import numpy as np


def posed_rms(lensmodel: str, intrinsics: np.ndarray, size, columns: int, rows: int, views: dict,
              warp: np.ndarray | None = None) -> float:
    """RMS over ``views`` of each view posed by mrcal with the intrinsics held (every corner, no outlier rejection)."""
    obs = np.array([np.concatenate([np.asarray(c, float).reshape(rows, columns, 2), np.ones((rows, columns, 1))], axis=-1)
                    for c in views.values()])
    n = len(obs)
    indices = np.column_stack([np.arange(n), np.zeros(n, int)]).astype(np.int32)
    Rt = mrcal.estimate_monocular_calobject_poses_Rt_tocam(indices, obs, 1.0, ((lensmodel, intrinsics),))
    frames = mrcal.rt_from_Rt(Rt)
    indices3 = np.column_stack([np.arange(n), np.zeros(n, int), -np.ones(n, int)]).astype(np.int32)
    mrcal.optimize(intrinsics[None].copy(), np.zeros((0, 6)), frames, None, obs, indices3, None, None, lensmodel,
                   calobject_warp=warp,
                   imagersizes=np.array([size], np.int32), do_optimize_intrinsics_core=False,
                   do_optimize_intrinsics_distortions=False, do_optimize_extrinsics=False, do_optimize_frames=True,
                   do_optimize_calobject_warp=False, calibration_object_spacing=1.0, do_apply_outlier_rejection=False,
                   do_apply_regularization=False)
    board = mrcal.ref_calibration_object(columns, rows, 1.0, calobject_warp=warp)
    q = mrcal.project(mrcal.transform_point_rt(frames[:, None, None, :], board), lensmodel, intrinsics)
    r = q - obs[..., :2]
    return float(np.sqrt(np.mean(np.sum(r * r, axis=-1))))


def main() -> None:
    spec = json.load(sys.stdin)
    columns, rows, size = spec["columns"], spec["rows"], spec["image_size"]
    with tempfile.TemporaryDirectory() as tmp:
        with open(Path(tmp) / "corners.vnl", "w") as out:
            out.write("# filename x y level\n")
            for name, corners in spec["train"].items():
                for x, y in corners:
                    out.write(f"{name} {x!r} {y!r} 0\n")
        run = subprocess.run(
            ["mrcal-calibrate-cameras", "--corners-cache", str(Path(tmp) / "corners.vnl"), "--lensmodel",
             spec["lensmodel"], "--focal", str(spec["focal"]), "--imagersize", str(size[0]), str(size[1]),
             "--object-spacing", "1", "--object-width-n", str(columns), "--object-height-n", str(rows),
             *([] if spec.get("warp") else ["--skip-calobject-warp-solve"]), "--outdir", tmp, "*"],
            capture_output=True, text=True)
        if run.returncode:
            raise SystemExit(f"mrcal-calibrate-cameras failed: {run.stderr.strip().splitlines()[-1:]}")
        model = mrcal.cameramodel(str(Path(tmp) / "camera-0.cameramodel"))
    lensmodel, intrinsics = model.intrinsics()
    warp = model.optimization_inputs().get("calobject_warp") if spec.get("warp") else None
    warp = None if warp is None else np.asarray(warp, dtype=float)
    json.dump({"train_rms_px": posed_rms(lensmodel, intrinsics, size, columns, rows, spec["train"], warp),
               "heldout_rms_px": posed_rms(lensmodel, intrinsics, size, columns, rows, spec["held"], warp),
               "intrinsics": intrinsics.tolist(), "calobject_warp": None if warp is None else warp.tolist()}, sys.stdout)


if __name__ == "__main__":
    main()
