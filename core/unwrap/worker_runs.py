"""Running one `xatlas_worker` task in a child process: retried when the child crashes or hangs,
killed when the unwrap is cancelled. No bpy."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import TypeVar

from ..errors import BakeCancelled, BakeError

T = TypeVar("T")

#: xatlas runs in child processes (`xatlas_worker`): tries before giving up, and the time after
#: which a child counts as hung (generous: several times the measured charting time, see
#: bench/results/unwrap.md).
XATLAS_ATTEMPTS = 3
XATLAS_TIMEOUT_BASE, XATLAS_TIMEOUT_PER_TRIANGLE = 120.0, 2e-4
#: Seconds between checks of `cancel()` while a child runs: a cancelled unwrap stops this soon.
CANCEL_POLL = 0.1
#: Seconds between the progress calls made while waiting on children (`waiting`): xatlas reports
#: nothing while it charts a part or packs a round, which takes seconds on a level.
HEARTBEAT = 1.0
_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xatlas_worker.py")


def waiting(work: Callable[[], T], beat: Callable[[float], None] | None) -> T:
    """work()'s result, run on a helper thread while this thread calls beat(seconds waited) every
    HEARTBEAT seconds (progress is reported from the calling thread only); work's exception is
    raised here. Without `beat`, work() is called here."""
    if beat is None:
        return work()
    start = time.monotonic()
    with ThreadPoolExecutor(max_workers=1) as pool:
        future = pool.submit(work)
        while not wait([future], timeout=HEARTBEAT).done:
            beat(time.monotonic() - start)
        return future.result()


def _check(cancel) -> None:
    """Raise BakeCancelled if `cancel` (or None) says so."""
    if cancel is not None and cancel():
        raise BakeCancelled("unwrap cancelled")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _run_worker(job, names, triangles, cancel=None):
    """Run one xatlas_worker task in a child process; a crashed or hung child is retried.
    cancel() True (checked every CANCEL_POLL seconds): the child is killed and reaped, then
    BakeCancelled is raised."""
    payload = pickle.dumps(list(sys.path)) + pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
    timeout = XATLAS_TIMEOUT_BASE + XATLAS_TIMEOUT_PER_TRIANGLE * triangles
    failures = []
    for _ in range(XATLAS_ATTEMPTS):
        _check(cancel)
        run = _run_child(payload, timeout, cancel)
        _check(cancel)  # a Ctrl-C on the terminal also reaches the child: not a crash
        if run is None:
            failures.append(f"no answer after {timeout:.0f} s")
            continue
        if run.returncode == 0 and run.stdout:
            result = pickle.loads(run.stdout)
            if "error" in result:
                raise BakeError(result["error"])
            return result
        failures.append(_describe_failure(run))
    shown = ", ".join(f"'{n}'" for n in names[:5]) + (" …" if len(names) > 5 else "")
    raise BakeError(f"xatlas failed {XATLAS_ATTEMPTS} times unwrapping {shown}: {'; '.join(failures)}")


def _run_child(payload: bytes, timeout: float, cancel=None):
    """Run the worker on `payload`: a CompletedProcess, or None if it gave no answer within
    `timeout` seconds (then killed). Raises BakeCancelled, the child killed and reaped, once
    cancel() returns True. The pipes are served by a helper thread (`communicate` cannot be
    retried after a timeout while input remains to be written), this one only waits."""
    proc = subprocess.Popen(
        [sys.executable, "-I", _WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    streams = []
    talker = threading.Thread(target=lambda: streams.append(proc.communicate(payload)), daemon=True)
    talker.start()
    deadline = time.monotonic() + timeout
    try:
        while talker.is_alive():
            talker.join(max(0.0, min(CANCEL_POLL, deadline - time.monotonic())))
            if talker.is_alive() and cancel is not None and cancel():
                raise BakeCancelled("unwrap cancelled")
            if talker.is_alive() and time.monotonic() >= deadline:
                return None
        stdout, stderr = streams[0] if streams else (b"", b"")
        return subprocess.CompletedProcess(proc.args, proc.wait(), stdout, stderr)
    finally:
        if talker.is_alive():
            proc.kill()
            talker.join()  # the pipes close with the child: communicate returns and reaps it
        proc.wait()


def _describe_failure(run) -> str:
    """One line on how the xatlas child ended: the signal that killed it or its last error line."""
    if run.returncode < 0:
        try:
            return f"crashed ({signal.Signals(-run.returncode).name})"
        except ValueError:
            return f"crashed (signal {-run.returncode})"
    lines = run.stderr.decode(errors="replace").strip().splitlines()
    return f"exit code {run.returncode}" + (f": {lines[-1]}" if lines else "")
