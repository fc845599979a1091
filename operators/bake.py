"""Operator: bake lightmaps for the receivers (`bpy.ops.hhd.bake()`).

From a script or in background mode `execute` runs the bake synchronously (a progress line on
stdout when headless). From the UI `invoke` runs it modally: the core pipeline works on a thread
(it touches no bpy data; Embree and numpy release the GIL), a timer updates the progress bar and
status text, Esc cancels within a chunk of texels, and the .blend is only changed once the bake
has finished (images loaded).
"""

import contextlib

import bpy

from ..bridge import bake_session, collection_instances
from ..core.console import ConsoleProgress
from ..core.errors import BakeError, InwardFacesRefused
from ..core.progress import with_eta
from ..core.tracer import BakeCancelled
from . import modal_work


def receivers_poll(cls, context) -> bool:
    """Shared poll of Bake / Re-encode: something to work on, and no bake running."""
    settings = context.scene.hhd
    if modal_work.busy(cls):
        return False
    if settings.target == 'COLLECTION':
        if settings.target_collection is None:
            cls.poll_message_set("Choose the receivers' collection")
            return False
        return True
    if not any(o.type == 'MESH' or collection_instances.shows_collection(o) for o in context.selected_objects):
        cls.poll_message_set("Select the mesh objects (or collection instances) that receive lightmaps")
        return False
    return True


@contextlib.contextmanager
def reading_progress(context):
    """`progress(fraction, message)` for reading the scene on the main thread (before the work
    starts): the progress line in background mode, else the window's progress cursor."""
    if bpy.app.background:
        console = ConsoleProgress(step=0.25)
        try:
            yield with_eta(console)
        finally:
            console.close()
        return
    wm = context.window_manager
    wm.progress_begin(0, 1000)
    try:
        yield lambda fraction, _message: wm.progress_update(int(1000 * fraction))
    finally:
        wm.progress_end()


class SessionWork(modal_work.ModalWork):
    """A bake-like operator: `_start` makes `self.session` (with `run(progress=, cancel=)`),
    `_done` reports its outcome. Synchronous from scripts and in background mode, modal from the
    UI (`modal_work.ModalWork`)."""

    def _announce(self) -> None:
        """The line printed before a headless run's progress lines (none by default)."""

    def execute(self, context):
        if not self._start(context):
            return {'CANCELLED'}
        progress = ConsoleProgress() if bpy.app.background else None
        if progress:
            self._announce()
        error = None
        try:
            self.session.run(progress=progress)
        except Exception as exc:  # reported (or re-raised) by _done, after the progress line
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
        return self._start_work(context, lambda progress, cancel: self.session.run(progress=progress, cancel=cancel))

    def _work_done(self, context, result, error):
        return self._done(context, error)


class HHD_OT_bake(SessionWork, bpy.types.Operator):
    """Path-trace the lightmaps of the receivers, encode them to HHD and write the EXR files"""

    bl_idname = "hhd.bake"
    bl_label = "Bake Lightmaps"
    bl_options = {'REGISTER'}

    TITLE = "HHD bake"

    @classmethod
    def poll(cls, context):
        return receivers_poll(cls, context)

    def _start(self, context):
        try:
            with reading_progress(context) as progress:
                self.session = bake_session.BakeSession(context, progress=progress)
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
            if isinstance(error, InwardFacesRefused):
                bake_session.set_inward_report(context.scene, error.messages)
            self.report({'ERROR'}, f"Bake failed: {error}")
            return {'CANCELLED'}
        if error is not None:
            raise error
        summary = self.session.finish()
        context.scene.hhd.bake_summary = summary
        bake_session.set_inward_report(context.scene, self.session.inward_warnings)
        for warning in self.session.result_warnings:  # e.g. no denoiser: written undenoised
            self.report({'WARNING'}, warning)
        self.report({'INFO'}, summary)
        return {'FINISHED'}

    def _announce(self) -> None:
        print(f"HHD bake: {self.session.describe()}", flush=True)
