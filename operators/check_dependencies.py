"""Operator: report whether the compiled dependencies (embreex, xatlas, OpenEXR) load."""

import bpy

from ..core import deps


class HHD_OT_check_dependencies(bpy.types.Operator):
    """Check that the bundled ray tracer, unwrapper and EXR libraries load on this machine"""

    bl_idname = "hhd.check_dependencies"
    bl_label = "Check Dependencies"

    def execute(self, context):
        status = deps.status()
        missing = [name for name, version in status.items() if version is None]
        summary = ", ".join(f"{n} {v or 'MISSING'}" for n, v in status.items())
        if missing:
            self.report({'ERROR'}, f"Missing: {', '.join(missing)} ({summary})")
            return {'CANCELLED'}
        self.report({'INFO'}, summary)
        return {'FINISHED'}
