"""Nothing left behind: every verb that fails on bad input leaves no new file or folder, exit 2.

The outputs are named under folders that do not exist yet (``new/deeper/``),
so a verb that created its output folder, or only its parents, before
failing shows up in the listing of the whole workspace, hidden temporary
folders included. The solve and rectify cases fail after their output
folder was begun (pycolmap finds nothing in plain images; the second
camera's image does not decode), so the temporary folder's removal is what
they check.
"""

import struct
import zlib

import cv2
import numpy as np
import pytest

from camcal.cli import main
from camcal.model.rig import Rig
from camcal.synthetic import example_camera


def _png_declaring(width, height):
    body = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + body + struct.pack(">I", zlib.crc32(body))
    end = struct.pack(">I", 0) + b"IEND" + struct.pack(">I", zlib.crc32(b"IEND"))
    return b"\x89PNG\r\n\x1a\n" + chunk + end


@pytest.fixture
def workspace(tmp_path):
    """Inputs in ``tmp_path/in``; the outputs go under ``tmp_path/new/deeper`` (absent)."""
    root = tmp_path / "in"
    root.mkdir()
    left = example_camera("left")
    Rig((left, example_camera("right", centre=(0.7, -6.0, 1.4)))).save(root / "good.rig.json")
    (root / "corrupt.json").write_text('{"format": "camcal.rig", "version": 1, "cameras": [')
    (root / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    (root / "giant.png").write_bytes(_png_declaring(200_000, 200_000))
    width, height = left.image_size
    cv2.imwrite(str(root / "plate.png"), np.full((height, width), 128, np.uint8))
    cv2.imwrite(str(root / "plain.png"), np.full((120, 160), 128, np.uint8))
    (root / "one").mkdir()
    cv2.imwrite(str(root / "one" / "a.png"), np.full((120, 160), 128, np.uint8))
    (root / "flat").mkdir()
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(root / "flat" / name), np.full((120, 160), 128, np.uint8))
    (root / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    (root / "patches.csv").write_text("R,G,B,X,Y,Z\n0.1,0.2,nan,0.1,0.1,0.1\n")
    (root / "lines.json").write_text('{"image_size": [100, 100], "lines": "not a list"}')
    return tmp_path


# (verb, argv with {in} for the inputs and {out} for tmp_path/new/deeper)
CASES = [
    ("solve one image", "solve {in}/one --out {out}/s"),
    ("solve nothing registered", "solve {in}/flat --features 100 --out {out}/s"),
    ("calibrate board --report", "calibrate board --board chessboard:9x6:1 --images left={in}/plain.png "
     "--out {out}/a.rig.json --report {out}/r --no-cache"),
    ("calibrate board giant header", "calibrate board --board chessboard:9x6:1 --images left={in}/giant.png "
     "--out {out}/a.rig.json --no-cache"),
    ("calibrate board --timestamps", "calibrate board --board chessboard:9x6:1 --images left={in}/plain.png "
     "--timestamps {in}/patches.csv --out {out}/a.rig.json --report {out}/r --no-cache"),
    ("calibrate board video", "calibrate board --board chessboard:9x6:1 --images left={in}/broken.mp4 "
     "--out {out}/a.rig.json --report {out}/r --no-cache"),
    ("undistort video", "undistort {in}/good.rig.json --camera left --images {in}/broken.mp4 --out {out}/u"),
    ("rectify video --write", "rectify {in}/good.rig.json --images left={in}/broken.mp4 right={in}/plate.png "
     "--write {out}/w --out {out}/r.rig.json"),
    ("distortion fit video", "distortion fit {in}/broken.mp4 --out {out}/lens.json --report {out}/r"),
    ("calibrate dlt", "calibrate dlt --points {in}/patches.csv --image-size 640 480 --out {out}/a.rig.json"),
    ("distortion fit --report", "distortion fit --lines {in}/lines.json --out {out}/lens.json --report {out}/r"),
    ("undistort", "undistort {in}/good.rig.json --camera left --images {in}/plate.png {in}/garbage.png --out {out}/u"),
    ("stmap", "stmap {in}/good.rig.json --camera centre --out {out}/s"),
    ("rectify --write", "rectify {in}/good.rig.json --images left={in}/plate.png right={in}/garbage.png "
     "--write {out}/w --report {out}/r --out {out}/r.rig.json"),
    ("rig export colmap", "rig export {in}/good.rig.json {out}/colmap --to colmap --camera centre"),
    ("rig export usd --stmaps", "rig export {in}/corrupt.json {out}/a.usda --to usd --stmaps"),
    ("rig export nuke", "rig export {in}/good.rig.json {out}/a.nk --to nuke --camera centre"),
    ("rig import", "rig import {in}/corrupt.json --from kalibr --out {out}/a.rig.json"),
    ("blender import", "blender import {in}/corrupt.json --blend {out}/a.blend"),
    ("colour fit --report", "colour fit --patches {in}/patches.csv --out {out}/a.colour.json --report {out}/r"),
    ("colour match --report", "colour match {in}/good.rig.json --images left={in}/garbage.png "
     "right={in}/garbage.png --out {out}/m.colour.json --report {out}/r"),
    ("colour sensitivities --report", "colour sensitivities --patches D65={in}/patches.csv --out {out}/c.ssf.json "
     "--report {out}/r"),
    ("colour export --ocio", "colour export {in}/corrupt.json --ocio {out}/o"),
    ("batch", "batch {in}/good.rig.json --camera centre --images {in}/f.%04d.png --frames 1-2 --out {out}/o.%04d.png"),
    ("demo", "demo --stages render,teleport --out {out}/d"),
]


def _listing(root):
    return sorted(str(path.relative_to(root)) for path in root.rglob("*"))


@pytest.mark.parametrize("case, argv", CASES, ids=[case for case, _ in CASES])
def test_a_failed_run_leaves_nothing(case, argv, workspace, capsys):
    before = _listing(workspace)
    code = main(argv.format(**{"in": workspace / "in", "out": workspace / "new" / "deeper"}).split())
    captured = capsys.readouterr()
    assert code == 2, (case, captured.err)
    assert captured.err.splitlines()[-1].startswith("camcal: error: "), captured.err
    assert _listing(workspace) == before, f"{case} left {sorted(set(_listing(workspace)) - set(before))}"


def test_a_giant_header_stops_calibrate_board_in_one_line(workspace, capsys):
    giant = workspace / "in" / "giant.png"
    code = main(["calibrate", "board", "--board", "chessboard:9x6:1", "--images", f"left={giant}",
                 "--out", str(workspace / "a.rig.json"), "--no-cache"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines()[-1] == (f"camcal: error: {giant}: the header declares 200000x200000 pixels "
                                    "(40,000,000,000), over the cap of 268,435,456 image pixels "
                                    "(set CAMCAL_MAX_IMAGE_PIXELS to raise it)"), err


def test_an_existing_output_folder_keeps_its_files(workspace, capsys):
    """``stmap`` into a folder the user already has: its other files stay, a failed run changes nothing."""
    out = workspace / "maps"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    before = _listing(workspace)
    assert main(["stmap", str(workspace / "in" / "good.rig.json"), "--camera", "centre", "--out", str(out)]) == 2
    assert _listing(workspace) == before
    assert main(["stmap", str(workspace / "in" / "good.rig.json"), "--camera", "left", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["left_redistort.exr", "left_undistort.exr",
                                                      "left_undistorted.rig.json", "notes.txt"]
    assert not [p for p in workspace.iterdir() if p.name.startswith(".")]
