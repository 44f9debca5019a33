"""Plain pycolmap on the same images as ``solve``: the peer ``solve --compare-pycolmap`` prints beside camcal."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_dir, remove_stale_temporaries
from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.base.native_log import native_output_to
from camcal.geometry.sfm import camera_name
from camcal.model.colmap import camera_from_colmap
from camcal.model.rig import Camera
from camcal.pipelines.solve_colmap import COLMAP_LOG, OWNED
from camcal.pipelines.solve_inputs import list_images, stage_images

__all__ = ["PycolmapPeer", "solve_pycolmap_plain"]


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

    images = {name: list_images(Path(value)) if isinstance(value, (str, os.PathLike)) else [Path(p) for p in value]
              for name, value in folders.items()}
    remove_stale_temporaries([out_dir])
    with atomic_dir(out_dir, replace=OWNED + (COLMAP_LOG,)) as staging:
        with native_output_to(staging / COLMAP_LOG, echo=verbose):
            return _plain_in(pycolmap, images, folders, staging, camera_model, seed, every)


def _plain_in(pycolmap, images, folders, out_dir: Path, camera_model: str, seed: int, every: int = 1) -> PycolmapPeer:
    """:func:`solve_pycolmap_plain`'s work inside its (temporary) output folder."""
    staged = stage_images(images, out_dir / "images", every)
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
