"""Rectified-pair sigma: the vertical disparity and depth sigma maps against a Monte-Carlo of recalibrations."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import Detection
from camcal.geometry.rectify import rectify
from camcal.geometry.rectify.sigma import pair_covariance, rectified_pair_sigma, rectified_world_rotation
from camcal.geometry.zhang import calibrate_board
from camcal.model.distortion import Distortion
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Camera, Rig
from tests.geometry.test_uncertainty import BOARD

SIZE = (640, 480)


def true_rig() -> Rig:
    """A stereo pair 12 cm apart, slightly turned, division lenses."""
    left = Camera("left", SIZE, np.array([[520.0, 0, 322], [0, 520, 236], [0, 0, 1]]),
                  Distortion("division", {"lambda": -0.15 / 520**2}), np.eye(3), np.zeros(3))
    right = Camera("right", SIZE, np.array([[530.0, 0, 316], [0, 530, 244], [0, 0, 1]]),
                   Distortion("division", {"lambda": -0.1 / 530**2}),
                   Rotation.from_euler("xyz", [0.5, -2.0, 0.3], degrees=True).as_matrix(), np.array([0.12, 0.003, -0.002]))
    return Rig((left, right))


def board_poses(rig: Rig, n: int, rng) -> list:
    """``n`` board poses whose corners both cameras see (10 px margin)."""
    centred, out = BOARD.object_points.mean(axis=0), []
    while len(out) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.5], degrees=True).as_matrix()
        depth = rng.uniform(0.4, 0.7)
        t = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.2, 0.2), 1.0]) * depth - R @ centred
        X = BOARD.object_points @ R.T + t
        if all(np.all((c.project(X) > 10) & (c.project(X) < np.array(SIZE) - 10)) for c in rig.cameras):
            out.append((R, t))
    return out


def detections(rig: Rig, poses, rng, noise_px=0.1) -> dict:
    """The true corners of each view in each camera plus independent Gaussian noise."""
    out = {}
    for camera in rig.cameras:
        out[camera.name] = []
        for k, (R, t) in enumerate(poses):
            q = camera.project(BOARD.object_points @ R.T + t)
            out[camera.name].append(Detection(f"{camera.name}_{k:03d}.png", SIZE, np.arange(BOARD.n_corners),
                                              q + rng.normal(0.0, noise_px, q.shape), ""))
    return out


def true_errors(estimated: Rig, truth: Rig, pixels: np.ndarray, distance: float) -> np.ndarray:
    """(N, 2): vertical disparity (px) and depth error of the scene points at ``distance`` behind the first
    camera's rectified ``pixels``, imaged by the TRUE cameras and rectified with the ESTIMATED ones
    (the reference camera's frame taken as the true one's)."""
    first, second = estimated.cameras
    W = rectified_world_rotation(first)
    K_rect = first.rectification.K_rect
    X = first.c + distance * (np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(K_rect).T @ W)
    rect = []
    for est, true in zip((first, second), truth.cameras):
        rays = est.distortion.rays_from_pixels(true.project(X), est.K)
        mapped = rays @ (est.rectification.H @ est.K).T
        rect.append(mapped[:, :2] / mapped[:, 2:3])
    baseline_x = (W @ (second.c - first.c))[0]
    depth = K_rect[0, 0] * baseline_x / (rect[0][:, 0] - rect[1][:, 0])
    return np.column_stack([rect[0][:, 1] - rect[1][:, 1], depth - distance])


def monte_carlo(n_runs: int, distance: float = 1.5, seed: int = 0):
    """z = error / predicted sigma of the vertical disparity and the depth over ``n_runs`` recalibrations of one
    scene (same board poses, new corner noise), on a 7 x 5 grid of rectified pixels; and the per-pixel spread."""
    truth = true_rig()
    rng = np.random.default_rng(seed)
    poses = board_poses(truth, 10, rng)
    z, errors, sigmas = [], [], []
    for _ in range(n_runs):
        result = calibrate_board(BOARD, detections(truth, poses, rng), model="division")
        rectified = rectify(result.rig, "camera").rig
        first, second = rectified.cameras
        pair = rectified_pair_sigma(first, second, distance)
        width, height = first.rectification.image_size
        gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 7) * (width - 1), np.linspace(0.1, 0.9, 5) * (height - 1))
        pixels = np.column_stack([gx.ravel(), gy.ravel()])
        error = true_errors(rectified, truth, pixels, distance)
        i, j = np.round(pixels[:, 1]).astype(int), np.round(pixels[:, 0]).astype(int)
        sigma = np.column_stack([pair.vertical_px[i, j], pair.depth[i, j]])
        z.append(error / sigma)
        errors.append(error)
        sigmas.append(sigma)
    return np.array(z), np.array(errors), np.array(sigmas)


def test_cross_covariance_is_written_and_used():
    truth = true_rig()
    rng = np.random.default_rng(3)
    result = calibrate_board(BOARD, detections(truth, board_poses(truth, 8, rng), rng), model="division")
    left, right = rectify(result.rig, "camera").rig.cameras
    assert "left.fx" in right.quality.covariance.names and not any("." in n for n in left.quality.covariance.names)
    joint, cross = pair_covariance(left, right)
    assert cross and {"left.cx", "right.cx", "right.rx"} <= set(joint.names)
    # the same figures with the cross terms dropped differ: the correlation between the cameras matters
    with_cross = rectified_pair_sigma(left, right, 1.0)
    own = [k for k, n in enumerate(right.quality.covariance.names) if not n.startswith("left.")]
    names = tuple(right.quality.covariance.names[k] for k in own)
    bare = ParameterCovariance(names, right.quality.covariance.array[np.ix_(own, own)])
    alone = rectified_pair_sigma(left, dataclasses.replace(right, quality={**right.quality.to_dict(), "covariance": bare}),
                                 1.0)
    assert not alone.cross_covariance and "independent" in alone.describe()
    assert not np.allclose(np.nanmedian(alone.vertical_px), np.nanmedian(with_cross.vertical_px), rtol=0.05)
    assert with_cross.vertical_px.shape == (left.rectification.image_size[1], left.rectification.image_size[0])


def test_one_principal_point_moves_the_rows_by_its_sigma():
    """Only the right camera's cy uncertain (sigma 0.5 px): the vertical disparity sigma is 0.5 px scaled by the
    rectified over the original focal length, near the centre (the rotation to the rectified frame is small)."""
    left, right = rectify(true_rig(), "camera").rig.cameras
    zero = ParameterCovariance(("fx",), ((0.0,),))
    left = dataclasses.replace(left, quality={"covariance": zero})
    right = dataclasses.replace(right, quality={"covariance": ParameterCovariance(("cy",), ((0.25,),))})
    pair = rectified_pair_sigma(left, right, None)
    assert pair.depth is None
    width, height = left.rectification.image_size
    centre = pair.vertical_px[height // 2, width // 2]
    expected = 0.5 * left.rectification.K_rect[1, 1] / right.K[1, 1]
    assert centre == pytest.approx(expected, rel=0.03)


def test_projective_rectification_is_refused():
    left, right = rectify(true_rig(), "camera").rig.cameras
    H = left.rectification.H @ np.array([[1.0, 0.02, 0], [0, 1, 0], [0, 0, 1]])
    bent = dataclasses.replace(left, rectification=dataclasses.replace(left.rectification, H=H))
    with pytest.raises(CamcalError, match="not a rotation"):
        rectified_pair_sigma(bent, right)


def _check(z, n_runs, label):
    """The pooled RMS of z against 1 within 3 sampling sigmas of a standard deviation of ``n_runs`` draws
    (1 / sqrt(2 n)); the pixels of one run share the run's parameter error, so runs are the samples."""
    rms = float(np.sqrt(np.mean(z**2)))
    inside = float(np.mean(np.abs(z) < 2.0))
    tolerance = 3.0 / np.sqrt(2.0 * n_runs)
    print(f"{label}: RMS error/sigma {rms:.2f} (1 +- {tolerance:.2f}), within 2 sigma {100 * inside:.0f} %")
    assert abs(rms - 1.0) < tolerance


@pytest.mark.slow
def test_predicted_sigma_matches_recalibrations():
    """50 recalibrations of one stereo scene (independent 0.1 px corner noise): the RMS of error / sigma of the
    vertical disparity and of the depth at 1.5 m is 1 within sampling error, and so is the median over the pixels
    of the observed spread over the runs against the mean predicted sigma (measured: RMS z 0.91 vertical, 0.85
    depth; per pixel 0.71-1.05: the board calibration's design effect, never below 1, errs on the wide side)."""
    n = 50
    z, errors, sigmas = monte_carlo(n, seed=1)
    _check(z[..., 0], n, "vertical disparity, 50 runs")
    _check(z[..., 1], n, "depth at 1.5 m, 50 runs")
    spread = np.sqrt(np.mean(errors**2, axis=0)) / np.mean(sigmas, axis=0)
    print(f"per pixel observed RMS / predicted: vertical {np.median(spread[:, 0]):.2f} "
          f"({spread[:, 0].min():.2f}-{spread[:, 0].max():.2f}), depth {np.median(spread[:, 1]):.2f} "
          f"({spread[:, 1].min():.2f}-{spread[:, 1].max():.2f})")
    assert np.all(np.abs(np.median(spread, axis=0) - 1.0) < 3.0 / np.sqrt(2.0 * n))


def test_rectify_sigma_verb_writes_exrs_aligned_with_the_rectified_images(tmp_path, capsys):
    import json

    import OpenEXR

    from camcal.cli import main
    from camcal.io.stmap import read_sigma_map

    truth = true_rig()
    rng = np.random.default_rng(5)
    rig_file = tmp_path / "pair.rig.json"
    calibrate_board(BOARD, detections(truth, board_poses(truth, 8, rng), rng), model="division").rig.save(rig_file)
    out, report = tmp_path / "rect.rig.json", tmp_path / "report"
    assert main(["rectify", str(rig_file), "--out", str(out), "--report", str(report), "--sigma", "--distance", "2",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    rectified = Rig.load(out)
    left, right = rectified.cameras
    width, height = left.rectification.image_size
    vertical, depth = report / "left-right_vertical_sigma.exr", report / "left-right_depth_sigma.exr"
    with OpenEXR.File(str(vertical)) as exr:
        assert exr.channels()["Y"].pixels.shape == (height, width)
    expected = rectified_pair_sigma(left, right, 2.0)
    assert np.allclose(read_sigma_map(vertical), expected.vertical_px, equal_nan=True, rtol=1e-6)
    assert np.allclose(read_sigma_map(depth), expected.depth, equal_nan=True, rtol=1e-6)
    figures = summary["figures"]["sigma"][0]
    assert figures["vertical_disparity"]["worst_px"] == pytest.approx(float(np.nanmax(expected.vertical_px)), rel=1e-6)
    assert figures["depth"]["median_m"] == pytest.approx(float(np.nanmedian(expected.depth)), rel=1e-6)
    assert {"path": str(depth), "kind": "sigma"} in summary["files"]
    # bad input: one line, exit 2, nothing written
    assert main(["rectify", str(rig_file), "--out", str(tmp_path / "x.rig.json"), "--sigma"]) == 2
    assert "--sigma needs --write DIR or --report DIR" in capsys.readouterr().err
    assert not (tmp_path / "x.rig.json").exists()
