"""The operator that solves a Movie Clip with camcal and brings the camera into the scene.

``camcal.solve_clip`` runs ``camcal solve`` (:mod:`.solvejob`: the executable
from the add-on's preferences or the PATH, in a subprocess) on the clip's
image sequence or movie, every frame of the clip. Invoked from the panel it
is modal: a timer polls the run, the status bar shows the elapsed time, the
stage and its share, the window manager's progress the same share; Esc
cancels (the run is stopped and its partial output removed). Run from a
script (``execute``) it waits for the run. On success the rig is imported
with :func:`.reimport.import_in_place` (a second solve of the same clip
replaces the first) at the clip's frames (rig frame ``k`` on the scene frame
that shows the clip's ``k``-th frame), and the clip itself becomes the
camera's background and carries the solved lens in its tracking camera.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from . import reimport, solvejob
from .operators import UP_AXIS_ITEMS, preferences
from .rigfile import RigFileError

__all__ = ["CAMCAL_OT_solve_clip", "clip_source", "attach_clip", "register", "unregister", "classes"]

MATCHER_ITEMS = (
    ("sequential", "Sequential", "Match each frame with its neighbours in frame order (plates)"),
    ("exhaustive", "Exhaustive", "Match every pair of frames (short clips, shots that revisit)"),
)
MODEL_ITEMS = (
    ("auto", "Auto", "camcal chooses the lens model by held-out residual"),
    ("division", "Division", "One-parameter division model"),
    ("polynomial", "Polynomial", "Radial k1, k2"),
    ("opencv", "OpenCV", "k1, k2, p1, p2, k3"),
    ("none", "None", "No distortion"),
)
# the tracking camera's settings in an order in which each stays as set (units before the values in them)
_LENS_FIRST = ("units", "sensor_width", "pixel_aspect", "distortion_model")
_LENS_LAST = ("focal_length_pixels", "principal_point_pixels")
_LENS_DUPLICATES = ("focal_length", "principal_point")  # the same values in other units


def clip_source(clip, camera):
    """What camcal reads of ``clip`` (:class:`.solvejob.ClipSource`), the rig camera named ``camera``."""
    path = bpy.path.abspath(clip.filepath, library=clip.library)
    if not os.path.isfile(path):
        raise solvejob.SolveError(f"the file of clip {clip.name!r} was not found: {path}")
    if clip.source == "SEQUENCE":
        _, first = solvejob.sequence_pattern(path)
        return solvejob.ClipSource(path, "SEQUENCE", first, clip.frame_duration, camera)
    return solvejob.ClipSource(path, "MOVIE", 0, clip.frame_duration, camera)


def _copy_lens(source, target):
    """The tracking camera (and its animation) of clip ``source`` onto clip ``target``."""
    src, dst = source.tracking.camera, target.tracking.camera
    names = [p.identifier for p in src.bl_rna.properties if not p.is_readonly and p.identifier != "rna_type"]
    middle = [n for n in names if n not in _LENS_FIRST + _LENS_LAST + _LENS_DUPLICATES]
    for name in (*_LENS_FIRST, *middle, *_LENS_LAST):
        setattr(dst, name, getattr(src, name))
    if source.animation_data is not None and source.animation_data.action is not None:
        target.animation_data_create().action = source.animation_data.action


def attach_clip(result, clip, scene):
    """Make ``clip`` the solved camera's lens clip and background (instead of the importer's blank-frame clip).

    The importer's lens clip of the camera (the solved lens on a blank frame)
    is copied onto ``clip``'s tracking camera and removed; ``clip`` is tagged
    as the user's (:data:`.reimport.SOURCE_CLIP`: a re-import keeps it), shown
    undistorted behind the camera and made the scene's active clip; a movie's
    frame rate becomes the scene's.
    """
    name, obj = next(iter(result.cameras.items()))
    lens_clip = result.clips.get(name)
    if lens_clip is not None and lens_clip != clip:
        _copy_lens(lens_clip, clip)
        bpy.data.movieclips.remove(lens_clip)
        result.clips[name] = clip
        obj.data["camcal_clip"] = clip.name
    clip[reimport.SOURCE_CLIP] = True
    data = obj.data
    data.show_background_images = True
    background = data.background_images.new()
    background.source = "MOVIE_CLIP"
    background.use_camera_clip = False
    background.clip = clip
    background.clip_user.use_render_undistorted = lens_clip is not None
    scene.active_clip = clip
    if clip.fps > 0:  # a movie's own rate (an image sequence plays at the scene's)
        scene.render.fps = max(1, round(clip.fps))
        scene.render.fps_base = scene.render.fps / clip.fps
    return obj


class CAMCAL_OT_solve_clip(bpy.types.Operator):
    """Solve the camera of a Movie Clip with camcal (in a subprocess) and import it into this scene"""

    bl_idname = "camcal.solve_clip"
    bl_label = "Solve Movie Clip"
    bl_options = {"REGISTER", "UNDO"}

    clip: StringProperty(name="Movie Clip", description="The clip to solve (default: the scene's active clip)")
    features: IntProperty(name="Features", default=8192, min=100, description="SIFT features per frame")
    matcher: EnumProperty(name="Matching", items=MATCHER_ITEMS, default="sequential")
    model: EnumProperty(name="Lens model", items=MODEL_ITEMS, default="auto")
    up_axis: EnumProperty(name="Up axis", items=UP_AXIS_ITEMS, default="Z")
    compositor: BoolProperty(name="Distortion compositor", default=True,
                             description="Scenes that distort the render with the solved lens")
    output_directory: StringProperty(
        name="Output folder", subtype="DIR_PATH", default="",
        description="Where camcal writes the solve (default: the add-on's preferences, else camcal_solve "
        "beside the saved .blend, else beside the clip)",
    )

    @classmethod
    def poll(cls, context):
        return len(bpy.data.movieclips) > 0

    def _target_clip(self, context):
        clip = bpy.data.movieclips.get(self.clip) if self.clip else context.scene.active_clip
        if clip is None:
            raise solvejob.SolveError(f"no Movie Clip named {self.clip!r}" if self.clip
                                      else "no active Movie Clip in the scene: open a clip or name one")
        return clip

    def _output(self, context, clip, source):
        prefs = preferences(context)
        folder = (bpy.path.abspath(self.output_directory) or bpy.path.abspath(getattr(prefs, "solve_directory", ""))
                  or (bpy.path.abspath("//camcal_solve") if bpy.data.filepath
                      else os.path.join(os.path.dirname(source.path), "camcal_solve")))
        return os.path.join(os.path.abspath(folder), source.name)

    def _start(self, context):
        """Check the input, then start camcal; the job."""
        clip = self._target_clip(context)
        source = clip_source(clip, solvejob.camera_name(clip.name))
        executable = solvejob.find_camcal(bpy.path.abspath(getattr(preferences(context), "camcal_executable", "")))
        out = self._output(context, clip, source)
        command = solvejob.solve_command(executable, source, out, features=self.features, matcher=self.matcher,
                                         model=self.model)
        self._clip_name = clip.name
        self._frame_start = clip.frame_start - clip.frame_offset  # the scene frame that shows the clip's first
        job = solvejob.SolveJob(command, out)
        job.start()
        return job

    def execute(self, context):
        """Solve and import, waiting for camcal (scripts, background Blender)."""
        try:
            job = self._start(context)
        except solvejob.SolveError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        job.wait()
        return self._finish(context, job)

    def invoke(self, context, event):
        if context.window is None:
            return self.execute(context)
        try:
            self._job = self._start(context)
        except solvejob.SolveError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        self._status(context, self._job.status_text())
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self.cancel(context)
            self.report({"INFO"}, "camcal solve cancelled: nothing was written")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not self._job.poll():
            self._status(context, self._job.status_text())
            context.window_manager.progress_update(round(100 * self._job.fraction))
            return {"PASS_THROUGH"}
        self._end_ui(context)
        return self._finish(context, self._job)

    def cancel(self, context):
        """Esc, or Blender ending the operator (a file loaded, the window closed): stop camcal, remove its output."""
        self._job.cancel()
        self._end_ui(context)

    def _status(self, context, text):
        if context.workspace is not None:
            context.workspace.status_text_set(text)

    def _end_ui(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        self._status(context, None)

    def _finish(self, context, job):
        """Import the solve into the scene, with the clip as the camera's lens and background."""
        clip = bpy.data.movieclips.get(self._clip_name)
        try:
            summary = job.summary()
            rig = job.rig_path()
            if clip is None:
                raise solvejob.SolveError(f"the Movie Clip {self._clip_name!r} was removed during the solve")
            result, replaced = reimport.import_in_place(
                context.scene, rig, up_axis=self.up_axis, frame_start=self._frame_start, import_plates=False,
                compositor=self.compositor,
                aux_directory=bpy.path.abspath(getattr(preferences(context), "lens_directory", "")) or None)
            obj = attach_clip(result, clip, context.scene)
        except (solvejob.SolveError, RigFileError, OSError, ValueError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        for warning in result.warnings:
            self.report({"WARNING"}, warning)
        figures = summary.get("figures", {})
        self.report({"INFO"}, f"solved {clip.name!r}: {figures.get('n_registered')} / {figures.get('n_images')} "
                    f"frames registered, RMS {figures.get('rms_px', float('nan')):.3g} px; camera {obj.name!r}"
                    + (" (the earlier solve replaced)" if replaced else ""))
        return {"FINISHED"}


classes = (CAMCAL_OT_solve_clip,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
