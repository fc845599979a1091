"""The finishing task: the post stages and encoding of one atlas on a worker (`finish_task`),
with the client's own denoiser only (`denoiser_identity`, `local_denoiser`). No bpy."""

from __future__ import annotations

import copy
import hashlib
import os
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import memory
from ..encoding import SH_FILE
from ..tracer import shipping
from ..tracer.scheduler import Outcome
from ..tracer.statistics import Reduced
from .names import plain
from .worker import _same_code, _unfinished, _where, _worker_threads

#: The worker's OIDN library (a file, or a folder holding it), when it has no pip `bpy` to take it from.
OIDN_ENV = "HHD_OIDN_LIBRARY"


#: Finished tracing statistics a finishing task assembles (`trace_group`'s arrays).
STATISTICS = ("total", "m2", "iz", "iz_sq", "passes")


_identities: dict[str, str | None] = {}  # library path -> denoiser_identity


def denoiser_identity(library: str) -> str | None:
    """What makes a process's denoised SH what it is: a hash of the OIDN library `library` and
    the core and CPU-device libraries beside it (same files, same version and build: same
    bits), or None when nothing can denoise with it here (no library, or the RTLightmap weights
    (`core.post.denoise.oidn.WEIGHTS`, hash-checked) missing)."""
    if not library:
        return None
    if library not in _identities:
        from ..post.denoise import oidn

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
    from ..post.denoise import oidn

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
    """A finishing task's stand-in for `bake.finishing.Staged`: keeps the finished files' data, in the
    order the atlas handed them, as plain data for the client to stage."""

    def __init__(self):
        self.calls: list[tuple[str, tuple]] = []

    def raw(self, name: str, parent: str, images_of: dict) -> None:
        # copies: the images are views of the SH the post stages then write into
        kept = {key: (spec, {n: np.array(a) for n, a in images.items()}) for key, (spec, images) in images_of.items()}
        self.calls.append(("raw", (name, parent, plain(kept))))

    def traced_sh(self, name: str, parent: str) -> np.ndarray:
        """The SH image `(H, W, 9, 3)` of the raw SH file kept for `name` (as `bake.finishing.Staged`'s)."""
        for method, args in reversed(self.calls):  # `seams` and `atlas` calls have other arguments
            if method == "raw" and args[0] == name:
                images = args[2][SH_FILE.key][1]
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
    its compact TracedAtlas built (`tracer.traced_atlas`), then `bake.finishing.finish_atlas` (seams, post stages,
    encoding) exactly as a local bake runs them. `meta` (pickled with worker names): atlas
    (AtlasInput without its surface), settings (PipelineSettings), t_points, extra, rays,
    stopped_by, seconds, denoiser (the client's `denoiser_identity`; None: its OIDN cannot run,
    so the client finishes the atlas). Returns plain data: "out", the files to stage in order, and "summary";
    or, when this worker cannot denoise as the client would (another or no OIDN library, or
    OIDN failing here), "traced", the TracedAtlas without its points, for the client to finish."""
    from .. import tracer
    from ..bake.finishing import finish_atlas

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
    # `finish_atlas` spends the SH it is handed: the client's fallback (OIDN failing here) needs it
    spent = replace(traced, sh=memory.keep(traced.sh), sh_error=memory.keep(traced.sh_error)) if denoising else traced
    summary = finish_atlas(m["atlas"], spent, compute, m["t_points"], m["extra"], kept, recorded=settings.trace)
    if denoising and not all(args[3]["post"]["denoise"].get("applied") for kind, args in kept.calls if kind == "atlas"):
        return _unfinished(traced, t0, "OIDN failed here")
    return {"out": kept.calls, "summary": plain(summary), "seconds": time.perf_counter() - t0, "worker": _where()}
