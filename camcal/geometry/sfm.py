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
from camcal.geometry.camera import from_colmap
from camcal.io.colmap import camera_from_colmap
from camcal.io.ply import write_points_ply
from camcal.rig import Frame, Rig, make_provenance

__all__ = ["IMAGE_SUFFIXES", "SfmResult", "solve_sfm"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
MATCHERS = ("exhaustive", "sequential")
MAPPERS = ("incremental", "global")


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
    """

    rig: Rig
    n_images: int
    n_registered: int
    unregistered: tuple[str, ...]
    n_points: int
    rms_px: float
    per_camera_rms_px: dict[str, float]
    reconstruction_dir: Path


def _list_images(folder: Path) -> list[str]:
    if not folder.is_dir():
        raise CamcalError(f"image folder not found: {folder}")
    names = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise CamcalError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return names


def _stage_images(folders: dict[str, Path], staging: Path) -> list[str]:
    """Link each camera's images under ``staging/<camera>/`` (COLMAP's rig layout)."""
    if staging.exists():
        shutil.rmtree(staging)
    names: list[str] = []
    for camera, folder in folders.items():
        (staging / camera).mkdir(parents=True)
        for name in _list_images(folder):
            os.symlink((folder / name).resolve(), staging / camera / name)
            names.append(f"{camera}/{name}")
    return names


def solve_sfm(
    folders: dict[str, Path],
    out_dir: Path,
    camera_model: str = "SIMPLE_RADIAL",
    matcher: str = "exhaustive",
    mapper: str = "incremental",
    seed: int = 0,
    num_threads: int = -1,
) -> SfmResult:
    """Run pycolmap SfM on one folder per camera and convert the result to a Rig.

    Parameters
    ----------
    folders : dict of str to Path
        Camera name -> its image folder. With several cameras, frames are
        matched by file name (``left/0001.png`` with ``right/0001.png``); the
        first camera is the rig's reference.
    out_dir : Path
        Receives ``database.db``, ``images/`` (links), ``sparse/`` (the COLMAP
        model), ``sfm.rig.json`` and ``points.ply``.
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
    image_names = _stage_images({name: Path(folder) for name, folder in folders.items()}, image_dir)
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
    model_dir = sparse / "best"
    model_dir.mkdir(exist_ok=True)
    reconstruction.write(model_dir)
    return _to_result(reconstruction, list(folders), image_names, out_dir, model_dir)


def _map(pycolmap, database: Path, image_dir: Path, sparse: Path, mapper: str, seed: int, num_threads: int) -> dict:
    if mapper == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = seed
        options.num_threads = num_threads
        return pycolmap.incremental_mapping(database, image_dir, sparse, options=options)
    return pycolmap.global_mapping(database, image_dir, sparse)


def _to_result(reconstruction, camera_names: list[str], image_names: list[str], out_dir: Path, model_dir: Path) -> SfmResult:
    """Convert a pycolmap reconstruction with one rig into camcal's Rig."""
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
    registered = set()
    for frame_index, frame_id in enumerate(sorted(reconstruction.reg_frame_ids())):
        frame = reconstruction.frame(frame_id)
        R, c = from_colmap(frame.rig_from_world.rotation.quat, frame.rig_from_world.translation)
        images = {}
        for data_id in frame.image_ids:
            image = reconstruction.image(data_id.id)
            images[camera_of_sensor[image.camera_id]] = f"images/{image.name}"
            registered.add(image.name)
        frames.append(Frame(frame_index, R, c, images))
    points_path = out_dir / "points.ply"
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()]).reshape(-1, 3)
    colours = np.array([p.color for p in reconstruction.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in reconstruction.points3D.values()], dtype=np.int32)
    write_points_ply(points_path, xyz, colours, tracks)
    result_rig = Rig(
        tuple(cameras), units="arbitrary", frames=tuple(frames), points=points_path.name,
        provenance=make_provenance("sfm (pycolmap)", images=len(image_names)),
    )
    per_camera, rms = _reprojection_rms(reconstruction, result_rig, camera_of_sensor, frames)
    result_rig = _with_quality(result_rig, per_camera)
    result_rig.save(out_dir / "sfm.rig.json")
    return SfmResult(
        rig=result_rig,
        n_images=len(image_names),
        n_registered=len(registered),
        unregistered=tuple(sorted(set(image_names) - registered)),
        n_points=len(xyz),
        rms_px=rms,
        per_camera_rms_px={name: value for name, (value, _) in per_camera.items()},
        reconstruction_dir=model_dir,
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


def _reprojection_rms(reconstruction, rig: Rig, camera_of_sensor: dict[int, str], frames: list[Frame]):
    """Reproject every observation through camcal's rig (checks the conversion too)."""
    squared: dict[str, list[NDArray[np.float64]]] = {}
    frame_of_image = {}
    for frame in frames:
        for path in frame.images.values():
            frame_of_image[path.removeprefix("images/")] = frame.index
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


def _with_quality(rig: Rig, per_camera: dict[str, tuple[float, int]]) -> Rig:
    cameras = tuple(
        dataclasses.replace(camera, quality={"rms_px": per_camera[camera.name][0], "n_observations": per_camera[camera.name][1]})
        if camera.name in per_camera else camera
        for camera in rig.cameras
    )
    return dataclasses.replace(rig, cameras=cameras)


def _progress(message: str) -> None:
    print(f"camcal solve: {message}", file=sys.stderr, flush=True)
