"""A progress line for headless runs (no bpy): one updating line on a terminal, a new line every
few percent when stdout is a log file (build machines), so either way the log shows progress."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time


class ConsoleProgress:
    """Callable `(fraction, message)`; prints `[ 42.0%] message`."""

    def __init__(self, stream=None, step: float = 0.05, min_interval: float = 10.0):
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.step = step
        self.min_interval = min_interval
        self.last_fraction = -1.0
        self.last_time = 0.0

    def __call__(self, fraction: float, message: str) -> None:
        line = f"[{100 * fraction:5.1f}%] {message}"
        now = time.monotonic()
        if self.tty:
            self.stream.write("\r" + line[:150].ljust(150))
            if fraction >= 1.0:
                self.stream.write("\n")
        elif fraction - self.last_fraction >= self.step or now - self.last_time >= self.min_interval or fraction >= 1.0:
            self.stream.write(line + "\n")
        else:
            return
        self.stream.flush()
        self.last_fraction, self.last_time = fraction, now

    def close(self) -> None:
        if self.tty and self.last_fraction < 1.0:
            self.stream.write("\n")
            self.stream.flush()


@contextlib.contextmanager
def interrupt_as_cancel():
    """Yield a `cancel()` callable that turns True on Ctrl-C (SIGINT) inside the block.

    The bake polls it between chunks and stops cleanly within one. A KeyboardInterrupt raised
    wherever the main thread happens to be is not safe here: inside a finalizer it is swallowed
    ("Exception ignored") and the bake runs on, and inside a thread pool's wait it can leave a
    lock held. A second Ctrl-C raises KeyboardInterrupt as usual. It is installed even when the
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
    previous = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        if flag.is_set():
            raise KeyboardInterrupt
        flag.set()

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield flag.is_set
    finally:
        signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)
