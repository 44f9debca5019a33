"""3DEqualizer's LDPK models: equal to the LDPK's own C++ (compiled here, or its recorded table), round trips."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import ldpk_reference as reference
from camcal.base.errors import CamcalError
from camcal.geometry.remap import build_maps
from camcal.model import tde4
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

#: camcal against the LDPK, diagonally normalised units (the film back's half-diagonal).
LDPK_TOLERANCE_DN = 1e-9

LENSES = {
    "3de-classic": {"distortion": -0.08, "anamorphic_squeeze": 1.3, "curvature_x": 0.02, "curvature_y": -0.03,
                    "quartic_distortion": 0.01},
    "3de4-radial-deg4": {"c2": -0.05, "u2": 0.01, "v2": -0.008, "c4": 0.01, "u4": 0.003, "v4": 0.002,
                         "cylindric_direction_deg": 30.0, "cylindric_bending": 0.05},
    "3de4-anamorphic-deg4": {"cx02": -0.05, "cy02": -0.03, "cx22": 0.01, "cy22": 0.02, "cx04": 0.01, "cy04": 0.005,
                             "cx24": 0.002, "cy24": 0.001, "cx44": -0.001, "cy44": 0.0005, "lens_rotation_deg": 1.5,
                             "squeeze_x": 1.02, "squeeze_y": 0.98},
    "3de4-fisheye-deg8": {"c2": 0.05, "c4": 0.01, "c6": 0.001, "c8": 0.0001},
}
W, H = 1920, 1080
FILMBACK = {"filmback_width_px": float(W), "filmback_height_px": float(H)}
K_ANAMORPHIC = np.array([[700.0, 0.0, 972.0], [0.0, 1400.0, 530.0], [0.0, 0.0, 1.0]])  # pixel aspect 2
K_FISHEYE = np.array([[1000.0, 0.0, 965.0], [0.0, 1000.0, 541.0], [0.0, 0.0, 1.0]])


def frame(step: float = 37.0) -> np.ndarray:
    u, v = np.meshgrid(np.arange(0.0, W, step), np.arange(0.0, H, step))
    return np.column_stack([u.ravel(), v.ravel()])


def camera_matrix(model: str) -> np.ndarray:
    return K_FISHEYE if model == "3de4-fisheye-deg8" else K_ANAMORPHIC


@pytest.fixture(scope="module")
def ldpk_driver(tmp_path_factory) -> Path:
    """The LDPK driver compiled against ``$CAMCAL_LDPK_DIR``, or a skip saying what is missing."""
    folder = os.environ.get(reference.LDPK_DIR_VARIABLE)
    if not folder:
        pytest.skip(f"LDPK equality against its C++ skipped: set {reference.LDPK_DIR_VARIABLE} to an LDPK source "
                    "tree (Science-D-Visions' Lens Distortion Plugin Kit) to compile and run it")
    if not (Path(folder) / "include" / "ldpk" / "tde4_ldp_radial_deg_8.h").is_file():
        pytest.skip(f"LDPK equality skipped: {folder} has no include/ldpk headers")
    if shutil.which("g++") is None and shutil.which("c++") is None:
        pytest.skip("LDPK equality against its C++ skipped: no C++ compiler (g++ or c++) on PATH")
    return reference.compile_driver(Path(folder), tmp_path_factory.mktemp("ldpk"))


@pytest.mark.parametrize("model", tde4.TDE4_MODELS)
def test_parameter_names_are_the_ldpks(ldpk_driver, model):
    names = reference.ldpk_names(ldpk_driver, model)
    assert names[0] == tde4.LDPK_MODEL_NAMES[model]
    assert names[1:] == [p.ldpk_name for p in tde4.LDPK_PARAMETERS[model]]


def test_equal_to_ldpk_on_random_lenses_both_directions(ldpk_driver):
    cases = reference.random_cases(seed=7, lenses_per_direction=6, n_points=100)
    assert {case.camera.pixel_aspect for case in cases if case.model == "3de4-anamorphic-deg4"} >= {2.0}
    worst = {}
    for case, answer in zip(cases, reference.run_driver(ldpk_driver, cases)):
        distance = reference.dn_difference(case, reference.camcal_unit(case), answer)
        key = f"{case.model} {case.direction}"
        worst[key] = max(worst.get(key, 0.0), float(np.max(distance)))  # NaN (camcal found no root) fails below
    assert len(worst) == 8 and all(value < LDPK_TOLERANCE_DN for value in worst.values()), worst


def test_equal_to_the_ldpk_reference_table():
    rows = reference.read_table(reference.TABLE)
    assert {(case.model, case.direction) for case, _ in rows} == {
        (model, direction) for model in tde4.TDE4_MODELS for direction in ("undistort", "distort")}
    assert len(rows) >= 8 * 20
    distances = [reference.dn_difference(case, reference.camcal_unit(case), answer)[0] for case, answer in rows]
    assert max(distances) < LDPK_TOLERANCE_DN


def test_ldpk_documentation_example():
    """LDPK 2.0's tde4_ldm_standard, section 2.1.4: radial standard degree 4, c2 = c4 = 0.1, its default camera
    (focal 2 cm, film back 1.6 x 0.9 cm): the image corners undistort to -0.1 / 1.1 and (0, 0) distorts to 0.0603."""
    camera = tde4.LdpkCamera(2.0, 1.6, 0.9, 0.0, 0.0, 1.0)
    size = (1600, 900)
    K = camera.camera_matrix(size)
    params = {"c2": 0.1, "c4": 0.1, "filmback_width_px": 1600.0, "filmback_height_px": 900.0}
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    case = reference.Case("3de4-radial-deg4", "undistort", size, camera, (0.1, 0, 0, 0.1, 0, 0, 0, 0), corners)
    assert case.params == {**dict.fromkeys(["c2", "c4"], 0.1), **params, **dict.fromkeys(
        ["u2", "v2", "u4", "v4", "cylindric_direction_deg", "cylindric_bending"], 0.0)}
    assert np.allclose(reference.camcal_unit(case), [[-0.1, -0.1], [1.1, -0.1], [-0.1, 1.1], [1.1, 1.1]], atol=1e-12)
    distorted = reference.camcal_unit(reference.Case("3de4-radial-deg4", "distort", size, camera, case.values,
                                                     corners))
    assert np.allclose(distorted, [[0.0603, 0.0603], [0.9397, 0.0603], [0.0603, 0.9397], [0.9397, 0.9397]],
                       atol=5e-5)
    assert np.allclose(K, [[2000.0, 0.0, 799.5], [0.0, 2000.0, 449.5], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("model", ["3de-classic", "3de4-radial-deg4", "3de4-anamorphic-deg4"])
def test_polynomial_jacobians_match_central_differences(model):
    """The Newton inverse's analytic Jacobians (private) against central differences of their functions."""
    c = tde4.coefficients(model, LENSES[model])
    if model == "3de4-radial-deg4":
        function, jacobian = (lambda p: tde4._radial_decentred(p, c)), (lambda p: tde4._radial_decentred_jacobian(p, c))
    else:
        terms = tde4._classic_terms(c) if model == "3de-classic" else tde4._anamorphic_terms(c)
        function, jacobian = (lambda p: tde4._even_quartic(p, *terms)), (lambda p: tde4._even_quartic_jacobian(p, *terms))
    points = np.random.default_rng(3).uniform(-1.2, 1.2, (50, 2))
    step = 1e-6
    numeric = np.stack([(function(points + step * e) - function(points - step * e)) / (2 * step)
                        for e in np.eye(2)], axis=2)
    assert np.abs(jacobian(points) - numeric).max() < 1e-8
    fisheye_terms = (0.05, 0.01, 0.001, 0.0001)
    numeric = np.stack([(tde4._radial_even(points + step * e, fisheye_terms)
                         - tde4._radial_even(points - step * e, fisheye_terms)) / (2 * step) for e in np.eye(2)], axis=2)
    assert np.abs(tde4._radial_even_jacobian(points, fisheye_terms) - numeric).max() < 1e-8


def test_fisheye_is_equisolid_and_stops_at_90_degrees():
    """With no polynomial the fisheye maps a ray at theta to 2 f sin(theta / 2) in the distorted image."""
    params = {**FILMBACK}
    K = K_FISHEYE
    theta = np.radians([0.0, 10.0, 45.0, 80.0, 89.9])
    pinhole = np.column_stack([K[0, 2] + K[0, 0] * np.tan(theta), np.full(theta.size, K[1, 2])])
    distorted = tde4.distort_pixels("3de4-fisheye-deg8", params, pinhole, K)
    assert np.allclose(distorted[:, 0] - K[0, 2], 2.0 * K[0, 0] * np.sin(theta / 2), rtol=1e-12, atol=1e-9)
    beyond = np.array([[K[0, 2] + 2.0 * K[0, 0] * np.sin(np.radians(45.0)) + 1.0, K[1, 2]]])
    assert np.all(np.isnan(tde4.undistort_pixels("3de4-fisheye-deg8", params, beyond, K)))


def test_past_the_fold_is_nan_not_a_far_root():
    """``q = p (1 - 0.3 r^2)`` peaks at ``|q| = 0.703`` (``r = 1.054``): the frame's corners (``|q| = 1``) have no
    distorted point, the centre keeps its own."""
    params = {"c2": -0.3, **FILMBACK}
    K = K_FISHEYE
    points = np.array([[W - 1.0, H - 1.0], [0.0, 0.0], [K[0, 2], K[1, 2]]])
    distorted = tde4.distort_pixels("3de4-radial-deg4", params, points, K)
    assert np.isnan(distorted[:2]).all() and np.allclose(distorted[2], points[2])


def test_ldpk_camera_round_trip_and_mismatch():
    camera = tde4.LdpkCamera.from_camera_matrix(K_ANAMORPHIC, (W, H), 2.4)
    assert camera.pixel_aspect == 2.0
    assert camera.filmback_width_cm / camera.filmback_height_cm == pytest.approx(W * 2.0 / H)
    assert camera.lens_center_offset_x_cm == pytest.approx((972.0 - 959.5) * 2.4 / W)
    assert camera.lens_center_offset_y_cm == pytest.approx(-(530.0 - 539.5) * camera.filmback_height_cm / H)
    assert np.allclose(camera.camera_matrix((W, H)), K_ANAMORPHIC, rtol=1e-14, atol=1e-12)
    assert list(camera.builtin_parameters()) == list(tde4.BUILTIN_PARAMETERS)
    with pytest.raises(CamcalError, match="pixel aspect 1 does not match"):
        tde4.LdpkCamera(3.5, 2.4, 1.8, 0.0, 0.0, 1.0).camera_matrix((W, H))
    with pytest.raises(CamcalError, match="no skew"):
        tde4.LdpkCamera.from_camera_matrix([[700.0, 1.0, 972.0], [0, 1400.0, 530.0], [0, 0, 1]], (W, H), 2.4)
    with pytest.raises(CamcalError, match="focal_length_cm must be a positive number"):
        tde4.LdpkCamera(0.0, 2.4, 1.8, 0.0, 0.0, 1.0)


@pytest.mark.parametrize("model, params, message", [
    ("3de4-radial-deg4", {"c2": 0.1}, "needs its film back: parameter 'filmback_width_px'"),
    ("3de4-radial-deg4", {**FILMBACK, "filmback_height_px": 0.0}, "'filmback_height_px' must be positive"),
    ("3de4-radial-deg4", {**FILMBACK, "cylindric_bending": -1.0}, "'cylindric_bending' must be above -1"),
    ("3de4-anamorphic-deg4", {**FILMBACK, "squeeze_y": 0.0}, "'squeeze_y' must be positive"),
    ("3de-classic", {**FILMBACK, "anamorphic_squeeze": -2.0}, "'anamorphic_squeeze' must be positive"),
    ("3de4-radial", FILMBACK, "unknown 3DE model '3de4-radial'"),
])
def test_bad_parameters_are_named(model, params, message):
    with pytest.raises(CamcalError, match=message):
        tde4.check_params(model, params)


def test_identity():
    assert tde4.is_identity("3de-classic", {"anamorphic_squeeze": 2.0})
    assert tde4.is_identity("3de4-radial-deg4", {"cylindric_direction_deg": 40.0})
    assert not tde4.is_identity("3de4-anamorphic-deg4", {"lens_rotation_deg": 0.5})
    assert not tde4.is_identity("3de4-fisheye-deg8", {})
    # the anamorphic lens rotation without coefficients still moves points when the pixel aspect is not 1
    rotated = tde4.undistort_dn("3de4-anamorphic-deg4", {"lens_rotation_deg": 2.0}, [[0.5, 0.3]], pixel_aspect=2.0)
    assert np.abs(rotated - [[0.5, 0.3]]).max() > 1e-3


# -- as camcal lens models: Distortion, the rig file, remap ---------------------------------------


def lens(model: str) -> Distortion:
    return Distortion(model, {**LENSES[model], **FILMBACK})


@pytest.mark.parametrize("model", tde4.TDE4_MODELS)
def test_distortion_round_trips_in_pixels(model):
    distortion, K, grid = lens(model), camera_matrix(model), frame()
    assert not distortion.is_identity and not distortion.is_fisheye
    distorted = distortion.distort(grid, K)
    assert np.all(np.isfinite(distorted))
    assert np.abs(distortion.undistort(distorted, K) - grid).max() < 1e-9
    undistorted = distortion.undistort(grid, K)
    assert np.abs(distortion.distort(undistorted, K) - grid).max() < 1e-9
    # LDPK's direction: the coefficients undistort, so camcal's undistort is the model function itself
    params = dict(distortion.params)
    expected = tde4.pixels_from_dn(tde4.undistort_dn(model, params, tde4.dn_from_pixels(grid, K, params),
                                                     K[1, 1] / K[0, 0], 1.0 / tde4.dn_radius(K, params)), K, params)
    assert np.array_equal(undistorted, expected)


def test_distortion_defaults_and_identity():
    identity = Distortion("3de4-radial-deg4", FILMBACK)
    assert identity.is_identity
    grid = frame(101.0)
    assert np.allclose(identity.distort(grid, K_FISHEYE), grid, atol=1e-12)
    assert Distortion("3de4-anamorphic-deg4", {**FILMBACK, "squeeze_x": 1.0}).is_identity
    with pytest.raises(CamcalError, match="has no parameter"):
        Distortion("3de4-radial-deg4", {**FILMBACK, "k1": 0.1})
    with pytest.raises(CamcalError, match="needs parameter"):
        Distortion("3de4-fisheye-deg8", {"c2": 0.1})
    with pytest.raises(CamcalError, match="'squeeze_x' must be positive"):
        Distortion("3de4-anamorphic-deg4", {**FILMBACK, "squeeze_x": -1.0})


def make_camera(model: str, name: str, image_size=(W, H)) -> Camera:
    return Camera(name, image_size, camera_matrix(model), lens(model), np.eye(3), [0.1 * len(name), 0.0, 0.0])


def test_rig_file_round_trip(tmp_path):
    rig = Rig(tuple(make_camera(model, model) for model in tde4.TDE4_MODELS), units="m")
    loaded = Rig.load(rig.save(tmp_path / "tde4.rig.json"))
    assert loaded == rig
    points = np.array([[0.3, -0.2, 3.0], [-1.0, 0.5, 4.0], [0.0, 0.0, 2.0]])
    for before, after in zip(rig.cameras, loaded.cameras):
        assert after.distortion.model == before.distortion.model
        assert dict(after.distortion.params) == dict(before.distortion.params)
        assert np.array_equal(after.project(points), before.project(points))


def test_camera_refuses_a_lens_on_another_film_back():
    with pytest.raises(CamcalError, match="on a 960x540 image must have that film back"):
        make_camera("3de4-radial-deg4", "half", image_size=(960, 540))


def test_remap_samples_the_lens():
    """``build_maps`` (undistortion) samples the distorted image where the 3DE lens puts each ideal pixel."""
    camera = make_camera("3de4-anamorphic-deg4", "anamorphic")
    quarter = np.diag([0.25, 0.25, 1.0])  # a quarter-size output: output pixel x_o samples the ideal pixel 4 x_o
    maps = build_maps(camera, quarter, (W // 4, H // 4))
    rows, cols = np.array([0, 50, 134, 269]), np.array([0, 175, 375, 479])
    expected = camera.distortion.distort(4.0 * np.column_stack([cols, rows]).astype(np.float64), camera.K)
    assert np.abs(np.column_stack([maps.map_x[rows, cols], maps.map_y[rows, cols]]) - expected).max() < 1e-3
