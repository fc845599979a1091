"""A progress line for headless runs (no bpy): one updating line on a terminal, a new line every
few percent when stdout is a log file (build machines), so either way the log shows progress."""
from __future__ import annotations

import sys
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
        elif (fraction - self.last_fraction >= self.step or now - self.last_time >= self.min_interval
              or fraction >= 1.0):
            self.stream.write(line + "\n")
        else:
            return
        self.stream.flush()
        self.last_fraction, self.last_time = fraction, now

    def close(self) -> None:
        if self.tty and self.last_fraction < 1.0:
            self.stream.write("\n")
            self.stream.flush()
