"""The View3D sidebar panel (tab "camcal")."""

import json

import bpy

__all__ = ["register", "unregister", "classes"]


def _quality_text(data):
    """'RMS 0.21 px, sigma.fx ±0.3' style summary of a camera's stored quality."""
    parts = []
    if "camcal_rms_px" in data:
        parts.append(f"RMS {data['camcal_rms_px']:.3g} px")
    try:
        quality = json.loads(data.get("camcal_quality", "{}"))
    except ValueError:
        quality = {}
    for key, value in _flatten(quality):
        if ("sigma" in key or "uncertainty" in key) and isinstance(value, (int, float)):
            parts.append(f"{key} ±{value:.3g}")
    return ", ".join(parts) or "no quality figures"


def _flatten(tree, prefix=""):
    """``{"sigma": {"fx": 0.3}}`` -> ``[("sigma.fx", 0.3)]``."""
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flatten(value, name + ".")
        else:
            yield name, value


class VIEW3D_PT_camcal(bpy.types.Panel):
    bl_label = "camcal rigs"
    bl_idname = "VIEW3D_PT_camcal"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "camcal"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        layout.operator("import_scene.camcal_rig", text="Import rig...", icon="IMPORT")
        clip = scene.active_clip
        row = layout.row()
        row.enabled = clip is not None
        text = f"Solve {clip.name}" if clip else "Solve Movie Clip (no active clip)"
        op = row.operator("camcal.solve_clip", text=text, icon="TRACKING")
        op.clip = clip.name if clip else ""
        roots = [o for o in scene.objects if "camcal_rig_path" in o]
        if not roots:
            layout.label(text="No camcal rig in this scene")
            return
        for root in roots:
            box = layout.box()
            box.label(text=root.name, icon="OUTLINER_COLLECTION")
            for obj in root.children:
                if obj.type != "CAMERA" or "camcal_image_size" not in obj.data:
                    continue
                row = box.row(align=True)
                active = scene.camera == obj
                op = row.operator("camcal.set_active_camera", text=obj.data.get("camcal_name", obj.name),
                                  icon="VIEW_CAMERA" if active else "CAMERA_DATA", depress=active)
                op.camera = obj.name
                w, h = obj.data["camcal_image_size"]
                box.label(text=f"  {w}x{h}, {_quality_text(obj.data)}")
                op = box.operator("camcal.sigma_overlay", text="Show sigma map...", icon="IMAGE_RGB_ALPHA")
                op.camera = obj.name
        render = scene.render
        row = layout.row(align=True)
        row.operator("camcal.toggle_stereo",
                     text=f"Stereo: {render.views_format if render.use_multiview else 'off'}",
                     icon="CAMERA_STEREO")
        row.operator("camcal.apply_resolution", icon="FULLSCREEN_ENTER")


classes = (VIEW3D_PT_camcal,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
