"""The B-spline correction field and a lens model carrying it: inverse, Jacobian, rig-file round trip."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.model.spline import SplineField

SIZE = (1280, 960)
K = np.array([[600.0, 0.0, 641.0], [0.0, 598.0, 477.0], [0.0, 0.0, 1.0]])


def smooth_field(seed: int, amplitude: float = 2.0) -> SplineField:
    rng = np.random.default_rng(seed)
    return SplineField(SIZE, rng.normal(0.0, amplitude, (8, 10, 2)))


def pixels(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform([0, 0], [SIZE[0] - 1, SIZE[1] - 1], (n, 2))


def test_constant_coefficients_give_a_constant_field():
    """The cubic B-spline basis sums to one (partition of unity): equal control displacements move every pixel alike."""
    field = SplineField(SIZE, np.broadcast_to([1.25, -0.5], (8, 10, 2)))
    assert np.abs(field.evaluate(pixels(500, 0)) - [1.25, -0.5]).max() < 1e-12


def test_remove_inverts_apply_and_jacobian_matches_differences():
    field = smooth_field(1)
    q0 = pixels(400, 2)
    assert np.abs(field.remove(field.apply(q0)) - q0).max() < 1e-9
    h = 1e-5
    numeric = np.stack([(field.evaluate(q0 + [h, 0]) - field.evaluate(q0 - [h, 0])) / (2 * h),
                        (field.evaluate(q0 + [0, h]) - field.evaluate(q0 - [0, h])) / (2 * h)], axis=2)
    assert np.abs(field.jacobian(q0) - numeric).max() < 1e-7


def test_basis_matrix_is_the_field():
    field = smooth_field(3)
    q0 = pixels(300, 4)
    assert np.abs(field.basis_matrix(q0) @ field.coefficients.reshape(-1, 2) - field.evaluate(q0)).max() < 1e-12


@pytest.mark.parametrize("lens", [
    Distortion("kannala-brandt", {"k1": -0.02, "k2": 0.01, "k3": -0.003, "k4": 0.0004}),
    Distortion("opencv", {"k1": -0.2, "k2": 0.05, "p1": 1e-3, "p2": -5e-4, "k3": -0.005}),
    Distortion("division", {"lambda": -2e-7}),
])
def test_a_lens_with_a_field_maps_both_ways(lens):
    """distort / undistort and project_rays / rays_from_pixels of a lens with a field invert each other."""
    splined = Distortion(lens.model, dict(lens.params), correction=smooth_field(5))
    q = pixels(300, 6)
    ideal = splined.undistort(q, K)
    assert np.abs(splined.distort(ideal, K) - q).max() < 1e-8
    rays = splined.rays_from_pixels(q, K)
    assert np.abs(splined.project_rays(rays, K) - q).max() < 1e-8
    # the field moves the parametric model's pixel by F(q0)
    q0 = lens.distort(ideal, K)
    assert np.abs(q - (q0 + splined.correction.evaluate(q0))).max() < 1e-8
    assert not splined.is_identity and splined.has_correction
    assert splined.without_correction() == lens


def test_rig_file_round_trip_and_refusals():
    splined = Distortion("kannala-brandt", {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0}, correction=smooth_field(7))
    again = Distortion.from_dict(splined.to_dict())
    assert again == splined
    assert np.array_equal(again.correction.coefficients, splined.correction.coefficients)
    with pytest.raises(CamcalError, match="no exact OpenCV distortion vector"):
        Distortion("opencv", {"k1": 0.1, "k2": 0, "p1": 0, "p2": 0, "k3": 0}, correction=smooth_field(7)).opencv_coefficients()
    bad = splined.to_dict()
    bad["correction"]["coefficients"][0][0][0] = float("nan")
    with pytest.raises(CamcalError, match="not all finite"):
        Distortion.from_dict(bad)
    with pytest.raises(CamcalError, match="shape"):
        SplineField(SIZE, np.zeros((3, 10, 2)))
    with pytest.raises(CamcalError, match="image_size"):
        SplineField.from_dict({"image_size": [1280.5, 960], "coefficients": [[[0, 0]] * 4] * 4})


def test_a_rig_file_keeps_the_field(tmp_path):
    from camcal.model.rig import Camera, Rig

    lens = Distortion("kannala-brandt", {"k1": -0.02, "k2": 0.01, "k3": 0.0, "k4": 0.0}, correction=smooth_field(8))
    Rig((Camera("wide", SIZE, K, lens, np.eye(3), np.zeros(3)),)).save(tmp_path / "rig.json")
    loaded = Rig.load(tmp_path / "rig.json").cameras[0]
    assert loaded.distortion == lens
    q = pixels(50, 9)
    assert np.array_equal(loaded.distortion.undistort(q, K), lens.undistort(q, K))
