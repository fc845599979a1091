"""Operator: the views before a bake (`bpy.ops.hhd.view_show(mode='DENSITY' | 'CHECKER' | 'PROBLEMS')`);
Hide Preview (`bpy.ops.hhd.preview_hide()`) hides them (shaders/texel_views.py)."""

import bpy
from bpy.props import EnumProperty

from ..bridge import bake_session
from ..core.errors import BakeError
from ..shaders import texel_views
from .bake import receivers_poll

#: The views (the panel's View choice lists the lighting preview besides them).
VIEW_ITEMS = [
    (
        'DENSITY',
        "Texel Density",
        "Heat map of each face's texels per metre against the target: blue half, green on target, red double",
    ),
    ('CHECKER', "Texel Checker", "A checker whose cells are exactly one texel of the object's atlas"),
    (
        'PROBLEMS',
        "Problems",
        "Texels shared by two charts (magenta), flipped (orange) and degenerate (yellow) UV faces, "
        "objects with too few texels (blue)",
    ),
]


class HHD_OT_view_show(bpy.types.Operator):
    """Show texel density, a texel checker or UV problems on the receivers, from their lightmap UVs (no bake needed)"""

    bl_idname = "hhd.view_show"
    bl_label = "Show View"
    bl_options = {'REGISTER', 'UNDO'}

    mode: EnumProperty(name="View", items=VIEW_ITEMS, default='DENSITY')

    @classmethod
    def poll(cls, context):
        return receivers_poll(cls, context)

    def execute(self, context):
        settings = context.scene.hhd
        try:
            objects = bake_session.target_objects(context)
            if not objects:
                raise BakeError("no mesh objects selected")
            lines, notes = texel_views.show(objects, self.mode, settings)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        for note in notes:
            self.report({'WARNING'}, note)
        for line in lines:
            self.report({'INFO'}, line)
        settings.view_summary = "\n".join(lines + notes)
        return {'FINISHED'}
