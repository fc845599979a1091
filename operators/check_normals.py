"""Operator: find the receivers' faces that point into their own object (`bpy.ops.hhd.check_normals()`)."""

import bpy

from ..bridge import bake_session
from ..core.errors import BakeError


class HHD_OT_check_normals(bpy.types.Operator):
    """Find faces whose normals point into their own closed object (their lightmap would be black
    there), without baking: the panel lists them by object"""

    bl_idname = "hhd.check_normals"
    bl_label = "Check Normals"

    def execute(self, context):
        try:
            messages = bake_session.check_inward(context)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        for message in messages:
            self.report({'WARNING'}, message)
        if not messages:
            self.report({'INFO'}, "No face points into its own object")
        return {'FINISHED'}
