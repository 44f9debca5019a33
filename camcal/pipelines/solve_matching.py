"""A solve's feature matching: in this process on one thread, or its image pairs in blocks on Dask, resumable.

In this process, :class:`PairMatcher` calls pycolmap's ``match_exhaustive``
or ``match_sequential`` (and ``match_image_pairs`` for a list of pairs, the
loop closure's), on one thread (:data:`MATCHING_THREADS`). On Dask (the solve's
:class:`~camcal.pipelines.solve_features.DaskExtraction`), the pairs COLMAP's
matcher would match are taken from COLMAP's own pair generator
(``pycolmap.SequentialPairGenerator`` / ``ExhaustivePairGenerator`` on the
solve's database, default options, as those two functions use them) and cut,
in the generator's order, into blocks of :data:`BLOCK_PAIRS`. Each block is
one task (:func:`match_block`): a scratch COLMAP database holding the
cameras and only the block's images, under their ids in the solve's
database, with their features from the extraction's cache files
(:mod:`camcal.pipelines.solve_features`); pycolmap's pair-list matcher
(``match_image_pairs``: the same SIFT matcher, the same options, and the
two-view geometric verification) matches the block there, and the matches and
verified geometries it wrote are saved atomically to the block's cache file
``OUT/.camcal-features/matches-<stage>-<block>.npz``. The client then writes
every block's rows into its database, block after block, pair ids in order.

The same matches
----------------
COLMAP matches and verifies each pair on its own, from the two images'
features, their cameras and the options alone (the RANSAC of each pair
seeded with the solve's seed): on one thread, a pair's matches and two-view
geometry do not depend on the other pairs or the other images. (On several
threads pycolmap 4.2.1's CPU matcher matched some pairs differently from run
to run, and worse: :data:`MATCHING_THREADS`.) The matches
and geometries written back are the in-process run's bit for bit, and so is
the reconstruction (checked by the tests: every row of both databases, then
the solved rig). The pair orientation (which image is first) is the
generator's, since the verification of (b, a) is not that of (a, b).

Resume
------
Each block's file records a key: the SHA-256 of its pairs, its images' ids,
cameras and feature keys (the images' bytes, masks and extraction options),
the matching and verification options (threads aside), the pycolmap version
and the cache format. A rerun takes every block whose file holds its key and
matches only the others; a block whose worker was killed is matched again by
another worker (Dask's retry) or by the rerun. The cache goes with the
feature cache when the solve ends.

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR (the matching and geometric verification of COLMAP).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_path, remove_stale_temporaries, scratch_dir
from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import glog_level
from camcal.pipelines.distributed import dask_client, run_tasks
from camcal.pipelines.solve_features import TASK_GLOG_LEVEL, DaskExtraction, cache_file, read_cached

__all__ = ["BLOCK_PAIRS", "MATCHING_THREADS", "PairMatcher", "block_file", "dask_stages", "match_block", "matcher_pairs",
           "read_block"]

#: Image pairs per Dask task. Each task loads its images' features and COLMAP builds each image's matching index
#: again in every block the image is in: on the 60-frame walk of ``bench/bench_plates.py`` (8192 features, 297
#: sequential pairs, one thread, a loaded machine) blocks of 50 pairs took 1.18x the time of one run over the
#: whole plate (168 image loads against 60), blocks of 150 1.05x (92). 100 pairs are under a minute of a worker
#: (what a killed worker loses) and a 1000-frame plate matched by frame order about 60 tasks.
BLOCK_PAIRS = 100
#: COLMAP's matching threads, in this process (:class:`PairMatcher`) and in each Dask block (:func:`match_block`),
#: whatever the options say. pycolmap 4.2.1's CPU matcher on several threads matched a few pairs of a plate
#: differently from run to run: on 80 frames of the rendered blurred walk, 2 to 17 of 436 pairs, keeping as few as
#: 681 of the 3,778 matches the single-threaded matcher finds between two neighbouring frames, which moved the
#: solved focal length by 1e-4 between runs. On one thread each pair's matches and geometry depend on its two
#: images and the options alone. Dask (``workers``, ``scheduler``) matches blocks of pairs in parallel.
MATCHING_THREADS = 1
_CACHE_FORMAT = "camcal.sift-matches.1"
#: The two-view geometry's matrices, each stored only where COLMAP estimated it.
_MATRICES = ("E", "F", "H")


@contextlib.contextmanager
def dask_stages(cache: Path, scheduler: str | None, workers: int | None) -> Iterator[DaskExtraction | None]:
    """A solve's Dask, one client for its extraction and matching; None unless ``scheduler`` or ``workers``.

    Enter it before COLMAP's output is captured (:func:`camcal.base.native_log.native_output_to`): the processes
    of a local cluster started inside that block would share the pipe it reads.

    Raises
    ------
    CamcalError
        The scheduler cannot be reached.
    """
    if scheduler is None and workers is None:
        yield None
        return
    with dask_client(workers, scheduler) as client:
        yield DaskExtraction(cache, scheduler, workers, client)


def matcher_pairs(pycolmap, database: Path, matcher: str) -> list[tuple[int, int]]:
    """The image pairs (ids, in order) COLMAP's ``matcher`` matches in ``database``: its own pair generator's."""
    db = pycolmap.Database.open(database)
    try:
        if matcher == "sequential":
            generator = pycolmap.SequentialPairGenerator(pycolmap.SequentialPairingOptions(), db)
        else:
            generator = pycolmap.ExhaustivePairGenerator(pycolmap.ExhaustivePairingOptions(), db)
        return [(int(a), int(b)) for a, b in generator.all_pairs()]
    finally:
        db.close()


def block_file(cache: str | os.PathLike, stage: str, index: int) -> Path:
    """The match file of block ``index`` of a matching stage: ``cache/matches-<stage>-<index>.npz``."""
    return Path(cache) / f"matches-{stage}-{index:05d}.npz"


def _block_key(pycolmap, cameras: list[tuple], images: list[tuple], pairs: list[tuple[str, str]], matching: dict,
               verification: dict) -> str:
    """What a block's cached matches must match: SHA-256 of its pairs, images, cameras, options and the version."""
    options = {key: value for key, value in matching.items() if key != "num_threads"}
    text = json.dumps([_CACHE_FORMAT, pycolmap.__version__, cameras, [row[:3] + row[4:] for row in images], pairs,
                       options, verification], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _concatenated(arrays: list[NDArray]) -> NDArray[np.uint32]:
    """Match lists (each M x 2) stacked, with an empty (0 x 2) for none."""
    return np.concatenate([np.asarray(a, np.uint32).reshape(-1, 2) for a in arrays]) if arrays else np.zeros(
        (0, 2), np.uint32)


def _database_rows(pycolmap, database: Path) -> dict[str, NDArray]:
    """Every match list and two-view geometry of a COLMAP ``database``, as arrays (what a block file holds)."""
    db = pycolmap.Database.open(database)
    try:
        match_pairs, matches = db.read_all_matches()
        geometry_pairs, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    rows = {"match_pairs": np.asarray(match_pairs, np.int64), "match_counts": np.array([len(m) for m in matches],
                                                                                        np.int64),
            "matches": _concatenated(matches), "geometry_pairs": np.asarray(geometry_pairs, np.int64),
            "configs": np.array([int(g.config) for g in geometries], np.int64),
            "inlier_counts": np.array([len(g.inlier_matches) for g in geometries], np.int64),
            "inliers": _concatenated([g.inlier_matches for g in geometries])}
    for name in _MATRICES:
        values = [getattr(g, name) for g in geometries]
        rows[f"has_{name}"] = np.array([v is not None for v in values], bool)
        rows[name] = np.array([np.zeros((3, 3)) if v is None else np.asarray(v, np.float64) for v in values],
                              np.float64).reshape(-1, 3, 3)
    poses = [g.cam2_from_cam1 for g in geometries]
    rows["has_pose"] = np.array([p is not None for p in poses], bool)
    rows["rotations"] = np.array([np.zeros(4) if p is None else p.rotation.quat for p in poses],
                                 np.float64).reshape(-1, 4)
    rows["translations"] = np.array([np.zeros(3) if p is None else p.translation for p in poses],
                                    np.float64).reshape(-1, 3)
    return rows


def _write_rows(path: Path, rows: dict[str, NDArray], key: str) -> None:
    """Write a block's rows and key to ``path`` (a temporary name), flushed to disk."""
    with open(path, "wb") as handle:
        np.savez(handle, key=np.array(key), **rows)
        handle.flush()
        os.fsync(handle.fileno())


def read_block(path: str | os.PathLike, key: str) -> dict[str, NDArray] | None:
    """The rows of a block file (see :func:`match_block`), or None unless it is complete and its key is ``key``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            rows = {name: data[name] for name in data.files if name != "key"}
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    n_pairs, n_geometries = len(rows.get("match_pairs", ())), len(rows.get("geometry_pairs", ()))
    shapes_fit = (
        "matches" in rows and "inliers" in rows and len(rows.get("match_counts", ())) == n_pairs
        and rows["match_counts"].sum() == len(rows["matches"])
        and all(len(rows.get(name, ())) == n_geometries
                for name in ("configs", "inlier_counts", "has_pose", "rotations", "translations",
                             *_MATRICES, *(f"has_{m}" for m in _MATRICES)))
        and rows["inlier_counts"].sum() == len(rows["inliers"]))
    return rows if shapes_fit else None


def match_block(cameras: list[tuple], images: list[tuple], pairs: list[tuple[str, str]], matching: dict,
                verification: dict, descriptor_type, key: str, target: str) -> int:
    """One Dask task: COLMAP's matches and two-view geometries of ``pairs``, written atomically to ``target``.

    Parameters
    ----------
    cameras : list of tuple
        ``(camera_id, model name, width, height, params, has_prior_focal_length)`` of the block's images' cameras,
        as the solve's database has them.
    images : list of tuple
        ``(image_id, name, camera_id, feature file, feature key)`` of the images the pairs name: their ids in the
        solve's database and their features' cache file (:mod:`camcal.pipelines.solve_features`).
    pairs : list of (str, str)
        The image pairs to match, in COLMAP's orientation.
    matching, verification : dict
        The solve's ``FeatureMatchingOptions`` and ``TwoViewGeometryOptions`` (``todict()``); the matching runs
        on one thread.
    descriptor_type : pycolmap.FeatureExtractorType
        The descriptors' type.
    key : str
        The block's key, recorded in the file.
    target : str
        The block file (:func:`block_file`).

    Returns
    -------
    int
        The number of pairs with matches.
    """
    pycolmap = require("pycolmap")
    matching_options = pycolmap.FeatureMatchingOptions(matching)
    matching_options.num_threads = MATCHING_THREADS
    with scratch_dir(target) as scratch, glog_level(pycolmap, TASK_GLOG_LEVEL):
        database = scratch / "database.db"
        db = pycolmap.Database.open(database)
        try:
            for camera_id, model, width, height, params, prior in cameras:
                db.write_camera(pycolmap.Camera(camera_id=camera_id, model=model, width=width, height=height,
                                                params=params, has_prior_focal_length=prior), use_camera_id=True)
            for image_id, name, camera_id, features_file, feature_key in images:
                features = read_cached(features_file, feature_key)
                if features is None:
                    raise CamcalError(f"the features of {name} are missing from {features_file}")
                db.write_image(pycolmap.Image(name=name, camera_id=camera_id, image_id=image_id), use_image_id=True)
                db.write_keypoints(image_id, features[0])
                db.write_descriptors(image_id, pycolmap.FeatureDescriptors(descriptor_type, features[1]))
        finally:
            db.close()
        pair_list = scratch / "pairs.txt"
        pair_list.write_text("".join(f"{a} {b}\n" for a, b in pairs))
        pycolmap.match_image_pairs(database, matching_options=matching_options,
                                   pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(pair_list)),
                                   verification_options=pycolmap.TwoViewGeometryOptions(verification),
                                   device=pycolmap.Device.cpu)
        rows = _database_rows(pycolmap, database)
    with atomic_path(target) as tmp:
        _write_rows(tmp, rows, key)
    return len(rows["match_pairs"])


def _write_block(pycolmap, db, rows: dict[str, NDArray]) -> None:
    """Write a block's match lists and two-view geometries into the open database ``db``, pair ids in order."""
    ends = np.cumsum(rows["match_counts"])
    for pair_id, end, count in zip(rows["match_pairs"], ends, rows["match_counts"]):
        db.write_matches(*pycolmap.pair_id_to_image_pair(int(pair_id)), rows["matches"][end - count:end])
    ends = np.cumsum(rows["inlier_counts"])
    for k, (pair_id, end, count) in enumerate(zip(rows["geometry_pairs"], ends, rows["inlier_counts"])):
        geometry = pycolmap.TwoViewGeometry()
        geometry.config = pycolmap.TwoViewGeometryConfiguration(int(rows["configs"][k]))
        for name in _MATRICES:
            if rows[f"has_{name}"][k]:
                setattr(geometry, name, rows[name][k])
        if rows["has_pose"][k]:
            geometry.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(rows["rotations"][k]),
                                                       rows["translations"][k])
        geometry.inlier_matches = rows["inliers"][end - count:end]
        db.write_two_view_geometry(*pycolmap.pair_id_to_image_pair(int(pair_id)), geometry)


class PairMatcher:
    """Matches the image pairs of a solve's COLMAP database: in this process, or in blocks on Dask.

    Parameters
    ----------
    pycolmap : module
    database : Path
        The solve's database, its features extracted (and its images numbered in name order).
    matching, verification
        The solve's ``FeatureMatchingOptions`` and ``TwoViewGeometryOptions``; the matching runs on
        :data:`MATCHING_THREADS` whatever ``matching.num_threads`` (a copy is changed, not ``matching``).
    dask : DaskExtraction, optional
        Match on this Dask cluster, from the feature cache of the extraction there; None: in this process.
    feature_keys : mapping, optional
        With ``dask``: image name -> the key of its feature file (what
        :func:`camcal.pipelines.solve_features.extract_features` returns).
    labels : mapping, optional
        Image name -> what to call it in messages (the user's file).
    progress : callable, optional
        Receives the Dask stages' lines.
    """

    def __init__(self, pycolmap, database: Path, matching, verification, dask: DaskExtraction | None = None,
                 feature_keys: Mapping[str, str] | None = None, labels: Mapping[str, object] | None = None,
                 progress: Callable[[str], None] | None = None) -> None:
        if dask is not None and feature_keys is None:
            raise ValueError("matching on Dask takes the features' keys of their extraction on Dask")
        self.pycolmap, self.database, self.dask = pycolmap, Path(database), dask
        self.matching, self.verification = pycolmap.FeatureMatchingOptions(matching.todict()), verification
        self.matching.num_threads = MATCHING_THREADS
        self.feature_keys, self.labels, self.progress = feature_keys or {}, labels or {}, progress

    def match(self, matcher: str) -> None:
        """Match and verify the pairs of COLMAP's ``matcher`` (``"exhaustive"`` or ``"sequential"``)."""
        pycolmap = self.pycolmap
        if self.dask is None:
            match = pycolmap.match_exhaustive if matcher == "exhaustive" else pycolmap.match_sequential
            match(self.database, matching_options=self.matching, verification_options=self.verification,
                  device=pycolmap.Device.cpu)
            return
        db = pycolmap.Database.open(self.database)
        try:
            names = {image.image_id: image.name for image in db.read_all_images()}
        finally:
            db.close()
        self._on_dask([(names[a], names[b]) for a, b in matcher_pairs(pycolmap, self.database, matcher)], matcher)

    def match_pairs(self, pairs: Sequence[tuple[str, str]], stage: str = "listed") -> None:
        """Match and verify the image pairs ``pairs`` (COLMAP's names), none of them matched yet.

        ``stage`` names the Dask stage's cache files (each stage of a solve its own).
        """
        if self.dask is not None:
            self._on_dask(list(pairs), stage)
            return
        pair_list = self.database.with_name("match_pairs.txt")
        pair_list.write_text("".join(f"{a} {b}\n" for a, b in pairs))
        try:
            self.pycolmap.match_image_pairs(self.database, matching_options=self.matching,
                                            pairing_options=self.pycolmap.ImportedPairingOptions(
                                                match_list_path=str(pair_list)),
                                            verification_options=self.verification, device=self.pycolmap.Device.cpu)
        finally:
            pair_list.unlink()

    def _on_dask(self, pairs: list[tuple[str, str]], stage: str) -> None:
        """Match ``pairs`` in blocks on Dask (taking the blocks an interrupted run finished), then write them here."""
        pycolmap, dask = self.pycolmap, self.dask
        if not pairs:
            return
        db = pycolmap.Database.open(self.database)
        try:
            cameras = {camera.camera_id: camera for camera in db.read_all_cameras()}
            images = {image.name: image for image in db.read_all_images()}
            descriptor_type = db.read_descriptors(images[pairs[0][0]].image_id).type
        finally:
            db.close()
        matching, verification = self.matching.todict(), self.verification.todict()
        blocks = [pairs[start:start + BLOCK_PAIRS] for start in range(0, len(pairs), BLOCK_PAIRS)]
        targets = [block_file(dask.cache, stage, index) for index in range(len(blocks))]
        tasks, keys = {}, []
        for index, block in enumerate(blocks):
            names = sorted({name for pair in block for name in pair})
            rows = [(images[name].image_id, name, images[name].camera_id, os.path.abspath(cache_file(dask.cache, name)),
                     self.feature_keys[name]) for name in names]
            block_cameras = [(c.camera_id, c.model.name, c.width, c.height, [float(p) for p in c.params],
                              bool(c.has_prior_focal_length))
                             for c in (cameras[camera_id] for camera_id in sorted({row[2] for row in rows}))]
            keys.append(_block_key(pycolmap, block_cameras, rows, block, matching, verification))
            tasks[index] = (match_block, (block_cameras, rows, block, matching, verification, descriptor_type,
                                          keys[index], os.path.abspath(targets[index])))
        remove_stale_temporaries(targets)  # what killed writers left
        todo = {index: task for index, task in tasks.items() if read_block(targets[index], keys[index]) is None}
        if self.progress is not None:
            reused = len(blocks) - len(todo)
            self.progress(f"matching {len(pairs)} image pairs in {len(blocks)} block{'s' * (len(blocks) != 1)} on Dask"
                          + (f" ({reused} taken from an interrupted run's cache)" if reused else ""))
        if todo:
            with dask.connect() as client:
                run_tasks(client, todo, lambda index, what: f"matching {self._span(blocks[index])}: {what}")
        db = pycolmap.Database.open(self.database)
        try:
            with pycolmap.DatabaseTransaction(db):
                for index, block in enumerate(blocks):  # block after block: the generator's order
                    rows = read_block(targets[index], keys[index])
                    if rows is None:
                        raise CamcalError(f"the matches of {self._span(block)} are missing from {targets[index]} "
                                          "after their matching")
                    _write_block(pycolmap, db, rows)
        finally:
            db.close()

    def _span(self, block: list[tuple[str, str]]) -> str:
        """A block's pairs in a message: its first and last images (the user's files)."""
        names = sorted({name for pair in block for name in pair})
        return (f"the {len(block)} image pairs of {self.labels.get(names[0], names[0])} to "
                f"{self.labels.get(names[-1], names[-1])}")
