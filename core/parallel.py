"""How many worker threads the bake's parallel stages use. No bpy.

Convention everywhere (`BakeSettings.threads`, `bakepoints.build`, the CLI's `--threads`): a
thread count is an int ≥ 0, and 0 means "all": every CPU this process may run on
(`machine_threads`). `resolve_threads` turns a setting into the count a stage actually starts;
it is resolved once per bake, so every stage uses the same count and the sidecar records it.

Results never depend on the count: work is split into fixed-size chunks whatever the thread
count, each chunk seeded by its index, and combined in chunk order.
"""

from __future__ import annotations

import os

from .errors import BakeError

#: Blender's Render > Performance > Threads modes (`scene.render.threads_mode`).
BLENDER_MODES = ("AUTO", "FIXED")


def machine_threads() -> int:
    """CPUs this process may run on (≥ 1): its CPU affinity where the platform reports one
    (Linux: a container or `taskset` may allow fewer than the machine has), else the number of
    logical CPUs."""
    try:
        count = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # macOS and Windows have no sched_getaffinity
        count = os.cpu_count() or 1
    return max(1, count)


def resolve_threads(threads: int) -> int:
    """The worker-thread count for a setting: `threads` itself if > 0, `machine_threads()` if 0.
    Raises BakeError for a negative count (or a non-integer)."""
    if isinstance(threads, bool) or not isinstance(threads, int):
        raise BakeError(f"the thread count must be a whole number ≥ 0 (0 = all cores), got {threads!r}")
    if threads < 0:
        raise BakeError(f"the thread count must be ≥ 0 (0 = all cores), got {threads}")
    return threads if threads > 0 else machine_threads()


def blender_threads(mode: str, threads: int) -> int:
    """The thread setting (0 = all) for Blender's Render > Performance > Threads:
    mode 'AUTO' → 0, every core this process may use (Blender then reports its own count of the
    machine's CPUs in `threads`, which ignores the affinity); 'FIXED' → the artist's `threads`
    (Blender keeps it in 1 … 1024)."""
    if mode == "AUTO":
        return 0
    if mode == "FIXED":
        return max(1, int(threads))
    raise BakeError(f"unknown Blender threads mode {mode!r}: expected one of {', '.join(BLENDER_MODES)}")
