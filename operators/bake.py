"""Operator: bake lightmaps for the receivers (`bpy.ops.hhd.bake()`).

From a script or in background mode `execute` runs the bake synchronously (a progress line on
stdout when headless). From the UI `invoke` runs it modally: the core pipeline works on a thread
(it touches no bpy data; Embree and numpy release the GIL), a timer updates the progress bar and
status text, Esc cancels within a chunk of texels, and the .blend is only changed once the bake
has finished (images loaded).
"""
import threading

import bpy

from ..core.console import ConsoleProgress
from ..core.errors import BakeError
from ..core.tracer import BakeCancelled
from . import bake_session


def receivers_poll(cls, context) -> bool:
    """Shared poll of Bake / Re-encode: something to work on, and no bake running."""
    settings = context.scene.hhd
    if HHD_OT_bake.running:
        cls.poll_message_set("A bake or unwrap is running (Esc cancels it)")
        return False
    if settings.target == 'COLLECTION':
        if settings.target_collection is None:
            cls.poll_message_set("Choose the receivers' collection")
            return False
        return True
    if not any(o.type == 'MESH' for o in context.selected_objects):
        cls.poll_message_set("Select the mesh objects that receive lightmaps")
        return False
    return True


class HHD_OT_bake(bpy.types.Operator):
    """Path-trace the lightmaps of the receivers, encode them to HHD and write the EXR files"""
    bl_idname = "hhd.bake"
    bl_label = "Bake Lightmaps"
    bl_options = {'REGISTER'}

    running = False          # class-wide: one bake at a time

    @classmethod
    def poll(cls, context):
        return receivers_poll(cls, context)

    def _start(self, context):
        try:
            self.session = bake_session.BakeSession(context)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return False
        for warning in self.session.warnings:
            self.report({'WARNING'}, warning)
        return True

    def _done(self, context, error):
        """Report the outcome; load the images only after a finished bake."""
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
        self.report({'INFO'}, summary)
        return {'FINISHED'}

    def execute(self, context):
        if not self._start(context):
            return {'CANCELLED'}
        progress = ConsoleProgress() if bpy.app.background else None
        if progress:
            print(f"HHD bake: {self.session.describe()}", flush=True)
        error = None
        try:
            self.session.run(progress=progress)
        except Exception as exc:      # reported (or re-raised) by _done, after the progress line
            error = exc
        finally:
            if progress:
                progress.close()
        return self._done(context, error)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        if not self._start(context):
            return {'CANCELLED'}
        self._cancel = threading.Event()
        self._state = {"fraction": 0.0, "message": "starting", "error": None}
        self._thread = threading.Thread(target=self._work, daemon=True)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        HHD_OT_bake.running = True
        self._thread.start()
        return {'RUNNING_MODAL'}

    def _work(self):
        try:
            self.session.run(progress=self._on_progress, cancel=self._cancel.is_set)
        except Exception as exc:
            self._state["error"] = exc

    def _on_progress(self, fraction, message):
        self._state["fraction"], self._state["message"] = fraction, message

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._cancel.set()
            self._state["message"] = "cancelling…"
            return {'RUNNING_MODAL'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        show_progress(context, "HHD bake", self._state["fraction"], self._state["message"])
        if self._thread.is_alive():
            return {'PASS_THROUGH'}
        self._cleanup(context)
        return self._done(context, self._state["error"])

    def _cleanup(self, context):
        context.window_manager.event_timer_remove(self._timer)
        clear_progress(context)
        HHD_OT_bake.running = False


def show_progress(context, title: str, fraction: float, message: str) -> None:
    """Show a modal job's progress (fraction in [0, 1]) in the window's progress bar (started with
    `progress_begin(0, 1000)`), the panel's bar and the status bar."""
    wm = context.window_manager
    text = f"{title} {100 * fraction:.0f}%: {message} (Esc cancels)"
    wm.progress_update(int(1000 * fraction))
    wm.hhd_progress, wm.hhd_status = fraction, text
    context.workspace.status_text_set(text)
    for area in context.screen.areas:
        if area.type == 'PROPERTIES':
            area.tag_redraw()


def clear_progress(context) -> None:
    """End what `show_progress` showed."""
    wm = context.window_manager
    wm.progress_end()
    wm.hhd_progress, wm.hhd_status = 0.0, ""
    context.workspace.status_text_set(None)
