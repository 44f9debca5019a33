"""The conversion core: a dense-grid refit of any camcal camera to a lens family, its residual figures checked
against an independent evaluation (random pixels, through distort / undistort instead of rays), exact where the
family holds the lens, and the one table of what goes exactly where."""

import dataclasses

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.conversion import EXACT_FAMILIES, FORMAT_FAMILIES, exactness_table, refit_camera
from camcal.io.interchange import format_of
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

from interchange_rigs import division_rig, fisheye_rig, stereo_rig


def random_pixels(camera, overscan, n=20000, seed=5):
    """Random distorted pixels inside the image and in the border of the frame scaled by ``overscan``: uniform, and
    as many again on the edges of both (where a lens' residual peaks), corners included."""
    rng = np.random.default_rng(seed)
    width, height = camera.image_size
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    edges = []
    for half in (np.array([(width - 1) / 2, (height - 1) / 2]), np.array([width, height]) / 2 * overscan):
        t = rng.uniform(-1, 1, n // 4)
        edges += [np.column_stack([t, np.full_like(t, side)]) * half for side in (-1, 1)]
        edges += [np.column_stack([np.full_like(t, side), t]) * half for side in (-1, 1)]
        edges.append(np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]]) * half)
    half = np.array([width / 2 * overscan, height / 2 * overscan])
    points = centre + np.concatenate([rng.uniform(-1, 1, (n, 2)) * half, *edges])
    inside = (points[:, 0] >= -1e-9) & (points[:, 0] <= width - 1 + 1e-9) & (points[:, 1] >= -1e-9) & (
        points[:, 1] <= height - 1 + 1e-9)
    uniform = np.arange(len(points)) < n  # the RMS is over these
    return points, inside, uniform


def independent_distances(source, target, points):
    """|target(ray) - x| for distorted pixels x, through the pinhole pixels (undistort, K, distort)."""
    ideal = source.distortion.undistort(points, source.K)
    rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(source.K).T
    mapped = rays @ target.K.T
    projected = target.distortion.distort(mapped[:, :2] / mapped[:, 2:], target.K)
    return np.linalg.norm(projected - points, axis=1)


@pytest.mark.parametrize("source, family", [
    (stereo_rig(rectified=False).cameras[0], "division"),
    (stereo_rig(rectified=False).cameras[0], "polynomial"),
    (division_rig().cameras[0], "opencv"),
])
def test_refit_figures_are_the_true_residual(source, family):
    converted, refit = refit_camera(source, family)
    assert not refit.exact and converted.distortion.model == family
    points, inside, uniform = random_pixels(source, refit.overscan)
    distances = independent_distances(source, converted, points)
    ok = np.isfinite(distances)
    inner, border = distances[inside & ok], distances[~inside & ok]
    inner_rms = np.sqrt(np.mean(distances[inside & ok & uniform] ** 2))
    border_rms = np.sqrt(np.mean(distances[~inside & ok & uniform] ** 2))
    print(f"{source.distortion.model} -> {family}: printed {refit.describe()}; random pixels: inside max "
          f"{inner.max():.4g} RMS {inner_rms:.4g}, border max {border.max():.4g} RMS {border_rms:.4g}")
    # the printed figures are over a 13 px grid, these over random pixels: the maxima to a few per cent, the RMS
    # (the grid samples the thin border band less evenly) to 10 %
    assert refit.max_px == pytest.approx(inner.max(), rel=0.05)
    assert refit.border_max_px == pytest.approx(border.max(), rel=0.05)
    assert refit.rms_px == pytest.approx(inner_rms, rel=0.1)
    assert refit.border_rms_px == pytest.approx(border_rms, rel=0.1)
    assert refit.border_max_px > refit.max_px  # extrapolating past the image costs more


@pytest.mark.parametrize("source, family", [
    (stereo_rig(rectified=False).cameras[0], "opencv"),
    (dataclasses.replace(stereo_rig(rectified=False).cameras[0],
                         distortion=Distortion("polynomial", {"k1": -0.1, "k2": 0.02, "k3": 0.001})), "opencv"),
    (fisheye_rig(rectified=False).cameras[0], "kannala-brandt-thin-prism"),
    (dataclasses.replace(division_rig().cameras[0], distortion=Distortion.none()), "polynomial"),
])
def test_refit_is_exact_where_the_family_holds_the_lens(source, family):
    converted, refit = refit_camera(source, family)
    print(f"{source.distortion.model} -> {family}: {refit.describe()}")
    assert refit.exact and converted.distortion.model == family
    assert refit.max_px < 1e-6 and refit.border_max_px < 1e-6
    points, inside, _ = random_pixels(source, refit.overscan, n=2000)
    assert np.nanmax(independent_distances(source, converted, points[inside])) < 1e-6


def test_a_fisheye_refit_to_a_rectilinear_family_counts_what_it_loses():
    """Rays beyond 90 degrees have no pinhole image: the refit says how many grid pixels it cannot image."""
    source = fisheye_rig(rectified=False).cameras[0]
    _, refit = refit_camera(source, "opencv")
    assert refit.n_lost > 0 and "not imaged" in refit.describe()


def test_the_exactness_table_is_the_families_table():
    table = exactness_table().splitlines()
    header, rows = table[0].split(), {line.split()[0]: line.split()[1:] for line in table[1:11]}
    formats = header[2:]
    assert formats == list(FORMAT_FAMILIES)
    for model, cells in rows.items():
        for fmt, cell in zip(formats, cells):
            held = any(model in EXACT_FAMILIES[family] for family in FORMAT_FAMILIES[fmt])
            assert cell == ("exact" if held else "refit"), (model, fmt)
    assert rows["opencv"][formats.index("opencv")] == "exact" and rows["opencv"][formats.index("3de")] == "refit"


def test_rig_export_help_prints_the_table(capsys):
    with pytest.raises(SystemExit):
        main(["rig", "export", "--help"])
    out = capsys.readouterr().out
    assert exactness_table().splitlines()[1] in out and "3de4-anamorphic-deg4" in out


def test_refit_rejects_a_bad_overscan_and_an_unknown_family():
    camera = stereo_rig(rectified=False).cameras[0]
    with pytest.raises(CamcalError, match="overscan must be a number >= 1"):
        refit_camera(camera, "division", overscan=0.5)
    with pytest.raises(CamcalError, match="unknown lens family 'brown'"):
        refit_camera(camera, "brown")


@pytest.mark.parametrize("name, fmt", [("shot.nk", "nuke"), ("a.usda", "usd"), ("a.USDC", "usd"), ("a.usd", "usd"),
                                       ("lens.txt", "3de")])
def test_the_format_is_read_from_the_file_name(name, fmt):
    assert format_of(name) == fmt
    assert format_of(name, "opencv") == "opencv"


def test_an_ambiguous_file_name_asks_for_the_format():
    with pytest.raises(CamcalError, match="cannot tell the format of 'cam.yaml'"):
        format_of("cam.yaml")


#: A wide OpenCV rational lens (k1..k6 and thin prism) at 320x240, f = 260 px: its radial function turns over at
#: about 54 degrees, inside the 1.25 overscan border.
WIDE_RATIONAL = Distortion("opencv", {"k1": -0.21, "k2": 0.04, "p1": 8e-4, "p2": -1.2e-3, "k3": -0.004, "k4": 0.05,
                                      "k5": 0.012, "k6": 0.002, "s1": 1.1e-3, "s2": -4e-4})
WIDE_K = np.array([[260.0, 0.0, 166.3], [0.0, 260.0, 114.6], [0.0, 0.0, 1.0]])
BROWN_ONLY = dict.fromkeys(("k4", "k5", "k6", "s1", "s2", "s3", "s4"), 0.0)


def radial_fold(distortion, samples=200001):
    """The normalised undistorted radius at which the lens' radial function r (1 + k1 r^2 + ...) / (1 + k4 r^2 +
    ...) stops growing (the tangential and prism terms, 1e-3 here, left out)."""
    p = distortion.params
    r = np.linspace(0.0, 5.0, samples)
    r2 = r * r
    numerator = 1 + r2 * (p["k1"] + r2 * (p["k2"] + r2 * p["k3"]))
    radial = r * numerator / (1 + r2 * (p["k4"] + r2 * (p["k5"] + r2 * p["k6"])))
    return r[np.argmax(np.diff(radial) <= 0)]


def test_a_wide_rational_lens_refit_is_no_worse_inside_the_image_than_the_image_only_fit():
    """The rational lens folds in the 1.25 overscan border: the border beyond the fold leaves the fit (it dragged
    the fit to 38.8 px max inside the image), and the figures say how much of the border was usable."""
    from camcal.model.distortion import fit_distortion

    source = Camera("wide", (320, 240), WIDE_K, WIDE_RATIONAL, np.eye(3), np.zeros(3))
    image_only = fit_distortion(WIDE_RATIONAL, WIDE_K, source.image_size, "opencv")
    converted, refit = refit_camera(source, "opencv", fixed=BROWN_ONLY)
    print(f"image only: max {image_only.max_px:.4g} px, RMS {image_only.rms_px:.4g} px; refit: {refit.describe()}")
    assert refit.overscan == 1.25 and converted.distortion.model == "opencv"
    assert refit.rms_px <= 1.05 * image_only.rms_px and refit.max_px <= 1.05 * image_only.max_px
    # independently: random pixels whose ray lies inside the radial function's fold
    points, inside, uniform = random_pixels(source, refit.overscan)
    ideal = WIDE_RATIONAL.undistort(points, WIDE_K)
    radius = np.linalg.norm((ideal - WIDE_K[:2, 2]) / 260.0, axis=1)
    back = WIDE_RATIONAL.distort(ideal, WIDE_K)
    usable = (radius < radial_fold(WIDE_RATIONAL)) & (np.linalg.norm(back - points, axis=1) < 1e-3)
    assert np.all(usable[inside])
    distances = independent_distances(source, converted, points)
    border = ~inside & usable
    border_rms = np.sqrt(np.mean(distances[border & uniform] ** 2))
    inner_rms = np.sqrt(np.mean(distances[inside & uniform] ** 2))
    print(f"random pixels: inside max {distances[inside].max():.4g} RMS {inner_rms:.4g}, border max "
          f"{distances[border].max():.4g} RMS {border_rms:.4g}, {border[uniform].sum() / (~inside[uniform]).sum():.3f}"
          " of the border usable")
    assert refit.max_px == pytest.approx(distances[inside].max(), rel=0.05)
    assert refit.rms_px == pytest.approx(inner_rms, rel=0.1)
    # the border max sits at the fold, where the residual climbs fast: the 3.3 px grid stops short of it by up to
    # a grid step, the random pixels do not
    assert refit.border_max_px == pytest.approx(distances[border].max(), rel=0.1)
    assert refit.border_rms_px == pytest.approx(border_rms, rel=0.1)
    assert refit.border_usable == pytest.approx(border[uniform].sum() / (~inside[uniform]).sum(), abs=0.02)
    assert 0.5 < refit.border_usable < 1.0 and "inside the source lens' fold" in refit.describe()


def test_a_lens_that_turns_over_inside_its_frame_is_measured_and_fitted_inside_its_fold_only():
    """An OpenCV lens (k1 -0.35, k2 0.03, f 500 px on 1280x960) whose distorted radius peaks at 0.683 f (341 px) and
    then falls: beyond it the frame's pixels are imaged by a ray past the fold only. Those pixels are left out of
    the figures and of the fit, and their share said; inside the fold the same family is exact and a family that
    holds the first branch fits it (before, the folded rays gave 1e14 px figures and spoiled every refit)."""
    K = np.array([[500.0, 0.0, 639.5], [0.0, 500.0, 479.5], [0.0, 0.0, 1.0]])
    camera = Camera("folding", (1280, 960), K,
                    Distortion("opencv", {"k1": -0.35, "k2": 0.03, "p1": 0.0, "p2": 0.0, "k3": 0.0}),
                    np.eye(3), np.zeros(3))
    r = np.linspace(0.0, 1.5, 3001)
    peak = 500.0 * np.max(r * (1 - 0.35 * r**2 + 0.03 * r**4))  # the first branch's largest distorted radius, px
    share = np.pi * peak**2 / (1280 * 960)  # the disc inside the fold, wholly inside the frame
    same, same_figures = refit_camera(camera, "polynomial")
    assert same_figures.exact is False and same_figures.max_px < 1e-9
    assert same_figures.image_usable == pytest.approx(share, abs=0.01)
    assert "inside the source lens' fold" in same_figures.describe()
    _, figures = refit_camera(camera, "kannala-brandt")
    assert figures.image_usable == pytest.approx(share, abs=0.01) and figures.rms_px < 0.01
