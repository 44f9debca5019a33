"""Nuke's lens nodes: the LensDistortion node (3DEqualizer preset, diagonal normalisation) and the LDPK node of the
same model, written beside the Camera3 and read back.

No Nuke here. The nodes' knobs are evaluated with the models' documented formulas (``ldpk_formulas``, written from
the LDPK documentation, independently of camcal's model code), on the knob names Foundry documents for the
LensDistortion node (learn.foundry.com/nuke/13.2/content/reference_guide/transform_nodes/lensdistortion.html:
``distortionModelPreset``, ``lens``, ``anamorphicSqueeze`` / ``anamorphicTwist`` / ``anamorphicScale``, the
``distortionNumerator`` / ``distortionDenominator`` families) and the ones 3DEqualizer's own Nuke export gives each
3DE parameter (``Distortion - Degree 2`` -> ``distortionNumerator0``, ``Cx02 - Degree 2`` ->
``distortionNumeratorX00``, ``Squeeze-X`` -> ``anamorphicScale`` [0], the lens centre offset over the film back's
half-diagonal as ``centre``; the LDPK node's ``tde4_*`` built-ins in cm and parameters by their 3DE names).
"""

import dataclasses
import re

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

import ldpk_formulas
from interchange_rigs import K, stereo_rig

SIZE = (480, 270)  # small: the ST-maps beside the script invert the 3DE lens at every pixel
LENSES = {
    "3de-classic": {"distortion": -0.06, "anamorphic_squeeze": 1.0, "curvature_x": 0.004, "curvature_y": -0.003,
                    "quartic_distortion": 0.011},
    "3de4-radial-deg4": {"c2": -0.05, "u2": 0.002, "v2": -0.0015, "c4": 0.012, "u4": -0.0007, "v4": 0.0004,
                         "cylindric_direction_deg": 20.0, "cylindric_bending": 0.01},
    "3de4-anamorphic-deg4": {"cx02": -0.04, "cy02": -0.035, "cx22": 0.003, "cy22": -0.002, "cx04": 0.006,
                             "cy04": 0.005, "cx24": -0.001, "cy24": 0.0008, "cx44": 0.0004, "cy44": -0.0003,
                             "lens_rotation_deg": 0.4, "squeeze_x": 1.002, "squeeze_y": 0.997},
    "3de4-fisheye-deg8": {"c2": 0.02, "c4": -0.004, "c6": 0.0005, "c8": -2e-5},
}


def tde_camera(model, pixel_aspect=1.0, name="cam"):
    params = {**LENSES[model], "filmback_width_px": float(SIZE[0]), "filmback_height_px": float(SIZE[1])}
    focal = 300.0 if model == "3de4-fisheye-deg8" else 394.0
    return Camera(name, SIZE, K(focal, focal * pixel_aspect, 244.6, 131.9), Distortion(model, params), np.eye(3),
                  np.zeros(3), sensor_width_mm=24.9)


def nodes(text, cls):
    assert text.count("{") == text.count("}")
    return re.findall(rf"^{cls} \{{\n(.*?)^\}}", text, flags=re.M | re.S)


def knob(body, name):
    match = re.search(rf"^ {name} (.+)$", body, flags=re.M)
    return None if match is None else match.group(1).strip()


def numbers(text):
    return [float(v) for v in text.strip("{}").split()]


def random_pixels(n=3000, seed=2):
    rng = np.random.default_rng(seed)
    return rng.uniform([0, 0], [SIZE[0] - 1, SIZE[1] - 1], (n, 2))


def lens_distortion_undistort(body, model, pixels):
    """The LensDistortion node's undistortion of camcal pixels, from its knobs and the documented formulas."""
    names = {"3de-classic": {"distortion": "distortionNumerator0", "quartic_distortion": "distortionNumerator1",
                             "curvature_x": "distortionNumeratorX00", "curvature_y": "distortionNumeratorY00",
                             "anamorphic_squeeze": "anamorphicSqueeze"},
             "3de4-radial-deg4": {"c2": "distortionNumerator0", "c4": "distortionNumerator1",
                                  "u2": "distortionNumeratorT0", "u4": "distortionNumeratorT1",
                                  "v2": "distortionNumeratorU0", "v4": "distortionNumeratorU1",
                                  "cylindric_direction_deg": "beamSplitterDirection",
                                  "cylindric_bending": "beamSplitterBending"},
             "3de4-fisheye-deg8": {f"c{d}": f"distortionNumerator{i}" for i, d in enumerate((2, 4, 6, 8))}}
    if model == "3de4-anamorphic-deg4":
        names = {f"c{a}{t}": f"distortionNumerator{a.upper()}{i}" for a in "xy"
                 for t, i in (("02", "00"), ("22", "10"), ("04", "01"), ("24", "11"), ("44", "20"))}
        coefficients = {key: float(knob(body, name)) for key, name in names.items()}
        coefficients["lens_rotation_deg"] = float(knob(body, "anamorphicTwist"))
        coefficients["squeeze_x"], coefficients["squeeze_y"] = numbers(knob(body, "anamorphicScale"))
    else:
        coefficients = {key: float(knob(body, name)) for key, name in names[model].items()}
    fmt = knob(body, "distortionScalingFormat").strip('"').split()
    assert (int(fmt[0]), int(fmt[1])) == SIZE
    sensor, centre = numbers(knob(body, "sensorSize")), numbers(knob(body, "centre"))
    half_diagonal = 0.5 * np.hypot(*sensor)
    return ldpk_formulas.undistort_pixels(model, coefficients, pixels, SIZE, sensor, np.array(centre) * half_diagonal,
                                          float(fmt[6]), float(knob(body, "focal")))


def ldpk_undistort(body, model, pixels):
    """The LDPK node's undistortion of camcal pixels, from its tde4_* knobs (cm) and its parameters by 3DE name."""
    ldpk_names = {"distortion": "Distortion", "anamorphic_squeeze": "Anamorphic_Squeeze", "curvature_x": "Curvature_X",
                  "curvature_y": "Curvature_Y", "quartic_distortion": "Quartic_Distortion",
                  "u2": "U_Degree_2", "v2": "V_Degree_2", "u4": "U_Degree_4", "v4": "V_Degree_4",
                  "cylindric_direction_deg": "Phi_Cylindric_Direction", "cylindric_bending": "B_Cylindric_Bending",
                  "lens_rotation_deg": "Lens_Rotation", "squeeze_x": "Squeeze_X", "squeeze_y": "Squeeze_Y",
                  **{f"c{a}{t}": f"C{a}{t}_Degree_{t[1]}" for a in "xy" for t in ("02", "22", "04", "24", "44")}}
    radial = {"c2": "Distortion_Degree_2", "c4": "Quartic_Distortion_Degree_4", "c6": "Degree_6", "c8": "Degree_8"}
    coefficients = {key: float(knob(body, {**ldpk_names, **radial}[key])) for key in LENSES[model]}
    cm = {name: float(knob(body, f"tde4_{name}")) for name in
          ("focal_length_cm", "filmback_width_cm", "filmback_height_cm", "lens_center_offset_x_cm",
           "lens_center_offset_y_cm", "pixel_aspect")}
    return ldpk_formulas.undistort_pixels(
        model, coefficients, pixels, SIZE, (cm["filmback_width_cm"], cm["filmback_height_cm"]),
        (cm["lens_center_offset_x_cm"], cm["lens_center_offset_y_cm"]), cm["pixel_aspect"], cm["focal_length_cm"])


@pytest.mark.parametrize("model", list(LENSES))
def test_lens_nodes_undistort_like_camcal_by_the_documented_formulas(model, tmp_path):
    camera = tde_camera(model)
    result = export_rig(Rig((camera,)), "nuke", tmp_path / "shot.nk")
    [conversion] = result.conversions
    assert conversion.refit.exact and conversion.refit.max_px < 1e-6
    text = (tmp_path / "shot.nk").read_text()
    [ld], [ldpk], [cam3] = nodes(text, "LensDistortion2"), nodes(text, "LD_3DE4?_[A-Za-z_0-9]+"), nodes(text, "Camera3")
    assert knob(ld, "distortionModelPreset").startswith('"3DEqualizer/3DE')
    assert knob(ld, "normalisationType") == "Diagonal" and knob(ld, "output") == "Undistort"
    pixels = random_pixels()
    expected = camera.distortion.undistort(pixels, camera.K)
    ok = np.all(np.isfinite(expected), axis=1)
    worst_ld = np.abs(lens_distortion_undistort(ld, model, pixels)[ok] - expected[ok]).max()
    worst_ldpk = np.abs(ldpk_undistort(ldpk, model, pixels)[ok] - expected[ok]).max()
    print(f"{model}: LensDistortion {worst_ld:.2e} px, LDPK {worst_ldpk:.2e} px from camcal's undistortion")
    assert worst_ld < 1e-9 and worst_ldpk < 1e-9
    # the Camera3 and the lens nodes hold one focal length and film back
    assert float(knob(cam3, "focal")) == pytest.approx(float(knob(ld, "focal")), rel=1e-12)
    assert float(knob(cam3, "focal")) == pytest.approx(10 * float(knob(ldpk, "tde4_focal_length_cm")), rel=1e-12)
    assert float(knob(cam3, "haperture")) == pytest.approx(numbers(knob(ld, "sensorSize"))[0], rel=1e-12)
    assert float(knob(cam3, "haperture")) == pytest.approx(10 * float(knob(ldpk, "tde4_filmback_width_cm")), rel=1e-12)


def test_anamorphic_pixels_go_through_the_ldpk_pixel_aspect(tmp_path):
    camera = tde_camera("3de4-anamorphic-deg4", pixel_aspect=2.0)
    export_rig(Rig((camera,)), "nuke", tmp_path / "ana.nk")
    [ldpk] = nodes((tmp_path / "ana.nk").read_text(), "LD_3DE4_Anamorphic_Standard_Degree_4")
    assert float(knob(ldpk, "tde4_pixel_aspect")) == 2.0
    pixels = random_pixels()
    expected = camera.distortion.undistort(pixels, camera.K)
    assert np.abs(ldpk_undistort(ldpk, "3de4-anamorphic-deg4", pixels) - expected).max() < 1e-9


def strip_camcal_lens(text):
    """The script as a tool that knows no camcal knobs would keep it: the Camera3's lens knobs gone."""
    return re.sub(r"^ (addUserKnob \{1 lens_\w+\}|lens_\w+ .*)\n", "", text, flags=re.M)


@pytest.mark.parametrize("model", list(LENSES))
@pytest.mark.parametrize("node", ["ldpk", "lens"])
def test_lens_nodes_are_read_back(model, node, tmp_path):
    camera = tde_camera(model)
    export_rig(Rig((camera,)), "nuke", tmp_path / "shot.nk")
    text = strip_camcal_lens((tmp_path / "shot.nk").read_text())
    if node == "lens":  # the LensDistortion node alone
        text = re.sub(r"^LD_3DE\w+ \{\n.*?^\}\n", "", text, flags=re.M | re.S)
    (tmp_path / "plain.nk").write_text(text)
    result = import_rig(tmp_path / "plain.nk", None)
    [back] = result.rig.cameras
    assert result.conversions[0].source.startswith("Nuke LD_3DE" if node == "ldpk" else "Nuke LensDistortion")
    assert back.distortion.model == model
    worst = max_pixel_residual(camera, back)
    print(f"{model} via the {node} node: {worst:.2e} px")
    assert worst < 1e-9


def test_a_refitted_lens_reads_back_to_the_residual_printed(tmp_path):
    rig = stereo_rig(rectified=False)  # OpenCV lenses: refitted to 3DE4 Radial - Standard, Degree 4
    rig = Rig(rig.cameras[:1])
    result = export_rig(rig, "nuke", tmp_path / "shot.nk")
    (tmp_path / "plain.nk").write_text(strip_camcal_lens((tmp_path / "shot.nk").read_text()))
    back = import_rig(tmp_path / "plain.nk", "nuke").rig
    for camera, conversion in zip(rig.cameras, result.conversions):
        refit = conversion.refit
        assert not refit.exact and refit.family == "3de4-radial-deg4"
        read = back.camera(camera.name)
        assert read.distortion.model == "3de4-radial-deg4"
        # the Camera3 has one focal scale: compare the lens on the original K (the refit's own camera)
        lens_only = dataclasses.replace(read, K=camera.K)
        worst = max_pixel_residual(camera, lens_only)
        print(f"{camera.name}: printed {refit.describe()}; read back {worst:.4g} px")
        assert worst == pytest.approx(refit.max_px, rel=0.05)


def test_a_script_with_lens_nodes_only_gives_one_camera_per_lens(tmp_path):
    camera = tde_camera("3de4-radial-deg4")
    export_rig(Rig((camera,)), "nuke", tmp_path / "shot.nk")
    text = (tmp_path / "shot.nk").read_text()
    text = re.sub(r"^(Camera3|STMap|Read) \{\n.*?^\}\n", "", text, flags=re.M | re.S)
    (tmp_path / "lens.nk").write_text(text)
    result = import_rig(tmp_path / "lens.nk", "nuke")
    [back] = result.rig.cameras
    assert back.name == "cam_ldpk" and max_pixel_residual(camera, back) < 1e-9


@pytest.mark.parametrize("text, message", [
    ('LensDistortion2 {\n distortionModelPreset "3DEqualizer/3DE5 Radial"\n name a\n}\n', "is not one of 3DEqualizer's"),
    ('Blur {\n name b\n}\n', "no Camera3 node and no"),
    ('Root {\n format "640 480 0 0 640 480 1 x"\n}\nLD_3DE4_Radial_Standard_Degree_4 {\n tde4_focal_length_cm 3\n'
     ' name lens\n}\n', "has no tde4_filmback_width_cm knob"),
    ('LD_3DE4_Radial_Standard_Degree_4 {\n tde4_focal_length_cm 3\n name lens\n', "unbalanced braces"),
    ('Root {\n format "640 480 0 0 640 480 1 x"\n}\nLensDistortion2 {\n distortionModelPreset '
     '"3DEqualizer/3DE4 Radial - Standard, Degree 4"\n focal nan\n sensorSize {3.6 2.7}\n name l\n}\n', "not finite"),
])
def test_bad_lens_nodes_are_one_line(tmp_path, text, message):
    path = tmp_path / "bad.nk"
    path.write_text(text)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "nuke")
    assert "\n" not in str(info.value)


def test_an_ldpk_node_alone_takes_the_image_size_given(tmp_path):
    """3DEqualizer's own export writes the LDPK node alone: no Root, no camera, no image size in the script."""
    camera = tde_camera("3de4-anamorphic-deg4", pixel_aspect=2.0)
    export_rig(Rig((camera,)), "nuke", tmp_path / "shot.nk")
    [ldpk] = nodes((tmp_path / "shot.nk").read_text(), "LD_3DE4_Anamorphic_Standard_Degree_4")
    (tmp_path / "ld.nk").write_text("LD_3DE4_Anamorphic_Standard_Degree_4 {\n" + ldpk + "}\n")
    with pytest.raises(CamcalError, match="no image size"):
        import_rig(tmp_path / "ld.nk", "nuke")
    [back] = import_rig(tmp_path / "ld.nk", "nuke", image_size=SIZE).rig.cameras
    assert max_pixel_residual(camera, back) < 1e-9
