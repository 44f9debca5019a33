"""A 2x anamorphic lens of the 3DE4 Anamorphic Standard Degree 4 model, rendered as chessboard images, end to end.

The images are rendered in numpy through camcal's exact mapping of the true lens (each pixel's ray, from
:meth:`~camcal.model.distortion.Distortion.rays_from_pixels`, met with the board's plane; the renderer and board
poses of ``test_zhang_anamorphic``, seeded blur and noise) in the fast test, and by Blender in a slow one: Cycles
renders each view as an undistorted pinhole on an overscan canvas whose non-square pixels Blender's own
``pixel_aspect_x`` / ``pixel_aspect_y`` carry (no resampling for the squeeze), then camcal's exact redistort map
applies the lens (:func:`camcal.demo.render.render_board_views`, the demo's renderer, with its band-limited
resampling: one cubic remap of the sharp render shifts corners with the map's sub-pixel phase). The lens has every
degree-2 and degree-4 coefficient, a lens rotation and squeezes x / y away from 1; its pixel aspect (fy / fx of the
pinhole the squeezes leave, ``fy sx / (fx sy)``: the squeezes scale the undistorted image along x and y) is 2.
camcal detects the corners and calibrates with ``model="3de4-anamorphic-deg4"``; the squeeze must come back within
0.05 %, the held-out views' error at the floor the data allows (the same fit fed the true corners plus Gaussian
noise of the detections' own spread), and the fitted parameters at the truth within their own covariance (the truth
expressed with the squeezes held at 1, as the fit holds them: a chi-square of the 15 parameters under its 99.9 %
point, the lens rotation within 3.3 sigma). The calibrated rig then goes to Nuke (LDPK node, LensDistortion node)
and to a 3DE lens file, and each read back distorts and undistorts a grid of pixels as the exported lens does, to
1e-9 px.
"""

import importlib.util
import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.optimize
import scipy.stats

import camcal
from camcal.demo.render import render_board_views
from camcal.geometry.board import Detection
from camcal.geometry.tde4_fit import FITTED_PARAMS
from camcal.geometry.zhang import calibrate_board as fit_board
from camcal.model.distortion import Distortion, frame_grid
from camcal.model.rig import Camera
from camcal.model.tde4 import FILMBACK_KEYS

from test_zhang_anamorphic import BOARD, board_poses, pixel_rays, render

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from test_nuke_lens import strip_camcal_lens  # noqa: E402

MODEL = "3de4-anamorphic-deg4"
SQUEEZE = 2.0
SQUEEZE_X, SQUEEZE_Y = 1.004, 0.998
COEFFICIENTS = {"cx02": -0.05, "cy02": -0.03, "cx22": 0.01, "cy22": 0.015, "cx04": 0.008, "cy04": 0.004,
                "cx24": 0.002, "cy24": -0.002, "cx44": -0.001, "cy44": 0.0008, "lens_rotation_deg": 0.5,
                "squeeze_x": SQUEEZE_X, "squeeze_y": SQUEEZE_Y}
#: The Blender test's plates, views (4 of them held out), Cycles samples a pixel and the render's band limit
#: (:func:`camcal.demo.render.write_plate`: a Gaussian of 1 canvas pixel, then a cubic B-spline through the map).
BLENDER_SIZE = (960, 540)
BLENDER_VIEWS = 16
BLENDER_SAMPLES = 8
BLENDER_BAND_LIMIT_PX = 1.0


def anamorphic_camera(size: tuple[int, int]) -> Camera:
    """The true lens on a ``size`` image: fx 0.4375 W, and fy such that the squeezed pinhole's aspect is 2."""
    width, height = size
    fx = 0.4375 * width
    K = np.array([[fx, 0.0, 0.5 * width + 3.1], [0.0, SQUEEZE * fx * SQUEEZE_Y / SQUEEZE_X, 0.5 * height - 3.6],
                  [0.0, 0.0, 1.0]])
    lens = Distortion(MODEL, {"filmback_width_px": float(width), "filmback_height_px": float(height), **COEFFICIENTS})
    return Camera("ana", size, K, lens, np.eye(3), np.zeros(3))


def rendered_views(truth: Camera, n_views: int, samples: int, folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """Write ``ana_NNN.png`` board images through the true lens; return their poses (cam_from_board)."""
    rng = np.random.default_rng(42)
    rays = pixel_rays(truth, samples)
    poses = board_poses(truth, n_views, rng)
    for n, (R, t) in enumerate(poses):
        cv2.imwrite(str(folder / f"ana_{n:03d}.png"), render(truth, rays, R, t, rng))
    return poses


def true_corners(truth: Camera, pose: tuple[np.ndarray, np.ndarray], ids: np.ndarray) -> np.ndarray:
    R, t = pose
    return truth.project(BOARD.object_points[ids] @ R.T + t)


def floor_views(truth: Camera, views, poses, sigma_px: float) -> list[Detection]:
    """The views' corners where the true lens puts them, plus seeded noise of ``sigma_px`` per axis."""
    rng = np.random.default_rng(7)
    noisy = []
    for view in views:
        exact = true_corners(truth, poses[int(re.search(r"(\d+)", view.image).group(1))], view.ids)
        noisy.append(Detection(view.image, view.image_size, view.ids, exact + rng.normal(0.0, sigma_px, exact.shape),
                               view.detector))
    return noisy


def lens_difference_px(exported: Camera, read: Camera) -> float:
    """Largest pixel difference of distorting and of undistorting a 4 px grid over the frame (and a 1.25 border)."""
    width, height = exported.image_size
    grid = frame_grid(exported.image_size, 4.0) * 1.25 - 0.125 * np.array([width - 1, height - 1])
    worst = 0.0
    for method in ("distort", "undistort"):
        ours = getattr(exported.distortion, method)(grid, exported.K)
        theirs = getattr(read.distortion, method)(grid, read.K)
        assert np.array_equal(np.isfinite(ours), np.isfinite(theirs))
        assert np.isfinite(ours).mean() > 0.9
        worst = max(worst, float(np.nanmax(np.abs(ours - theirs))))
    return worst


def fit_gauge_truth(truth: Camera) -> dict[str, float]:
    """The truth as the fit parameterises it: ``fx, fy, cx, cy`` and :data:`FITTED_PARAMS`, the squeezes held at 1
    (they only rescale the undistorted image, :mod:`camcal.geometry.tde4_fit`), fitted to the truth's projection
    of the rays of a 24 px grid; the same lens to 1e-6 px (asserted)."""
    grid = frame_grid(truth.image_size, 24.0)
    rays = truth.distortion.rays_from_pixels(grid, truth.K)
    filmback = {key: truth.distortion.params[key] for key in FILMBACK_KEYS}
    names = FITTED_PARAMS[MODEL]

    def camera(vector: np.ndarray) -> tuple[np.ndarray, Distortion]:
        K = np.array([[vector[0], 0.0, vector[2]], [0.0, vector[1], vector[3]], [0.0, 0.0, 1.0]])
        return K, Distortion(MODEL, {**filmback, **dict(zip(names, vector[4:]))})

    def residuals(vector: np.ndarray) -> np.ndarray:
        K, lens = camera(vector)
        return np.nan_to_num(lens.project_rays(rays, K) - grid, nan=1e3).ravel()

    start = np.array([truth.K[0, 0] / SQUEEZE_X, truth.K[1, 1] / SQUEEZE_Y, truth.K[0, 2], truth.K[1, 2],
                      *(COEFFICIENTS[name] for name in names)])
    solution = scipy.optimize.least_squares(residuals, start, x_scale="jac", method="lm", xtol=1e-15, ftol=1e-15)
    assert np.abs(solution.fun).max() < 1e-6
    K, lens = camera(solution.x)
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], **lens.params}


def chi_square(fit, expected: dict[str, float]) -> tuple[float, dict[str, float]]:
    """``r^T C^-1 r`` of the fit's camera parameters against ``expected`` with the fit's own covariance (a
    chi-square of as many degrees of freedom as parameters when the covariance is right), and each one's z."""
    [camera] = fit.rig.cameras
    estimate = {"fx": camera.K[0, 0], "fy": camera.K[1, 1], "cx": camera.K[0, 2], "cy": camera.K[1, 2],
                **camera.distortion.params}
    names = [name.split(".", 1)[1] for name in fit.parameter_names]
    r = np.array([estimate[name] - expected[name] for name in names])
    z = {name: float(value / np.sqrt(fit.covariance[k, k])) for k, (name, value) in enumerate(zip(names, r))}
    return float(r @ np.linalg.solve(fit.covariance, r)), z


def calibrate_export_read_back(truth: Camera, poses: list[tuple[np.ndarray, np.ndarray]], pattern: str,
                               holdout: list[int], tmp_path: Path) -> None:
    """Calibrate the images of ``pattern`` (``*NN.png``: the view of ``poses[NN]``) with :data:`MODEL`, check the
    figures of the module docstring against the truth and the floor, export to Nuke and 3DE, read each back."""
    size = truth.image_size
    result = camcal.calibrate_board({"ana": pattern}, BOARD, model=MODEL, holdout=holdout, cache=False,
                                    progress=False)
    camera = result.rig.cameras[0]
    assert result.calibration.model == MODEL and camera.distortion.model == MODEL
    views = result.views["ana"]
    assert len(views) == len(poses)
    detected = np.concatenate([view.corners_px for view in views])
    exact = np.concatenate([true_corners(truth, poses[int(re.search(r"(\d+)", v.image).group(1))], v.ids)
                            for v in views])
    sigma_px = float(np.sqrt(np.mean((detected - exact) ** 2)))  # the detections' spread per axis
    floor = fit_board(BOARD, {"ana": floor_views(truth, views, poses, sigma_px)}, model=MODEL, holdout=set(holdout))
    squeeze = camera.K[1, 1] / camera.K[0, 0]
    floor_squeeze = floor.rig.cameras[0].K[1, 1] / floor.rig.cameras[0].K[0, 0]
    expected = fit_gauge_truth(truth)
    chi2, z = chi_square(result.calibration, expected)
    floor_chi2, _ = chi_square(floor, expected)
    bound = float(scipy.stats.chi2.ppf(0.999, len(z)))
    squeeze_error, floor_squeeze_error = squeeze / SQUEEZE - 1.0, floor_squeeze / SQUEEZE - 1.0
    print(f"{size[0]}x{size[1]}, {len(poses)} views ({len(holdout)} held out): detections {sigma_px:.4f} px per "
          f"axis; squeeze {squeeze:.6f} (error {100 * squeeze_error:+.4f} %), lens rotation "
          f"{camera.distortion.params['lens_rotation_deg']:.4f} deg (truth {COEFFICIENTS['lens_rotation_deg']}); "
          f"training {result.rms_px:.4f} px, held out {result.heldout_rms_px:.4f} px; the floor (true corners + "
          f"the same noise): squeeze error {100 * floor_squeeze_error:+.4f} %, training "
          f"{floor.rms_px:.4f} px, held out {floor.heldout_rms_px:.4f} px")
    print(f"against the truth, with the printed sigma: chi-square {chi2:.1f} of {len(z)} parameters (floor "
          f"{floor_chi2:.1f}; 99.9 % bound {bound:.1f}); z " + ", ".join(f"{name} {v:+.2f}" for name, v in z.items()))
    assert abs(squeeze_error) < 5e-4
    assert camera.distortion.params["lens_rotation_deg"] == pytest.approx(COEFFICIENTS["lens_rotation_deg"], abs=0.02)
    assert result.heldout_rms_px < 1.3 * floor.heldout_rms_px
    assert chi2 < bound and abs(z["lens_rotation_deg"]) < 3.3
    # export to Nuke (its LDPK node, its LensDistortion node) and 3DE, read each back
    nuke, tde = tmp_path / "shot.nk", tmp_path / "lens.txt"
    for path, to in ((nuke, "nuke"), (tde, "3de")):
        [conversion] = camcal.export_rig(result.rig, path, to).conversions
        assert conversion.refit.exact and conversion.refit.max_px < 1e-6, conversion
    plain = strip_camcal_lens(nuke.read_text())
    (tmp_path / "ldpk.nk").write_text(plain)
    (tmp_path / "lens_distortion.nk").write_text(re.sub(r"^LD_3DE\w+ \{\n.*?^\}\n", "", plain, flags=re.M | re.S))
    # the LDPK node alone (no Camera3): its K from its own tde4_* knobs, pixel aspect included
    (tmp_path / "ldpk_alone.nk").write_text(re.sub(r"^(Camera3|LensDistortion2) \{\n.*?^\}\n", "", plain,
                                                   flags=re.M | re.S))
    read_back = {}
    sources = {"shot.nk": "Nuke Camera3", "ldpk.nk": "Nuke LD_3DE", "lens_distortion.nk": "Nuke LensDistortion",
               "ldpk_alone.nk": "Nuke LD_3DE", "lens.txt": "3DE"}
    for name, source in sources.items():
        back = camcal.import_rig(tmp_path / name)
        [read] = back.rig.cameras
        assert back.conversions[0].source.startswith(source), back.conversions[0]
        assert read.distortion.model == MODEL and read.image_size == size
        read_back[name] = lens_difference_px(camera, read)
    print("read back, max over a grid (distort and undistort): "
          + ", ".join(f"{name} {worst:.2e} px" for name, worst in read_back.items()))
    assert max(read_back.values()) < 1e-9


def test_rendered_anamorphic_lens_calibrated_exported_and_read_back(tmp_path):
    """Fast: 640 x 360 images, 2 x 2 rays per pixel, 10 views (2 held out)."""
    truth = anamorphic_camera((640, 360))
    poses = rendered_views(truth, 10, 2, tmp_path)
    calibrate_export_read_back(truth, poses, str(tmp_path / "ana_*.png"), [8, 9], tmp_path)


@pytest.mark.slow
def test_rendered_anamorphic_lens_at_1280x720(tmp_path):
    """Full: 1280 x 720 images, 3 x 3 rays per pixel, 16 views (4 held out)."""
    truth = anamorphic_camera((1280, 720))
    poses = rendered_views(truth, 16, 3, tmp_path)
    calibrate_export_read_back(truth, poses, str(tmp_path / "ana_*.png"), [12, 13, 14, 15], tmp_path)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="Blender's bpy module is not installed")
def test_blender_rendered_anamorphic_lens(tmp_path):
    """The same lens rendered by Blender (module docstring): 960 x 540 plates, 16 views (4 held out)."""
    truth = anamorphic_camera(BLENDER_SIZE)
    poses = board_poses(truth, BLENDER_VIEWS, np.random.default_rng(42))
    [pattern] = render_board_views(BOARD, {"ana": (truth, poses)}, tmp_path, BLENDER_SAMPLES,
                                   band_limit_px=BLENDER_BAND_LIMIT_PX).values()
    calibrate_export_read_back(truth, poses, pattern, list(range(BLENDER_VIEWS - 4, BLENDER_VIEWS)), tmp_path)
