"""Loop closure for a plate matched by frame order: keyframes retrieved by VLAD, the revisits matched and verified.

COLMAP's own loop detection in the sequential matcher needs a vocabulary-tree
file trained elsewhere; this one trains its vocabulary on the plate's own
features (:mod:`camcal.geometry.retrieval`). After feature extraction and the
matching by frame order, every second frame of each camera is a keyframe
(:data:`KEYFRAME_STEP`); the keyframes' SIFT descriptors (as COLMAP's database holds them)
give each a VLAD vector; keyframe pairs further apart in time than the
matching window whose vectors stand out as mutual nearest neighbours are
handed to COLMAP's matcher as a list of image pairs, and COLMAP's geometric
verification decides which of them hold (``pycolmap.match_image_pairs``).

References
----------
Jégou, H., Douze, M., Schmid, C. & Pérez, P. (2010). Aggregating local
descriptors into a compact image representation. CVPR.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.geometry.retrieval import revisit_pairs, train_vocabulary, vlad
from camcal.pipelines.solve_colmap import MIN_PAIR_MATCHES

__all__ = ["KEYFRAME_STEP", "LOOP_MODES", "LoopClosure", "close_loops", "keyframe_times"]

LOOP_MODES = ("auto", "off")
#: every this many frames of each camera is a keyframe (every third missed the revisit of a rendered orbit with
#: some vocabulary seeds, every second found it with each).
KEYFRAME_STEP = 2
#: words of the VLAD vocabulary (32 x 128 SIFT dimensions: a 4096-long vector per keyframe).
_WORDS = 32
#: local descriptors per keyframe pooled for the vocabulary (spread evenly over the keyframe's).
_PER_KEYFRAME = 400


@dataclass(frozen=True)
class LoopClosure:
    """What loop closure added to the matching.

    Attributes
    ----------
    n_keyframes : int
        Frames a global descriptor was computed for.
    pairs : tuple of (str, str)
        Image pairs (COLMAP's names) retrieved as revisits and matched.
    n_verified : int
        Of those, the pairs COLMAP's geometric verification kept (at least
        :data:`camcal.pipelines.solve_colmap.MIN_PAIR_MATCHES` inliers).
    """

    n_keyframes: int
    pairs: tuple[tuple[str, str], ...]
    n_verified: int

    def line(self) -> str:
        """What the solve prints."""
        return (f"loop closure: {len(self.pairs)} revisit pairs among {self.n_keyframes} keyframes matched, "
                f"{self.n_verified} verified")


def keyframe_times(names: list[str], step: int) -> dict[str, int]:
    """Every ``step``-th image of each camera (names ``camera/file``, in name order) -> its frame index."""
    per_camera: dict[str, list[str]] = {}
    for name in sorted(names):
        per_camera.setdefault(name.split("/")[0] if "/" in name else "", []).append(name)
    return {name: index for frames in per_camera.values() for index, name in enumerate(frames) if index % step == 0}


def _spread(rows: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` of ``rows``, evenly spaced (a copy: the whole array is not kept alive)."""
    return rows[::max(1, -(-len(rows) // count))][:count].copy()


def close_loops(pycolmap, database: Path, window: int, match_pairs: Callable[[Sequence[tuple[str, str]]], None],
                seed: int) -> LoopClosure:
    """Retrieve the revisits of a plate matched by frame order (``window`` frames each way) and match them.

    Parameters
    ----------
    pycolmap : module
    database : Path
        COLMAP's database, features extracted and matched by frame order.
    window : int
        The sequential matcher's overlap: revisits nearer in time are left
        to it. With COLMAP's default quadratic overlap it matches the gaps
        1, 2, 4, 8, ... (pycolmap 4.2.1), not every gap up to ``window``;
        pairs it matched already are skipped here.
    match_pairs : callable
        Matches and verifies a list of image pairs (COLMAP's names) as the
        sequential matching did
        (:meth:`camcal.pipelines.solve_matching.PairMatcher.match_pairs`).
    seed : int
        Seeds the vocabulary.
    """
    db = pycolmap.Database.open(database)
    try:
        images = {image.name: image.image_id for image in db.read_all_images()}
        times = keyframe_times(list(images), KEYFRAME_STEP)
        names = sorted(times)
        # two passes over the keyframes, one held at a time: a long plate's descriptors do not fit in memory
        pooled = [_spread(np.asarray(db.read_descriptors(images[name]).data), _PER_KEYFRAME) for name in names]
        if len(names) < 4 or sum(len(block) for block in pooled) < 10 * _WORDS:
            return LoopClosure(len(names), (), 0)
        vocabulary = train_vocabulary(np.concatenate(pooled), _WORDS, seed)
        del pooled
        vectors = np.stack([vlad(np.asarray(db.read_descriptors(images[name]).data), vocabulary) for name in names])
    finally:
        db.close()
    found = revisit_pairs(vectors, [times[name] for name in names], min_gap=window + 1)
    db = pycolmap.Database.open(database)
    try:
        pairs = tuple((names[i], names[j]) for i, j, _ in found
                      if not db.exists_matches(images[names[i]], images[names[j]]))
    finally:
        db.close()
    if not pairs:
        return LoopClosure(len(names), (), 0)
    match_pairs(pairs)
    db = pycolmap.Database.open(database)
    try:
        verified = sum(db.exists_two_view_geometry(images[a], images[b])
                       and len(db.read_two_view_geometry(images[a], images[b]).inlier_matches) >= MIN_PAIR_MATCHES
                       for a, b in pairs)
    finally:
        db.close()
    return LoopClosure(len(names), pairs, int(verified))
