"""The cost of camcal's default lens model choice (``model="auto"``) against a single-model fit, and its held-out error.

End to end (``calibrate board`` as the command runs it, :func:`camcal.calibrate_board`: detection, the fit, the
rig; the interpreter's start-up, the same for both, left out): the CPU time (``time.process_time``: this process,
every thread) of the default and of the single-model command for the model it picked (``board_shape="flat"``), each
with a fresh corner cache (detection included), then each again with its cache warm; on the shared stereo pair (the
rig, and its left camera) and on every ``--images NAME DIR PATTERN COLUMNSxROWS`` given.

Per corner set: the CPU time of the fit alone (:func:`camcal.geometry.zhang.calibrate_board`) with the default
(``model="auto"``, ``board_shape="auto"``), with the model it picked named (flat board) and with ``opencv``; the
held-out RMS of the default against OpenCV's best model (default, rational, rational + thin prism, ``cv2.fisheye``,
and the release-object fits ``calibrateCameraRO`` rational and rational + thin prism, each held-out view posed
against the board it estimated) on the same corners and split (every 6th view held out); ``--thorough``: the
thorough ranking (the folds) too. Sets: the shared stereo pair (OpenCV's SB corners, cached with ``--cache``), the
public corner sets of ``tests/data/real_boards``, a dense synthetic 24x17 board seen 21 times by an industrial lens
(OpenCV rational distortion) and a synthetic fisheye (Kannala-Brandt) seen 20 times; synthetic corners carry
0.1 px Gaussian noise (seeded). The floor: one scoring fit of every lens model and one surface fit of every board
shape with the model picked (what a ranking that fits every candidate pays).

Run with ``OPENBLAS_NUM_THREADS=1`` on a shared machine: OpenBLAS threads spinning on busy cores multiply the CPU
time of every dense solve (the jackknife of a single fit: 0.07 s on one thread, 1.3-4.4 s with the default threads
on this two-core machine under a load of 20).

Last run (one BLAS thread, a two-core machine at a load of about 20; the udacity image sets of
``tests/data/real_boards/README.md`` as ``--images``). End to end, fresh cache, default / single: shared pair rig
9.7 / 7.3 s (1.34), its left camera 6.8 / 4.4 s (1.56), GoPro 36 images 28.1 / 21.9 s (1.29), car camera 18
images 10.0 / 9.3 s (1.08): within 2x everywhere. Warm cache: 2.9 / 0.4 s (7.3), 2.5 / 0.1 s (18), 7.5 / 0.4 s
(19), 1.9 / 0.3 s (6.0): the single fit of a plain lens costs 0.1-0.4 s, and fitting every lens model once
(the floor, 2.5-10x it) and one or two board surfaces cannot be within 2x of it. Fit alone and held out (every 6th
view): car camera kannala-brandt on the free surface, 1.29 / 0.29 s, 0.5619 px against OpenCV's best (RO
rational) 0.6008 px (0.935); GoPro kannala-brandt-thin-prism on 6+plane, 13.49 / 0.52 s (two surface fits of that lens: most of it; the
floor, every lens once and every surface once, 29x), 0.2369 px against 0.2449 (RO
rational, 0.967; 273.5 s CPU with the folds before); shared pair left polynomial on 6+plane, 1.65 / 0.12 s,
0.1370 px against 0.1284 (RO rational, 1.067; camcal's opencv lens on that surface: 0.1303); right 1.52 / 0.12 s,
0.1333 against 0.1307 (RO rational + thin prism, 1.020); synthetic 24x17 opencv on the flat board, 7.66 / 0.99 s
(more than 22 minutes with the folds before; fitting every surface once would take 90.5 s, 95x: the first-order
screen fits none on a flat board), 0.1387 px, OpenCV's default the same (OpenCV's release-object fits refuse partial views); synthetic fisheye
kannala-brandt on the flat board, 0.99 / 0.21 s, 0.1414 px against OpenCV's rational 0.1422 (0.994).

``--rotate``: instead of the fit-alone figures, the held-out comparison on every rotation of the split (each view
held out once), with a 95 % interval per rotation from resampling its held-out views. Last run: every view held
out once, the default / OpenCV's best per rotation: shared pair left 1.031 (rotations 0.999-1.067), right 0.964
(0.773-1.020), car camera 0.954 (0.811-1.136), GoPro 1.044 (0.967-1.147), synthetic 24x17 1.000, synthetic
fisheye 0.993 (see docs/benchmarks.md).

Usage: OPENBLAS_NUM_THREADS=1 python bench/bench_auto_cost.py [--cache DIR] [--quick] [--only TEXT] [--thorough]
[--rotate] [--images NAME DIR PATTERN COLUMNSxROWS ...]   (``--quick``: synthetic sets only; ``--only``: the sets
whose name holds TEXT)
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from bench_lens_models import opencv_held_out_rms, opencv_models, posed_rms, release_object_fit, sb_detections
import camcal
from camcal.geometry.board import Board, Detection
from camcal.geometry.board_shape import AUTO_SHAPES
from camcal.geometry.zhang import AUTO_MODELS, SPLINE_SUFFIX, calibrate_board
from camcal.geometry.zhang_fit import calibrate_model
from camcal.geometry.zhang_refit import shape_specs, surface_fit
from camcal.geometry.zhang_starts import FIT_ERRORS, checked_views
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stereo_chessboard"
REAL_BOARDS = Path(__file__).resolve().parents[1] / "tests" / "data" / "real_boards"
NOISE_PX = 0.1
HELD_EVERY = 6
OPTIONS = dict(units="m", outlier_factor=3.0, min_outlier_px=1.0, loss="trivial", loss_scale=1.0)


def projected_views(camera: Camera, board: Board, n: int, seed: int, distance: tuple[float, float],
                    tilt: float = 35.0) -> list[Detection]:
    """``n`` views of ``board`` projected by ``camera`` (the corners inside the frame, at least half the board),
    with :data:`NOISE_PX` noise."""
    rng = np.random.default_rng(seed)
    out, centred = [], board.object_points - board.object_points.mean(axis=0)
    width, height = camera.image_size
    while len(out) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-tilt, tilt, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        z = rng.uniform(*distance)
        X = centred @ R.T + np.array([rng.uniform(-0.3, 0.3) * z, rng.uniform(-0.2, 0.2) * z, z])
        p = camera.project(X)
        inside = np.all((p > 5) & (p < np.array([width, height]) - 5), axis=1) & (X[:, 2] > 0)
        if inside.sum() < board.n_corners // 2:
            continue
        ids = np.flatnonzero(inside)
        out.append(Detection(f"view_{len(out):03d}.png", camera.image_size, ids,
                             p[ids] + rng.normal(0.0, NOISE_PX, (len(ids), 2)), "synthetic"))
    return out


def data_sets(cache: Path | None, quick: bool):
    """(name, board, views) of every set available."""
    if not quick and SHARED.is_dir():
        board = Board("chessboard", 9, 6, 1.0)
        for side in ("left", "right"):
            yield f"shared pair {side}", board, sb_detections(SHARED, f"{side}*.jpg", board, cache)
    for path in sorted(REAL_BOARDS.glob("*.json")) if not quick else ():
        data = json.loads(path.read_text())
        board = Board("chessboard", data["board"]["columns"], data["board"]["rows"], 1.0)
        yield path.stem, board, [Detection(f"view{n:03d}.jpg", tuple(data["image_size"]), np.arange(board.n_corners),
                                           np.asarray(corners, np.float64), "sb")
                                 for n, corners in enumerate(data["corners_px"].values())]
    dense = Board("chessboard", 24, 17, 0.02)
    industrial = Camera("industrial", (2448, 2048), np.array([[3500.0, 0, 1230.3], [0, 3500.0, 1018.7], [0, 0, 1]]),
                        Distortion.from_opencv_coefficients([-0.09, 0.12, 2e-4, -3e-4, -0.05, 0.02, 0.05, -0.03]),
                        np.eye(3), np.zeros(3))
    yield "synthetic 24x17, 21 views", dense, projected_views(industrial, dense, 21, 1, (0.45, 0.8))
    fisheye = Camera("fisheye", (1920, 1080), np.array([[560.0, 0, 962.4], [0, 558.7, 537.9], [0, 0, 1]]),
                     Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}),
                     np.eye(3), np.zeros(3))
    board = Board("chessboard", 9, 6, 0.05)
    yield "synthetic fisheye, 20 views", board, projected_views(fisheye, board, 20, 2, (0.25, 0.6), tilt=45.0)


def timed(function, *args, **kwargs):
    """``(result, CPU seconds)`` of one call."""
    start = time.process_time()
    result = function(*args, **kwargs)
    return result, time.process_time() - start


def opencv_peers(board: Board, train: list[Detection], held: list[Detection]) -> dict[str, np.ndarray]:
    """Held-out RMS of each held-out view (px) under OpenCV's flat-board models (:func:`opencv_models`) and its
    release-object fits (rational, rational + thin prism: the board's points refined, each held-out view posed
    against them)."""
    size = train[0].image_size
    peers = {peer: np.array([posed_rms(board, camera, [view]) for view in held])
             for peer, camera in opencv_models(board, train, size)}
    for name, flags in (("RO rational", cv2.CALIB_RATIONAL_MODEL),
                        ("RO rational+thin-prism", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL)):
        try:
            _, K, dist, points = release_object_fit(board, train, size, flags)
            peers[name] = np.array([opencv_held_out_rms(points, [view], K, dist) for view in held])
        except cv2.error as error:
            print(f"  opencv {name}: failed ({error})")
    return peers


def pooled_rms(view_rms: np.ndarray) -> float:
    """The RMS over every held-out corner from each view's RMS (every view has the whole board: equal weights)."""
    return float(np.sqrt(np.mean(np.square(view_rms))))


def best_peer(peers: dict[str, np.ndarray]) -> str:
    """The OpenCV model with the lowest held-out RMS."""
    return min(peers, key=lambda peer: pooled_rms(peers[peer]))


def run(name: str, board: Board, views: list[Detection], thorough: bool) -> None:
    holdout = set(range(0, len(views), HELD_EVERY))
    detections = {"cam": views}
    auto, t_auto = timed(calibrate_board, board, detections, holdout=holdout)
    picked = auto.rig.provenance.get("model", auto.model).split("@")[0].removesuffix(SPLINE_SUFFIX)
    _, t_single = timed(calibrate_board, board, detections, model=picked, holdout=holdout, board_shape="flat")
    _, t_opencv = timed(calibrate_board, board, detections, model="opencv", holdout=holdout, board_shape="flat")
    train = [v for n, v in enumerate(views) if n not in holdout]
    held = [v for n, v in enumerate(views) if n in holdout]
    peers = opencv_peers(board, train, held)
    best = best_peer(peers)
    best_rms = pooled_rms(peers[best])
    shape = "" if auto.board_shape is None else f" on the {auto.notes[-1].split(' on ')[-1].split()[0]} surface"
    print(f"{name}: auto picked {auto.model}{shape}; fit CPU auto {t_auto:.2f} s, single {picked} {t_single:.2f} s, "
          f"opencv {t_opencv:.2f} s; auto / single {t_auto / t_single:.1f}, auto / opencv {t_auto / t_opencv:.1f}")
    print(f"  held out: auto {auto.heldout_rms_px:.4f} px, best OpenCV ({best}) {best_rms:.4f} px, "
          f"auto / best {auto.heldout_rms_px / best_rms:.3f}")
    if thorough:
        full, t_full = timed(calibrate_board, board, detections, holdout=holdout, thorough=True)
        print(f"  thorough: {full.model}, held out {full.heldout_rms_px:.4f} px (/ best {full.heldout_rms_px / best_rms:.3f}), "
              f"fit CPU {t_full:.1f} s ({t_full / t_single:.0f}x single)")
    t_lenses, t_shapes = floor(board, detections, holdout, picked)
    print(f"  floor: every lens model fitted once {t_lenses:.2f} s ({t_lenses / t_single:.1f}x single), every board "
          f"surface once with {picked} {t_shapes:.2f} s ({(t_lenses + t_shapes) / t_single:.1f}x single with both)")
    sys.stdout.flush()


def rotations(name: str, board: Board, views: list[Detection]) -> None:
    """The held-out comparison on every rotation of the split (view ``n`` held out in rotation ``n % 6``: each view
    held out once): per rotation the default / OpenCV's best with a 95 % interval from resampling the held-out
    views (paired, seeded bootstrap: how much the ratio owes to which few views are held out), then pooled over
    every view."""
    rng = np.random.default_rng(0)
    ours, theirs = [], []
    for rotation in range(HELD_EVERY):
        holdout = {n for n in range(len(views)) if n % HELD_EVERY == rotation}
        auto = calibrate_board(board, {"cam": views}, holdout=holdout)
        peers = opencv_peers(board, [v for n, v in enumerate(views) if n not in holdout],
                             [v for n, v in enumerate(views) if n in holdout])
        best = best_peer(peers)
        mine, peer = np.asarray(auto.heldout_view_rms_px), peers[best]
        draws = rng.integers(0, len(mine), (2000, len(mine)))
        ratios = [pooled_rms(mine[d]) / pooled_rms(peer[d]) for d in draws]
        low, high = np.percentile(ratios, [2.5, 97.5])
        print(f"{name} rotation {rotation} ({len(mine)} held out): auto {auto.model} {pooled_rms(mine):.4f} px, "
              f"OpenCV best ({best}) {pooled_rms(peer):.4f} px, ratio {pooled_rms(mine) / pooled_rms(peer):.3f} "
              f"(95 % {low:.3f}-{high:.3f})")
        ours.append(mine)
        theirs.append(peer)
    ours, theirs = np.concatenate(ours), np.concatenate(theirs)
    print(f"{name} every view held out once: auto {pooled_rms(ours):.4f} px, OpenCV best per rotation "
          f"{pooled_rms(theirs):.4f} px, ratio {pooled_rms(ours) / pooled_rms(theirs):.3f}")
    sys.stdout.flush()


def end_to_end(name: str, images: dict[str, str], board: str) -> None:
    """``calibrate board`` as the command runs it (:func:`camcal.calibrate_board`: detection, the fit, the rig), the
    default against the single fit of the model it picked (``board_shape="flat"``), CPU seconds of this process:
    each with a fresh corner cache (detection included), then each again with its cache warm."""
    with tempfile.TemporaryDirectory() as tmp:
        def command(cache: str, **kwargs):
            return timed(camcal.calibrate_board, images, board, cache=Path(tmp) / cache, progress=False, **kwargs)

        auto, t_auto = command("auto")
        picked = auto.calibration.rig.provenance.get("model", auto.calibration.model).split("@")[0]
        _, t_single = command("single", model=picked, board_shape="flat")
        _, w_auto = command("auto")
        _, w_single = command("single", model=picked, board_shape="flat")
    shape = "" if auto.calibration.board_shape is None else " on a board surface"
    print(f"{name} end to end: auto picked {auto.calibration.model}{shape}; fresh cache: auto {t_auto:.1f} s, single "
          f"{picked} {t_single:.1f} s, auto / single {t_auto / t_single:.2f}; warm cache: auto {w_auto:.1f} s, single "
          f"{w_single:.1f} s, auto / single {w_auto / w_single:.2f}")
    sys.stdout.flush()


def floor(board: Board, detections: dict, holdout: set[int], picked: str) -> tuple[float, float]:
    """CPU seconds of one scoring fit of every lens model of ``auto`` on the training views, and of one surface fit
    of every board shape with ``picked`` (the least any ranking by held-out error must pay)."""
    names, by_frame, holdout = checked_views(detections, board, holdout)
    training = [{f: d for f, d in by_frame[0].items() if f not in holdout}]
    start, full = time.process_time(), None
    for model in AUTO_MODELS:
        try:
            fit = calibrate_model(board, names, training, model, set(), scoring=True, **OPTIONS)
        except FIT_ERRORS:
            continue
        full = fit if model == picked else full
    t_lenses = time.process_time() - start
    start = time.process_time()
    for spec in shape_specs(board, AUTO_SHAPES) if full is not None else ():
        try:
            surface_fit(board, full, training[0], picked, spec)
        except FIT_ERRORS:
            continue
    return t_lenses, time.process_time() - start


def main() -> None:
    args = sys.argv[1:]
    cache = Path(args[args.index("--cache") + 1]) if "--cache" in args else None
    only = args[args.index("--only") + 1] if "--only" in args else ""
    image_sets = [args[k + 1:k + 5] for k, a in enumerate(args) if a == "--images"]
    if SHARED.is_dir() and "--quick" not in args and "shared pair".startswith(only[:11]):
        pair = {side: str(SHARED / f"{side}*.jpg") for side in ("left", "right")}
        end_to_end("shared pair (the rig)", pair, "chessboard:9x6:1")
        end_to_end("shared pair left", {"left": pair["left"]}, "chessboard:9x6:1")
    for name, folder, pattern, grid in image_sets:
        if only in name:
            end_to_end(name, {"cam": str(Path(folder) / pattern)}, f"chessboard:{grid}:1")
    for name, board, views in data_sets(cache, "--quick" in args):
        if only in name and "--rotate" in args:
            rotations(name, board, views)
        elif only in name:
            run(name, board, views, "--thorough" in args)


if __name__ == "__main__":
    main()
