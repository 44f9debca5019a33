"""COLMAP's stages of a solve, each seeded and in a fixed order: extraction, image numbering, verification, mapping.

What makes the same images give the same reconstruction, run after run
(:func:`number_by_name`, :func:`verification_options`, :func:`map_images`),
and what the database says when the images cannot make one
(:func:`check_parallax`, :func:`why_nothing_registered`).

References
----------
Schoenberger, J. L. & Frahm, J.-M. (2016). Structure-from-Motion Revisited.
CVPR.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = [
    "COLMAP_LOG",
    "MAPPERS",
    "MATCHERS",
    "MIN_PAIR_MATCHES",
    "OWNED",
    "REFINED_GLOBAL_BA_RATIO",
    "REFINED_GLOBAL_BA_REFINEMENTS",
    "REFINED_LOCAL_BA_REFINEMENTS",
    "SEQUENTIAL_INIT_TRI_ANGLE_DEG",
    "UPSAMPLE_BELOW_PX",
    "check_parallax",
    "extraction_options",
    "map_images",
    "number_by_name",
    "verification_options",
    "why_nothing_registered",
]

MATCHERS = ("exhaustive", "sequential")
MAPPERS = ("incremental", "global")
#: the file in the output folder that receives COLMAP's, glog's and Ceres' own lines.
COLMAP_LOG = "colmap.log"
#: What a solve writes in its folder as a whole: an earlier run's are replaced, not merged into.
OWNED = ("images", "masks", "sparse", "database.db")
#: images of at least this many pixels are not upsampled before SIFT (:func:`extraction_options`).
UPSAMPLE_BELOW_PX = 4_000_000


def extraction_options(pycolmap, paths: list[Path], max_num_features: int, num_threads: int):
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


def number_by_name(pycolmap, database: Path) -> None:
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


def verification_options(pycolmap, seed: int):
    """Geometric verification options with a seeded RANSAC (COLMAP's default seed -1 draws from the clock)."""
    options = pycolmap.TwoViewGeometryOptions()
    options.ransac.random_seed = seed
    return options


def map_images(pycolmap, database: Path, image_dir: Path, sparse: Path, mapper: str, seed: int,
               hold_intrinsics: bool = False, sequential: bool = False, refined: bool = False) -> tuple[dict, str]:
    """COLMAP's mapping, seeded and on one thread (multi-threaded Ceres sums in the order threads finish).

    ``hold_intrinsics``: the mapper's bundle adjustments keep the cameras' intrinsics as the database has them
    (a lens known from a grid, :mod:`camcal.pipelines.solve_lens`). ``sequential``: the pairs were matched in
    frame order (a plate): the incremental mapper looks for its initial pair with the triangulation angle
    :data:`SEQUENTIAL_INIT_TRI_ANGLE_DEG` from the start; with ``refined`` as well (camcal's bundle adjustment
    refines the whole model afterwards), its global bundle adjustments run as the model grows by
    :data:`REFINED_GLOBAL_BA_RATIO` instead of COLMAP's 1.1, each once (:data:`REFINED_GLOBAL_BA_REFINEMENTS`), and
    each local one once (:data:`REFINED_LOCAL_BA_REFINEMENTS`).

    The incremental mapper never starts from a pair whose relative translation points along the view by more
    than ``init_max_forward_motion`` (0.95 of its length), and its relaxations lower the inliers and the
    triangulation angle it asks of the first pair, never that bound: on footage that moves forward
    (driving, walking down a corridor) no pair can start a model, and nothing is registered. When the first
    run leaves images unregistered, the mapper runs again allowing a forward-moving first pair (the
    triangulation-angle bound still keeps a degenerate one out), and the run that registers more images is
    kept (the first on a tie).

    Returns
    -------
    models : dict
        COLMAP's reconstructions by index (written under ``sparse``).
    note : str
        What was done beyond one plain run (the forward-motion retry and its outcome), else empty.
    """
    pycolmap.set_random_seed(seed)
    if mapper == "global":
        options = pycolmap.GlobalPipelineOptions()
        options.random_seed = seed
        options.num_threads = 1
        if hold_intrinsics:
            adjustment = options.mapper.bundle_adjustment
            adjustment.refine_focal_length = adjustment.refine_extra_params = adjustment.refine_principal_point = False
        return pycolmap.global_mapping(database, image_dir, sparse, options=options), ""
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = seed
    options.num_threads = 1
    if sequential:
        options.mapper.init_min_tri_angle = SEQUENTIAL_INIT_TRI_ANGLE_DEG
        if refined:
            options.ba_global_frames_ratio = options.ba_global_points_ratio = REFINED_GLOBAL_BA_RATIO
            options.ba_global_max_refinements = REFINED_GLOBAL_BA_REFINEMENTS
            options.ba_local_max_refinements = REFINED_LOCAL_BA_REFINEMENTS
    if hold_intrinsics:
        options.ba_refine_focal_length = options.ba_refine_extra_params = False
        options.ba_refine_principal_point = False
    models = pycolmap.incremental_mapping(database, image_dir, sparse, options=options)
    n_images = _image_count(pycolmap, database)
    first = _most_registered(models)
    if first >= n_images:
        return models, ""
    retry = sparse.with_name(sparse.name + ".forward")
    retry.mkdir()
    options.mapper.init_max_forward_motion = 1.0
    pycolmap.set_random_seed(seed)
    forward = pycolmap.incremental_mapping(database, image_dir, retry, options=options)
    second = _most_registered(forward)
    note = (f"the mapper registered {first} of {n_images} images; started again from a pair that may move along "
            f"its view (forward motion): {second}")
    if second <= first:
        shutil.rmtree(retry)
        return models, note + ", the first run kept"
    shutil.rmtree(sparse)
    retry.rename(sparse)
    return forward, note + ", kept"


def _most_registered(models: dict) -> int:
    """The registered images of the largest of COLMAP's ``models`` (0 for none)."""
    return max((model.num_reg_images() for model in models.values()), default=0)


def _image_count(pycolmap, database: Path) -> int:
    """The images in a COLMAP ``database``."""
    db = pycolmap.Database.open(database)
    try:
        return db.num_images()
    finally:
        db.close()


#: the smallest triangulation angle (deg) of the incremental mapper's initial pair when the pairs were matched in
#: frame order. COLMAP asks 16 deg and, when no pair gives it, searches every pair again with fewer inliers, then
#: with half the angle, down to 4 deg after four failed searches; frames matched within the sequential matcher's
#: window (10 frames, under half a second of a plate) rarely turn 16 deg about the points, so those searches cost
#: about half of the mapping of a walking plate (5 of 10 min at 60 frames) and find nothing. Starting at COLMAP's
#: last relaxed angle (the inliers still asked) found the same initial pair and the same reconstruction, bit
#: for bit, on rendered walk and orbit plates.
SEQUENTIAL_INIT_TRI_ANGLE_DEG = 4.0
#: the growth of the model (registered frames or points) between two of the incremental mapper's global bundle
#: adjustments on a plate matched in frame order whose model camcal refines afterwards (COLMAP's default: 1.1, a
#: global adjustment at almost every frame of a short plate, 26 on a 60-frame orbit; the cost of all of them is
#: about 1 / (1 - 1 / ratio) times the last one's). Each frame is still registered against its neighbours and
#: refined by the mapper's local bundle adjustment, and the whole model is adjusted once more when the mapper
#: ends; camcal's bundle adjustment then refines every frame, point and intrinsic from that model.
REFINED_GLOBAL_BA_RATIO = 1.5
#: on such a plate each of those global adjustments runs once (COLMAP's default: up to 5 rounds of adjustment,
#: re-triangulation and outlier filtering while more than 0.05 % of the observations change). camcal's own bundle
#: adjustment, outlier rejection and re-triangulation follow the mapper: on the rendered 240-frame orbit the
#: mapper took 20 % less CPU, on the walk 4 %; the refined cameras' errors moved by a few % either way.
REFINED_GLOBAL_BA_REFINEMENTS = 1
#: on such a plate the local bundle adjustment after each registered frame runs once too (COLMAP's default: up to
#: 2 rounds of adjustment, track merging and completion, and filtering). A plate's points are seen by 16-60 frames,
#: so each local adjustment carries every observation of the points its 6 frames see, a good part of the model.
#: On the rendered 240-frame walk the mapper took 34 % less CPU (175 against 265 s), the refined cameras' errors
#: within 7 % of before (position 6 % lower, rotation 2 % higher).
REFINED_LOCAL_BA_REFINEMENTS = 1
#: a pair of images counts as matched with at least this many verified matches.
MIN_PAIR_MATCHES = 15


def _verified_pairs(pycolmap, database: Path) -> list:
    """The two-view geometries of the pairs with at least :data:`MIN_PAIR_MATCHES` verified matches."""
    db = pycolmap.Database.open(database)
    try:
        return [geometry for geometry in db.read_two_view_geometries()[1]
                if len(geometry.inlier_matches) >= MIN_PAIR_MATCHES]
    finally:
        db.close()


def check_parallax(pycolmap, database: Path, n_images: int) -> None:
    """Refuse a plate none of whose matched pairs has parallax (a nodal pan, a locked-off camera).

    COLMAP's verification calls a pair ``PANORAMIC`` or ``PLANAR_OR_PANORAMIC``
    when a homography explains its matches and its relative pose, if any,
    triangulates under too small an angle: a rotation alone. If every
    matched pair is such, depth cannot be triangulated, and the mapper's
    result (when it makes one) has a focal length and points made up of noise.
    """
    pairs = _verified_pairs(pycolmap, database)
    rotation_only = (pycolmap.TwoViewGeometryConfiguration.PANORAMIC,
                     pycolmap.TwoViewGeometryConfiguration.PLANAR_OR_PANORAMIC)
    if pairs and all(geometry.config in rotation_only for geometry in pairs):
        raise CamcalError(f"too little parallax in the {n_images} images: the camera turns or barely moves between "
                          f"them (all {len(pairs)} matched pairs fit a rotation alone), so depth cannot be "
                          "triangulated: structure from motion needs a camera that moves (a nodal pan cannot be "
                          "solved), or frames further apart")


def why_nothing_registered(pycolmap, database: Path, n_images: int) -> str:
    """One line on why the mapper registered nothing: no matched pair, or no pair that starts a model."""
    pairs = _verified_pairs(pycolmap, database)
    if not pairs:
        return (f"structure from motion registered none of the {n_images} images: no two of them share enough "
                "features (too little texture or overlap?)")
    return (f"structure from motion registered none of the {n_images} images although {len(pairs)} pairs match: "
            "no pair gave a stable start (too little parallax or too few matches?)")
