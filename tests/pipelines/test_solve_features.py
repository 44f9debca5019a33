"""A solve's feature extraction on Dask: the in-process extraction's features, bit for bit, and its resume.

The fast tests use a ``LocalCluster`` of threads in this process (its workers
run the same task function as a farm's); the slow test in
``test_solve_faults.py`` runs a solve on worker processes and kills them.
"""

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.base.atomic import TEMPORARY_TAG
from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.pipelines.solve import solve_sfm
from camcal.pipelines.solve_colmap import extraction_options, number_by_name
from camcal.pipelines.solve_features import (FEATURE_CACHE, DaskExtraction, cache_file, extract_features,
                                             feature_key)
from camcal.synthetic import render_stereo_sequence

pycolmap = pytest.importorskip("pycolmap")
distributed = pytest.importorskip("distributed")

SIZE = (160, 120)


@pytest.fixture(scope="module")
def scheduler():
    """The address of a Dask cluster of 2 worker threads in this process."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0",
                                  silence_logs=logging.CRITICAL) as cluster:
        yield cluster.scheduler_address


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """Three frames of one camera of a rendered stereo sequence in COLMAP's layout: (folder, image names)."""
    folder = tmp_path_factory.mktemp("features") / "images"
    focal = 125.0
    render_stereo_sequence(folder, n_frames=3, image_size=SIZE,
                           K=((focal, 0.0, (SIZE[0] - 1) / 2), (0.0, focal, (SIZE[1] - 1) / 2), (0.0, 0.0, 1.0)))
    return folder, sorted(p.relative_to(folder).as_posix() for p in (folder / "left").iterdir())


def _extract(images, database, dask=None, progress=None, mask_dir=None):
    folder, names = images
    extraction = extraction_options(pycolmap, [folder / names[0]], 512, -1)
    extract_features(pycolmap, database, folder, names, pycolmap.CameraMode.PER_FOLDER, "SIMPLE_RADIAL", mask_dir,
                     extraction, 0, dask, progress=progress)
    number_by_name(pycolmap, database)
    return extraction


def _contents(database):
    """Every row a solve reads from an extracted database: cameras, rigs, frames, images and their features."""
    db = pycolmap.Database.open(database)
    try:
        cameras = [(c.camera_id, c.model, c.width, c.height, tuple(c.params)) for c in db.read_all_cameras()]
        images = [(i.image_id, i.name, i.camera_id) for i in db.read_all_images()]
        features = {i.name: (db.read_keypoints(i.image_id), db.read_descriptors(i.image_id).data)
                    for i in db.read_all_images()}
        rigs = [str(rig) for rig in db.read_all_rigs()]
        frames = [str(frame) for frame in db.read_all_frames()]
    finally:
        db.close()
    return cameras, images, features, rigs, frames


def _same_database(ours, local, n_images=3):
    *rows, features, rigs, frames = _contents(ours)
    *local_rows, local_features, local_rigs, local_frames = _contents(local)
    assert rows == local_rows and rigs == local_rigs and frames == local_frames
    assert list(features) == list(local_features) and len(features) == n_images
    for name, (keypoints, descriptors) in features.items():
        assert len(keypoints) > 50, name
        np.testing.assert_array_equal(keypoints, local_features[name][0])  # bit for bit
        np.testing.assert_array_equal(descriptors, local_features[name][1])


def test_dask_tasks_give_the_in_process_features_and_a_rerun_takes_what_a_killed_one_finished(images, scheduler,
                                                                                             tmp_path):
    _extract(images, tmp_path / "local.db")
    cache = tmp_path / "out" / FEATURE_CACHE
    dask = DaskExtraction(cache, scheduler=scheduler)
    lines = []
    extraction = _extract(images, tmp_path / "dask.db", dask, lines.append)
    assert lines == ["extracting features from 3 images on Dask"]
    _same_database(tmp_path / "dask.db", tmp_path / "local.db")

    # what a killed run leaves: a complete file, a write cut short, a task's scratch folder; and a stale file
    folder, names = images
    files = [cache_file(cache, name) for name in names]
    assert all(path.is_file() for path in files)
    np.savez(files[0], keypoints=np.zeros((1, 6), np.float32), descriptors=np.zeros((1, 128), np.uint8),
             key=np.array("of other options"))
    leave_a_killed_runs_files(cut=files[1], scratch_beside=files[2])
    kept = {files[2]: files[2].stat().st_mtime_ns}
    assert feature_key(pycolmap, folder / names[0], None, extraction) != "of other options"

    lines.clear()
    _extract(images, tmp_path / "resumed.db", dask, lines.append)
    assert lines == ["extracting features from 3 images on Dask (1 taken from an interrupted run's cache)"]
    assert {path: path.stat().st_mtime_ns for path in kept} == kept  # taken, not extracted again
    assert not [p for p in tmp_path.rglob("*") if TEMPORARY_TAG in p.name]
    _same_database(tmp_path / "resumed.db", tmp_path / "local.db")


def test_masks_reach_the_tasks(images, scheduler, tmp_path):
    """COLMAP's masks (white: no feature), given to the tasks: the in-process masked features, none on the left."""
    folder, names = images
    one = (folder, names[:1])
    edge = SIZE[0] // 2
    mask = np.full((SIZE[1], SIZE[0]), 255, np.uint8)
    mask[:, :edge] = 0  # COLMAP's mask: 0 where no feature is taken
    (tmp_path / "masks" / "left").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "masks" / f"{names[0]}.png"), mask)
    _extract(one, tmp_path / "local.db", mask_dir=tmp_path / "masks")
    _extract(one, tmp_path / "dask.db", DaskExtraction(tmp_path / "cache", scheduler=scheduler),
             mask_dir=tmp_path / "masks")
    _same_database(tmp_path / "dask.db", tmp_path / "local.db", n_images=1)
    assert _contents(tmp_path / "dask.db")[2][names[0]][0][:, 0].min() >= edge


def test_scheduler_and_workers_are_one_or_the_other(tmp_path, capsys):
    assert main(["solve", str(tmp_path), "--scheduler", "tcp://127.0.0.1:1", "--workers", "2", "--out", "out"]) == 2
    assert "argument --workers: not allowed with argument --scheduler" in capsys.readouterr().err


def test_a_frame_colmap_cannot_read_is_one_error_naming_it_and_nothing_is_left(images, scheduler, tmp_path):
    """The tasks of the other frames wrote their features: the failed solve removes them, and the folder a killed
    run left with only its cache, with the rest."""
    folder, _ = images
    plate = tmp_path / "plate"
    plate.mkdir()
    for index, png in enumerate(sorted((folder / "left").iterdir())):
        (plate / f"shot.{1001 + index}.png").write_bytes(png.read_bytes())
    (plate / "shot.1004.png").write_bytes(b"not a png")
    (tmp_path / "out" / FEATURE_CACHE / "left").mkdir(parents=True)  # a killed run's cache, and all it left
    (tmp_path / "out" / FEATURE_CACHE / "left" / "000000.png.npz").write_bytes(b"of another plate")
    with pytest.raises(CamcalError, match=r"feature extraction of .*shot\.1004\.png: COLMAP cannot read it"):
        solve_sfm({"left": plate}, tmp_path / "out", max_num_features=512, scheduler=scheduler)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plate"]


def leave_a_killed_runs_files(cut: Path, scratch_beside: Path) -> None:
    """What a killed run leaves in a cache: ``cut``'s write cut short (its temporary holds 100 bytes, the file is
    gone) and a task's scratch folder (with a database) beside ``scratch_beside``."""
    partial = cut.with_name(f".{cut.name}.{TEMPORARY_TAG}.k1ll3d00.npz")
    partial.write_bytes(cut.read_bytes()[:100])
    cut.unlink()
    (scratch_beside.with_name(f".{scratch_beside.name}.{TEMPORARY_TAG}.k1ll3d01") / "database.db").parent.mkdir()
