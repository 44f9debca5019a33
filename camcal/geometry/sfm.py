"""Cameras from image correspondences: pycolmap structure from motion -> Rig.

One folder of images gives one camera moving over frames; several folders,
one per camera of a rig with the same file name per frame, give a rig whose
cameras share one relative pose over all frames (pycolmap's rig support:
``RigConfig`` + ``apply_rig_config`` before mapping, so that the mapper's
bundle adjustment keeps ``sensor_from_rig`` common to every frame).

The result is a :class:`camcal.rig.Rig` whose ``frames`` hold each frame's
``rig_from_world`` and whose cameras hold ``cam_from_rig`` (the first folder
is the reference sensor, at the rig origin), plus a sibling PLY of the
sparse points. COLMAP's pixel centre (0.5) is converted at the boundary
(:mod:`camcal.io.colmap`).

After mapping, camcal's bundle adjustment (:mod:`camcal.geometry.bundle`)
refines the seed: intrinsics shared per camera, one rig pose for all frames,
optionally held at a known calibration (``known_rig``, e.g. from
``calibrate board``, which also gives the reconstruction its units), a robust
loss, and the uncertainty of the intrinsics and the rig pose.

pycolmap is imported only here (and in the bundle adjustment module).

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.errors import CamcalError
from camcal.geometry.bundle import BundleOptions, BundleResult, bundle_adjust, hold_rig, state_from_reconstruction, state_to_reconstruction
from camcal.geometry.camera import from_colmap
from camcal.io.colmap import camera_from_colmap
from camcal.io.ply import write_points_ply
from camcal.rig import Frame, Rig, make_provenance

__all__ = ["IMAGE_SUFFIXES", "MODELS", "SfmResult", "collect_images", "solve_sfm"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
MATCHERS = ("exhaustive", "sequential")
MAPPERS = ("incremental", "global")
#: camcal's distortion models and the COLMAP camera model that is exactly each of them.
MODELS = {"division": "SIMPLE_DIVISION", "polynomial": "RADIAL", "opencv": "OPENCV", "none": "SIMPLE_PINHOLE"}


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


def _list_images(folder: Path, pattern: str = "*") -> list[Path]:
    if not folder.is_dir():
        raise CamcalError(f"image folder not found: {folder}")
    images = sorted(p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise CamcalError(f"no images ({', '.join(IMAGE_SUFFIXES)}) matching {pattern!r} in {folder}")
    return images


def collect_images(folders: list[Path], camera_globs: dict[str, str] | None = None) -> dict[str, list[Path]]:
    """Images per camera: one folder per camera (named after it), or globs in one folder.

    Parameters
    ----------
    folders : list of Path
        Image folders. Without ``camera_globs`` each is one camera; a single
        folder holding only sub-folders of images is a rig, one camera per
        sub-folder.
    camera_globs : dict of str to str, optional
        Camera name -> glob relative to the (single) folder, e.g.
        ``{"left": "*_L.png", "right": "*_R.png"}``; frames pair up by sorted order.
    """
    folders = [Path(folder) for folder in folders]
    if camera_globs:
        if len(folders) != 1:
            raise CamcalError("--camera NAME=GLOB selects images inside one folder: give exactly one")
        return {name: _list_images(folders[0], pattern) for name, pattern in camera_globs.items()}
    if len(folders) == 1 and folders[0].is_dir():
        subfolders = sorted(p for p in folders[0].iterdir() if p.is_dir())
        if subfolders and not any(p.suffix.lower() in IMAGE_SUFFIXES for p in folders[0].iterdir() if p.is_file()):
            folders = subfolders
    names = [folder.name for folder in folders]
    if len(set(names)) != len(names):
        raise CamcalError("image folders must have distinct names (they name the cameras)")
    return {folder.name: _list_images(folder) for folder in folders}


def _stage_images(images: dict[str, list[Path]], staging: Path) -> dict[str, Path]:
    """Link each camera's images under ``staging/<camera>/`` (COLMAP's rig layout).

    Frames pair up by position in each camera's sorted list: the k-th image
    of every camera is linked under the same name ``<k>.<suffix>``.

    Returns
    -------
    dict
        Staged name (``camera/<k>.<suffix>``, COLMAP's image name) -> the user's image.
    """
    if staging.exists():
        shutil.rmtree(staging)
    staged: dict[str, Path] = {}
    for camera, paths in images.items():
        (staging / camera).mkdir(parents=True)
        for index, path in enumerate(paths):
            name = f"{index:06d}{path.suffix.lower()}"
            os.symlink(path.resolve(), staging / camera / name)
            staged[f"{camera}/{name}"] = path
    return staged


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
) -> SfmResult:
    """Run pycolmap SfM, refine it with camcal's bundle adjustment, convert it to a Rig.

    Parameters
    ----------
    folders : dict of str to Path or list of Path
        Camera name -> its image folder (or its images, see
        :func:`collect_images`). With several cameras, frames pair up by the
        sorted order of each camera's images; the first camera is the rig's
        reference.
    out_dir : Path
        Receives ``database.db``, ``images/`` (links), ``sparse/`` (the COLMAP
        model), ``solve.rig.json`` and ``points.ply``.
    camera_model : str
        COLMAP model for every camera: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL,
        RADIAL, OPENCV, SIMPLE_DIVISION... (one with a camcal counterpart).
    matcher : {"exhaustive", "sequential"}
        Exhaustive for unordered sets under ~50 images; sequential for video.
    mapper : {"incremental", "global"}
    seed : int
        The mapper's random seed (repeatable runs).
    num_threads : int
        -1 uses every core.
    refine : bool
        Run camcal's bundle adjustment after pycolmap's mapping.
    known_rig : Rig, optional
        A calibrated rig with the same camera names (``calibrate board``):
        the cameras' relative poses are held at it and the reconstruction
        takes its units.
    loss : {"trivial", "huber", "soft_l1", "cauchy"}
        Robust loss of the refinement (scale 1 px).

    Returns
    -------
    SfmResult
    """
    import pycolmap  # noqa: PLC0415 - optional heavy dependency, only here

    if not folders:
        raise CamcalError("need at least one image folder")
    if matcher not in MATCHERS:
        raise CamcalError(f"unknown matcher {matcher!r}, expected one of: {', '.join(MATCHERS)}")
    if mapper not in MAPPERS:
        raise CamcalError(f"unknown mapper {mapper!r}, expected one of: {', '.join(MAPPERS)}")
    if not hasattr(pycolmap.CameraModelId, camera_model):
        raise CamcalError(f"unknown COLMAP camera model {camera_model!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    image_dir = out_dir / "images"
    images = {name: _list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    if known_rig is not None:
        missing = [name for name in images if name not in {camera.name for camera in known_rig.cameras}]
        if missing:
            raise CamcalError(f"the known rig has no camera named {', '.join(map(repr, missing))}")
    options = BundleOptions(loss=loss, refine_sensor_from_rig=known_rig is None)
    staged = _stage_images(images, image_dir)
    image_names = list(staged)
    if len(image_names) < 2:
        raise CamcalError(f"need at least 2 images, got {len(image_names)}")
    database = out_dir / "database.db"
    database.unlink(missing_ok=True)

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    _progress(f"extracting features from {len(image_names)} images")
    pycolmap.extract_features(
        database, image_dir, image_names=image_names, camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    _progress(f"matching ({matcher})")
    match = pycolmap.match_exhaustive if matcher == "exhaustive" else pycolmap.match_sequential
    match(database, device=pycolmap.Device.cpu)
    sparse = out_dir / "sparse"
    if sparse.exists():
        shutil.rmtree(sparse)
    sparse.mkdir()
    _progress(f"mapping ({mapper})")
    models = _map(pycolmap, database, image_dir, sparse, mapper, seed, num_threads)
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
        db = pycolmap.Database.open(database)
        try:
            pycolmap.apply_rig_config([rig_config], db, first_pass)
        finally:
            db.close()
        shutil.rmtree(sparse)
        sparse.mkdir()
        _progress(f"mapping ({mapper}) with the rig constraint")
        models = _map(pycolmap, database, image_dir, sparse, mapper, seed, num_threads)
    if not models:
        raise CamcalError("structure from motion registered no images: too little texture or overlap?")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    bundle = None
    if refine:
        _progress("bundle adjustment (camcal)")
        names = {camera_id: _camera_name(reconstruction, camera_id) for camera_id in reconstruction.cameras}
        state = state_from_reconstruction(reconstruction, names)
        if known_rig is not None:
            state = hold_rig(state, _relative_poses(known_rig, state.camera_names[0]))
        bundle = bundle_adjust(state, options)
        state_to_reconstruction(bundle.state, reconstruction)
    model_dir = sparse / "best"
    model_dir.mkdir(exist_ok=True)
    reconstruction.write(model_dir)
    originals = {name: Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()
                 for name, path in staged.items()}
    units = known_rig.units if known_rig is not None else "arbitrary"
    return _to_result(reconstruction, list(folders), out_dir, model_dir, originals, units, bundle)


def _relative_poses(rig: Rig, reference: str) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Each camera's ``cam_from_reference`` (R, t) in a calibrated rig (X_cam = R X_ref + t)."""
    names = {camera.name for camera in rig.cameras}
    if reference not in names:
        raise CamcalError(f"the known rig has no camera named {reference!r}")
    ref = rig.camera(reference)
    return {camera.name: (camera.R @ ref.R.T, camera.R @ (ref.c - camera.c)) for camera in rig.cameras}


def _map(pycolmap, database: Path, image_dir: Path, sparse: Path, mapper: str, seed: int, num_threads: int) -> dict:
    if mapper == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = seed
        options.num_threads = num_threads
        return pycolmap.incremental_mapping(database, image_dir, sparse, options=options)
    return pycolmap.global_mapping(database, image_dir, sparse)


def _to_result(reconstruction, camera_names: list[str], out_dir: Path, model_dir: Path,
               originals: dict[str, str], units: str, bundle: BundleResult | None) -> SfmResult:
    """Convert a pycolmap reconstruction with one rig into camcal's Rig.

    ``originals`` maps every staged image name (COLMAP's) to the user's
    image, relative to ``out_dir``: the frames point at those.
    """
    if reconstruction.num_rigs() != 1:
        raise CamcalError(f"expected one rig in the reconstruction, got {reconstruction.num_rigs()}")
    rig = next(iter(reconstruction.rigs.values()))
    cameras = []
    camera_of_sensor: dict[int, str] = {}
    for camera_id, colmap_camera in reconstruction.cameras.items():
        name = _camera_name(reconstruction, camera_id)
        if rig.is_ref_sensor(_sensor(camera_id)):
            R, c = np.eye(3), np.zeros(3)
        else:
            sensor_from_rig = rig.sensor_from_rig(_sensor(camera_id))
            R, c = from_colmap(sensor_from_rig.rotation.quat, sensor_from_rig.translation)
        cameras.append(
            camera_from_colmap(name, colmap_camera.model.name, (colmap_camera.width, colmap_camera.height),
                               colmap_camera.params, R, c)
        )
        camera_of_sensor[camera_id] = name
    order = {name: index for index, name in enumerate(camera_names)}
    cameras.sort(key=lambda camera: order[camera.name])

    frames = []
    frame_of_image: dict[str, int] = {}
    for frame_index, frame_id in enumerate(sorted(reconstruction.reg_frame_ids())):
        frame = reconstruction.frame(frame_id)
        R, c = from_colmap(frame.rig_from_world.rotation.quat, frame.rig_from_world.translation)
        images = {}
        for data_id in frame.image_ids:
            image = reconstruction.image(data_id.id)
            images[camera_of_sensor[image.camera_id]] = originals[image.name]
            frame_of_image[image.name] = frame_index
        frames.append(Frame(frame_index, R, c, images))
    points_path = out_dir / "points.ply"
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()]).reshape(-1, 3)
    colours = np.array([p.color for p in reconstruction.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in reconstruction.points3D.values()], dtype=np.int32)
    write_points_ply(points_path, xyz, colours, tracks)
    result_rig = Rig(
        tuple(cameras), units=units, frames=tuple(frames), points=points_path.name,
        provenance=make_provenance("sfm (pycolmap)" + (" + camcal bundle adjustment" if bundle else ""),
                                   images=len(originals)),
    )
    per_camera, rms = _reprojection_rms(reconstruction, result_rig, camera_of_sensor, frame_of_image)
    result_rig = _with_quality(result_rig, per_camera, bundle)
    result_rig.save(out_dir / "solve.rig.json")
    return SfmResult(
        rig=result_rig,
        n_images=len(originals),
        n_registered=len(frame_of_image),
        unregistered=tuple(sorted(set(originals) - set(frame_of_image))),
        n_points=len(xyz),
        rms_px=rms,
        per_camera_rms_px={name: value for name, (value, _) in per_camera.items()},
        reconstruction_dir=model_dir,
        bundle=bundle,
    )


def _sensor(camera_id: int):
    """The pycolmap sensor id of a camera."""
    import pycolmap  # noqa: PLC0415

    return pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_id)


def _camera_name(reconstruction, camera_id: int) -> str:
    """The camera's folder name, from the name of one of its images."""
    for image in reconstruction.images.values():
        if image.camera_id == camera_id:
            return image.name.split("/", 1)[0]
    raise CamcalError(f"COLMAP camera {camera_id} has no registered image")


def _reprojection_rms(reconstruction, rig: Rig, camera_of_sensor: dict[int, str], frame_of_image: dict[str, int]):
    """Reproject every observation through camcal's rig (checks the conversion too)."""
    squared: dict[str, list[NDArray[np.float64]]] = {}
    for image in reconstruction.images.values():
        if image.name not in frame_of_image:
            continue
        observed = [(p.xy, reconstruction.points3D[p.point3D_id].xyz) for p in image.points2D if p.has_point3D()]
        if not observed:
            continue
        xy = np.array([o[0] for o in observed]) - 0.5
        X = np.array([o[1] for o in observed])
        name = camera_of_sensor[image.camera_id]
        camera = rig.camera_at_frame(name, frame_of_image[image.name])
        squared.setdefault(name, []).append(np.sum((camera.project(X) - xy) ** 2, axis=1))
    per_camera = {name: (float(np.sqrt(np.mean(np.concatenate(v)))), int(sum(len(a) for a in v))) for name, v in squared.items()}
    everything = np.concatenate([np.concatenate(v) for v in squared.values()])
    return per_camera, float(np.sqrt(np.mean(everything)))


def _with_quality(rig: Rig, per_camera: dict[str, tuple[float, int]], bundle: BundleResult | None) -> Rig:
    cameras = []
    for camera in rig.cameras:
        if camera.name not in per_camera:
            cameras.append(camera)
            continue
        quality: dict = {"rms_px": per_camera[camera.name][0], "n_observations": per_camera[camera.name][1]}
        if bundle is not None:
            quality["rms_seed_px"] = bundle.rms_before_px[camera.name]
            prefix = f"{camera.name}."
            quality["sigma"] = {key[len(prefix):]: value for key, value in bundle.sigmas.items() if key.startswith(prefix)}
        cameras.append(dataclasses.replace(camera, quality=quality))
    return dataclasses.replace(rig, cameras=tuple(cameras))


def _progress(message: str) -> None:
    print(f"camcal solve: {message}", file=sys.stderr, flush=True)
