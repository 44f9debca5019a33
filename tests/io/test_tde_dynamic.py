"""3DEqualizer's dynamic distortion: a zoom's or a rack focus's lens as curves over focal length / focus distance.

The file is read as 3DE4's own Import Lens script reads it (the curve of each parameter after its value: a key count,
then ``x y t1x t1y t2x t2y MODE`` per key; the 2D LUT of focal length and focus distance after ``<end_of_file>``),
and read back by camcal frame by frame.
"""

import dataclasses

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

from interchange_rigs import K, zoom_rig
from test_nuke_animated_lens import tde_lens_per_zoom
from test_nuke_lens import tde_camera

ZOOMS = (1.0, 1.2, 1.5)


def curves(path):
    """3DE's reading: parameter -> its keys [(x, y)], and the 2D LUT parameter -> [(focal, focus, value)]."""
    lines = path.read_text().splitlines()
    out, index = {}, 4
    while lines[index] != "<end_of_file>":
        name, n = lines[index], int(lines[index + 2])
        out[name] = [tuple(float(v) for v in line.split()[:2]) for line in lines[index + 3:index + 3 + n]]
        assert all(line.split()[6] == "SMOOTH" and len(line.split()) == 7 for line in lines[index + 3:index + 3 + n])
        index += 3 + n
    lut, index = {}, index + 1
    if lines[index] == "<begin_2dlut_samples>":
        index += 1
        while lines[index] != "<end_2dlut_samples>":
            name, n = lines[index], int(lines[index + 1])
            lut[name] = [tuple(float(v) for v in line.split()) for line in lines[index + 2:index + 2 + n]]
            index += 2 + n
    return lines[2], out, lut


def read_back_per_frame(rig, path):
    back = import_rig(path, "3de").rig
    assert [f.index for f in back.frames] == [f.index for f in rig.frames]
    return [max_pixel_residual(rig.camera_at_frame(c.name, f.index), back.camera_at_frame(c.name, f.index))
            for c in rig.cameras for f in rig.frames], back


@pytest.mark.parametrize("state, mode", [
    (lambda i, zoom: (24.0 * zoom, 3.0), "DISTORTION_DYNAMIC_FOCAL_LENGTH"),
    (lambda i, zoom: (24.0, 1.5 + i), "DISTORTION_DYNAMIC_FOCUS_DISTANCE"),
    (lambda i, zoom: (24.0 * zoom, 1.5 + i), "DISTORTION_DYNAMIC_FOCAL_AND_FOCUS_DISTANCE"),
])
def test_an_exact_lens_is_keyed_over_its_state_and_reads_back_per_frame(state, mode, tmp_path):
    rig = zoom_rig(tde_camera("3de4-radial-deg4"), ZOOMS, tde_lens_per_zoom, drift=(0.0, 0.0), state=state)
    out = tmp_path / "zoom.txt"
    [conversion] = export_rig(rig, "3de", out).conversions
    assert conversion.exact and mode in conversion.target
    written_mode, keyed, lut = curves(out)
    assert written_mode == mode
    states = [rig.frames[i].lenses["cam"] for i in (1, 2)]  # frame 1001 is the camera's own lens, no state
    c2 = [rig.frames[i].lenses["cam"].distortion.params["c2"] for i in (1, 2)]
    if mode == "DISTORTION_DYNAMIC_FOCAL_AND_FOCUS_DISTANCE":
        assert all(len(keys) == 0 for keys in keyed.values())
        assert lut["Distortion - Degree 2"] == [(s.focal_mm / 10, s.focus_m * 100, v) for s, v in zip(states, c2)]
    else:
        x = [s.focal_mm / 10 if "FOCAL" in mode else s.focus_m * 100 for s in states]  # 3DE's cm
        assert keyed["Distortion - Degree 2"] == list(zip(x, c2)) and lut == {}
    residuals, back = read_back_per_frame(rig, out)
    print(f"{mode}: read back per frame {', '.join(f'{r:.1e}' for r in residuals)} px")
    assert max(residuals) < 1e-9
    assert back.frames[2].lenses["cam"].focus_m == states[1].focus_m


def test_a_refitted_zoom_reads_back_to_the_worst_residual_printed(tmp_path):
    camera = Camera("wide", (320, 180), K(300.0, 300.0, 160.3, 89.6), Distortion("division", {"lambda": -2.0e-6}),
                    np.eye(3), np.zeros(3))
    rig = zoom_rig(camera, ZOOMS, lambda d, z: Distortion("division", {"lambda": d.params["lambda"] / z ** 2}))
    out = tmp_path / "zoom.txt"
    [conversion] = export_rig(rig, "3de", out).conversions
    assert not conversion.exact
    residuals, _ = read_back_per_frame(rig, out)
    print(f"printed {conversion.refit.describe()}; read back {', '.join(f'{r:.3g}' for r in residuals)} px")
    assert max(residuals) == pytest.approx(conversion.max_px, rel=0.05)


def test_lenses_without_a_state_are_refused(tmp_path):
    rig = zoom_rig(tde_camera("3de4-radial-deg4"), ZOOMS, tde_lens_per_zoom, state=lambda i, zoom: (None, None))
    with pytest.raises(CamcalError, match="do not say which lens state they are"):
        export_rig(rig, "3de", tmp_path / "zoom.txt")
    partly = zoom_rig(tde_camera("3de4-radial-deg4"), (1.0, 1.2, 1.5, 1.7), tde_lens_per_zoom,
                      state=lambda i, zoom: (24.0 * zoom if i < 3 else None, 2.0))
    with pytest.raises(CamcalError, match="the lens of frame 1004 has no focal_mm"):
        export_rig(partly, "3de", tmp_path / "zoom.txt")
    assert not (tmp_path / "zoom.txt").exists()
    static = dataclasses.replace(rig, frames=())
    assert export_rig(static, "3de", tmp_path / "static.txt").conversions[0].exact
