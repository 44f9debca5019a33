"""Kalibr camchain export / import, checked against Kalibr's documented YAML schema with PyYAML."""

import numpy as np
import pytest
import yaml

from camcal.base.errors import CamcalError
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig

from interchange_rigs import BROWN, RADTAN, division_rig, fisheye_rig, relative_projection_error, stereo_rig, world_points


def check_camchain_schema(chain):
    """Kalibr wiki, "Yaml formats" / camchain.yaml: every field, type and shape it documents."""
    assert isinstance(chain, dict) and list(chain) == [f"cam{i}" for i in range(len(chain))]
    for index, (key, cam) in enumerate(chain.items()):
        assert cam["camera_model"] in ("pinhole", "omni", "ds", "eucm")
        assert len(cam["intrinsics"]) == {"pinhole": 4, "omni": 5, "ds": 6, "eucm": 6}[cam["camera_model"]]
        assert cam["distortion_model"] in ("radtan", "equidistant", "fov", "none")
        assert len(cam["distortion_coeffs"]) == {"radtan": 4, "equidistant": 4, "fov": 1, "none": 0}[cam["distortion_model"]]
        assert all(isinstance(v, float) for v in cam["intrinsics"] + cam["distortion_coeffs"])
        assert len(cam["resolution"]) == 2 and all(isinstance(v, int) and v > 0 for v in cam["resolution"])
        assert isinstance(cam["rostopic"], str) and cam["rostopic"].startswith("/")
        if index == 0:
            assert "T_cn_cnm1" not in cam
        else:
            T = np.array(cam["T_cn_cnm1"], dtype=float)
            assert T.shape == (4, 4) and np.array_equal(T[3], [0, 0, 0, 1])
            assert np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() < 1e-12
            assert cam["cam_overlaps"] == [index - 1]


def test_radtan_round_trip_is_exact(tmp_path):
    rig = stereo_rig(RADTAN, rectified=False)
    out = tmp_path / "camchain.yaml"
    result = export_rig(rig, "kalibr", out)
    assert all(c.exact for c in result.conversions)
    chain = yaml.safe_load(out.read_text())
    check_camchain_schema(chain)
    assert chain["cam0"]["distortion_model"] == "radtan" and chain["cam1"]["rostopic"] == "/right/image_raw"
    back = import_rig(out, "kalibr").rig
    assert [c.name for c in back.cameras] == ["left", "right"]
    assert relative_projection_error(rig, back) < 1e-9
    # T_cn_cnm1 is the pose of cam1 in cam0's frame, as Kalibr defines it: X_c1 = T X_c0
    left, right = rig.cameras
    X = np.array([[0.3, -0.2, 4.0], [1.0, 0.5, 7.0]])
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    in_left = (X - left.c) @ left.R.T
    assert np.abs(in_left @ T[:3, :3].T + T[:3, 3] - (X - right.c) @ right.R.T).max() < 1e-12


def test_lossy_lens_within_the_printed_residual(tmp_path):
    for rig, expected in ((stereo_rig(BROWN, rectified=False), "opencv"), (division_rig(), "division with skew")):
        out = tmp_path / "camchain.yaml"
        result = export_rig(rig, "kalibr", out)
        check_camchain_schema(yaml.safe_load(out.read_text()))
        back = import_rig(out, "kalibr").rig
        for camera, converted, conversion in zip(rig.cameras, back.cameras, result.conversions):
            assert not conversion.exact and conversion.source == expected
            assert max_pixel_residual(camera, converted) == pytest.approx(conversion.max_px, rel=1e-9)
            print(f"{camera.name} {conversion.source} -> radtan: max residual {conversion.max_px:.3g} px")
        assert max(c.max_px for c in result.conversions) < 2.0


def equidistant_pixels(cam, X_camera):
    """Kalibr's pinhole-equi projection (its EquidistantDistortion, Kannala-Brandt), from the YAML entry alone."""
    fu, fv, pu, pv = cam["intrinsics"]
    k1, k2, k3, k4 = cam["distortion_coeffs"]
    x, y = X_camera[:, 0] / X_camera[:, 2], X_camera[:, 1] / X_camera[:, 2]
    r = np.hypot(x, y)
    theta = np.arctan(r)
    theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    scale = theta_d / r
    return np.column_stack([fu * x * scale + pu, fv * y * scale + pv])


def test_fisheye_is_pinhole_equi_exactly(tmp_path):
    rig = fisheye_rig(rectified=False)
    out = tmp_path / "camchain.yaml"
    result = export_rig(rig, "kalibr", out)
    assert all(c.exact and c.target == "pinhole-equi" for c in result.conversions)
    chain = yaml.safe_load(out.read_text())
    check_camchain_schema(chain)
    worst = 0.0
    for camera, cam in zip(rig.cameras, chain.values()):
        assert (cam["camera_model"], cam["distortion_model"]) == ("pinhole", "equidistant")
        p = camera.distortion.params
        assert cam["distortion_coeffs"] == [p["k1"], p["k2"], p["k3"], p["k4"]]
        X, pixels = world_points(rig, camera, n=500)
        worst = max(worst, np.abs(equidistant_pixels(cam, (X - camera.c) @ camera.R.T) - pixels).max())
    print(f"Kalibr's equidistant model on the file vs camcal: {worst:.1e} px")
    assert worst < 1e-9
    back = import_rig(out, "kalibr")
    assert [c.distortion for c in back.rig.cameras] == [c.distortion for c in rig.cameras]
    assert relative_projection_error(rig, back.rig) < 1e-9


@pytest.mark.parametrize("text, message", [
    ("cam0: {camera_model: pinhole, intrinsics: [500, 500, 320], distortion_model: radtan, "
     "distortion_coeffs: [0, 0, 0, 0], resolution: [640, 480]}", r"cam0.intrinsics must be a list of 4"),
    ("cam0: {camera_model: pinhole, intrinsics: [.nan, 500, 320, 240], distortion_model: radtan, "
     "distortion_coeffs: [0, 0, 0, 0], resolution: [640, 480]}", "contains NaN"),
    ("cam0: {camera_model: omni, intrinsics: [1, 500, 500, 320, 240], distortion_model: radtan, "
     "distortion_coeffs: [0, 0, 0, 0], resolution: [640, 480]}", "only pinhole"),
    ("K1: [1, 2]", "not a Kalibr camchain"),
    ("cam0: {camera_model: pinhole, intrinsics: [500, 500, 320, 240], distortion_model: radtan, "
     "distortion_coeffs: [0, 0, 0, 0], resolution: [640, 480]}\ncam1: {camera_model: pinhole, "
     "intrinsics: [500, 500, 320, 240], distortion_model: radtan, distortion_coeffs: [0, 0, 0, 0], "
     "resolution: [640, 480]}", "cam1.T_cn_cnm1 must be a 4x4"),
    ("cam0: [unclosed", "not a YAML file"),
])
def test_bad_input_is_one_line(tmp_path, text, message):
    path = tmp_path / "camchain.yaml"
    path.write_text(text)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "kalibr")
    assert "\n" not in str(info.value)
