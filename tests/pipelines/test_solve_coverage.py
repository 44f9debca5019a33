"""Projection sigma of `solve` rigs against the truth over seeded rendered scenes, in the scene gauge."""

from pathlib import Path

import numpy as np
import pytest

from camcal.geometry.uncertainty import projection_sigma, scene_gauge_rotation
from camcal.model.rig import Rig
from camcal.synthetic import example_stereo_rig, render_rig_orbit


def solve_scene(seed: int, frames: tuple[int, int] | None = None) -> tuple[tuple, dict]:
    """A rendered orbit drawn per seed: one moving camera (even seeds) or a moving stereo rig (odd seeds),
    image size, focal, principal points, division lens, rig, motion, image noise; small (320-384 px wide,
    6-8 frames for the rig, 10-12 for one camera) so that a solve takes seconds. ``frames`` (lo, hi): the
    same scene but for its number of frames, drawn in [lo, hi] apart from the rest (seed 1700 + seed)."""
    rng = np.random.default_rng(700 + seed)
    width = int(rng.choice([320, 384]))
    cameras = example_stereo_rig(image_size=(width, width * 3 // 4), f=float(rng.uniform(0.65, 0.95) * width),
                                 pp_offsets=rng.uniform(-5, 5, (2, 2)),
                                 lam=tuple(rng.uniform(-5e-7, -0.5e-7, 2) * (640 / width) ** 2),
                                 rig_euler_deg=rng.uniform(-3, 3, 3), baseline=float(rng.uniform(0.15, 0.4)),
                                 focal_ratio=float(rng.uniform(0.985, 1.015)))
    stereo = seed % 2 == 1
    # the orbit spans 240 degrees: one camera needs more frames than a rig to link them
    orbit = dict(n_frames=int(rng.integers(6, 9) if stereo else rng.integers(10, 13)),
                 roll_deg=float(rng.uniform(15, 35)), radius=float(rng.uniform(2.6, 3.4)),
                 image_noise=float(rng.uniform(0, 3)), seed=seed)
    if frames is not None:
        orbit["n_frames"] = int(np.random.default_rng(1700 + seed).integers(frames[0], frames[1] + 1))
    return (cameras if stereo else cameras[:1]), orbit


def scene_gauge_error(rig: Rig, truth: dict, cameras: tuple, name: str, pixels: np.ndarray) -> np.ndarray:
    """True projection error (pixels) of the rays at infinity through ``pixels`` of camera ``name``, in the
    scene gauge: the estimated rig frame carried into the true one by
    :func:`camcal.geometry.uncertainty.scene_gauge_rotation` over the solved frames (each matched to its
    rendered frame by its image's file name), then into the true camera by its true ``cam_from_rig``."""
    reference = cameras[0].name
    estimated_R, true_R = [], []
    for frame in rig.frames:
        index = int(Path(next(iter(frame.images.values()))).stem)
        estimated_R.append(frame.R)
        true_R.append(truth[reference, index].R)  # the reference camera is the rig frame
    G = scene_gauge_rotation(true_R, estimated_R)
    estimated = rig.camera(name)
    true = next(camera for camera in cameras if camera.name == name)
    rays = estimated.distortion.rays_from_pixels(pixels, estimated.K) @ estimated.R  # into the estimated rig frame
    rays = rays @ G.T @ true.R.T
    return np.linalg.norm(true.distortion.project_rays(rays, true.K) - pixels, axis=1)


def scene_ratios(rig: Rig, truth: dict, cameras: tuple, grid=(9, 7)) -> dict[str, np.ndarray]:
    """Camera name -> |error| / sigma at a grid of its frame (rays at infinity, scene gauge)."""
    out = {}
    for camera in cameras:
        width, height = camera.image_size
        gx, gy = np.meshgrid(np.linspace(0, width - 1, grid[0]), np.linspace(0, height - 1, grid[1]))
        pixels = np.column_stack([gx.ravel(), gy.ravel()])
        error = scene_gauge_error(rig, truth, cameras, camera.name, pixels)
        out[camera.name] = error / projection_sigma(rig.camera(camera.name), pixels)
    return out


def run_scene(seed: int, folder: Path, frames: tuple[int, int] | None = None, **options):
    """Render and solve seed ``seed``'s scene (:func:`solve_scene`; ``options``: more of :func:`solve_sfm`'s);
    returns the scene, its orbit, the truth and the solve's result."""
    from camcal.pipelines.solve import solve_sfm

    cameras, orbit = solve_scene(seed, frames)
    truth = render_rig_orbit(folder / "in", cameras, **orbit)
    result = solve_sfm({c.name: folder / "in" / c.name for c in cameras}, folder / "out", max_num_features=2048,
                       seed=seed, num_threads=1, **options)
    return cameras, orbit, truth, result


#: A 2-D Gaussian error exceeds this many worst-direction sigmas with probability 0.27 %.
CHI2_9973 = float(np.sqrt(-2.0 * np.log(0.0027)))


def test_solve_rig_carries_the_scene_gauge_and_its_sigma_bounds_the_error(tmp_path):
    """One rendered orbit of one camera (seed 0): the rig's covariance has the scene gauge, and the true error
    of rays at infinity in it stays within 3.44 sigma RMS over the frame (one draw; the coverage over seeded
    scenes is the slow test below)."""
    cameras, _, truth, result = run_scene(0, tmp_path)
    camera = result.rig.camera("left")
    assert {"gauge_rx", "gauge_ry", "gauge_rz"} <= set(camera.quality.covariance.names)
    ratios = scene_ratios(result.rig, truth, cameras)["left"]
    print(f"seed 0: error/sigma RMS {np.sqrt(np.mean(ratios**2)):.2f}, median {np.median(ratios):.2f}")
    assert np.sqrt(np.mean(ratios**2)) < CHI2_9973


def coverage(seeds, folder: Path, frames: tuple[int, int] | None = None) -> tuple[float, float]:
    """Share of sampled pixels with |error| < 2 sigma and the median error / sigma over the seeded scenes (every
    camera of each), each scene's figures printed; each rig must carry the scene gauge it is judged in."""
    ratios = []
    for seed in seeds:
        cameras, orbit, truth, result = run_scene(seed, folder / f"scene{seed}", frames)
        for name, r in scene_ratios(result.rig, truth, cameras).items():
            assert "gauge_rx" in result.rig.camera(name).quality.covariance.names, (seed, name)
            print(f"seed {seed} {name} ({orbit['n_frames']} frames, {len(result.rig.frames)} registered): "
                  f"within 2 sigma {100 * np.mean(r < 2):.0f} %, median error/sigma {np.median(r):.2f}")
            ratios.append(r)
    ratios = np.concatenate(ratios)
    return float(np.mean(ratios < 2.0)), float(np.median(ratios))


#: frames of the must-show's orbits: what a solve is given, not the handful that keeps the fast test fast
ORBIT_FRAMES = (18, 24)


@pytest.mark.slow
def test_solve_sigma_covers_the_error_over_seeded_scenes(tmp_path):
    """Must-show (issue 30): over 20 seeded rendered orbits of 18-24 frames (even seeds one moving camera, odd
    seeds a moving stereo rig), |error| < 2 sigma at >= 90 % of sampled pixels and median error / sigma >= 0.5,
    rays at infinity in the scene gauge (:func:`camcal.geometry.uncertainty.scene_gauge_rotation`); on seeds
    0-19 and on 24 more (24-47). Measured: 97.1 % / 0.71 and 92.3 % / 0.61; fresh seeds 96-119 (run once,
    after): 91.3 % / 0.78. With the frames' influences taken over the jackknife's groups (pairs of frames past
    20 frames) instead of single frames: seeds 0-19 97.0 % / 0.71. The covariance alone: 86.1 % / 1.03, 83.7 % / 1.01 and 80.2 % / 1.18 (the
    features' errors are correlated within an image: the frame jackknife's design effect, 1.0-4.6 here,
    covers it)."""
    figures = {}
    for label, seeds in (("seeds 0-19", range(20)), ("seeds 24-47", range(24, 48))):
        figures[label] = coverage(seeds, tmp_path, ORBIT_FRAMES)
        print(f"solve, scene gauge, {label}: {100 * figures[label][0]:.1f} % within 2 sigma, median error/sigma "
              f"{figures[label][1]:.2f}")
    assert all(inside >= 0.9 and median >= 0.5 for inside, median in figures.values())


@pytest.mark.slow
def test_solve_sigma_on_short_orbits_errs_wide_never_narrow(tmp_path):
    """The same scenes cut to 6-8 frames (stereo rigs) and 10-12 (one camera): the sigma still covers >= 90 % of
    sampled pixels, but it is wide. Measured: seeds 0-19 97.7 % within 2 sigma, median error / sigma 0.41; seeds
    24-47 92.8 % / 0.32. Two causes. (1) The stereo rigs whose motion does not determine fx - fy hold square
    pixels and carry the aspect prior's spread (fx - fy ~ N(0, 1 % of f)) while these scenes' pixels are
    exactly square, the prior's mean (seeds 3, 5, 7, 13, 33, 37, 43: median 0.13-0.25); no posterior sigma is
    calibrated against a truth held at its prior's mean (drawn from the prior instead: 97.0 % / 0.43 on seeds
    24-47). (2) With 6-8 frames the delete-one-frame jackknife's design effect is unstable: one frame linking the
    others turns the scene gauge by 1.8 degrees when left out (seeds 29 and 47: design effect 140-210, where the
    covariance alone gives a median of 0.84-1.47). With 18-24 frames neither happens (the must-show above)."""
    inside, median = coverage(range(24, 48), tmp_path)
    print(f"solve, short orbits, seeds 24-47: {100 * inside:.1f} % within 2 sigma, median error/sigma {median:.2f}")
    assert inside >= 0.9
