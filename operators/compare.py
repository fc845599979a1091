"""Operator: compare every encoding of the last bake against Cycles from the scene camera
(`bpy.ops.hhd.compare()`; `bridge.compare`). No tracing and no bake file changes: the report
(compare.md, compare.json, contact_sheet.png) goes to `<output folder>/compare`. The reference
renders run in the foreground, as F12 would, with the render's own progress."""

import traceback

import bpy
from bpy.props import IntProperty

from ..bridge import compare
from ..core.errors import BakeError
from .bake import receivers_poll


class HHD_OT_compare(bpy.types.Operator):
    """Compare every lightmap encoding of the last bake with Cycles from the scene camera: bytes per texel, diffuse
    and specular error, a table and a contact sheet in the output folder's 'compare' folder"""

    bl_idname = "hhd.compare"
    bl_label = "Compare Encodings"
    bl_options = {'REGISTER'}

    samples: IntProperty(name="Samples", default=256, min=1, max=65536, description="Cycles samples per reference")
    percentage: IntProperty(
        name="Size", default=50, min=1, max=100, subtype='PERCENTAGE', description="Share of the render size"
    )

    @classmethod
    def poll(cls, context):
        if context.scene.camera is None:
            cls.poll_message_set("The comparison renders from the scene camera: add one")
            return False
        return receivers_poll(cls, context)

    def execute(self, context):
        try:
            summary, warnings = compare.run(context, samples=self.samples, percentage=self.percentage)
        except BakeError as exc:
            self.report({'ERROR'}, f"Compare failed: {exc}")
            return {'CANCELLED'}
        except OSError as exc:
            self.report(
                {'ERROR'}, f"Compare failed: cannot write {exc.filename or 'the report'}: {exc.strerror or exc}"
            )
            return {'CANCELLED'}
        except Exception as exc:  # a bug: the traceback goes to the console, the artist gets one line
            traceback.print_exc()
            self.report({'ERROR'}, f"Compare failed (a bug, please report it with the console's traceback): {exc}")
            return {'CANCELLED'}
        for warning in warnings:
            self.report({'WARNING'}, warning)
        self.report({'INFO'}, summary)
        return {'FINISHED'}
