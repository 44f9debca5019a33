"""Build a camcal rig in a Blender scene: the one function everything calls.

The File > Import operator, the panel, ``camcal blender import`` and
``blender -b --python-expr`` scripts all call :func:`import_rig`. The maths
lives in the pure modules (:mod:`.mapping`, :mod:`.rigfile`); this module only
creates Blender data from their results.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field

import bpy
from mathutils import Matrix

from . import compositor, fisheye, lens_animation, mapping, plyfile, pngfile, rigfile, tracking
from .rigfile import RigFileError

__all__ = [
    "ImportResult",
    "RigFileError",
    "import_rig",
    "apply_resolution",
    "camera_colour_space",
    "distortion_shift",
]

PLATE_KINDS = ("raw", "undistorted", "rectified")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".dpx", ".bmp")


@dataclass
class ImportResult:
    """What :func:`import_rig` created.

    ``cameras`` maps rig camera names to camera objects; ``clips`` to the
    MovieClips carrying their lenses; ``distorted_scenes`` to the scenes whose
    compositor distorts the render; ``warnings`` are one-line messages.
    """

    rig: rigfile.Rig
    scene: object
    collection: object
    root: object
    cameras: dict = field(default_factory=dict)
    clips: dict = field(default_factory=dict)
    distorted_scenes: dict = field(default_factory=dict)
    points: object = None
    stereo_mode: str = "NONE"
    warnings: list = field(default_factory=list)


@dataclass(frozen=True)
class _Cam:
    """A rig camera as imported: effective K, R, c, size and distortion."""

    name: str
    K: tuple
    R: tuple
    c: tuple
    size: tuple
    distortion: rigfile.Distortion
    sensor_width_mm: float
    source: rigfile.RigCamera


def import_rig(
    context_or_scene,
    path,
    *,
    up_axis="Z",
    sensor_fit="AUTO",
    use_rectified=False,
    frame_start=1,
    import_plates=True,
    plates=None,
    plate_directory=None,
    import_points=True,
    stereo=True,
    distortion=True,
    compositor=True,
    overscan=1.1,
    aux_directory=None,
    lens_model=None,
    uv_maps=None,
):
    """Import a camcal rig file into a scene.

    Parameters
    ----------
    context_or_scene : bpy.types.Context or bpy.types.Scene
    path : str
        The ``*.rig.json`` file.
    up_axis : {'Z', 'Y', '-Y'}
        The camcal world axis that points up in Blender (applied on the rig root).
    sensor_fit : {'AUTO', 'HORIZONTAL', 'VERTICAL'}
        The cameras' sensor fit; the projection is exact with each.
    use_rectified : bool
        Import the rectified cameras (``K_rect``, rectified rotation and size,
        no distortion); plates then come from ``plates`` / ``plate_directory``.
    frame_start : int
        Blender frame of rig frame index 0 (the rig's per-frame poses become
        keyframes on the rig root).
    import_plates : bool
        Camera background images from ``frames[*].images`` (the first frame
        that has one), from ``plates`` or from ``plate_directory``.
    plates : dict, optional
        ``{camera name: image path}``, overriding the rig's plates.
    plate_directory : str, optional
        A folder holding ``<camera name>.<ext>`` images.
    import_points : bool
        The rig's sparse points (PLY) as a point-cloud mesh.
    stereo : bool
        Set up stereo 3D (two rectified cameras) or multi-view (otherwise).
    distortion : bool
        MovieClips whose tracking cameras carry the lenses.
    compositor : bool
        For each distorted camera, an overscan render scene and a scene whose
        compositor distorts it with Movie Distortion.
    overscan : float
        Overscan factor of the render that the compositor distorts.
    lens_model : {None, 'POLYNOMIAL', 'DIVISION', 'NUKE', 'BROWN'}
        The tracking camera's distortion model; None takes the one that
        holds each lens exactly (:func:`.tracking.blender_lens`); another is
        fitted, with its residual among the warnings.
    uv_maps : dict, optional
        ``{camera name: EXR path}``: camcal's exact redistort map of the
        camera on the overscan frame, as the UV of Blender's Map UV node
        (``camcal.blender_bridge.write_blender_uv_maps``); that camera's
        compositor re-distorts with it instead of Movie Distortion (its
        clip keeps the tracking lens).
    aux_directory : str, optional
        Where blank lens frames are written (default: beside the saved
        .blend, else beside the rig file, else a temporary folder).

    Returns
    -------
    ImportResult

    Raises
    ------
    RigFileError
        A bad rig file, plate or point cloud; the message names it.
    """
    scene = context_or_scene if isinstance(context_or_scene, bpy.types.Scene) else context_or_scene.scene
    rig = rigfile.load_rig(path)
    if not overscan >= 1.0:
        raise RigFileError(f"overscan: must be >= 1, got {overscan}")
    if lens_model is not None and lens_model not in tracking.BLENDER_MODELS:
        raise RigFileError(f"lens_model: unknown {lens_model!r}, expected one of: {', '.join(tracking.BLENDER_MODELS)}")
    cams = [_effective_camera(c, use_rectified) for c in rig.cameras]
    cloud = None
    if import_points and rig.points is not None:  # read before creating anything
        try:
            cloud = plyfile.read_ply_points(rig.points)
        except plyfile.PlyError as error:
            raise RigFileError(f"points: {error}") from None

    collection = bpy.data.collections.new(rig.name)
    scene.collection.children.link(collection)
    root = bpy.data.objects.new(rig.name, None)
    root.empty_display_type = "PLAIN_AXES"
    root.rotation_mode = "QUATERNION"
    root.matrix_basis = Matrix(mapping.up_axis_matrix(up_axis))
    root["camcal_rig_path"] = rig.path
    root["camcal_up_axis"] = up_axis
    root["camcal_rectified"] = bool(use_rectified)
    root["camcal_provenance"] = json.dumps(rig.provenance)
    collection.objects.link(root)
    result = ImportResult(rig=rig, scene=scene, collection=collection, root=root)

    base = _unique_base(rig.name, [c.name for c in cams])
    for cam in cams:
        obj = _build_camera(cam, base, sensor_fit, collection, root, result)
        result.cameras[cam.name] = obj
    _keyframe_rig(rig, root, up_axis, frame_start, scene)

    first = result.cameras[cams[0].name]
    scene.camera = first
    apply_resolution(scene, first)
    if len({c.size for c in cams}) > 1:
        result.warnings.append(
            "the cameras have different image sizes: the scene resolution fits "
            f"{cams[0].name!r}; re-apply the resolution when switching cameras"
        )

    if stereo and len(cams) >= 2:
        _setup_views(scene, cams, result)

    plate_paths = _plate_paths(rig, cams, use_rectified, plates, plate_directory, result) if import_plates else {}
    for cam in cams:
        obj = result.cameras[cam.name]
        plate = plate_paths.get(cam.name)
        if plate is not None and not os.path.isfile(plate):
            result.warnings.append(f"plate of {cam.name!r} not found: {plate}")
            plate = None
        clip = None
        # a fisheye's lens is in its panoramic camera itself (see _set_fisheye), not in a MovieClip
        if distortion and cam.distortion.model != "none" and cam.distortion.model not in rigfile.FISHEYE_MODELS:
            clip = _lens_clip(cam, obj, plate, result, path, aux_directory, scene, lens_model)
            result.clips[cam.name] = clip
            if compositor:
                result.distorted_scenes[cam.name] = _distortion_setup(
                    scene, cam, obj, overscan, result, path, aux_directory, lens_model, (uv_maps or {}).get(cam.name)
                )
        if plate is not None:
            _background(cam, obj, plate, clip)
    if use_rectified and any(frame.lenses for frame in rig.frames):
        result.warnings.append("the rig has per-frame lenses; the rectified cameras (one K_rect) do not take them")
    elif not use_rectified:
        lens_animation.animate_lenses(rig, cams, result, frame_start, lens_model, overscan)

    if cloud is not None:
        result.points = _point_cloud(rig, cloud, base, collection, root)
    return result


# --------------------------------------------------------------------------
# Cameras.


def _effective_camera(cam, use_rectified):
    if not use_rectified:
        return _Cam(cam.name, cam.K, cam.R, cam.c, cam.image_size, cam.distortion, cam.sensor_width_mm, cam)
    if cam.rectification is None:
        raise RigFileError(f"camera {cam.name!r}: no rectification in the rig, cannot import rectified")
    try:
        K, R, size = mapping.rectified_camera(cam.K, cam.R, cam.rectification)
    except ValueError as error:
        raise RigFileError(f"camera {cam.name!r}.rectification: {error}") from None
    return _Cam(cam.name, K, R, cam.c, size, rigfile.Distortion(), cam.sensor_width_mm, cam)


def _unique_base(name, camera_names):
    """A base name such that every ``<base>_<camera>`` object name is free."""
    base, n = name, 0
    while any(f"{base}_{c}" in bpy.data.objects for c in camera_names):
        n += 1
        base = f"{name}.{n:03d}"
    return base


def _set_intrinsics(data, b):
    data.type = "PERSP"
    data.lens_unit = "MILLIMETERS"
    data.sensor_fit = b.sensor_fit
    data.sensor_width = b.sensor_width
    data.sensor_height = b.sensor_height
    data.lens = b.lens
    data.shift_x = b.shift_x
    data.shift_y = b.shift_y


def _set_fisheye(data, cam, sensor_fit, result):
    """A Kannala-Brandt lens: Cycles' panoramic fisheye-polynomial camera (fisheye.blender_fisheye)."""
    try:
        f = fisheye.blender_fisheye(cam.K, cam.size, cam.distortion.params, cam.sensor_width_mm, sensor_fit)
    except ValueError as error:
        raise RigFileError(f"camera {cam.name!r}: {error}") from None
    data.type = "PANO"
    # Blender 4.x and 5.x keep the panorama settings on the camera data
    data.panorama_type = "FISHEYE_LENS_POLYNOMIAL"
    data.sensor_width = f.sensor_width
    data.sensor_height = f.sensor_height
    data.shift_x = f.shift_x
    data.shift_y = f.shift_y
    data.fisheye_fov = min(max(f.fov * 1.0001, 0.1745), 31.4)
    for n, value in enumerate(f.polynomial):
        setattr(data, f"fisheye_polynomial_k{n}", value)
    data["camcal_fisheye_fit_max_px"] = f.fit_max_px
    data["camcal_fisheye_fit_rms_px"] = f.fit_rms_px
    result.warnings.append(
        f"camera {cam.name!r}: fisheye as Cycles' fisheye-polynomial camera (renders with Cycles only); "
        f"the quartic matches the lens to {f.fit_max_px:.3g} px at worst, {f.fit_rms_px:.3g} px RMS over the frame"
    )
    if cam.distortion.model != "kannala-brandt":
        offset = fisheye.thin_prism_offset_px(cam.K, cam.size, cam.distortion.params)
        data["camcal_fisheye_left_out_px"] = offset
        result.warnings.append(
            f"camera {cam.name!r}: inexact: Cycles' fisheye camera is radial; the lens's tangential and thin-prism "
            f"terms (up to {offset:.3g} px over the frame) are left out (use the ST-maps for exact plates)"
        )


def _build_camera(cam, base, sensor_fit, collection, root, result):
    b = mapping.blender_intrinsics(cam.K, cam.size, cam.sensor_width_mm, sensor_fit)
    if abs(b.skew) > 1e-9 * cam.K[0][0]:
        result.warnings.append(
            f"camera {cam.name!r}: skew {b.skew:.3g} px cannot be represented in Blender, ignored"
        )
    name = f"{base}_{cam.name}"
    data = bpy.data.cameras.new(name)
    _set_intrinsics(data, b)
    if cam.distortion.model in rigfile.FISHEYE_MODELS:
        _set_fisheye(data, cam, sensor_fit, result)
    data["camcal_name"] = cam.name
    data["camcal_K"] = [v for row in cam.K for v in row]
    data["camcal_R"] = [v for row in cam.R for v in row]
    data["camcal_c"] = list(cam.c)
    data["camcal_image_size"] = list(cam.size)
    data["camcal_pixel_aspect"] = [b.pixel_aspect_x, b.pixel_aspect_y]
    data["camcal_distortion"] = json.dumps(
        {"model": cam.distortion.model, "params": cam.distortion.params,
         "center": list(cam.distortion.center) if cam.distortion.center else None}
    )
    data["camcal_camera"] = json.dumps(cam.source.raw)
    quality = cam.source.quality
    if "rms_px" in quality and isinstance(quality["rms_px"], (int, float)):
        data["camcal_rms_px"] = float(quality["rms_px"])
    data["camcal_quality"] = json.dumps(quality)
    obj = bpy.data.objects.new(name, data)
    obj["camcal_camera"] = cam.name
    collection.objects.link(obj)
    obj.parent = root
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.rotation_mode = "QUATERNION"
    obj.matrix_basis = Matrix(mapping.camera_matrix_local(cam.R, cam.c))
    return obj


def apply_resolution(scene, camera_object):
    """Set the scene's render size and pixel aspect to those of a camcal camera.

    The Blender camera is exact only at its own resolution; multi-view
    renders share one scene resolution.
    """
    data = camera_object.data
    if "camcal_image_size" not in data:
        raise RigFileError(f"{camera_object.name!r} is not a camera imported by camcal")
    w, h = data["camcal_image_size"]
    ax, ay = data["camcal_pixel_aspect"]
    render = scene.render
    render.resolution_x, render.resolution_y = int(w), int(h)
    render.resolution_percentage = 100
    render.pixel_aspect_x, render.pixel_aspect_y = float(ax), float(ay)


def _keyframe_rig(rig, root, up_axis, frame_start, scene):
    """Per-frame rig poses (``rig_from_world``) as keyframes on the rig root.

    The cameras stay put under the root (their ``R, c`` are ``cam_from_rig``),
    so each camera's world pose at a frame is camcal's ``camera_at_frame``.
    """
    if not rig.frames:
        return
    up = Matrix(mapping.up_axis_matrix(up_axis))
    previous = None
    for frame in sorted(rig.frames, key=lambda f: f.index):
        root.matrix_basis = up @ Matrix(mapping.rig_matrix(frame.R, frame.c))
        q = root.rotation_quaternion.copy()
        if previous is not None and q.dot(previous) < 0:  # keep quaternions continuous
            q.negate()
            root.rotation_quaternion = q
        previous = q
        number = frame_start + frame.index
        root.keyframe_insert("location", frame=number)
        root.keyframe_insert("rotation_quaternion", frame=number)
    numbers = [frame_start + f.index for f in rig.frames]
    scene.frame_start, scene.frame_end = min(numbers), max(numbers)
    scene.frame_set(scene.frame_start)


def _setup_views(scene, cams, result):
    render = scene.render
    render.use_multiview = True
    if len(cams) == 2 and cams[0].size == cams[1].size:
        for left, right in ((cams[0], cams[1]), (cams[1], cams[0])):
            ok, baseline = mapping.is_parallel_pair((left.K, left.R, left.c), (right.K, right.R, right.c))
            if ok:
                render.views_format = "STEREO_3D"
                for cam, pivot in ((left, "LEFT"), (right, "RIGHT")):
                    stereo = result.cameras[cam.name].data.stereo
                    stereo.convergence_mode = "PARALLEL"
                    stereo.interocular_distance = baseline
                    stereo.pivot = pivot
                scene.camera = result.cameras[left.name]
                result.stereo_mode = "STEREO_3D"
                return
    render.views_format = "MULTIVIEW"
    names = [c.name for c in cams]
    for view in render.views:
        view.use = view.name in names
    for cam in cams:
        view = render.views.get(cam.name) or render.views.new(cam.name)
        view.camera_suffix = f"_{cam.name}"
        view.use = True
    result.stereo_mode = "MULTIVIEW"


# --------------------------------------------------------------------------
# Plates, clips and colour.


def _plate_paths(rig, cams, use_rectified, plates, plate_directory, result):
    """Plate per camera: the first frame that has one, a plate folder, or ``plates``.

    The rig's plates are the images the cameras were solved on; rectified
    cameras take plates only from ``plates`` or ``plate_directory``.
    """
    paths = {}
    if use_rectified:
        if any(frame.images for frame in rig.frames):
            result.warnings.append("the rig's plates are not rectified: give rectified plates as a folder")
    else:
        for frame in sorted(rig.frames, key=lambda f: f.index):
            for name, path in frame.images.items():
                paths.setdefault(name, path)
    if plate_directory:
        for cam in cams:
            for ext in IMAGE_EXTENSIONS:
                candidate = os.path.join(plate_directory, cam.name + ext)
                if os.path.isfile(candidate):
                    paths[cam.name] = candidate
                    break
    for name, value in (plates or {}).items():
        paths[name] = os.fspath(value)
    return paths


def camera_colour_space(camera_name):
    """The name of camcal's input colour space for a camera, if the active OCIO config has it.

    camcal's exported configs name them ``camcal <camera name>`` (family
    ``Input/camcal``); ``None`` when the active config has no such space.
    """
    name = f"camcal {camera_name}"
    items = bpy.types.ColorManagedInputColorspaceSettings.bl_rna.properties["name"].enum_items
    return name if name in items.keys() else None


def _apply_colour_space(datablock, camera_name):
    space = camera_colour_space(camera_name)
    if space is not None:
        datablock.colorspace_settings.name = space
    return space


def _aux_folder(rig_path, aux_directory):
    if aux_directory:
        folder = aux_directory
    elif bpy.data.filepath:
        folder = os.path.join(os.path.dirname(bpy.data.filepath), "camcal_lens")
    else:
        folder = os.path.join(os.path.dirname(os.path.abspath(rig_path)), "camcal_lens")
    try:
        os.makedirs(folder, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=folder, delete=True)
        probe.close()
    except OSError:
        folder = tempfile.mkdtemp(prefix="camcal_lens_")
    return folder


def _blank_frame(name, size, rig_path, aux_directory):
    folder = _aux_folder(rig_path, aux_directory)
    path = os.path.join(folder, f"{bpy.path.clean_name(name)}_{size[0]}x{size[1]}.png")
    if not os.path.isfile(path):
        pngfile.write_grid_png(path, size[0], size[1])
    return path


def _load_clip(name, filepath):
    clip = bpy.data.movieclips.load(filepath)
    clip.name = name
    return clip


def _set_lens(clip, lens, sensor_width_mm):
    lens_animation.set_tracking_camera(clip, lens_animation.tracking_key(lens, sensor_width_mm))


def _tracking_lens(cam, margins, lens_model):
    try:
        return tracking.blender_lens(cam.distortion, cam.K, cam.size, margins, lens_model)
    except ValueError as error:
        raise RigFileError(f"camera {cam.name!r}: {error}") from None


def _lens_clip(cam, obj, plate, result, rig_path, aux_directory, scene, lens_model):
    lens = _tracking_lens(cam, (0, 0), lens_model)
    if not lens.exact:
        result.warnings.append(f"camera {cam.name!r}: lens is approximate in Blender: {lens.note}")
    clip = None
    if plate is not None:
        clip = _load_clip(f"{obj.name} lens", plate)
        if tuple(clip.size) != tuple(cam.size):
            result.warnings.append(
                f"plate of {cam.name!r} is {tuple(clip.size)}, the camera {tuple(cam.size)}: "
                "the lens clip uses a blank frame"
            )
            bpy.data.movieclips.remove(clip)
            clip = None
        else:
            _apply_colour_space(clip, cam.name)
    if clip is None:
        clip = _load_clip(f"{obj.name} lens", _blank_frame(obj.name, cam.size, rig_path, aux_directory))
    _set_lens(clip, lens, cam.sensor_width_mm)
    clip.frame_start = scene.frame_start
    obj.data["camcal_blender_lens"] = json.dumps(
        {"model": lens.distortion_model, "params": lens.params, "exact": lens.exact, "fit_max_px": lens.fit_max_px}
    )
    obj.data["camcal_clip"] = clip.name
    return clip


def _background(cam, obj, plate, clip):
    data = obj.data
    data.show_background_images = True
    bg = data.background_images.new()
    if clip is not None and clip.filepath and os.path.samefile(bpy.path.abspath(clip.filepath), plate):
        bg.source = "MOVIE_CLIP"
        bg.use_camera_clip = False
        bg.clip = clip
        bg.clip_user.use_render_undistorted = True
        return
    image = bpy.data.images.load(plate, check_existing=True)
    _apply_colour_space(image, cam.name)
    bg.source = "IMAGE"
    bg.image = image


def _point_cloud(rig, cloud, base, collection, root):
    points, colours = cloud
    mesh = bpy.data.meshes.new(f"{base} points")
    mesh.vertices.add(len(points))
    mesh.vertices.foreach_set("co", [v for p in points for v in p])
    if colours is not None:
        attr = mesh.color_attributes.new("Col", "FLOAT_COLOR", "POINT")
        attr.data.foreach_set("color", [v for c in colours for v in (c[0], c[1], c[2], 1.0)])
    mesh.update()
    obj = bpy.data.objects.new(f"{base} points", mesh)
    obj["camcal_points"] = rig.points
    collection.objects.link(obj)
    obj.parent = root
    obj.matrix_parent_inverse = Matrix.Identity(4)
    return obj


# --------------------------------------------------------------------------
# Compositor: distort the render with Movie Distortion, with overscan.


def _movie_distortion(tree, clip):
    node = tree.nodes.new("CompositorNodeMovieDistortion")
    node.clip = clip
    if "Type" in node.inputs:  # Blender 5.0
        node.inputs["Type"].default_value = "Distort"
    else:  # Blender 4.x
        node.distortion_type = "DISTORT"
    return node


def _copy_render_settings(src, dst):
    dst.render.engine = src.render.engine
    dst.render.pixel_aspect_x = src.render.pixel_aspect_x
    dst.render.pixel_aspect_y = src.render.pixel_aspect_y
    dst.render.resolution_percentage = 100
    dst.frame_start, dst.frame_end = src.frame_start, src.frame_end
    dst.world = src.world
    dst.view_settings.view_transform = src.view_settings.view_transform
    dst.view_settings.look = src.view_settings.look
    if hasattr(src, "cycles") and hasattr(dst, "cycles"):
        dst.cycles.samples = src.cycles.samples


def _distortion_setup(scene, cam, obj, overscan, result, rig_path, aux_directory, lens_model, uv_map=None):
    """An overscan render scene and a scene whose compositor distorts it.

    ``<camera> overscan``: renders the main scene (as its background set)
    through a child camera with the same pixel scale on a frame enlarged
    by whole-pixel margins. ``<camera> distorted``: its compositor takes that
    render through Movie Distortion with a clip whose lens is expressed on
    the enlarged frame, then a Translate node that cancels the integer offset
    Blender's Movie Distortion adds when it grows or shrinks the image; the
    output is the camera's own frame (``W x H``), centred. With ``uv_map``
    (an EXR of the camera's frame whose R, G are the U, V of the overscan
    render to sample) a Map UV node (bilinear) replaces Movie Distortion and
    Translate: camcal's own lens, any model.
    """
    W, H = cam.size
    mx, my = tracking.overscan_margins(cam.size, overscan)
    size_os = (W + 2 * mx, H + 2 * my)
    K = cam.K
    K_os = ((K[0][0], K[0][1], K[0][2] + mx), (0.0, K[1][1], K[1][2] + my), (0.0, 0.0, 1.0))
    b = mapping.blender_intrinsics(K_os, size_os, cam.sensor_width_mm * size_os[0] / W, obj.data.sensor_fit)
    os_data = bpy.data.cameras.new(f"{obj.name}_overscan")
    _set_intrinsics(os_data, b)
    os_data.clip_start, os_data.clip_end = obj.data.clip_start, obj.data.clip_end
    os_obj = bpy.data.objects.new(f"{obj.name}_overscan", os_data)
    os_obj.parent = obj
    os_obj.matrix_parent_inverse = Matrix.Identity(4)
    os_obj.hide_render = True

    os_scene = bpy.data.scenes.new(f"{obj.name} overscan")
    os_scene.background_set = scene
    os_scene.collection.objects.link(os_obj)
    os_scene.camera = os_obj
    _copy_render_settings(scene, os_scene)
    os_scene.render.resolution_x, os_scene.render.resolution_y = size_os
    os_scene.render.use_compositing = False
    os_scene["camcal_overscan_margins"] = [mx, my]

    lens = _tracking_lens(cam, (mx, my), lens_model)
    clip = _load_clip(
        f"{obj.name} lens overscan", _blank_frame(f"{obj.name}_overscan", size_os, rig_path, aux_directory)
    )
    _set_lens(clip, lens, cam.sensor_width_mm * size_os[0] / W)

    dist_scene = bpy.data.scenes.new(f"{obj.name} distorted")
    _copy_render_settings(scene, dist_scene)
    dist_scene.render.resolution_x, dist_scene.render.resolution_y = W, H
    dist_scene.camera = os_obj
    tree, out = compositor.new_compositor_tree(dist_scene, f"{obj.name} distort")
    layers = tree.nodes.new("CompositorNodeRLayers")
    layers.scene = os_scene
    # Blender scales another scene's render to this scene's width (one factor
    # for both axes); undo it so Movie Distortion sees the overscan frame's pixels.
    unscale = tree.nodes.new("CompositorNodeScale")
    unscale.inputs["Type"].default_value = "Relative"
    unscale.inputs["X"].default_value = size_os[0] / W
    unscale.inputs["Y"].default_value = size_os[0] / W
    tree.links.new(layers.outputs["Image"], unscale.inputs["Image"])
    if uv_map is not None:
        chain = _map_uv(tree, uv_map, (W, H))
        dist_scene["camcal_uv_map"] = uv_map
    else:
        md = _movie_distortion(tree, clip)
        shift = distortion_shift(clip, lens, (mx, my), (W, H))
        translate = tree.nodes.new("CompositorNodeTranslate")
        translate.inputs["X"].default_value = shift[0]
        translate.inputs["Y"].default_value = shift[1]
        tree.links.new(md.outputs["Image"], translate.inputs["Image"])
        chain = (md, translate)
        dist_scene["camcal_distortion_shift_px"] = list(shift)
    tree.links.new(unscale.outputs["Image"], chain[0].inputs["Image"])
    tree.links.new(chain[-1].outputs["Image"], out.inputs[0])
    for i, node in enumerate((layers, unscale, *chain, out)):
        node.location = (i * 250.0, 0.0)
    obj.data["camcal_distorted_scene"] = dist_scene.name
    return dist_scene


def _map_uv(tree, path, size):
    """A Map UV node (bilinear) whose UV is the EXR at ``path`` (data, no colour transform); ``(node,)``."""
    image = bpy.data.images.load(path, check_existing=True)
    image.colorspace_settings.is_data = True
    if tuple(image.size) != tuple(size):
        raise RigFileError(f"UV map {path} is {tuple(image.size)}, the camera {tuple(size)}")
    uv = tree.nodes.new("CompositorNodeImage")
    uv.image = image
    node = tree.nodes.new("CompositorNodeMapUV")
    node.inputs["Interpolation"].default_value = "Bilinear"
    tree.links.new(uv.outputs["Image"], node.inputs["UV"])
    uv.location = (500.0, -250.0)
    return (node,)


def distortion_shift(clip, lens, margins, size):
    """The offset (Blender pixels, x right, y up) Movie Distortion adds, measured.

    Blender's Movie Distortion grows or shrinks its output by the distorted
    bounds of the frame and re-centres it, which moves the picture by a
    whole number of pixels that depends on the lens and the frame (1 px
    even at k = 0, from the bounds' rounding). This runs the node once on a
    coordinate ramp in a throw-away scene and compares the coordinates it
    reads back with Blender's formula for ``lens`` (a
    :class:`.tracking.BlenderLens` on the overscan frame,
    :func:`.tracking.blender_distort`): the difference is the offset.
    """
    import numpy as np  # Blender's bundled numpy; only the bpy layer uses it

    W, H = size
    mx, my = margins
    Wo, Ho = W + 2 * mx, H + 2 * my
    ramp = bpy.data.images.new("camcal ramp", Wo, Ho, alpha=True, float_buffer=True)
    xs = (np.arange(Wo, dtype=np.float64) + 0.5) / Wo
    ys = (np.arange(Ho, dtype=np.float64) + 0.5) / Ho
    pixels = np.ones((Ho, Wo, 4), dtype=np.float32)
    pixels[:, :, 0] = xs[None, :]
    pixels[:, :, 1] = ys[:, None]
    pixels[:, :, 2] = 0.0
    ramp.pixels.foreach_set(pixels.ravel())
    ramp.update()
    probe = bpy.data.scenes.new("camcal shift probe")
    folder = tempfile.mkdtemp(prefix="camcal_shift_")
    cam_obj = None
    try:
        probe.render.engine = "CYCLES"
        probe.cycles.samples = 1
        probe.render.resolution_x, probe.render.resolution_y = W, H
        probe.render.resolution_percentage = 100
        probe.view_settings.view_transform = "Standard"
        cam_obj = bpy.data.objects.new("camcal shift probe", bpy.data.cameras.new("camcal shift probe"))
        probe.collection.objects.link(cam_obj)
        probe.camera = cam_obj
        tree, out = compositor.new_compositor_tree(probe, "camcal shift probe")
        image = tree.nodes.new("CompositorNodeImage")
        image.image = ramp
        md = _movie_distortion(tree, clip)
        tree.links.new(image.outputs["Image"], md.inputs["Image"])
        tree.links.new(md.outputs["Image"], out.inputs[0])
        probe.render.image_settings.file_format = "OPEN_EXR"
        probe.render.image_settings.color_depth = "32"
        probe.render.filepath = os.path.join(folder, "shift.exr")
        bpy.ops.render.render(write_still=True, scene=probe.name)
        result = bpy.data.images.load(probe.render.filepath)
        out_px = np.empty(W * H * 4, dtype=np.float32)
        result.pixels.foreach_get(out_px)
        out_px = out_px.reshape(H, W, 4)
        bpy.data.images.remove(result)
        # Sample pixels around the centre (well inside the frame).
        shifts = []
        for fy in (0.4, 0.5, 0.6):
            for fx in (0.4, 0.5, 0.6):
                j, i = int(H * fy), int(W * fx)
                qx, qy = float(out_px[j, i, 0]) * Wo, float(out_px[j, i, 1]) * Ho
                # q is where Blender sampled the undistorted render (overscan frame, edges, y up).
                ideal = tracking.from_blender_pixel((qx, qy), Ho)
                d = tracking.to_blender_pixel(tracking.blender_distort(lens, ideal), Ho)
                shifts.append((d[0] - (i + 0.5 + mx), d[1] - (j + 0.5 + my)))
        sx = sum(s[0] for s in shifts) / len(shifts)
        sy = sum(s[1] for s in shifts) / len(shifts)
    finally:
        tree = compositor.compositor_tree(probe) if compositor.tree_is_a_node_group(probe) else None
        bpy.data.scenes.remove(probe)
        if tree is not None:
            bpy.data.node_groups.remove(tree)
        if cam_obj is not None:
            camera_data = cam_obj.data
            bpy.data.objects.remove(cam_obj)
            bpy.data.cameras.remove(camera_data)
        bpy.data.images.remove(ramp)
        for name in os.listdir(folder):
            os.unlink(os.path.join(folder, name))
        os.rmdir(folder)
    # The offset is a whole number of pixels; keep measured fractions only if large.
    rx, ry = round(sx), round(sy)
    return (float(rx) if abs(sx - rx) < 0.05 else sx, float(ry) if abs(sy - ry) < 0.05 else sy)
