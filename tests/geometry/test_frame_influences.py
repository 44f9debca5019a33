"""Each frame's (or group of frames') influence on a bundle adjustment (the projection sigma's design effect),
against the one-step replicates, the dense normal equations and constructed contributions."""

import dataclasses

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse
from test_selfcal import stereo_rig, tracks_state

from camcal.geometry.bundle import BundleOptions, bundle_adjust
from camcal.geometry.bundle import covariance, deletion, influences
from camcal.geometry.bundle.deletion import one_step_replicates
from camcal.geometry.bundle.influences import frame_influences
from camcal.geometry.bundle.prior import PriorSpec, mean_focal
from camcal.geometry.selfcal_aspect import ASPECT_HELD, SQUARE_PIXELS_HELD
from camcal.geometry.selfcal_models import with_fixed_params, with_lenses
from camcal.geometry.uncertainty import shrunk_design_effect

OPTIONS = BundleOptions(refine_principal_point=True)


def test_influences_are_the_one_step_replicates_moves(monkeypatch):
    # Woodbury: (H - J_k^T J_k)^-1 J_k^T r_k = H^-1 J_k^T (I - H_kk)^-1 r_k, so the leverage-corrected influence of
    # each frame is the move of the one-step replicate without it (itself within a few percent of a full refit,
    # test_jackknife.py); the scene gauge rides along (the frames turn about more than one axis)
    state = tracks_state(stereo_rig(), np.random.default_rng(5), n_frames=6, n_points=500)
    full = bundle_adjust(state, OPTIONS)
    frames, per_frame = np.unique(full.state.obs_frame, return_counts=True)
    shapes = []
    toarray = scipy.sparse.csr_matrix.toarray

    def spy(matrix, *args, **kwargs):
        shapes.append(matrix.shape)
        return toarray(matrix, *args, **kwargs)

    monkeypatch.setattr(scipy.sparse.csr_matrix, "toarray", spy)
    influences = frame_influences(full.state, OPTIONS)
    monkeypatch.undo()
    # made dense one frame at a time (or the columns square): never observations x columns over every frame,
    # which grows with the square of the frame count (gigabytes on a long plate)
    n_columns = max((columns for _, columns in shapes), default=0)
    assert all(rows <= max(2 * per_frame.max(), n_columns) < 2 * per_frame.sum() for rows, _ in shapes)
    replicates = one_step_replicates(full.state, OPTIONS, [np.array([f]) for f in frames])
    assert influences.values.shape == (len(frames), len(influences.names))
    assert {"gauge.rx", "gauge.ry", "gauge.rz", "right.rx"} <= set(influences.names)
    assert tuple(n for n in influences.names if not n.startswith("gauge.")) == tuple(
        n for n in full.covariance_names if not n.startswith("gauge."))
    for camera, name in enumerate(full.state.camera_names):
        for i, param in enumerate(full.state.param_names(camera)):
            key = f"{name}.{param}"
            moved = np.array([r.params[camera][i] - full.state.params[camera][i] for r in replicates])
            mine = influences.values[:, influences.names.index(key)]
            print(key, np.round(moved, 6), np.round(mine, 6))
            assert np.max(np.abs(mine - moved)) < 1e-3 * np.max(np.abs(moved)) + 1e-12, key


def test_shrunk_design_effect_on_constructed_contributions():
    model = 2.0
    # frames that agree: no shrinkage, the jackknife's variance over the model's
    assert shrunk_design_effect(model, np.full(8, 4 * model / 8)) == pytest.approx(4.0)
    # one frame carries the whole excess: its variance is the excess itself, shrunk all the way to the model
    assert shrunk_design_effect(model, [10 * model] + [0.0] * 7) == 1.0
    # in between: a convex combination of the two, never below 1
    mixed = [3 * model / 8 + 0.3 * model * (-1) ** k for k in range(8)]
    assert 1.0 < shrunk_design_effect(model, mixed) < 3.0
    assert shrunk_design_effect(model, np.full(8, 0.5 * model / 8)) == 1.0
    # the intensity by hand: n var(c) / (v - m)^2
    c = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    delta = len(c) * np.var(c, ddof=1) / (c.sum() - model) ** 2
    assert shrunk_design_effect(model, c) == pytest.approx((delta * model + (1 - delta) * c.sum()) / model)


def _dense_replicate(state, group):
    """The one-step replicate without ``group`` from the dense normal equations of the rows kept (points
    included, nothing eliminated): the reference the reduced systems are checked against."""
    systems = []
    bundle_adjust(state, dataclasses.replace(OPTIONS, max_iterations=0, compute_sigmas=False),
                  inspect=lambda problem, colmap: systems.append(deletion.linearise(state, OPTIONS, colmap, problem)))
    system = systems[0]
    rows = len(system.r)
    point_columns = np.zeros((rows, 3 * system.n_points))
    seen = np.flatnonzero(system.row_point >= 0)
    point_columns[seen[:, None], 3 * system.row_point[seen, None] + np.arange(3)] = system.point_rows[seen]
    J = np.hstack([system.J_c.toarray(), point_columns])
    deleted = np.isin(system.row_frame, group)
    counts = np.bincount(system.row_point[~deleted & (system.row_point >= 0)], minlength=system.n_points) // 2
    kept = ~deleted & ((system.row_point < 0) | (counts[np.maximum(system.row_point, 0)] >= 2))
    columns = np.flatnonzero(np.any(J[kept] != 0, axis=0))  # the deleted frames' poses and dropped points go
    step = np.zeros(J.shape[1])
    step[columns] = -np.linalg.solve(J[np.ix_(kept, columns)].T @ J[np.ix_(kept, columns)],
                                     J[np.ix_(kept, columns)].T @ system.r[kept])
    return deletion.apply_step(state, system.blocks, step[:system.J_c.shape[1]])


def test_one_step_replicates_by_updated_sums_are_the_dense_normal_equations_solved(monkeypatch):
    # a group's reduced system is the full one less the sums over the rows that go, its points' terms taken out
    # and put back without it (a few frames' worth on a long plate) or summed again over every point: both the
    # one Gauss-Newton step of the dense normal equations of the rows kept
    state = tracks_state(stereo_rig(), np.random.default_rng(5), n_frames=6, n_points=300)
    full = bundle_adjust(state, OPTIONS)
    groups = [np.array([0]), np.array([2, 3]), np.array([5])]  # frame 0 holds the gauge: the pseudo-inverse
    runs = {}
    for share in (0.0, np.inf):
        monkeypatch.setattr(deletion, "_UPDATE_BELOW", share)
        runs[share] = one_step_replicates(full.state, OPTIONS, groups)
    for again, updated in zip(runs[0.0], runs[np.inf]):
        for a, b in zip(again.params, updated.params):
            assert np.allclose(a, b, rtol=1e-10, atol=0), (a, b)
        assert np.allclose(again.frame_t, updated.frame_t, rtol=0, atol=1e-10)
        assert np.allclose(again.frame_R, updated.frame_R, rtol=0, atol=1e-10)
        assert not np.array_equal(again.params[0], full.state.params[0])  # the group moved the solution
    for group, again, updated in zip(groups[1:], runs[0.0][1:], runs[np.inf][1:]):  # the gauge held: one solution
        reference = _dense_replicate(full.state, group)
        for replicate in (again, updated):
            for mine, peer, start in zip(replicate.params, reference.params, full.state.params):
                moved, expected = mine - start, peer - start
                assert np.allclose(moved, expected, rtol=1e-7, atol=1e-12 * np.abs(start).max()), (mine, peer)
            assert np.allclose(replicate.frame_t, reference.frame_t, rtol=0, atol=1e-9)


def test_group_influences_are_the_dense_delete_a_cluster_moves():
    # each group's influence, from the dense normal equations (points included, nothing eliminated): the move the
    # rows that go make, (J_kept^T J_kept)^+ J_gone^T r_gone, with what the rows kept leave free (the group's
    # frame poses; the gauge where the group holds frame 0 or the scale) chosen as the Woodbury form's
    # pseudo-inverse of I - H_gg chooses it: least energy delta_c^T S delta_c in the reduced system S of every
    # row. Single frames, contiguous groups (a plate's clusters) and the groups that hold the gauge
    state = tracks_state(stereo_rig(), np.random.default_rng(5), n_frames=8, n_points=250)
    full = bundle_adjust(state, OPTIONS)
    groups = [np.array([0]), np.array([1]), np.array([4]), np.array([0, 1, 2]), np.array([3, 4]), np.array([5, 6, 7])]
    got = frame_influences(full.state, OPTIONS, groups)
    found = []
    bundle_adjust(full.state, dataclasses.replace(OPTIONS, max_iterations=0, compute_sigmas=False),
                  inspect=lambda problem, colmap: found.append(deletion.linearise(full.state, OPTIONS, colmap, problem))
                  or found.append(influences._parameter_rows(full.state, found[0], colmap)[1]))
    system, B = found
    n_c = system.J_c.shape[1]
    point_columns = np.zeros((len(system.r), 3 * system.n_points))
    seen = np.flatnonzero(system.row_point >= 0)
    point_columns[seen[:, None], 3 * system.row_point[seen, None] + np.arange(3)] = system.point_rows[seen]
    J = np.hstack([system.J_c.toarray(), point_columns])
    H = J.T @ J
    S = H[:n_c, :n_c] - H[:n_c, n_c:] @ np.linalg.solve(H[n_c:, n_c:], H[n_c:, :n_c])
    for group, mine in zip(groups, got.values):
        deleted = np.isin(system.row_frame, group)
        counts = np.bincount(system.row_point[~deleted & (system.row_point >= 0)], minlength=system.n_points) // 2
        kept = ~deleted & ((system.row_point < 0) | (counts[np.maximum(system.row_point, 0)] >= 2))
        H_kept = J[kept].T @ J[kept]
        scale = 1.0 / np.sqrt(np.where(np.diag(H_kept) > 0, np.diag(H_kept), 1.0))
        values, vectors = np.linalg.eigh(H_kept * np.outer(scale, scale))
        used = values > 1e-11 * values[-1]
        step = scale * (vectors[:, used] @ ((vectors[:, used].T @ (scale * (J[~kept].T @ system.r[~kept]))) / values[used]))
        free, spread, _ = np.linalg.svd((scale[:, None] * vectors[:, ~used])[:n_c], full_matrices=False)
        free = free[:, spread > 1e-8 * spread.max()]  # a dropped point's own direction has no camera part
        free /= np.sqrt(np.diag(free.T @ S @ free))  # free directions of unit energy: a well-conditioned solve
        step = step[:n_c] - free @ np.linalg.solve(free.T @ S @ free, free.T @ S @ step[:n_c])
        expected = B @ step
        print(group, np.round(mine, 7), np.round(expected, 7))
        assert np.allclose(mine, expected, rtol=0, atol=1e-5 * np.abs(expected).max()), group
    # single frames are the default
    assert np.array_equal(frame_influences(full.state, OPTIONS).values[[0, 1, 4]], got.values[:3])


def test_replicates_and_influences_in_one_pass_are_the_two_passes(monkeypatch):
    # the self-calibration's uncertainty: the jackknife's replicates under the loose aspect prior and the
    # influences under the fit's (square pixels held on one camera: its aspect prior a million times tighter)
    # from one linearisation and one pass over the groups' sums, each problem adding its priors' rows (the
    # loose ones made with the noise read off the fit's): the same as each on its own, which the dense normal
    # equations check above. With the same options one factorisation serves both
    lenses = dict.fromkeys(("left", "right"), "division")
    loose = with_fixed_params(dataclasses.replace(OPTIONS, default_priors=True), lenses)
    state = with_lenses(tracks_state(stereo_rig(), np.random.default_rng(7), n_frames=8, n_points=250), lenses)
    seed = bundle_adjust(state, loose).state
    held = dataclasses.replace(loose, priors=(PriorSpec("left", "aspect", 0.0, ASPECT_HELD * mean_focal(seed, 0),
                                                        SQUARE_PIXELS_HELD),))
    fit = bundle_adjust(seed, held).state
    groups = [np.array([0]), np.array([1, 2]), np.array([3, 4]), np.array([5, 6, 7])]
    built, original = [], deletion.FrameDeletion
    for module in (deletion, influences):
        monkeypatch.setattr(module, "FrameDeletion", lambda system: built.append(system) or original(system))
    for replicate_options in (loose, held):
        built.clear()
        replicates, shared = influences.replicates_and_influences(fit, replicate_options, held, groups)
        assert len(built) == 1  # one problem linearised, one pass over the groups
        peers = one_step_replicates(fit, replicate_options, groups)
        alone = frame_influences(fit, held, groups)
        assert shared.names == alone.names
        # the same to the rounding of the sums over the problem's condition (1e-10 of each column seen)
        scale = np.abs(alone.values).max(axis=0)
        print(np.max(np.abs(shared.values - alone.values) / scale))
        assert np.all(np.abs(shared.values - alone.values) <= 1e-9 * scale)
        for mine, peer in zip(replicates, peers):
            for camera, start in enumerate(fit.params):
                moved, expected = mine.params[camera] - start, peer.params[camera] - start
                print(replicate_options is held, np.max(np.abs(moved - expected) / np.abs(expected).max()))
                assert np.allclose(moved, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
            assert np.allclose(mine.frame_t, peer.frame_t, rtol=0, atol=1e-12)
            assert np.allclose(mine.frame_R, peer.frame_R, rtol=0, atol=1e-12)
    # options that differ in more than their priors: each on its own
    built.clear()
    replicates, shared = influences.replicates_and_influences(fit, dataclasses.replace(held, refine_principal_point=False),
                                                              held, groups)
    assert len(built) == 2 and np.array_equal(shared.values, frame_influences(fit, held, groups).values)


def test_point_schur_terms_are_the_dense_products():
    # H_cp V^+ H_pc and H_cp V^+ b over points spread over several chunks, each seeing a few columns of a band
    # (a plate's frames) and the shared ones (intrinsics), against the dense block-diagonal product
    rng = np.random.default_rng(3)
    n_points, n_columns = 700, 60
    rows, cols = [], []
    for p in range(n_points):
        start = rng.integers(5, n_columns - 12)
        seen = np.r_[0:5, start:start + rng.integers(3, 12)]
        rows += [3 * p + k for k in range(3) for _ in seen]
        cols += [c for _ in range(3) for c in seen]
    H_pc = scipy.sparse.csr_matrix((rng.standard_normal(len(rows)), (rows, cols)), shape=(3 * n_points, n_columns))
    root = rng.standard_normal((n_points, 3, 3))
    root[::7] = 0.0  # points not eliminated
    rhs = rng.standard_normal((n_points, 3))
    V_plus = scipy.linalg.block_diag(*(r @ r.T for r in root))
    dense = H_pc.toarray()
    terms, vector = covariance.point_schur_terms(H_pc, root, rhs)
    expected = dense.T @ V_plus @ dense
    assert np.allclose(terms, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    assert np.array_equal(terms, terms.T)
    expected = dense.T @ V_plus @ rhs.ravel()
    assert np.allclose(vector, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    assert np.allclose(covariance.point_schur_vector(H_pc, root, rhs), expected, rtol=0, atol=1e-12 * np.abs(expected).max())
