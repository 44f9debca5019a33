"""Structure from motion on image folders: pycolmap features, matches and mapping, then camcal's refinement.

One folder of images gives one camera moving over frames; several folders,
one per camera of a rig with the same file name per frame, give a rig whose
cameras share one relative pose over all frames (pycolmap's rig support:
``RigConfig`` + ``apply_rig_config`` before mapping, so that the mapper's
bundle adjustment keeps ``sensor_from_rig`` common to every frame).

The result is a :class:`camcal.model.rig.Rig` (:func:`camcal.geometry.sfm.sparse_model`)
written as ``solve.rig.json`` with a sibling PLY of the sparse points.

After mapping, camcal's bundle adjustment (:mod:`camcal.geometry.bundle`)
refines the seed: intrinsics shared per camera, one rig pose for all frames,
optionally held at a known calibration (``known_rig``, e.g. from
``calibrate board``, which also gives the reconstruction its units), a robust
loss, the lens models chosen and the uncertainty of the intrinsics and the
rig pose (:func:`camcal.geometry.selfcal.self_calibrate`); or, with a lens
from a grid calibration, that lens held or refined under its sigmas
(:mod:`camcal.pipelines.solve_lens`). Images the mapper cannot register are
named by frame number (or refused, ``require_all``); the world can be set
after the solve: up, origin, scale and units, or all from a board seen in the images
(:mod:`camcal.pipelines.solve_world`).

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from camcal.base.atomic import atomic_dir, final_path, remove_stale_temporaries
from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import native_output_to
from camcal.geometry.bundle import (
    WARM_START_RADIUS,
    BundleOptions,
    BundleResult,
    BundleState,
    PriorSpec,
    bundle_adjust,
    hold_rig,
    observations_to_reconstruction,
    state_from_reconstruction,
    state_images,
    state_to_reconstruction,
)
from camcal.geometry.jackknife import METHODS as JACKKNIFE_METHODS
from camcal.geometry.bundle.state import model_layout
from camcal.geometry.selfcal import LENS_MODELS, SelfCalibration, as_lens_model, self_calibrate
from camcal.geometry.track_refine import refine_tracks
from camcal.geometry.sfm import (camera_name, check_every_camera_registered, reject_outliers, relative_poses,
                                 sparse_model)
from camcal.io.frames import imread
from camcal.io.ply import write_points_ply
from camcal.io.video import video_info
from camcal.model.rig import Rig
from camcal.pipelines.solve_colmap import (COLMAP_LOG, MAPPERS, MATCHERS, OWNED, check_parallax, extraction_options,
                                           map_images, number_by_name, verification_options, why_nothing_registered)
from camcal.pipelines.solve_features import FEATURE_CACHE, DaskExtraction, extract_features
from camcal.pipelines.solve_inputs import (check_one_size_per_camera, collect_images, list_images, stage_images,
                                           plate_frame_number, stage_masks, unregistered_line, video_of)
from camcal.pipelines.solve_lens import GridLens, drift_lines, grid_lens, hold_in_database, lens_priors
from camcal.pipelines.solve_loops import LOOP_MODES, close_loops
from camcal.pipelines.solve_matching import PairMatcher, dask_stages
from camcal.pipelines.solve_plain import PycolmapPeer, solve_pycolmap_plain
from camcal.pipelines.solve_shutter import DEFAULT_FPS, ShutterSpec, check_rolling_shutter
from camcal.pipelines.solve_world import WorldAlignment, WorldSpec, align_world, board_world, scaled_translations

__all__ = [
    "COLMAP_LOG",
    "PRE_REJECTION_TOLERANCE",
    "PycolmapPeer",
    "SfmResult",
    "TRACK_MODES",
    "collect_images",
    "solve_pycolmap_plain",
    "solve_sfm",
]

#: Ceres' function tolerance of the bundle adjustment that frees the mapper's principal point before the outlier
#: rejection (camcal's default, 1e-10, for the others): that fit only places the residuals the rejection thresholds
#: at 4 sigma of their median, and every fit after it converges fully from its solution. On the rendered 120- and
#: 240-frame walks it stops after 6-8 iterations instead of 14-15, its cost within 4e-6 of the converged one, the
#: observations rejected within 0.05 % of the same; the chosen fit after it takes as many iterations as before.
PRE_REJECTION_TOLERANCE = 1e-6
#: what the bundle adjustment takes as the observations of a track (:func:`solve_sfm`'s ``tracks``).
TRACK_MODES = ("auto", "refine", "detected")


@dataclass(frozen=True)
class SfmResult:
    """What structure from motion recovered.

    Attributes
    ----------
    rig : Rig
        Cameras (cam_from_rig), per-frame rig poses, points file name.
    n_images, n_registered : int
        Images given, images with a pose.
    unregistered : tuple of str
        Images without a pose (``camera/file``, COLMAP's staged names).
    n_points : int
        Sparse 3D points.
    rms_px : float
        RMS reprojection error of every observation through the camcal rig
        (distortion included), in pixels.
    per_camera_rms_px : dict
        The same per camera.
    reconstruction_dir : Path
        The COLMAP model (binary), for other tools.
    bundle : BundleResult or None
        camcal's refinement of the pycolmap seed (costs, RMS before/after,
        sigmas), None when not refined.
    self_calibration : SelfCalibration or None
        The lens models chosen (held-out RMS of each) and the principal point
        decisions, None when not refined or with one fixed COLMAP model.
    notes : tuple of str
        What the solve says beside its figures: the frames not registered
        (by number), the lens taken from the grid and how far it moved, the
        world set.
    """

    rig: Rig
    n_images: int
    n_registered: int
    unregistered: tuple[str, ...]
    n_points: int
    rms_px: float
    per_camera_rms_px: dict[str, float]
    reconstruction_dir: Path
    bundle: BundleResult | None = None
    self_calibration: SelfCalibration | None = None
    notes: tuple[str, ...] = ()


def solve_sfm(
    folders: dict[str, Path | list[Path]],
    out_dir: Path,
    camera_model: str = "SIMPLE_RADIAL",
    matcher: str = "exhaustive",
    mapper: str = "incremental",
    seed: int = 0,
    num_threads: int = -1,
    refine: bool = True,
    known_rig: Rig | None = None,
    loss: str = "trivial",
    lens_models: tuple[str, ...] | None = LENS_MODELS,
    principal_point: str = "auto",
    max_num_features: int = 8192,
    progress: Callable[[str], None] | None = None,
    jackknife: str | None = "step",
    priors: tuple[PriorSpec, ...] = (),
    verbose: bool = False,
    guided_matching: bool = False,
    every: int = 1,
    masks: dict[str, list[Path]] | None = None,
    intrinsics: Rig | None = None,
    intrinsics_mode: str = "fixed",
    intrinsics_source: str = "the grid",
    world: WorldSpec | None = None,
    require_all: bool = False,
    loops: str = "auto",
    tracks: str = "auto",
    rolling_shutter: ShutterSpec | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
) -> SfmResult:
    """Run pycolmap SfM, refine it with camcal's bundle adjustment, convert it to a Rig.

    Parameters
    ----------
    folders : dict of str to Path or list of Path
        Camera name -> its image folder (or its images, see
        :func:`collect_images`, or one video: its every ``every``-th frame,
        streamed into ``out_dir/images``). With several cameras, frames pair up by the
        sorted order of each camera's images; the first camera is the rig's
        reference.
    out_dir : Path
        Receives ``database.db``, ``images/`` (links), ``sparse/`` (the COLMAP
        model), ``solve.rig.json`` and ``points.ply``; built under a temporary
        name and renamed at the end, removed on any error
        (:func:`camcal.base.atomic.atomic_dir`; an earlier run's ``images/``
        and ``sparse/`` in it are replaced as a whole, and the staging folder
        a killed run left beside it is removed first).
    camera_model : str
        COLMAP model for every camera: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL,
        RADIAL, OPENCV, SIMPLE_DIVISION... (one with a camcal counterpart).
    matcher : {"exhaustive", "sequential"}
        Exhaustive for unordered sets under ~50 images; sequential for video.
    mapper : {"incremental", "global"}
    seed : int
        Seeds every random choice: COLMAP's global generator, the RANSAC of
        the geometric verification, the mapper, the held-out points of the
        lens-model choice. The same images and options then give the same
        rig (recorded in its provenance).
    num_threads : int
        Threads of feature extraction and of the track refinement (-1: every
        core); neither's result depends on scheduling. The matching runs on one thread
        (:data:`camcal.pipelines.solve_matching.MATCHING_THREADS`), and so
        does the mapper, so that two runs give the same cameras; matching in
        parallel: ``workers`` or ``scheduler`` (Dask, each block of pairs on
        one thread).
    refine : bool
        Run camcal's bundle adjustment after pycolmap's mapping.
    known_rig : Rig, optional
        A calibrated rig with the same camera names (``calibrate board``):
        the cameras' relative poses are held at it and the reconstruction
        takes its units.
    loss : {"trivial", "huber", "soft_l1", "cauchy"}
        Robust loss of the refinement (scale 1 px).
    lens_models : tuple of str or None
        camcal lens models each camera chooses among by held-out residual
        (:func:`self_calibrate`; each refined with fx and fy apart under the
        square-pixel prior); one model is used as given; None keeps
        ``camera_model`` (one with a single focal length keeps fx = fy).
    principal_point : {"auto", "refine", "centre"}
        Refine the principal point (and the lens) under the sensor's
        Gaussian priors (``auto``), by the images alone, or hold it at the
        image centre (COLMAP's default).
    max_num_features : int
        SIFT features per image (pycolmap's ``max_num_features``).
    progress : callable, optional
        Called with each stage's message (the CLI prints them to stderr).
    jackknife : {"step", "refit"} or None
        Sigmas also by the delete-one-frame jackknife, each replicate by one
        Gauss-Newton step or a full refit; None: the covariance alone
        (:func:`self_calibrate`).
    priors : tuple of PriorSpec
        Gaussian priors on intrinsics (e.g. ``parse_prior("left.f=1200+-30")``);
        the rig's intrinsics are then the posterior's.
    verbose : bool
        Also show COLMAP's own log lines on stderr; they always go to
        ``out_dir/colmap.log`` (:data:`COLMAP_LOG`).
    every : int
        Of a camera given as a video, frames 0, every, 2 every... are used.
    guided_matching : bool
        Match each verified pair again along its epipolar geometry (more,
        longer tracks); on the CPU it costs 10-20 times the matching itself
        (345 s against 21 s for 12 images of 640 x 480 with 8192 features).
    masks : dict of str to list of Path, optional
        Camera name -> one matte file per image (a matte sequence,
        :func:`camcal.io.sequence.sequence_paths`), white where no feature
        may be taken (moving actors, the sky): staged as COLMAP's feature
        masks in ``out_dir/masks`` (:func:`camcal.io.sequence.feature_mask`).
    intrinsics : Rig, optional
        A grid calibration (``calibrate board``) whose lens each camera takes
        (by name; one camera each: the one), at the plate's size
        (:func:`camcal.pipelines.solve_lens.grid_lens`): the lens-model choice
        is skipped. A rig with a lens per frame (a zoom, a refocus) holds each
        image at the lens of the frame of its number, and the solved rig's
        frames carry those lenses (one camera, ``fixed`` only).
    intrinsics_mode : {"fixed", "prior"}
        Hold that lens, or refine it under a Gaussian prior of the grid's sigmas.
    intrinsics_source : str
        The grid's name in messages (its file).
    world : WorldSpec, optional
        Up, origin, scale and units to set after the solve
        (:func:`camcal.pipelines.solve_world.world_spec`).
    loops : {"auto", "off"}
        With the sequential matcher, ``auto`` also matches the keyframes a
        retrieval finds revisiting an earlier part of the shot
        (:mod:`camcal.pipelines.solve_loops`); how many such pairs were
        matched and verified is a note. The exhaustive matcher matches every
        pair already.
    tracks : {"auto", "refine", "detected"}
        ``refine``: before camcal's bundle adjustment, every observation of
        every track is aligned to its track's middle observation by an
        affine patch alignment (:mod:`camcal.geometry.track_refine`), so
        that the observations of a track image one point (a SIFT keypoint's
        position moves with the viewpoint: on a pan the focal length
        absorbs it); an observation the alignment does not settle keeps its
        detected position; a line says how many moved. ``detected``: the
        keypoints as detected. ``auto``: ``refine`` with the sequential
        matcher (the frames of a shot, whose neighbours look alike),
        ``detected`` otherwise.
    require_all : bool
        An image that cannot be registered is an error (nothing is written)
        instead of a line naming it.
    rolling_shutter : ShutterSpec, optional
        A readout time (or one to estimate from the plate): each solved frame's
        rolling-shutter displacement is computed, stored in the rig's frames and
        frames above the threshold named (:mod:`camcal.pipelines.solve_shutter`);
        the frame rate is the spec's, else a movie's own, else 24.
    scheduler : str, optional
        Extract the features on the Dask cluster of this scheduler
        (``tcp://host:8786``), one task per image, whose workers must see
        the images and ``out_dir``'s parent folder, then match them there,
        one task per block of image pairs; each image's features and each
        block's matches are cached in ``out_dir/.camcal-features`` until the
        solve ends, so that a rerun of a killed solve extracts and matches
        only what it had not finished (:mod:`camcal.pipelines.solve_features`,
        :mod:`camcal.pipelines.solve_matching`). The same features, matches
        and verified geometries as in this process, bit for bit; the mapping
        stays here.
    workers : int, optional
        The same on a local Dask cluster of this many worker processes.

    Returns
    -------
    SfmResult
    """
    pycolmap = require("pycolmap")

    if not folders:
        raise CamcalError("need at least one image folder")
    if matcher not in MATCHERS:
        raise CamcalError(f"unknown matcher {matcher!r}, expected one of: {', '.join(MATCHERS)}")
    if loops not in LOOP_MODES:
        raise CamcalError(f"unknown loop closure {loops!r}, expected one of: {', '.join(LOOP_MODES)}")
    if tracks not in TRACK_MODES:
        raise CamcalError(f"unknown track mode {tracks!r}, expected one of: {', '.join(TRACK_MODES)}")
    if mapper not in MAPPERS:
        raise CamcalError(f"unknown mapper {mapper!r}, expected one of: {', '.join(MAPPERS)}")
    if jackknife is not None and jackknife not in JACKKNIFE_METHODS:
        raise CamcalError(f"unknown jackknife method {jackknife!r}, expected one of: {', '.join(JACKKNIFE_METHODS)}")
    if not hasattr(pycolmap.CameraModelId, camera_model):
        raise CamcalError(f"unknown COLMAP camera model {camera_model!r}")
    images = {name: list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    if known_rig is not None:
        missing = [name for name in images if name not in {camera.name for camera in known_rig.cameras}]
        if missing:
            raise CamcalError(f"the known rig has no camera named {', '.join(map(repr, missing))}")
    if int(every) < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    videos = {name: video_of(paths) for name, paths in images.items()}
    n_images = sum(len(paths) if videos[name] is None else -(-max(1, video_info(videos[name]).frame_count) // every)
                   for name, paths in images.items())
    if n_images < 2:
        where = "; ".join(f"{name}: " + (f"folder {value}" if isinstance(value, (str, os.PathLike)) else
                                          ", ".join(map(str, value)) or "no file") for name, value in folders.items())
        raise CamcalError(f"need at least 2 images, got {n_images} ({where})")
    shutter = None
    if rolling_shutter is not None:
        movies = [video for video in videos.values() if video is not None]
        fps = rolling_shutter.fps or (video_info(movies[0]).fps if movies else DEFAULT_FPS)
        shutter = (rolling_shutter, (every if movies else 1) / fps, fps)
    if scheduler is not None and workers is not None:
        raise CamcalError("give a Dask scheduler or a number of local workers, not both")
    if workers is not None and workers < 1:
        raise CamcalError(f"--workers must be at least 1, got {workers}")
    target = Path(out_dir)
    remove_stale_temporaries([target])  # the staging folder of a killed earlier run
    new_target = not target.exists() or [entry.name for entry in target.iterdir()] == [FEATURE_CACHE]
    try:
        with dask_stages(target / FEATURE_CACHE, scheduler, workers) as dask, \
                atomic_dir(target, replace=OWNED + (COLMAP_LOG,)) as staging:
            with native_output_to(staging / COLMAP_LOG, echo=verbose):
                result = _solve_in(pycolmap, images, folders, staging, camera_model, matcher, mapper, seed,
                                   num_threads, refine, known_rig, loss, lens_models, principal_point,
                                   max_num_features, progress, jackknife, guided_matching, priors, every, masks or {},
                                   intrinsics=None if intrinsics is None else (intrinsics, intrinsics_mode,
                                                                               intrinsics_source),
                                   world=world, require_all=require_all, loops=loops, shutter=shutter,
                                   dask=dask, refine_tracks=tracks == "refine" or (tracks == "auto"
                                                                                   and matcher == "sequential"))
    except CamcalError:  # an error of the input: nothing left, the feature cache of an interrupted run included
        shutil.rmtree(target / FEATURE_CACHE, ignore_errors=True)
        if new_target and target.is_dir() and not any(target.iterdir()):
            target.rmdir()
        raise
    shutil.rmtree(target / FEATURE_CACHE, ignore_errors=True)  # the database holds the features now
    return dataclasses.replace(result, reconstruction_dir=final_path(result.reconstruction_dir, staging, target))


def _solve_in(pycolmap, images, folders, out_dir: Path, camera_model, matcher, mapper, seed, num_threads, refine,
              known_rig, loss, lens_models, principal_point, max_num_features, progress, jackknife,
              guided_matching: bool, priors: tuple[PriorSpec, ...], every: int = 1,
              masks: dict[str, list[Path]] | None = None, intrinsics: tuple[Rig, str, str] | None = None,
              world: WorldSpec | None = None, require_all: bool = False, loops: str = "auto",
              shutter: tuple[ShutterSpec, float, float] | None = None,
              dask: DaskExtraction | None = None, refine_tracks: bool = False) -> SfmResult:
    """:func:`solve_sfm`'s work inside its (temporary) output folder, COLMAP's output captured."""
    image_dir = out_dir / "images"
    options = BundleOptions(loss=loss, refine_sensor_from_rig=known_rig is None, priors=tuple(priors))
    free_pp = dict(refine_principal_point=principal_point != "centre", default_priors=principal_point == "auto")
    staged = stage_images(images, image_dir, every)
    sizes = check_one_size_per_camera(staged, image_dir)
    lens = None
    if intrinsics is not None:
        unknown = [name for name in folders if name not in sizes]
        if unknown:
            raise CamcalError(f"cannot read the image size of camera {unknown[0]!r} to fit the grid's lens to it")
        lens = grid_lens(intrinsics[0], {name: sizes[name] for name in folders}, intrinsics[1], intrinsics[2],
                         {name: plate_frame_number(path) for name, path in staged.items()})
        for line in lens.lines:
            _say(progress, line)
    image_names = list(staged)
    database = out_dir / "database.db"

    mask_dir = stage_masks(masks, staged, image_dir, out_dir / "masks") if masks else None
    firsts: dict[str, Path] = {}
    for name in image_names:
        firsts.setdefault(name.split("/")[0], image_dir / name)
    extraction = extraction_options(pycolmap, list(firsts.values()), max_num_features, num_threads)
    feature_keys = extract_features(pycolmap, database, image_dir, image_names,
                                    pycolmap.CameraMode.PER_IMAGE if lens is not None and lens.lenses
                                    else pycolmap.CameraMode.PER_FOLDER,
                                    camera_model, mask_dir, extraction, seed, dask, labels=staged, progress=progress)
    number_by_name(pycolmap, database)
    if lens is not None:
        hold_in_database(pycolmap, database, lens)
    _say(progress, f"matching ({matcher})")
    matching = pycolmap.FeatureMatchingOptions()
    matching.guided_matching = guided_matching
    pair_matcher = PairMatcher(pycolmap, database, matching, verification_options(pycolmap, seed), dask,
                               feature_keys, labels=staged, progress=progress)
    pair_matcher.match(matcher)
    stage_notes = []
    if matcher == "sequential" and loops == "auto":
        _say(progress, "loop closure: retrieving revisits")
        closure = close_loops(pycolmap, database, pycolmap.SequentialPairingOptions().overlap,
                              pair_matcher.match_pairs, seed)
        _say(progress, closure.line())
        stage_notes.append(closure.line())
    check_parallax(pycolmap, database, len(staged))
    sparse = out_dir / "sparse"
    sparse.mkdir()
    _say(progress, f"mapping ({mapper})")
    models, mapping_note = map_images(pycolmap, database, image_dir, sparse, mapper, seed, lens is not None,
                                      sequential=matcher == "sequential", refined=refine)
    if len(folders) > 1 and models:
        # COLMAP needs sensor_from_rig to start a rig-constrained mapping: take it
        # from an unconstrained first pass, then map again with the rig.
        rig_config = pycolmap.RigConfig(
            cameras=[
                pycolmap.RigConfigCamera(ref_sensor=index == 0, image_prefix=f"{name}/")
                for index, name in enumerate(folders)
            ]
        )
        first_pass = max(models.values(), key=lambda r: r.num_reg_images())
        per_camera = Counter(staged_name.split("/")[0] for staged_name in staged)
        check_every_camera_registered(first_pass, {name: per_camera[name] for name in folders})
        db = pycolmap.Database.open(database)
        try:
            pycolmap.apply_rig_config([rig_config], db, first_pass)
        finally:
            db.close()
        shutil.rmtree(sparse)
        sparse.mkdir()
        _say(progress, f"mapping ({mapper}) with the rig constraint")
        models, mapping_note = map_images(pycolmap, database, image_dir, sparse, mapper, seed, lens is not None,
                                          sequential=matcher == "sequential", refined=refine)
    if mapping_note:
        _say(progress, mapping_note)
        stage_notes.append(mapping_note)
    if not models:
        raise CamcalError(why_nothing_registered(pycolmap, database, len(staged)))
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    registered = {image.name for image in reconstruction.images.values() if image.has_pose}
    missing = unregistered_line([name for name in staged if name not in registered], staged)
    if missing and require_all:
        raise CamcalError(f"{missing} (--require-all)")
    notes = ([missing] if missing else []) + stage_notes
    bundle = calibration = None
    if refine:
        _say(progress, "bundle adjustment (camcal)")
        names = {camera_id: camera_name(reconstruction, camera_id) for camera_id in reconstruction.cameras}
        if lens is not None and lens.lenses:  # a camera per image, each its own rig, held at its frame's lens
            names = {image.camera_id: image.name for image in reconstruction.images.values()}
            options = dataclasses.replace(options, refine_sensor_from_rig=False)
        state = state_from_reconstruction(reconstruction, names)
        if known_rig is not None:
            state = hold_rig(state, relative_poses(known_rig, state.camera_names[0]))
        if refine_tracks:
            state = _refined_tracks(reconstruction, state, image_dir, num_threads, progress)
        if lens is not None:
            bundle = _refine_with_lens(reconstruction, names, state, options, lens, progress)
        elif lens_models is None:
            pp_options = dataclasses.replace(options, **free_pp)
            bundle = bundle_adjust(state, pp_options)
        else:
            # the mapper's principal point is the image centre: free it once, then drop the matches
            # that no camera model explains (mismatches, features astride an occluding edge)
            _say(progress, "bundle adjustment (camcal) with the principal point free, then outlier rejection")
            pre = bundle_adjust(state, dataclasses.replace(options, **free_pp, compute_sigmas=False,
                                                           reweigh_priors=False, tolerance=PRE_REJECTION_TOLERANCE))
            state_to_reconstruction(pre.state, reconstruction)
            _say(progress, reject_outliers(reconstruction))
            state = state_from_reconstruction(reconstruction, names)
            # each of its refinements starts from the one above (the lens converted), near its solution
            warm = dataclasses.replace(options, trust_region_radius=WARM_START_RADIUS)
            bundle, calibration = self_calibrate(state, warm, tuple(lens_models), principal_point, seed, progress,
                                                 jackknife)
            for line in calibration.lines():
                _say(progress, line)
        camera_ids = {name: camera_id for camera_id, name in names.items()}
        for name, model in zip(bundle.state.camera_names, bundle.state.models):
            reconstruction.cameras[camera_ids[name]].model = getattr(pycolmap.CameraModelId, model)
        state_to_reconstruction(bundle.state, reconstruction)
    units = known_rig.units if known_rig is not None else "arbitrary"
    world_scale, world_record = 1.0, None
    if world is not None and world.active:
        _say(progress, "setting the world")
        alignment = _set_world(pycolmap, reconstruction, list(folders), world, seed, image_dir)
        world_scale, world_record = alignment.similarity.s, alignment.record()
        for line in alignment.lines:
            _say(progress, line)
            notes.append(line)
        units = world.units or units
    model_dir = sparse / "best"
    model_dir.mkdir(exist_ok=True)
    reconstruction.write(model_dir)
    originals = {name: Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()
                 for name, path in staged.items()}
    result = _to_result(reconstruction, list(folders), out_dir, model_dir, originals, units, bundle, calibration,
                        seed, lens, world_scale, shutter, world_record)
    for line in result.notes:
        _say(progress, line)
    if lens is not None and lens.mode == "prior":
        notes += drift_lines(lens, {camera.name: camera for camera in result.rig.cameras})
    return dataclasses.replace(result, notes=tuple(([*lens.lines] if lens is not None else []) + notes
                                                   + list(result.notes)))


def _refine_with_lens(reconstruction, names: dict[int, str], state, options: BundleOptions, lens: GridLens,
                      progress: Callable[[str], None] | None) -> BundleResult:
    """camcal's bundle adjustment with the grid's lens: held, outliers dropped, then held again or refined under
    the grid's sigmas (every other intrinsic held, no default prior: the grid measured the lens)."""
    held = dataclasses.replace(options, constant_intrinsics=tuple(state.camera_names))
    _say(progress, "bundle adjustment (camcal) with the grid's lens held, then outlier rejection")
    pre = bundle_adjust(state, dataclasses.replace(held, compute_sigmas=False))  # only its solution is used
    state_to_reconstruction(pre.state, reconstruction)
    _say(progress, reject_outliers(reconstruction))
    state = state_from_reconstruction(reconstruction, names)
    if lens.mode == "fixed":
        return bundle_adjust(state, held)
    _say(progress, "bundle adjustment (camcal) with the grid's lens under its sigmas")
    fixed = {}
    for index, name in enumerate(state.camera_names):
        colmap_names = model_layout(state.models[index])[0]
        known = set(lens.sigmas.get(name, {}))
        fixed[name] = tuple(param for param in colmap_names if _camcal_names(param, state.models[index]) - known)
    return bundle_adjust(state, dataclasses.replace(options, refine_principal_point=True, default_priors=False,
                                                    priors=options.priors + lens_priors(lens), fixed_params=fixed))


def _refined_tracks(reconstruction, state: BundleState, image_dir: Path, num_threads: int,
                    progress: Callable[[str], None] | None) -> BundleState:
    """The state's observations aligned along their tracks (:func:`refine_tracks`), written into
    ``reconstruction``'s keypoints too (its outlier rejection and the model written then see them)."""
    names = state_images(reconstruction)
    _say(progress, f"refining the tracks: {len(state.obs_xy)} observations of {len(state.points)} points")
    refinement = refine_tracks(state, lambda camera, frame: imread(image_dir / names[camera, frame],
                                                                   cv2.IMREAD_GRAYSCALE),
                               threads=(os.cpu_count() or 1) if num_threads < 1 else num_threads)
    observations_to_reconstruction(refinement.state, reconstruction)
    _say(progress, refinement.line())
    return refinement.state


def _camcal_names(colmap_name: str, model: str) -> set[str]:
    """The camcal intrinsics a COLMAP parameter carries (``f`` is ``fx`` and ``fy``; a division ``k`` is ``lambda``)."""
    if colmap_name == "f":
        return {"fx", "fy"}
    if colmap_name == "k":
        return {"lambda"} if model in ("SIMPLE_DIVISION", "DIVISION") else {"k1"}
    return {colmap_name}


def _set_world(pycolmap, reconstruction, camera_names: list[str], world: WorldSpec, seed: int,
               image_dir: Path) -> WorldAlignment:
    """Move the reconstruction into the world ``world`` asks for (points, frames and the rig's baselines); how."""
    if world.board is not None:
        alignment = board_world(reconstruction, image_dir, world.board, world.units, seed)
    else:
        xyz = np.array([point.xyz for point in reconstruction.points3D.values()]).reshape(-1, 3)
        poses = sorted((camera_names.index(image.name.split("/")[0]), image.name, image.cam_from_world())
                       for image in reconstruction.images.values() if image.has_pose)
        rotations = np.array([pose.rotation.matrix() for _, _, pose in poses])
        centres = np.array([-pose.rotation.matrix().T @ pose.translation for _, _, pose in poses])
        alignment = align_world(xyz, rotations, centres, world, seed)
    similarity = alignment.similarity
    reconstruction.transform(pycolmap.Sim3d(similarity.s, pycolmap.Rotation3d(similarity.R), similarity.t))
    return alignment



def _to_result(reconstruction, camera_names: list[str], out_dir: Path, model_dir: Path,
               originals: dict[str, str], units: str, bundle: BundleResult | None,
               calibration: SelfCalibration | None, seed: int, lens: GridLens | None = None,
               world_scale: float = 1.0, shutter: tuple[ShutterSpec, float, float] | None = None,
               world_record: dict | None = None) -> SfmResult:
    """Convert a pycolmap reconstruction with one rig into camcal's Rig; write its points and the rig.

    ``originals`` maps every staged image name (COLMAP's) to the user's
    image, relative to ``out_dir``: the frames point at those. The rig's
    provenance records the seed. A lens held from the grid is written as the
    grid has it (its model and terms); refined under its prior, under the
    grid's model name. ``world_scale``: the world was scaled after the bundle
    adjustment, and the covariance of translations is scaled with it. ``shutter``: the readout to check each
    frame with, the seconds between frame numbers and the frame rate (the lines it says become the notes).
    ``world_record``: how the world was set (:meth:`WorldAlignment.record`), the provenance's ``world``.
    """
    points_path = out_dir / "points.ply"
    model = sparse_model(reconstruction, camera_names, originals, units, bundle, calibration, points_path.name,
                         None if lens is None else lens.lenses)
    rig = dataclasses.replace(scaled_translations(model.rig, world_scale),
                              provenance={**model.rig.provenance, "seed": seed,
                                          **({} if world_record is None else {"world": world_record})})
    if lens is not None:
        rig = dataclasses.replace(rig, cameras=tuple(_as_grid_lens(camera, lens) for camera in rig.cameras),
                                  provenance={**rig.provenance, "intrinsics": list(lens.lines)})
    shutter_lines = []
    if shutter is not None:
        rig, shutter_lines = check_rolling_shutter(reconstruction, rig, {path: name for name, path in originals.items()},
                                                   *shutter, seed=seed)
    write_points_ply(points_path, model.xyz, model.colours, model.track_lengths)
    rig.save(out_dir / "solve.rig.json")
    return SfmResult(
        rig=rig,
        n_images=len(originals),
        n_registered=len(model.registered),
        unregistered=tuple(sorted(set(originals) - set(model.registered))),
        n_points=len(model.xyz),
        rms_px=model.rms_px,
        per_camera_rms_px=model.per_camera_rms_px,
        reconstruction_dir=model_dir,
        bundle=bundle,
        self_calibration=calibration,
        notes=tuple(shutter_lines),
    )


def _as_grid_lens(camera, lens: GridLens):
    """A solved camera with the grid's lens: held, exactly the grid's; refined, under the grid's model name."""
    grid = lens.cameras[camera.name]
    if lens.mode == "fixed":
        return dataclasses.replace(camera, K=grid.K, distortion=grid.distortion)
    return as_lens_model(camera, grid.distortion.model)


def _say(progress: Callable[[str], None] | None, message: str) -> None:
    """Hand a stage message to the caller's progress callback, if any."""
    if progress is not None:
        progress(message)
