"""What a farm worker runs: the code and packages it traces with (`environment`), the bake
points of an atlas (`points_task`) and the passes of a group of chunks (`trace_group`). No bpy."""

from __future__ import annotations

import hashlib
import os
import pickle
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import BakeError
from ..tracer import shipping
from ..tracer.scheduler import WorkUnit
from ..tracer.settings import MIN_ADAPTIVE_PASSES, BakeSettings
from ..tracer.statistics import Statistics
from .names import plain

#: Packages whose versions must match between the client and every worker.
MATCHED = ("numpy", "numba", "llvmlite", "embreex")


_fingerprint: str | None = None


def code_fingerprint() -> str:
    """Hash of the core's Python sources (every module the tracer may run): client and workers
    must trace with the same code."""
    global _fingerprint
    if _fingerprint is None:
        h = hashlib.blake2b(digest_size=12)
        root = Path(__file__).resolve().parent.parent  # core/
        for path in sorted(root.rglob("*.py")):
            h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
        _fingerprint = h.hexdigest()
    return _fingerprint


def environment() -> dict:
    """What makes a process's traced numbers what they are: the core's code, Python and the
    compiled packages' versions, and the CPU target numba and Embree compile for (docs/farm.md,
    "CPU types")."""
    from importlib import metadata

    env = {"code": code_fingerprint(), "python": f"{sys.version_info[0]}.{sys.version_info[1]}"}
    for name in MATCHED:
        try:
            env[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            env[name] = "missing"
    try:
        from llvmlite import binding

        host = binding.get_host_cpu_name()
    except Exception:  # noqa: BLE001 - informative only
        host = "unknown"
    env["cpu"] = os.environ.get("NUMBA_CPU_NAME") or host
    env["embree_config"] = os.environ.get("HHD_EMBREE_CONFIG", "")
    env["machine"] = platform.machine()
    return env


def _same_code(code: str) -> None:
    """BakeError unless this worker runs the client's core code (`code`: its fingerprint)."""
    if code != code_fingerprint():
        raise BakeError(
            f"this worker ({platform.node()}) runs other tracer code ({code_fingerprint()}) than the client "
            f"({code}): install the same hhd_lightmapper version on every machine"
        )


def _where() -> str:
    """This process, as a task's record names it: host:pid."""
    return f"{platform.node()}:{os.getpid()}"


def trace_group(
    payload: bytes,
    digest: str,
    settings: dict,
    code: str,
    chunks: list,
    passes: tuple[int, int] | None = None,
    state: dict | None = None,
    floor: float | None = None,
) -> dict:
    """One task: passes `passes` (first, end; default all) of the fixed chunks `chunks`
    [(index, first texel, end)] of an atlas, chunk by chunk into statistics of their own (see the
    module doc), returned as plain arrays for the texels first..end of the group (contiguous)
    with the rays traced. With a noise target the client runs two: the first MIN_ADAPTIVE_PASSES
    passes, then (given `state`, the first's result, and the atlas's `floor`) the rest, testing
    each texel before every pass and after the last."""
    _same_code(code)
    t0 = time.perf_counter()
    estimator = shipping._receive(digest, payload)
    trace = BakeSettings(**settings)
    first_pass, end_pass = passes if passes is not None else (0, trace.passes)
    channels = estimator.scene.channels
    first, end = chunks[0][1], chunks[-1][2]
    n = end - first
    out: dict = {
        "total": np.zeros((n, 9, channels)),
        "m2": np.zeros((n, 9, channels), np.float32),
        "iz": np.zeros(n),
        "iz_sq": np.zeros(n),
        "passes": np.zeros(n, np.int64),
    }
    rays = texel_passes = 0
    converged = floor is not None
    for c, start, stop in chunks:
        stats = Statistics(stop - start, estimator.points.normal[start:stop], channels)
        if state is not None:
            for key in out:
                getattr(stats, key)[:] = state[key][start - first : stop - first]
        texels = np.arange(start, stop)
        active = np.arange(stop - start)
        for p in range(first_pass, end_pass):
            if floor is not None and p >= MIN_ADAPTIVE_PASSES:
                active = active[~stats.converged(active, trace.noise_target, floor)]
                if len(active) == 0:
                    break
            result = estimator.trace(WorkUnit(trace.seed, p, c, texels[active]))
            rays += result.rays
            stats.add(active, result.estimate)
        if floor is not None and len(active):  # the test after the last pass (stopped_by only)
            active = active[~stats.converged(active, trace.noise_target, floor)]
        converged = converged and len(active) == 0
        texel_passes += stats.texel_passes
        for key in out:
            out[key][start - first : stop - first] = getattr(stats, key)
    out.update(
        first=first,
        end=end,
        rays=rays,
        texel_passes=texel_passes,
        converged=converged,
        seconds=time.perf_counter() - t0,
        worker=_where(),
    )
    return out


_scenes: dict = {}  # digest -> BakeScene, the last few (a worker's bake points of one bake)


def points_task(scene_payload: bytes, scene_digest: str, atlas_payload: bytes) -> dict:
    """One task: the bake points of one atlas ((surface, width, height) pickled), against the
    Embree scene of the shipped BakeScene (built once per worker process and triangle content),
    as plain data (`plain`: a client inside Blender has other class names)."""
    from .. import bakepoints

    scene = _scenes.get(scene_digest)
    if scene is None:
        scene = pickle.loads(scene_payload)
        _scenes.clear()
        _scenes[scene_digest] = scene
    surface, width, height = pickle.loads(atlas_payload)
    occluders = shipping.ray_scene(scene.triangles) if len(scene.triangles) else None
    # one thread: a worker process is one of many on its machine; the points do not depend on it
    return plain(bakepoints.build(surface, width, height, occluders=occluders, threads=1))


def _unfinished(traced, t0: float, why: str) -> dict:
    """A finishing task's answer when the client must run the post stages: the TracedAtlas
    without its points (the client has them)."""
    return {
        "traced": plain(replace(traced, points=None)),
        "why": why,
        "seconds": time.perf_counter() - t0,
        "worker": _where(),
    }


def _worker_threads() -> int:
    """Threads of this Dask worker (1 outside one): the post stages' count here (their result
    does not depend on it)."""
    try:
        from distributed import get_worker

        return max(int(getattr(get_worker(), "nthreads", 1)), 1)
    except (ImportError, ValueError):
        return 1
