"""3DEqualizer lens files: written as 3DE4's lens import reads them, read back by camcal to the exported lens.

The file's lines are checked against the film back a 3DE user would type (cm, from the camera's sensor width and
``K`` by hand) and its parameters evaluated with the models' documented formulas (``ldpk_formulas``, independent of
camcal's model code); a refitted lens reads back to the residual the export printed.
"""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.conversion import max_pixel_residual
from camcal.io.interchange import export_rig, import_rig
from camcal.model.rig import Rig

import ldpk_formulas
from interchange_rigs import fisheye_rig, stereo_rig
from test_nuke_lens import LENSES, SIZE, random_pixels, tde_camera


def read_file(path):
    lines = path.read_text().splitlines()
    header = [float(v) for v in lines[1].split()]
    params, index = {}, 4
    while lines[index] != "<end_of_file>":
        name, value, keys = lines[index], float(lines[index + 1]), int(lines[index + 2])
        params[name] = value
        index += 3 + keys
    return lines, header, params


@pytest.mark.parametrize("model", list(LENSES))
def test_a_3de_lens_is_written_exactly_and_read_back(model, tmp_path):
    camera = tde_camera(model, pixel_aspect=2.0 if model == "3de4-anamorphic-deg4" else 1.0)
    out = tmp_path / "lens.txt"
    result = export_rig(Rig((camera,)), None, out)
    [conversion] = result.conversions
    assert conversion.exact and conversion.refit.max_px < 1e-6
    lines, header, params = read_file(out)
    fb_w, fb_h, focal, film_aspect, lco_x, lco_y, pixel_aspect = header
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    width, height = SIZE
    assert lines[0] == camera.name and lines[2] == "DISTORTION_STATIC"
    assert fb_w == pytest.approx(2.49) and focal == pytest.approx(fx * 2.49 / width)
    assert pixel_aspect == pytest.approx(fy / fx) and film_aspect == pytest.approx(fb_w / fb_h)
    assert fb_h == pytest.approx(2.49 * height / width / pixel_aspect)
    assert lco_x == pytest.approx((cx - (width - 1) / 2) * fb_w / width)
    assert lco_y == pytest.approx(-(cy - (height - 1) / 2) * fb_h / height)
    assert len(params) == len(LENSES[model])
    back = import_rig(out, None).rig
    [read] = back.cameras
    assert read.distortion.model == model and read.image_size == SIZE
    worst = max_pixel_residual(camera, read)
    print(f"{model}: read back {worst:.2e} px")
    assert worst < 1e-9


def test_the_written_parameters_undistort_by_the_documented_formula(tmp_path):
    camera = tde_camera("3de4-radial-deg4")
    export_rig(Rig((camera,)), "3de", tmp_path / "lens.txt")
    _, header, params = read_file(tmp_path / "lens.txt")
    fb_w, fb_h, focal, _, lco_x, lco_y, pixel_aspect = header
    assert list(params) == ["Distortion - Degree 2", "U - Degree 2", "V - Degree 2", "Quartic Distortion - Degree 4",
                            "U - Degree 4", "V - Degree 4", "Phi - Cylindric Direction", "B - Cylindric Bending"]
    keys = ("c2", "u2", "v2", "c4", "u4", "v4", "cylindric_direction_deg", "cylindric_bending")
    coefficients = dict(zip(keys, params.values()))
    pixels = random_pixels()
    documented = ldpk_formulas.undistort_pixels("3de4-radial-deg4", coefficients, pixels, SIZE, (fb_w, fb_h),
                                                (lco_x, lco_y), pixel_aspect, focal)
    assert np.abs(documented - camera.distortion.undistort(pixels, camera.K)).max() < 1e-9


@pytest.mark.parametrize("rig, family", [(stereo_rig(rectified=False), "3de4-radial-deg4"),
                                         (fisheye_rig(rectified=False), "3de4-fisheye-deg8")])
def test_a_refitted_lens_reads_back_to_the_residual_printed(rig, family, tmp_path, capsys):
    rig_path = Rig(rig.cameras[:1]).save(tmp_path / "cam.rig.json")
    assert main(["rig", "export", str(rig_path), str(tmp_path / "lens.txt")]) == 0
    printed = capsys.readouterr().out
    assert "max residual" in printed and "overscan border" in printed
    result = export_rig(Rig(rig.cameras[:1]), "3de", tmp_path / "lens2.txt")
    [conversion] = result.conversions
    refit = conversion.refit
    assert not conversion.exact and refit.family == family
    assert main(["rig", "import", str(tmp_path / "lens.txt"), "--out", str(tmp_path / "back.rig.json")]) == 0
    [read] = Rig.load(tmp_path / "back.rig.json").cameras
    assert read.distortion.model == family
    worst = max_pixel_residual(rig.cameras[0], read)
    print(f"{family}: printed {refit.describe()}; read back {worst:.4g} px (16 px grid)")
    assert worst == pytest.approx(refit.max_px, rel=0.05)


def test_more_than_one_camera_asks_for_one(tmp_path):
    rig = stereo_rig(rectified=False)
    with pytest.raises(CamcalError, match="holds one lens; the rig has 2 cameras"):
        export_rig(rig, "3de", tmp_path / "lens.txt")
    assert not (tmp_path / "lens.txt").exists()
    export_rig(rig, "3de", tmp_path / "right.txt", cameras=["right"])
    assert import_rig(tmp_path / "right.txt", "3de").rig.cameras[0].name == "right"


def written_by_3de(tmp_path, model_line="3DE4 Radial - Standard, Degree 4", mode="DISTORTION_STATIC", keys=""):
    """A lens file as 3DE4 writes it (no image size), the quartic term's curve keyed on focal length."""
    text = (f"zoom lens\n3.6 2.025 3.5 1.7777777777777777 0.01 -0.02 1.0\n{mode}\n{model_line}\n"
            f"Distortion - Degree 2\n-0.04\n0\nQuartic Distortion - Degree 4\n0.002\n{keys or '0'}\n<end_of_file>\n")
    path = tmp_path / "from_3de.txt"
    path.write_text(text)
    return path


def test_a_file_3de_wrote_needs_the_image_size_and_takes_the_key_at_its_focal_length(tmp_path):
    path = written_by_3de(tmp_path, mode="DISTORTION_DYNAMIC_FOCAL_LENGTH",
                          keys="2\n2.5 0.001 0 0 0 0 LINEAR\n3.5 0.003 0 0 0 0 LINEAR")
    with pytest.raises(CamcalError, match="holds no image size"):
        import_rig(path, "3de")
    [camera] = import_rig(path, "3de", image_size=(1920, 1080)).rig.cameras
    assert camera.distortion.params["c4"] == 0.003 and camera.distortion.params["c2"] == -0.04
    assert camera.K[0, 0] == pytest.approx(3.5 * 1920 / 3.6)
    assert camera.K[0, 2] == pytest.approx(959.5 + 0.01 * 1920 / 3.6)
    assert camera.K[1, 2] == pytest.approx(539.5 + 0.02 * 1080 / 2.025)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("3DE4 Radial - Standard, Degree 4", "3DE4 Radial - Standard, Degree 6"),
     "unknown 3DE lens model '3DE4 Radial - Standard, Degree 6'"),
    (lambda t: t.replace("<end_of_file>\n", ""), "truncated 3DE lens file"),
    (lambda t: t.split("Quartic")[0], "truncated 3DE lens file"),
    (lambda t: t.replace("Distortion - Degree 2", "Degree 2"), "has no parameter 'Degree 2'"),
    (lambda t: t.replace("3.6 2.025 3.5", "3.6 2.025 x"), "the film back line must be numbers"),
    (lambda t: t.replace("-0.04", "nan"), "not finite"),
    (lambda t: t.replace("STATIC", "DYNAMIC_FOCAL_LENGTH").replace("0.002\n0", "0.002\n1\n2.0 0.1 0 0 0 0 LINEAR"),
     "no key at the lens' focal length"),
])
def test_bad_lens_files_are_one_line(tmp_path, edit, message):
    path = written_by_3de(tmp_path)
    path.write_text(edit(path.read_text()))
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "3de", image_size=(1920, 1080))
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_the_command_refuses_a_bad_file_with_exit_2(tmp_path, capsys):
    path = written_by_3de(tmp_path, model_line="Brown")
    assert main(["rig", "import", str(path), "--image-size", "1920", "1080", "--out", str(tmp_path / "x.rig.json")]) == 2
    assert "unknown 3DE lens model 'Brown'" in capsys.readouterr().err
    assert not (tmp_path / "x.rig.json").exists()
