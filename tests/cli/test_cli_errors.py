"""No traceback for any input: every verb, every class of bad input.

A user's mistake is one line ``camcal: error: ...`` and exit 2 with nothing
written; an internal error is one line naming the verb and ``--debug``,
exit 1; ``--debug`` prints the traceback.
"""

import argparse
import json

import numpy as np
import pytest

from camcal.cli import app, main
from camcal.io.points_csv import write_correspondences
from camcal.model.rig import Rig
from camcal.synthetic import example_camera, points_in_view


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Good and bad input files shared by the cases (read only)."""
    root = tmp_path_factory.mktemp("inputs")
    rig = Rig((example_camera("left"), example_camera("right", centre=(0.7, -6.0, 1.4))))
    rig.save(root / "good.rig.json")
    (root / "empty.json").write_text("")
    (root / "empty.csv").write_text("")
    (root / "corrupt.json").write_text('{"format": "camcal.rig", "version": 1, "cameras": [')
    (root / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    (root / "binary.csv").write_bytes(bytes(range(256)) * 8)
    text = (root / "good.rig.json").read_text()
    data = json.loads(text)
    data["cameras"][0]["c"][0] = float("nan")
    (root / "nan.rig.json").write_text(json.dumps(data))
    data = json.loads(text)
    data["cameras"][0]["distortion"]["model"] = "fisheye-of-doom"
    (root / "unknown_model.rig.json").write_text(json.dumps(data))
    camera = example_camera("cam")
    rng = np.random.default_rng(1)
    X = points_in_view(camera, 20, rng)
    write_correspondences(root / "points.csv", X, camera.project(X))
    lines = (root / "points.csv").read_text().splitlines()
    lines[4] = "inf," + lines[4].split(",", 1)[1]
    (root / "points_inf.csv").write_text("\n".join(lines) + "\n")
    import cv2

    grey = np.full((120, 160), 128, np.uint8)
    cv2.imwrite(str(root / "plain.png"), grey)  # no board, no chart, no lines
    cv2.imwrite(str(root / "small.png"), grey[:40, :50])  # wrong size for the rig's cameras
    (root / "patches.csv").write_text("R,G,B,X,Y,Z\n0.1,0.2,nan,0.1,0.1,0.1\n")
    (root / "lines.json").write_text('{"image_size": [100, 100], "lines": "not a list"}')
    _spectral_inputs(root)
    return root


def _spectral_inputs(root):
    """Spectral patch CSVs (good, with a NaN) and a good ``*.ssf.json`` for the spectral verbs."""
    from camcal.colour.chart.patches import PatchSet
    from camcal.io.patches import write_patch_csv
    from camcal.colour.spectral.data import camera_sensitivities, reflectance_set
    from camcal.colour.spectral.sensitivities import Sensitivities
    from camcal.io.ssf import write_sensitivities

    wl = np.arange(400.0, 701.0, 10.0)
    sens = Sensitivities(wl, camera_sensitivities("Nikon 5100 (NPL)", wl)[1], camera="nikon")
    write_sensitivities(root / "nikon.ssf.json", sens)
    names, R = reflectance_set("BabelColor Average", wl)
    RGB = sens.camera_under("D65").RGB(R)

    def rows(RGB):
        return [",".join([n, *(repr(float(v)) for v in (*rgb, *r))]) for n, rgb, r in zip(names, RGB, R)]

    header = "name,R,G,B," + ",".join(f"{w:g}" for w in wl)
    (root / "spectral.csv").write_text("\n".join([header, *rows(RGB)]) + "\n")
    with_nan = RGB.copy()
    with_nan[3, 2] = np.nan
    (root / "spectral_nan.csv").write_text("\n".join([header, *rows(with_nan)]) + "\n")
    write_patch_csv(root / "chart.csv", PatchSet(tuple(names), RGB, sens.camera_under("D65").XYZ(R)))


# (case id, argv with {in} for the inputs folder and {out} for a fresh output folder)
CASES = [
    ("rig show missing", "rig show {in}/missing.rig.json"),
    ("rig show empty", "rig show {in}/empty.json"),
    ("rig show corrupt", "rig show {in}/corrupt.json"),
    ("rig show non-finite", "rig show {in}/nan.rig.json"),
    ("rig show unknown model", "rig show {in}/unknown_model.rig.json"),
    ("rig export missing", "rig export {in}/missing.rig.json {out}/cam.yaml --to opencv"),
    ("rig export corrupt", "rig export {in}/corrupt.json {out}/cam.yaml --to opencv"),
    ("rig export wrong name", "rig export {in}/good.rig.json {out}/cam.yaml --to opencv --camera centre"),
    ("rig import missing", "rig import {in}/missing.yaml --from opencv --out {out}/a.rig.json"),
    ("rig import corrupt", "rig import {in}/corrupt.json --from kalibr --out {out}/a.rig.json"),
    ("rig import empty", "rig import {in}/empty.json --from opencv --out {out}/a.rig.json"),
    ("calibrate dlt missing", "calibrate dlt --points {in}/missing.csv --image-size 640 480 --out {out}/a.rig.json"),
    ("calibrate dlt empty", "calibrate dlt --points {in}/empty.csv --image-size 640 480 --out {out}/a.rig.json"),
    ("calibrate dlt binary", "calibrate dlt --points {in}/binary.csv --image-size 640 480 --out {out}/a.rig.json"),
    ("calibrate dlt non-finite", "calibrate dlt --points {in}/points_inf.csv --image-size 640 480 --out {out}/a.rig.json"),
    ("calibrate dlt wrong size", "calibrate dlt --points {in}/points.csv --image-size 0 480 --out {out}/a.rig.json"),
    ("calibrate board no match", "calibrate board --board chessboard:9x6:1 --images left={in}/nothing*.png --out {out}/a.rig.json"),
    ("calibrate board wrong pattern", "calibrate board --board chessboard:9y6:1 --images left={in}/plain.png --out {out}/a.rig.json"),
    ("calibrate board absent board", "calibrate board --board chessboard:9x6:1 --images left={in}/plain.png --out {out}/a.rig.json"),
    ("calibrate board corrupt image", "calibrate board --board chessboard:9x6:1 --images left={in}/garbage.png --out {out}/a.rig.json"),
    ("calibrate board duplicate name", "calibrate board --board chessboard:9x6:1 --images a={in}/plain.png a={in}/plain.png --out {out}/a.rig.json"),
    ("calibrate board missing =", "calibrate board --board chessboard:9x6:1 --images {in}/plain.png --out {out}/a.rig.json"),
    ("distortion fit missing", "distortion fit {in}/missing.png --out {out}/lens.json"),
    ("distortion fit corrupt", "distortion fit {in}/garbage.png --out {out}/lens.json"),
    ("distortion fit wrong pattern", "distortion fit --images {in}/plain.png --board chessboard:9by6 --out {out}/lens.json"),
    ("distortion fit absent lines", "distortion fit {in}/plain.png --out {out}/lens.json"),
    ("distortion fit malformed lines", "distortion fit --lines {in}/lines.json --out {out}/lens.json"),
    ("undistort missing rig", "undistort {in}/missing.rig.json --camera left --images {in}/plain.png --out {out}/u"),
    ("undistort wrong name", "undistort {in}/good.rig.json --camera centre --images {in}/plain.png --out {out}/u"),
    ("undistort wrong size", "undistort {in}/good.rig.json --camera left --images {in}/small.png --out {out}/u"),
    ("undistort corrupt image", "undistort {in}/good.rig.json --camera left --images {in}/garbage.png --out {out}/u"),
    ("stmap wrong name", "stmap {in}/good.rig.json --camera centre --out {out}/s"),
    ("stmap corrupt rig", "stmap {in}/corrupt.json --camera left --out {out}/s"),
    ("rectify wrong name", "rectify {in}/good.rig.json --images centre={in}/plain.png --write {out}/w --out {out}/r.rig.json"),
    ("rectify no match", "rectify {in}/good.rig.json --images left={in}/none*.png right={in}/none*.png --write {out}/w --out {out}/r.rig.json"),
    ("rectify duplicate", "rectify {in}/good.rig.json --images left={in}/plain.png --images left={in}/plain.png --out {out}/r.rig.json"),
    ("rectify non-finite alpha", "rectify {in}/good.rig.json --alpha nan --out {out}/r.rig.json"),
    ("rectify missing matches", "rectify {in}/good.rig.json --method hartley --matches {in}/missing.csv --out {out}/r.rig.json"),
    ("solve missing folder", "solve {in}/missing_dir --out {out}/s"),
    ("solve no match", "solve {in} --images left=nothing*.png --out {out}/s"),
    ("solve unknown rig", "solve {in} --images left=plain.png --rig {in}/corrupt.json --out {out}/s"),
    ("blender import missing", "blender import {in}/missing.rig.json --blend {out}/a.blend"),
    ("blender import corrupt", "blender import {in}/corrupt.json --blend {out}/a.blend"),
    ("colour fit absent chart", "colour fit --chart {in}/plain.png --out {out}/a.colour.json"),
    ("colour fit corrupt chart", "colour fit --chart {in}/garbage.png --out {out}/a.colour.json"),
    ("colour fit non-finite patches", "colour fit --patches {in}/patches.csv --out {out}/a.colour.json"),
    ("colour fit empty patches", "colour fit --patches {in}/empty.csv --out {out}/a.colour.json"),
    ("colour fit unknown model", "colour fit --patches {in}/patches.csv --model poly:3 --out {out}/a.colour.json"),
    ("colour export missing", "colour export {in}/missing.colour.json --ocio {out}/o"),
    ("colour export corrupt", "colour export {in}/corrupt.json --ocio {out}/o"),
    ("colour export wrong kind", "colour export {in}/good.rig.json --ocio {out}/o"),
    ("colour fit for-illuminant absent chart", "colour fit --chart {in}/plain.png --for-illuminant A --sensitivities {in}/nikon.ssf.json --out {out}/a.colour.json"),
    ("colour fit for-illuminant corrupt chart", "colour fit --chart {in}/garbage.png --for-illuminant A --sensitivities {in}/nikon.ssf.json --out {out}/a.colour.json"),
    ("colour fit for-illuminant non-finite patches", "colour fit --patches {in}/patches.csv --for-illuminant A --sensitivities {in}/nikon.ssf.json --out {out}/a.colour.json"),
    ("colour fit for-illuminant unknown illuminant", "colour fit --patches {in}/chart.csv --for-illuminant Z9 --sensitivities {in}/nikon.ssf.json --out {out}/a.colour.json"),
    ("colour fit for-illuminant corrupt sensitivities", "colour fit --patches {in}/chart.csv --for-illuminant A --sensitivities {in}/corrupt.json --out {out}/a.colour.json"),
    ("colour fit for-illuminant malformed sensitivities", "colour fit --patches {in}/chart.csv --for-illuminant A --sensitivities {in}/binary.csv --out {out}/a.colour.json"),
    ("colour sensitivities missing chart", "colour sensitivities --chart D65={in}/missing.png --out {out}/c.ssf.json"),
    ("colour sensitivities absent chart", "colour sensitivities --chart D65={in}/plain.png --out {out}/c.ssf.json"),
    ("colour sensitivities corrupt chart", "colour sensitivities --chart D65={in}/garbage.png --out {out}/c.ssf.json"),
    ("colour sensitivities malformed csv", "colour sensitivities --patches D65={in}/binary.csv --out {out}/c.ssf.json"),
    ("colour sensitivities empty csv", "colour sensitivities --patches D65={in}/empty.csv --out {out}/c.ssf.json"),
    ("colour sensitivities non-finite", "colour sensitivities --patches D65={in}/spectral_nan.csv --out {out}/c.ssf.json"),
    ("colour sensitivities unknown illuminant", "colour sensitivities --patches Z9={in}/spectral.csv --out {out}/c.ssf.json"),
    ("colour sensitivities missing =", "colour sensitivities --patches {in}/spectral.csv --out {out}/c.ssf.json"),
    ("colour sensitivities malformed measured", "colour sensitivities --measured {in}/binary.csv --out {out}/c.ssf.json"),
    ("colour match missing images", "colour match {in}/good.rig.json --images left={in}/missing.png right={in}/missing.png --out {out}/m.colour.json"),
    ("colour match corrupt image", "colour match {in}/good.rig.json --images left={in}/garbage.png right={in}/garbage.png --out {out}/m.colour.json"),
    ("colour match unknown model", "colour match {in}/good.rig.json --images left={in}/plain.png right={in}/plain.png --model cubic --out {out}/m.colour.json"),
    ("colour match duplicate", "colour match --patches a={in}/patches.csv a={in}/patches.csv --out {out}/m.colour.json"),
    ("colour sensitivities missing", "colour sensitivities --patches D65={in}/missing.csv --out {out}/c.ssf.json"),
    ("colour sensitivities non-finite", "colour sensitivities --patches D65={in}/patches.csv --out {out}/c.ssf.json"),
    ("colour sensitivities corrupt chart", "colour sensitivities --chart D65={in}/garbage.png --out {out}/c.ssf.json"),
    ("colour sensitivities unknown illuminant", "colour sensitivities --chart D99={in}/plain.png --out {out}/c.ssf.json"),
    ("colour sensitivities missing =", "colour sensitivities --chart {in}/plain.png --out {out}/c.ssf.json"),
    ("batch missing rig", "batch {in}/missing.rig.json --camera left --images {in}/f.%04d.png --frames 1-2 --out {out}/o.%04d.png"),
    ("batch wrong frames", "batch {in}/good.rig.json --camera left --images {in}/f.%04d.png --frames 5-x --out {out}/o.%04d.png"),
    ("batch wrong name", "batch {in}/good.rig.json --camera centre --images {in}/f.%04d.png --frames 1-2 --out {out}/o.%04d.png"),
    ("demo unknown stage", "demo --stages render,teleport --out {out}/d"),
]


@pytest.mark.parametrize("case, argv", CASES, ids=[case for case, _ in CASES])
def test_bad_input_is_one_line_exit_2_nothing_written(case, argv, inputs, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    code = main(argv.format(**{"in": inputs, "out": out}).split())
    captured = capsys.readouterr()
    assert code == 2, (case, captured.err)
    # progress lines may come first; the error is the one last line (a malformed command line: then the hint)
    lines = captured.err.splitlines()
    if lines[-1].startswith("see 'camcal "):
        verb = lines[-1].removeprefix("see '").removesuffix(" --help'")
        assert len(lines) == 2 and lines[0].startswith(f"{verb}: error: "), captured.err
    else:
        messages = [line for line in lines if line.startswith("camcal:")]
        assert len(messages) == 1 and lines[-1].startswith("camcal: error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    assert list(out.iterdir()) == [], f"{case} wrote {list(out.iterdir())}"


def test_json_error_object(inputs, capsys):
    assert main(["rig", "show", str(inputs / "missing.rig.json"), "--json"]) == 2
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["format"] == "camcal.summary" and summary["version"] == 1
    assert summary["verb"] == "rig show" and summary["exit_code"] == 2
    assert "missing.rig.json" in summary["error"] and captured.err.startswith("camcal: error: ")


def _boom(args: argparse.Namespace) -> int:
    raise RuntimeError("a bug raised on purpose")


@pytest.fixture
def broken_rig_show(monkeypatch):
    """``rig show`` whose handler fails like a bug in camcal would."""
    real = app.build_parser

    def build(verbs=None):
        parser = real(verbs)
        for path, leaf in app.leaf_parsers(parser):
            if path == ("rig", "show"):
                leaf.set_defaults(func=_boom)
        return parser

    monkeypatch.setattr(app, "build_parser", build)


def test_internal_error_names_the_verb_and_debug(broken_rig_show, inputs, capsys):
    assert main(["rig", "show", str(inputs / "good.rig.json")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "`camcal rig show`" in err and "RuntimeError: a bug raised on purpose" in err
    assert "run with --debug for the traceback" in err


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_prints_the_traceback(broken_rig_show, inputs, capsys, where):
    argv = ["rig", "show", str(inputs / "good.rig.json")]
    argv = ["--debug", *argv] if where == "before" else [*argv, "--debug"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in _boom" in err
    assert "RuntimeError: a bug raised on purpose" in err


def test_os_error_on_a_user_path_is_bad_input(monkeypatch, inputs, capsys):
    def unreadable(args):
        raise PermissionError(13, "Permission denied", str(inputs / "locked.png"))

    real = app.build_parser

    def build(verbs=None):
        parser = real(verbs)
        for path, leaf in app.leaf_parsers(parser):
            if path == ("rig", "show"):
                leaf.set_defaults(func=unreadable)
        return parser

    monkeypatch.setattr(app, "build_parser", build)
    assert main(["rig", "show", "x"]) == 2
    assert capsys.readouterr().err == f"camcal: error: {inputs / 'locked.png'}: Permission denied\n"


def test_camcal_error_is_not_a_value_error():
    from camcal.base.errors import CamcalError

    assert not issubclass(CamcalError, ValueError)


def test_usage_error_is_one_line_and_a_hint(capsys):
    assert main(["rectify", "--out", "r.rig.json"]) == 2  # RIG missing: argparse's usage error, without its dump
    assert capsys.readouterr().err.splitlines() == [
        "camcal rectify: error: the following arguments are required: RIG", "see 'camcal rectify --help'"]
    assert main(["calibrate", "board", "--board", "chessboard:9x6:1", "--images", "a=x", "--out", "o", "--bogus"]) == 2
    assert capsys.readouterr().err.splitlines() == [  # named after the verb, not the top-level parser
        "camcal calibrate board: error: unrecognized arguments: --bogus", "see 'camcal calibrate board --help'"]


def test_json_object_for_a_malformed_command_line(capsys):
    assert main(["rectify", "--json"]) == 2  # RIG and --out missing: argparse's usage error
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["exit_code"] == 2 and summary["verb"] == "rectify"
    assert summary["error"] == "the following arguments are required: RIG, --out"
    assert captured.err.splitlines()[0] == f"camcal rectify: error: {summary['error']}"
