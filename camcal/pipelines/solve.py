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
rig pose (:func:`camcal.geometry.selfcal.self_calibrate`).

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

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_dir, final_path, remove_stale_temporaries
from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import native_output_to
from camcal.geometry.bundle import (
    BundleOptions,
    BundleResult,
    PriorSpec,
    bundle_adjust,
    hold_rig,
    state_from_reconstruction,
    state_to_reconstruction,
)
from camcal.geometry.jackknife import METHODS as JACKKNIFE_METHODS
from camcal.geometry.selfcal import LENS_MODELS, SelfCalibration, self_calibrate
from camcal.geometry.sfm import (camera_name, check_every_camera_registered, reject_outliers, relative_poses,
                                 sparse_model)
from camcal.model.colmap import camera_from_colmap
from camcal.io.frames import imwrite
from camcal.io.ply import write_points_ply
from camcal.io.headers import declared_size
from camcal.io.sequence import (
    camera_of, feature_image, feature_mask, is_sequence_pattern, read_image, sequence_paths,
)
from camcal.io.video import is_video, iter_frames, video_info
from camcal.model.rig import Camera, Rig

__all__ = [
    "COLMAP_LOG",
    "UPSAMPLE_BELOW_PX",
    "DECODED_SUFFIXES",
    "IMAGE_SUFFIXES",
    "MAPPERS",
    "MATCHERS",
    "PycolmapPeer",
    "SfmResult",
    "collect_images",
    "solve_pycolmap_plain",
    "solve_sfm",
]

#: Suffixes COLMAP reads itself (linked into the work folder) and those of plates it does not (EXR, DPX,
#: Cineon: read with OpenImageIO and staged as 8-bit PNG, :func:`camcal.io.sequence.feature_image`).
DECODED_SUFFIXES = (".exr", ".dpx", ".cin")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp") + DECODED_SUFFIXES
MATCHERS = ("exhaustive", "sequential")
MAPPERS = ("incremental", "global")
#: the file in the output folder that receives COLMAP's, glog's and Ceres' own lines.
COLMAP_LOG = "colmap.log"
#: What a solve writes in its folder as a whole: an earlier run's are replaced, not merged into.
_OWNED = ("images", "masks", "sparse", "database.db")


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
        Images without a pose (``camera/file``).
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


def _list_images(folder: Path, pattern: str = "*") -> list[Path]:
    if not folder.is_dir():
        raise CamcalError(f"image folder not found: {folder}")
    images = sorted(p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise CamcalError(f"no images ({', '.join(IMAGE_SUFFIXES)}) matching {pattern!r} in {folder}")
    return images


def collect_images(folders: list[Path], camera_globs: dict[str, str] | None = None,
                   frames: str | None = None) -> dict[str, list[Path]]:
    """Images per camera: one folder per camera (named after it), or globs in one folder, or plates.

    Parameters
    ----------
    folders : list of Path
        Image folders. Without ``camera_globs`` each is one camera; a single
        folder holding only sub-folders of images is a rig, one camera per
        sub-folder. An entry (or a glob) with a frame placeholder
        (``plates/left.%04d.exr``, ``left.####.dpx``) is a plate: the
        frames of ``frames`` (or all on disk), every one checked to exist
        (:func:`camcal.io.sequence.sequence_paths`); its camera is named by
        the file name before the placeholder.
    camera_globs : dict of str to str, optional
        Camera name -> glob relative to the (single) folder, e.g.
        ``{"left": "*_L.png", "right": "*_R.png"}``; frames pair up by sorted order.
    frames : str, optional
        The frame range of plates (``1001-1100``, ``1001-1100x2``).
    """
    folders = [Path(folder) for folder in folders]
    if camera_globs:
        if len(folders) != 1:
            raise CamcalError("--camera NAME=GLOB selects images inside one folder: give exactly one")
        return {name: sequence_paths(folders[0] / pattern, frames) if is_sequence_pattern(pattern)
                else _list_images(folders[0], pattern) for name, pattern in camera_globs.items()}
    if any(is_sequence_pattern(folder) for folder in folders):
        if not all(is_sequence_pattern(folder) for folder in folders):
            raise CamcalError("give plates (a frame placeholder like %04d or ####) or image folders, not both")
        plates = {camera_of(folder): sequence_paths(folder, frames) for folder in folders}
        if len(plates) != len(folders):
            raise CamcalError("plates must have distinct names before their frame numbers (they name the cameras)")
        return plates
    if len(folders) == 1 and folders[0].is_dir():
        subfolders = sorted(p for p in folders[0].iterdir() if p.is_dir())
        if subfolders and not any(p.suffix.lower() in IMAGE_SUFFIXES for p in folders[0].iterdir() if p.is_file()):
            folders = subfolders
    names = [folder.name for folder in folders]
    if len(set(names)) != len(names):
        raise CamcalError("image folders must have distinct names (they name the cameras)")
    return {folder.name: _list_images(folder) for folder in folders}


def _video_of(paths: list[Path]) -> Path | None:
    """The video a camera's images are (one video file), else None; a video among images is refused."""
    videos = [path for path in paths if is_video(path)]
    if videos and len(paths) > 1:
        raise CamcalError(f"give a camera one video or images, not both ({videos[0].name} among {len(paths)} files)")
    return videos[0] if videos else None


def _stage_images(images: dict[str, list[Path]], staging: Path, every: int = 1) -> dict[str, Path]:
    """Link each camera's images under ``staging/<camera>/`` (COLMAP's rig layout).

    Frames pair up by position in each camera's sorted list: the k-th image
    of every camera is linked under the same name ``<k>.<suffix>``. A
    camera given as one video has its every ``every``-th frame decoded
    (streamed, :func:`camcal.io.video.iter_frames`) and written there as
    ``<k>.png`` instead: the k-th kept frame of every video pairs up. A
    plate frame COLMAP cannot read (:data:`DECODED_SUFFIXES`) is decoded
    and staged as ``<k>.png`` the same way, one at a time.

    Returns
    -------
    dict
        Staged name (``camera/<k>.<suffix>``, COLMAP's image name) -> the user's image (a video's frame: the
        staged file).
    """
    if staging.exists():
        shutil.rmtree(staging)
    staged: dict[str, Path] = {}
    for camera, paths in images.items():
        (staging / camera).mkdir(parents=True)
        video = _video_of(paths)
        if video is not None:
            for index, (_, image) in enumerate(iter_frames(video, every=every, gray=False)):
                name = f"{index:06d}.png"
                staged[f"{camera}/{name}"] = imwrite(staging / camera / name, image)
            continue
        for index, path in enumerate(paths):
            if path.suffix.lower() in DECODED_SUFFIXES:  # one frame decoded at a time
                name = f"{index:06d}.png"
                imwrite(staging / camera / name, feature_image(read_image(path), bgr=True))
            else:
                name = f"{index:06d}{path.suffix.lower()}"
                os.symlink(path.resolve(), staging / camera / name)
            staged[f"{camera}/{name}"] = path
    return staged


def _check_one_size_per_camera(staged: dict[str, Path], image_dir: Path) -> None:
    """Refuse a camera whose staged images differ in size (a plate with a frame of another size), naming both files.

    COLMAP gives each camera one size (its folder, ``CameraMode.PER_FOLDER``)
    and skips an image of another size, which would leave the camera short
    of frames or unregistered with no word why. Sizes are read from the
    staged files' headers (:func:`camcal.io.headers.declared_size`).
    """
    first: dict[str, tuple[str, tuple[int, int]]] = {}
    for name in staged:
        size = declared_size(image_dir / name)
        if size is None:
            continue
        camera = name.split("/")[0]
        first_name, first_size = first.setdefault(camera, (name, size))
        if size != first_size:
            raise CamcalError(f"camera {camera!r}: {staged[name]} is {size[0]}x{size[1]} but "
                              f"{staged[first_name]} is {first_size[0]}x{first_size[1]}: a camera's images must all "
                              "have one size")


def _stage_masks(masks: dict[str, list[Path]], staged: dict[str, Path], image_dir: Path, mask_dir: Path) -> Path:
    """Each matte as COLMAP's mask of its image, ``mask_dir/<camera>/<k>.<suffix>.png``; one matte read at a time."""
    for camera, mattes in masks.items():
        names = [name for name in staged if name.split("/")[0] == camera]
        if not names:
            raise CamcalError(f"masks given for {camera!r}, which is not a camera of this solve")
        if len(mattes) != len(names):
            raise CamcalError(f"camera {camera!r} has {len(names)} images but {len(mattes)} mattes")
        (mask_dir / camera).mkdir(parents=True)
        for name, matte in zip(names, mattes):
            mask = feature_mask(read_image(matte))
            size = declared_size(image_dir / name)
            if size is not None and size != (mask.shape[1], mask.shape[0]):
                raise CamcalError(f"matte {matte} is {mask.shape[1]}x{mask.shape[0]} px but its image "
                                  f"{staged[name]} is {size[0]}x{size[1]}")
            imwrite(mask_dir / f"{name}.png", mask)
    return mask_dir


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
        Threads of feature extraction and matching (-1: every core); their
        results do not depend on scheduling. The mapper runs on one thread,
        so that its bundle adjustments sum in a fixed order.
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

    Returns
    -------
    SfmResult
    """
    pycolmap = require("pycolmap")

    if not folders:
        raise CamcalError("need at least one image folder")
    if matcher not in MATCHERS:
        raise CamcalError(f"unknown matcher {matcher!r}, expected one of: {', '.join(MATCHERS)}")
    if mapper not in MAPPERS:
        raise CamcalError(f"unknown mapper {mapper!r}, expected one of: {', '.join(MAPPERS)}")
    if jackknife is not None and jackknife not in JACKKNIFE_METHODS:
        raise CamcalError(f"unknown jackknife method {jackknife!r}, expected one of: {', '.join(JACKKNIFE_METHODS)}")
    if not hasattr(pycolmap.CameraModelId, camera_model):
        raise CamcalError(f"unknown COLMAP camera model {camera_model!r}")
    images = {name: _list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    if known_rig is not None:
        missing = [name for name in images if name not in {camera.name for camera in known_rig.cameras}]
        if missing:
            raise CamcalError(f"the known rig has no camera named {', '.join(map(repr, missing))}")
    if int(every) < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    videos = {name: _video_of(paths) for name, paths in images.items()}
    n_images = sum(len(paths) if videos[name] is None else -(-max(1, video_info(videos[name]).frame_count) // every)
                   for name, paths in images.items())
    if n_images < 2:
        where = "; ".join(f"{name}: " + (f"folder {value}" if isinstance(value, (str, os.PathLike)) else
                                          ", ".join(map(str, value)) or "no file") for name, value in folders.items())
        raise CamcalError(f"need at least 2 images, got {n_images} ({where})")
    target = Path(out_dir)
    remove_stale_temporaries([target])  # the staging folder of a killed earlier run
    with atomic_dir(target, replace=_OWNED + (COLMAP_LOG,)) as staging:
        with native_output_to(staging / COLMAP_LOG, echo=verbose):
            result = _solve_in(pycolmap, images, folders, staging, camera_model, matcher, mapper, seed, num_threads,
                               refine, known_rig, loss, lens_models, principal_point, max_num_features, progress,
                               jackknife, guided_matching, priors, every, masks or {})
    return dataclasses.replace(result, reconstruction_dir=final_path(result.reconstruction_dir, staging, target))


def _solve_in(pycolmap, images, folders, out_dir: Path, camera_model, matcher, mapper, seed, num_threads, refine,
              known_rig, loss, lens_models, principal_point, max_num_features, progress, jackknife,
              guided_matching: bool, priors: tuple[PriorSpec, ...], every: int = 1,
              masks: dict[str, list[Path]] | None = None) -> SfmResult:
    """:func:`solve_sfm`'s work inside its (temporary) output folder, COLMAP's output captured."""
    image_dir = out_dir / "images"
    options = BundleOptions(loss=loss, refine_sensor_from_rig=known_rig is None, priors=tuple(priors))
    free_pp = dict(refine_principal_point=principal_point != "centre", default_priors=principal_point == "auto")
    staged = _stage_images(images, image_dir, every)
    _check_one_size_per_camera(staged, image_dir)
    image_names = list(staged)
    database = out_dir / "database.db"

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    if masks:
        reader.mask_path = _stage_masks(masks, staged, image_dir, out_dir / "masks")
    firsts: dict[str, Path] = {}
    for name in image_names:
        firsts.setdefault(name.split("/")[0], image_dir / name)
    extraction = _extraction_options(pycolmap, list(firsts.values()), max_num_features, num_threads)
    _say(progress, f"extracting features from {len(image_names)} images")
    pycolmap.set_random_seed(seed)
    pycolmap.extract_features(
        database, image_dir, image_names=image_names, camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    _number_by_name(pycolmap, database)
    _say(progress, f"matching ({matcher})")
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.guided_matching = guided_matching
    match = pycolmap.match_exhaustive if matcher == "exhaustive" else pycolmap.match_sequential
    match(database, matching_options=matching, verification_options=_verification(pycolmap, seed),
          device=pycolmap.Device.cpu)
    sparse = out_dir / "sparse"
    sparse.mkdir()
    _say(progress, f"mapping ({mapper})")
    models = _map(pycolmap, database, image_dir, sparse, mapper, seed)
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
        models = _map(pycolmap, database, image_dir, sparse, mapper, seed)
    if not models:
        raise CamcalError("structure from motion registered no images: too little texture or overlap?")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    bundle = calibration = None
    if refine:
        _say(progress, "bundle adjustment (camcal)")
        names = {camera_id: camera_name(reconstruction, camera_id) for camera_id in reconstruction.cameras}
        state = state_from_reconstruction(reconstruction, names)
        if known_rig is not None:
            state = hold_rig(state, relative_poses(known_rig, state.camera_names[0]))
        if lens_models is None:
            pp_options = dataclasses.replace(options, **free_pp)
            bundle = bundle_adjust(state, pp_options)
        else:
            # the mapper's principal point is the image centre: free it once, then drop the matches
            # that no camera model explains (mismatches, features astride an occluding edge)
            _say(progress, "bundle adjustment (camcal) with the principal point free, then outlier rejection")
            pre = bundle_adjust(state, dataclasses.replace(options, **free_pp))
            state_to_reconstruction(pre.state, reconstruction)
            _say(progress, reject_outliers(reconstruction))
            state = state_from_reconstruction(reconstruction, names)
            bundle, calibration = self_calibrate(state, options, tuple(lens_models), principal_point, seed, progress,
                                                 jackknife)
            for line in calibration.lines():
                _say(progress, line)
        camera_ids = {name: camera_id for camera_id, name in names.items()}
        for name, model in zip(bundle.state.camera_names, bundle.state.models):
            reconstruction.cameras[camera_ids[name]].model = getattr(pycolmap.CameraModelId, model)
        state_to_reconstruction(bundle.state, reconstruction)
    model_dir = sparse / "best"
    model_dir.mkdir(exist_ok=True)
    reconstruction.write(model_dir)
    originals = {name: Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()
                 for name, path in staged.items()}
    units = known_rig.units if known_rig is not None else "arbitrary"
    return _to_result(reconstruction, list(folders), out_dir, model_dir, originals, units, bundle, calibration, seed)


@dataclass(frozen=True)
class PycolmapPeer:
    """Plain pycolmap's self-calibration of the same images, for comparison.

    Attributes
    ----------
    cameras : dict of str to Camera
        Camera name -> its intrinsics and lens (pose: identity).
    rms_px : dict of str to float
        Camera name -> RMS reprojection error (pycolmap's own residuals).
    right_from_left : dict of str to list of ndarray
        Camera name -> ``cam_from_reference`` rotation of every frame in which
        both it and the reference camera (the first) are registered: plain
        pycolmap has no rig constraint, so each frame has its own.
    n_registered : int
    cam_from_world : dict of str to ndarray
        The user's image path -> the rotation world -> camera of every
        registered image (for rotation errors against a ground truth).
    """

    cameras: dict[str, Camera]
    rms_px: dict[str, float]
    right_from_left: dict[str, list[NDArray[np.float64]]]
    n_registered: int
    cam_from_world: dict[str, NDArray[np.float64]] = dataclasses.field(default_factory=dict)


def solve_pycolmap_plain(folders: dict[str, Path | list[Path]], out_dir: Path, camera_model: str = "SIMPLE_DIVISION",
                         seed: int = 0, verbose: bool = False, every: int = 1) -> PycolmapPeer:
    """The plain pycolmap pipeline a user would script, on the same images as :func:`solve_sfm`.

    Default SIFT extraction with one camera per folder (``camera_model``),
    exhaustive matching, incremental mapping (pycolmap's defaults, every
    core), then ``pycolmap.bundle_adjustment`` with
    ``refine_principal_point``. No rig constraint. Writes only under
    ``out_dir``; COLMAP's lines go to ``out_dir/colmap.log`` (and stderr
    with ``verbose``).
    """
    pycolmap = require("pycolmap")

    images = {name: _list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    remove_stale_temporaries([out_dir])
    with atomic_dir(out_dir, replace=_OWNED + (COLMAP_LOG,)) as staging:
        with native_output_to(staging / COLMAP_LOG, echo=verbose):
            return _plain_in(pycolmap, images, folders, staging, camera_model, seed, every)


def _plain_in(pycolmap, images, folders, out_dir: Path, camera_model: str, seed: int, every: int = 1) -> PycolmapPeer:
    """:func:`solve_pycolmap_plain`'s work inside its (temporary) output folder."""
    staged = _stage_images(images, out_dir / "images", every)
    database = out_dir / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    pycolmap.extract_features(database, out_dir / "images", image_names=list(staged),
                              camera_mode=pycolmap.CameraMode.PER_FOLDER, reader_options=reader,
                              device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    sparse = out_dir / "sparse"
    sparse.mkdir()
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = seed
    models = pycolmap.incremental_mapping(database, out_dir / "images", sparse, options=options)
    if not models:
        raise CamcalError("plain pycolmap registered no images")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_principal_point = True
    pycolmap.bundle_adjustment(reconstruction, options)
    cameras, squared, rotations = {}, {}, {}
    for camera_id, camera in reconstruction.cameras.items():
        name = camera_name(reconstruction, camera_id)
        cameras[name] = camera_from_colmap(name, camera.model.name, (camera.width, camera.height), camera.params,
                                           np.eye(3), np.zeros(3))
    reference = next(iter(folders))
    by_frame: dict[str, dict[str, NDArray[np.float64]]] = {}
    cam_from_world: dict[str, NDArray[np.float64]] = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        name, file = image.name.split("/", 1)
        by_frame.setdefault(file, {})[name] = image.cam_from_world().rotation.matrix()
        cam_from_world[str(staged[image.name])] = by_frame[file][name]
        for point in image.points2D:
            if point.has_point3D():
                projected = image.project_point(reconstruction.points3D[point.point3D_id].xyz)
                if projected is not None:
                    squared.setdefault(name, []).append(float(np.sum((point.xy - projected) ** 2)))
    for poses in by_frame.values():
        for name, R in poses.items():
            if name != reference and reference in poses:
                rotations.setdefault(name, []).append(R @ poses[reference].T)
    return PycolmapPeer(cameras, {name: float(np.sqrt(np.mean(v))) for name, v in squared.items()}, rotations,
                        reconstruction.num_reg_images(), cam_from_world)


#: images of at least this many pixels are not upsampled before SIFT (:func:`_extraction_options`).
UPSAMPLE_BELOW_PX = 4_000_000


def _extraction_options(pycolmap, paths: list[Path], max_num_features: int, num_threads: int):
    """SIFT options sized to the images (``paths``: one of each camera's): no upsampled octave from 4 Mpx up.

    COLMAP's SIFT starts at octave -1 (the image upsampled twice) and, past
    ``max_num_features``, keeps the larger-scale features: on a 6 Mpx
    photograph the octaves from 0 up already give more than 8192 features,
    so the upsampled octave (4 times the pixels of the image, most of the
    extraction time) is computed only to be dropped.
    """
    import cv2  # noqa: PLC0415

    options = pycolmap.FeatureExtractionOptions()
    options.num_threads = num_threads
    options.sift.max_num_features = max_num_features
    sizes = [image.shape[0] * image.shape[1] for image in (cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                                                             for path in paths) if image is not None]
    if sizes and max(sizes) >= UPSAMPLE_BELOW_PX:
        options.sift.first_octave = 0
    return options


def _number_by_name(pycolmap, database: Path) -> None:
    """Renumber the images (and their frames) of a freshly extracted ``database`` in the order of their names.

    COLMAP's extraction threads write each image as they finish it, so the
    ids -- the order the matcher and the mapper take images and pairs in --
    changed from run to run, and with them the reconstruction (in its 7th
    digit on a rendered stereo sequence). Cameras and rigs keep their ids
    (the reader, on one thread, creates them in name order); pose priors
    (EXIF GPS) follow their image.
    """
    ordered = database.with_name(database.stem + ".ordered.db")
    old, new = pycolmap.Database.open(database), pycolmap.Database.open(ordered)
    try:
        for camera in old.read_all_cameras():
            new.write_camera(camera, use_camera_id=True)
        for rig in old.read_all_rigs():
            new.write_rig(rig, use_rig_id=True)
        frame_of = {}
        for frame in old.read_all_frames():
            (data_id,) = frame.data_ids  # extraction makes one frame per image; the rig config comes later
            frame_of[data_id.id] = (frame.rig_id, data_id.sensor_id)
        priors = {prior.corr_data_id.id: prior for prior in old.read_all_pose_priors()}
        for image in sorted(old.read_all_images(), key=lambda image: image.name):
            image_id = new.write_image(pycolmap.Image(name=image.name, camera_id=image.camera_id))
            if image.image_id in priors:
                prior = priors[image.image_id]
                prior.corr_data_id = pycolmap.data_t(prior.corr_data_id.sensor_id, image_id)
                new.write_pose_prior(prior)
            new.write_keypoints(image_id, old.read_keypoints(image.image_id))
            new.write_descriptors(image_id, old.read_descriptors(image.image_id))
            rig_id, sensor_id = frame_of[image.image_id]
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(pycolmap.data_t(sensor_id, image_id))
            new.write_frame(frame)
    finally:
        old.close()
        new.close()
    ordered.replace(database)


def _verification(pycolmap, seed: int):
    """Geometric verification options with a seeded RANSAC (COLMAP's default seed -1 draws from the clock)."""
    options = pycolmap.TwoViewGeometryOptions()
    options.ransac.random_seed = seed
    return options


def _map(pycolmap, database: Path, image_dir: Path, sparse: Path, mapper: str, seed: int) -> dict:
    """COLMAP's mapping, seeded and on one thread (multi-threaded Ceres sums in the order threads finish)."""
    pycolmap.set_random_seed(seed)
    if mapper == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = seed
        options.num_threads = 1
        return pycolmap.incremental_mapping(database, image_dir, sparse, options=options)
    options = pycolmap.GlobalPipelineOptions()
    options.random_seed = seed
    options.num_threads = 1
    return pycolmap.global_mapping(database, image_dir, sparse, options=options)


def _to_result(reconstruction, camera_names: list[str], out_dir: Path, model_dir: Path,
               originals: dict[str, str], units: str, bundle: BundleResult | None,
               calibration: SelfCalibration | None, seed: int) -> SfmResult:
    """Convert a pycolmap reconstruction with one rig into camcal's Rig; write its points and the rig.

    ``originals`` maps every staged image name (COLMAP's) to the user's
    image, relative to ``out_dir``: the frames point at those. The rig's
    provenance records the seed.
    """
    points_path = out_dir / "points.ply"
    model = sparse_model(reconstruction, camera_names, originals, units, bundle, calibration, points_path.name)
    rig = dataclasses.replace(model.rig, provenance={**model.rig.provenance, "seed": seed})
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
    )


def _say(progress: Callable[[str], None] | None, message: str) -> None:
    """Hand a stage message to the caller's progress callback, if any."""
    if progress is not None:
        progress(message)
