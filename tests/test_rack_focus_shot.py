"""A zoom with a rack focus, 48 frames with their lens metadata, end to end: profile, ``camcal lens``, Blender, Nuke, 3DE.

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
  that frame's lens (Blender's POLYNOMIAL holds camcal's ``polynomial``);
- the Nuke script and the 3DE lens file read back by camcal per frame:
  exact families to 1e-9 px, refitted ones within the residual printed.
"""

from __future__ import annotations

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
from test_lens_profile import BOARD, SIZE, board_views, calibrated  # noqa: E402
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
