"""A plate's feature extraction and matching on Dask against the same stages in one process: time ratio, same rows.

The ``walk`` plate of ``bench_plates.py`` (640 x 360, rendered through
camcal's lens mapping), its first N frames. Both sides take the solve's own
options (``extraction_options`` with 8192 features, the seeded verification,
the sequential matcher):

- ``local``: ``extract_features`` then ``PairMatcher.match`` in this process,
  COLMAP's threads on every core (what ``solve`` does without Dask);
- ``dask``: the same two calls on a ``LocalCluster`` of W worker processes
  (one thread each), one task per image then one per block of image pairs,
  through the per-image and per-block cache files; the cluster's start-up is
  timed apart.

The two databases are then compared row by row: every match list and two-view
geometry must be equal bit for bit, or the run fails. On one machine Dask
cannot be faster than COLMAP's own threads on the same cores (it adds a
scheduler, the cache files and the tasks' databases); what it adds is more
machines (``solve --scheduler``) and resumption. Timings on a shared machine
are only comparable as the ratio within one run.

Usage: ``python bench/bench_dask_matching.py [--frames 60] [--workers 2] [--cache DIR]``.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_plates import render_shot  # noqa: E402

from camcal.pipelines.solve_colmap import extraction_options, number_by_name, verification_options  # noqa: E402
from camcal.pipelines.solve_features import FEATURE_CACHE, DaskExtraction, extract_features  # noqa: E402
from camcal.pipelines.solve_matching import PairMatcher  # noqa: E402


def _stages(pycolmap, plate: Path, database: Path, dask: DaskExtraction | None) -> tuple[float, float]:
    """Extract (from ``plate``'s PNG frames) and match by frame order into ``database``: the two stages' seconds."""
    names = sorted(p.name for p in plate.glob("plate.*.png"))
    extraction = extraction_options(pycolmap, [plate / names[0]], 8192, -1)
    start = time.perf_counter()
    keys = extract_features(pycolmap, database, plate, names, pycolmap.CameraMode.SINGLE, "SIMPLE_RADIAL", None,
                            extraction, 0, dask)
    number_by_name(pycolmap, database)
    extracted = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = -1
    PairMatcher(pycolmap, database, matching, verification_options(pycolmap, 0), dask, keys).match("sequential")
    return extracted - start, time.perf_counter() - extracted


def _rows(pycolmap, database: Path) -> tuple[dict, dict]:
    db = pycolmap.Database.open(database)
    try:
        return dict(zip(*db.read_all_matches())), dict(zip(*db.read_two_view_geometries()))
    finally:
        db.close()


def _same_rows(pycolmap, ours: Path, theirs: Path) -> int:
    """The pairs both databases hold, after checking every row is equal bit for bit (AssertionError otherwise)."""
    (matches, geometries), (their_matches, their_geometries) = _rows(pycolmap, ours), _rows(pycolmap, theirs)
    assert matches.keys() == their_matches.keys() and geometries.keys() == their_geometries.keys()
    for pair, rows in matches.items():
        assert np.array_equal(rows, their_matches[pair]), pair
    for pair, geometry in geometries.items():
        theirs_ = their_geometries[pair]
        assert int(geometry.config) == int(theirs_.config), pair
        assert np.array_equal(geometry.inlier_matches, theirs_.inlier_matches), pair
        for name in ("E", "F", "H"):
            a, b = getattr(geometry, name), getattr(theirs_, name)
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b)), (pair, name)
        a, b = geometry.cam2_from_cam1, theirs_.cam2_from_cam1
        assert (a is None) == (b is None) and (a is None or np.array_equal(a.matrix(), b.matrix())), pair
    return len(matches)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", type=Path, help="keep the render here between runs (default: a temporary folder)")
    args = parser.parse_args()
    import distributed
    import pycolmap

    with tempfile.TemporaryDirectory() as tmp:
        plate = (args.cache or Path(tmp)) / f"walk-{args.frames}"
        render_shot(plate, "walk", args.frames)
        work = Path(tmp) / "work"
        work.mkdir()
        local = _stages(pycolmap, plate, work / "local.db", None)
        start = time.perf_counter()
        with distributed.LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                                      dashboard_address=":0", silence_logs=logging.CRITICAL) as cluster, \
                distributed.Client(cluster) as client:
            started = time.perf_counter() - start
            dask = _stages(pycolmap, plate, work / "dask.db",
                           DaskExtraction(work / "out" / FEATURE_CACHE, workers=args.workers, client=client))
        shutil.rmtree(work / "out")
        n_pairs = _same_rows(pycolmap, work / "dask.db", work / "local.db")
    print(f"{args.frames} frames, {n_pairs} matched pairs: the Dask rows equal the local ones bit for bit")
    print(f"{'stage':<12}{'local s':>10}{f'dask ({args.workers} workers) s':>24}{'dask / local':>14}")
    for stage, a, b in (("extraction", local[0], dask[0]), ("matching", local[1], dask[1]),
                        ("both", sum(local), sum(dask))):
        print(f"{stage:<12}{a:>10.1f}{b:>24.1f}{b / a:>14.2f}")
    print(f"(the local cluster's start: {started:.1f} s, not counted)")


if __name__ == "__main__":
    main()
