"""A capture volume through every interchange format: `rig export` writes all 8 cameras, `rig import` reads them back.

Poses are compared relative to the first camera (Kalibr's camchain holds each camera relative to the one before
it, not the world); pixels through :func:`camcal.io.conversion.max_pixel_residual` (each camera's projection of
points over its image, lens included, against the original's).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import FORMATS, export_rig, import_rig
from camcal.model.camera import rotation_angle_deg
from camcal.model.distortion import Distortion
from camcal.model.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import make_volume  # noqa: E402

N = 8


@pytest.fixture(scope="module")
def volume_rig():
    volume = make_volume(N, 1, image_size=(480, 270), radius=2.5, seed=13,
                         distortion=Distortion("opencv", {"k1": -0.09, "k2": 0.02, "p1": 1e-4, "p2": -2e-4,
                                                          "k3": 0.0}))
    return Rig(tuple(volume.cameras))


def relative(camera, ref):
    return camera.R @ ref.R.T, ref.R @ (camera.c - ref.c)


SUFFIX = {"opencv": "yaml", "kalibr": "yaml", "usd": "usda", "nuke": "nk"}
# OpenCV's file holds one camera or a stereo pair, a 3DE lens file one lens (tests/io/test_tde_file.py), a Lensfun
# file lenses without poses (tests/io/test_lensfun.py)
RIG_FORMATS = [fmt for fmt in FORMATS if fmt not in ("opencv", "3de", "lensfun")]


def read_back(fmt, out):
    return import_rig(out, fmt, **({"image_size": (480, 270)} if fmt == "usd" else {})).rig


@pytest.mark.parametrize("fmt", RIG_FORMATS)
def test_every_rig_format_round_trips_all_cameras(volume_rig, fmt, tmp_path):
    out = tmp_path / ("colmap" if fmt == "colmap" else f"volume.{SUFFIX[fmt]}")
    written = export_rig(volume_rig, fmt, out)
    assert len(written.conversions) == N
    back = read_back(fmt, out)
    assert len(back.cameras) == N
    by_name = {c.name: c for c in back.cameras}
    matched = [by_name.get(c.name) for c in volume_rig.cameras]
    if None in matched:  # a format without camera names keeps their order
        matched = list(back.cameras)
    ref, ref_back = volume_rig.cameras[0], matched[0]
    worst_px = worst_deg = worst_m = 0.0
    for camera, other in zip(volume_rig.cameras, matched):
        (R, c), (R_back, c_back) = relative(camera, ref), relative(other, ref_back)
        worst_deg = max(worst_deg, rotation_angle_deg(R_back @ R.T))
        worst_m = max(worst_m, float(np.linalg.norm(c_back - c)))
        worst_px = max(worst_px, max_pixel_residual(camera, other))
    print(f"\n{fmt}: {N} cameras back, worst rotation {worst_deg:.2e} deg, centre {worst_m:.2e} m, "
          f"pixels {worst_px:.2e} px")
    assert worst_deg < 1e-4 and worst_m < 1e-6 and worst_px < 0.01


def test_opencv_files_hold_the_volume_one_camera_each(volume_rig, tmp_path):
    """OpenCV's calibration file holds one camera or a pair: all 8 at once is refused in one line naming them; each
    camera exported on its own round-trips."""
    with pytest.raises(CamcalError, match="one camera or a stereo pair; the rig has 8 cameras"):
        export_rig(volume_rig, "opencv", tmp_path / "all.yaml")
    assert not (tmp_path / "all.yaml").exists()
    worst = 0.0
    for camera in volume_rig.cameras:
        out = tmp_path / f"{camera.name}.yaml"
        export_rig(volume_rig, "opencv", out, cameras=[camera.name])
        [back] = read_back("opencv", out).cameras
        worst = max(worst, max_pixel_residual(camera, back))
    assert worst < 0.01


def test_rig_export_command_writes_every_camera(volume_rig, tmp_path, capsys):
    rig_path = volume_rig.save(tmp_path / "volume.rig.json")
    for fmt in RIG_FORMATS:
        out = tmp_path / (fmt if fmt == "colmap" else f"volume.{SUFFIX[fmt]}")
        assert main(["rig", "export", str(rig_path), "--to", fmt, str(out)]) == 0, capsys.readouterr()
        text = capsys.readouterr().out
        assert all(f"camera '{c.name}'" in text for c in volume_rig.cameras), (fmt, text)
