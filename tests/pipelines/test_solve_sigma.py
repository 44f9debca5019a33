"""Projection sigma of `solve` rigs: the covariance written to the rig file, `camcal sigma` on it, one truth check."""

import json

import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.rectify import rectify
from camcal.geometry.rectify.sigma import pair_covariance, rectified_pair_sigma
from camcal.geometry.uncertainty import projection_sigma
from camcal.io.stmap import read_sigma_map
from camcal.model.rig import Rig
from camcal.pipelines.solve import solve_sfm
from camcal.synthetic import render_stereo_sequence

#: A 2-D Gaussian error exceeds this many worst-direction sigmas with probability 0.27 %.
CHI2_9973 = float(np.sqrt(-2.0 * np.log(0.0027)))


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """A rendered 5-position stereo sequence 256 px wide (as the fast solve test), solved."""
    folder = tmp_path_factory.mktemp("solve")
    width, height = 256, 192
    focal = 500.0 * width / 640
    truth = render_stereo_sequence(folder / "in", n_frames=5, image_size=(width, height),
                                   K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    result = solve_sfm({"left": folder / "in/left", "right": folder / "in/right"}, folder / "out",
                       max_num_features=512)
    return folder, truth, result, Rig.load(folder / "out/solve.rig.json")


def test_solve_rig_keeps_the_covariance_in_camcal_names(solved):
    _, _, result, rig = solved
    left, right = rig.camera("left"), rig.camera("right")
    covariance = left.quality.covariance
    assert covariance is not None and {"fx", "fy", "cx", "cy"} <= set(covariance.names)
    names = list(covariance.names)
    # COLMAP's fx and fy (the aspect refined under its prior) are camcal's, scaled by one design effect of the
    # camera's projection (uncertainty.shrunk_design_effect over the frames' influences), at least 1
    calibration, bundle = result.self_calibration, result.bundle
    assert calibration.frame_influences is not None and len(calibration.frame_influences.values) == 5
    # (the bundle's covariance: a sideways slide holds square pixels, selfcal.aspect_visibility, and carries the
    # aspect prior's spread into it; covariance_sigmas are its diagonal)
    fx, fy = bundle.covariance_names.index("left.fx"), bundle.covariance_names.index("left.fy")
    factor = covariance.array[names.index("fx"), names.index("fx")] / bundle.covariance[fx, fx]
    assert factor >= 1.0 - 1e-9  # a design effect of 1 comes back through the conversion to camcal names to rounding
    assert bundle.covariance[fx, fx] == pytest.approx(calibration.covariance_sigmas["left.fx"] ** 2, rel=1e-9)
    assert covariance.array[names.index("fy"), names.index("fy")] == pytest.approx(factor * bundle.covariance[fy, fy],
                                                                                   rel=1e-6)
    assert covariance.array[names.index("fx"), names.index("fy")] == pytest.approx(factor * bundle.covariance[fx, fy],
                                                                                   rel=1e-6)
    # two parameters now: not fully correlated (the aspect's prior alone would allow 1 % of f between them)
    correlation = bundle.covariance[fx, fy] / np.sqrt(bundle.covariance[fx, fx] * bundle.covariance[fy, fy])
    assert correlation < 1 - 1e-6
    # the right camera carries its pose and the left camera's intrinsics (cross-covariance)
    assert {"rx", "tz", "left.fx"} <= set(right.quality.covariance.names)
    assert pair_covariance(left, right)[1]
    for camera in (left, right):
        worst = camera.quality["worst_projection_sigma_px"]
        assert 0 < worst < 5 and worst == pytest.approx(
            float(np.max(projection_sigma(camera, [[0, 0], [camera.image_size[0] - 1, camera.image_size[1] - 1]]))),
            rel=0.5)


def test_sigma_verb_on_a_solve_rig(solved, tmp_path, capsys):
    folder, _, _, rig = solved
    for name in ("left", "right"):
        out = tmp_path / f"{name}.exr"
        assert main(["sigma", str(folder / "out/solve.rig.json"), "--camera", name, "--out", str(out), "--json"]) == 0
        figures = json.loads(capsys.readouterr().out)["figures"]["sigma"]
        sigma = read_sigma_map(out)
        assert sigma.shape == (192, 256) and np.all(np.isfinite(sigma))
        assert figures["worst_px"] == pytest.approx(float(sigma.max()), rel=1e-6)
        assert sigma[40, 50] == pytest.approx(projection_sigma(rig.camera(name), [[50, 40]])[0], rel=1e-3)


def test_solve_sigma_against_the_truth(solved):
    """One solve is one draw of its error: the true projection error of rays at infinity in the camera's own
    frame (this sequence's frames all turn alike, so the rig has no scene gauge, :func:`scene_gauge_rows`:
    intrinsics only for the reference camera) stays within 3.44 sigma RMS over the frame (the 99.73 % radius
    of a 2-D Gaussian); figures printed. The scene gauge's coverage is in test_solve_coverage.py."""
    _, truth, _, rig = solved
    assert "gauge_rx" not in rig.camera("left").quality.covariance.names
    for name in ("left",):
        estimated, true = rig.camera(name), truth[name, 0]
        gx, gy = np.meshgrid(np.linspace(0, 255, 9), np.linspace(0, 191, 7))
        pixels = np.column_stack([gx.ravel(), gy.ravel()])
        error = np.linalg.norm(true.distortion.project_rays(estimated.distortion.rays_from_pixels(pixels, estimated.K),
                                                            true.K) - pixels, axis=1)
        sigma = projection_sigma(estimated, pixels)
        ratio = float(np.sqrt(np.mean((error / sigma) ** 2)))
        print(f"solve, {name}: true error RMS {np.sqrt(np.mean(error**2)):.3f} px, sigma RMS "
              f"{np.sqrt(np.mean(sigma**2)):.3f} px, error/sigma RMS {ratio:.2f}")
        assert ratio < CHI2_9973


def test_rectify_sigma_on_a_solve_rig(solved):
    _, _, _, rig = solved
    left, right = rectify(rig, "camera").rig.cameras
    pair = rectified_pair_sigma(left, right, 5.0)
    assert pair.cross_covariance and np.nanmax(pair.vertical_px) > 0 and np.nanmax(pair.depth) > 0
