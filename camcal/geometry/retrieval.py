"""Image retrieval for loop closure: a VLAD descriptor per frame from its local descriptors, and the revisits.

A plate matched by frame order (each frame with the next few) links only
frames close in time; a shot that comes back to where it was sees the same
set again many frames later, and without a pair between those frames the
reconstruction drifts between the two passes. Retrieval finds them: each
frame's local (SIFT) descriptors are summarised into one global vector,
VLAD (Jégou et al. 2010): the descriptors are assigned to the nearest word of
a small vocabulary (k-means over the plate's own descriptors, seeded), and
the residuals ``x - c_k`` are summed per word,

.. math:: v_k = \\sum_{x : NN(x) = c_k} (x - c_k),

then each ``v_k`` is L2-normalised (intra-normalisation, Arandjelović &
Zisserman 2013), the whole vector square-rooted with its sign kept (power
normalisation, Jégou et al. 2012) and L2-normalised. Two frames that see the
same part of the set have a high cosine similarity ``v_i . v_j``.

The frames' vectors are compared centred on their mean and re-normalised:
what every frame of the shot shares (the texture of the whole set) says
nothing about where a frame is (Jégou & Chum 2012 centre VLAD likewise
before whitening). A pair of frames far apart in time is a revisit
(:func:`revisit_pairs`) when
each is the other's most similar frame outside its time window (mutual
nearest neighbours), the similarity stands out of that frame's similarities
to the frames outside the window (a robust z-score: above the median by
``min_score`` median absolute deviations), and it is at least ``min_ratio``
of the similarity frames have to their neighbours inside the window (which
do overlap). Frames whose best match is merely the least unlike give no pair.

References
----------
Jégou, H., Douze, M., Schmid, C. & Pérez, P. (2010). Aggregating local
descriptors into a compact image representation. CVPR.
Arandjelović, R. & Zisserman, A. (2013). All About VLAD. CVPR.
Jégou, H., Perronnin, F., Douze, M., Sánchez, J., Pérez, P. & Schmid, C.
(2012). Aggregating local image descriptors into compact codes. IEEE TPAMI.
Jégou, H. & Chum, O. (2012). Negative evidence and co-occurrences in image
retrieval: the benefit of PCA and whitening. ECCV.
Arthur, D. & Vassilvitskii, S. (2007). k-means++: the advantages of careful
seeding. SODA.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from camcal.base.errors import CamcalError

__all__ = ["revisit_pairs", "train_vocabulary", "vlad"]


def _unit_rows(descriptors: ArrayLike) -> NDArray[np.float32]:
    """Descriptors as float32 rows of unit length (an all-zero row stays zero)."""
    rows = np.asarray(descriptors, dtype=np.float32)
    if rows.ndim != 2:
        raise CamcalError(f"descriptors must be an (N, D) array, got shape {rows.shape}")
    norms = np.linalg.norm(rows, axis=1, keepdims=True)
    return rows / np.maximum(norms, 1e-12)


def _nearest(rows: NDArray[np.float32], centres: NDArray[np.float32]) -> NDArray[np.intp]:
    """Index of the nearest centre (Euclidean) of every row: the smallest ``|c|^2 - 2 x . c``."""
    return np.argmin((centres * centres).sum(1)[None, :] - 2.0 * rows @ centres.T, axis=1)


def train_vocabulary(descriptors: ArrayLike, n_words: int = 32, seed: int = 0, iterations: int = 10,
                     max_samples: int = 20_000) -> NDArray[np.float32]:
    """A visual vocabulary: k-means (k-means++ seeding, Lloyd's iterations) over unit-length descriptors.

    Parameters
    ----------
    descriptors : array_like, shape (N, D)
        Local descriptors (e.g. SIFT as COLMAP stores them, uint8), pooled
        from the frames; each is scaled to unit length first.
    n_words : int
        Vocabulary size ``k`` (at most N).
    seed : int
        Seeds the sampling (at most ``max_samples`` descriptors) and the
        k-means++ draws: the same descriptors give the same vocabulary.
    iterations : int
        Lloyd iterations (assign, re-centre); stops early once no
        assignment changes.

    Returns
    -------
    ndarray, shape (n_words, D), float32
        The words; an empty cluster keeps its previous centre.
    """
    rows = _unit_rows(descriptors)
    if len(rows) < n_words or n_words < 1:
        raise CamcalError(f"a vocabulary of {n_words} words needs at least as many descriptors, got {len(rows)}")
    rng = np.random.default_rng(seed)
    if len(rows) > max_samples:
        rows = rows[np.sort(rng.choice(len(rows), max_samples, replace=False))]
    centres = np.empty((n_words, rows.shape[1]), np.float32)
    centres[0] = rows[rng.integers(len(rows))]
    closest = ((rows - centres[0]) ** 2).sum(1)
    for k in range(1, n_words):  # k-means++: the next centre drawn in proportion to the squared distance
        total = float(closest.sum())
        index = rng.choice(len(rows), p=closest / total) if total > 0 else rng.integers(len(rows))
        centres[k] = rows[index]
        closest = np.minimum(closest, ((rows - centres[k]) ** 2).sum(1))
    labels = None
    for _ in range(iterations):
        new_labels = _nearest(rows, centres)
        if labels is not None and np.array_equal(new_labels, labels):
            break
        labels = new_labels
        for k in range(n_words):
            members = rows[labels == k]
            if len(members):
                centres[k] = members.mean(0)
    return centres


def vlad(descriptors: ArrayLike, vocabulary: ArrayLike) -> NDArray[np.float32]:
    """The VLAD vector of one frame (Jégou et al. 2010), intra-, power- and L2-normalised.

    Parameters
    ----------
    descriptors : array_like, shape (N, D)
        The frame's local descriptors (scaled to unit length first).
    vocabulary : array_like, shape (k, D)
        From :func:`train_vocabulary`.

    Returns
    -------
    ndarray, shape (k * D,), float32
        Unit length; all zero for a frame without descriptors.
    """
    words = np.asarray(vocabulary, dtype=np.float32)
    result = np.zeros_like(words)
    rows = _unit_rows(np.asarray(descriptors).reshape(-1, words.shape[1]))
    if len(rows):
        labels = _nearest(rows, words)
        np.add.at(result, labels, rows - words[labels])
    result /= np.maximum(np.linalg.norm(result, axis=1, keepdims=True), 1e-12)  # intra-normalisation
    flat = (np.sign(result) * np.sqrt(np.abs(result))).ravel()  # power normalisation
    return flat / max(float(np.linalg.norm(flat)), 1e-12)


def revisit_pairs(vectors: ArrayLike, times: ArrayLike, min_gap: int, min_score: float = 3.0,
                  min_ratio: float = 0.5, per_frame: int = 1) -> list[tuple[int, int, float]]:
    """Pairs of frames far apart in time that see the same thing: mutual nearest neighbours that stand out.

    Parameters
    ----------
    vectors : array_like, shape (n, d)
        A global descriptor per frame (:func:`vlad`), centred on the
        frames' mean and scaled to unit length here.
    times : array_like of int, shape (n,)
        Each frame's position in the shot (frame index).
    min_gap : int
        Only frames at least this many frames apart count (the ones nearer
        are matched by order already).
    min_score : float
        How far a pair's similarity must stand above the frame's others
        outside the window: ``(s - median) / (1.4826 MAD)`` for both frames.
    min_ratio : float
        A pair's similarity must also be at least ``min_ratio`` times the
        median over frames of each frame's highest similarity to a frame
        inside the window (a neighbour it overlaps), the shot's own scale
        of "alike".
    per_frame : int
        Each frame's ``per_frame`` most similar frames outside the window are
        its candidates; a pair is kept when each frame is among the other's.

    Returns
    -------
    list of (i, j, similarity)
        Indices into ``vectors`` with ``i < j``, sorted by ``(i, j)``.
    """
    v = np.asarray(vectors, dtype=np.float64)
    t = np.asarray(times, dtype=np.int64)
    if v.ndim != 2 or len(v) != len(t):
        raise CamcalError(f"need one vector per frame time, got {v.shape} vectors and {t.shape} times")
    v = v - v.mean(axis=0)
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    similarity = v @ v.T
    gaps = np.abs(t[:, None] - t[None, :])
    far = gaps >= int(min_gap)
    near = np.where((gaps > 0) & ~far, similarity, -np.inf).max(axis=1)
    alike = float(np.median(near[np.isfinite(near)])) if np.isfinite(near).any() else 0.0
    candidates: list[set[int]] = []
    scores = np.full(similarity.shape, -np.inf)
    for i in range(len(v)):
        others = np.flatnonzero(far[i])
        if len(others) < 3:
            candidates.append(set())
            continue
        values = similarity[i, others]
        median = np.median(values)
        spread = 1.4826 * np.median(np.abs(values - median))
        scores[i, others] = (values - median) / max(spread, 1e-9)
        order = others[np.argsort(-values, kind="stable")[:per_frame]]
        candidates.append({int(j) for j in order})
    pairs = []
    for i in range(len(v)):
        for j in sorted(candidates[i]):
            if (i < j and i in candidates[j] and min(scores[i, j], scores[j, i]) >= min_score
                    and similarity[i, j] >= min_ratio * alike):
                pairs.append((i, j, float(similarity[i, j])))
    return pairs
