"""Per-frame lenses in Blender (a zoom, a rack focus): keyed camera intrinsics and the tracking lens per frame.

A rig whose frames carry a camera's lens (``frames[i].lenses``, read by
:mod:`.rigfile`) is imported with, for that camera:

- the Blender camera's ``lens``, ``shift_x`` and ``shift_y`` keyed on every
  rig frame (Blender frame ``frame_start + index``, as the rig root's pose
  keys), from :func:`.mapping.blender_intrinsics` of that frame's ``K``, so
  the camera projects like camcal's ``camera_at_frame`` at each frame; the
  overscan render camera of the compositor set-up likewise;
- the lens clip's tracking camera (focal length, principal point and
  distortion coefficients) set per frame. Blender cannot key these: a
  MovieClip's tracking-camera properties are not animatable (Blender 4.2 to
  5.2 refuse ``keyframe_insert`` and ``driver_add`` on them). Each frame's
  lens (:func:`.tracking.blender_lens`) is stored on the clip as the custom
  property ``camcal_lens_keys`` (JSON: Blender frame -> the tracking camera's
  settings), and a frame-change handler (:func:`apply_lens_keys`, registered
  with the add-on and by the import) sets the tracking camera to the key at
  the current frame, or the last key before it, on every frame change,
  playback and render included.

The sensor size is the first frame's. A lens whose pixel aspect (``fy / fx``)
changes over the shot (a profile fitted from boards gives each state its own)
has its render pixel aspect per frame too: Blender cannot key the scene's
``render.pixel_aspect_x/y`` (not animatable), so each frame's is stored on the
camera as ``camcal_pixel_aspect_keys`` and the same handler sets the scene's
render pixel aspect from its active camera's keys. A skew (Blender has none)
is imported with a warning. The compositor's Translate offset after Movie Distortion
(:func:`.importer.distortion_shift`) is measured on the camera's own lens.
A Kannala-Brandt lens (Cycles' fisheye camera) keeps the camera's own
polynomial, said in a warning. Rectified imports (fixed ``K_rect``) take no per-frame lens.
"""

from __future__ import annotations

import json

import bpy
from bpy.app.handlers import persistent

from . import compositor, mapping, rigfile, tracking

__all__ = ["ASPECT_KEYS", "LENS_KEYS", "animate_lenses", "apply_lens_keys", "ensure_handler", "register",
           "set_tracking_camera", "tracking_key", "unregister"]

#: The custom property of a MovieClip holding its tracking camera per Blender frame.
LENS_KEYS = "camcal_lens_keys"
#: The custom property of a Blender camera holding the render's pixel aspect per Blender frame.
ASPECT_KEYS = "camcal_pixel_aspect_keys"


def tracking_key(lens, sensor_width_mm):
    """The tracking camera's settings of a :class:`.tracking.BlenderLens` (as :data:`LENS_KEYS` stores them)."""
    return {"sensor_width": sensor_width_mm, "focal_length_pixels": lens.focal_length_pixels,
            "principal_point_pixels": list(lens.principal_point_pixels), "distortion_model": lens.distortion_model,
            "params": dict(lens.params)}


def set_tracking_camera(clip, key):
    """Set a clip's tracking camera from :func:`tracking_key`'s settings."""
    camera = clip.tracking.camera
    camera.sensor_width = key["sensor_width"]
    camera.pixel_aspect = 1.0
    camera.units = "PIXELS"
    camera.focal_length_pixels = key["focal_length_pixels"]
    camera.distortion_model = key["distortion_model"]
    for name, value in key["params"].items():
        setattr(camera, name, value)
    camera.principal_point_pixels = key["principal_point_pixels"]


def _key_at(keys, frame):
    """The key at ``frame``, else the last one before it, else the first (keys: {frame number as text: key})."""
    frames = sorted(int(f) for f in keys)
    before = [f for f in frames if f <= frame]
    return keys[str(before[-1] if before else frames[0])]


@persistent
def apply_lens_keys(scene, *_):
    """Frame-change handler: every clip with :data:`LENS_KEYS` gets its tracking camera at ``scene``'s frame, and
    ``scene``'s render its active camera's pixel aspect (:data:`ASPECT_KEYS`) there."""
    for clip in bpy.data.movieclips:
        if LENS_KEYS in clip:
            set_tracking_camera(clip, _key_at(json.loads(clip[LENS_KEYS]), scene.frame_current))
    camera = scene.camera
    if camera is not None and camera.type == "CAMERA" and ASPECT_KEYS in camera.data:
        aspect_x, aspect_y = _key_at(json.loads(camera.data[ASPECT_KEYS]), scene.frame_current)
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect_x, aspect_y


def ensure_handler():
    """Register :func:`apply_lens_keys` once (the import calls it; so does the add-on's ``register``)."""
    handlers = bpy.app.handlers.frame_change_pre
    if not any(getattr(h, "__name__", "") == apply_lens_keys.__name__ and getattr(h, "__module__", "") == __name__
               for h in handlers):
        handlers.append(apply_lens_keys)


def register():
    """Register the frame-change handler (with the add-on, so that a saved .blend's zoom plays back when reopened)."""
    ensure_handler()


def unregister():
    """Remove this module's frame-change handler."""
    handlers = bpy.app.handlers.frame_change_pre
    for handler in [h for h in handlers if getattr(h, "__module__", "") == __name__]:
        handlers.remove(handler)


def _key_intrinsics(data, K, size, sensor_width_mm, frame_number):
    b = mapping.blender_intrinsics(K, size, sensor_width_mm, data.sensor_fit)
    data.lens, data.shift_x, data.shift_y = b.lens, b.shift_x, b.shift_y
    for name in ("lens", "shift_x", "shift_y"):
        data.keyframe_insert(name, frame=frame_number)
    return b


def _overscan_parts(dist_scene):
    """The overscan camera and the clip of the Movie Distortion node of a ``<camera> distorted`` scene."""
    tree = compositor.compositor_tree(dist_scene)
    clips = [node.clip for node in tree.nodes if node.bl_idname == "CompositorNodeMovieDistortion"]
    return dist_scene.camera, (clips[0] if clips else None)


def animate_lenses(rig, cams, result, frame_start, lens_model, overscan):
    """Key each camera with per-frame lenses (see the module docstring); warnings go to ``result.warnings``.

    Parameters
    ----------
    rig : rigfile.Rig
    cams : sequence
        The imported cameras (name, size, sensor width, distortion), as :func:`.importer.import_rig` built them.
    result : importer.ImportResult
        Its cameras, clips and distorted scenes are keyed.
    frame_start : int
        Blender frame of rig frame index 0.
    lens_model : str or None
        The tracking camera's model (:func:`.tracking.blender_lens`).
    overscan : float
        The compositor set-up's overscan factor (its margins).
    """
    keyed = False
    for cam in cams:
        frames = sorted(rig.frames, key=lambda f: f.index)
        if not rig.lens_frames(cam.name):
            continue
        obj = result.cameras[cam.name]
        clip = result.clips.get(cam.name)
        dist_scene = result.distorted_scenes.get(cam.name)
        os_obj, os_clip = _overscan_parts(dist_scene) if dist_scene is not None else (None, None)
        W, H = cam.size
        mx, my = tracking.overscan_margins(cam.size, overscan)
        clip_keys, os_keys, aspect_keys, skewed, worst_fit = {}, {}, {}, False, 0.0
        for frame in frames:
            number = frame_start + frame.index
            K, distortion = rig.lens_at(cam.name, frame)
            b = _key_intrinsics(obj.data, K, cam.size, cam.sensor_width_mm, number)
            aspect_keys[str(number)] = [b.pixel_aspect_x, b.pixel_aspect_y]
            skewed = skewed or abs(b.skew) > 1e-9 * K[0][0]
            if os_obj is not None:
                K_os = ((K[0][0], K[0][1], K[0][2] + mx), (0.0, K[1][1], K[1][2] + my), (0.0, 0.0, 1.0))
                _key_intrinsics(os_obj.data, K_os, (W + 2 * mx, H + 2 * my),
                                cam.sensor_width_mm * (W + 2 * mx) / W, number)
            if distortion.model == "none" or distortion.model in rigfile.FISHEYE_MODELS:
                continue
            try:
                lens = tracking.blender_lens(distortion, K, cam.size, (0, 0), lens_model)
                os_lens = tracking.blender_lens(distortion, K, cam.size, (mx, my), lens_model)
            except ValueError as error:
                raise rigfile.RigFileError(f"camera {cam.name!r} at frame {frame.index}: {error}") from None
            worst_fit = max(worst_fit, lens.fit_max_px)
            clip_keys[str(number)] = tracking_key(lens, cam.sensor_width_mm)
            os_keys[str(number)] = tracking_key(os_lens, cam.sensor_width_mm * (W + 2 * mx) / W)
        for target, keys in ((clip, clip_keys), (os_clip, os_keys)):
            if target is not None and keys:
                target[LENS_KEYS] = json.dumps(keys)
                keyed = True
        if len({tuple(aspect) for aspect in aspect_keys.values()}) > 1:
            for camera_object in (obj, os_obj):
                if camera_object is not None:
                    camera_object.data[ASPECT_KEYS] = json.dumps(aspect_keys)
            keyed = True
        if skewed:
            result.warnings.append(f"camera {cam.name!r}: its lens has skew over the shot; Blender has none")
        if worst_fit > 0.0:
            result.warnings.append(f"camera {cam.name!r}: the per-frame tracking lenses are fits, worst "
                                   f"{worst_fit:.3g} px over the frames")
        if cam.distortion.model in rigfile.FISHEYE_MODELS:
            result.warnings.append(f"camera {cam.name!r}: Cycles' fisheye polynomial is the camera's own lens "
                                   "(the per-frame fisheye lenses are not keyed)")
        if dist_scene is not None and "camcal_uv_map" in dist_scene:
            result.warnings.append(f"camera {cam.name!r}: the compositor re-distorts with the camera's own lens "
                                   "(its exact UV map is of one lens); render the zoom's frames through its ST-maps")
        elif dist_scene is not None:
            result.warnings.append(f"camera {cam.name!r}: the compositor's Movie Distortion offset is measured on "
                                   "the camera's own lens")
        obj.data["camcal_lens_frames"] = len(rig.lens_frames(cam.name))
    if keyed:
        ensure_handler()
        apply_lens_keys(result.scene)
