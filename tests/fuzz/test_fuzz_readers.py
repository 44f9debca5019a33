"""Every reader against valid files mutated at random and random bytes: a valid result or one-line CamcalError.

Mutations (applied one to four at a time): truncation, a flipped bit,
inserted random bytes, a number replaced by a huge, tiny, negative or
non-finite one or by a value of the wrong type, a random span replaced by
such a token, deep nesting, a duplicated line (duplicate keys in JSON and
YAML), a deleted line. Any other outcome (an exception other than
:class:`CamcalError`, or a message of more than one line) fails the test
with the input that caused it; every such input found is kept below as an
``@example`` beside the reader's test, with the fix in the reader.

Readers: rig JSON, colour fit and match JSON, OpenCV YAML, Kalibr YAML,
COLMAP text, USD (.usda), Nuke, patch CSV, points CSV, matches CSV, lines
JSON, timestamps CSV (read, then synchronised), frame lists, camera specs (NAME=VALUE), board specs. COLMAP's binary
model is not read by camcal (``rig import --from colmap`` names the
converter to run), so it has no reader here.

Profiles: see :mod:`fuzzing` (``CAMCAL_FUZZ=long`` in ``make fuzz``).
"""

import argparse
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from fuzzing import EXAMPLES, FUZZ
from hypothesis import example, given
from hypothesis import strategies as st

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import parse_frames
from camcal.cli import main
from camcal.cli.options import NamedValues
from camcal.colour.chart.patches import PatchSet
from camcal.io.colourfile import load_colour_file, load_match
from camcal.io.patches import read_patch_csv, write_patch_csv
from camcal.geometry.board import parse_board
from camcal.geometry.lines import LineSet
from camcal.io.interchange import export_rig, import_rig
from camcal.io.lines import read_lines, write_lines
from camcal.io.matches import read_matches_csv
from camcal.io.points_csv import read_correspondences, write_correspondences
from camcal.io.timestamps import read_timestamps, synchronise
from camcal.model.rig import Rig
from camcal.synthetic import example_camera, points_in_view

# -- the inputs ------------------------------------------------------------------

NASTY = [b"NaN", b"nan", b".nan", b"Infinity", b"-inf", b".inf", b"1e308", b"1e309", b"-1e308", b"9" * 400,
         b"9" * 5000, b"0", b"-0", b"1e-320", b"-1", b"4294967296", b"18446744073709551616", b"1e400", b'"x"',
         b"'x'", b"[]", b"{}", b"null", b"true", b"~", b"[" * 50, b"\x00", b"\xff\xfe", b"", b"\n", b",", b":",
         b"- ", b"=", b"\"", b"#", b"!!binary", b"&a", b"*a", b"%YAML:1.0", b"\\", b"0x10", b"1_000", b"\t"]
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


@st.composite
def mutated(draw, seed: bytes) -> bytes:
    """``seed`` with one to four random mutations (see the module docstring)."""
    data = seed
    for _ in range(draw(st.integers(1, 4))):
        if not data:
            break
        kind = draw(st.sampled_from(("truncate", "flip", "insert", "number", "token", "nest", "duplicate",
                                     "delete")))
        at = draw(st.integers(0, len(data) - 1))
        if kind == "truncate":
            data = data[:at]
        elif kind == "flip":
            data = data[:at] + bytes([data[at] ^ (1 << draw(st.integers(0, 7)))]) + data[at + 1:]
        elif kind == "insert":
            data = data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
        elif kind == "number":
            numbers = list(NUMBER.finditer(data))
            if numbers:
                match = draw(st.sampled_from(numbers))
                data = data[:match.start()] + draw(st.sampled_from(NASTY)) + data[match.end():]
        elif kind == "token":
            end = min(len(data), at + draw(st.integers(0, 8)))
            data = data[:at] + draw(st.sampled_from(NASTY)) + data[end:]
        elif kind == "nest":
            depth = draw(st.sampled_from((10, 100, 5000)))
            opening, closing = draw(st.sampled_from(((b"[", b"]"), (b"{\"a\":", b"}"), (b"- ", b""))))
            data = data[:at] + opening * depth + b"1" + closing * depth + data[at:]
        else:
            lines = data.split(b"\n")
            row = draw(st.integers(0, len(lines) - 1))
            if kind == "duplicate":
                lines.insert(row, lines[row])
            else:
                del lines[row]
            data = b"\n".join(lines)
    return data


def inputs(seed: bytes):
    """Mutated ``seed`` (mostly) or random bytes."""
    return st.one_of(mutated(seed), mutated(seed), mutated(seed), st.binary(max_size=600))


def run_reader(name: str, read, *args) -> None:
    """``read(*args)``: any result, or CamcalError with one non-empty line; counted in the summary."""
    EXAMPLES[name] += 1
    try:
        read(*args)
    except CamcalError as error:
        message = str(error)
        assert message.strip() and "\n" not in message.strip(), f"{name}: not one line: {message!r}"


class Files:
    """A scratch folder for the mutated files (Hypothesis reruns the test body; pytest's tmp_path is per test)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.count = 0

    def write(self, name: str, content: bytes) -> Path:
        self.count += 1
        folder = self.root / f"{self.count}"
        folder.mkdir()
        path = folder / name
        path.write_bytes(content)
        return path


@pytest.fixture(scope="module")
def files():
    root = Path(tempfile.mkdtemp(prefix="camcal-fuzz-"))
    yield Files(root)
    shutil.rmtree(root, ignore_errors=True)


# -- the seeds: valid files, written once ---------------------------------------------


def _seeds() -> dict[str, bytes | dict[str, bytes]]:
    root = Path(tempfile.mkdtemp(prefix="camcal-fuzz-seeds-"))
    try:
        left = example_camera("left")
        rig = Rig((left, example_camera("right", centre=(0.7, -6.0, 1.4))))
        rig.save(root / "a.rig.json")
        seeds: dict = {"rig": (root / "a.rig.json").read_bytes()}
        for fmt, name in (("opencv", "cam.yaml"), ("kalibr", "camchain.yaml"), ("usd", "rig.usda"),
                          ("nuke", "rig.nk")):
            export_rig(rig, fmt, root / fmt / name, rig_path=root / "a.rig.json")
            seeds[fmt] = (root / fmt / name).read_bytes()
        export_rig(rig, "colmap", root / "colmap", rig_path=root / "a.rig.json")
        seeds["colmap"] = {p.name: p.read_bytes() for p in sorted((root / "colmap").iterdir())}
        rng = np.random.default_rng(3)
        X = points_in_view(left, 12, rng)
        write_correspondences(root / "points.csv", X, left.project(X))
        seeds["points"] = (root / "points.csv").read_bytes()
        u = left.project(X)
        seeds["matches"] = ("camera_a,u_a,v_a,camera_b,u_b,v_b\n" + "".join(
            f"left,{a:.3f},{b:.3f},right,{a + 5:.3f},{b - 2:.3f}\n" for a, b in u)).encode()
        write_lines(root / "lines.json", LineSet(tuple(np.cumsum(rng.normal(size=(3, 6, 2)), axis=1) + 50),
                                                 (100, 100)))
        seeds["lines"] = (root / "lines.json").read_bytes()
        jitter = np.random.default_rng(4)
        seeds["timestamps"] = ("camera,frame,time\n" + "".join(
            f"cam{c},{k},{10 + c * 0.013 + k / 30 + jitter.uniform(-1e-3, 1e-3)!r}\n" for c in range(2)
            for k in range(6))).encode()
        names = tuple(f"patch{i:02d}" for i in range(24))
        RGB = rng.uniform(0.05, 0.9, (24, 3))
        M = np.array([[0.41, 0.36, 0.18], [0.21, 0.72, 0.07], [0.02, 0.12, 0.95]])
        for camera, gain in (("a", 1.0), ("b", 1.1)):
            write_patch_csv(root / f"{camera}.csv", PatchSet(names, RGB * gain, RGB @ M.T))
            assert main(["colour", "fit", "--patches", str(root / f"{camera}.csv"), "--model", "matrix3x3",
                         "--out", str(root / f"{camera}.colour.json")]) == 0
        assert main(["colour", "match", "--fits", f"a={root}/a.colour.json", f"b={root}/b.colour.json",
                     "--patches", f"a={root}/a.csv", f"b={root}/b.csv", "--out", str(root / "m.colour.json")]) == 0
        seeds["patches"] = (root / "a.csv").read_bytes()
        seeds["colour fit"] = (root / "a.colour.json").read_bytes()
        seeds["colour match"] = (root / "m.colour.json").read_bytes()
        return seeds
    finally:
        shutil.rmtree(root, ignore_errors=True)


SEEDS = _seeds()

#: Inputs the fuzzing found that crashed a reader (fixed there), run first every time.
FOUND = {
    # OpenCV asserts on a root that is no map and on a matrix without dt: cv2.error
    "opencv": [b"%YAML:1.0\n---\n- 1\n- 2\n",
               b"%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
               b"   data: [1, 2, 3, 4, 5, 6, 7, 8, 9]\nimage_width: 10\nimage_height: 10\n",
               # a key that is not UTF-8: UnicodeDecodeError from the binding
               SEEDS["opencv"].replace(b"\nD1:", b"\n\x80D1:")],
    # an integer past the float range: OverflowError where the reader made it a float
    "colour fit": [re.sub(rb"\[0\.4\d*", b"[" + b"9" * 400, SEEDS["colour fit"], count=1)],
    # a string where a number belongs: float("0/0") raised ValueError
    "kalibr": [SEEDS["kalibr"].replace(b"- [0.0, 0.0, 0.0, 1.0]", b"- [0.0, 0/0, 0.0, 1.0]"),
               # an integer past the float range: np.isfinite raised TypeError on the object array
               SEEDS["kalibr"].replace(b"intrinsics: [1500.0", b"intrinsics: [" + b"9" * 400, 1)],
    # pxr's error quotes the bad bytes: str() of the error raised UnicodeDecodeError
    "usd": [SEEDS["usd"].replace(b"#usda 1.0", b"#usda\x80 1.0"),
            # an invalid xformOp name: pxr raised Tf.ErrorException while computing the pose
            SEEDS["usd"].replace(b'xformOpOrder = ["xformOp:transform"]', b'xformOpOrder = ["xformOp;transform"]', 1)],
    # not UTF-8: read_text raised UnicodeDecodeError
    "colmap": [b"\x80" + SEEDS["colmap"]["cameras.txt"]],
    "patches": [b"\xee" + SEEDS["patches"][1:],
                # an opening quote makes the header one cell holding every line: the message had newlines
                b'"' + SEEDS["patches"]],
    "matches": [b"\x80"],
    # past Python's 4300-digit int conversion limit: ValueError
    "frames": ["9" * 5000],
    # a newline inside an entry: the message had two lines
    "camera specs": [["left=shots/left*.jpg", "left=shots/left*.jpg\nleft=shots/left*.jpg"]],
}


# -- file readers ------------------------------------------------------------------


@FUZZ
@given(content=inputs(SEEDS["rig"]))
def test_rig_json(files, content):
    run_reader("rig JSON", Rig.load, files.write("a.rig.json", content))


@FUZZ
@given(content=inputs(SEEDS["colour fit"]))
@example(content=FOUND["colour fit"][0])
def test_colour_fit_json(files, content):
    run_reader("colour fit JSON", load_colour_file, files.write("a.colour.json", content))


@FUZZ
@given(content=inputs(SEEDS["colour match"]))
def test_colour_match_json(files, content):
    run_reader("colour match JSON", load_match, files.write("m.colour.json", content))


@pytest.mark.parametrize("fmt, name", [("opencv", "cam.yaml"), ("kalibr", "camchain.yaml"), ("usd", "rig.usda"),
                                       ("nuke", "rig.nk")])
def test_camera_files(files, fmt, name):
    def fuzz(content):
        run_reader(f"{fmt} import", import_rig, files.write(name, content), fmt)

    for content in FOUND.get(fmt, ()):
        fuzz = example(content=content)(fuzz)
    FUZZ(given(content=inputs(SEEDS[fmt]))(fuzz))()


@FUZZ
@given(which=st.sampled_from(sorted(SEEDS["colmap"])), data=st.data())
def test_colmap_text(files, which, data):
    folder = files.write("cameras.txt", b"").parent
    for name, content in SEEDS["colmap"].items():
        (folder / name).write_bytes(data.draw(inputs(content)) if name == which else content)
    run_reader("colmap import", import_rig, folder, "colmap")


@pytest.mark.parametrize("content", FOUND["colmap"])
def test_colmap_text_found(files, content):
    folder = files.write("cameras.txt", content).parent
    for name, seed in SEEDS["colmap"].items():
        if name != "cameras.txt":
            (folder / name).write_bytes(seed)
    run_reader("colmap import", import_rig, folder, "colmap")


@FUZZ
@given(content=inputs(SEEDS["patches"]))
@example(content=FOUND["patches"][0])
@example(content=FOUND["patches"][1])
def test_patch_csv(files, content):
    run_reader("patch CSV", read_patch_csv, files.write("p.csv", content))


@FUZZ
@given(content=inputs(SEEDS["points"]))
def test_points_csv(files, content):
    run_reader("points CSV", read_correspondences, files.write("points.csv", content))


@FUZZ
@given(content=inputs(SEEDS["matches"]))
@example(content=FOUND["matches"][0])
def test_matches_csv(files, content):
    run_reader("matches CSV", read_matches_csv, files.write("matches.csv", content))


@FUZZ
@given(content=inputs(SEEDS["lines"]))
def test_lines_json(files, content):
    run_reader("lines JSON", read_lines, files.write("lines.json", content))


def _synchronised(path):
    timestamps = read_timestamps(path)
    return synchronise(timestamps, sorted(timestamps.times))


@FUZZ
@given(content=inputs(SEEDS["timestamps"]))
def test_timestamps_csv(files, content):
    run_reader("timestamps CSV", _synchronised, files.write("ts.csv", content))


# -- text the user types ---------------------------------------------------------


def texts(*seeds: str):
    """Mutated seeds as text, or any text."""
    mutated_text = st.sampled_from(seeds).flatmap(lambda seed: mutated(seed.encode())).map(
        lambda raw: raw.decode("utf-8", "replace"))
    return st.one_of(mutated_text, mutated_text, st.text(max_size=60))


@FUZZ
@given(text=texts("1001-1240", "1001-1240x2", "1,5,10-12", "-5--1"))
@example(text=FOUND["frames"][0])
def test_frame_lists(text):
    run_reader("frame list", parse_frames, text)


def _camera_specs(values: list[str]) -> dict:
    namespace = argparse.Namespace()
    NamedValues(["--camera"], "camera", metavar="NAME=GLOB")(None, namespace, values, "--camera")
    return namespace.camera


@FUZZ
@given(values=st.lists(texts("left=shots/left*.jpg", "right=/abs/R_*.png", "a=b=c"), min_size=1, max_size=3))
@example(values=FOUND["camera specs"][0])
def test_camera_specs(values):
    run_reader("camera spec", _camera_specs, values)


@FUZZ
@given(text=texts("chessboard:9x6:0.025", "charuco:DICT_5X5_100:7x5:0.04:0.03"))
@example(text="chessboard:4294967296x6:0.025")  # found: numpy asked for 32 GiB of corner ids
@example(text="charuco:DICT_5X5_100:42949672967x5:0.04:0.03")  # found: cv2.error building the board
def test_board_specs(text):
    run_reader("board spec", parse_board, text)
