"""The flat-field maths against a grey card and neutral patches rendered through a lens of known vignetting."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.colour.flatfield import (
    FlatField,
    apply_vignetting,
    common_radial_terms,
    correct_flat_field,
    fit_flat_field,
    half_diagonal,
    samples_from_images,
    samples_from_patches,
)
from flatfield_scenes import K_TRUE, SIZE, render_grey_card, true_flat


def frame_error(flat: FlatField, gain: np.ndarray) -> float:
    """Largest relative error of the fitted gain over the whole frame (corners included)."""
    return float(np.max(np.abs(flat.gain() / gain - 1.0)))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_grey_card_filling_80_percent_is_corrected_within_half_a_percent_over_the_frame(seed):
    """No mask: the wall around the card, the card's edge and the shot noise are the fit's to reject."""
    scene = render_grey_card(seed)
    flat = fit_flat_field(samples_from_images([scene.image]))
    assert frame_error(flat, scene.gain) < 0.005
    np.testing.assert_allclose(flat.centre, true_flat().centre, atol=1.5)
    # the corrected card is flat: its block medians within 0.5 % of each other's median
    corrected = correct_flat_field(scene.image, flat)
    level = np.median(corrected[scene.card], axis=0)
    np.testing.assert_allclose(level, [0.36, 0.40, 0.32], rtol=0.003)
    # the reported uncertainty covers the error seen (first order, from the samples' noise)
    assert frame_error(flat, scene.gain) < 5 * float(np.max(flat.gain_sigma_max)) + 0.001
    assert float(np.max(flat.residual_rms)) < 0.003 and flat.n_samples > 900


def test_a_mask_and_several_exposures_average_out():
    scenes = [render_grey_card(seed, exposure=exposure) for seed, exposure in ((2, 1.0), (3, 0.6))]
    flat = fit_flat_field(samples_from_images([s.image for s in scenes], [s.card for s in scenes]))
    assert frame_error(flat, scenes[0].gain) < 0.004 and flat.n_rejected == 0


def test_a_non_radial_falloff_needs_the_smooth_term():
    """A tilt of 4 % across the frame: the radial model misses it, degree 2 holds it."""
    scene = render_grey_card(4)
    width, height = SIZE
    u = (np.arange(width) - (width - 1) / 2) / half_diagonal(SIZE)
    tilt = np.exp(0.02 * u)[None, :, None]
    samples = samples_from_images([scene.image * tilt], [scene.card])
    assert frame_error(fit_flat_field(samples), scene.gain * tilt) > 0.006
    smooth = fit_flat_field(samples, smooth_degree=2)
    assert frame_error(smooth, scene.gain * tilt) < 0.005 and smooth.smooth.shape == (3, 5)


def test_neutral_patches_at_several_places_give_the_flat_field():
    """The six neutral patches of a ColorChecker in a row, the chart shot at 16 places (a 4 x 4 grid), each shot
    at its own exposure; 0.05 % noise on each patch value (a patch's mean over a few hundred pixels)."""
    rng = np.random.default_rng(5)
    truth = true_flat()
    reflectance = np.array([0.90, 0.59, 0.36, 0.19, 0.09, 0.03])
    xy, values, patch, shot = [], [], [], []
    width, height = SIZE
    places = [(x * width, y * height) for y in (0.05, 0.35, 0.65, 0.95) for x in (0.17, 0.39, 0.61, 0.83)]
    for s, (cx, cy) in enumerate(places):
        exposure = rng.uniform(0.6, 1.0)
        for p in range(6):
            here = np.array([[cx + (p - 2.5) * 0.063 * width, cy]])
            xy.append(here[0])
            values.append(exposure * reflectance[p] * np.array([0.9, 1.0, 0.8]) * truth.gain_at(here)[0]
                          * (1 + rng.normal(0, 0.0005, 3)))
            patch.append(f"neutral {p}")
            shot.append(s)
    samples = samples_from_patches(np.array(xy), np.array(values), np.array(patch), SIZE, shot=np.array(shot),
                                   sigma=0.0005)
    flat = fit_flat_field(samples, source="neutral patches")
    assert frame_error(flat, truth.gain()) < 0.005
    assert flat.source == "neutral patches" and flat.n_samples == 96 and flat.n_rejected == 0
    # the shots' exposures and the patches' values are not confused with the falloff: the residual is the noise
    assert float(np.max(flat.residual_rms)) < 0.0008
    np.testing.assert_allclose(flat.centre, truth.centre, atol=2.0)


def test_correction_and_its_inverse():
    flat = true_flat()
    image = np.random.default_rng(6).uniform(0.1, 0.9, (SIZE[1], SIZE[0], 3))
    np.testing.assert_allclose(correct_flat_field(apply_vignetting(image, flat), flat), image, rtol=1e-6)
    # 1 at the optical centre, the pa formula elsewhere
    np.testing.assert_allclose(flat.gain_at(flat.centre[None]), 1.0)
    corner = np.array([[0.0, 0.0]])
    r2 = np.sum((corner - flat.centre) ** 2) / half_diagonal(SIZE) ** 2
    np.testing.assert_allclose(flat.gain_at(corner)[0], 1 + K_TRUE @ [r2, r2**2, r2**3])
    # the same frame at half resolution: the same falloff at the same place
    half = flat.gain((SIZE[0] // 2, SIZE[1] // 2))
    np.testing.assert_allclose(half[100, 150], flat.gain_at(np.array([[300.5, 200.5]]))[0], rtol=1e-6)
    with pytest.raises(CamcalError, match="another aspect ratio"):
        flat.gain((400, 400))


def test_one_falloff_for_every_channel_says_what_it_misses():
    same = true_flat(np.tile(K_TRUE[1], (3, 1)))
    terms = common_radial_terms(same)
    np.testing.assert_allclose(terms.k, K_TRUE[1], atol=1e-9)
    assert terms.max_deviation < 1e-9
    shaded = common_radial_terms(true_flat())
    gain = true_flat().gain()
    assert shaded.max_deviation > 0.02  # red falls off faster than blue
    assert shaded.max_deviation == pytest.approx(np.max(np.abs(gain / gain.mean(axis=2, keepdims=True) - 1)), rel=0.1)


def test_the_file_content_round_trips_and_is_checked():
    flat = fit_flat_field(samples_from_images([render_grey_card(7).image]), smooth_degree=1)
    again = FlatField.from_dict(flat.to_dict())
    np.testing.assert_array_equal(again.gain(), flat.gain())
    assert again.to_dict() == flat.to_dict()
    data = flat.to_dict()
    for change, message in [
        (lambda d: d.update(extra=1), "unknown key 'extra'"),
        (lambda d: d.update(format="camcal rig"), "is not 'camcal flat field'"),
        (lambda d: d["model"].update(k=[[-3.0, 0, 0]] * 3), "gain falls to"),
        (lambda d: d["model"].update(smooth=[[0.0]] * 3), "model.smooth"),
        (lambda d: d.update(image_size=[600.5, 400]), "image_size"),
        (lambda d: d["model"].update(radial="poly"), "model.radial"),
    ]:
        broken = FlatField.from_dict(data).to_dict()
        change(broken)
        with pytest.raises(CamcalError, match=message):
            FlatField.from_dict(broken)


def test_bad_samples_are_refused_in_one_line():
    scene = render_grey_card(8)
    with pytest.raises(CamcalError, match="differ in size: a.exr is 960x640 px, b.exr is 480x320 px"):
        samples_from_images([scene.image, scene.image[::2, ::2]], names=["a.exr", "b.exr"])
    with pytest.raises(CamcalError, match="too dark for a flat field"):
        samples_from_images([np.zeros_like(scene.image)])
    dark = np.random.default_rng(9).normal(0.001, 0.002, scene.image.shape)  # a lens cap: black and noise
    with pytest.raises(CamcalError, match="too dark for a flat field"):
        samples_from_images([dark])
    centre_only = np.zeros(scene.card.shape, bool)
    centre_only[240:400, 400:560] = True
    with pytest.raises(CamcalError, match=r"reach 0\.1\d of the half diagonal"):
        fit_flat_field(samples_from_images([scene.image], [centre_only]))
    with pytest.raises(CamcalError, match="too few samples"):
        fit_flat_field(samples_from_patches(np.array([[0.0, 0.0], [959.0, 639.0]]), np.ones((2, 3)), [0, 0], SIZE))
    with pytest.raises(CamcalError, match="<= 0"):
        samples_from_patches(np.zeros((1, 2)), np.zeros((1, 3)), [0], SIZE)


@pytest.mark.slow
def test_the_reported_gain_sigma_matches_the_scatter_over_noisy_renders():
    """Twenty renders, twenty fits: the scatter of the corner gain against the sigma each fit reported."""
    errors, sigmas = [], []
    for seed in range(20):
        scene = render_grey_card(100 + seed, electrons=5000)
        flat = fit_flat_field(samples_from_images([scene.image], [scene.card]))
        errors.append(flat.gain_at(np.zeros((1, 2)))[0] / scene.gain[0, 0] - 1)
        sigmas.append(flat.gain_sigma_max)
    ratio = np.std(errors, axis=0) / np.mean(sigmas, axis=0)
    assert np.all((ratio > 0.4) & (ratio < 2.0)), ratio


def test_a_wall_that_matches_the_card_in_one_channel_is_not_the_card():
    """A neutral wall around a warm card: equal in green, brighter in red and blue, at the edges of the frame
    where a free falloff could bend to it. The middle of the frame is fitted first; the wall is rejected."""
    scene = render_grey_card(16)
    rng = np.random.default_rng(16)
    wall = rng.poisson(0.40 * scene.gain * 20000) / 20000
    samples = samples_from_images([np.where(scene.card[..., None], scene.image, wall)])
    flat = fit_flat_field(samples)
    assert frame_error(flat, scene.gain) < 0.005 and flat.n_rejected > 150


def test_natural_vignetting_outside_the_radial_family_is_held_with_the_smooth_term():
    """cos^4 of the field angle (no lens was asked to fit it: 1 / (1 + r^2 / f^2)^2, the half diagonal seen at
    30 deg, corners at 0.54): the three radial terms fitted on the card extrapolate to the corners 1.3 % off,
    the smooth term of degree 2 holds the whole frame within 0.5 %."""
    width, height = size = (480, 320)
    f = np.hypot(width, height) / 2 / np.tan(np.radians(30.0))
    centre = true_flat(size=size).centre
    x, y = np.meshgrid(np.arange(width), np.arange(height))
    gain = np.repeat((1.0 / (1.0 + ((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / f**2) ** 2)[..., None], 3, axis=2)
    scene = render_grey_card(5, size=size)
    image = scene.image / scene.gain * gain  # the same card and wall, this falloff (noise scaled with it)
    samples = samples_from_images([image])
    radial = frame_error(fit_flat_field(samples), gain)
    smooth = fit_flat_field(samples, smooth_degree=2)
    assert 0.008 < radial < 0.03
    assert frame_error(smooth, gain) < 0.005
    np.testing.assert_allclose(smooth.centre, centre, atol=2.0)
