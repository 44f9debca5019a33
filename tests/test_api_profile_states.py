"""``calibrate profile --states-from folders | exif | csv``: the lens states and their board images from folder
names, the images' EXIF or a CSV give the profile ``--state`` gives, and bad input is one line, nothing written."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

import camcal
from camcal.model.lens_profile import LensProfile, parse_state
from camcal.pipelines.lens_states import states_from
from test_api_profile import BOARD, STATES, K_of, cli, same_file, write_state

OpenImageIO = pytest.importorskip("OpenImageIO")

#: The rendered states' folder names (two spellings of the grammar) and the lens state their EXIF records.
FOLDERS = {"24mm@1.2m": "24mm_1.2m", "35mm@1.2m": "35mm@1.2m", "50mm@inf": "50mm_inf"}


def write_exif(path: Path, pixels: np.ndarray, focal_mm: float | None, focus_m: float | None) -> Path:
    """``pixels`` as ``path`` (PNG or JPEG) with the EXIF FocalLength and SubjectDistance given (None: absent;
    infinity as EXIF writes it, the numerator 0xFFFFFFFF)."""
    spec = OpenImageIO.ImageSpec(pixels.shape[1], pixels.shape[0], 1, "uint8")
    if focal_mm is not None:
        spec.attribute("Exif:FocalLength", float(focal_mm))
    if focus_m is not None:
        spec.attribute("Exif:SubjectDistance", float(0xFFFFFFFF) if math.isinf(focus_m) else float(focus_m))
    out = OpenImageIO.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(pixels[:, :, None]))  # (H, W, 1)
    out.close()
    return path


@pytest.fixture(scope="module")
def grids(tmp_path_factory) -> Path:
    """The three states of ``test_api_profile`` rendered in folders named after them, each image carrying its
    state in EXIF, and a CSV ``image,focal_mm,focus_m`` beside them."""
    root = tmp_path_factory.mktemp("states")
    rows = ["image,focal_mm,focus_m"]
    for seed, (label, (focal_px, offset)) in enumerate(STATES.items()):
        focal_mm, focus_m = parse_state(label)
        write_state(root / FOLDERS[label], K_of(focal_px, offset), seed)
        for path in sorted((root / FOLDERS[label]).glob("v*.png")):
            write_exif(path, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), focal_mm, focus_m)
            rows.append(f"{FOLDERS[label]}/{path.name},{focal_mm:g},{'inf' if math.isinf(focus_m) else focus_m}")
    (root / "states.csv").write_text("\n".join(rows) + "\n")
    return root


def test_folders_exif_and_a_csv_give_each_state_its_images(grids):
    truth = {label: tuple(sorted((grids / FOLDERS[label]).glob("v*.png"))) for label in STATES}
    assert len({len(paths) for paths in truth.values()}) == 1 and len(truth["24mm@1.2m"]) == 4
    assert states_from("folders", grids) == truth  # the folder's name, "_" read as "@", is the label
    assert states_from("exif", f"{grids}/*/v*.png") == truth  # 50 mm at EXIF's infinity
    assert states_from("csv", grids / "states.csv") == truth


def test_a_profile_from_folders_is_the_profile_of_state(grids, tmp_path, capsys):
    """The API given --state globs and the command given --states-from folders write the same profile, every
    state's focal length its truth."""
    reference = tmp_path / "state.profile.json"
    camcal.calibrate_profile({label: f"{grids}/{FOLDERS[label]}/v*.png" for label in STATES}, BOARD,
                             cache=tmp_path / "corners", progress=False, out=reference)
    code, out, _ = cli(["calibrate", "profile", "--board", BOARD, "--states-from", "folders", grids,
                        "--cache", tmp_path / "corners", "--out", tmp_path / "folders.profile.json"], capsys)
    assert code == 0 and "--states-from folders: 24mm@1.2m (4 images), 35mm@1.2m (4 images)" in out
    same_file(reference, tmp_path / "folders.profile.json")
    profile = LensProfile.load(reference)
    for state in profile.states:
        assert abs(state.params["fx"] - STATES[state.label][0]) < 0.005 * STATES[state.label][0]


def assert_refused(tmp_path: Path, capsys, message: str, *, api: dict | None, argv: list) -> None:
    """The API (``api``: its keywords) and the command refuse with one line containing ``message`` and write
    nothing."""
    out = tmp_path / "out.profile.json"
    if api is not None:
        with pytest.raises(camcal.CamcalError, match=re.escape(message)):
            camcal.calibrate_profile(api.pop("states", None), BOARD, progress=False, out=out, **api)
    code, _, err = cli(["calibrate", "profile", "--board", BOARD, *argv, "--out", out], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_bad_state_sources_are_one_line_and_nothing_written(grids, tmp_path, capsys):
    blank = np.full((24, 32), 128, np.uint8)
    # folder names that are not lens states, every one named
    folders = tmp_path / "folders"
    for name in ("24mm@1.2m", "wide", "35mm-inf", ".hidden"):
        (folders / name).mkdir(parents=True)
    assert_refused(tmp_path, capsys, "sub-folder names that are not lens states: 35mm-inf, wide (expected",
                   api={"states_from": ("folders", folders)}, argv=["--states-from", "folders", folders])
    # an empty state and a state of one image, both named
    states = tmp_path / "states"
    (states / "24mm@1.2m").mkdir(parents=True)
    (states / "35mm_2m").mkdir()
    cv2.imwrite(str(states / "35mm_2m" / "a.png"), blank)
    (states / "35mm_2m" / "notes.txt").write_text("not an image")
    assert_refused(tmp_path, capsys, "at least 3 board images, these have fewer: 24mm@1.2m 0; 35mm@2m 1 (a.png)",
                   api={"states_from": ("folders", states)}, argv=["--states-from", "folders", states])
    # two folders of one state
    (states / "24mm@120cm").mkdir()
    assert_refused(tmp_path, capsys, "24mm@1.2m and 24mm@120cm are the same lens state",
                   api={"states_from": ("folders", states)}, argv=["--states-from", "folders", states])
    # images lacking the EXIF of their lens state, named
    exif = tmp_path / "exif"
    exif.mkdir()
    write_exif(exif / "a.jpg", blank, 24.0, 1.2)
    write_exif(exif / "b.jpg", blank, 24.0, None)
    write_exif(exif / "c.jpg", blank, None, None)
    assert_refused(tmp_path, capsys, "2 of 3 images lack the EXIF FocalLength and SubjectDistance of their lens "
                   "state: b.jpg, c.jpg", api={"states_from": ("exif", f"{exif}/*.jpg")},
                   argv=["--states-from", "exif", f"{exif}/*.jpg"])
    # a CSV naming an image that is not there, or a focus that is not a number
    for row, message in (("v09.png,24,1.2", "states.csv, line 2: image not found: 'v09.png'"),
                         ("24mm_1.2m/v00.png,24,near", "line 2: focus_m must be a number, got 'near'")):
        (tmp_path / "states.csv").write_text(f"image,focal_mm,focus_m\n{row}\n")
        (tmp_path / "24mm_1.2m").mkdir(exist_ok=True)
        cv2.imwrite(str(tmp_path / "24mm_1.2m" / "v00.png"), blank)
        assert_refused(tmp_path, capsys, message, api={"states_from": ("csv", tmp_path / "states.csv")},
                       argv=["--states-from", "csv", tmp_path / "states.csv"])
    # mixed sources: --state with --states-from, two --states-from, neither
    glob = f"{grids}/24mm_1.2m/v*.png"
    assert_refused(tmp_path, capsys, "with --state or with --states-from (one of them)",
                   api={"states": {"24mm@1.2m": glob}, "states_from": ("folders", grids)},
                   argv=["--state", f"24mm@1.2m={glob}", "--states-from", "folders", grids])
    assert_refused(tmp_path, capsys, "--states-from: give one source, got 2 (folders, csv)", api=None,
                   argv=["--states-from", "folders", grids, "--states-from", "csv", grids / "states.csv"])
    assert_refused(tmp_path, capsys, "with --state or with --states-from (one of them)", api={}, argv=[])
    assert_refused(tmp_path, capsys, "unknown source 'names', expected one of: folders, exif, csv",
                   api={"states_from": ("names", grids)}, argv=["--states-from", "names", grids])
