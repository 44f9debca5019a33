"""Nuke script export / import. No Nuke here: the script's Camera3 knobs are projected with the
camera model Foundry documents (focal / haperture, win_translate in half-widths, rot_order XYZ)."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.stmap import make_stmaps
from camcal.io.stmap import read_exr
from camcal.io.interchange import export_rig, import_rig

from interchange_rigs import division_rig, moving_rig, stereo_rig, world_points


def camera_nodes(text):
    assert text.count("{") == text.count("}")
    return re.findall(r"^Camera3 \{\n(.*?)^\}", text, flags=re.M | re.S)


def knob(body, name):
    return re.search(rf"^ {name} (.+)$", body, flags=re.M).group(1)


def keyed(text, frame):
    """The value of each axis' curve at ``frame``, or the constant vector."""
    if "curve" not in text:
        return np.array([float(v) for v in text.strip("{}").split()])
    return np.array([float(re.search(rf"x{frame} (\S+)", curve).group(1)) for curve in re.findall(r"\{curve ([^}]*)\}", text)])


def nuke_project(body, frame, X_camcal, size, pixel_aspect=1.0):
    """Nuke's Camera3 projection: world (Y up) -> camera (-Z forward) -> screen -> pixel centres, y down; a pixel
    ``pixel_aspect`` times as wide as it is high (the format's) spans that many rows per screen unit."""
    width, height = size
    translate, rotate = keyed(knob(body, "translate"), frame), keyed(knob(body, "rotate"), frame)
    world_from_camera = Rotation.from_euler("xyz", rotate, degrees=True).as_matrix()  # X, then Y, then Z
    X_nuke = X_camcal * [1, -1, -1]
    local = (X_nuke - translate) @ world_from_camera
    scale = 2 * float(knob(body, "focal")) / float(knob(body, "haperture"))
    win = [float(v) for v in knob(body, "win_translate").strip("{}").split()]
    screen = np.column_stack([scale * local[:, 0] / -local[:, 2] + win[0], scale * local[:, 1] / -local[:, 2] + win[1]])
    return np.column_stack([(screen[:, 0] + 1) * width / 2 - 0.5,
                            height / 2 - screen[:, 1] * width * pixel_aspect / 2 - 0.5])


def ideal_pixels(camera, X):
    x = (X - camera.c) @ camera.R.T @ camera.K.T
    return x[:, :2] / x[:, 2:]


def test_moving_rig_cameras_project_like_camcal_and_round_trip(tmp_path):
    rig, rig_path = moving_rig(tmp_path)
    out = tmp_path / "shot.nk"
    result = export_rig(rig, "nuke", out, rig_path=rig_path)
    assert all(c.exact for c in result.conversions)
    text = out.read_text()
    bodies = camera_nodes(text)
    assert len(bodies) == 2 and text.count("STMap {") == 4
    worst = 0.0
    for body, camera in zip(bodies, rig.cameras):
        for frame in rig.frames:
            posed = rig.camera_at_frame(camera.name, frame.index)
            X, _ = world_points(rig, posed)
            worst = max(worst, np.abs(nuke_project(body, frame.index, X, camera.image_size) - ideal_pixels(posed, X)).max())
    print(f"Camera3 knobs (documented projection) vs camcal: {worst:.2e} px")
    assert worst < 1e-9
    back = import_rig(out, "nuke").rig
    for frame in rig.frames:
        for camera in rig.cameras:
            a, b = rig.camera_at_frame(camera.name, frame.index), back.camera_at_frame(camera.name, frame.index)
            X, _ = world_points(rig, a)
            assert np.abs(a.project(X) - b.project(X)).max() < 1e-9
    # the STMap chain reads camcal's own maps
    maps = make_stmaps(rig.cameras[0])
    written = read_exr(tmp_path / "shot_stmaps" / "left_undistort.exr")
    assert np.array_equal(written, maps.undistort)
    assert f'file "{(tmp_path / "shot_stmaps" / "left_undistort.exr").resolve()}"' in text


def test_non_square_pixels_and_skew_are_reported(tmp_path):
    """The Root format takes the first camera's pixel aspect (fy / fx): exact without skew; another camera's fy / fx,
    and skew, are reported."""
    for rig in (stereo_rig(rectified=False), division_rig()):
        result = export_rig(rig, "nuke", tmp_path / "cams.nk")
        text = (tmp_path / "cams.nk").read_text()
        pixel_aspect = float(re.search(r"^ format \"(?:\S+ ){6}(\S+)", text, flags=re.M).group(1))
        assert pixel_aspect == pytest.approx(rig.cameras[0].K[1, 1] / rig.cameras[0].K[0, 0], rel=1e-12)
        for index, (body, camera, conversion) in enumerate(zip(camera_nodes(text), rig.cameras, result.conversions)):
            assert conversion.exact == (index == 0 and camera.K[0, 1] == 0.0)
            X, pixels = world_points(rig, camera, n=3000)
            observed = np.abs(nuke_project(body, 1, X, camera.image_size, pixel_aspect) - ideal_pixels(camera, X)).max()
            print(f"{camera.name}: printed {conversion.max_px:.3g} px, documented projection {observed:.3g} px")
            assert observed <= conversion.max_px * 1.01 + 1e-6


@pytest.mark.parametrize("text, message", [
    ("Root {\n}\n", "no Camera3 node"),
    ("Camera3 {\n focal 35\n name cam\n}\n", "no image_width"),
    ("Camera3 {\n focal nan\n image_width 640\n image_height 480\n name cam\n}\n", "not finite"),
    ("Camera3 {\n focal 35\n image_width 640\n image_height 480\n name cam\n", "unbalanced braces"),
])
def test_bad_input_is_one_line(tmp_path, text, message):
    path = tmp_path / "bad.nk"
    path.write_text(text)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "nuke")
    assert "\n" not in str(info.value)
