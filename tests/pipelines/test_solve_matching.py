"""A solve's matching on Dask: the in-process matches, two-view geometries and rig, bit for bit, and its resume.

The fast tests use a ``LocalCluster`` of threads in this process (its workers
run the same task function as a farm's); the slow test in
``test_solve_faults.py`` kills a worker mid-block and the client, then reruns.
"""

import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from camcal.base.atomic import TEMPORARY_TAG
from camcal.pipelines import solve_matching
from camcal.pipelines.solve import solve_sfm
from camcal.pipelines.solve_colmap import extraction_options, number_by_name, verification_options
from camcal.pipelines.solve_features import FEATURE_CACHE, DaskExtraction, extract_features
from camcal.pipelines.solve_matching import MATCHING_THREADS, PairMatcher, block_file, matcher_pairs
from camcal.synthetic import render_stereo_sequence
from test_solve import _numbers
from dask_faults import workers_elsewhere
from test_solve_features import leave_a_killed_runs_files
from test_solve_features import scheduler  # noqa: F401 - the fixture: a Dask cluster of 2 threads in this process

pycolmap = pytest.importorskip("pycolmap")
distributed = pytest.importorskip("distributed")

N_FRAMES = 6


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """Six frames of one camera of a rendered stereo sequence: the folder of its PNG files."""
    root = tmp_path_factory.mktemp("matching")
    width = 192
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(root, n_frames=N_FRAMES, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    return root / "left"


@pytest.fixture(scope="module")
def extracted(plate, scheduler, tmp_path_factory):
    """The plate's features extracted on Dask, images numbered by name: (database, Dask stages, feature keys)."""
    root = tmp_path_factory.mktemp("extracted")
    images = root / "images"
    shutil.copytree(plate, images / "left")
    names = sorted(f"left/{p.name}" for p in plate.iterdir())
    dask = DaskExtraction(root / "out" / FEATURE_CACHE, scheduler=scheduler)
    keys = extract_features(pycolmap, root / "database.db", images, names, pycolmap.CameraMode.PER_FOLDER,
                            "SIMPLE_RADIAL", None, extraction_options(pycolmap, [images / names[0]], 512, -1), 0, dask)
    number_by_name(pycolmap, root / "database.db")
    return root / "database.db", dask, keys


def _rows(database):
    """Every match list and two-view geometry of a database, by image pair: what the mapper reads."""
    db = pycolmap.Database.open(database)
    try:
        matches = dict(zip(*db.read_all_matches()))
        geometries = {pair: geometry.todict() for pair, geometry in zip(*db.read_two_view_geometries())}
    finally:
        db.close()
    return matches, geometries


def _same_rows(ours, local):
    (matches, geometries), (local_matches, local_geometries) = _rows(ours), _rows(local)
    assert list(matches) == list(local_matches) and list(geometries) == list(local_geometries)
    for pair, rows in matches.items():
        np.testing.assert_array_equal(rows, local_matches[pair])  # bit for bit
    for pair, geometry in geometries.items():
        _same_value(geometry, local_geometries[pair], str(pair))
    return matches, geometries


def _same_value(ours, theirs, where):
    """Equal bit for bit, through pycolmap's ``todict()`` nesting (the relative pose's rotation and translation)."""
    if isinstance(ours, dict):
        assert isinstance(theirs, dict) and ours.keys() == theirs.keys(), where
        for field, value in ours.items():
            _same_value(value, theirs[field], f"{where}.{field}")
    elif isinstance(ours, np.ndarray) or isinstance(theirs, np.ndarray):
        np.testing.assert_array_equal(ours, theirs, err_msg=where)
        assert np.asarray(ours).dtype == np.asarray(theirs).dtype, where
    else:
        assert ours == theirs, where


def _copy(database, path, prior_focal_length=False):
    """A copy of the extracted database; with its cameras' focal length taken as known (calibrated verification)."""
    shutil.copy(database, path)
    if prior_focal_length:
        db = pycolmap.Database.open(path)
        try:
            for camera in db.read_all_cameras():
                camera.has_prior_focal_length = True
                db.update_camera(camera)
        finally:
            db.close()
    return path


def _matcher(database, dask=None, keys=None, lines=None, relative_pose=False):
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = -1  # every core asked: the matcher runs on MATCHING_THREADS all the same
    verification = verification_options(pycolmap, 0)
    verification.compute_relative_pose = relative_pose
    return PairMatcher(pycolmap, database, matching, verification, dask, keys,
                       progress=None if lines is None else lines.append)


@pytest.mark.parametrize(("matcher", "prior"), [("sequential", False), ("exhaustive", True)])
def test_blocks_on_dask_write_the_in_process_matches_and_geometries_bit_for_bit(extracted, matcher, prior, tmp_path,
                                                                                monkeypatch):
    """In 3-pair blocks, then listed pairs (the loop closure's path): every row as COLMAP's own matcher wrote it,
    with the focal length unknown (fundamental matrices) or known (essential matrices and relative poses)."""
    database, dask, keys = extracted
    monkeypatch.setattr(solve_matching, "BLOCK_PAIRS", 3)
    local, ours = (_copy(database, tmp_path / f"{name}.db", prior) for name in ("local", "dask"))
    generated = matcher_pairs(pycolmap, local, matcher)
    _matcher(local, relative_pose=prior).match(matcher)
    lines = []
    _matcher(ours, dask, keys, lines, relative_pose=prior).match(matcher)
    assert lines == [f"matching {len(generated)} image pairs in {-(-len(generated) // 3)} blocks on Dask"]
    matches, geometries = _same_rows(ours, local)
    assert {pycolmap.pair_id_to_image_pair(pair) for pair in matches} <= set(generated)
    assert len(geometries) >= N_FRAMES - 1
    configs = {geometry["config"] for geometry in geometries.values()}
    calibrated = int(pycolmap.TwoViewGeometryConfiguration.CALIBRATED)
    assert (calibrated in configs) == prior
    assert any(geometry["E"] is not None for geometry in geometries.values()) == prior
    assert any(geometry["cam2_from_cam1"] is not None for geometry in geometries.values()) == prior
    assert all(geometry["F"] is not None for geometry in geometries.values() if geometry["config"] == calibrated)
    if matcher == "sequential":  # frames the sequential pairs skip, as the loop closure hands them over
        unmatched = [(f"left/{a:04d}.png", f"left/{b:04d}.png") for a, b in ((0, 3), (1, 4))]
        assert not {pycolmap.image_pair_to_pair_id(a + 1, b + 1) for a, b in ((0, 3), (1, 4))} & set(matches)
        _matcher(local).match_pairs(unmatched)
        _matcher(ours, dask, keys).match_pairs(unmatched)
        assert len(_same_rows(ours, local)[0]) == len(matches) + 2
    # this test's folder and the extracted plate's (the folder other tests share holds their own temporaries)
    assert not [p for folder in (tmp_path, database.parent) for p in folder.rglob("*") if TEMPORARY_TAG in p.name]


def test_a_rerun_takes_the_blocks_a_killed_run_finished(extracted, tmp_path, monkeypatch):
    """What a killed run leaves (a complete block, a write cut short, a task's scratch folder, a block of other
    options): the rerun takes the complete block, matches the others again, leaves no temporary."""
    database, dask, keys = extracted
    monkeypatch.setattr(solve_matching, "BLOCK_PAIRS", 4)
    local = _copy(database, tmp_path / "local.db")
    _matcher(local).match("sequential")
    cache = tmp_path / "cache"
    ours = DaskExtraction(cache, scheduler=dask.scheduler)
    for name in keys:
        (cache / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(dask.cache / f"{name}.npz", cache / f"{name}.npz")
    _matcher(_copy(database, tmp_path / "first.db"), ours, keys).match("sequential")
    files = [block_file(cache, "sequential", index) for index in range(3)]
    assert all(path.is_file() for path in files) and not block_file(cache, "sequential", 3).exists()
    with np.load(files[0]) as data:
        np.savez(files[0], **{name: data[name] for name in data.files if name != "key"},
                 key=np.array("of other options"))
    leave_a_killed_runs_files(cut=files[1], scratch_beside=files[2])
    kept = {files[2]: files[2].stat().st_mtime_ns}

    lines = []
    _matcher(_copy(database, tmp_path / "resumed.db"), ours, keys, lines).match("sequential")
    assert lines == ["matching 11 image pairs in 3 blocks on Dask (1 taken from an interrupted run's cache)"]
    assert {path: path.stat().st_mtime_ns for path in kept} == kept  # taken, not matched again
    assert not [p for p in tmp_path.rglob("*") if TEMPORARY_TAG in p.name]
    _same_rows(tmp_path / "resumed.db", local)


def test_a_solve_matched_on_dask_gives_the_in_process_rig_bit_for_bit(plate, scheduler, tmp_path, monkeypatch):
    """solve --matcher sequential with loop closure, COLMAP's mapper only: the same database rows, the same rig and
    points; the caches gone."""
    monkeypatch.setattr(solve_matching, "BLOCK_PAIRS", 4)
    lines = []
    for name, where in (("local", None), ("dask", scheduler)):
        solve_sfm({"left": plate}, tmp_path / name, matcher="sequential", max_num_features=512, refine=False,
                  scheduler=where, progress=lines.append if where else None)
    assert "matching 11 image pairs in 3 blocks on Dask" in lines
    _same_rows(tmp_path / "dask" / "database.db", tmp_path / "local" / "database.db")
    ours = dict(_numbers(json.loads((tmp_path / "dask" / "solve.rig.json").read_text())))
    theirs = dict(_numbers(json.loads((tmp_path / "local" / "solve.rig.json").read_text())))
    assert ours == theirs and len(ours) > 6 * N_FRAMES
    assert (tmp_path / "dask" / "points.ply").read_bytes() == (tmp_path / "local" / "points.ply").read_bytes()
    assert sorted(p.name for p in (tmp_path / "dask").iterdir()) == sorted(
        p.name for p in (tmp_path / "local").iterdir())


def test_a_solve_matches_in_this_process_on_one_thread(plate, tmp_path, monkeypatch):
    """COLMAP's CPU matcher on several threads matches some pairs differently from run to run (pycolmap 4.2.1): the
    solve's sequential matching and its loop closure's listed pairs run on one thread, whatever ``num_threads``."""
    threads = []

    def recording(function):
        def call(*args, matching_options, **kwargs):
            threads.append((function.__name__, matching_options.num_threads))
            return function(*args, matching_options=matching_options, **kwargs)
        return call

    for name in ("match_sequential", "match_image_pairs"):
        monkeypatch.setattr(pycolmap, name, recording(getattr(pycolmap, name)))
    solve_sfm({"left": plate}, tmp_path / "out", matcher="sequential", max_num_features=512, refine=False,
              num_threads=2)
    assert MATCHING_THREADS == 1
    assert threads[0] == ("match_sequential", 1) and {n for _, n in threads} == {1}


def test_a_farm_whose_workers_run_elsewhere_gets_paths_relative_to_the_client(plate, tmp_path, monkeypatch):
    """A farm's workers do not share the client's working directory: a solve given relative paths (the plate, OUT)
    extracts and matches on a worker process in another directory, and gives the in-process rig."""
    monkeypatch.setattr(solve_matching, "BLOCK_PAIRS", 4)
    monkeypatch.chdir(plate.parent)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=logging.CRITICAL) as cluster, distributed.Client(cluster) as client:
        for out, where in ((tmp_path / "local", None), (tmp_path / "farm", cluster.scheduler_address)):
            with workers_elsewhere(client, tmp_path / "worker"):
                solve_sfm({"left": Path(plate.name)}, Path(os.path.relpath(out)), matcher="sequential",
                          max_num_features=512, refine=False, scheduler=where)
    ours, theirs = ({key: value for key, value in _numbers(json.loads((out / "solve.rig.json").read_text()))}
                    for out in (tmp_path / "farm", tmp_path / "local"))
    assert ours == theirs and len(ours) > 6 * N_FRAMES
