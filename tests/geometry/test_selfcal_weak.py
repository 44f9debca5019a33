"""Sigmas that cover on weak geometry (issue 28): a stereo rig sliding sideways over a few positions, no roll,
principal points off the image centre, features found by SIFT in rendered images."""

import contextlib
import io

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.synthetic import example_stereo_rig, lateral_rig_poses, orbit_set_planes, procedural_texture, render_rig_poses


def lateral_scene(seed):
    """A rendered lateral stereo rig drawn per seed: 384-512 px wide, principal points 4-8 px off-centre,
    a mild division lens, 5-7 positions 0.15-0.35 m apart, yaw and pitch within 0.5 degree, no roll."""
    rng = np.random.default_rng(900 + seed)
    width = int(rng.choice([384, 448, 512]))
    angle = rng.uniform(0, 2 * np.pi, 2)
    radius = rng.uniform(4, 8, 2)
    rig = dict(image_size=(width, width * 3 // 4), f=float(rng.uniform(0.65, 0.95) * width),
               pp_offsets=np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1),
               lam=tuple(rng.uniform(-1.5e-7, -0.2e-7, 2) * (640 / width) ** 2), rig_euler_deg=rng.uniform(-3, 3, 3),
               baseline=float(rng.uniform(0.15, 0.4)), focal_ratio=float(rng.uniform(0.985, 1.015)))
    path = dict(n_frames=int(rng.integers(5, 8)), step=float(rng.uniform(0.15, 0.35)),
                distance=float(rng.uniform(2.2, 3.0)), image_noise=float(rng.uniform(0, 3)), seed=seed)
    return rig, path


def render_lateral(root, seed):
    rig, path = lateral_scene(seed)
    cameras = example_stereo_rig(**rig)
    rng = np.random.default_rng(path["seed"])
    planes = orbit_set_planes(rng)
    textures = tuple(procedural_texture(rng) for _ in planes)
    poses = lateral_rig_poses(rng, path["n_frames"], path["step"], path["distance"], jitter_deg=0.5)
    render_rig_poses(root, cameras, poses, planes, textures, path["image_noise"], rng)
    return cameras, path


def focal_error(camera, truth):
    """The mean relative error of fx and fy."""
    return 0.5 * (abs(camera.K[0, 0] / truth.K[0, 0] - 1) + abs(camera.K[1, 1] / truth.K[1, 1] - 1))


@pytest.mark.slow
def test_sigmas_cover_the_error_on_lateral_few_frame_rigs(tmp_path):
    """Over 20 rendered lateral rigs, |error| < 2 sigma for fx, fy, cx, cy of both cameras in >= 90 % of cases,
    and a mean focal error (of fx and fy) no larger than plain pycolmap's (SIMPLE_DIVISION per folder, principal
    point refined).

    Seeds 0-19 (scenes where COLMAP's mapper registers nothing are drawn again, up to 4): the constants
    of the priors come from sensors and lenses (camcal.geometry.bundle.prior), not from these scenes.
    Measured with fx and fy refined apart under the square-pixel prior (seeds 0-19, all mapped; 63 min on a
    loaded machine): 156 / 160 = 97.5 % of fx, fy, cx, cy within 2 sigma (RMS error / sigma 0.87), mean focal error
    (fx and fy) camcal 0.334 %, plain pycolmap 0.518 %; the misses: seed 8's fx and fy in both cameras (+1.68 /
    +2.39 px, 3.3-3.6 sigma: a scale shared by the rig that the delete-one-frame jackknife over 6 frames does not
    see). Before fx and fy were freed (one focal length f): 116 / 120 = 96.7 %, 0.312 % against 0.510 %.
    Since square pixels are held where the motion does not determine the aspect (selfcal.aspect_visibility: these
    slides move the images by 0.009-0.016 px per 1 % of fx - fy, so every one is held, the prior's spread of
    fx - fy carried to every parameter that re-adjusts with it, the jackknife's replicates refitted under the
    prior; seeds 0-19, all mapped, 11 min): 158 / 160 = 98.8 % within 2 sigma (RMS error / sigma 0.47), mean focal
    error camcal 0.312 %, plain pycolmap 0.512 %; the misses: seed 8's fx in both cameras (2.2 and 2.3 sigma).
    With fx and fy alone widened (by +-0.5 % of f each): also 98.8 %, RMS error / sigma 0.72, but the long-lens
    test below failed (seed 2's principal point)."""
    from camcal.pipelines.solve import solve_pycolmap_plain, solve_sfm

    ratios, ours, theirs, failed = [], [], [], []
    seed = 0
    while len(ours) < 40 and len(failed) <= 4:
        cameras, path = render_lateral(tmp_path / f"in{seed}", seed)
        folders = {c.name: tmp_path / f"in{seed}" / c.name for c in cameras}
        try:
            with contextlib.redirect_stderr(io.StringIO()):
                result = solve_sfm(folders, tmp_path / f"out{seed}", max_num_features=4096, seed=seed)
                peer = solve_pycolmap_plain(folders, tmp_path / f"peer{seed}", seed=seed)
        except CamcalError as error:  # the mapper found no initial pair: a scene, not a calibration
            failed.append(f"seed {seed}: {error}")
            seed += 1
            continue
        row = []
        for truth in cameras:
            solved = result.rig.camera(truth.name)
            for key, error in (("fx", solved.K[0, 0] - truth.K[0, 0]), ("fy", solved.K[1, 1] - truth.K[1, 1]),
                               ("cx", solved.K[0, 2] - truth.K[0, 2]), ("cy", solved.K[1, 2] - truth.K[1, 2])):
                sigma = result.bundle.sigmas[f"{truth.name}.{key}"]
                ratios.append(abs(error) / sigma)
                row.append(f"{truth.name}.{key} {error:+.3f}/{sigma:.3f}")
            ours.append(focal_error(solved, truth))
            theirs.append(focal_error(peer.cameras[truth.name], truth))
        print(f"seed {seed} ({path['n_frames']} positions): error/sigma px " + ", ".join(row)
              + f"; focal error camcal {100 * np.mean(ours[-2:]):.3f} %, pycolmap {100 * np.mean(theirs[-2:]):.3f} %")
        seed += 1
    ratios = np.asarray(ratios)
    print(f"coverage: {np.sum(ratios < 2)} / {len(ratios)} = {100 * np.mean(ratios < 2):.1f} % within 2 sigma, "
          f"RMS error/sigma {np.sqrt(np.mean(ratios ** 2)):.2f}; mean focal error camcal {100 * np.mean(ours):.3f} %, "
          f"plain pycolmap {100 * np.mean(theirs):.3f} %; not mapped: {failed}")
    assert len(ours) == 40 and len(ratios) == 160
    assert np.mean(ratios < 2) >= 0.9
    assert np.mean(ours) <= np.mean(theirs)


def long_lens_scene(seed):
    """The scene of the original report, made harder: a 960 x 720 stereo rig with a long lens (f 1.25-1.45 image
    widths), principal points 4-7 px off-centre, sliding sideways over 7 positions 0.25 m apart, no roll, no yaw
    or pitch, in front of a set without boxes (the back wall and a strip of floor: little depth)."""
    rng = np.random.default_rng(700 + seed)
    angle, radius = rng.uniform(0, 2 * np.pi, 2), rng.uniform(4, 7, 2)
    rig = dict(image_size=(960, 720), f=float(rng.uniform(1.25, 1.45) * 960),
               pp_offsets=np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1),
               lam=(-0.4e-7, -0.4e-7), rig_euler_deg=rng.uniform(-2, 2, 3), baseline=0.3, focal_ratio=1.01)
    return example_stereo_rig(**rig)


def render_long_lens(root, seed):
    cameras = long_lens_scene(seed)
    rng = np.random.default_rng(seed)
    planes = orbit_set_planes(rng, n_boxes=0)
    textures = tuple(procedural_texture(rng) for _ in planes)
    poses = lateral_rig_poses(rng, 7, 0.25, 2.5, jitter_deg=0.0)
    render_rig_poses(root, cameras, poses, planes, textures, 1.0, rng)
    return cameras


def covered_or_said(result, cameras):
    """Per camera and intrinsic (fx, fy, cx, cy): its error, its sigma, and whether |error| < 2 sigma or the
    solve says in one line that the images barely determine it."""
    lines = result.self_calibration.lines()
    rows = []
    for truth in cameras:
        solved = result.rig.camera(truth.name)
        decision = next(d for d in result.self_calibration.principal_point if d.camera == truth.name)
        for key, error in (("fx", solved.K[0, 0] - truth.K[0, 0]), ("fy", solved.K[1, 1] - truth.K[1, 1]),
                           ("cx", solved.K[0, 2] - truth.K[0, 2]), ("cy", solved.K[1, 2] - truth.K[1, 2])):
            sigma = result.bundle.sigmas[f"{truth.name}.{key}"]
            said = (any(line.startswith(f"{truth.name}.{key}: the images barely determine it: ") for line in lines)
                    if key in ("fx", "fy") else not decision.determined)
            rows.append((f"{truth.name}.{key}", error, sigma, abs(error) < 2 * sigma or said, said))
    return rows


@pytest.mark.slow
def test_long_lens_lateral_slide_sigma_covers_or_says_the_images_cannot_tell(tmp_path):
    """The original report (focal errors 3.9-8.8 % with a printed sigma of 1.7 %), harder: on three seeded long-lens
    lateral slides before little depth, every fx, fy, cx, cy of both cameras lies within 2 sigma of the truth, or the
    solve says in one line that the images barely determine it (with the sigma).
    Measured with fx and fy refined apart (seeds 0-2, 53 min on a loaded machine): every fx and fy said
    undetermined (errors +9 to +86 px against sigmas 79-186 px, 6-14 % of f); principal points within 1.5 sigma
    (cx -2.4 to +2.1 px against 1.8-7.4 px, cy -15 to +29 px against 5.4-23 px: cy now shares the weak
    direction of fy). Before fx and fy were freed, seed 0: f +25.6 / +37.7 px against sigma 149 / 141 px (said),
    principal points (-1.9, +3.2) / (-0.3, -0.4) px against sigma (1.3, 3.0) / (2.7, 4.2) px."""
    from camcal.pipelines.solve import solve_sfm

    failures, report = [], []
    for seed in range(3):
        cameras = render_long_lens(tmp_path / f"in{seed}", seed)
        folders = {c.name: tmp_path / f"in{seed}" / c.name for c in cameras}
        with contextlib.redirect_stderr(io.StringIO()):
            result = solve_sfm(folders, tmp_path / f"out{seed}", seed=seed)
        rows = covered_or_said(result, cameras)
        report.append(f"seed {seed}: " + ", ".join(f"{name} {error:+.2f}/{sigma:.2f}{' (said)' if said else ''}"
                                                   for name, error, sigma, _, said in rows))
        failures += [f"seed {seed} {name}" for name, _, _, ok, _ in rows if not ok]
    print("\n".join(report))
    assert not failures, (failures, report)
