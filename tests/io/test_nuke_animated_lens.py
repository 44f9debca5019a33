"""A zoom in Nuke: per-frame lenses keyed on the Camera3 and on the lens nodes, ST-maps per frame, read back.

No Nuke here: each frame's knobs are taken from the keyed curves by the test (the value keyed at that frame) and
evaluated as in ``test_nuke_lens`` / ``test_nuke_interchange`` (Foundry's Camera3 projection, the LDPK formulas).
"""

import dataclasses
import re

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.stmap import make_stmaps
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.io.stmap import read_exr, read_exr_window
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

from interchange_rigs import K, world_points, zoom_rig
from test_nuke_interchange import camera_nodes, nuke_project
from test_nuke_lens import ldpk_undistort, lens_distortion_undistort, nodes, random_pixels, strip_camcal_lens, tde_camera

FRAMES = (1001, 1002, 1003)


def at_frame(body, frame):
    """A node's body with every keyed knob replaced by its value at ``frame`` (Nuke's curve at a key)."""
    def value(match):
        keys, current = {}, None
        for token in match.group(1).split():
            if token.startswith("x"):
                current = int(token[1:])
            else:
                keys[current] = token
                current += 1
        return keys[frame]

    body = re.sub(r"\{curve ([^{}]*)\}", value, body)
    return re.sub(r"^ (\w+) \{(\S+)\}$", r" \1 \2", body, flags=re.M)  # a keyed scalar: {v} -> v


def tde_lens_per_zoom(distortion, zoom):
    """A 3DE4 Radial lens whose barrel eases as the lens zooms in."""
    return Distortion(distortion.model, {**distortion.params, "c2": distortion.params["c2"] / zoom,
                                         "c4": distortion.params["c4"] * zoom})


@pytest.fixture(scope="module")
def zoom(tmp_path_factory):
    folder = tmp_path_factory.mktemp("zoom")
    rig = zoom_rig(tde_camera("3de4-radial-deg4"), scale_lens=tde_lens_per_zoom)
    result = export_rig(rig, "nuke", folder / "zoom.nk")
    return rig, result, folder


def test_camera3_and_lens_nodes_are_keyed_per_frame(zoom):
    rig, result, folder = zoom
    text = (folder / "zoom.nk").read_text()
    [camera3], [ld], [ldpk] = camera_nodes(text), nodes(text, "LensDistortion2"), nodes(text, "LD_3DE4_Radial\\w+")
    for name in ("focal", "haperture", "win_translate"):
        assert "{curve x1001 " in re.search(rf"^ {name} (.+)$", camera3, flags=re.M).group(1)
    [conversion] = result.conversions
    assert conversion.refit.exact and "keyed on 3 frames" in conversion.target
    pixels = random_pixels()
    for frame in FRAMES:
        camera = rig.camera_at_frame("cam", frame)
        # the Camera3 at this frame projects like camcal's camera at this frame (pinhole part)
        X, _ = world_points(rig, rig.camera("cam"), n=50)  # rig coordinates
        frame_pose = rig.frames[frame - 1001]
        X_world = X @ frame_pose.R + frame_pose.c
        x = (X_world - camera.c) @ camera.R.T @ camera.K.T
        ideal = x[:, :2] / x[:, 2:]
        nuke = nuke_project(at_frame(camera3, frame), frame, X_world, camera.image_size)
        assert np.abs(nuke - ideal).max() < 1e-7
        # both lens nodes undistort like camcal's lens at this frame, by the LDPK's documented formulas
        expected = camera.distortion.undistort(pixels, camera.K)
        ok = np.all(np.isfinite(expected), axis=1)
        worst_ld = np.abs(lens_distortion_undistort(at_frame(ld, frame), camera.distortion.model, pixels)[ok]
                          - expected[ok]).max()
        worst_ldpk = np.abs(ldpk_undistort(at_frame(ldpk, frame), camera.distortion.model, pixels)[ok]
                            - expected[ok]).max()
        print(f"frame {frame}: Camera3 {np.abs(nuke - ideal).max():.1e} px, LensDistortion {worst_ld:.1e} px, "
              f"LDPK {worst_ldpk:.1e} px")
        assert worst_ld < 1e-9 and worst_ldpk < 1e-9


def test_the_zoom_reads_back_per_frame(zoom, tmp_path):
    rig, _, folder = zoom
    back = import_rig(folder / "zoom.nk", "nuke").rig
    assert [f.index for f in back.frames] == list(FRAMES)
    plain = tmp_path / "plain.nk"  # without camcal's knobs: the lens from the keyed LDPK node
    plain.write_text(strip_camcal_lens((folder / "zoom.nk").read_text()))
    from_node = import_rig(plain, "nuke").rig
    for frame in FRAMES:
        original = rig.camera_at_frame("cam", frame)
        for read in (back, from_node):
            worst = max_pixel_residual(original, read.camera_at_frame("cam", frame))
            assert worst < 1e-9, (frame, worst)
        state = rig.frames[frame - 1001].lenses.get("cam")
        lens = back.frames[frame - 1001].lenses.get("cam")
        if state is not None:  # the lens state travels with camcal's knobs
            assert (lens.focal_mm, lens.focus_m) == (state.focal_mm, state.focus_m)
    assert back.frames[0].lenses == {}  # the first frame's lens is the camera's own


def test_st_maps_are_a_sequence_one_pair_per_frame(zoom):
    rig, result, folder = zoom
    text = (folder / "zoom.nk").read_text()
    reads = re.findall(r'^ file "(\S+_(?:un|re)distort\.%04d\.exr)"\n first 1001\n last 1003$', text, flags=re.M)
    assert len(reads) == 2
    for frame in FRAMES:
        maps = make_stmaps(rig.camera_at_frame("cam", frame))
        undistort, border = read_exr_window(folder / "zoom_stmaps" / f"cam_undistort.{frame:04d}.exr")
        assert border == maps.border
        assert np.array_equal(undistort, maps.undistort.astype(np.float32))
        assert np.array_equal(read_exr(folder / "zoom_stmaps" / f"cam_redistort.{frame:04d}.exr"),
                              maps.redistort.astype(np.float32))
    undistorted = Rig.load(folder / "zoom_stmaps" / "cam_undistorted.rig.json")
    for frame in FRAMES:
        assert np.array_equal(undistorted.camera_at_frame("cam", frame).K,
                              make_stmaps(rig.camera_at_frame("cam", frame)).undistorted.K)


def test_a_refitted_zoom_reads_back_to_the_worst_residual_printed(tmp_path):
    """A division lens per frame, refitted to 3DE4 Radial - Standard, Degree 4 frame by frame."""
    camera = Camera("wide", (320, 180), K(300.0, 300.0, 160.3, 89.6), Distortion("division", {"lambda": -2.0e-6}),
                    np.eye(3), np.zeros(3))
    rig = zoom_rig(camera, scale_lens=lambda d, z: Distortion("division", {"lambda": d.params["lambda"] / z ** 2}))
    [conversion] = export_rig(rig, "nuke", tmp_path / "zoom.nk").conversions
    assert not conversion.refit.exact and conversion.refit.family == "3de4-radial-deg4"
    (tmp_path / "plain.nk").write_text(strip_camcal_lens((tmp_path / "zoom.nk").read_text()))
    back = import_rig(tmp_path / "plain.nk", "nuke").rig
    residuals = []
    for frame in FRAMES:
        original = rig.camera_at_frame("wide", frame)
        read = dataclasses.replace(back.camera_at_frame("wide", frame), K=original.K)
        assert read.distortion.model == "3de4-radial-deg4"
        residuals.append(max_pixel_residual(original, read))
    print(f"printed {conversion.refit.describe()}; read back per frame {', '.join(f'{r:.3g}' for r in residuals)} px")
    assert max(residuals) == pytest.approx(conversion.refit.max_px, rel=0.05)
    assert len(set(np.round(residuals, 12))) == 3  # each frame refitted on its own lens


def test_nukes_own_zoom_camera_reads_as_a_lens_per_frame(tmp_path):
    """A Camera3 written by Nuke (no camcal knobs): focal keyed, pose fixed; the image size from the Root format."""
    script = tmp_path / "zoom.nk"
    script.write_text('Root {\n format "640 360 0 0 640 360 1 HD"\n}\nCamera3 {\n focal {{curve x12 35 50}}\n'
                      ' haperture 36\n win_translate {0.1 {curve x12 0 0.05}}\n name Camera1\n}\n')
    rig = import_rig(script, "nuke").rig
    assert [f.index for f in rig.frames] == [12, 13]
    for frame, focal, win_y in ((12, 35.0, 0.0), (13, 50.0, 0.05)):
        K = rig.camera_at_frame("Camera1", frame).K
        assert K[0, 0] == pytest.approx(focal * 640 / 36) and K[0, 2] == pytest.approx(0.1 * 320 + 319.5)
        assert K[1, 2] == pytest.approx(179.5 - win_y * 320)


@pytest.mark.parametrize("knobs, message", [
    (' focal {{curve x1 35 x2 50}}\n lens_keys "k1=0.1"\n', "before the first frame"),
    (' focal {{curve x1 35 x2 50}} \n rotate {{curve x1 0 x3 1} 0 0}\n', "keyed on different frames|key the lens"),
    (' focal {{curve}}\n', "focal: an animated knob with no key"),
])
def test_bad_keys_are_one_line(tmp_path, knobs, message):
    script = tmp_path / "bad.nk"
    script.write_text('Root {\n format "640 360 0 0 640 360 1 HD"\n}\nCamera3 {\n' + knobs + ' name cam\n}\n')
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(script, "nuke")
    assert "\n" not in str(info.value)
