"""The uncertainty of a bundle adjustment: the marginal covariance of intrinsics and rig poses.

``Sigma = sigma^2 (J^T J)^-1`` restricted to the intrinsics and the rig
poses, frames and points marginalised (:func:`marginal_covariance`: Ceres'
Jacobian of the adjuster's own problem, the points eliminated by the Schur
complement of their 3x3 blocks, a point seen along nearly parallel rays
left out of the covariance instead of making it singular), with
``sigma^2 = 2 cost / (m - n)``, ``n`` the free unknowns (Triggs et al. 2000,
section 6; Hartley & Zisserman 2004, section 5.2). Rotations are in Ceres'
quaternion tangent space ``q' = [cos|d|, sin|d| d / |d|] q``, i.e. a
rotation vector ``2 d`` applied on the left; these sigmas measure the
sampling noise of the observations, not model error.

References
----------
Triggs, B., McLauchlan, P., Hartley, R. & Fitzgibbon, A. (2000). Bundle
Adjustment - A Modern Synthesis. Vision Algorithms: Theory and Practice.
Agarwal, S., Mierle, K. et al. Ceres Solver: covariance estimation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from camcal.base.extras import require

__all__ = ["MIN_POINT_SINGULAR_RATIO", "ceres_covariance", "is_free_block", "marginal_covariance", "point_schur_terms",
           "point_schur_vector"]

#: A free 3D point whose Jacobian has ``sigma_min < MIN_POINT_SINGULAR_RATIO x sigma_max`` (its depth
#: is not determined to the rounding of the Jacobian) is left out of the covariance, not of the fit
#: (:func:`marginal_covariance`).
MIN_POINT_SINGULAR_RATIO = 1e-10
#: Points whose 3x3 information block has ``lambda_min`` below this share of ``lambda_max`` are eliminated
#: through the SVD of their own Jacobian rows instead of the normal equations (:func:`marginal_covariance`).
_NORMAL_EQUATIONS_MIN_RATIO = 1e-10
#: points whose Schur terms are made dense together (:func:`point_schur_terms`): 3 rows each, times the columns
#: the chunk touches (at most every camera and frame column: 750 x 2900 doubles, 17 MB, on a 480-frame plate). A
#: smaller chunk touches a narrower band of frames (fewer zeros multiplied), a larger one makes fewer, larger
#: products: on a 60-frame plate whose points are each seen in 35 frames, 250 points took 0.76 of 1000's time.
_POINTS_PER_CHUNK = 250


def is_free_block(problem, block: NDArray[np.float64]) -> bool:
    """Whether ``block`` is a parameter block of the Ceres ``problem`` that the solve moves."""
    return problem.has_parameter_block(block) and not problem.is_parameter_block_constant(block)



def ceres_covariance(problem, blocks: list[NDArray[np.float64]], num_threads: int = 2) -> NDArray[np.float64] | None:
    """``(J^T J)^-1`` of some parameter blocks by Ceres' own ``Covariance`` (sparse QR of the whole Jacobian).

    The reference :func:`marginal_covariance` is checked against (tests,
    ``bench/bench_sfm.py``); ``None`` where Ceres finds the Jacobian rank
    deficient (one point seen along parallel rays is enough).

    Parameters
    ----------
    problem : pyceres.Problem
        A solved problem.
    blocks : list of ndarray
        Its free parameter blocks, in the order of the result (tangent space).
    num_threads : int
        Ceres' threads.
    """
    pyceres = require("pyceres")

    options = pyceres.CovarianceOptions()
    options.algorithm_type = pyceres.CovarianceAlgorithmType.SPARSE_QR
    options.num_threads = num_threads
    covariance = pyceres.Covariance(options)
    if not covariance.compute([(a, b) for i, a in enumerate(blocks) for b in blocks[i:]], problem):
        return None
    sizes = [problem.parameter_block_tangent_size(b) for b in blocks]
    offsets = np.r_[0, np.cumsum(sizes)]
    out = np.zeros((offsets[-1], offsets[-1]))
    for i, a in enumerate(blocks):
        for j in range(i, len(blocks)):
            part = np.asarray(covariance.get_covariance_block_tangent_space(a, blocks[j], problem)).reshape(sizes[i], sizes[j])
            out[offsets[i]:offsets[i + 1], offsets[j]:offsets[j + 1]] = part
            out[offsets[j]:offsets[j + 1], offsets[i]:offsets[i + 1]] = part.T
    return out


def marginal_covariance(problem, reconstruction, blocks: list[NDArray[np.float64]],
                        min_point_singular_ratio: float = MIN_POINT_SINGULAR_RATIO, num_threads: int = 2,
                        ) -> tuple[NDArray[np.float64], int]:
    """``(J^T J)^-1`` of some parameter blocks of a COLMAP bundle adjustment, all other unknowns marginalised.

    Parameters
    ----------
    problem : pyceres.Problem
        The problem of a pycolmap Ceres bundle adjuster (e.g.
        ``create_default_ceres_bundle_adjuster(...).problem``), at its solution.
    reconstruction : pycolmap.Reconstruction
        The reconstruction that problem refines: its cameras, rig sensor
        poses, frame poses and 3D points are the problem's parameter blocks.
    blocks : list of ndarray
        The free parameter blocks wanted (e.g. camera ``params``, a rig
        sensor pose's ``params``), in the order of the result.
    min_point_singular_ratio : float
        A free 3D point whose own Jacobian rows ``J_p`` (2k x 3) have
        ``sigma_min < ratio x sigma_max`` is left out of the covariance.
    num_threads : int
        Ceres' threads for the Jacobian; 1 when the problem has Python cost
        functions (pyceres' ``evaluate_jacobian`` holds the GIL that their
        evaluation on a worker thread would wait for).

    Returns
    -------
    covariance : ndarray, shape (n, n)
        In the blocks' tangent spaces (Ceres' manifolds; held coordinates of
        a ``SubsetManifold`` omitted), in the order of ``blocks``; shape
        (0, 0) when the reduced normal equations are singular (a gauge or a
        parameter the data do not fix).
    n_points_left_out : int
        Free 3D points left out as singular.

    Raises
    ------
    RuntimeError
        The problem has parameter blocks that are not part of the
        reconstruction (their columns would be missed).

    Notes
    -----
    With ``J = [J_c J_p]`` (``c``: the wanted blocks, then the frames and
    any other free block; ``p``: the 3D points), each residual involves one
    point, so ``H_pp = J_p^T J_p`` is block diagonal with 3x3 blocks and the
    points are eliminated exactly by the Schur complement (Triggs et al.
    2000, section 6.1)::

        S = J_c^T J_c - sum_p H_cp H_pp^-1 H_pc,      Cov(c) = S^-1

    the ``c`` block of ``(J^T J)^-1``, which Ceres' ``Covariance`` computes
    from a rank-revealing QR of the whole ``J``. A point seen along nearly
    parallel rays (a tiny triangulation angle) has a nearly null depth
    direction: that QR then declares the whole Jacobian rank deficient and
    gives no covariance at all, and ``H_pp^-1`` from the normal equations
    loses the small eigenvalue to rounding (``eps lambda_max``). So a point
    with ``lambda_min < 1e-10 lambda_max`` is eliminated from the SVD of
    its own rows instead, ``J_p = U s V^T``: ``H_cp H_pp^-1 H_pc = (J_c^T
    U)(U^T J_c)``, exact while ``s_min`` stands above the rounding of
    ``J_p``. Below ``min_point_singular_ratio`` its depth is not determined
    at all and the point is left out of the covariance with its
    observations -- it stays in the fit -- which can only enlarge
    ``Cov(c)``. ``S`` is factored by Cholesky after Jacobi scaling
    (``D^-1/2 S D^-1/2``, ``D = diag S``); a pivot below 1e-14 (Ceres'
    ``min_reciprocal_condition_number``) means singular.
    """
    import scipy.linalg  # noqa: PLC0415

    J, n_wanted, n_camera = _jacobian(problem, reconstruction, blocks, num_threads)
    n_points = (J.shape[1] - n_camera) // 3

    # the 3x3 information block of each point, from the rows (residuals) that see it
    Jp = J[:, n_camera:].tocoo()
    row_point = np.full(J.shape[0], -1, dtype=np.int64)
    row_point[Jp.row] = Jp.col // 3
    A = np.zeros((J.shape[0], 3))
    A[Jp.row, Jp.col % 3] = Jp.data
    seen = row_point >= 0
    H_pp = np.empty((n_points, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            H_pp[:, i, j] = H_pp[:, j, i] = np.bincount(row_point[seen], A[seen, i] * A[seen, j], minlength=n_points)
    eigenvalues, eigenvectors = np.linalg.eigh(H_pp)
    by_normal_equations = eigenvalues[:, 0] > _NORMAL_EQUATIONS_MIN_RATIO * eigenvalues[:, 2]
    # the others through the SVD of their own rows J_p = U s V^T: H_cp H_pp^-1 H_pc = (J_c^T U)(U^T J_c)
    order = np.argsort(row_point, kind="stable")
    starts = np.searchsorted(row_point[order], np.arange(n_points + 1))
    left_out = np.zeros(n_points + 1, dtype=bool)  # the last entry: rows without a free point
    projections = []
    for p in np.flatnonzero(~by_normal_equations):
        rows = order[starts[p]:starts[p + 1]]
        U, singular, _ = np.linalg.svd(A[rows], full_matrices=False)
        if len(singular) < 3 or not singular[2] > min_point_singular_ratio * singular[0]:
            left_out[p] = True
        else:
            projections.append(J[rows, :n_camera].T @ U)
    kept = J[~left_out[row_point]]
    J_c = kept[:, :n_camera]
    S = (J_c.T @ J_c).toarray()
    for JcU in projections:
        S -= JcU @ JcU.T
    if n_points:
        inverse_eigen = np.where(by_normal_equations[:, None], 1.0 / np.where(by_normal_equations[:, None], eigenvalues, 1.0), 0.0)
        S -= point_schur_terms((kept[:, n_camera:].T @ J_c).tocsr(), eigenvectors * np.sqrt(inverse_eigen)[:, None, :])[0]
    n_left_out = int(left_out.sum())

    d = np.sqrt(np.diag(S))
    if not np.all(d > 0):
        return np.zeros((0, 0)), n_left_out
    try:
        factor = scipy.linalg.cholesky(S / np.outer(d, d), lower=True)
    except np.linalg.LinAlgError:
        return np.zeros((0, 0)), n_left_out
    if np.min(np.diag(factor)) ** 2 < 1e-14:
        return np.zeros((0, 0)), n_left_out
    unit = np.zeros((n_camera, n_wanted))
    unit[np.arange(n_wanted), np.arange(n_wanted)] = 1.0
    scaled = scipy.linalg.cho_solve((factor, True), unit)[:n_wanted]
    covariance = scaled / np.outer(d[:n_wanted], d[:n_wanted])
    return 0.5 * (covariance + covariance.T), n_left_out


def point_schur_terms(H_pc, root: NDArray[np.float64], rhs: NDArray[np.float64] | None = None,
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """The points' Schur complement terms ``H_cp V^+ H_pc`` (and ``H_cp V^+ rhs``), dense.

    Parameters
    ----------
    H_pc : scipy.sparse.csr_matrix, shape (3 n, c)
        Each point's 3 rows of ``J_p^T J_c``.
    root : ndarray, shape (n, 3, 3)
        ``R`` with ``R R^T = V^+`` for each point's 3x3 block ``V = J_p^T J_p`` (zero where a point is not
        eliminated).
    rhs : ndarray, shape (n, 3), optional
        Each point's ``J_p^T r``.

    Notes
    -----
    ``H_cp V^+ H_pc = L^T L`` with ``L = R^T H_pc``: ``L`` is made dense a chunk of points at a time on
    the columns the chunk touches, the points in the order of their mean column (so that a chunk of a long
    plate touches a band of frames), and ``L^T L`` is one dense product per chunk, its upper triangle only
    (BLAS ``syrk``: half the flops of the full product), mirrored once at the end (Triggs et al. 2000,
    section 6.1). A sparse product of ``H_pc^T`` and ``V^+ H_pc`` does the same sums one entry at a time:
    on a 60-frame plate whose points are each seen in 35 frames the dense products take a third of its
    time, the same terms to 1e-15 of their largest.
    """
    import scipy.linalg  # noqa: PLC0415

    n_points, n_columns = len(root), H_pc.shape[1]
    terms = np.zeros((n_columns, n_columns))
    vector = None if rhs is None else np.zeros(n_columns)
    if n_points == 0:
        return terms, vector
    point_of_entry = np.repeat(np.arange(3 * n_points) // 3, np.diff(H_pc.indptr))
    entries = np.bincount(point_of_entry, minlength=n_points)
    mean_column = np.bincount(point_of_entry, H_pc.indices, minlength=n_points) / np.maximum(entries, 1)
    order = np.argsort(mean_column, kind="stable")
    projected = None if rhs is None else np.einsum("pji,pj->pi", root, rhs)  # R^T rhs
    ordered = H_pc[(3 * order[:, None] + np.arange(3)).ravel()]  # each chunk's rows one run
    seen, position = np.zeros(n_columns, dtype=bool), np.zeros(n_columns, dtype=np.int64)
    start = 0
    for chunk in np.array_split(order, -(-n_points // _POINTS_PER_CHUNK)):
        stop = start + len(chunk)
        pointers = ordered.indptr[3 * start:3 * stop + 1]
        indices = ordered.indices[pointers[0]:pointers[-1]]
        seen[:] = False
        seen[indices] = True
        columns = np.flatnonzero(seen)  # ascending: the chunk's upper triangle lands in the terms' upper one
        position[columns] = np.arange(len(columns))
        flat = np.repeat(np.arange(3 * len(chunk)) * len(columns), np.diff(pointers)) + position[indices]
        block = np.bincount(flat, ordered.data[pointers[0]:pointers[-1]], minlength=3 * len(chunk) * len(columns))
        L = np.einsum("pji,pjc->pic", root[chunk], block.reshape(len(chunk), 3, len(columns)))
        L = L.reshape(3 * len(chunk), len(columns))
        terms[np.ix_(columns, columns)] += scipy.linalg.blas.dsyrk(1.0, L.T)  # the upper triangle of L^T L
        if vector is not None:
            vector[columns] += L.T @ projected[chunk].ravel()
        start = stop
    return terms + np.triu(terms, 1).T, vector


def point_schur_vector(H_pc, root: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """The points' Schur term ``H_cp V^+ rhs`` alone (:func:`point_schur_terms`' second term), by one sparse
    product: ``H_pc^T (R R^T rhs)``, no dense block made.

    Parameters
    ----------
    H_pc : scipy.sparse.csr_matrix, shape (3 n, c)
    root : ndarray, shape (n, 3, 3)
    rhs : ndarray, shape (n, 3)
        As :func:`point_schur_terms`'.
    """
    projected = np.einsum("pji,pj->pi", root, rhs)  # R^T rhs
    return H_pc.T @ np.einsum("pij,pj->pi", root, projected).ravel()


def _jacobian(problem, reconstruction, blocks: list[NDArray[np.float64]], num_threads: int = 2):
    """Ceres' Jacobian (SciPy CSR, loss applied) of a COLMAP problem, columns: ``blocks``, other free blocks, points.

    Returns the matrix, the columns of ``blocks`` and the columns before the
    points (:func:`marginal_covariance`).
    """
    pyceres = require("pyceres")
    import scipy.sparse  # noqa: PLC0415

    candidates = [camera.params for camera in reconstruction.cameras.values()]
    candidates += [pose.params for rig in reconstruction.rigs.values() for pose in rig.non_ref_sensors.values()]
    candidates += [frame.rig_from_world.params for frame in reconstruction.frames.values() if frame.has_pose]
    others = [block for block in candidates if problem.has_parameter_block(block)]
    points = [point.xyz for point in reconstruction.points3D.values() if problem.has_parameter_block(point.xyz)]
    if len(others) + len(points) != problem.num_parameter_blocks():
        raise RuntimeError(f"the problem has {problem.num_parameter_blocks()} parameter blocks, the reconstruction "
                           f"{len(others) + len(points)}: not a plain COLMAP bundle adjustment")
    wanted = {block.ctypes.data for block in blocks}  # pycolmap hands a new view of the same memory each time
    rest = [block for block in others if is_free_block(problem, block) and block.ctypes.data not in wanted]
    evaluate = pyceres.EvaluateOptions()
    evaluate.set_parameter_blocks(list(blocks) + rest + [block for block in points if is_free_block(problem, block)])
    evaluate.num_threads = num_threads
    crs = problem.evaluate_jacobian(evaluate)
    J = scipy.sparse.csr_matrix((np.asarray(crs.values), np.asarray(crs.cols), np.asarray(crs.rows)),
                                shape=(crs.num_rows, crs.num_cols))
    n_wanted = sum(problem.parameter_block_tangent_size(block) for block in blocks)
    return J, n_wanted, n_wanted + sum(problem.parameter_block_tangent_size(block) for block in rest)
