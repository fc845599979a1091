"""A progress line for headless runs (no bpy): one updating line on a terminal, and when stdout is
a log file (build machines) a new line at each stage's start, then every few percent or every
few seconds, so either way the log shows every stage and that it is moving."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time


class ConsoleProgress:
    """Callable `(fraction, message)`; prints `[ 42.0%] message`. In a log: a line whenever the
    stage changes (the message's head, before its first ": "), the bar moved `step` or
    `min_interval` seconds passed since the last line, and at the end."""

    def __init__(self, stream=None, step: float = 0.05, min_interval: float = 5.0):
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.step = step
        self.min_interval = min_interval
        self.last_fraction = -1.0
        self.last_time = 0.0
        self.last_stage: str | None = None

    def __call__(self, fraction: float, message: str) -> None:
        line = f"[{100 * fraction:5.1f}%] {message}"
        now = time.monotonic()
        stage = message.split(": ", 1)[0]
        if self.tty:
            self.stream.write("\r" + line[:150].ljust(150))
            if fraction >= 1.0:
                self.stream.write("\n")
        elif (
            stage != self.last_stage
            or fraction - self.last_fraction >= self.step
            or now - self.last_time >= self.min_interval
            or fraction >= 1.0
        ):
            self.stream.write(line + "\n")
        else:
            return
        self.stream.flush()
        self.last_fraction, self.last_time, self.last_stage = fraction, now, stage

    def close(self) -> None:
        if self.tty and self.last_fraction < 1.0:
            self.stream.write("\n")
            self.stream.flush()


#: The signals that stop a bake: Ctrl-C, and what CI time-outs and farm managers send.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def interrupt_as_cancel():
    """Yield a `cancel()` callable that turns True on Ctrl-C (SIGINT) or SIGTERM inside the block.

    The bake polls it between chunks and stops cleanly within one. A KeyboardInterrupt raised
    wherever the main thread happens to be is not safe here: inside a finalizer it is swallowed
    ("Exception ignored") and the bake runs on, and inside a thread pool's wait it can leave a
    lock held. A second Ctrl-C (or SIGTERM) raises KeyboardInterrupt as usual. SIGTERM, which
    would otherwise end the process at once and leave the writers' temporary files behind, is
    handled the same way, so every stop removes them. It is installed even when the
    process started with SIGINT ignored: a shell without job control (a CI runner, a script's
    `cmd &`) starts background commands that way, and Python then never raises
    KeyboardInterrupt, so a SIGINT sent to the bake would be lost. The previous handler comes back
    afterwards; one Python cannot reinstall (Blender's own, under `blender --background`, which
    only sets an internal break flag the bake cannot see) is replaced by the default, which ends
    the process on Ctrl-C as Blender's second Ctrl-C does. Off the main thread signals cannot be
    handled, so nothing is installed and `cancel()` stays False."""
    flag = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag.is_set
        return

    def on_signal(signum, frame):
        if flag.is_set():
            raise KeyboardInterrupt
        flag.set()

    with _handlers(on_signal):
        yield flag.is_set


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def terminate_as_interrupt():
    """Inside the block SIGTERM (and SIGINT, even if the process started with it ignored) raises
    KeyboardInterrupt, as Ctrl-C does: `finally` blocks run, so staged files are deleted and no
    file is replaced (a command line run maps it to its "cancelled" exit code). A bake inside
    uses `interrupt_as_cancel` instead. Off the main thread nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _handlers(_raise_interrupt):
        yield


@contextlib.contextmanager
def _handlers(handler):
    """`handler` for every STOP_SIGNALS inside the block, the previous ones back afterwards (a
    handler Python cannot reinstall, such as Blender's own, is replaced by the default)."""
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, before in previous.items():
            signal.signal(s, signal.SIG_DFL if before is None else before)


def exit_on_stop_signal(code: int, prefix: str) -> None:
    """Until other handlers are installed, SIGINT or SIGTERM ends the process at once with exit
    `code` and one line on stderr: for a command line's start-up (importing bpy and numpy), when
    nothing has been written yet. A KeyboardInterrupt raised inside those imports is caught by
    their C code and turned into a misleading ImportError, and the run would go on half set up."""

    def on_signal(signum, frame):
        name = signal.Signals(signum).name
        sys.stderr.write(f"{prefix}: error: interrupted ({name}) while starting: nothing was written\n")
        sys.stderr.flush()
        os._exit(code)

    for s in STOP_SIGNALS:
        signal.signal(s, on_signal)
