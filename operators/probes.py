"""Operators: show / hide the baked light probes on the selected meshes in EEVEE
(`bpy.ops.hhd.probe_preview_show()` / `probe_preview_hide()`), for objects without a lightmap."""

import bpy

from ..bridge import bake_session
from ..core.errors import BakeError
from ..shaders import probe_preview


def selected_meshes(context) -> list:
    return [o for o in context.selected_objects if o.type == 'MESH']


class HHD_OT_probe_preview_show(bpy.types.Operator):
    """Light the selected meshes with the baked probe volumes in EEVEE (SH at each object's
    origin; the scene's hhd_probe_mode: 0 plain SH, 1 HLSH hemisphere, 2 HLSH + AO cone)"""

    bl_idname = "hhd.probe_preview_show"
    bl_label = "Show Probe Lighting"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not selected_meshes(context):
            cls.poll_message_set("Select mesh objects")
            return False
        return True

    def execute(self, context):
        try:
            objects = selected_meshes(context)
            folder = bake_session.output_folder(context.scene.hhd)
            notes = probe_preview.show(objects, folder, context.scene)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        probe_preview.register_handlers()  # idempotent: also when the add-on did not install them
        for note in notes:
            self.report({'WARNING'}, note)
        self.report({'INFO'}, f"Probe lighting on {len(objects)} object(s)")
        return {'FINISHED'}


class HHD_OT_probe_preview_hide(bpy.types.Operator):
    """Remove the probe lighting preview and restore every material exactly as it was"""

    bl_idname = "hhd.probe_preview_hide"
    bl_label = "Hide Probe Lighting"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not any(probe_preview.RECORD in m for m in bpy.data.materials):
            cls.poll_message_set("No probe lighting is shown")
            return False
        return True

    def execute(self, context):
        restored = probe_preview.hide()
        self.report({'INFO'}, f"Probe lighting removed from {restored} material(s)")
        return {'FINISHED'}
