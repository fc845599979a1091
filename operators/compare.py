"""Operator: compare every encoding of the last bake against Cycles from the scene camera
(`bpy.ops.hhd.compare()`; `bridge.compare`). No tracing and no bake file changes: the report
(compare.md, compare.json, contact_sheet.png) goes to `<output folder>/compare`, replacing an
earlier one only when the comparison has finished.

From a script or in background mode `execute` runs every step at once (a console line per
step). From the UI `invoke` runs them modally, one per timer event on the main thread (the
renders need bpy there, so not `modal_work.ModalWork`'s thread), with the progress bar; Esc
cancels before the next step, so at most one render late. While it runs, input other than Esc
is held back (the references must all see the scene the compared pixels were found in), and
no bake or unwrap can start (`ModalWork.running`), nor a compare during them."""

import traceback

import bpy
from bpy.props import IntProperty

from ..bridge import compare
from ..core.errors import BakeCancelled, BakeError
from ..core.files import exr
from . import modal_work
from .bake import receivers_poll

#: The status text's hint: Esc is heard between steps, so after the render running.
HINT = "Esc cancels, at most one render late"


class HHD_OT_compare(bpy.types.Operator):
    """Compare every lightmap encoding of the last bake with Cycles from the scene camera: bytes per texel, diffuse
    and specular error, a table and a contact sheet in the output folder's 'compare' folder"""

    bl_idname = "hhd.compare"
    bl_label = "Compare Encodings"
    bl_options = {'REGISTER'}
    TITLE = "HHD compare"

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
            outcome = compare.run(context, samples=self.samples, percentage=self.percentage)
        except Exception as exc:  # reported by _done
            outcome = exc
        return self._done(outcome)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self._job = compare.prepare(context, samples=self.samples, percentage=self.percentage)
        except Exception as exc:
            return self._done(exc)
        self._cancelled = False
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        modal_work.ModalWork.running = True
        compare.begin(self._job, self._shower(context))
        return {'RUNNING_MODAL'}

    def _shower(self, context):
        return lambda fraction, message: modal_work.show_progress(context, self.TITLE, fraction, message, HINT)

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._cancelled = True  # the next advance raises BakeCancelled instead of running a step
        elif event.type != 'TIMER':
            return {'RUNNING_MODAL'}  # held back: the scene must not change between the renders
        try:
            if compare.advance(self._job, self._shower(context), lambda: self._cancelled):
                return {'RUNNING_MODAL'}
            outcome = (self._job.summary, self._job.warnings)
        except Exception as exc:
            outcome = exc
        self._end(context)
        return self._done(outcome)

    def cancel(self, context):
        """Blender ends the operator (a file loaded, the window closed): nothing is written."""
        self._job.close()
        self._end(context)

    def _end(self, context) -> None:
        context.window_manager.event_timer_remove(self._timer)
        modal_work.clear_progress(context)
        modal_work.ModalWork.running = False

    def _done(self, outcome):
        """Report (summary, warnings) or the exception that ended the comparison."""
        if isinstance(outcome, BakeCancelled):
            self.report({'WARNING'}, "Compare cancelled: nothing was changed")
            return {'CANCELLED'}
        if isinstance(outcome, BakeError):
            self.report({'ERROR'}, f"Compare failed: {outcome}")
            return {'CANCELLED'}
        if isinstance(outcome, OSError):
            name = exr.target_of(outcome.filename) if outcome.filename else "the report"  # not its temporary
            self.report({'ERROR'}, f"Compare failed: cannot write {name}: {outcome.strerror or outcome}")
            return {'CANCELLED'}
        if isinstance(outcome, Exception):  # a bug: the traceback goes to the console, the artist gets one line
            traceback.print_exception(outcome)
            self.report({'ERROR'}, f"Compare failed (a bug, please report it with the console's traceback): {outcome}")
            return {'CANCELLED'}
        summary, warnings = outcome
        for warning in warnings:
            self.report({'WARNING'}, warning)
        self.report({'INFO'}, summary)
        return {'FINISHED'}
