"""Operators: glue between the UI and :func:`.importer.import_rig`."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from . import importer, overlay, reimport
from .rigfile import RigFileError

__all__ = ["register", "unregister", "classes", "preferences", "UP_AXIS_ITEMS"]

UP_AXIS_ITEMS = (
    ("Z", "Z up", "The rig's world z axis points up"),
    ("-Y", "-Y up", "The rig's world y axis points down (OpenCV-style world)"),
    ("Y", "Y up", "The rig's world y axis points up"),
)
SENSOR_FIT_ITEMS = (
    ("AUTO", "Auto", "Blender's automatic fit (exact as well)"),
    ("HORIZONTAL", "Horizontal", "Fit the sensor width to the image width"),
    ("VERTICAL", "Vertical", "Fit the sensor height to the image height"),
)


class CamcalRigPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    lens_directory: StringProperty(
        name="Lens frames folder", subtype="DIR_PATH", default="",
        description="Where blank lens frames for movie clips are written "
        "(default: beside the saved .blend, else beside the rig file)",
    )

    camcal_executable: StringProperty(
        name="camcal executable", subtype="FILE_PATH", default="",
        description="The camcal command that solves Movie Clips (default: camcal on the PATH)",
    )
    solve_directory: StringProperty(
        name="Solve folder", subtype="DIR_PATH", default="",
        description="Where Movie Clip solves are written, one folder per clip "
        "(default: camcal_solve beside the saved .blend, else beside the clip)",
    )

    def draw(self, context):
        self.layout.prop(self, "lens_directory")
        self.layout.prop(self, "camcal_executable")
        self.layout.prop(self, "solve_directory")


def preferences(context):
    """The add-on's preferences (None when it is loaded without being enabled, as in tests)."""
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon is not None else None


def _camcal_camera(obj):
    return obj is not None and obj.type == "CAMERA" and "camcal_image_size" in obj.data


class IMPORT_SCENE_OT_camcal_rig(bpy.types.Operator, ImportHelper):
    """Import a camera rig solved by camcal (*.rig.json)"""

    bl_idname = "import_scene.camcal_rig"
    bl_label = "Import camcal rig"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.rig.json;*.json", options={"HIDDEN"})

    up_axis: EnumProperty(name="Up axis", items=UP_AXIS_ITEMS, default="Z")
    sensor_fit: EnumProperty(name="Sensor fit", items=SENSOR_FIT_ITEMS, default="AUTO")
    use_rectified: BoolProperty(name="Rectified cameras", default=False,
                                description="Import the rectified cameras and plates")
    import_plates: BoolProperty(name="Plates", default=True,
                                description="Camera background images from the rig's frames")
    plate_directory: StringProperty(name="Plate folder", subtype="DIR_PATH", default="",
                                    description="Folder of <camera name>.<ext> plates (optional)")
    import_points: BoolProperty(name="Sparse points", default=True)
    stereo: BoolProperty(name="Stereo / multi-view", default=True)
    distortion: BoolProperty(name="Lens distortion clips", default=True)
    compositor: BoolProperty(name="Distortion compositor", default=True,
                             description="Scenes that distort the render with Movie Distortion")
    overscan: FloatProperty(name="Overscan", default=1.1, min=1.0, max=2.0)
    replace_previous: BoolProperty(name="Replace earlier import", default=True,
                                   description="Replace this rig's earlier import in the scene, in place")

    def execute(self, context):
        try:
            result, replaced = reimport.import_in_place(
                context,
                self.filepath,
                up_axis=self.up_axis,
                sensor_fit=self.sensor_fit,
                use_rectified=self.use_rectified,
                import_plates=self.import_plates,
                plate_directory=bpy.path.abspath(self.plate_directory) or None,
                import_points=self.import_points,
                stereo=self.stereo,
                distortion=self.distortion,
                compositor=self.compositor,
                overscan=self.overscan,
                aux_directory=bpy.path.abspath(getattr(preferences(context), "lens_directory", "")) or None,
                replace=self.replace_previous,
            )
        except (RigFileError, OSError, ValueError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        for warning in result.warnings:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"{'re-imported' if replaced else 'imported'} rig {result.rig.name!r}: "
                    f"{len(result.cameras)} camera(s)")
        return {"FINISHED"}


class CAMCAL_OT_set_active_camera(bpy.types.Operator):
    """Make this camcal camera the scene camera, with its resolution, and look through it"""

    bl_idname = "camcal.set_active_camera"
    bl_label = "Set active camera"
    bl_options = {"REGISTER", "UNDO"}

    camera: StringProperty(name="Camera object")
    view: BoolProperty(name="Look through", default=True)

    def execute(self, context):
        obj = bpy.data.objects.get(self.camera)
        if not _camcal_camera(obj):
            self.report({"ERROR"}, f"{self.camera!r} is not a camera imported by camcal")
            return {"CANCELLED"}
        context.scene.camera = obj
        importer.apply_resolution(context.scene, obj)
        space = context.space_data
        if self.view and space is not None and space.type == "VIEW_3D":
            space.region_3d.view_perspective = "CAMERA"
        return {"FINISHED"}


class CAMCAL_OT_apply_resolution(bpy.types.Operator):
    """Set the render size and pixel aspect to those of the active camcal camera"""

    bl_idname = "camcal.apply_resolution"
    bl_label = "Re-apply resolution"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _camcal_camera(context.scene.camera)

    def execute(self, context):
        importer.apply_resolution(context.scene, context.scene.camera)
        return {"FINISHED"}


class CAMCAL_OT_toggle_stereo(bpy.types.Operator):
    """Switch stereo / multi-view rendering on or off"""

    bl_idname = "camcal.toggle_stereo"
    bl_label = "Toggle stereo"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        render = context.scene.render
        render.use_multiview = not render.use_multiview
        return {"FINISHED"}


#: Name of the background image slot a sigma overlay takes (one per camera).
SIGMA_OVERLAY = "camcal sigma"


def show_sigma_overlay(obj, path, alpha=0.6):
    """Show a sigma map (PNG heat map or EXR) as ``obj``'s background overlay, in front of its plate.

    The map must be the camera's image size (:func:`.overlay.check_overlay`): it is stretched onto the
    camera frame, pixel for pixel with the plate. A previous sigma overlay of the camera is replaced.
    Returns the background image entry.
    """
    overlay.check_overlay(path, tuple(obj.data["camcal_image_size"]))
    data = obj.data
    for bg in list(data.background_images):
        if bg.image is not None and bg.image.get("camcal_overlay") == SIGMA_OVERLAY:
            data.background_images.remove(bg)
    image = bpy.data.images.load(path, check_existing=False)
    image["camcal_overlay"] = SIGMA_OVERLAY
    image.colorspace_settings.name = "sRGB" if path.lower().endswith(".png") else "Non-Color"
    worst = overlay.sigma_max(path)
    if worst is not None:
        image["camcal_sigma_max_px"] = worst
    data.show_background_images = True
    bg = data.background_images.new()
    bg.source = "IMAGE"
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    bg.frame_method = "STRETCH"
    return bg


class CAMCAL_OT_sigma_overlay(bpy.types.Operator, ImportHelper):
    """Show a camera's projection-sigma map (camcal sigma --heatmap PNG, or its EXR) over its view"""

    bl_idname = "camcal.sigma_overlay"
    bl_label = "Show sigma map"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".png"
    filter_glob: StringProperty(default="*.png;*.exr", options={"HIDDEN"})
    camera: StringProperty(name="Camera object", description="Default: the scene camera")
    alpha: FloatProperty(name="Opacity", default=0.6, min=0.0, max=1.0)

    def execute(self, context):
        obj = bpy.data.objects.get(self.camera) if self.camera else context.scene.camera
        if not _camcal_camera(obj):
            self.report({"ERROR"}, f"{self.camera or 'the scene camera'!r} is not a camera imported by camcal")
            return {"CANCELLED"}
        try:
            show_sigma_overlay(obj, bpy.path.abspath(self.filepath), self.alpha)
        except (overlay.OverlayError, OSError, RuntimeError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self.report({"INFO"}, f"sigma map shown on {obj.name!r}")
        return {"FINISHED"}


def menu_import(self, context):
    self.layout.operator(IMPORT_SCENE_OT_camcal_rig.bl_idname, text="camcal rig (.rig.json)")


classes = (
    CamcalRigPreferences,
    IMPORT_SCENE_OT_camcal_rig,
    CAMCAL_OT_set_active_camera,
    CAMCAL_OT_apply_resolution,
    CAMCAL_OT_toggle_stereo,
    CAMCAL_OT_sigma_overlay,
)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
