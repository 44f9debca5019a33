"""``rig export PROFILE lens.xml --to lensfun --vignetting STATE/fN=flat.json``: a lens profile's Lensfun lens with a
``pa`` vignetting entry per flat field, checked by Lensfun itself (lensfunpy) on the rendered grey cards the flat
fields were fitted from."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest

import camcal
from camcal.cli import main
from camcal.colour.flatfield import correct_flat_field
from camcal.io.flatfield import load_flat_field
from camcal.io.frames import imwrite
from camcal.model.distortion import Distortion
from flatfield_scenes import CENTRE_OFFSET, K_TRUE, render_grey_card

lensfunpy = pytest.importorskip("lensfunpy")

SIZE = (480, 320)
#: Per lens state: one falloff for every channel (what Lensfun's pa holds), stronger at the wide end.
FALLOFF = {"24mm@inf/f2.8": [-0.42, 0.10, -0.04], "24mm@1m/f4": [-0.22, 0.03, -0.01]}


@pytest.fixture(scope="module")
def profile(tmp_path_factory) -> Path:
    """A lens profile of a 24 mm lens focused at 1 m and at infinity, its principal point at the grey
    cards' optical centre (the image centre moved by ``CENTRE_OFFSET``)."""
    from camcal.geometry.lens_profile import fit_profile
    from camcal.model.lens_profile import LensProfile, LensState, format_state

    parameters = ("fx", "fy", "cx", "cy", "k1", "k2")
    centre = np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2]) + CENTRE_OFFSET
    states = []
    for focal in (24.0,):  # one focal length: the Lensfun export fits its distortion once
        for focus in (1.0, math.inf):
            fx = 10.0 * focal * (1.0 + 0.02 / focus)
            values = [fx, fx, *centre, -0.15 + 0.002 * focal, 0.0]
            states.append(LensState(format_state(focal, focus), focal, focus, dict(zip(parameters, values)),
                                    np.diag([1.0, 1.0, 0.3, 0.3, 0.002, 0.01]) ** 2, 8, 0.2))
    profile = LensProfile("polynomial", SIZE, "chessboard:9x6:0.03", parameters, tuple(states),
                          fit_profile(states, parameters).surfaces)
    return profile.save(tmp_path_factory.mktemp("profile") / "zoom.profile.json")


def flat_file(folder: Path, name: str, k, seed: int):
    """The grey card rendered through falloff ``k`` (per channel) and camcal's flat field fitted from it."""
    scene = render_grey_card(seed, k=np.asarray(k, float), size=SIZE)
    exr = imwrite(folder / f"{name}.exr", np.ascontiguousarray(scene.image[:, :, ::-1]).astype(np.float32))
    camcal.fit_flat_field(exr, out=folder / f"{name}.json")
    return folder / f"{name}.json", scene


def lensfun_corrected(path: Path, image: np.ndarray, focal_mm: float, aperture: float, distance_m: float):
    """Lensfun's own vignetting correction of ``image`` at a lens state, from the file's entries."""
    database = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
    [lens] = database.lenses
    height, width = image.shape[:2]
    modifier = lensfunpy.Modifier(lens, lens.crop_factor, width, height)
    modifier.initialize(focal_mm, aperture, distance_m, pixel_format=np.float32,
                        flags=lensfunpy.ModifyFlags.VIGNETTING)
    corrected = np.array(image, dtype=np.float32, order="C")  # a copy: Lensfun corrects in place
    assert modifier.apply_color_modification(corrected)
    return corrected


def cli(argv, capsys) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_lensfun_corrects_each_states_grey_card_as_camcal_does(profile, tmp_path, capsys):
    """Where the pa model holds the falloff (one for every channel, about the lens' centre), Lensfun's correction
    of each state's rendered grey card is flat within 0.5 % (the flat field fitted from it with shot noise: its
    channels' fits differ by up to 1 %, which the one pa term set cannot hold, and the export prints). Where the
    falloff differs per channel (colour shading), Lensfun's correction differs from camcal's per-channel one by
    about the deviation printed."""
    flats, scenes = {}, {}
    for seed, (key, k) in enumerate([*((key, np.tile(k, (3, 1))) for key, k in FALLOFF.items()),
                                     ("24mm@inf/f8", K_TRUE)]):
        flats[key], scenes[key] = flat_file(tmp_path, f"flat{seed}", k, 30 + seed)
    code, out, _ = cli(["rig", "export", profile, tmp_path / "cli.xml", "--to", "lensfun", "--vignetting",
                        *(f"{key}={path}" for key, path in flats.items())], capsys)
    assert code == 0
    printed = [line for line in out.splitlines() if "vignetting at" in line]
    assert len(printed) == 3 and printed[0].startswith("note: vignetting at 24 mm f/2.8 focus inf: pa k1 ")
    entries = ElementTree.parse(tmp_path / "cli.xml").getroot().findall("lens/calibration/vignetting")
    states = [(24.0, 2.8, 1000.0), (24.0, 4.0, 1.0), (24.0, 8.0, 1000.0)]
    assert [tuple(float(e.get(name)) for name in ("focal", "aperture", "distance")) for e in entries] == states
    for (key, scene), line, state in zip(scenes.items(), printed, states):  # infinity written as 1000 m
        by_lensfun = lensfun_corrected(tmp_path / "cli.xml", scene.gain, *state)
        by_camcal = correct_flat_field(scene.gain, load_flat_field(flats[key]))
        deviation = float(line.split("within ")[1].split(" %")[0]) / 100
        from_truth, from_camcal = (float(np.max(np.abs(by_lensfun / other - 1.0))) for other in (1.0, by_camcal))
        print(f"{key}: Lensfun's correction of the true falloff within {100 * from_truth:.3f} %, of camcal's "
              f"{100 * from_camcal:.3f} %; printed {100 * deviation:.2f} %")
        assert from_camcal == pytest.approx(deviation, rel=0.1, abs=0.0005), key  # what the entry misses, printed
        if key in FALLOFF:
            assert from_truth < 0.005 and deviation < 0.01, key
        else:
            assert from_camcal > 0.02, key


def test_bad_vignetting_is_one_line_and_nothing_written(profile, tmp_path, capsys):
    flat, _ = flat_file(tmp_path, "flat", np.tile(FALLOFF["24mm@inf/f2.8"], (3, 1)), 50)
    wide = tmp_path / "wide.json"
    camcal.fit_flat_field(imwrite(tmp_path / "wide.exr", np.ascontiguousarray(
        render_grey_card(51, size=(640, 320)).image[:, :, ::-1]).astype(np.float32)), out=wide)
    rig = tmp_path / "cam.rig.json"
    camcal.Rig((camcal.Camera("cam", SIZE, np.array([[300.0, 0, 240], [0, 300.0, 160], [0, 0, 1]]),
                              Distortion.none(), np.eye(3), np.zeros(3)),)).save(rig)
    out = tmp_path / "out.xml"
    cases = [
        (profile, {"24mm@inf": flat}, "lensfun", "expected FOCALmm@FOCUSm/fN"),
        (profile, {"24mm@inf/4": flat}, "lensfun", "expected FOCALmm@FOCUSm/fN"),
        (profile, {"70mm@inf/f4": flat}, "lensfun", "outside the profile's calibrated range (24 mm, focus 1 m "
                                                    "to inf)"),
        (profile, {"30mm@0.5m/f4": flat}, "lensfun", "outside the profile's calibrated range"),
        (profile, {"24mm@inf/f4": flat, "24mm@infinity/f4.0": flat}, "lensfun", "are the same lens state"),
        (profile, {"24mm@inf/f4": wide}, "lensfun", "the flat field is of 640x320 images (aspect ratio 2.003), the "
                                                    "lens' images have 1.502"),
        (profile, {"24mm@inf/f4": tmp_path / "missing.json"}, "lensfun", "missing.json"),
        (profile, {"24mm@inf/f4": flat}, "3de", "--vignetting applies to lensfun, not 3de"),
        (rig, {"24mm@inf/f4": flat}, "lensfun", "--vignetting applies to a lens profile's lensfun export"),
    ]
    for source, vignetting, to, message in cases:
        target = out.with_suffix(".txt") if to == "3de" else out
        with pytest.raises(camcal.CamcalError) as raised:
            camcal.export_rig(source, target, to, vignetting=vignetting)
        assert message in str(raised.value), str(raised.value)
        code, _, err = cli(["rig", "export", source, target, "--to", to, "--vignetting",
                            *(f"{key}={path}" for key, path in vignetting.items())], capsys)
        assert code == 2 and err.strip() == f"camcal: error: {raised.value}"
        assert not target.exists() and not list(tmp_path.glob(".out*"))
