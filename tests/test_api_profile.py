"""``camcal.calibrate_profile`` and ``camcal.lens_rig`` against ``camcal calibrate profile`` and ``camcal lens``
on the same rendered board images at three lens states: the same files, the same error lines, nothing written
on bad input."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

import camcal
from camcal.api.board import BoardCalibration
from camcal.cli import main
from camcal.geometry.board import Detection, parse_board
from camcal.geometry.zhang import calibrate_board as fit_board
from camcal.model.distortion import Distortion
from camcal.model.lens_profile import LensProfile

COLUMNS, ROWS = 6, 4
BOARD = f"chessboard:{COLUMNS}x{ROWS}:0.04"
SIZE = (480, 360)
#: lens state -> (fx px, principal point offset px): a zoom breathing a little, its centre drifting
STATES = {"24mm@1.2m": (330.0, (-2.0, 1.0)), "35mm@1.2m": (480.0, (0.0, 0.0)), "50mm@inf": (680.0, (3.0, -1.5))}


def K_of(focal_px: float, offset: tuple[float, float]) -> np.ndarray:
    return np.array([[focal_px, 0, (SIZE[0] - 1) / 2 + offset[0]], [0, focal_px, (SIZE[1] - 1) / 2 + offset[1]],
                     [0, 0, 1]])


def board_texture(px: int) -> tuple[np.ndarray, np.ndarray]:
    """The board's texture (0.04 m squares, a white margin), ``px`` pixels a square, and the map from its pixels to
    the board's plane (m, its first inner corner at the origin)."""
    squares = np.indices((ROWS + 3, COLUMNS + 3)).sum(axis=0) % 2
    texture = np.where(squares == 1, 25, 230).astype(np.uint8)
    texture[0, :] = texture[-1, :] = texture[:, 0] = texture[:, -1] = 230
    texture = np.kron(texture, np.ones((px, px), np.uint8))
    corner0 = 2 * px - 0.5
    scale = np.array([[0.04 / px, 0, -corner0 * 0.04 / px], [0, 0.04 / px, -corner0 * 0.04 / px], [0, 0, 1]])
    return texture, scale


def render_board(K: np.ndarray, R: np.ndarray, t: np.ndarray, size=SIZE, px: int = 20) -> np.ndarray:
    """The board (0.04 m squares, a white margin) at ``cam_from_board = (R, t)`` through the pinhole ``K``."""
    texture, scale = board_texture(px)
    H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ scale
    return cv2.GaussianBlur(cv2.warpPerspective(texture, H, size, flags=cv2.INTER_AREA, borderValue=128), (0, 0), 0.7)


def write_state(folder: Path, K: np.ndarray, seed: int, size=SIZE, n_views: int = 4) -> str:
    """``n_views`` views of the board filling about half the frame; returns the glob of their files."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    width, height = 0.04 * (COLUMNS + 1), 0.04 * (ROWS + 1)
    centre = np.array([width / 2 - 0.04, height / 2 - 0.04, 0.0])
    outline = np.array([[x, y, 0.0] for x in (-0.04, width - 0.04) for y in (-0.04, height - 0.04)])
    distance = K[0, 0] * width / (0.6 * size[0])
    k = 0
    while k < n_views:
        R = Rotation.from_euler("xyz", rng.uniform(-30, 30, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        t = np.array([*rng.uniform(-0.08, 0.08, 2) * distance, distance]) - R @ centre
        p = (outline @ R.T + t) @ K.T
        if not np.all((p[:, :2] / p[:, 2:] > 8) & (p[:, :2] / p[:, 2:] < np.array(size) - 8)):
            continue
        cv2.imwrite(str(folder / f"v{k:02d}.png"), render_board(K, R, t, size))
        k += 1
    return f"{folder}/v*.png"


@pytest.fixture(scope="module")
def corners(tmp_path_factory) -> Path:
    """One corner cache for the module: each image is detected once (the cache holds the float64 corners)."""
    return tmp_path_factory.mktemp("corners")


@pytest.fixture(scope="module")
def grids(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("grids")
    return {label: write_state(root / label, K_of(*value), seed) for seed, (label, value) in enumerate(STATES.items())}


def cli(argv: list, capsys) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def same_file(a: Path, b: Path) -> None:
    created = re.compile(rb'"created": "[^"]*"')
    assert created.sub(b"", a.read_bytes()) == created.sub(b"", b.read_bytes())


@pytest.fixture(scope="module")
def profile_file(grids, corners, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("profile") / "lens.profile.json"
    camcal.calibrate_profile(grids, BOARD, cache=corners, progress=False, out=out)
    return out


def test_calibrate_profile_api_and_cli_write_the_same_profile(grids, corners, profile_file, tmp_path, capsys):
    code, out, _ = cli(["calibrate", "profile", "--board", BOARD, *(a for label, glob in grids.items()
                                                                    for a in ("--state", f"{label}={glob}")),
                        "--cache", corners, "--suggest", "--out", tmp_path / "lens.profile.json"], capsys)
    assert code == 0
    same_file(profile_file, tmp_path / "lens.profile.json")
    assert "next state to shoot:" in out
    profile = LensProfile.load(profile_file)
    # each state's calibration found its pinhole truth
    for state in profile.states:
        focal, offset = STATES[state.label]
        K = K_of(focal, offset)
        assert abs(state.params["fx"] - K[0, 0]) < max(4 * state.sigma["fx"], 0.005 * K[0, 0])
        assert abs(state.params["cx"] - K[0, 2]) < max(4 * state.sigma["cx"], 2.0)


def test_lens_api_and_cli_write_the_same_rig(profile_file, tmp_path, capsys):
    result = camcal.lens_rig(profile_file, 30.0, 1.2, out=tmp_path / "api.rig.json")
    code, out, _ = cli(["lens", profile_file, "--focal", 30, "--focus", 1.2, "--out", tmp_path / "cli.rig.json"],
                       capsys)
    assert code == 0
    same_file(tmp_path / "api.rig.json", tmp_path / "cli.rig.json")
    # between the states of 24 and 35 mm, focused where they were: fx between theirs
    fx = result.rig.cameras[0].K[0, 0]
    assert STATES["24mm@1.2m"][0] < fx < STATES["35mm@1.2m"][0]
    csv = tmp_path / "shot.csv"
    csv.write_text("frame,focal_mm,focus_m\n" + "".join(f"{f},{24 + f * 0.5},{1.2 + f * 0.2}\n" for f in range(1, 9)))
    per_frame = camcal.lens_rig(profile_file, metadata=csv, out=tmp_path / "api_frames.rig.json").rig
    code, _, _ = cli(["lens", profile_file, "--metadata", csv, "--out", tmp_path / "cli_frames.rig.json"], capsys)
    assert code == 0
    same_file(tmp_path / "api_frames.rig.json", tmp_path / "cli_frames.rig.json")
    assert [frame.index for frame in per_frame.frames] == list(range(1, 9))
    for frame in per_frame.frames:
        lens = frame.lenses["camera"]
        single = camcal.lens_rig(profile_file, lens.focal_mm, lens.focus_m).rig.cameras[0]
        np.testing.assert_allclose(lens.K, single.K, rtol=1e-12)
    focal = [frame.lenses["camera"].K[0, 0] for frame in per_frame.frames]
    assert np.all(np.diff(focal) > 0)  # zooming in


def assert_same_error(api_call, argv, capsys, tmp_path) -> str:
    with pytest.raises(camcal.CamcalError) as raised:
        api_call()
    code, out, err = cli(argv, capsys)
    assert code == 2
    assert err.strip().splitlines()[-1] == f"camcal: error: {raised.value}"  # after the progress bars
    assert not [path for path in tmp_path.iterdir() if path.name.startswith(("out", ".out"))]
    return str(raised.value)


def test_bad_profile_input_is_one_line_and_nothing_written(grids, corners, profile_file, tmp_path, capsys):
    out = tmp_path / "out.profile.json"
    first, second = list(grids.items())[:2]
    base = ["calibrate", "profile", "--board", BOARD, "--cache", corners, "--out", out]
    cases = [
        ({first[0]: first[1], "24mm@120cm": second[1]}, "are the same lens state"),
        ({first[0]: first[1], "24mm": second[1]}, "expected FOCALmm@FOCUSm"),
        ({first[0]: first[1]}, "at least 2 lens states"),
    ]
    # a state of another image size
    small = write_state(tmp_path / "small", K_of(400.0, (0.0, 0.0)), 9, size=(400, 300))
    cases.append(({first[0]: first[1], "70mm@2m": small}, "one camera format per profile"))
    for states, message in cases:
        text = assert_same_error(lambda: camcal.calibrate_profile(states, BOARD, cache=corners, progress=False,
                                                                  out=out),
                                 [*base, *(a for label, g in states.items() for a in ("--state", f"{label}={g}"))],
                                 capsys, tmp_path)
        assert message in text, text
    # a state calibrated on another board, and one with another lens model
    other = tmp_path / "other.rig.json"
    camcal.calibrate_board(first[1], f"chessboard:{COLUMNS}x{ROWS}:0.03", model="polynomial", cache=corners,
                           progress=False, out=other)
    text = assert_same_error(lambda: camcal.calibrate_profile({first[0]: first[1], "90mm@3m": other}, BOARD,
                                                              cache=corners, progress=False, out=out),
                             [*base, "--state", f"{first[0]}={first[1]}", "--state", f"90mm@3m={other}"],
                             capsys, tmp_path)
    assert "every state on one board" in text
    division = tmp_path / "division.rig.json"
    camcal.calibrate_board(second[1], BOARD, model="division", cache=corners, progress=False, out=division)
    text = assert_same_error(lambda: camcal.calibrate_profile({first[0]: first[1], "90mm@3m": division}, BOARD,
                                                              cache=corners, progress=False, out=out),
                             [*base, "--state", f"{first[0]}={first[1]}", "--state", f"90mm@3m={division}"],
                             capsys, tmp_path)
    assert "one lens model per profile" in text


def test_bad_lens_input_is_one_line_and_nothing_written(profile_file, tmp_path, capsys):
    out = tmp_path / "out.rig.json"
    gaps = tmp_path / "gaps.csv"
    gaps.write_text("frame,focal_mm,focus_m\n1,30,2\n2,30,2\n5,31,2\n")
    beyond = tmp_path / "beyond.csv"
    beyond.write_text("frame,focal_mm,focus_m\n1,30,2\n2,60,2\n")
    encoders = tmp_path / "encoders.csv"
    encoders.write_text("frame,focal,focus\n1,0.5,0.5\n2,1.2,0.5\n")
    cases = [
        (dict(focal_mm=80.0, focus_m=2.0), ["--focal", 80, "--focus", 2], "outside the profile's calibrated range"),
        (dict(focal_mm=30.0, focus_m=0.5), ["--focal", 30, "--focus", 0.5], "focus distance 0.5 m is outside"),
        (dict(metadata=gaps), ["--metadata", gaps], "miss 2 frame(s): 3, 4"),
        (dict(metadata=beyond), ["--metadata", beyond], "frame 2: focal length 60 mm is outside"),
        (dict(metadata=encoders, encoders=True), ["--metadata", encoders, "--encoders"], "encoder values run from 0"),
        (dict(focal_mm=0.5, focus_m=1.5, encoders=True), ["--focal", 0.5, "--focus", 1.5, "--encoders"],
         "encoder values run from 0"),
    ]
    for kwargs, argv, message in cases:
        text = assert_same_error(lambda: camcal.lens_rig(profile_file, out=out, **kwargs),
                                 ["lens", profile_file, *argv, "--out", out], capsys, tmp_path)
        assert message in text, text
    # asked for, the extrapolation is made and said
    code, printed, _ = cli(["lens", profile_file, "--focal", 80, "--focus", 2, "--extrapolate", "--out", out], capsys)
    assert code == 0 and "extrapolated beyond the calibrated range" in printed
    # the encoders map through the calibrated ranges as OpenTrackIO's run: zoom 0 wide, focus 0 at infinity
    wide = camcal.lens_rig(profile_file, 0.0, 1.0, encoders=True).states[0]
    assert wide[1:] == (24.0, 1.2)
    far = camcal.lens_rig(profile_file, 1.0, 0.0, encoders=True).states[0]
    assert far[1] == 50.0 and math.isinf(far[2])
    middle = camcal.lens_rig(profile_file, 0.5, 0.5, encoders=True).states[0]
    assert middle[1] == 37.0 and middle[2] == pytest.approx(2.4)  # half of 1 / 1.2 m dioptres


def test_the_profile_file_is_validated(profile_file, tmp_path):
    data = json.loads(profile_file.read_text())
    data["states"][0]["focus_m"] = -1
    bad = tmp_path / "bad.profile.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(camcal.CamcalError, match=r"bad.profile.json: not a lens profile: /states/0/focus_m"):
        LensProfile.load(bad)
    data = json.loads(profile_file.read_text())
    data["surfaces"].pop("k1")
    bad.write_text(json.dumps(data))
    with pytest.raises(camcal.CamcalError, match="one surface per parameter"):
        LensProfile.load(bad)


def test_a_profile_exports_as_a_lens_table_over_its_encoders(profile_file, tmp_path, capsys):
    out = tmp_path / "lens.json"
    code, printed, _ = cli(["rig", "export", profile_file, out, "--to", "lens-table"], capsys)
    assert code == 0 and "samples (5 zoom x 3 focus encoder values)" in printed
    table = json.loads(out.read_text())
    assert table["encoderRanges"]["zoom"]["0"] == 24.0 and table["encoderRanges"]["focus"]["0"] == "inf"
    assert len(table["samples"]) == 15
    for sample in table["samples"]:
        encoders, distance = sample["lens"]["encoders"], sample["lens"]["focusDistance"]
        focus_m = math.inf if distance == "inf" else distance
        # the sample is the profile's camera at the state its encoders stand for
        state = camcal.lens_rig(profile_file, encoders["zoom"], encoders["focus"], encoders=True).states[0]
        assert state[1] == pytest.approx(sample["focalLength_mm"]) and state[2] == pytest.approx(focus_m)
        camera = camcal.lens_rig(profile_file, sample["focalLength_mm"], focus_m).rig.cameras[0]
        np.testing.assert_allclose(sample["K"], camera.K, rtol=1e-12)
    assert table["samples"][0]["lens"]["encoders"] == {"zoom": 0.0, "focus": 0.0}
    assert table["samples"][0]["focalLength_mm"] == 24.0 and table["samples"][0]["lens"]["focusDistance"] == "inf"


def test_a_rig_is_not_a_lens_table(tmp_path, capsys):
    rig = tmp_path / "cam.rig.json"
    camcal.Rig((camcal.Camera("cam", SIZE, K_of(400.0, (0.0, 0.0)), Distortion.none(), np.eye(3), np.zeros(3)),
                )).save(rig)
    out = tmp_path / "out.json"
    text = assert_same_error(lambda: camcal.export_rig(rig, out, "lens-table"),
                             ["rig", "export", rig, out, "--to", "lens-table"], capsys, tmp_path)
    assert "exports a lens profile" in text


def test_profile_states_carry_the_view_jackknife_sigma_that_covers_per_view_errors():
    """A principal point that moves from shot to shot (0.5 px a view, a sensor-shift stabiliser): every corner of
    a view shares its error, which ``sigma^2 (J^T J)^-1`` does not see and the board fit's delete-one-view jackknife
    does (its design effect scales the camera's covariance). 8 states of 5 views: the states' own covariance
    against the truth gives a pooled chi-square of 48 degrees of freedom below its 99 % point (73.7; measured
    47.3); the fit's unscaled covariance, which the profile took before, gave 190. A state read from the
    calibration's rig carries the same covariance."""
    board, size = parse_board("chessboard:9x6:0.03"), (640, 426)
    K = np.array([[600.0, 0.0, 322.0], [0.0, 600.0, 210.0], [0.0, 0.0, 1.0]])
    lens = Distortion("polynomial", {"k1": -0.12, "k2": 0.05})
    centre = board.object_points.mean(axis=0)
    calibrations = {}
    for k in range(8):
        rng = np.random.default_rng(k)
        views = []
        while len(views) < 5:
            R = Rotation.from_euler("xyz", rng.uniform(-35, 35, 3) * [1, 1, 0.3], degrees=True).as_matrix()
            t = np.array([rng.uniform(-0.06, 0.06), rng.uniform(-0.04, 0.04), rng.uniform(0.35, 0.5)]) - R @ centre
            K_shot = K.copy()
            K_shot[:2, 2] += rng.normal(0.0, 0.5, 2)
            px = lens.project_rays(board.object_points @ R.T + t, K_shot)
            if np.all((px > 10) & (px < np.array(size) - 10)):
                views.append(Detection(f"v{len(views):02d}.png", size, np.arange(len(px)),
                                       px + rng.normal(0.0, 0.03, px.shape), "sb"))
        fit = fit_board(board, {"camera": views}, model="polynomial", board_shape="flat")
        calibrations[f"{20 + 5 * k}mm@inf"] = BoardCalibration(fit, board, {}, {"camera": tuple(views)})
    profile = camcal.calibrate_profile(calibrations, board, model="polynomial").profile
    truth = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], **lens.params}
    chi_square = []
    for state in profile.states:
        r = np.array([state.params[name] - truth[name] for name in profile.parameters])
        chi_square.append(float(r @ np.linalg.solve(state.covariance, r)))
    print(f"states' chi-square {np.round(chi_square, 1)}, pooled {sum(chi_square):.1f}")
    assert sum(chi_square) < chi2.ppf(0.99, len(profile.parameters) * len(chi_square))
    from_rigs = camcal.calibrate_profile({label: c.rig for label, c in list(calibrations.items())[:2]}, board,
                                         model="polynomial").profile
    for state, again in zip(profile.states, from_rigs.states):
        assert np.allclose(state.covariance, again.covariance, rtol=1e-9, atol=0.0)
