"""A 48-frame zoom and rack focus with its lens metadata, end to end: profile, ``camcal lens``, Blender, Nuke, 3DE.

The truth is a zoom lens whose focal length, principal point and
``polynomial`` distortion move smoothly with focal length and focus
(breathing: the focal length 3 % longer per dioptre of focus). Board corners
are projected through camcal's mapping of it at a few lens states (with
noise) and calibrated (the helpers of ``tests/geometry/test_lens_profile.py``);
the profile of those states turns the shot's metadata CSV (a zoom and a rack
focus, its frames between the calibrated states) into a rig with a lens per
frame (``camcal lens PROFILE --metadata shot.csv``), checked frame by frame:

- against the truth at that frame's state: within 2 of the profile's own
  projection sigma over 95 % of the image;
- in Blender (the add-on, headless): the camera's keyed focal length and shift
  project like ``camera_at_frame(...).project`` (pinhole part) to 1e-3 px,
  and the clip's tracking lens after the frame-change handler distorts like
  that frame's lens to 1e-3 px (Blender's POLYNOMIAL is camcal's ``polynomial``
  normalised by ``fx`` alone; the profile's ``fy / fx`` is 1 within 1e-4);
- the Nuke script and the 3DE lens file read back by camcal per frame: within
  what the export printed (:func:`check_exports` says what each cannot hold).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import camcal
from camcal.cli import main
from camcal.geometry.lens_profile import camera_at, projection_sigma_px
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.distortion import Distortion, frame_grid
from camcal.model.lens_profile import format_state
from camcal.model.rig import Camera, Rig

sys.path.insert(0, str(Path(__file__).resolve().parent / "geometry"))
sys.path.insert(0, str(Path(__file__).resolve().parent / "io"))
sys.path.insert(0, str(Path(__file__).resolve().parent / "addon"))
from addon_helpers import addon, blender_project, bpy, points_in_view  # noqa: E402, F401  (fixtures)
from test_lens_profile import BOARD, SIZE, board_views, calibrated  # noqa: E402
from test_addon_lens_animation import tracking_lens_now  # noqa: E402
from test_nuke_lens import strip_camcal_lens  # noqa: E402

#: The calibrated states (focal mm, focus m): the zoom's ends and middle, each near and far.
STATES = ((24.0, 1.0), (24.0, math.inf), (47.0, 1.0), (47.0, math.inf), (70.0, 1.0), (70.0, math.inf))
FIRST_FRAME = 1001
N_FRAMES = 48


def truth_camera(focal_mm: float, focus_m: float) -> Camera:
    """The truth zoom at a lens state (``R = I``, ``c = 0``): its focal length breathing with focus, its centre
    drifting with zoom and focus, its barrel easing toward the long end and with close focus."""
    vergence = 1.0 / focus_m
    zoom = (focal_mm - 24.0) / 46.0
    fx = focal_mm * SIZE[0] / 36.0 * (1.0 + 0.03 * vergence)
    cx = (SIZE[0] - 1) / 2 + 5.0 * zoom - 2.0 * vergence
    cy = (SIZE[1] - 1) / 2 - 3.0 * zoom + 2.5 * vergence
    K = np.array([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]])
    lens = Distortion("polynomial", {"k1": -0.16 + 0.12 * zoom + 0.02 * vergence, "k2": 0.05 - 0.03 * zoom})
    return Camera("camera", SIZE, K, lens, np.eye(3), np.zeros(3))


def shot_states() -> list[tuple[int, float, float]]:
    """The shot: a zoom from 28 to 66 mm eased in and out, the focus racked from 1.3 m to 12 m over the middle."""
    t = np.linspace(0.0, 1.0, N_FRAMES)
    focal = 28.0 + 38.0 * (3 * t**2 - 2 * t**3)
    rack = np.clip((t - 0.25) / 0.5, 0.0, 1.0)
    vergence = 1.0 / 1.3 + (1.0 / 12.0 - 1.0 / 1.3) * rack
    return [(FIRST_FRAME + i, round(float(f), 4), round(float(1.0 / v), 4))
            for i, (f, v) in enumerate(zip(focal, vergence))]


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """The profile (from boards at the six states), the shot's CSV and the rig ``camcal lens`` made of it."""
    folder = tmp_path_factory.mktemp("rack_focus")
    states = {format_state(f, d): calibrated(board_views(truth_camera(f, d), 10, seed, "s"))
              for seed, (f, d) in enumerate(STATES)}
    profile_path = folder / "zoom.profile.json"
    profile = camcal.calibrate_profile(states, BOARD, model="polynomial", out=profile_path).profile
    csv = folder / "shot.csv"
    csv.write_text("frame,focal_mm,focus_m\n" + "".join(f"{i},{f},{d}\n" for i, f, d in shot_states()))
    rig_path = folder / "shot.rig.json"
    assert main(["lens", str(profile_path), "--metadata", str(csv), "--out", str(rig_path)]) == 0
    return profile, Rig.load(rig_path), folder


def test_the_shot_is_a_zoom_and_a_rack_focus_between_the_calibrated_states():
    states = shot_states()
    assert len(states) >= 48
    calibrated_states = {(f, d) for f, d in STATES}
    assert not any((f, d) in calibrated_states for _, f, d in states)
    assert np.all(np.diff([f for _, f, _ in states]) >= 0) and states[-1][1] - states[0][1] > 30
    assert states[0][2] < 1.5 and states[-1][2] > 10


def test_each_frame_is_the_truth_within_the_profiles_sigma(shot):
    profile, rig, _ = shot
    assert [frame.index for frame in rig.frames] == [i for i, _, _ in shot_states()]
    grid = frame_grid(SIZE, 40.0)
    worst = []
    for (index, focal, focus), frame in zip(shot_states(), rig.frames):
        lens = frame.lenses["camera"]
        assert (lens.focal_mm, lens.focus_m) == (focal, focus)
        truth = truth_camera(focal, focus)
        camera = rig.camera_at_frame("camera", index)
        pixels = camera.distortion.project_rays(truth.distortion.rays_from_pixels(grid, truth.K), camera.K)
        sigma = projection_sigma_px(profile, focal, focus, pixels)
        error = np.linalg.norm(pixels - grid, axis=1)
        within = float(np.mean(error <= 2.0 * sigma))
        # each parameter within 3 of its printed sigma
        printed = camera_at(profile, focal, focus).quality.sigma
        values = {"fx": camera.K[0, 0], "fy": camera.K[1, 1], "cx": camera.K[0, 2], "cy": camera.K[1, 2],
                  **camera.distortion.params}
        expected = {"fx": truth.K[0, 0], "fy": truth.K[1, 1], "cx": truth.K[0, 2], "cy": truth.K[1, 2],
                    **truth.distortion.params}
        z = {name: abs(values[name] - expected[name]) / printed[name] for name in printed}
        worst.append((index, within, float(error.max()), float(sigma.max()), max(z.values())))
        assert within >= 0.95, (index, within)
        assert max(z.values()) < 3.0, (index, z)
    print("frame, share within 2 sigma, worst error px, worst sigma px, worst parameter z:")
    for row in worst[::8]:
        print("  %d  %.3f  %.3f  %.3f  %.2f" % row)


def test_blender_projects_every_frame_as_camcal(shot, bpy, addon):
    _, rig, folder = shot
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(folder / "shot.rig.json"), frame_start=0, compositor=False)
    obj, clip = result.cameras["camera"], result.clips["camera"]
    rng = np.random.default_rng(11)
    ideal = rng.uniform([0, 0], [SIZE[0] - 1, SIZE[1] - 1], (100, 2))
    worst_projection = worst_lens = 0.0
    for frame in reversed(rig.frames):  # out of order: every frame change sets the lens from its keys
        scene.frame_set(frame.index)
        camera = rig.camera_at_frame("camera", frame.index)
        X = points_in_view(camera.K, camera.R, camera.c, SIZE, 100, rng)
        pinhole = Camera("p", SIZE, camera.K, Distortion.none(), camera.R, camera.c).project(X)
        worst_projection = max(worst_projection, np.abs(blender_project(bpy, obj, scene, X) - pinhole).max())
        lens = tracking_lens_now(addon, clip, SIZE)
        assert lens.distortion_model == "POLYNOMIAL"
        blender = np.array([addon.tracking.blender_distort(lens, tuple(p)) for p in ideal])
        worst_lens = max(worst_lens, np.abs(blender - camera.distortion.distort(ideal, camera.K)).max())
    print(f"Blender over {len(rig.frames)} frames: projection {worst_projection:.1e} px, tracking lens "
          f"{worst_lens:.1e} px")
    assert worst_projection < 1e-3 and worst_lens < 1e-3
    assert obj.data["camcal_lens_frames"] == len(rig.frames)


def residuals_per_frame(rig: Rig, back: Rig) -> list[float]:
    """Each frame's largest distance between the two rigs' projections of the same rays (px)."""
    assert [f.index for f in back.frames] == [f.index for f in rig.frames]
    return [max_pixel_residual(rig.camera_at_frame("camera", f.index), back.camera_at_frame("camera", f.index))
            for f in rig.frames]


def check_exports(rig: Rig, folder: Path) -> None:
    """Read back by camcal, each frame projects as the rig's within what the export printed.

    Nuke: camcal's knobs hold each frame's lens; the Camera3 holds one pixel aspect (the Root format's), the
    profile's ``fy / fx`` moves a little from state to state: that residual is printed. Without camcal's knobs the
    keyed 3DE4 Radial lens node is a refit of the ``polynomial`` lens (printed). 3DE: the dynamic distortion is keyed
    over the frames' lens states; 3DE's lens centre is one per lens, so each state's refit absorbs the drift of the
    principal point (printed).
    """
    [nuke] = export_rig(rig, "nuke", folder / "shot.nk").conversions
    with_knobs = residuals_per_frame(rig, import_rig(folder / "shot.nk", "nuke").rig)
    plain = folder / "plain.nk"  # without camcal's knobs: the lens from the keyed lens node
    plain.write_text(strip_camcal_lens((folder / "shot.nk").read_text()))
    lens_node = residuals_per_frame(rig, import_rig(plain, "nuke").rig)
    [tde] = export_rig(rig, "3de", folder / "shot.txt").conversions
    tde_back = import_rig(folder / "shot.txt", "3de").rig
    tde_read = residuals_per_frame(rig, tde_back)
    print(f"Nuke: {nuke.describe()}\n  read back per frame, worst {max(with_knobs):.3g} px; from the lens node "
          f"{max(lens_node):.3g} px")
    print(f"3DE: {tde.describe()}\n  read back per frame, worst {max(tde_read):.3g} px")
    n = len(rig.frames)
    assert f"keyed on {n} frames" in nuke.target and f"over {n} lens states" in tde.target
    for residuals, printed in ((with_knobs, nuke.max_px), (lens_node, nuke.max_px + nuke.refit.max_px),
                               (tde_read, tde.max_px)):
        assert max(residuals) <= max(1.05 * printed, 1e-9), (max(residuals), printed)
    # the printed figures are the worst frame's, not a bound far above it
    assert max(with_knobs) >= 0.95 * nuke.max_px and max(tde_read) >= 0.95 * tde.max_px
    # every frame's lens state travels with it
    for frame, read in zip(rig.frames, tde_back.frames):
        state, lens = frame.lenses["camera"], read.lenses["camera"]
        assert (lens.focal_mm, lens.focus_m) == pytest.approx((state.focal_mm, state.focus_m), rel=1e-9)


def test_nuke_and_3de_carry_the_lens_of_frames_across_the_shot(shot, tmp_path):
    """Four frames from the zoom's start to its end, the rack focus's near and far (the whole shot: the slow sibling;
    the Nuke export writes two ST-maps a frame, the 3DE export refits a lens per state)."""
    _, rig, _ = shot
    check_exports(dataclasses.replace(rig, frames=tuple(rig.frames[i] for i in (0, 16, 32, 47))), tmp_path)


@pytest.mark.slow
def test_nuke_and_3de_carry_every_frames_lens(shot, tmp_path):
    _, rig, _ = shot
    check_exports(rig, tmp_path)
