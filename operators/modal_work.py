"""Long work run modally from the UI: on a thread, with the progress bar and Esc to cancel.

The bake and the unwrap share it (and so run one at a time). The work function touches no bpy
data (the core pipeline: Embree, numpy and child processes release the GIL); what it reads from
Blender is read before it starts and what it writes is written on the main thread afterwards.
"""

import threading


class ModalWork:
    """Mixin for an Operator. `_start_work(context, work)` runs `work(progress, cancel)` on a
    thread and returns {'RUNNING_MODAL'}; every TIMER event updates the progress display; Esc
    makes `cancel()` return True (the work then raises BakeCancelled); when the thread ends,
    `_work_done(context, result, error)` runs on the main thread and returns the operator's
    result. TITLE names the work in the status bar."""

    TITLE = "HHD"
    running = False  # shared by every subclass: one modal job at a time

    def _start_work(self, context, work):
        self._cancel = threading.Event()
        self._state = {"fraction": 0.0, "message": "starting", "result": None, "error": None}
        self._thread = threading.Thread(target=self._run_work, args=(work,), daemon=True)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        ModalWork.running = True
        self._thread.start()
        return {'RUNNING_MODAL'}

    def _run_work(self, work):
        try:
            self._state["result"] = work(self._on_progress, self._cancel.is_set)
        except Exception as exc:  # handed to the main thread by modal
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
        show_progress(context, self.TITLE, self._state["fraction"], self._state["message"])
        if self._thread.is_alive():
            return {'PASS_THROUGH'}
        context.window_manager.event_timer_remove(self._timer)
        clear_progress(context)
        ModalWork.running = False
        return self._work_done(context, self._state["result"], self._state["error"])


def show_progress(context, title: str, fraction: float, message: str, hint: str = "Esc cancels") -> None:
    """Show a modal job's progress (fraction in [0, 1]) in the window's progress bar (started with
    `progress_begin(0, 1000)`), the panel's bar and the status bar (`hint` in brackets after it)."""
    wm = context.window_manager
    text = f"{title} {100 * fraction:.0f}%: {message} ({hint})"
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


def busy(cls) -> bool:
    """In a poll: True (with the reason shown) while a bake, unwrap or compare runs (the compare
    operator sets `ModalWork.running` too)."""
    if ModalWork.running:
        cls.poll_message_set("A bake, unwrap or compare is running (Esc cancels it)")
        return True
    return False
