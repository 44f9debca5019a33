"""A lens with a smooth correction field: fitted by name and chosen by ``model="auto"`` only when it is there."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.zhang import SPLINE_SUFFIX, calibrate_board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from camcal.model.spline import SplineField

SIGMA_PX = 0.1
BOARD = Board("chessboard", 9, 6, 0.04)
SIZE = (1280, 960)
KB = Distortion("kannala-brandt", {"k1": -0.03, "k2": 0.004, "k3": -0.001, "k4": 0.0002})


def bumpy_field() -> SplineField:
    """A smooth field of a few pixels no parametric model holds (a moulded asphere's ripple): sines over a 10x8 grid."""
    ys, xs = np.meshgrid(np.linspace(0, 1, 8), np.linspace(0, 1, 10), indexing="ij")
    dx = 3.0 * np.sin(1.5 * np.pi * xs) * np.cos(1.0 * np.pi * ys)
    dy = 2.5 * np.cos(1.2 * np.pi * xs + 0.4) * np.sin(1.5 * np.pi * ys)
    return SplineField(SIZE, np.stack([dx, dy], axis=-1))


def camera(correction: SplineField | None) -> Camera:
    lens = Distortion(KB.model, dict(KB.params), correction=correction)
    return Camera("wide", SIZE, np.array([[560.0, 0, 639.0], [0, 561.0, 481.0], [0, 0, 1]]), lens, np.eye(3), np.zeros(3))


def views(cam: Camera, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    out, centred = [], BOARD.object_points - BOARD.object_points.mean(axis=0)
    while len(out) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-40, 40, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        X = centred @ R.T + rng.uniform([-0.25, -0.2, 0.25], [0.25, 0.2, 0.5])
        p = cam.project(X)
        if not np.all(np.isfinite(p)) or not np.all((p > 5) & (p < np.array(SIZE) - 5)):
            continue
        out.append(Detection(f"view_{len(out):03d}.png", SIZE, np.arange(BOARD.n_corners),
                             p + rng.normal(0.0, SIGMA_PX, p.shape), "synthetic"))
    return {cam.name: out}


def test_a_named_spline_model_recovers_the_field():
    """``kannala-brandt+spline`` on a fisheye with a ripple of a few pixels: held-out views at the noise, the parametric model not."""
    truth = camera(bumpy_field())
    detections = views(truth, 30, 1)
    held = set(range(0, 30, 6))
    noise = math.sqrt(2) * SIGMA_PX  # per-corner norm of 2D noise of sigma 0.1 px
    splined = calibrate_board(BOARD, detections, model="kannala-brandt" + SPLINE_SUFFIX, holdout=held)
    assert splined.heldout_rms_px < 1.2 * noise and splined.rms_px < 1.05 * noise
    for model in ("kannala-brandt", "kannala-brandt-thin-prism"):  # the parametric models alone do not hold it
        plain = calibrate_board(BOARD, detections, model=model, holdout=held)
        assert plain.heldout_rms_px > 1.2 * splined.heldout_rms_px, model
    fitted = splined.rig.cameras[0]
    assert fitted.distortion.has_correction and fitted.quality["heldout_rms_px"] == splined.heldout_rms_px
    assert splined.model == "kannala-brandt" + SPLINE_SUFFIX and len(splined.residuals_px) == len(splined.points_px)
    with pytest.raises(CamcalError, match="one camera at a time"):
        calibrate_board(BOARD, {"a": detections["wide"], "b": detections["wide"]}, model="opencv" + SPLINE_SUFFIX)


@pytest.mark.slow
def test_auto_takes_the_field_only_where_the_lens_has_one():
    """The thorough auto picks ``<model>+spline`` on the rippled lens and a parametric model on the same lens without
    the ripple (the default's one-fit ranking scores no field)."""
    held = set(range(0, 24, 6))
    rippled = calibrate_board(BOARD, views(camera(bumpy_field()), 24, 2), holdout=held, thorough=True)
    assert rippled.model.endswith(SPLINE_SUFFIX), [s.describe() for s in rippled.model_ranking]
    assert rippled.heldout_rms_px < 1.3 * math.sqrt(2) * SIGMA_PX
    smooth = calibrate_board(BOARD, views(camera(None), 24, 2), holdout=held, thorough=True)
    assert not smooth.model.endswith(SPLINE_SUFFIX), [s.describe() for s in smooth.model_ranking]
    assert any(s.model.endswith(SPLINE_SUFFIX) and s.rms_px is not None for s in smooth.model_ranking)


def test_undistortion_maps_and_exports_carry_the_field():
    """Remap maps sample through the field; exports take the nearest parametric model and say how far it is."""
    from camcal.geometry.remap import build_maps
    from camcal.io.conversion import nearest_camera
    from camcal.model.colmap import camera_to_colmap

    truth = camera(bumpy_field())
    maps = build_maps(truth, np.eye(3), SIZE)
    xs, ys = np.meshgrid(np.arange(100, 1200, 100), np.arange(100, 900, 100))
    expected = truth.distortion.distort(np.column_stack([xs.ravel(), ys.ravel()]), truth.K)
    sampled = np.column_stack([maps.map_x[ys.ravel(), xs.ravel()], maps.map_y[ys.ravel(), xs.ravel()]])
    assert np.abs(sampled - expected).max() < 1e-3  # float32 maps
    plain = Camera(truth.name, SIZE, truth.K, KB, truth.R, truth.c)
    assert np.abs(build_maps(plain, np.eye(3), SIZE).map_x[ys.ravel(), xs.ravel()] - sampled[:, 0]).max() > 1.0
    converted, conversion = nearest_camera(truth, lambda d: d.model == "kannala-brandt", "kannala-brandt", "fisheye")
    assert not converted.distortion.has_correction and not conversion.exact
    assert 0.5 < conversion.max_px < 10.0  # the field's few pixels, what the nearest model loses
    with pytest.raises(CamcalError, match="correction field"):
        camera_to_colmap(truth)


def test_cli_board_models_are_the_solvers():
    """``calibrate board --model`` offers every model of the solver, each with a correction field, and auto."""
    from camcal.cli.calibrate import _BOARD_MODELS, _TDE4_MODELS
    from camcal.geometry.zhang import MODELS
    from camcal.model.tde4 import TDE4_MODELS

    assert _BOARD_MODELS == tuple(MODELS)
    assert _TDE4_MODELS == TDE4_MODELS


def test_cli_fits_a_named_model_with_a_correction_field(tmp_path, capsys, monkeypatch):
    """``camcal calibrate board --model kannala-brandt+spline`` writes the field into the rig, held-out views at the
    noise; with two cameras it refuses in one line and writes nothing."""
    from camcal.cli import main
    from camcal.geometry.board import DetectionReport
    from camcal.model.rig import Rig

    truth = camera(bumpy_field())
    detections = views(truth, 24, 3)["wide"]
    for d in detections:
        (tmp_path / d.image).write_bytes(b"")
    monkeypatch.setattr("camcal.pipelines.board.detect_in_images",
                        lambda board, paths, progress=None, **options: DetectionReport(tuple(detections), ()))
    out = tmp_path / "wide.rig.json"
    code = main(["calibrate", "board", "--board", "chessboard:9x6:0.04", "--images", f"wide={tmp_path / 'view_*.png'}",
                 "--model", "kannala-brandt" + SPLINE_SUFFIX, "--holdout", "0,6,12,18", "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed
    lens = Rig.load(out).cameras[0]
    assert lens.distortion.model == "kannala-brandt" and lens.distortion.has_correction
    assert lens.quality["heldout_rms_px"] < 1.2 * math.sqrt(2) * SIGMA_PX, printed.out
    two = tmp_path / "two.rig.json"
    code = main(["calibrate", "board", "--board", "chessboard:9x6:0.04", "--images", f"a={tmp_path / 'view_*.png'}",
                 f"b={tmp_path / 'view_*.png'}", "--model", "opencv" + SPLINE_SUFFIX, "--out", str(two)])
    printed = capsys.readouterr()
    assert code == 2 and not two.exists()
    assert [line for line in printed.err.splitlines() if line.startswith("camcal: error:")] == [
        "camcal: error: model opencv+spline calibrates one camera at a time, without given intrinsics"], printed.err


def test_a_posed_view_gives_nan_where_the_lens_cannot_project_a_corner():
    """:func:`camcal.geometry.spline_fit.pose_view`: a corner that lies behind a pinhole camera at the pose found
    has no image: its residual is NaN (it was the fit's 1e6 px placeholder, a finite score that ranked a broken
    model among the others), the other corners' residuals are the real ones."""
    from camcal.geometry.spline_fit import pose_view

    pinhole = Camera("pin", SIZE, np.array([[560.0, 0, 639.0], [0, 561.0, 481.0], [0, 0, 1]]),
                     Distortion("none", {}), np.eye(3), np.zeros(3))
    board_in_camera = BOARD.object_points - BOARD.object_points.mean(axis=0) + [0.0, 0.0, 0.4]  # R = I
    detection = Detection("square.png", SIZE, np.arange(BOARD.n_corners), pinhole.project(board_in_camera), "synthetic")
    points = BOARD.object_points.copy()
    points[0, 2] = -1.0  # 1 m towards the camera from a board 0.4 m away: behind it
    _, _, residuals = pose_view(BOARD, pinhole.K, pinhole.distortion, detection, points)
    assert np.all(np.isnan(residuals[0]))
    assert np.all(np.isfinite(residuals[1:])) and np.sqrt(np.mean(np.sum(residuals[1:] ** 2, axis=1))) < 100.0


def test_a_corner_outside_a_fisheye_lenss_image_is_measured_from_its_rim():
    """:func:`camcal.geometry.spline_fit.pose_view`: a fisheye lens fitted on views that did not reach the image's
    corners can turn over (``theta_d(theta)`` stops growing) before a held-out view's outermost corner: no ray
    reaches that pixel. It was NaN, and one such corner ranked the whole model out of ``model="auto"`` (a real
    640x640 fisheye: kannala-brandt, then the best lens on the board's surface). It is now the distance to the
    lens's image rim: at least how far the corner lies outside it."""
    from camcal.geometry.spline_fit import pose_view

    K = np.array([[300.0, 0, 639.0], [0, 300.0, 479.0], [0, 0, 1]])
    truth = Distortion("kannala-brandt", {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0})  # equidistant: r = f theta
    folding = Distortion("kannala-brandt", {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": -0.02})  # turns over
    theta_max = folding.max_angle_rad
    rim_px = 300.0 * float(folding.theta_d(theta_max))
    R = Rotation.from_euler("xyz", [0.0, 45.0, 0.0], degrees=True).as_matrix()
    X = (BOARD.object_points - BOARD.object_points.mean(axis=0)) @ R.T + [0.15, 0.0, 0.2]  # its right edge far out
    x = truth.project_rays(X, K)
    radius = np.hypot(*(x - K[:2, 2]).T)
    outside = radius > rim_px + 5.0
    assert 0 < outside.sum() < BOARD.n_corners // 4, (theta_max, rim_px, radius.max())  # the case is the one meant
    _, _, residuals = pose_view(BOARD, K, folding, Detection("rim.png", SIZE, np.arange(BOARD.n_corners), x, "synth"))
    assert np.all(np.isfinite(residuals))
    lengths = np.linalg.norm(residuals, axis=1)
    assert np.all(lengths[outside] >= radius[outside] - rim_px - 1e-6)
