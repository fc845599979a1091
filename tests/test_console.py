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
        progress(i / 10, f"'A': chunk {i}")
    progress.close()
    lines = out.getvalue().splitlines()
    assert lines == [
        "[ 10.0%] 'A': chunk 1",
        "[ 40.0%] 'A': chunk 4",
        "[ 70.0%] 'A': chunk 7",
        "[100.0%] 'A': chunk 10",
    ]


def test_progress_in_a_log_prints_each_stage_start_and_after_min_interval(monkeypatch):
    out = io.StringIO()
    clock = iter([0.0, 0.1, 0.2, 0.3, 6.0, 6.1])
    monkeypatch.setattr("hhd_lightmapper.core.console.time.monotonic", lambda: next(clock))
    progress = ConsoleProgress(out, step=0.25, min_interval=5.0)
    progress(0.10, "bake points of 'A': rasterising")
    progress(0.11, "bake points of 'A': settling")  # same stage, 1%, 0.1 s: not printed
    progress(0.12, "'A': chunk 1 of 9")  # a new stage
    progress(0.13, "'A': chunk 2 of 9")
    progress(0.14, "'A': chunk 3 of 9")  # 5.7 s after the last line
    progress(0.15, "'A': chunk 4 of 9")
    lines = out.getvalue().splitlines()
    assert lines == [
        "[ 10.0%] bake points of 'A': rasterising",
        "[ 12.0%] 'A': chunk 1 of 9",
        "[ 14.0%] 'A': chunk 3 of 9",
    ]


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
