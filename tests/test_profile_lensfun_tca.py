"""``rig export PROFILE lens.xml --to lensfun --tca FOCALmm=GLOB``: the lateral chromatic aberration of colour
board images rendered with a known ``poly3`` TCA, measured corner by corner in each channel, written as Lensfun's
``<tca>`` and checked by Lensfun itself (lensfunpy): its red and blue source coordinates against the truth
(rendered: ``slow``; from exact corners: fast)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import camcal
from camcal.geometry.board import detect_board, parse_board
from camcal.geometry.lateral_ca import channel_corners, fit_lateral_ca
from camcal.io.lensfun import export_states
from camcal.io.lensfun_tca import TCAState
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from test_api_profile import BOARD, COLUMNS, ROWS, SIZE, K_of, board_texture, cli

lensfunpy = pytest.importorskip("lensfunpy")

#: The lens centre's offset from the image centre (px), and the true poly3 terms (v, c, b) of red and blue in
#: Lensfun's unit, half the shorter side: red magnified 0.17 % at the corners, blue shrunk 0.08 %.
OFFSET = (6.0, -4.0)
TRUE_RED, TRUE_BLUE = np.array([1.0006, 0.0, 0.0004]), np.array([0.9996, 0.0003, -0.0002])
UNIT = (min(SIZE) - 1) / 2


def centre() -> np.ndarray:
    return np.array([(SIZE[0] - 1) / 2 + OFFSET[0], (SIZE[1] - 1) / 2 + OFFSET[1]])


def true_scale(terms: np.ndarray, r: np.ndarray) -> np.ndarray:
    return terms[0] + r * (terms[1] + r * terms[2])


def render_fringed(K: np.ndarray, R: np.ndarray, t: np.ndarray, px: int = 12) -> np.ndarray:
    """The board (as ``test_api_profile.render_board`` draws it) through a lens whose red and blue images are the
    green one scaled by the true poly3 TCA about the lens centre, as BGR: channel X at pixel p shows the board
    point green images at q, ``p - c = (q - c) s_X(|q - c| / unit)`` (solved for q); every channel drawn alike
    (bilinear from the texture, then blurred)."""
    texture, scale = board_texture(px)
    texture = texture.astype(np.float32)
    from_pixel = np.linalg.inv(K @ np.column_stack([R[:, 0], R[:, 1], t]) @ scale)
    width, height = SIZE
    p = np.stack(np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)), axis=-1)
    p -= centre()
    channels = []
    for terms in (TRUE_BLUE, np.array([1.0, 0.0, 0.0]), TRUE_RED):
        q = p.copy()
        for _ in range(6):
            q = p / true_scale(terms, np.linalg.norm(q, axis=-1) / UNIT)[..., None]
        q += centre()
        uvw = np.concatenate([q, np.ones(q.shape[:2] + (1,))], axis=-1) @ from_pixel.T
        uv = (uvw[..., :2] / uvw[..., 2:]).astype(np.float32)
        drawn = cv2.remap(texture, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR, borderValue=128)
        channels.append(cv2.GaussianBlur(drawn, (0, 0), 0.7))
    return np.clip(np.rint(np.stack(channels, axis=-1)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def tca_images(tmp_path_factory) -> str:
    """6 colour views of the board at 24 mm spread over the frame, out to its corners."""
    folder = tmp_path_factory.mktemp("tca")
    rng = np.random.default_rng(7)
    K = K_of(330.0, OFFSET)
    width, height = 0.04 * (COLUMNS + 1), 0.04 * (ROWS + 1)
    board_centre = np.array([width / 2 - 0.04, height / 2 - 0.04, 0.0])
    outline = np.array([[x, y, 0.0] for x in (-0.04, width - 0.04) for y in (-0.04, height - 0.04)])
    distance = K[0, 0] * width / (0.45 * SIZE[0])
    k = 0
    while k < 6:
        R = Rotation.from_euler("xyz", rng.uniform(-25, 25, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        t = np.array([*rng.uniform(-0.3, 0.3, 2) * distance, distance]) - R @ board_centre
        p = (outline @ R.T + t) @ K.T
        if not np.all((p[:, :2] / p[:, 2:] > 8) & (p[:, :2] / p[:, 2:] < np.array(SIZE) - 8)):
            continue
        cv2.imwrite(str(folder / f"t{k:02d}.png"), render_fringed(K, R, t))
        k += 1
    return f"{folder}/t*.png"


def profile_file(folder: Path) -> Path:
    """A lens profile of a 24 mm lens focused at 1 m and at infinity, without distortion, its principal point
    the lens centre."""
    from camcal.geometry.lens_profile import fit_profile
    from camcal.model.lens_profile import LensProfile, LensState, format_state

    parameters = ("fx", "fy", "cx", "cy", "k1", "k2")
    states = []
    for focal in (24.0,):  # one focal length: the Lensfun export fits its distortion once
        for focus in (1.0, math.inf):
            fx = 330.0 * focal / 24.0 * (1.0 + 0.02 / focus)
            states.append(LensState(format_state(focal, focus), focal, focus,
                                    dict(zip(parameters, [fx, fx, *centre(), 0.0, 0.0])),
                                    np.diag([1.0, 1.0, 0.3, 0.3, 0.002, 0.01]) ** 2, 8, 0.2))
    lens = LensProfile("polynomial", SIZE, BOARD, parameters, tuple(states), fit_profile(states, parameters).surfaces)
    return lens.save(folder / "zoom.profile.json")


@pytest.fixture(scope="module")
def profile(tmp_path_factory) -> Path:
    return profile_file(tmp_path_factory.mktemp("profile"))


def lensfun_tca_error(path: Path, focal_mm: float = 24.0) -> tuple[float, float]:
    """How far Lensfun's TCA correction (lensfunpy) samples red and blue from where the true lens put them, at
    most over the frame (px), and how far red moved there at most."""
    database = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
    [lens] = database.lenses
    modifier = lensfunpy.Modifier(lens, lens.crop_factor, *SIZE)
    modifier.initialize(focal_mm, 8.0, 1000.0, flags=lensfunpy.ModifyFlags.TCA)
    coordinates = modifier.apply_subpixel_distortion()  # (H, W, 3, 2): each output pixel's source per channel
    pixels = np.stack(np.meshgrid(np.arange(SIZE[0]), np.arange(SIZE[1])), axis=-1).astype(np.float64)
    offset = pixels - centre()
    r = np.linalg.norm(offset, axis=-1) / UNIT
    np.testing.assert_allclose(coordinates[:, :, 1], pixels, atol=1e-3)  # green stays
    errors = [np.linalg.norm(coordinates[:, :, channel] - centre() - offset * true_scale(terms, r)[..., None],
                             axis=-1).max() for channel, terms in ((0, TRUE_RED), (2, TRUE_BLUE))]
    return float(max(errors)), float(np.linalg.norm(offset * (true_scale(TRUE_RED, r) - 1)[..., None], axis=-1).max())


@pytest.mark.slow
def test_lensfun_moves_red_and_blue_where_the_rendered_lens_put_them(profile, tca_images, tmp_path, capsys):
    """From the rendered colour board (6 views, each corner found in every channel): Lensfun's TCA correction
    samples red and blue where the lens put them, within 0.03 px over the frame (measured 0.022 px, red moved up
    to 0.54 px); the API and the command write the same file and print the corners' residual. Fast siblings:
    ``test_each_channel_finds_the_corners_where_the_lens_put_them`` and
    ``test_exact_corners_give_lensfuns_correction_and_bad_input_is_one_line``."""
    result = camcal.export_rig(profile, tmp_path / "api.xml", "lensfun", tca={"24mm": tca_images})
    code, out, _ = cli(["rig", "export", profile, tmp_path / "cli.xml", "--to", "lensfun", "--tca",
                        f"24mm={tca_images}"], capsys)
    assert code == 0 and (tmp_path / "api.xml").read_bytes() == (tmp_path / "cli.xml").read_bytes()
    [note] = [note for note in result.notes if note.startswith("TCA at 24 mm")]
    assert " corners in 6 / 6 images: poly3 red v " in note
    assert f"note: {note}" in out
    [entry] = ElementTree.parse(tmp_path / "cli.xml").getroot().findall("lens/calibration/tca")
    assert entry.get("model") == "poly3" and entry.get("focal") == "24"
    error, shift = lensfun_tca_error(tmp_path / "cli.xml")
    print(f"red moved up to {shift:.2f} px; Lensfun's red and blue off the truth by at most {error:.4f} px; {note}")
    assert shift > 0.4 and error < 0.03


def test_each_channel_finds_the_corners_where_the_lens_put_them():
    """One rendered colour view: the board's corners found in red and blue sit where the true TCA moves the green
    ones, within 0.03 px (measured 0.006 px)."""
    board = parse_board(BOARD)
    BGR = render_fringed(K_of(330.0, OFFSET), Rotation.from_euler("xyz", [10, -5, 3], degrees=True).as_matrix(),
                         np.array([0.0, 0.0, 0.5]))
    corners, ok = channel_corners(BGR[:, :, ::-1], board, detect_board(board, BGR))
    assert ok.all() and len(corners) == board.n_corners
    green = corners[:, 1]
    r = np.linalg.norm(green - centre(), axis=1) / UNIT
    for channel, terms in ((0, TRUE_RED), (2, TRUE_BLUE)):
        truth = centre() + (green - centre()) * true_scale(terms, r)[:, None]
        assert np.abs(corners[:, channel] - truth).max() < 0.03, channel


def test_exact_corners_give_lensfuns_correction_and_bad_input_is_one_line(tmp_path, capsys):
    """Noise-free corners moved by the true terms give them back, and Lensfun's correction from the entry written
    is the truth to float32 precision; a focal length outside the range, a grey image, images without the board,
    no image, and a rig are refused in one line, nothing written."""
    rng = np.random.default_rng(3)
    green = rng.uniform([0, 0], SIZE, (40, 2))
    moved = [centre() + (green - centre()) * true_scale(terms, np.linalg.norm(green - centre(), axis=1) / UNIT)[:, None]
             for terms in (TRUE_RED, TRUE_BLUE)]
    corners = np.stack([moved[0], green, moved[1]], axis=1)
    fit = fit_lateral_ca(corners, centre(), UNIT)
    np.testing.assert_allclose(fit.red, TRUE_RED, atol=1e-10)
    np.testing.assert_allclose(fit.blue, TRUE_BLUE, atol=1e-10)
    assert fit.max_px.max() < 1e-9
    camera = Camera("lens", SIZE, K_of(330.0, OFFSET), Distortion.none(), np.eye(3), np.zeros(3))
    result = export_states([(24.0, camera)], tmp_path / "lens.xml", name="lens", tca=[TCAState(24.0, corners, SIZE)])
    assert any(note.startswith("TCA at 24 mm from 40 corners") for note in result.notes)
    error, shift = lensfun_tca_error(tmp_path / "lens.xml")
    assert shift > 0.4 and error < 2e-3
    profile = profile_file(tmp_path)
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((SIZE[1], SIZE[0]), 128, np.uint8))
    cv2.imwrite(str(tmp_path / "blank.png"), np.full((SIZE[1], SIZE[0], 3), 128, np.uint8))
    rig = tmp_path / "cam.rig.json"
    Rig((camera,)).save(rig)
    out = tmp_path / "out.xml"
    cases = [
        (profile, {"70mm": f"{tmp_path}/blank.png"}, "--tca 70mm: expected FOCALmm inside the profile's calibrated "
                                                     "range (24 mm)"),
        (profile, {"24mm": f"{tmp_path}/grey.png"}, "grey.png is not an 8-bit colour image"),
        (profile, {"24mm": f"{tmp_path}/blank.png"}, "the board chessboard:6x4:0.04 is found in none of the 1 images"),
        (profile, {"24mm": f"{tmp_path}/none*.png"}, "--tca 24mm="),
        (rig, {"24mm": f"{tmp_path}/blank.png"}, "--tca applies to a lens profile's lensfun export"),
    ]
    for source, tca, message in cases:
        with pytest.raises(camcal.CamcalError) as raised:
            camcal.export_rig(source, out, "lensfun", tca=tca)
        assert message in str(raised.value), str(raised.value)
        code, _, err = cli(["rig", "export", source, out, "--to", "lensfun", "--tca",
                            *(f"{key}={value}" for key, value in tca.items())], capsys)
        assert code == 2 and err.strip() == f"camcal: error: {raised.value}"
        assert not out.exists() and not list(tmp_path.glob(".out*"))
