"""camcal's default lens model (auto) against OpenCV's models on real wide-angle boards, views held out.

The corners are OpenCV's ``findChessboardCornersSB`` (EXHAUSTIVE | ACCURACY) on public real image sets,
committed as ``tests/data/real_boards/*.json`` (sources and licences in that folder's README): every tool
gets the same corners and the same split (every 6th view held out, each posed by PnP with the fitted
intrinsics held), so the lens model and the solver are what is compared (``bench/bench_lens_models.py``
does the same on image folders). Each tool's held-out views are posed against its own board: camcal's default
board shape (flat or fitted, chosen by the folds), OpenCV's release-object fits' refined board, mrcal's warped
board (``+warp``) or the flat board.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.geometry import zhang, zhang_fit, zhang_starts
from camcal.geometry.board import Board, Detection
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from bench_lens_models import opencv_held_out_rms  # noqa: E402  (the bench's posing of held-out views, shared)

DATA = Path(__file__).resolve().parents[1] / "data" / "real_boards"
SETS = ("udacity_gopro", "udacity_dashcam")
MRCAL_PEER = Path(__file__).resolve().parents[2] / "bench" / "mrcal_peer.py"
SYSTEM_PYTHON = "/usr/bin/python3"


def mrcal_available() -> bool:
    try:
        return subprocess.run([SYSTEM_PYTHON, "-c", "import mrcal"], capture_output=True).returncode == 0
    except OSError:
        return False


def load(name: str):
    data = json.loads((DATA / f"{name}.json").read_text())
    board = Board("chessboard", data["board"]["columns"], data["board"]["rows"], 1.0)
    size = tuple(data["image_size"])
    views = [Detection(f"view{n:03d}.jpg", size, np.arange(board.n_corners), np.asarray(corners, np.float64), "sb")
             for n, corners in enumerate(data["corners_px"].values())]
    return board, views


def heldout_rms(board, camera, views) -> float:
    r = np.concatenate([zhang_fit.posed_residuals(board, camera, d) for d in views])
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def release_object_heldout(board, train, held, size, flags: int) -> float:
    """Held-out RMS of OpenCV's release-object fit (``calibrateCameraRO``, Strobl & Hirzinger 2011: the board's
    points refined with the camera), each held-out view posed against the board it estimated."""
    obj = [board.object_points[d.ids].astype(np.float32) for d in train]
    img = [d.corners_px.astype(np.float32).reshape(-1, 1, 2) for d in train]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    _, K, dist, _, _, points = cv2.calibrateCameraRO(obj, img, size, board.columns - 1, None, None, flags=flags,
                                                     criteria=criteria)
    return opencv_held_out_rms(points.reshape(-1, 3).astype(np.float64), held, K, dist)


def opencv_heldout(board, train, held, size) -> dict[str, float]:
    """Held-out RMS of OpenCV's default, rational, rational + thin-prism and fisheye models (flat board), and of its
    rational and rational + thin-prism release-object fits (the board refined, posed against it)."""
    obj = [board.object_points[d.ids].astype(np.float32) for d in train]
    img = [d.corners_px.astype(np.float32).reshape(-1, 1, 2) for d in train]
    out = {}
    for name, flags, n in (("default", 0, 5), ("rational", cv2.CALIB_RATIONAL_MODEL, 8),
                           ("rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL, 12)):
        _, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
        camera = Camera("cv", size, K, Distortion.from_opencv_coefficients(dist.ravel()[:n]), np.eye(3), np.zeros(3))
        out[name] = heldout_rms(board, camera, held)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    _, K, D, _, _ = cv2.fisheye.calibrate([o.reshape(1, -1, 3).astype(np.float64) for o in obj],
                                          [i.reshape(1, -1, 2).astype(np.float64) for i in img], size, None, None,
                                          flags=zhang_starts.fisheye_flags("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW"),
                                          criteria=criteria)
    lens = Distortion("kannala-brandt", dict(zip(("k1", "k2", "k3", "k4"), D.ravel())))
    out["fisheye"] = heldout_rms(board, Camera("cv", size, K, lens, np.eye(3), np.zeros(3)), held)
    for name, flags in (("RO rational", cv2.CALIB_RATIONAL_MODEL),
                        ("RO rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL)):
        out[name] = release_object_heldout(board, train, held, size, flags)
    return out


def mrcal_heldout(board, train, held, size, focal: float, fov_x_deg: float) -> dict[str, float]:
    """Held-out RMS of mrcal's OPENCV8 and splined stereographic models (bench/mrcal_peer.py, the system python3),
    each on a flat board and with mrcal's board warp solved (held-out views posed against its warped board)."""
    fov = min(175, 5 * math.ceil(fov_x_deg * 1.1 / 5))
    out = {}
    for lensmodel in ("LENSMODEL_OPENCV8", f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg={fov}",
                      f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg={fov}"):
        for warp in (False, True):
            spec = {"columns": board.columns, "rows": board.rows, "image_size": list(size), "focal": focal,
                    "lensmodel": lensmodel, "train": {d.image: d.corners_px.tolist() for d in train},
                    "held": {d.image: d.corners_px.tolist() for d in held}, "warp": warp}
            run = subprocess.run([SYSTEM_PYTHON, str(MRCAL_PEER)], input=json.dumps(spec), capture_output=True,
                                 text=True, check=True)
            out[lensmodel + ("+warp" if warp else "")] = json.loads(run.stdout)["heldout_rms_px"]
    return out


@pytest.fixture(scope="module", params=SETS)
def measured(request):
    board, views = load(request.param)
    held = [d for n, d in enumerate(views) if n % 6 == 0]
    train = [d for n, d in enumerate(views) if n % 6]
    result = zhang.calibrate_board(board, {"cam": views}, units="squares", holdout=set(range(0, len(views), 6)))
    return request.param, result, opencv_heldout(board, train, held, views[0].image_size)


@pytest.fixture(scope="module")
def mrcal_measured(measured):
    if not mrcal_available():
        pytest.skip("mrcal is not installed for the system python3 (apt-get install mrcal python3-mrcal)")
    name, result, peers = measured
    board, views = load(name)
    held = [d for n, d in enumerate(views) if n % 6 == 0]
    train = [d for n, d in enumerate(views) if n % 6]
    size = views[0].image_size
    # the peer's set-up owes nothing to camcal: OpenCV's default fit's focal, its rational fit's field of view
    obj = [board.object_points[d.ids].astype(np.float32) for d in train]
    img = [d.corners_px.astype(np.float32).reshape(-1, 1, 2) for d in train]
    focal = cv2.calibrateCamera(obj, img, size, None, None)[1][0, 0]
    _, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None, flags=cv2.CALIB_RATIONAL_MODEL)
    lens = Distortion.from_opencv_coefficients(dist.ravel()[:8])
    edges = lens.rays_from_pixels(np.array([[0.0, K[1, 2]], [size[0] - 1.0, K[1, 2]]]), K)
    fov_x = float(np.degrees(np.arccos(np.clip(edges[0] @ edges[1], -1.0, 1.0))))
    return name, result, mrcal_heldout(board, train, held, size, float(focal), fov_x)


@pytest.mark.slow
def test_default_never_refuses_where_one_of_its_models_fits(measured):
    name, result, _ = measured
    assert any(score.rms_px is not None for score in result.model_ranking)
    assert zhang.quality_problems(result) == [], name
    assert result.heldout_rms_px is not None and np.isfinite(result.heldout_rms_px)


@pytest.mark.slow
def test_default_beats_opencvs_best_model_by_three_percent(measured):
    # OpenCV's flat-board models and its release-object fits (the board's points refined, held-out views posed
    # against that board). Measured (README, "Board shape"): the car camera 0.5619 px held out (kannala-brandt on
    # the board with every corner's height free, chosen by the folds) = 0.935 x OpenCV RO rational (0.6008); it was
    # 0.8295 px (1.090 x) on the flat board. The GoPro: below 0.97 x too (README).
    name, result, peers = measured
    assert result.heldout_rms_px <= 0.97 * min(peers.values()), (name, result.model, result.heldout_rms_px, peers)


@pytest.mark.slow
def test_default_beats_mrcal_by_three_percent(mrcal_measured):
    # mrcal OPENCV8 and splined stereographic (16x12 and 10x8 knots), each on a flat board and with its
    # calobject_warp solved; the same corners and split. The car camera: 0.5619 against mrcal OPENCV8+warp 0.7689.
    name, result, peers = mrcal_measured
    assert result.heldout_rms_px <= 0.97 * min(peers.values()), (name, result.model, result.heldout_rms_px, peers)


@pytest.mark.slow
def test_3de_anamorphic_model_calibrates_the_gopro(monkeypatch):
    """3DE4 Anamorphic Standard Degree 4 on the GoPro's square pixels (a free lens rotation from 0 once wandered
    until corners left the image): it calibrates, and freeing the rotation from the held fit is worth it held out,
    against the same fit with the rotation held (its bound set to 0). The fast sibling of holding it is
    ``test_zhang_tde4``'s square-pixel lens."""
    from camcal.geometry import tde4_fit

    board, views = load("udacity_gopro")
    holdout = set(range(0, len(views), 6))
    free = zhang.calibrate_board(board, {"gopro": views}, model="3de4-anamorphic-deg4", holdout=holdout)
    bound = tde4_fit.MAX_ROTATION_SIGMA_DEG
    monkeypatch.setattr(tde4_fit, "MAX_ROTATION_SIGMA_DEG", 0.0)
    held = zhang.calibrate_board(board, {"gopro": views}, model="3de4-anamorphic-deg4", holdout=holdout)
    sigma = free.rig.cameras[0].quality.sigma["lens_rotation_deg"]
    rotation = free.rig.cameras[0].distortion.params["lens_rotation_deg"]
    print(f"GoPro 3DE4 anamorphic: rotation {rotation:.2f} +/- {sigma:.2f} deg, held out {free.heldout_rms_px:.3f} px "
          f"(rotation held: {held.heldout_rms_px:.3f} px)")
    assert sigma <= bound and not any("held at 0 deg" in note for note in free.notes)
    assert held.rig.cameras[0].distortion.params["lens_rotation_deg"] == 0.0
    assert any("lens rotation held at 0 deg" in note for note in held.notes)
    assert free.heldout_rms_px < held.heldout_rms_px
