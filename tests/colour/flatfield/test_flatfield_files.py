"""``camcal colour flatfield`` and its files: the command against the API, the gain EXR read back, the Lensfun
entry corrected by Lensfun itself (lensfunpy), ``colour fit --flat-field``, and bad input refused in one line."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import cv2
import numpy as np
import pytest

import camcal
from camcal.cli import main
from camcal.colour.flatfield import FlatField, correct_flat_field
from camcal.io.flatfield import load_flat_field, save_flat_field
from camcal.io.frames import imread, imwrite
from flatfield_scenes import K_TRUE, SIZE, render_grey_card, true_flat

LENS_STATE = ["--focal-mm", "35", "--aperture", "4", "--distance-m", "2"]


def write_exr(path: Path, RGB: np.ndarray) -> Path:
    return imwrite(path, np.ascontiguousarray(RGB[:, :, ::-1]).astype(np.float32))


def cli(argv, capsys) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def grey(tmp_path_factory) -> Path:
    """Two grey-card EXRs of one lens (the card over 80 % of the frame), at two exposures."""
    folder = tmp_path_factory.mktemp("grey")
    for i, exposure in enumerate((1.0, 0.7)):
        write_exr(folder / f"grey{i}.exr", render_grey_card(10 + i, exposure=exposure).image)
    return folder


def test_the_command_and_the_api_write_the_same_files(grey, tmp_path, capsys):
    images = f"{grey}/grey*.exr"
    outputs = {name: {"out": tmp_path / name / "flat.json", "gain_exr": tmp_path / name / "gain.exr",
                      "lensfun": tmp_path / name / "lens.xml"} for name in ("api", "cli")}
    (tmp_path / "api").mkdir()
    (tmp_path / "cli").mkdir()
    result = camcal.fit_flat_field(images, focal_mm=35.0, aperture=4.0, distance_m=2.0, **outputs["api"])
    code, out, err = cli(["colour", "flatfield", "--images", images, "--out", outputs["cli"]["out"], "--gain-exr",
                          outputs["cli"]["gain_exr"], "--lensfun", outputs["cli"]["lensfun"], *LENS_STATE, "--json"],
                         capsys)
    assert code == 0 and all(line in err for line in result.lines())
    for key in ("out", "gain_exr", "lensfun"):
        assert outputs["api"][key].read_bytes() == outputs["cli"][key].read_bytes(), key
    assert [path for path, _ in result.files] == list(outputs["api"].values())
    # the file holds the fit: corrected within 0.5 % over the frame
    flat = load_flat_field(outputs["cli"]["out"])
    assert np.max(np.abs(flat.gain() / true_flat().gain() - 1)) < 0.005 and len(result.images) == 2
    # the gain EXR is the model's gain, pixel for pixel (float32)
    gain = imread(outputs["cli"]["gain_exr"])[:, :, ::-1]
    np.testing.assert_array_equal(gain, flat.gain())
    # --json says the same
    figures = json.loads(out)["figures"]
    assert figures["n_images"] == 2 and figures["centre_px"] == list(flat.centre) == result.figures()["centre_px"]
    assert figures["lensfun"]["k"] == result.figures()["lensfun"]["k"]


def lensfun_corrected(path: Path, image: np.ndarray, focal_mm: float = 35.0) -> np.ndarray:
    """Lensfun's own vignetting correction of ``image`` with the entry in ``path`` (the lens state written)."""
    lensfunpy = pytest.importorskip("lensfunpy")
    database = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
    [lens] = database.lenses
    height, width = image.shape[:2]
    modifier = lensfunpy.Modifier(lens, lens.crop_factor, width, height)
    modifier.initialize(focal_mm, 4.0, 2.0, pixel_format=np.float32, flags=lensfunpy.ModifyFlags.VIGNETTING)
    corrected = np.array(image, dtype=np.float32, order="C")  # a copy: Lensfun corrects in place
    assert modifier.apply_color_modification(corrected)
    return corrected


def test_lensfun_corrects_the_grey_card_as_camcal_does(tmp_path, capsys):
    """One falloff for every channel (what Lensfun's pa holds): Lensfun's correction of the rendered card equals
    camcal's within 0.5 % over the frame, and the card comes out flat."""
    same = np.tile(K_TRUE[1], (3, 1))
    scene = render_grey_card(12, k=same)
    write_exr(tmp_path / "grey.exr", scene.image)
    code, out, _ = cli(["colour", "flatfield", "--images", tmp_path / "grey.exr", "--out", tmp_path / "flat.json",
                        "--lensfun", tmp_path / "lens.xml", *LENS_STATE], capsys)
    assert code == 0 and "within 0.0" in out
    by_lensfun = lensfun_corrected(tmp_path / "lens.xml", scene.gain)
    by_camcal = correct_flat_field(scene.gain, load_flat_field(tmp_path / "flat.json"))
    assert np.max(np.abs(by_lensfun / by_camcal - 1)) < 0.005
    assert np.max(np.abs(by_lensfun - 1)) < 0.005  # the true falloff, divided out


def test_lensfun_holds_one_falloff_and_the_command_says_how_far_off_it_is(tmp_path, capsys):
    """Per-channel falloff (colour shading): Lensfun's one pa term set differs from camcal's per-channel
    correction by about the deviation the command printed."""
    flat = true_flat()
    from camcal.io.flatfield import write_lensfun_vignetting

    terms = write_lensfun_vignetting(flat, tmp_path / "lens.xml", focal_mm=35.0, aperture=4.0, distance_m=2.0)
    gain = flat.gain()
    difference = np.max(np.abs(lensfun_corrected(tmp_path / "lens.xml", gain) / correct_flat_field(gain, flat) - 1))
    assert difference > 0.02 and difference == pytest.approx(terms.max_deviation, rel=0.1)


def test_colour_fit_divides_the_chart_by_the_flat_field(tmp_path):
    """A linear chart photo seen through the lens: with --flat-field its patches are the chart's own, within
    0.2 %; without, the corner patches are several per cent darker."""
    from camcal.colour.chart.detect import chart_from_corners
    from camcal.colour.chart.reference import reference_chart

    width, height = SIZE
    corners = np.array([[60, 50], [900, 40], [910, 600], [50, 610]], float)
    chart = reference_chart()
    linear = np.clip(chart.XYZ @ np.array([[3.24, -0.97, 0.06], [-1.54, 1.88, -0.20], [-0.50, 0.04, 1.06]]),
                     0.01, 0.95)  # linear sRGB of the patches
    image = np.full((height, width, 3), 0.3)
    H = chart_from_corners(corners).H

    def poly(uv):
        p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
        return np.round(p[:, :2] / p[:, 2:]).astype(np.int32)

    cv2.fillConvexPoly(image, poly(np.array([[-0.05, -0.08], [1.05, -0.08], [1.05, 1.08], [-0.05, 1.08]])),
                       (0.02, 0.02, 0.02))
    for i in range(24):
        r, c = divmod(i, 6)
        quad = np.array([[(c + 0.1) / 6, (r + 0.1) / 4], [(c + 0.9) / 6, (r + 0.1) / 4],
                         [(c + 0.9) / 6, (r + 0.9) / 4], [(c + 0.1) / 6, (r + 0.9) / 4]])
        cv2.fillConvexPoly(image, poly(quad), tuple(float(v) for v in linear[i]))
    flat = true_flat()
    write_exr(tmp_path / "chart.exr", image * flat.gain())
    save_flat_field(flat, tmp_path / "flat.json")
    grid = ",".join(str(v) for v in corners.ravel())
    options = dict(chart=tmp_path / "chart.exr", corners=grid, linearise="none", model="matrix3x3")
    plain = camcal.fit_colour(**options)
    flattened = camcal.fit_colour(**options, flat_field=tmp_path / "flat.json")
    used = [chart.patch_names.index(name) for name in flattened.chart.patches.names]
    np.testing.assert_allclose(flattened.chart.patches.RGB, linear[used], rtol=0.002)
    assert np.max(np.abs(plain.chart.patches.RGB / linear[used] - 1)) > 0.05
    with pytest.raises(camcal.CamcalError, match="--flat-field divides linear values"):
        camcal.fit_colour(chart=tmp_path / "chart.exr", corners=grid, flat_field=tmp_path / "flat.json")


def bad_inputs(grey: Path, tmp_path: Path) -> list[tuple[list, str]]:
    """(arguments, the line the command prints) for input that must be refused before anything is written."""
    card = render_grey_card(13).image
    write_exr(tmp_path / "small.exr", card[::2, ::2])
    write_exr(tmp_path / "dark.exr", np.zeros_like(card))
    cv2.imwrite(str(tmp_path / "grey8.png"), np.round(np.clip(card[:, :, ::-1], 0, 1) * 255).astype(np.uint8))
    (tmp_path / "bad.csv").write_text("x,y,R,G,B\n1,2,0.5,0.5,0.5\n")
    (tmp_path / "two.xml").write_text("<lensdatabase><lens/><lens/></lensdatabase>")
    return [
        (["--images", grey / "grey0.exr", tmp_path / "small.exr"], "the grey-card images differ in size"),
        (["--images", tmp_path / "dark.exr"], "is too dark for a flat field"),
        (["--images", tmp_path / "grey8.png"], "is an 8-bit image, most likely display-encoded (sRGB)"),
        (["--images", grey / "grey0.exr", "--lensfun", tmp_path / "o" / "lens.xml", "--focal-mm", "35"],
         "--lensfun needs the lens state: --aperture, --distance-m"),
        (["--images", f"{tmp_path}/nothing*.exr"], "no image matches"),
        (["--images", grey / "grey0.exr", tmp_path / "gone.exr"], "gone.exr (missing file)"),
        (["--images", grey / "grey0.exr", "--lensfun", tmp_path / "two.xml", *LENS_STATE],
         "a Lensfun file with one <lens>, this one has 2"),
        (["--patches", tmp_path / "p.csv"], "--patches needs --image-size W H"),
        (["--patches", tmp_path / "bad.csv", "--image-size", "960", "640"],
         "the header must be x,y,R,G,B,patch[,shot], got x,y,R,G,B"),
        (["--images", grey / "grey0.exr", "--smooth-degree", "5"], "--smooth-degree must be 0 to 4, got 5"),
    ]


def test_bad_input_is_one_line_and_writes_nothing(grey, tmp_path, capsys):
    """The command prints one line and exits 2; the API raises the same line; no output is left."""
    outputs = ["--out", tmp_path / "o" / "flat.json", "--gain-exr", tmp_path / "o" / "gain.exr"]
    for arguments, message in bad_inputs(grey, tmp_path):
        code, _, err = cli(["colour", "flatfield", *arguments, *outputs], capsys)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and message in lines[0], (arguments, err)
        assert not (tmp_path / "o").exists()
    # the API refuses the same input with the same line
    with pytest.raises(camcal.CamcalError) as raised:
        camcal.fit_flat_field(tmp_path / "grey8.png", out=tmp_path / "o" / "flat.json")
    code, _, err = cli(["colour", "flatfield", "--images", tmp_path / "grey8.png", *outputs], capsys)
    assert err.strip() == f"camcal: error: {raised.value}"
    # the promise that an 8-bit image is linear lets it through (the card is quantised to 1/255)
    flat = camcal.fit_flat_field(tmp_path / "grey8.png", linear=True).flat
    assert np.max(np.abs(flat.gain() / true_flat().gain() - 1)) < 0.01


def test_a_flat_field_file_is_checked_on_load(tmp_path):
    path = tmp_path / "flat.json"
    save_flat_field(true_flat(), path)
    data = json.loads(path.read_text())
    data["model"]["k"] = [[-3.0, 0.0, 0.0]] * 3
    path.write_text(json.dumps(data))
    with pytest.raises(camcal.CamcalError, match=f"{path}: flat field: its gain falls to"):
        load_flat_field(path)
    with pytest.raises(camcal.CamcalError, match="a flat-field file ends in .json"):
        save_flat_field(true_flat(), tmp_path / "flat.txt")
    assert FlatField.from_dict(true_flat().to_dict()).to_dict() == true_flat().to_dict()


def test_neutral_patches_from_a_csv(tmp_path, capsys):
    """The patch route through the command: a CSV of the chart's six neutrals at 16 places."""
    truth = true_flat()
    rng = np.random.default_rng(14)
    width, height = SIZE
    rows = ["x,y,R,G,B,patch,shot"]
    for s, (cx, cy) in enumerate([(x * width, y * height) for y in (0.05, 0.35, 0.65, 0.95)
                                  for x in (0.17, 0.39, 0.61, 0.83)]):
        exposure = rng.uniform(0.6, 1.0)
        for p, reflectance in enumerate((0.90, 0.59, 0.36, 0.19, 0.09, 0.03)):
            x, y = cx + (p - 2.5) * 0.063 * width, cy
            R, G, B = exposure * reflectance * truth.gain_at(np.array([[x, y]]))[0] * (1 + rng.normal(0, 5e-4, 3))
            rows.append(f"{x},{y},{R},{G},{B},neutral {p},{s}")
    (tmp_path / "neutrals.csv").write_text("\n".join(rows) + "\n")
    code, out, _ = cli(["colour", "flatfield", "--patches", tmp_path / "neutrals.csv", "--image-size", width, height,
                        "--out", tmp_path / "flat.json"], capsys)
    assert code == 0 and "from neutral patches: 96 samples" in out
    flat = load_flat_field(tmp_path / "flat.json")
    assert np.max(np.abs(flat.gain() / truth.gain() - 1)) < 0.01


def test_a_raw_grey_card(tmp_path, capsys):
    """A 14-bit DNG of the card (RGGB, black 512): read as linear camera RGB at half size, saturated photosites
    (a glint on the card) left out; the flat field within 0.5 % over the frame."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "io"))
    from dng_writer import write_cfa_dng

    black, white = 512, 16383
    scene = render_grey_card(15)
    RGB = scene.image.copy()
    RGB[300:330, 400:430] = 3.0  # a glint on the card: clipped photosites
    cells = np.empty((SIZE[1] * 2, SIZE[0] * 2))
    cells[0::2, 0::2], cells[0::2, 1::2], cells[1::2, 0::2], cells[1::2, 1::2] = (RGB[:, :, 0], RGB[:, :, 1],
                                                                                  RGB[:, :, 1], RGB[:, :, 2])
    photosites = np.clip(np.round(black + cells * 0.8 * (white - black)), 0, white).astype(np.uint16)
    write_cfa_dng(tmp_path / "grey.dng", photosites, black=(black,) * 4, white=white)
    code, out, _ = cli(["colour", "flatfield", "--images", tmp_path / "grey.dng", "--out", tmp_path / "flat.json"],
                       capsys)
    assert code == 0
    flat = load_flat_field(tmp_path / "flat.json")
    assert flat.image_size == SIZE and np.max(np.abs(flat.gain() / scene.gain - 1)) < 0.005


def test_the_api_has_the_commands_defaults_and_loads_light():
    """``camcal.fit_flat_field``'s defaults are the command's; naming it imports none of the heavy libraries."""
    import inspect
    import subprocess
    import sys

    from camcal.cli import build_parser
    from camcal.cli.app import leaf_parsers

    [leaf] = [leaf for path, leaf in leaf_parsers(build_parser()) if path == ("colour", "flatfield")]
    defaults = {action.dest: action.default for action in leaf._actions}
    parameters = inspect.signature(camcal.fit_flat_field).parameters
    for name in ("smooth_degree", "lens_name", "linear", "mask", "gain_exr", "lensfun", "sensor_width_mm"):
        assert parameters[name].default == defaults[name], name
    assert parameters["fit_centre"].default is (not defaults["fixed_centre"])
    code = ("import sys, camcal\ncamcal.fit_flat_field, camcal.FlatFieldFit\n"
            "print([m for m in ('cv2', 'scipy', 'OpenEXR', 'colour') if m in sys.modules])")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "[]"


def test_vignetting_added_to_a_lens_profile_per_lens_state(tmp_path, capsys):
    """A lens exported to Lensfun (its distortion about the principal point) gets a vignetting entry per lens
    state: the terms are fitted about the lens' one centre, a state given again is replaced, the distortion
    is kept, and Lensfun's correction differs from camcal's by the deviation the command printed."""
    from camcal.io.interchange import export_rig, import_rig
    from camcal.model.distortion import Distortion
    from camcal.model.rig import Camera, Rig

    width, height = SIZE
    K = np.array([[800.0, 0.0, (width - 1) / 2 + 12], [0.0, 800.0, (height - 1) / 2 - 7], [0.0, 0.0, 1.0]])
    camera = Camera("lens", SIZE, K, Distortion("polynomial", {"k1": -0.1, "k2": 0.01}), np.eye(3), np.zeros(3))
    lens = tmp_path / "lens.xml"
    export_rig(Rig((camera,)), "lensfun", lens)
    scene = render_grey_card(17, k=np.tile(K_TRUE[1], (3, 1)))
    write_exr(tmp_path / "grey.exr", scene.image)
    base = ["colour", "flatfield", "--images", tmp_path / "grey.exr", "--out", tmp_path / "flat.json", "--lensfun",
            lens, "--focal-mm", "30", "--distance-m", "2"]
    for aperture in ("4", "8", "8"):
        code, out, _ = cli([*base, "--aperture", aperture], capsys)
        assert code == 0
    deviation = float(out.split("within ")[1].split(" %")[0]) / 100
    entries = ElementTree.parse(lens).getroot().findall("lens/calibration/vignetting")
    assert sorted(entry.get("aperture") for entry in entries) == ["4", "8"]
    np.testing.assert_allclose(import_rig(lens, "lensfun").rig.cameras[0].K, K, atol=1e-6)  # the distortion kept
    by_lensfun = lensfun_corrected(lens, scene.gain, focal_mm=30.0)
    by_camcal = correct_flat_field(scene.gain, load_flat_field(tmp_path / "flat.json"))
    difference = float(np.max(np.abs(by_lensfun / by_camcal - 1)))
    assert 0.003 < difference and difference == pytest.approx(deviation, abs=0.001)
