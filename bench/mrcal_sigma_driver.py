"""Run by the system python3 with mrcal 2.2 (Debian python3-mrcal): mrcal's calibration and projection
uncertainty on corners given by camcal's bench (bench_sigma_mrcal.py), in a subprocess.

stdin: JSON {"size": [W, H], "spacing": s, "width_n": 9, "height_n": 6, "lensmodel": "LENSMODEL_OPENCV4",
"focal": f, "views": [[[x, y], ...] per view, row-major corners], "pixels": [[x, y], ...]}
stdout: JSON {"rms_px", "sigma_px": per pixel (worst direction, rays at infinity), "rays": mrcal's
unprojected rays of the pixels, "R_camera_board": per view 3x3}.
"""

import json
import os
import subprocess
import sys
import tempfile

import mrcal
import numpy as np


def main():
    spec = json.load(sys.stdin)
    with tempfile.TemporaryDirectory() as folder:
        names = [f"view{k:03d}.png" for k in range(len(spec["views"]))]
        with open(os.path.join(folder, "corners.vnl"), "w") as handle:
            handle.write("# filename x y level\n")
            for name, corners in zip(names, spec["views"]):
                for x, y in corners:
                    handle.write(f"{name} {x:.6f} {y:.6f} 0\n")
        command = ["mrcal-calibrate-cameras", "--corners-cache", os.path.join(folder, "corners.vnl"),
                   "--lensmodel", spec["lensmodel"], "--focal", str(spec["focal"]),
                   "--imagersize", str(spec["size"][0]), str(spec["size"][1]),
                   "--object-spacing", str(spec["spacing"]), "--object-width-n", str(spec["width_n"]),
                   "--object-height-n", str(spec["height_n"]), "--outdir", folder,
                   "--skip-calobject-warp-solve", "--skip-outlier-rejection", "view*.png"]
        subprocess.run(command, cwd=folder, check=True, capture_output=True, text=True)
        model = mrcal.cameramodel(os.path.join(folder, "camera-0.cameramodel"))
    pixels = np.array(spec["pixels"], dtype=float)
    rays = mrcal.unproject(pixels, *model.intrinsics(), normalize=True)
    sigma = mrcal.projection_uncertainty(rays, model=model, atinfinity=True, what="worstdirection-stdev")
    inputs = model.optimization_inputs()
    frames = inputs["frames_rt_toref"]  # board -> reference (= camera 0) transforms
    R = mrcal.R_from_r(frames[:, :3])
    residuals = mrcal.optimizer_callback(**inputs)[1][:mrcal.num_measurements_boards(**inputs)]
    json.dump({"rms_px": float(np.sqrt(np.mean(residuals.reshape(-1, 2) ** 2) * 2)),
               "sigma_px": sigma.tolist(), "rays": rays.tolist(), "R_camera_board": R.tolist()}, sys.stdout)


if __name__ == "__main__":
    main()
