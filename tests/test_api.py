"""The public Python API (``camcal.calibrate_board``, ``solve``, ``rectify``, ``undistort``, rig files,
``fit_colour``, ``export_colour``) against the command line on the same inputs: the same file byte for byte (its creation time
aside), the same error line; and ``import camcal`` loads no heavy dependency."""

import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import camcal
from camcal.cli import main
from camcal.model.distortion import Distortion

BOARD = "chessboard:9x6:0.04"
SIZE = (480, 360)
K = np.array([[450.0, 0.0, 239.5], [0.0, 450.0, 179.5], [0.0, 0.0, 1.0]])
#: right_from_left: 0.1 m to the right, turned 2 degrees about y
R_RIGHT = Rotation.from_euler("y", -2.0, degrees=True).as_matrix()
HEAVY = ("cv2", "pycolmap", "dask", "distributed", "pxr", "scipy", "colour", "matplotlib", "PyOpenColorIO", "bpy")


def render_board(R: np.ndarray, t: np.ndarray, px: int = 20) -> np.ndarray:
    """The 9x6 board (0.04 m squares, one white square of margin) at ``cam_from_board = (R, t)`` through ``K``:
    a texture of ``px`` pixels per square mapped by its homography, blurred a little."""
    squares = np.indices((9, 12)).sum(axis=0) % 2  # 7 x 10 squares and a margin of one
    texture = np.where(squares == 1, 25, 230).astype(np.uint8)
    texture[0, :] = texture[-1, :] = texture[:, 0] = texture[:, -1] = 230
    texture = np.kron(texture, np.ones((px, px), np.uint8))
    corner0 = 2 * px - 0.5  # the texture pixel of inner corner 0 (pixel centres at integers)
    scale = np.array([[0.04 / px, 0, -corner0 * 0.04 / px], [0, 0.04 / px, -corner0 * 0.04 / px], [0, 0, 1]])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ scale
    image = cv2.warpPerspective(texture, H, SIZE, flags=cv2.INTER_AREA, borderValue=128)
    return cv2.GaussianBlur(image, (0, 0), 0.7)


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    """Six views of the board by a pinhole stereo pair, ``left0K.png`` / ``right0K.png`` (seeded)."""
    folder = tmp_path_factory.mktemp("shots")
    rng = np.random.default_rng(44)
    t_right = -R_RIGHT @ np.array([0.1, 0.0, 0.0])
    centre = np.array([0.16, 0.10, 0.0])
    outline = np.array([[x, y, 0.0] for x in (-0.04, 0.36) for y in (-0.04, 0.24)])
    k = 0
    while k < 6:
        R = Rotation.from_euler("xyz", rng.uniform(-30, 30, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        t = rng.uniform([-0.05, -0.03, 0.45], [0.1, 0.03, 0.65]) - R @ centre
        poses = {"left": (R, t), "right": (R_RIGHT @ R, R_RIGHT @ t + t_right)}
        pixels = [(outline @ Rb.T + tb) @ K.T for Rb, tb in poses.values()]
        if not all(np.all((p[:, :2] / p[:, 2:] > 8) & (p[:, :2] / p[:, 2:] < np.array(SIZE) - 8)) for p in pixels):
            continue
        for name, (Rb, tb) in poses.items():
            cv2.imwrite(str(folder / f"{name}{k:02d}.png"), render_board(Rb, tb))
        k += 1
    return folder


def same_file(a: Path, b: Path) -> None:
    """Byte for byte, but for the rig's creation time (the clock's, to the second)."""
    created = re.compile(rb'"created": "[^"]*"')
    assert created.sub(b"", a.read_bytes()) == created.sub(b"", b.read_bytes())


def cli(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def corners(tmp_path_factory) -> Path:
    """One corner cache for the module: the board is detected once per image (the cache holds the detector's
    float64 corners exactly, so a run that reads it fits what a run that detects fits)."""
    return tmp_path_factory.mktemp("corners")


@pytest.fixture(scope="module")
def stereo_rig(shots, corners, tmp_path_factory) -> Path:
    """The pair calibrated through the API (polynomial lens), for the verbs that take a rig."""
    out = tmp_path_factory.mktemp("rig") / "stereo.rig.json"
    camcal.calibrate_board({"left": f"{shots}/left*.png", "right": f"{shots}/right*.png"}, BOARD,
                           model="polynomial", cache=corners, progress=False, out=out)
    return out


def test_calibrate_board_api_and_cli_write_the_same_rig(shots, corners, tmp_path, capsys):
    images = {"left": f"{shots}/left*.png", "right": f"{shots}/right*.png"}
    result = camcal.calibrate_board(images, BOARD, model="polynomial", holdout="0.2", cache=corners, progress=False,
                                    out=tmp_path / "api.rig.json")
    code, out, _ = cli(["calibrate", "board", "--board", BOARD, "--images", *(f"{n}={g}" for n, g in images.items()),
                        "--model", "polynomial", "--holdout", "0.2", "--cache", corners, "--out",
                        tmp_path / "cli.rig.json"], capsys)
    assert code == 0
    same_file(tmp_path / "api.rig.json", tmp_path / "cli.rig.json")
    # the result holds what the command prints, and the truth it was rendered from
    assert result.lines()[-1] in out and result.passed and result.heldout_rms_px is not None
    right = result.rig.camera("right")
    assert result.rms_px < 0.2 and abs(np.linalg.norm(right.c) - 0.1) < 1e-3
    assert result.quality["right"]["rms_px"] == right.quality["rms_px"] < 0.2
    np.testing.assert_allclose(right.K, K, atol=2.0)
    assert result.save(tmp_path / "again.rig.json").read_text() == (tmp_path / "api.rig.json").read_text()


def test_undistort_api_and_cli_write_the_same_rig_and_images(stereo_rig, shots, tmp_path, capsys):
    files = sorted(shots.glob("left0[01].png"))
    result = camcal.undistort(stereo_rig, "left", files, tmp_path / "api", mode="keep")
    code, _, _ = cli(["undistort", stereo_rig, "--camera", "left", "--images", *files, "--mode", "keep", "--out",
                      tmp_path / "cli"], capsys)
    assert code == 0 and [path.name for path in result.images] == ["left00.png", "left01.png"]
    same_file(tmp_path / "api" / "undistorted.rig.json", tmp_path / "cli" / "undistorted.rig.json")
    for path in result.images:
        assert path.read_bytes() == (tmp_path / "cli" / path.name).read_bytes()
    assert result.camera.distortion.model == "none" and result.rig_path == tmp_path / "api" / "undistorted.rig.json"


def test_rectify_api_and_cli_write_the_same_rig(stereo_rig, shots, tmp_path, capsys):
    images = {"left": f"{shots}/left00.png", "right": f"{shots}/right00.png"}
    result = camcal.rectify(stereo_rig, images=images, out=tmp_path / "api.rig.json", write=tmp_path / "api")
    code, _, _ = cli(["rectify", stereo_rig, "--images", *(f"{n}={g}" for n, g in images.items()),
                      "--out", tmp_path / "cli.rig.json", "--write", tmp_path / "cli"], capsys)
    assert code == 0
    same_file(tmp_path / "api.rig.json", tmp_path / "cli.rig.json")
    assert [path.relative_to(tmp_path / "api") for path in result.images] == \
        [Path("left/left00.png"), Path("right/right00.png")]
    for path in result.images:
        assert path.read_bytes() == (tmp_path / "cli" / path.relative_to(tmp_path / "api")).read_bytes()
    # rectified: the board's corners on the same rows in both images
    rows = []
    for path in result.images:
        found, corners = cv2.findChessboardCorners(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), (9, 6))
        assert found, path
        rows.append(corners.reshape(-1, 2)[:, 1])
    assert np.abs(rows[0] - rows[1]).max() < 1.0


@pytest.mark.parametrize("fmt, name, named", [("opencv", "pair.xml", True), ("nuke", "pair.nk", False),
                                               ("colmap", "model", True)])
def test_rig_export_and_import_through_the_api_and_the_cli(stereo_rig, tmp_path, capsys, fmt, name, named):
    """Both write to the same place in turn (a .nk names its ST-maps by their paths): the same bytes. A .nk says
    its format; the others are named."""
    to = fmt if named else None
    exported = camcal.export_rig(camcal.load_rig(stereo_rig), tmp_path / name, to)
    by_api = {path: path.read_bytes() for path in exported.paths}
    for path in exported.paths:
        path.unlink()
    code, _, _ = cli(["rig", "export", stereo_rig, "--to", fmt, tmp_path / name], capsys)
    assert code == 0 and by_api and all(path.read_bytes() == data for path, data in by_api.items())
    imported = camcal.import_rig(tmp_path / name, to)
    imported.save(tmp_path / "api.rig.json")
    code, _, _ = cli(["rig", "import", tmp_path / name, "--from", fmt, "--out", tmp_path / "cli.rig.json"], capsys)
    assert code == 0
    same_file(tmp_path / "api.rig.json", tmp_path / "cli.rig.json")
    original = camcal.load_rig(stereo_rig)
    with pytest.raises(camcal.CamcalError, match="yaml"):  # OpenCV's or Kalibr's: the name does not say
        camcal.export_rig(stereo_rig, tmp_path / "pair.yaml")
    assert not (tmp_path / "pair.yaml").exists()
    for camera in imported.rig.cameras:  # Nuke holds one focal length: fy = fx, 5e-5 from the calibrated fy
        np.testing.assert_allclose(camera.K, original.camera(camera.name).K, rtol=1e-4 if fmt == "nuke" else 1e-9)


@pytest.mark.slow
def test_solve_api_and_cli_write_the_same_rig(tmp_path, capsys):
    from camcal.synthetic import render_stereo_sequence

    width, height = 256, 192
    focal = 500.0 * width / 640
    render_stereo_sequence(tmp_path / "in", n_frames=5, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    result = camcal.solve(tmp_path / "in", tmp_path / "api", features=512, progress=False)
    code, out, _ = cli(["solve", tmp_path / "in", "--features", "512", "--out", tmp_path / "cli"], capsys)
    assert code == 0
    same_file(tmp_path / "api" / "solve.rig.json", tmp_path / "cli" / "solve.rig.json")
    assert result.sfm.n_registered == 10 and result.lines()[0] in out


def test_solve_api_and_cli_refuse_the_same_input(tmp_path, capsys):
    """The fast sibling of the solve comparison: its checks before pycolmap runs, through both."""
    (tmp_path / "in").mkdir()
    for api_call, argv in [
        (lambda: camcal.solve(tmp_path / "nope", tmp_path / "o"),
         ["solve", tmp_path / "nope", "--out", tmp_path / "o"]),
        (lambda: camcal.solve(tmp_path / "in", tmp_path / "o", features=50),
         ["solve", tmp_path / "in", "--features", "50", "--out", tmp_path / "o"]),
    ]:
        assert_same_error(api_call, argv, capsys)
    assert not (tmp_path / "o").exists()


def assert_same_error(api_call, argv, capsys) -> str:
    """The API raises CamcalError with the very line the command prints after ``camcal: error:``, exit 2."""
    with pytest.raises(camcal.CamcalError) as raised:
        api_call()
    code, _, err = cli(argv, capsys)
    assert code == 2 and err.strip().splitlines()[-1] == f"camcal: error: {raised.value}"
    return str(raised.value)


def bad_board_inputs(shots, tmp_path):
    """(API call, argv) pairs for calibrate board's checks, each refused before anything is written."""
    left = f"left={shots}/left*.png"
    base = ["calibrate", "board", "--board", BOARD, "--out", tmp_path / "x.rig.json", "--no-cache"]
    return [
        (lambda: camcal.calibrate_board({"left": f"{shots}/left*.png"}, BOARD, every=0),
         [*base, "--images", left, "--every", "0"]),
        (lambda: camcal.calibrate_board({"left": f"{shots}/nothing*.png"}, BOARD),
         [*base, "--images", f"left={shots}/nothing*.png"]),
        (lambda: camcal.calibrate_board({"left": f"{shots}/left*.png"}, BOARD, refine_intrinsics=True),
         [*base, "--images", left, "--refine-intrinsics"]),
        (lambda: camcal.calibrate_board({"left": f"{shots}/left*.png"}, "chessboard:9:0.04"),
         [*base[:3], "chessboard:9:0.04", *base[4:], "--images", left]),
        (lambda: camcal.calibrate_board({"left": f"{shots}/left*.png"}, BOARD, holdout="x", cache=False,
                                        progress=False),
         [*base, "--images", left, "--holdout", "x"]),
    ]


def test_bad_input_raises_the_line_the_command_prints(shots, tmp_path, capsys):
    messages = [assert_same_error(api_call, argv, capsys) for api_call, argv in bad_board_inputs(shots, tmp_path)]
    assert any("--every must be 1 or more, got 0" in m for m in messages)
    assert any("no image matches" in m for m in messages) and any("bad --holdout" in m for m in messages)
    rig = tmp_path / "rig.rig.json"
    camcal.Rig((camcal.Camera("left", SIZE, K, Distortion.none(), np.eye(3), np.zeros(3)),)).save(rig)
    assert_same_error(lambda: camcal.rectify(rig, alpha=2.0), ["rectify", rig, "--alpha", "2", "--out",
                                                                 tmp_path / "r.rig.json"], capsys)
    assert_same_error(lambda: camcal.undistort(rig, "left", [shots / "left00.png", tmp_path / "a.mp4"], tmp_path / "u"),
                      ["undistort", rig, "--camera", "left", "--images", shots / "left00.png", tmp_path / "a.mp4", "--out",
                       tmp_path / "u"], capsys)
    assert_same_error(lambda: camcal.undistort(rig, "nobody", [shots / "left00.png"], tmp_path / "u"),
                      ["undistort", rig, "--camera", "nobody", "--images", shots / "left00.png", "--out", tmp_path / "u"], capsys)
    assert not any((tmp_path / name).exists() for name in ("x.rig.json", "r.rig.json", "u"))


def test_the_quality_gate_refuses_in_the_api_as_in_the_command(shots, corners, tmp_path, capsys, monkeypatch):
    """A gate of 0.001 px refuses the pair (RMS about 0.03 px): CamcalError and exit 2, nothing written; with
    force, the rig is written, its problems listed and the command exits 3."""
    import camcal.geometry.zhang_result as zhang_result

    monkeypatch.setattr(zhang_result, "MAX_RMS_PX", 0.001)
    images = {"left": f"{shots}/left*.png"}
    argv = ["calibrate", "board", "--board", BOARD, "--images", f"left={shots}/left*.png", "--model", "polynomial",
            "--cache", corners, "--out", tmp_path / "cli.rig.json"]
    message = assert_same_error(lambda: camcal.calibrate_board(images, BOARD, model="polynomial", cache=corners,
                                                               progress=False, out=tmp_path / "api.rig.json"),
                                argv, capsys)
    assert message.startswith("calibration refused") and "RMS" in message
    assert not (tmp_path / "api.rig.json").exists() and not (tmp_path / "cli.rig.json").exists()
    forced = camcal.calibrate_board(images, BOARD, model="polynomial", cache=corners, progress=False, force=True,
                                    out=tmp_path / "api.rig.json")
    code, out, _ = cli([*argv, "--force"], capsys)
    assert code == 3 and not forced.passed and forced.quality_problems[0] in out
    same_file(tmp_path / "api.rig.json", tmp_path / "cli.rig.json")


def test_colour_fit_api_and_cli_write_the_same_file(sim, tmp_path, capsys):
    from camcal.colour.chart.patches import PatchSet
    from camcal.io.patches import write_patch_csv

    train, test = tmp_path / "train.csv", tmp_path / "test.csv"
    write_patch_csv(train, PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train))
    write_patch_csv(test, PatchSet(sim.names_test, sim.RGB_test, sim.XYZ_test))
    result = camcal.fit_colour(train, test_patches=test, illuminant="D65", model="matrix3x3", camera="nikon",
                               out=tmp_path / "api.colour.json")
    code, out, _ = cli(["colour", "fit", "--patches", train, "--test-patches", test, "--illuminant", "D65",
                        "--model", "matrix3x3", "--camera-name", "nikon", "--out", tmp_path / "cli.colour.json"], capsys)
    assert code == 0 and result.lines()[0] in out
    same_file(tmp_path / "api.colour.json", tmp_path / "cli.colour.json")
    # the simulated camera is linear: a 3x3 matrix fits its held-out colours closely
    assert result.figures()["delta_E2000"]["test"]["n"] == len(sim.names_test)
    assert result.outcome.result.stats_test.mean < 3.0
    assert_same_error(lambda: camcal.fit_colour(train, detector="cv2.mcc"),
                      ["colour", "fit", "--patches", train, "--detector", "cv2.mcc", "--out", tmp_path / "x.json"],
                      capsys)


@pytest.fixture(scope="module")
def train_csv(sim, tmp_path_factory) -> Path:
    from camcal.colour.chart.patches import PatchSet
    from camcal.io.patches import write_patch_csv

    path = tmp_path_factory.mktemp("colour") / "train.csv"
    write_patch_csv(path, PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train))
    return path


def without_creation_time(icc: bytes) -> bytes:
    """An ICC profile's bytes but its header's creation time (ICC.1:2010 7.2.1, bytes 24-35) and the profile ID
    computed over it (7.2.18, bytes 84-99)."""
    return icc[:24] + bytes(12) + icc[36:84] + bytes(16) + icc[100:]


@pytest.mark.parametrize("model, options", [
    ("matrix3x3", {}),
    ("matrix3x3", {"ocio_version": "2.5", "family": "Input/Witness", "icc_version": 2, "adaptation": "CAT02"}),
    pytest.param("root-polynomial:2", {}, marks=pytest.mark.slow),  # baked: a CLF and ICC CLUTs, 30 s a run
])
def test_colour_export_api_and_cli_write_the_same_files(train_csv, tmp_path, capsys, model, options):
    """The OCIO config, its CLFs and the ICC profile, byte for byte; the figures are the profile's own."""
    from camcal.colour.export.icc import check_icc
    from camcal.colour.export.ocio_config import STUDIO_CONFIG

    ocio = pytest.importorskip("PyOpenColorIO")
    wanted = options.get("ocio_version", "2.3")
    if tuple(map(int, ocio.__version__.split(".")[:2])) < tuple(map(int, wanted.split("."))):
        pytest.skip(f"needs OpenColorIO {wanted} or newer (profile {wanted}); installed: {ocio.__version__}")
    fit = tmp_path / "nikon.colour.json"
    camcal.fit_colour(train_csv, illuminant="D65", model=model, camera="nikon", out=fit)
    result = camcal.export_colour([fit], ocio=tmp_path / "api", icc=tmp_path / "api.icc", base="camcal", **options)
    flags = {"ocio_version": "--ocio-version", "family": "--family", "icc_version": "--icc-version",
             "adaptation": "--adaptation"}
    code, out, _ = cli(["colour", "export", fit, "--ocio", tmp_path / "cli", "--icc", tmp_path / "cli.icc",
                        "--base", "camcal", *(arg for key, value in options.items() for arg in (flags[key], value))],
                       capsys)
    assert code == 0 and out.splitlines() == [line.replace(str(tmp_path / "api"), str(tmp_path / "cli"))
                                             for line in result.lines()]
    written = sorted(path.relative_to(tmp_path / "api") for path in (tmp_path / "api").rglob("*") if path.is_file())
    assert written == sorted(path.relative_to(tmp_path / "cli") for path in (tmp_path / "cli").rglob("*")
                             if path.is_file())
    assert [path for path, kind in result.files if kind != "icc"] == [tmp_path / "api" / name for name in written]
    for name in written:
        same_file(tmp_path / "api" / name, tmp_path / "cli" / name)
    data = (tmp_path / "api.icc").read_bytes()
    assert data == result.icc.data and without_creation_time(data) == without_creation_time(
        (tmp_path / "cli.icc").read_bytes())
    check_icc(data)
    # the header says the version asked for (ICC.1 7.2.4: byte 8 the major version)
    assert data[8] == options.get("icc_version", 4) == result.figures()["icc"]["version"]
    figures = result.figures()
    config = (tmp_path / "api" / "config.ocio").read_text()
    # camcal's base is a 2.1 config: an older base than ocio_version keeps its version
    assert figures["ocio_profile_version"] == "2.1" and config.startswith("ocio_profile_version: 2.1")
    [space] = figures["spaces"]
    assert space["camera"] == "nikon" and (space["clf"] is None) == (model == "matrix3x3")
    if "family" in options:
        assert f"family: {options['family']}" in config
    # the signature's default base is the command's
    import inspect

    assert inspect.signature(camcal.export_colour).parameters["base"].default == STUDIO_CONFIG


def test_colour_export_api_and_cli_refuse_the_same_input(train_csv, tmp_path, capsys):
    fit = tmp_path / "nikon.colour.json"
    camcal.fit_colour(train_csv, illuminant="D65", model="matrix3x3", camera="nikon", out=fit)
    message = assert_same_error(lambda: camcal.export_colour([fit, fit], icc=tmp_path / "x.icc"),
                                ["colour", "export", fit, fit, "--icc", tmp_path / "x.icc"], capsys)
    assert message == "--icc writes one profile: give one fit, got 2"
    for option, value in (("family", "Input/Witness"), ("ocio_version", "2.3")):
        assert_same_error(lambda: camcal.export_colour([fit], icc=tmp_path / "x.icc", **{option: value}),
                          ["colour", "export", fit, "--icc", tmp_path / "x.icc", f"--{option.replace('_', '-')}", value],
                          capsys)
    assert_same_error(lambda: camcal.export_colour([fit], ocio=tmp_path / "o", max_bake_error=0.0),
                      ["colour", "export", fit, "--ocio", tmp_path / "o", "--max-bake-error", "0"], capsys)
    assert not (tmp_path / "x.icc").exists() and not (tmp_path / "o").exists()


def test_colour_export_aces_api_and_cli_write_the_same_files(train_csv, tmp_path, capsys):
    """CLF, DCTL byte for byte; the AMF but for its time (the clock's, to the second), its UUIDs equal."""
    fit = tmp_path / "nikon.colour.json"
    camcal.fit_colour(train_csv, illuminant="D65", model="matrix3x3", linearise="gamma-offset", camera="nikon",
                      out=fit)
    outputs = {side: {kind: tmp_path / side / f"nikon.{kind}" for kind in ("clf", "amf", "dctl")}
               for side in ("api", "cli")}
    result = camcal.export_colour([fit], applied=True, **outputs["api"])
    code, out, _ = cli(["colour", "export", fit, "--applied",
                        *(arg for kind, path in outputs["cli"].items() for arg in (f"--{kind}", path))], capsys)
    assert code == 0 and out.splitlines() == [line.replace(str(tmp_path / "api"), str(tmp_path / "cli"))
                                             for line in result.lines()]
    times = re.compile(rb"<aces:(creation|modification)DateTime>[^<]*<")
    for kind in ("clf", "amf", "dctl"):
        api, cli_file = (outputs[side][kind].read_bytes() for side in ("api", "cli"))
        assert times.sub(b"", api) == times.sub(b"", cli_file), kind
    assert [kind for _, kind in result.files] == ["aces clf", "amf", "dctl"]
    aces = result.figures()["aces"]
    assert aces["kind"] == "matrix" and aces["amf_applied"] is True and aces["space"] == "ACES2065-1"
    assert aces["transform_id"] == "urn:ampas:aces:transformId:v2.0:Input.camcal.nikon_D65_to_ACES.a2.v1"
    assert_same_error(lambda: camcal.export_colour([fit], amf=tmp_path / "x.amf"),
                      ["colour", "export", fit, "--amf", tmp_path / "x.amf"], capsys)
    assert not (tmp_path / "x.amf").exists()


def test_import_camcal_loads_no_heavy_dependency():
    """``import camcal`` (and naming the API) imports none of the heavy libraries; using a function does."""
    code = ("import sys, camcal\n"
            "names = [getattr(camcal, name) for name in camcal.__all__ if name in ('load_rig', 'export_rig', "
            "'import_rig', 'calibrate_board', 'solve', 'rectify', 'undistort', 'fit_colour', 'export_colour')]\n"
            f"print([m for m in {HEAVY!r} if m in sys.modules])\n"
            "import camcal.api.board, camcal.geometry.zhang\n"
            f"print([m for m in {HEAVY!r} if m in sys.modules])\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, after = (json.loads(line.replace("'", '"')) for line in run.stdout.splitlines())
    assert before == [] and "cv2" in after  # the check sees a heavy import when one happens


def test_every_public_name_resolves_and_is_documented():
    for name in camcal.__all__:
        value = getattr(camcal, name)
        assert name == "__version__" or (value.__doc__ or "").strip(), name
    assert set(camcal.__all__) <= set(dir(camcal))
    with pytest.raises(AttributeError, match="no attribute 'calibrate'"):
        camcal.calibrate  # noqa: B018
