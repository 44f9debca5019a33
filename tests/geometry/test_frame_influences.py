"""Each frame's influence on a bundle adjustment (the projection sigma's design effect), against the one-step
replicates and constructed contributions."""

import dataclasses

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse
from test_selfcal import stereo_rig, tracks_state

from camcal.geometry.bundle import BundleOptions, bundle_adjust
from camcal.geometry.bundle import deletion
from camcal.geometry.bundle.deletion import frame_influences, one_step_replicates
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
    n_columns = max(columns for _, columns in shapes)
    assert max(rows for rows, _ in shapes) <= max(2 * per_frame.max(), n_columns) < 2 * per_frame.sum()
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
                  inspect=lambda problem, colmap: systems.append(deletion._system(state, OPTIONS, colmap, problem)))
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
    return deletion._apply(state, system.blocks, step[:system.J_c.shape[1]])


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


def test_leverage_correction_is_the_pseudo_inverse_of_one_minus_the_hat_matrix(monkeypatch):
    # X^T (I - X Q X^T)^+ z by its definition (a dense pseudo-inverse over the rows) against the form on the
    # columns alone; the hat matrix has two leverages of exactly 1 (what only the frame fixes), a null direction
    # of Q (the gauge) and leverages just inside the threshold
    rng = np.random.default_rng(3)
    n_rows, n_columns = 40, 12
    left, _ = np.linalg.qr(rng.normal(size=(n_rows, n_columns)))
    right, _ = np.linalg.qr(rng.normal(size=(n_columns, n_columns)))
    singular = np.sqrt(np.r_[1.0, 1.0, 1.0 - 1e-6, rng.uniform(0.05, 0.95, n_columns - 3)])
    X = left @ np.diag(singular) @ right.T  # E = X R with R = I: leverages singular^2
    z = rng.normal(size=n_rows)
    hat = X @ X.T
    expected = X.T @ np.linalg.pinv(np.eye(n_rows) - hat, rcond=1e-9, hermitian=True) @ z
    got = deletion._leverage_corrected(X, z, np.eye(n_columns))
    assert np.allclose(got, expected, rtol=1e-8, atol=1e-8 * np.abs(expected).max())
    # where Cholesky refuses (a leverage at the threshold's rounding), every eigenpair gives the same
    with monkeypatch.context() as patch:
        patch.setattr(scipy.linalg, "cho_factor", lambda *args, **kwargs: (_ for _ in ()).throw(np.linalg.LinAlgError()))
        fallback = deletion._leverage_corrected(X, z, np.eye(n_columns))
    assert np.allclose(fallback, expected, rtol=1e-8, atol=1e-8 * np.abs(expected).max())
    # a root R with a null column (Q singular along a gauge direction): the same as X R R^T X^T spelled out
    R = rng.normal(size=(n_columns, n_columns)) @ np.diag(np.r_[0.0, np.ones(n_columns - 1)])
    R *= 0.9 / np.linalg.norm(X @ R, 2)  # every leverage below 1
    expected = X.T @ np.linalg.solve(np.eye(n_rows) - X @ R @ R.T @ X.T, z)
    assert np.allclose(deletion._leverage_corrected(X, z, R), expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
