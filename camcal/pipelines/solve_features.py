"""A solve's feature extraction: in this process on COLMAP's threads, or one Dask task per image, resumable.

In this process, :func:`extract_features` is pycolmap's ``extract_features``
over every image, as ``solve`` always did. On Dask (:class:`DaskExtraction`:
a scheduler's address or a local cluster of worker processes), each image is
one task (:func:`extract_image`): COLMAP's own extractor, with the options
the local run uses, on that one image into a scratch database beside its
cache file; its keypoints and descriptors are then written atomically to
the cache file ``OUT/.camcal-features/<camera>/<image>.npz``
(:data:`FEATURE_CACHE`). The client then creates the cameras, rigs, frames
and images with COLMAP's image reader (``pycolmap.import_images``, the reader
the extraction uses, so the cameras are the same) and writes each image's
features into the database in name order, that is frame order. The matching
runs on Dask too, from these cache files (:mod:`camcal.pipelines.solve_matching`); the mapper stays on the
client.

The same features
-----------------
COLMAP's CPU SIFT extracts each image on one thread, whatever the number of
threads (``num_threads`` only sets how many images are in flight), from the
image, its mask and the options alone: a task's keypoints and descriptors
are the in-process run's bit for bit (checked by the tests on the local
path's database, image by image).

Resume
------
Each cache file records a key: the SHA-256 of the staged image's bytes, its
mask's, the extraction options (threads aside), the pycolmap version and the
cache format. A run takes every cache file whose key is its own and extracts
only the others; a killed client or worker leaves complete files (each
renamed into place whole) and, at most, the temporaries of the writes it
was in (``.NAME.camcal-tmp.XXXXXXXX``, :mod:`camcal.base.atomic`), which the
next run removes before it starts. The cache is removed once the solve ends
(:func:`camcal.pipelines.solve.solve_sfm`): it is kept only by a run that
was killed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_path, remove_stale_temporaries, scratch_dir
from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import glog_level
from camcal.pipelines.distributed import dask_client, run_tasks

__all__ = ["FEATURE_CACHE", "TASK_GLOG_LEVEL", "DaskExtraction", "cache_file", "extract_features", "extract_image",
           "feature_key", "read_cached"]

#: The folder, inside a solve's output folder, of the per-image feature files of an extraction on Dask.
FEATURE_CACHE = ".camcal-features"
_CACHE_FORMAT = "camcal.sift-features.1"
#: COLMAP's log lines a task lets through (glog's severities: 0 info, 1 warning, 2 error): a worker's output is the
#: terminal of ``solve --workers`` or a farm's worker log, not the solve's ``colmap.log``, so its progress lines stay
#: out and its warnings go on.
TASK_GLOG_LEVEL = 1


@dataclass(frozen=True)
class DaskExtraction:
    """Where a solve's features are extracted (and matched) on Dask, and the cache its tasks write.

    Attributes
    ----------
    cache : Path
        The folder of the per-image feature files (``OUT/.camcal-features``) and of the per-block match files.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); its workers must see the solve's output folder.
    workers : int, optional
        Otherwise, worker processes of a local cluster (default: one per core).
    client : distributed.Client, optional
        A client already open on that cluster, which each stage uses instead of opening its own.
    """

    cache: Path
    scheduler: str | None = None
    workers: int | None = None
    client: Any = None

    def connect(self) -> contextlib.AbstractContextManager:
        """A ``with`` block's client: :attr:`client`, else a new one on the scheduler or a local cluster."""
        return contextlib.nullcontext(self.client) if self.client is not None else dask_client(self.workers,
                                                                                                self.scheduler)


def cache_file(cache: str | os.PathLike, name: str) -> Path:
    """The feature file of COLMAP's image ``name`` (``camera/000012.png``): ``cache/camera/000012.png.npz``."""
    return Path(cache) / f"{name}.npz"


def feature_key(pycolmap, image: Path, mask: Path | None, extraction) -> str:
    """What a cached extraction of ``image`` must match: SHA-256 of its bytes, its mask's, the options, the version.

    ``extraction`` is a ``pycolmap.FeatureExtractionOptions``; its thread count is left out (the features do not
    depend on it).
    """
    options = {key: value for key, value in extraction.todict().items() if key != "num_threads"}
    digest = hashlib.sha256()
    digest.update(json.dumps([_CACHE_FORMAT, pycolmap.__version__, options], sort_keys=True, default=str).encode())
    for path in (image, mask):
        data = b"" if path is None else Path(path).read_bytes()
        digest.update(len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()


def read_cached(path: str | os.PathLike, key: str) -> tuple[NDArray[np.float32], NDArray[np.uint8]] | None:
    """The keypoints (N x 6, COLMAP's) and descriptors (N x 128) of a feature file, or None unless it is complete
    and its key is ``key``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            keypoints, descriptors = data["keypoints"], data["descriptors"]
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    if (keypoints.dtype != np.float32 or descriptors.dtype != np.uint8 or keypoints.ndim != 2 or descriptors.ndim != 2
            or keypoints.shape[1] != 6 or len(keypoints) != len(descriptors)):
        return None
    return keypoints, descriptors


def _write_features(path: Path, keypoints: NDArray[np.float32], descriptors: NDArray[np.uint8], key: str) -> None:
    """Write one image's features and key to ``path`` (a temporary name), flushed to disk."""
    with open(path, "wb") as handle:
        np.savez(handle, keypoints=keypoints, descriptors=descriptors, key=np.array(key))
        handle.flush()
        os.fsync(handle.fileno())


def extract_image(image_dir: str, name: str, mask_dir: str | None, extraction: dict, key: str, target: str,
                  seed: int) -> int:
    """One Dask task: COLMAP's features of image ``name`` under ``image_dir``, written atomically to ``target``.

    Parameters
    ----------
    image_dir : str
        COLMAP's image folder (the solve's staged images).
    name : str
        The image, relative to it (``camera/000012.png``).
    mask_dir : str, optional
        COLMAP's mask folder (``mask_dir/<name>.png``), if the solve has masks.
    extraction : dict
        The solve's ``pycolmap.FeatureExtractionOptions`` as ``todict()`` gives them (pycolmap's pickled options
        lose an unset path); the extraction runs on one thread.
    key : str
        :func:`feature_key` of the image, recorded in the file.
    target : str
        The feature file (:func:`cache_file`).
    seed : int
        COLMAP's global random seed, as the in-process extraction sets it.

    Returns
    -------
    int
        The number of features.
    """
    pycolmap = require("pycolmap")
    options = pycolmap.FeatureExtractionOptions(extraction)
    options.num_threads = 1
    with scratch_dir(target) as scratch, glog_level(pycolmap, TASK_GLOG_LEVEL):
        database = scratch / "database.db"
        pycolmap.set_random_seed(seed)
        pycolmap.extract_features(database, image_dir, image_names=[name], camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=_reader(pycolmap, "SIMPLE_PINHOLE", mask_dir),
                                  extraction_options=options, device=pycolmap.Device.cpu)
        db = pycolmap.Database.open(database)
        try:
            images = db.read_all_images()
            if len(images) != 1:
                raise CamcalError("COLMAP cannot read it (a damaged or unsupported image?)")
            keypoints = np.asarray(db.read_keypoints(images[0].image_id), np.float32)
            descriptors = np.asarray(db.read_descriptors(images[0].image_id).data, np.uint8)
        finally:
            db.close()
    with atomic_path(target) as tmp:
        _write_features(tmp, keypoints, descriptors, key)
    return len(keypoints)


def _reader(pycolmap, camera_model: str, mask_dir: str | os.PathLike | None):
    """COLMAP's image reader options: the cameras' model, the masks' folder (COLMAP's empty default when None)."""
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    if mask_dir is not None:
        reader.mask_path = mask_dir
    return reader


def extract_features(pycolmap, database: Path, image_dir: Path, image_names: Sequence[str], camera_mode,
                     camera_model: str, mask_dir: Path | None, extraction, seed: int, dask: DaskExtraction | None = None,
                     labels: Mapping[str, object] | None = None,
                     progress: Callable[[str], None] | None = None) -> dict[str, str] | None:
    """Extract the features of ``image_names`` into a new COLMAP ``database``: in this process, or on Dask.

    Parameters
    ----------
    database, image_dir : Path
        The database to create, COLMAP's image folder.
    image_names : sequence of str
        The images, relative to ``image_dir``.
    camera_mode : pycolmap.CameraMode
    camera_model : str
        COLMAP's model of the cameras the image reader creates.
    mask_dir : Path, optional
        COLMAP's masks, ``mask_dir/<image name>.png``.
    extraction : pycolmap.FeatureExtractionOptions
    seed : int
        COLMAP's global random seed.
    dask : DaskExtraction, optional
        One Dask task per image, through the per-image cache (see the module); None: in this process.
    labels : mapping, optional
        Image name -> what to call it in messages (the user's file).
    progress : callable, optional
        Receives the stage's line.

    Returns
    -------
    dict of str to str or None
        On Dask, image name -> :func:`feature_key` of its feature file (what the matching tasks read); else None.

    Raises
    ------
    CamcalError
        An image COLMAP cannot read, a task lost with more workers than Dask allows, an unreachable scheduler.
    """
    reader = _reader(pycolmap, camera_model, mask_dir)
    if dask is None:
        if progress is not None:
            progress(f"extracting features from {len(image_names)} images")
        pycolmap.set_random_seed(seed)
        pycolmap.extract_features(database, image_dir, image_names=list(image_names), camera_mode=camera_mode,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        return None
    names = sorted(image_names)
    targets = {name: cache_file(dask.cache, name) for name in names}
    remove_stale_temporaries(targets.values())  # what killed writers left
    keys = {name: feature_key(pycolmap, image_dir / name, None if mask_dir is None else mask_dir / f"{name}.png",
                              extraction) for name in names}
    todo = [name for name in names if read_cached(targets[name], keys[name]) is None]
    if progress is not None:
        reused = len(names) - len(todo)
        progress(f"extracting features from {len(names)} images on Dask"
                 + (f" ({reused} taken from an interrupted run's cache)" if reused else ""))
    if todo:
        _run_tasks(todo, image_dir, mask_dir, extraction.todict(), keys, targets, seed, dask, labels or {})
    pycolmap.Database.open(database).close()
    pycolmap.import_images(database, image_dir, camera_mode=camera_mode, image_names=names, options=reader)
    db = pycolmap.Database.open(database)
    try:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        for name in names:  # frame order
            features = read_cached(targets[name], keys[name])
            if features is None or name not in ids:
                raise CamcalError(f"the features of {labels.get(name, name) if labels else name} are missing from "
                                  f"{targets[name]} after their extraction")
            db.write_keypoints(ids[name], features[0])
            db.write_descriptors(ids[name], pycolmap.FeatureDescriptors(extraction.type, features[1]))
    finally:
        db.close()
    return keys


def _run_tasks(todo: list[str], image_dir: Path, mask_dir: Path | None, extraction: dict, keys: dict[str, str],
               targets: dict[str, Path], seed: int, dask: DaskExtraction, labels: Mapping[str, object]) -> None:
    """Submit one :func:`extract_image` task per image of ``todo`` and wait for them all; a failure names its image."""
    with dask.connect() as client:
        # absolute paths: a farm's workers do not share the client's working directory
        run_tasks(client, {name: (extract_image, (os.path.abspath(image_dir), name,
                                                  None if mask_dir is None else os.path.abspath(mask_dir),
                                                  extraction, keys[name], os.path.abspath(targets[name]), seed))
                           for name in todo},
                  lambda name, what: f"feature extraction of {labels.get(name, name)}: {what}")
