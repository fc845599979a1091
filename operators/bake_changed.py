"""Operators: what changed since the last bake (`bpy.ops.hhd.check_stale()`), and a bake of some
receivers into the last bake's files (`bpy.ops.hhd.bake_changed(mode=...)`: Bake Selected, Bake
Changed, Changed + Influenced; `bridge.incremental_session`). Modal from the UI (progress bar,
Esc cancels, nothing replaced), synchronous from scripts, as Bake is."""

import bpy

from ..bridge import collection_instances, incremental_session
from ..core.errors import BakeError
from ..core.tracer import BakeCancelled
from . import modal_work
from .bake import SessionWork

_MODES = (
    ('SELECTED', "Bake Selected", "Re-trace the selected receivers of the last bake into its files"),
    (
        'CHANGED',
        "Bake Changed",
        "Re-trace the receivers whose geometry, transform or material changed since the last bake",
    ),
    (
        'INFLUENCED',
        "Changed + Influenced",
        "Re-trace the changed receivers and those the changes (objects, lights, world) influence (README: Bake what changed)",
    ),
)


class HHD_OT_check_stale(bpy.types.Operator):
    """List what changed since the last bake in the output folder (objects, lights, world, layouts); traces nothing"""

    bl_idname = "hhd.check_stale"
    bl_label = "What Changed"
    bl_options = {'REGISTER'}

    def execute(self, context):
        try:
            _, lines = incremental_session.stale_report(context)
        except BakeError as exc:
            lines = [str(exc)]
        context.scene.hhd.stale_report = "\n".join(lines)
        self.report({'INFO'}, "; ".join(lines))
        return {'FINISHED'}


class HHD_OT_bake_changed(SessionWork, bpy.types.Operator):
    """Re-trace some receivers of the last bake and write their texels into its files; every other texel stays as it is"""

    bl_idname = "hhd.bake_changed"
    bl_label = "Bake Changed"
    bl_options = {'REGISTER'}

    TITLE = "HHD partial bake"

    mode: bpy.props.EnumProperty(name="Receivers", items=_MODES, default='CHANGED')

    @classmethod
    def poll(cls, context):
        return not modal_work.busy(cls)

    def _start(self, context):
        mode = {'SELECTED': "only", 'CHANGED': "changed", 'INFLUENCED': "influenced"}[self.mode]
        selected = [o for o in context.selected_objects if o.type == 'MESH' or collection_instances.shows_collection(o)]
        names = [o.name for o in selected] if mode == "only" else None
        try:
            self.session = incremental_session.IncrementalSession(context, mode, names)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return False
        for warning in self.session.warnings:
            self.report({'WARNING'}, warning)
        return True

    def _done(self, context, error):
        if isinstance(error, BakeCancelled):
            self.report({'WARNING'}, "Bake cancelled: nothing was changed")
            return {'CANCELLED'}
        if isinstance(error, (BakeError, OSError)):
            self.report({'ERROR'}, f"Bake failed: {error}")
            return {'CANCELLED'}
        if error is not None:
            raise error
        summary = self.session.finish()
        context.scene.hhd.bake_summary = summary
        context.scene.hhd.stale_report = ""
        for warning in self.session.result_warnings:
            self.report({'WARNING'}, warning)
        self.report({'INFO'}, summary)
        return {'FINISHED'}
