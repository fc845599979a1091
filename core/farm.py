"""The bake on a Dask cluster (a render farm), bit-identical to the local bake. No bpy.

`connect(address)` opens a `dask.distributed` client (imported here only: a bake without a
scheduler never imports Dask) and checks that every worker runs the same tracer code and the
same compiled packages as this process. `bake.run(..., farm=)` then traces every atlas as Dask
tasks, one per group of `chunks_per_task` fixed chunks of `BakeSettings.chunk_texels` texels,
each task running *every pass* of its chunks, and finishes each atlas in one more task
(`Farm.submit`, `Farm.finish`, below).

Bit-identical. A local bake adds, pass after pass, each chunk's estimate to per-texel running
statistics (`Statistics.add`, Welford per texel), and a chunk's estimate depends only on
(seed, pass, chunk index, its texels) (`WorkUnit`). A texel's statistics therefore depend only
on its own estimates in pass order, which a task reproduces by running the passes of its chunks
in order into statistics of its own; the client copies them into the atlas's statistics. The
result does not depend on the number of workers, the group size, retries, duplicates or the
order tasks finish in. The noise target's rule is the local scheduler's (`scheduler.py`): chunks
stay fixed, and the floor is fixed once from the atlas after MIN_ADAPTIVE_PASSES passes; so with
a noise target each group takes two tasks, the first MIN_ADAPTIVE_PASSES passes, then, with the
floor the client computed from all of them, the rest. A time budget is refused (`Farm.check`):
where it stops would depend on the farm's speed.

Shipping. The estimator (bake points, scene, lights; `tracer.shipping.Shipped`) is pickled once
per atlas, with this package's module names rewritten to the worker's `hhd_lightmapper` (inside
Blender the extension is `bl_ext.<repo>.hhd_lightmapper`), scattered to the cluster under a key
made from its content hash, fetched once per worker and unpickled once per worker process
(`shipping._receive`), where its Embree scenes are rebuilt once per triangle content
(`shipping.ray_scene`) and the compiled kernels load from numba's disk cache (`kernels.get`).

Bake points. `Farm.bake_points` runs `bakepoints.build` of every atlas as one task each, against
the BakeScene sent once to every worker; the BakePoints come back as plain data (`plain`,
`unplain`) and equal the local ones. They are not checkpointed (a restart builds them again).

Every atlas's tracing tasks start at once (`Farm.submit`, called by `bake.run` after the bake points);
`bake.run` then collects them atlas by atlas (`Farm.finish`) and starts each atlas's finishing task
(`finish_task`) once its tracing is done: on a worker, with the tracing results Dask moves there,
it reduces the statistics group by group to what the files take, builds the (compact)
TracedAtlas and runs `bake.finish_atlas` (seams, post stages, encoding), returning the encoded images and sidecars as plain data (`plain`); the client
only writes them (`bake.Staged`), so the farm traces and finishes the next atlases meanwhile. The
denoiser runs on a worker only with the client's own OIDN files (`denoiser_identity`,
`local_denoiser`); a task without them returns the TracedAtlas and the client finishes that atlas.
`Farm.runner` traces one atlas for `tracer.bake(..., runner=)` (tests, benches).

Nothing lost. A worker killed mid-task costs a retry of its task (Dask reschedules it; the
client resubmits a failed task RETRIES times; a failed finishing task with its inputs made anew
from the checkpoints). Each finished task's statistics are written to
`<out_dir>/.hhd_farm/<atlas>-<key>/` (key: a hash of the atlas's name, the estimator's bytes, the
tracer settings, the grouping and the code), so the same command run again resumes from them;
`Farm.finished()` deletes them once the bake's files are committed. `cancel()` (Ctrl-C on the
command line) cancels the farm's tasks and raises BakeCancelled. docs/farm.md is the user's side.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import importlib
import io
import os
import pickle
import platform
import re
import shutil
import socket
import sys
import time
import types
import uuid
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from .encoding import SH_FILE
from .errors import BakeCancelled, BakeError, DependencyMissing
from .tracer import scheduler, shipping
from .tracer.scheduler import Outcome, WorkUnit
from .tracer.settings import MIN_ADAPTIVE_PASSES, BakeSettings
from .tracer.statistics import Reduced, Statistics

#: The package name workers import (`pip install ".[farm]"` installs it under this name).
WORKER_PACKAGE = "hhd_lightmapper"
#: This process's name of the package: WORKER_PACKAGE, or Blender's `bl_ext.<repo>.hhd_lightmapper`.
PACKAGE = __name__[: -len(".core.farm")]
#: The hidden folder of the output folder holding finished tasks' checkpoints.
CHECKPOINTS = ".hhd_farm"
#: Fixed chunks per task (`BakeSettings.chunk_texels` texels each): long enough to hide a task's
#: overhead at usual sample counts (bench/results/farm.md has the per-task costs).
CHUNKS_PER_TASK = 4
#: Times the client submits a task again after it failed on the farm (beyond Dask's own
#: rescheduling of a task whose worker died), before the bake fails.
RETRIES = 2
#: How often the client looks for finished tasks and a cancel.
POLL_SECONDS = 0.05
#: Packages whose versions must match between the client and every worker.
MATCHED = ("numpy", "numba", "llvmlite", "embreex")
INSTALL_HINT = (
    "install Dask into the Python that runs the bake: `pip install \"dask[distributed]\"` "
    "(with Blender: `blender -b --python-expr \"import subprocess, sys; subprocess.check_call([sys.executable, "
    "'-m', 'pip', 'install', 'dask[distributed]'])\"`; docs/farm.md)"
)


# ---- names on the workers ---------------------------------------------------------------------


def _worker_module(module: str) -> str | None:
    """The worker's name of one of this package's modules; None for other modules."""
    if module == PACKAGE or module.startswith(PACKAGE + "."):
        return WORKER_PACKAGE + module[len(PACKAGE) :]
    return None


class _Module:
    """A module by name: pickled as `importlib.import_module(name)`."""

    def __init__(self, name: str):
        self.name = name

    def __reduce__(self):
        return importlib.import_module, (self.name,)


class _Named:
    """A module-level function `name` of this package's module `module`: callable here, pickled
    as the worker package's function of that name (pickle and cloudpickle would otherwise name
    this process's module, which a worker outside Blender cannot import)."""

    def __init__(self, module: str, name: str):
        self.module, self.__name__ = module, name
        self.function = getattr(importlib.import_module(module), name)

    def __call__(self, *args, **kwargs):
        return self.function(*args, **kwargs)

    def __reduce__(self):
        return getattr, (_Module(_worker_module(self.module) or self.module), self.__name__)


class _Pickler(pickle.Pickler):
    """Pickles with this package's classes and functions named as the workers import them, and a
    `Shipped` context as its plain state (no live Embree objects)."""

    def reducer_override(self, obj):
        if isinstance(obj, shipping.Shipped):
            return _Named(shipping.__name__, "_receive"), ship(obj)
        if PACKAGE != WORKER_PACKAGE and isinstance(obj, type | types.FunctionType):
            module = _worker_module(getattr(obj, "__module__", None) or "")
            if module is not None and "." not in obj.__qualname__:
                return getattr, (_Module(module), obj.__qualname__)
        return NotImplemented


def ship(obj: shipping.Shipped) -> tuple[str, bytes]:
    """(digest, payload) of a Shipped context, `shipping._receive(digest, payload)` rebuilding it
    in a worker: its state without live attributes, pickled with worker names."""
    state = {k: v for k, v in obj.__dict__.items() if k not in obj._live and k != "_shipped"}
    payload = dumps((type(obj), state))
    return hashlib.blake2b(payload, digest_size=16).hexdigest(), payload


def dumps(obj) -> bytes:
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buffer.getvalue()


# ---- what a worker runs -----------------------------------------------------------------------


_fingerprint: str | None = None


def code_fingerprint() -> str:
    """Hash of the core's Python sources (every module the tracer may run): client and workers
    must trace with the same code."""
    global _fingerprint
    if _fingerprint is None:
        h = hashlib.blake2b(digest_size=12)
        root = Path(__file__).resolve().parent
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
    first_pass, end_pass = passes if passes is not None else (0, max_passes(trace))
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
    from . import bakepoints

    scene = _scenes.get(scene_digest)
    if scene is None:
        scene = pickle.loads(scene_payload)
        _scenes.clear()
        _scenes[scene_digest] = scene
    surface, width, height = pickle.loads(atlas_payload)
    occluders = shipping.ray_scene(scene.triangles) if len(scene.triangles) else None
    # one thread: a worker process is one of many on its machine; the points do not depend on it
    return plain(bakepoints.build(surface, width, height, occluders=occluders, threads=1))


# ---- the finishing task: post stages and encoding of one atlas on a worker ---------------------

#: The worker's OIDN library (a file, or a folder holding it), when it has no pip `bpy` to take it from.
OIDN_ENV = "HHD_OIDN_LIBRARY"
#: Finished tracing statistics a finishing task assembles (`trace_group`'s arrays).
STATISTICS = ("total", "m2", "iz", "iz_sq", "passes")

_identities: dict[str, str | None] = {}  # library path -> denoiser_identity


def denoiser_identity(library: str) -> str | None:
    """What makes a process's denoised SH what it is: a hash of the OIDN library `library` and
    the core and CPU-device libraries beside it (same files, same version and build: same
    bits), or None when nothing can denoise with it here (no library, or the RTLightmap weights
    (`core.oidn.WEIGHTS`, hash-checked) missing)."""
    if not library:
        return None
    if library not in _identities:
        from . import oidn

        path = Path(library)
        try:
            for mode in oidn.WEIGHTS:
                oidn.load_weights(mode)
            h = hashlib.blake2b(digest_size=12)
            siblings = [
                *path.parent.glob("*OpenImageDenoise_core*"),
                *path.parent.glob("*OpenImageDenoise_device_cpu*"),
            ]
            for f in [path, *sorted(siblings)]:
                h.update(f.name.encode() + b"\0" + f.read_bytes())
            _identities[library] = h.hexdigest()
        except (OSError, oidn.DenoiserError):
            _identities[library] = None
    return _identities[library]


def local_denoiser() -> tuple[str, str | None]:
    """This process's OIDN library and its `denoiser_identity` ("", None: none): the file or
    folder of $HHD_OIDN_LIBRARY, else the library of a pip-installed `bpy` (found without
    importing it), the one Blender's Python module ships."""
    from . import oidn

    setting = os.environ.get(OIDN_ENV, "")
    if setting:
        path = Path(setting)
        found = path if path.is_file() else oidn.find_library([path, path / "lib"])
    else:  # the pip `bpy`'s folder: its lib/ (Linux, macOS) or itself (Windows), `bridge/denoiser.py`
        # Every sys.path entry, not `find_spec("bpy")`: once bpy was imported in the process that
        # started this worker, Blender's scripts/modules (holding a pure-Python `bpy` package) can
        # come first on the path a spawned worker inherits.
        packages = [Path(entry) / "bpy" for entry in sys.path if entry]
        found = oidn.find_library([d for package in packages for d in (package / "lib", package)])
    library = "" if found is None else str(found)
    return library, denoiser_identity(library)


class _Kept:
    """A finishing task's stand-in for `bake.Staged`: keeps the finished files' data, in the
    order the atlas handed them, as plain data for the client to stage."""

    def __init__(self):
        self.calls: list[tuple[str, tuple]] = []

    def raw(self, name: str, parent: str, images_of: dict) -> None:
        # copies: the images are views of the SH the post stages then write into
        kept = {key: (spec, {n: np.array(a) for n, a in images.items()}) for key, (spec, images) in images_of.items()}
        self.calls.append(("raw", (name, parent, plain(kept))))

    def traced_sh(self, name: str, parent: str) -> np.ndarray:
        """The SH image `(H, W, 9, 3)` of the raw SH file kept for `name` (as `bake.Staged`'s)."""
        for method, (kept, _, images_of) in reversed(self.calls):
            if method == "raw" and kept == name:
                images = images_of[SH_FILE.key][1]
                sh = np.stack([images[n] for n in SH_FILE.exr_names], axis=-1)
                return sh.reshape(sh.shape[:2] + (9, 3))
        raise KeyError(f"no raw SH file kept for {name!r}")

    def atlas(self, name: str, parent: str, encoded, sidecar: dict) -> None:
        self.calls.append(("atlas", (name, parent, plain(encoded), copy.deepcopy(sidecar))))

    def seams(self, name: str, atlas_seams) -> None:
        self.calls.append(("seams", (name, plain(atlas_seams))))


def finish_task(payload: bytes, digest: str, code: str, meta: bytes, *results: dict) -> dict:
    """One task per atlas, run once its tracing tasks are done (`results`: the last stage's of
    every group, which Dask brings to this worker): the atlas's statistics reduced group by group,
    its compact TracedAtlas built (`tracer.traced_atlas`), then `bake.finish_atlas` (seams, post stages,
    encoding) exactly as a local bake runs them. `meta` (pickled with worker names): atlas
    (AtlasInput without its surface), settings (PipelineSettings), t_points, extra, rays,
    stopped_by, seconds, denoiser (the client's `denoiser_identity`; None: its OIDN cannot run,
    so the client finishes the atlas). Returns plain data: "out", the files to stage in order, and "summary";
    or, when this worker cannot denoise as the client would (another or no OIDN library, or
    OIDN failing here), "traced", the TracedAtlas without its points, for the client to finish."""
    from . import bake, tracer

    _same_code(code)
    t0 = time.perf_counter()
    estimator = shipping._receive(digest, payload)
    m = pickle.loads(meta)
    settings, points, sets = m["settings"], estimator.points, estimator.scene.sets
    # reduced group by group to what the files take, as a local bake's (`tracer.bake(..., compact=True)`)
    reduced = Reduced(points.normal, estimator.scene.channels, points.buried, bool(sets))
    for result in results:
        first, end = int(result["first"]), int(result["end"])
        stats = reduced.statistics(first, end)
        for key in STATISTICS:
            getattr(stats, key)[:] = result[key]
        reduced.take(first, stats)
    outcome = Outcome(m["stopped_by"], m["rays"])
    traced = tracer.traced_atlas(points, sets, reduced, settings.trace, outcome, m["seconds"])
    library = settings.denoiser_library  # "" (the client has none): undenoised here as there, same warning
    denoising = settings.denoise and bool(library)
    if denoising:
        library, identity = local_denoiser()
        if m["denoiser"] is None or identity != m["denoiser"]:  # None: the client's OIDN cannot run
            return _unfinished(traced, t0, "no OIDN library here like the client's")
    threads = _worker_threads()
    compute = replace(settings, denoiser_library=library, trace=replace(settings.trace, threads=threads))
    kept = _Kept()
    summary = bake.finish_atlas(  # released SH only where no fallback may need it
        m["atlas"], traced, compute, m["t_points"], m["extra"], kept, recorded=settings.trace, release=not denoising
    )
    if denoising and not all(args[3]["post"]["denoise"].get("applied") for kind, args in kept.calls if kind == "atlas"):
        return _unfinished(traced, t0, "OIDN failed here")
    return {"out": kept.calls, "summary": plain(summary), "seconds": time.perf_counter() - t0, "worker": _where()}


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


def plain(obj):
    """This package's dataclass instances (nested, also inside dicts, lists and tuples) as dicts
    naming their class relative to the package, its classes and functions as dicts naming them
    the same way, everything else as it is: what a worker returns
    to a client that may name the package otherwise (`unplain` there)."""
    cls = type(obj)
    if cls is dict:
        return {k: plain(v) for k, v in obj.items()}
    if cls is list or cls is tuple:
        return cls(plain(v) for v in obj)
    module = getattr(cls, "__module__", "") or ""
    if hasattr(obj, "__dataclass_fields__") and _worker_module(module) is not None:
        return {"__class__": (module[len(PACKAGE) :], cls.__qualname__), **{k: plain(v) for k, v in vars(obj).items()}}
    module = getattr(obj, "__module__", "") or ""
    if isinstance(obj, type | types.FunctionType) and _worker_module(module) is not None:
        return {"__object__": (module[len(PACKAGE) :], obj.__qualname__)}  # e.g. a Channel's `pack`
    return obj


def unplain(obj):
    """The inverse of `plain`, with this process's classes."""
    cls = type(obj)
    if cls is dict and "__class__" in obj:
        module, name = obj["__class__"]
        cls = getattr(importlib.import_module(PACKAGE + module), name)
        instance = cls.__new__(cls)
        instance.__dict__.update({k: unplain(v) for k, v in obj.items() if k != "__class__"})
        return instance
    if cls is dict and "__object__" in obj:
        module, name = obj["__object__"]
        found = importlib.import_module(PACKAGE + module)
        for part in name.split("."):
            found = getattr(found, part)
        return found
    if cls is dict:
        return {k: unplain(v) for k, v in obj.items()}
    if cls is list or cls is tuple:
        return cls(unplain(v) for v in obj)
    return obj


def max_passes(settings: BakeSettings) -> int:
    return max(1, -(-settings.samples // settings.pass_samples))


# ---- the client -------------------------------------------------------------------------------


def _probe(address: str, timeout: float) -> None:
    """BakeError at once when a tcp:// scheduler address cannot be reached because nothing
    listens there or the host is unknown: Dask's client would retry until its `timeout`. Any
    other outcome (it answers, or does not answer in time) is left to the client."""
    scheme, sep, rest = address.rpartition("://")
    host, colon, port = rest.rpartition(":")
    if (sep and scheme != "tcp") or not colon:
        return  # another protocol, or Dask's default port
    try:
        with socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=min(timeout, 5.0)):
            return
    except ValueError:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: expected tcp://HOST:PORT") from None
    except (ConnectionRefusedError, socket.gaierror) as exc:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    except OSError:
        return


def connect(address: str, chunks_per_task: int = CHUNKS_PER_TASK, timeout: float = 30.0) -> Farm:
    """A Farm on the Dask scheduler at `address` (e.g. tcp://host:8786), after checking that at
    least one worker is there and every worker's `environment()` matches this process's (else
    BakeError naming what differs). DependencyMissing when Dask is not installed here."""
    try:
        import distributed
    except ImportError:
        if PACKAGE == WORKER_PACKAGE:  # the package as pip installs it
            raise DependencyMissing(f"--scheduler needs Dask, which this Python lacks: {INSTALL_HINT}") from None
        raise DependencyMissing(  # the extension, which bundles Dask's wheels
            "--scheduler needs Dask, which the extension bundles as wheels, but Blender's Python cannot import it: "
            "reinstall the extension from the zip for this platform (Blender installs an extension's wheels when it "
            f"enables it; 4.2.13 or newer), or {INSTALL_HINT}"
        ) from None
    _probe(address, timeout)
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except ValueError as exc:  # a malformed address (the CLI refuses those before; a scene setting may hold one)
        raise BakeError(f"'{address}' is not a Dask scheduler address ({exc}): give tcp://HOST:PORT") from None
    except (OSError, TimeoutError) as exc:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise BakeError(f"the Dask scheduler at {address} has no worker (start `dask worker {address}`)") from None
        farm = Farm(client, address, chunks_per_task)
        farm.warnings = check_workers(client.run(_Named(__name__, "environment"), on_error="return"))
        return farm
    except BaseException:
        client.close()
        raise


def check_workers(envs: dict) -> list[str]:
    """BakeError if a worker cannot run the bake or runs other code or package versions than this
    process; returns warnings (workers of other CPU targets: see docs/farm.md)."""
    mine = environment()
    problems: list[str] = []
    cpus: dict[tuple, list[str]] = {}
    for worker, env in sorted(envs.items()):
        if isinstance(env, BaseException):
            hint = (
                f" (install it on the workers: pip install \"{WORKER_PACKAGE}[farm]\")"
                if isinstance(env, ImportError)
                else ""
            )
            problems.append(f"{worker}: {type(env).__name__}: {env}{hint}")
            continue
        differ = [f"{k} {env.get(k)} (here {mine[k]})" for k in ("code", "python", *MATCHED) if env.get(k) != mine[k]]
        if differ:
            problems.append(f"{worker}: {', '.join(differ)}")
        cpus.setdefault((env.get("cpu"), env.get("embree_config"), env.get("machine")), []).append(worker)
    if problems:
        raise BakeError(
            "the farm's workers do not match this bake's versions (a farm bake is bit-identical to a local bake only "
            "with the same code and packages): " + "; ".join(problems)
        )
    if len(cpus) > 1:
        kinds = "; ".join(f"cpu {c}, Embree '{e}', {m}: {len(w)} worker(s)" for (c, e, m), w in cpus.items())
        return [
            f"the farm's workers are of {len(cpus)} CPU kinds ({kinds}): results may differ in the last bits "
            "between them; pin NUMBA_CPU_NAME and HHD_EMBREE_CONFIG on every worker (docs/farm.md)"
        ]
    return []


class Finishing:
    """One atlas's finishing task on the farm (`Farm.finish`): its name, its tracing's plan
    (without the estimator's bytes), the task's arguments, the workers it should run on (none:
    any), its future; `estimator`: to ship again for a retry."""

    def __init__(self, name: str, plan: dict, args: tuple, workers: list[str], estimator):
        self.name, self.args, self.workers, self.estimator = name, args, workers, estimator
        self.plan = {k: v for k, v in plan.items() if k not in ("payload", "data")}
        self.future: Any = None  # a distributed.Future once started
        self.retries = 0

    def done(self) -> bool:
        return self.future is not None and self.future.done()


class Farm:
    """A connected Dask client: `submit` starts an atlas's tracing, `finish` its finishing task
    (`result` waits for it); `runner(name, out_dir)` traces one atlas alone (tests, benches)."""

    def __init__(self, client, address: str, chunks_per_task: int = CHUNKS_PER_TASK):
        if chunks_per_task < 1:
            raise BakeError(f"chunks per task must be ≥ 1, got {chunks_per_task}")
        self.client, self.address, self.chunks_per_task = client, address, chunks_per_task
        self.warnings: list[str] = []
        self.checkpoints: list[Path] = []
        self.tasks: list[dict] = []  # per finished task: seconds, worker, texels (bench/farm.py)
        self._submitted: dict[str, dict] = {}  # checkpoint key -> {future: group} started by `submit`
        self._points: list = []  # the futures of `bake_points`
        self._finishing: list[Finishing] = []  # finishing tasks not collected yet
        self._oidn: dict[str, list[str]] = {}  # the client's denoiser identity -> workers of the same
        self.finishing: list[dict] = []  # per finished atlas: seconds, worker, finished_on (bench/farm.py)

    def __enter__(self) -> Farm:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.cancel_all()
        self.client.close()

    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    @staticmethod
    def check(settings: BakeSettings) -> None:
        """BakeError for settings a farm cannot bake reproducibly (a time budget)."""
        if settings.time_budget:
            raise BakeError(
                "a time budget cannot be used with --scheduler: where it stops depends on the farm's speed, so the "
                "result would not be reproducible; use --samples or --noise-target instead"
            )

    def runner(self, name: str, out_dir) -> Callable[..., Outcome]:
        """A stand-in for `tracer.scheduler.run` tracing atlas `name` on the farm, its finished
        tasks checkpointed under `out_dir`/.hhd_farm."""

        def run(estimator, stats, settings, start, progress=None, cancel=None, executor=None) -> Outcome:
            return self._trace(name, Path(out_dir), estimator, stats, settings, start, progress, cancel)

        return run

    def finished(self) -> None:
        """The bake's files are committed: delete its checkpoints."""
        for folder in self.checkpoints:
            shutil.rmtree(folder, ignore_errors=True)
        for folder in {f.parent for f in self.checkpoints}:
            try:
                folder.rmdir()  # only when empty (another bake's may be there)
            except OSError:
                pass
        self.checkpoints = []

    def bake_points(self, atlases, scene, cancel: Callable[[], bool] | None = None) -> list[Callable[[], object]]:
        """Start the bake points of every atlas (`core.bake.AtlasInput`) on the farm, against
        `scene` (BakeScene); returns per atlas a function waiting for its BakePoints (the same
        as `bakepoints.build` here; BakeCancelled when `cancel()` turns True meanwhile). The scene
        is sent once, to every worker."""
        payload = dumps(scene)
        digest = hashlib.blake2b(payload, digest_size=16).hexdigest()
        [data] = self.client.scatter([payload], hash=True, broadcast=True)
        task = _Named(__name__, "points_task")
        futures = [
            self.client.submit(task, data, digest, dumps((a.surface, a.width, a.height)), pure=False) for a in atlases
        ]
        self._points = futures
        return [functools.partial(self._wait_points, f, a.name, cancel) for f, a in zip(futures, atlases)]

    def _wait_points(self, future, name: str, cancel) -> object:
        while not future.done():
            if cancel is not None and cancel():
                self.cancel_all()
                raise BakeCancelled("bake cancelled")
            time.sleep(POLL_SECONDS)
        try:
            result = future.result()
        except BakeError:
            raise
        except Exception as exc:  # the worker's error, KilledWorker
            raise BakeError(
                f"the bake points of atlas '{name}' failed on the farm: {type(exc).__name__}: {exc}"
            ) from exc
        future.release()
        return unplain(result)

    def submit(self, name: str, out_dir, estimator, settings: BakeSettings) -> None:
        """Start tracing atlas `name` now (its first stage's tasks not checkpointed yet), so the
        farm works on every atlas while the client collects and writes one after the other
        (`bake.run` submits them all after the bake points). `finish` (or `tracer.bake(...,
        runner=)`) with the same estimator and settings then picks these tasks up."""
        plan = self._plan(name, Path(out_dir), estimator, settings)
        if plan["key"] not in self._submitted:
            self._submitted[plan["key"]] = self._submit(plan, 0, None, self._saved(plan, 0))

    def _plan(self, name: str, out_dir: Path, estimator, settings: BakeSettings) -> dict:
        """What the tasks of one atlas need: its chunk groups, stages, the estimator's bytes and
        the key of its checkpoints."""
        self.check(settings)
        n = len(estimator.points.texel)
        chunks = [(c, int(a[0]), int(a[-1]) + 1) for c, a in enumerate(scheduler.chunks(settings, n))]
        groups = [chunks[g : g + self.chunks_per_task] for g in range(0, len(chunks), self.chunks_per_task)]
        digest, payload = ship(estimator)
        trace = {k: v for k, v in asdict(settings).items() if k != "threads"}
        code = code_fingerprint()
        key = hashlib.blake2b(
            repr((name, digest, sorted(trace.items()), self.chunks_per_task, code)).encode(), digest_size=10
        ).hexdigest()
        passes = max_passes(settings)
        two_stages = bool(settings.noise_target) and passes >= MIN_ADAPTIVE_PASSES
        return {
            "name": name,
            "key": key,
            "folder": out_dir / CHECKPOINTS / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}-{key}",
            "groups": groups,
            "digest": digest,
            "payload": payload,
            "trace": trace,
            "code": code,
            "stages": [(0, MIN_ADAPTIVE_PASSES), (MIN_ADAPTIVE_PASSES, passes)] if two_stages else [(0, passes)],
        }

    def _saved(self, plan: dict, stage: int) -> dict[int, dict]:
        """The checkpointed results of one stage, by group."""
        saved = {}
        for g in range(len(plan["groups"])):
            result = _load(plan["folder"] / f"task-{g}-{stage}.npz")
            if result is not None:
                saved[g] = result
        return saved

    def _submit(self, plan: dict, stage: int, floor: float | None, saved: dict, only=None) -> dict:
        """Submit the tasks of one stage that no checkpoint holds (of the groups `only`, if
        given): {future: group}."""
        pending = {}
        todo = [g for g in (range(len(plan["groups"])) if only is None else only) if g not in saved]
        if todo:
            if "data" not in plan:
                # content-keyed, copied to every worker: a dying worker does not take the only copy
                [plan["data"]] = self.client.scatter([plan["payload"]], hash=True, broadcast=True)
            task = _Named(__name__, "trace_group")
            for g in todo:
                state = _load(plan["folder"] / f"task-{g}-0.npz") if stage == 1 else None
                future = self.client.submit(
                    task,
                    plan["data"],
                    plan["digest"],
                    plan["trace"],
                    plan["code"],
                    plan["groups"][g],
                    plan["stages"][stage],
                    state,
                    floor,
                    key=f"hhd-{plan['key']}-{stage}-{g}-{uuid.uuid4().hex[:8]}",  # unique: a cancelled one may linger
                    pure=False,
                )
                pending[future] = g
        return pending

    def _trace(self, name, out_dir: Path, estimator, stats: Statistics, settings, start, progress, cancel) -> Outcome:
        plan = self._plan(name, out_dir, estimator, settings)
        rays, stopped_by, _ = self._collect(plan, stats, settings, start, progress, cancel)
        plan.pop("data", None)
        return Outcome(stopped_by, rays)

    def _collect(
        self, plan: dict, stats, settings: BakeSettings, start: float, progress, cancel, keep: bool = False
    ) -> tuple[int, str, dict]:
        """Run (or load from checkpoints) every task of one atlas, checkpointing each as it
        finishes and copying its arrays into `stats` (those of STATISTICS it has: a finishing
        bake keeps only what the noise target's floor needs). Returns the rays traced, what
        stopped the bake, and with `keep` the last stage's result per group (its future, kept
        on the farm for the finishing task, or a checkpoint's arrays)."""
        folder, groups = plan["folder"], plan["groups"]
        folder.mkdir(parents=True, exist_ok=True)
        if folder not in self.checkpoints:
            self.checkpoints.append(folder)
        rays, converged, done = 0, True, 0
        of = len(groups) * len(plan["stages"])
        last = len(plan["stages"]) - 1
        final: dict = {}

        def add(g: int, result, stage: int) -> None:
            nonlocal rays, converged, done
            first, end = int(result["first"]), int(result["end"])
            for k in STATISTICS:
                if getattr(stats, k, None) is not None:
                    getattr(stats, k)[first:end] = result[k]
            stats.texel_passes += int(result["texel_passes"])
            rays += int(result["rays"])
            if stage == last:
                converged &= bool(result["converged"])
            done += 1
            if progress:
                elapsed = max(time.perf_counter() - start, 1e-9)
                progress(
                    done / of,
                    f"farm: {done} of {of} tasks, {rays / elapsed / 1e6:.2f} M rays/s, "
                    f"{stats.texel_passes * settings.pass_samples / elapsed / 1e3:.0f} k texel-samples/s",
                )

        retries: dict[int, int] = {}
        for s in range(len(plan["stages"])):
            floor = stats.floor() if s == 1 else None  # the atlas's, after the first stage (scheduler.py)
            saved = self._saved(plan, s)
            for g, result in saved.items():
                add(g, result, s)
                if keep and s == last:
                    final[g] = result
            submitted = self._submitted.pop(plan["key"], None) if s == 0 else None
            if submitted is not None:  # `submit` started them: drop those a checkpoint now holds
                pending = {f: g for f, g in submitted.items() if g not in saved}
                self.client.cancel([f for f, g in submitted.items() if g in saved])
            else:
                pending = self._submit(plan, s, floor, saved)
            try:
                while pending:
                    finished = [f for f in pending if f.done()]
                    if not finished:
                        time.sleep(POLL_SECONDS)
                    for future in [*finished, None]:
                        if cancel is not None and cancel():
                            raise BakeCancelled("bake cancelled")
                        if future is None:
                            break
                        g = pending.pop(future)
                        try:
                            result = future.result()
                        except BakeError:
                            raise
                        except Exception as exc:  # KilledWorker, a worker's error, lost data, a cancel on the farm
                            retries[g] = retries.get(g, 0) + 1
                            if retries[g] > RETRIES:
                                raise BakeError(
                                    f"farm task {g} of atlas '{plan['name']}' failed: {type(exc).__name__}: {exc}"
                                ) from exc
                            plan.pop("data", None)  # scattered again: its copies may be what was lost
                            pending.update(self._submit(plan, s, floor, {}, only=[g]))
                            continue
                        _save(folder / f"task-{g}-{s}.npz", result)
                        self.tasks.append(
                            {
                                "seconds": float(result["seconds"]),
                                "worker": result["worker"],
                                "texels": len(result["iz"]),
                            }
                        )
                        add(g, result, s)
                        if keep and s == last:
                            final[g] = future  # its data stays on the farm for the finishing task
                        else:
                            future.release()
            except BaseException:
                self.cancel_all()
                raise
            finally:
                if pending:  # cancelled or failed: no task of this bake keeps running on the farm
                    self.client.cancel(list(pending), force=True)
        two_stages = len(plan["stages"]) == 2
        stopped = "noise_target" if two_stages and converged and len(stats.passes) else "samples"
        return rays, stopped, final

    # ---- finishing on the farm: post stages and encoding per atlas ----------------------------

    def finish(
        self, atlas, settings, out_dir, estimator, t_points: float, extra: dict, progress=None, cancel=None
    ) -> Finishing:
        """Collect the tracing of `atlas` (`core.bake.AtlasInput`; started by `submit`, or
        started now) with `estimator` (as `submit`'s), then start its finishing task
        (`finish_task`: post stages and encoding on a worker, ahead of queued tracing tasks);
        returns at once with its handle (`result` waits). `settings`: the PipelineSettings;
        `t_points`, `extra`: the sidecar's bake-point seconds and extra entries."""
        start = time.perf_counter()
        plan = self._plan(atlas.name, Path(out_dir), estimator, settings.trace)
        n = len(estimator.points.texel)
        floor_stats = Statistics.__new__(Statistics)  # only what the noise target's floor reads
        floor_stats.iz, floor_stats.passes, floor_stats.texel_passes = np.zeros(n), np.zeros(n, np.int64), 0
        rays, stopped_by, final = self._collect(plan, floor_stats, settings.trace, start, progress, cancel, keep=True)
        saved = {g: r for g, r in final.items() if isinstance(r, dict)}
        if saved:  # checkpointed results travel to the farm as data
            for g, future in zip(saved, self.client.scatter(list(saved.values()))):
                final[g] = future
        if "data" not in plan:
            [plan["data"]] = self.client.scatter([plan["payload"]], hash=True, broadcast=True)
        identity = denoiser_identity(settings.denoiser_library) if settings.denoise else None
        meta = dumps(
            {
                "atlas": replace(atlas, surface=None),
                "settings": settings,
                "t_points": t_points,
                "extra": extra,
                "rays": rays,
                "stopped_by": stopped_by,
                "seconds": time.perf_counter() - start,
                "denoiser": identity,
            }
        )
        args = (plan["data"], plan["digest"], plan["code"], meta, *[final[g] for g in range(len(plan["groups"]))])
        workers = self._denoisers(identity) if identity is not None else []
        handle = Finishing(atlas.name, plan, args, workers, estimator)
        self._start(handle)
        return handle

    def _reload(self, handle: Finishing) -> None:
        """The arguments of a failed finishing task made anew from what cannot be lost: the
        estimator shipped again and the tracing results from their checkpoints (a dead worker may
        have held the only copy of either: Dask keeps one replica of scattered data)."""
        plan = handle.plan
        last = len(plan["stages"]) - 1
        results = [_load(plan["folder"] / f"task-{g}-{last}.npz") for g in range(len(plan["groups"]))]
        if any(r is None for r in results):
            raise BakeError(f"the checkpoints of atlas '{handle.name}' are gone from {plan['folder']}: bake again")
        _, payload = ship(handle.estimator)
        [data] = self.client.scatter([payload], hash=True, broadcast=True)
        handle.args = (data, *handle.args[1:4], *self.client.scatter(results))

    def _denoisers(self, identity: str) -> list[str]:
        """The workers whose OIDN is the client's (`denoiser_identity` `identity`), asked once
        per farm: the finishing tasks of a denoised bake go to them first."""
        if identity not in self._oidn:
            found = self.client.run(_Named(__name__, "local_denoiser"), on_error="return")
            self._oidn[identity] = sorted(
                w for w, r in found.items() if not isinstance(r, BaseException) and r[1] == identity
            )
        return self._oidn[identity]

    def _start(self, handle: Finishing) -> None:
        """Submit (again) the finishing task of `handle`."""
        handle.future = self.client.submit(
            _Named(__name__, "finish_task"),
            *handle.args,
            key=f"hhd-finish-{handle.plan['key']}-{uuid.uuid4().hex[:8]}",
            pure=False,
            priority=1,  # before the tracing tasks still queued: the client writes sooner
            workers=handle.workers or None,
            allow_other_workers=bool(handle.workers),  # another worker if none of them is left
        )
        self._finishing.append(handle)

    def result(self, handle: Finishing, cancel=None) -> tuple[str, object]:
        """Wait for the finishing task of `handle`: ("out", {"out": the files to stage in order
        [(method of `bake.Staged`, args)], "summary": `bake.finish_atlas`'s}) or ("traced", a
        TracedAtlas without points: this client must finish it, `finish_task`). BakeCancelled
        when `cancel()` turns True; a failed task is submitted again RETRIES times."""
        try:
            while True:
                while True:  # a cancel is seen before an answer is taken, even one already there
                    if cancel is not None and cancel():
                        raise BakeCancelled("bake cancelled")
                    if handle.future.done():
                        break
                    time.sleep(POLL_SECONDS)
                try:
                    answer = handle.future.result()
                    break
                except BakeError:
                    raise
                except Exception as exc:  # KilledWorker, a worker's error, lost inputs
                    handle.retries += 1
                    if handle.retries > RETRIES:
                        raise BakeError(
                            f"the finishing task of atlas '{handle.name}' failed on the farm: {type(exc).__name__}: {exc}"
                        ) from exc
                    self._finishing.remove(handle)
                    self._reload(handle)
                    self._start(handle)
        except BaseException:
            self.cancel_all()
            raise
        self._finishing.remove(handle)
        handle.future.release()
        handle.args, handle.estimator = (), None  # the tracing results and the estimator may go from the farm
        record = {"atlas": handle.name, "seconds": float(answer["seconds"]), "worker": answer["worker"]}
        where = "client" if "traced" in answer else "worker"
        self.finishing.append({**record, "finished_on": where, "bytes": _nbytes(answer)})
        if "traced" in answer:
            return "traced", unplain(answer["traced"])
        return "out", {"out": unplain(answer["out"]), "summary": unplain(answer["summary"])}

    def cancel_all(self) -> None:
        """Cancel the tasks `submit` and `bake_points` started that were not collected yet."""
        for submitted in self._submitted.values():
            self.client.cancel(list(submitted), force=True)
        self._submitted.clear()
        if self._points:
            self.client.cancel(self._points, force=True)
            self._points = []
        if self._finishing:
            self.client.cancel([h.future for h in self._finishing], force=True)
            self._finishing = []


def _nbytes(obj) -> int:
    """Bytes of the arrays in `obj` (nested dicts, lists, tuples): what a task's answer carried."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(_nbytes(v) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(_nbytes(v) for v in obj)
    return 0


def _save(path: Path, result: dict) -> None:
    tmp = path.with_suffix(".tmp.npz")
    arrays: dict = {k: np.asarray(v) for k, v in result.items() if k != "worker"}
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _load(path: Path) -> dict | None:
    """A checkpoint's arrays, or None if missing or unreadable (then the task runs again)."""
    if not path.exists():
        return None
    try:
        with np.load(path) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError, KeyError):
        path.unlink(missing_ok=True)
        return None
