"""A board that is not flat: its surface recovered with the lens, chosen by held-out error, and a flat one left flat."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.board_shape import AUTO_SHAPES, BoardShape
from camcal.geometry import zhang, zhang_rank
from camcal.geometry.zhang import calibrate_board
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

SIGMA_PX = 0.1
BOARD = Board("chessboard", 9, 6, 0.04)
SIZE = (1280, 960)
CAMERA = Camera("cam", SIZE, np.array([[900.0, 0, 641.0], [0, 902.0, 478.0], [0, 0, 1]]),
                Distortion("polynomial", {"k1": -0.12, "k2": 0.05}), np.eye(3), np.zeros(3))


def bent_heights(xy: np.ndarray, relief_squares: float) -> np.ndarray:
    """A board bowed along x and along y (mrcal's parabolic warp, unequal bows) and twisted, peak ``relief_squares``,
    its least-squares plane over the corners removed (that part is a pose)."""
    u = (xy[:, 0] - 4 * BOARD.square) / (4 * BOARD.square)
    v = (xy[:, 1] - 2.5 * BOARD.square) / (2.5 * BOARD.square)
    z = (1 - u**2) + 0.6 * (1 - v**2) + 0.5 * u * v
    corners = BOARD.object_points[:, :2]
    cu = (corners[:, 0] - 4 * BOARD.square) / (4 * BOARD.square)
    cv = (corners[:, 1] - 2.5 * BOARD.square) / (2.5 * BOARD.square)
    zc = (1 - cu**2) + 0.6 * (1 - cv**2) + 0.5 * cu * cv
    A = np.column_stack([np.ones(len(cu)), cu, cv])
    plane = np.linalg.lstsq(A, zc, rcond=None)[0]
    z = z - np.column_stack([np.ones(len(u)), u, v]) @ plane
    scale = relief_squares * BOARD.square / np.abs(zc - A @ plane).max()
    return scale * z


def stretched(xy: np.ndarray, stretch: float) -> np.ndarray:
    """The corners of a print ``1 + stretch`` times too wide and ``1 - stretch`` times too tall about its centre."""
    centre = BOARD.object_points[:, :2].mean(axis=0)
    return centre + (xy - centre) * [1.0 + stretch, 1.0 - stretch]


def views(relief_squares: float, n: int, seed: int, cameras: tuple[Camera, ...] = (CAMERA,),
          stretch: float = 0.0) -> dict:
    """``n`` views of the board bent by ``relief_squares`` (0: flat) and printed ``stretch`` too wide along x
    (and as much too short along y), each seen whole by every one of ``cameras``, with noise of ``SIGMA_PX``
    per coordinate."""
    rng = np.random.default_rng(seed)
    points = np.array(BOARD.object_points)
    points[:, 2] = bent_heights(points[:, :2], relief_squares)
    points[:, :2] = stretched(points[:, :2], stretch)
    out: dict = {camera.name: [] for camera in cameras}
    centred = points - BOARD.object_points.mean(axis=0)
    while len(out[cameras[0].name]) < n:
        R = Rotation.from_euler("xyz", rng.uniform(-40, 40, 3) * [1, 1, 0.3], degrees=True).as_matrix()
        X = centred @ R.T + rng.uniform([-0.15, -0.1, 0.35], [0.15, 0.1, 0.6])
        projected = [camera.project(X) for camera in cameras]
        if not all(np.all(np.isfinite(p)) and np.all((p > 5) & (p < np.array(SIZE) - 5)) for p in projected):
            continue
        for camera, p in zip(cameras, projected):
            out[camera.name].append(Detection(f"view_{len(out[camera.name]):03d}.png", SIZE,
                                              np.arange(BOARD.n_corners), p + rng.normal(0.0, SIGMA_PX, p.shape),
                                              "synthetic"))
    return out


def test_a_named_surface_recovers_the_bent_board_and_the_intrinsics():
    """A board bowed and twisted by 0.2 squares: the degree-2 surface recovers its heights to 2 % of the relief and
    brings fx, fy and the held-out RMS back to the noise, where the flat board's fit is biased."""
    detections = views(0.2, 24, 3)
    held = set(range(0, 24, 6))
    noise = math.sqrt(2) * SIGMA_PX
    flat = calibrate_board(BOARD, detections, model="polynomial", holdout=held, board_shape="flat")
    bent = calibrate_board(BOARD, detections, model="polynomial", holdout=held, board_shape="2")
    truth = bent_heights(BOARD.object_points[:, :2], 0.2)
    fitted = bent.board_shape.heights(BOARD.object_points[:, :2])
    assert np.abs(fitted - truth).max() < 0.02 * 0.2 * BOARD.square, np.abs(fitted - truth).max() / BOARD.square
    assert bent.heldout_rms_px < 1.15 * noise and bent.rms_px < 1.05 * noise
    assert flat.heldout_rms_px > 1.5 * bent.heldout_rms_px
    for k in (0, 1):  # the focal lengths: the flat fit is off, the surface's within a few sigma of the truth
        flat_error = abs(flat.rig.cameras[0].K[k, k] - CAMERA.K[k, k])
        bent_error = abs(bent.rig.cameras[0].K[k, k] - CAMERA.K[k, k])
        assert bent_error < 0.25 * flat_error, (k, flat_error, bent_error)
    assert flat.board_shape is None and "board_shape" not in flat.rig.provenance
    assert any(note.startswith("board relief: max 0.2") for note in bent.notes), bent.notes


def test_a_stretched_print_is_recovered_in_the_boards_plane():
    """A board bent by 0.2 squares and printed 0.5 % too wide and too short: ``2+plane`` recovers the corners'
    in-plane displacement (but for its similarity part, the gauge) to 5 % of its largest value and fits to the noise held out, where
    ``2`` (height only) cannot."""
    detections = views(0.2, 24, 7, stretch=0.005)
    held = set(range(0, 24, 6))
    noise = math.sqrt(2) * SIGMA_PX
    height_only = calibrate_board(BOARD, detections, model="polynomial", holdout=held, board_shape="2")
    planar = calibrate_board(BOARD, detections, model="polynomial", holdout=held, board_shape="2+plane")
    xy = BOARD.object_points[:, :2]
    truth = stretched(xy, 0.005) - xy
    # its shift, turn and scale over the corners are the gauge (the poses' and the square size's): taken out
    c = xy - xy.mean(axis=0)
    one, zero = np.ones(len(xy)), np.zeros(len(xy))
    G = np.column_stack([np.concatenate(g) for g in ((one, zero), (zero, one), (-c[:, 1], c[:, 0]), (c[:, 0], c[:, 1]))])
    stacked = truth.T.ravel()
    truth = (stacked - G @ np.linalg.lstsq(G, stacked, rcond=None)[0]).reshape(2, -1).T
    fitted = planar.board_shape.displacements(xy)
    largest = np.linalg.norm(truth, axis=1).max()
    assert np.linalg.norm(fitted - truth, axis=1).max() < 0.05 * largest, np.linalg.norm(fitted - truth, axis=1).max()
    assert planar.heldout_rms_px < 1.15 * noise and height_only.heldout_rms_px > 1.3 * planar.heldout_rms_px
    assert "off the printed grid" in planar.board_shape.describe(BOARD)
    loaded = BoardShape.from_dict(planar.board_shape.to_dict())
    assert loaded == planar.board_shape


def test_the_surface_round_trips_through_the_rig_file(tmp_path):
    """``provenance.board_shape`` is written and read back exactly; a rig without it loads as before (flat)."""
    detections = views(0.2, 12, 4)
    result = calibrate_board(BOARD, detections, model="polynomial", board_shape="2")
    path = tmp_path / "cam.rig.json"
    result.rig.save(path)
    loaded = BoardShape.from_dict(Rig.load(path).provenance["board_shape"])
    assert loaded == result.board_shape
    xy = BOARD.object_points[:, :2]
    assert np.array_equal(loaded.heights(xy), result.board_shape.heights(xy))
    with pytest.raises(CamcalError, match="board_shape"):
        BoardShape.from_dict({"surface": "legendre", "degree": 2})
    with pytest.raises(CamcalError, match="one camera"):
        calibrate_board(BOARD, {"a": detections["cam"], "b": detections["cam"]}, model="polynomial", board_shape="2")
    with pytest.raises(CamcalError, match="unknown board shape"):
        calibrate_board(BOARD, detections, model="polynomial", board_shape="bent")


def test_a_rig_on_the_same_board_holds_its_surface():
    """The surface fitted with one camera, held for a two-camera rig with the intrinsics held (the same board seen
    again): the rig fits to the noise where the flat board leaves the bend in its residuals."""
    right = Camera("right", SIZE, np.array([[880.0, 0, 630.0], [0, 880.0, 485.0], [0, 0, 1]]),
                   Distortion("polynomial", {"k1": -0.08, "k2": 0.02}), np.eye(3), np.array([0.08, 0.0, 0.0]))
    detections = views(0.2, 16, 6, (CAMERA, right))
    noise = math.sqrt(2) * SIGMA_PX
    single = {name: calibrate_board(BOARD, {name: detections[name]}, model="polynomial", board_shape="2")
              for name in detections}
    intrinsics = {name: result.rig.cameras[0] for name, result in single.items()}
    held = calibrate_board(BOARD, detections, intrinsics=intrinsics, board_shape=single["cam"].board_shape,
                           holdout={0, 8})
    flat = calibrate_board(BOARD, detections, intrinsics=intrinsics, board_shape="flat", holdout={0, 8})
    assert held.rms_px < 1.1 * noise and held.heldout_rms_px < 1.2 * noise, (held.rms_px, held.heldout_rms_px)
    assert flat.rms_px > 1.5 * held.rms_px
    assert held.board_shape == single["cam"].board_shape and "board_shape" in held.rig.provenance
    baseline = np.linalg.norm(held.rig.cameras[1].c - held.rig.cameras[0].c)
    assert abs(baseline - 0.08) < 0.002, baseline
    with pytest.raises(CamcalError, match="named model"):
        calibrate_board(BOARD, detections, board_shape=held.board_shape)


@pytest.mark.slow
def test_auto_bends_a_bent_board_and_keeps_a_flat_one_flat():
    """``model="auto"`` with ``board_shape="auto"``, thorough: the bent board (0.1 squares) gets a surface, chosen by the
    folds, and better held out than flat, with the lens ranked again on that surface (the rendered polynomial
    kept: the simplest within 1 % of the best there); the flat board stays flat (no surface beats it held out)."""
    held = set(range(0, 18, 6))
    bent = calibrate_board(BOARD, views(0.1, 18, 5), holdout=held, thorough=True)
    assert bent.board_shape is not None, [s.describe() for s in bent.shape_ranking]
    flat_score = next(s for s in bent.shape_ranking if "@board-" not in s.model)
    assert min(s.rms_px for s in bent.shape_ranking if "@board-" in s.model and s.rms_px is not None) < (
        0.8 * flat_score.rms_px)
    # the lens is ranked again on the surface taken: the rendered lens (polynomial) is the simplest within 1 %
    spec = next(n for n in bent.notes if n.endswith("chosen by held-out error")).split(" on ")[-1].split()[0]
    on_surface = {s.model.split("@board-")[0]: s.rms_px for s in bent.shape_ranking
                  if s.model.endswith(f"@board-{spec}") and s.rms_px is not None}
    # every lens the flat folds scored (the screen's finalists) is scored again on the surface
    finalists = {s.model for s in bent.model_ranking if s.rms_px is not None and "+" not in s.model}
    assert "polynomial" in on_surface and finalists - {"opencv-thin-prism"} <= set(on_surface), on_surface
    best = min(v for lens, v in on_surface.items() if "+spline" not in lens)
    assert bent.model == "polynomial" and on_surface["polynomial"] <= 1.01 * best, (bent.model, on_surface)
    assert bent.heldout_rms_px < 1.2 * math.sqrt(2) * SIGMA_PX, bent.heldout_rms_px
    flat = calibrate_board(BOARD, views(0.0, 18, 5), holdout=held, thorough=True)
    assert flat.board_shape is None and len(flat.shape_ranking) > 1, [s.describe() for s in flat.shape_ranking]
    assert any(note.startswith("board shape auto: flat") for note in flat.notes)


@pytest.mark.slow
def test_a_flat_pick_without_a_surface_path_still_gets_the_boards_surface(monkeypatch):
    """Slow (every lens and surface fitted on 12 views); in `make test`, the choice alone:
    :func:`test_a_flat_pick_without_a_surface_path_has_the_surface_chosen_with_the_simplest_lens_that_has_one`.

    A flat-ranked lens with no surface path (OpenCV's own thin-prism fit; here ``opencv`` taken off the surface
    lenses, so that the flat pick is a robust one, not OpenCV's thin-prism fit, which lands in different minima) on a
    bent board: the surface is chosen with the simplest lens within 1 % that has one and the lens ranked again on
    it, where the flat board used to be kept (the ordinary stereo pair's right camera, 5 of its 6 splits: 1.5-1.7 x
    calibrateCameraRO held out)."""
    monkeypatch.setattr(zhang_rank, "SHAPE_LENSES", tuple(m for m in zhang_rank.SHAPE_LENSES if m != "opencv"))
    s1 = 0.01
    prism = Camera("cam", SIZE, CAMERA.K, Distortion("opencv", {"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0,
                                                               "s1": s1, "s2": -s1 / 2, "s3": -0.75 * s1, "s4": s1 / 2}),
                   np.eye(3), np.zeros(3))
    held = {0, 6}
    detections = views(0.02, 12, 7, cameras=(prism,))
    result = calibrate_board(BOARD, detections, holdout=held, thorough=True)
    assert any(n.startswith("board shape auto: opencv (ranked on the flat board) has no surface fit") for n in
               result.notes), result.notes
    assert result.board_shape is not None and result.model != "opencv", (result.model, result.notes)
    assert result.heldout_rms_px < 1.2 * math.sqrt(2) * SIGMA_PX, result.heldout_rms_px
    flat = calibrate_board(BOARD, detections, model="opencv", holdout=held, board_shape="flat")
    assert result.heldout_rms_px < 0.75 * flat.heldout_rms_px, (flat.heldout_rms_px, result.heldout_rms_px)


def test_a_flat_pick_with_a_field_has_the_surface_chosen_with_its_parametric_lens_too(monkeypatch):
    """The flat ranking picks ``kannala-brandt+spline``; on the folds, its parametric lens on the ``free+plane``
    board beats every pair with the field (the field did the board's work on the flat board). The surfaces are
    scored for the parametric lens too, and the pair is taken by the same held-out rule: ``kannala-brandt`` on
    ``free+plane``, where only the field's surfaces used to be scored and the field kept on its best one (the real
    640x640 fisheye, split 5: 0.194 px held out with the field on a degree-4 surface, 0.096 px for the lens on
    ``free+plane``). The scores are set by hand (a fake ``_score_shapes``): the test is the choice, not the fits."""
    n_views, n_corners = 12, float(BOARD.n_corners)
    corners = np.full(n_views, n_corners)
    wobble = 1.0 + 0.05 * np.sin(np.arange(n_views))  # views differ, so the paired differences have a spread

    def per_view(rms: float) -> np.ndarray:
        return rms**2 * n_corners * wobble

    table = {"kannala-brandt+spline": {"4": 0.20}, "kannala-brandt": {"free+plane": 0.15}}
    field, lens = "kannala-brandt+spline", "kannala-brandt"
    scored = [zhang.ModelScore(field, 0.30, 208), zhang.ModelScore(lens, 0.33, 8), zhang.ModelScore("division", 0.34, 5)]
    squared = {s.model: per_view(s.rms_px) for s in scored}
    scored_shapes = []

    def fake_scores(board, views, model, folds, results, corners, squared, specs=None, fits=None, screen=None):
        out = []
        for spec in zhang_rank.shape_specs(board, AUTO_SHAPES) if specs is None else specs:
            name = f"{model}@board-{spec}"
            rms = table.get(model, {}).get(spec, 0.25 if model.startswith(lens) else 0.30)
            squared[name] = per_view(rms)
            scored_shapes.append(name)
            out.append(zhang.ModelScore(name, rms, 10))
        return out

    fitted = []
    flat = type("Flat", (), {"rig": type("Rig", (), {"cameras": (None,)})()})()
    monkeypatch.setattr(zhang_rank, "_score_shapes", fake_scores)
    monkeypatch.setattr(zhang_rank, "calibrate_shaped", lambda board, names, by_frame, model, holdout, spec, flat=None,
                        **options: fitted.append((model, spec)) or flat_result)
    monkeypatch.setattr(zhang_rank, "quality_problems", lambda result: [])
    monkeypatch.setattr(zhang_rank, "fold_radius_px", lambda camera: None)
    training = [{f: None for f in range(n_views)}]
    folds = [set(range(k, n_views, 4)) for k in range(4)]
    fold_results = {"folds": folds, lens: [None] * 4, "division": [None] * 4}
    flat_result = flat
    _, ranking, notes = zhang_rank.with_board_shape(BOARD, ["cam"], training, field, set(), flat, "auto", "", scored,
                                                squared, corners, fold_results, training, {"loss": "trivial"})
    assert f"{lens}@board-free+plane" in scored_shapes, scored_shapes
    assert fitted == [(lens, "free+plane")], (fitted, notes)
    assert ranking[0].model == f"{lens}@board-free+plane", [s.describe() for s in ranking]


def test_a_flat_pick_without_a_surface_path_has_the_surface_chosen_with_the_simplest_lens_that_has_one(monkeypatch):
    """The fast sibling of :func:`test_a_flat_pick_without_a_surface_path_still_gets_the_boards_surface`, on the
    choice alone (scores set by hand, as above): the flat ranking picks ``opencv-thin-prism``, which has no surface
    fit; the surface is chosen with ``polynomial``, the simplest lens within 1 % of the best that has one
    (``opencv-rational`` is 0.2 % better, ``division`` 2.6 % worse), and that lens is fitted on the surface it wins."""
    n_views, n_corners = 12, float(BOARD.n_corners)
    wobble = 1.0 + 0.05 * np.sin(np.arange(n_views))

    def per_view(rms: float) -> np.ndarray:
        return rms**2 * n_corners * wobble

    scored = [zhang.ModelScore("opencv-thin-prism", 0.300, 12), zhang.ModelScore("opencv-rational", 0.302, 8),
              zhang.ModelScore("polynomial", 0.3025, 2), zhang.ModelScore("division", 0.310, 1)]
    squared = {s.model: per_view(s.rms_px) for s in scored}
    scored_for = []

    def fake_scores(board, views, model, folds, results, corners, squared, specs=None, fits=None, screen=None):
        out = []
        for spec in zhang_rank.shape_specs(board, AUTO_SHAPES) if specs is None else specs:
            name = f"{model}@board-{spec}"
            rms = 0.15 if (model, spec) == ("polynomial", "free+plane") else 0.30
            squared[name] = per_view(rms)
            scored_for.append(model)
            out.append(zhang.ModelScore(name, rms, 10))
        return out

    fitted = []
    flat_result = type("Flat", (), {"rig": type("Rig", (), {"cameras": (None,)})()})()
    monkeypatch.setattr(zhang_rank, "_score_shapes", fake_scores)
    monkeypatch.setattr(zhang_rank, "calibrate_shaped", lambda board, names, by_frame, model, holdout, spec, flat=None,
                        **options: fitted.append((model, spec)) or flat_result)
    monkeypatch.setattr(zhang_rank, "quality_problems", lambda result: [])
    monkeypatch.setattr(zhang_rank, "fold_radius_px", lambda camera: None)
    training = [{f: None for f in range(n_views)}]
    fold_results = {"folds": [set(range(k, n_views, 4)) for k in range(4)], "polynomial": [None] * 4}
    _, ranking, notes = zhang_rank.with_board_shape(BOARD, ["cam"], training, "opencv-thin-prism", set(), flat_result,
                                                "auto", "", scored, squared, corners=np.full(n_views, n_corners),
                                                fold_results=fold_results, training=training,
                                                options={"loss": "trivial"})
    assert notes[0].startswith("board shape auto: opencv-thin-prism (ranked on the flat board) has no surface fit; "
                               "the surface is chosen with polynomial"), notes
    assert "opencv-thin-prism" not in scored_for and "polynomial" in scored_for
    assert fitted == [("polynomial", "free+plane")], (fitted, notes)
    assert ranking[0].model == "polynomial@board-free+plane", [s.describe() for s in ranking]
