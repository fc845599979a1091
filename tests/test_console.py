"""The headless progress line and Ctrl-C as a cancel flag (core/console.py, no bpy)."""

import io
import os
import signal

import pytest

from hhd_lightmapper.core.console import ConsoleProgress, interrupt_as_cancel


def test_progress_in_a_log_prints_a_line_every_step_and_the_end():
    out = io.StringIO()
    progress = ConsoleProgress(out, step=0.25, min_interval=1e9)
    for i in range(1, 11):
        progress(i / 10, f"chunk {i}")
    progress.close()
    lines = out.getvalue().splitlines()
    assert lines == ["[ 10.0%] chunk 1", "[ 40.0%] chunk 4", "[ 70.0%] chunk 7", "[100.0%] chunk 10"]


def test_first_ctrl_c_sets_the_cancel_flag_second_interrupts_and_the_handler_comes_back():
    before = signal.getsignal(signal.SIGINT)
    with interrupt_as_cancel() as cancel:
        assert not cancel()
        os.kill(os.getpid(), signal.SIGINT)  # handled at the next bytecode: sets the flag only
        assert cancel()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # give the interpreter a bytecode boundary
                pass
    assert signal.getsignal(signal.SIGINT) is before


def test_ctrl_c_cancels_even_when_the_process_started_with_sigint_ignored():
    """CI runners and `cmd &` in scripts start commands with SIGINT ignored (POSIX, no job control)."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with interrupt_as_cancel() as cancel:
            os.kill(os.getpid(), signal.SIGINT)
            assert cancel()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)
