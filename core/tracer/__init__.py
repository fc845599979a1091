"""Path-traced L2 SH bake on Embree: per bake point, incident radiance over the hemisphere of
n_v projected to world-space radiance SH (`bake` -> `core.stages.TracedAtlas`). No bpy.

The stages, one module each:
  * `lights`: every light type behind one interface (`Light`: sample, pdf, evaluate, power,
    group), sun / point / spot / area lights (next-event estimation only), the HDRI world and
    the emissive triangles (also reached by rays: MIS);
  * `paths`: the one radiance function (`Paths.radiance`: a wavefront over bounces with
    Russian roulette and next-event estimation at every vertex) and the scene it traces in
    (`TraceScene`); it knows nothing of texels;
  * `hemisphere`: the texel estimator (`TexelEstimator`): origins over each texel's footprint,
    mixture-pdf hemisphere directions, the SH projection and the direct light at the bake point;
  * `scheduler`: passes cut into deterministic work units run on any executor, merged in unit
    order; progress, cancel, noise target, time budget;
  * `statistics`: the per-texel running mean and standard error; `shipping`: what lets a unit
    run in another process; `settings`: BakeSettings.
Each unit draws its random numbers from its own generator seeded by (seed, pass, chunk), which
also seeds the compiled kernels it calls, so results do not depend on the executor or its
thread or process count.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor

import numpy as np

from ..bakepoints import BakePoints
from ..errors import BakeCancelled, BakeError
from ..memory import keep, trim_heap
from ..rays import RayScene
from ..scene import BakeScene
from ..stages import TracedAtlas
from . import scheduler
from .hemisphere import TexelEstimator
from .paths import RR_MAX_SURVIVAL, RR_REFERENCE, RR_START, RR_SURVIVAL_POWER, TraceScene
from .scheduler import WorkUnit
from .settings import MIN_ADAPTIVE_PASSES, NOISE_FLOOR, BakeSettings
from .statistics import Reduced, Statistics, finished

__all__ = [
    "bake",
    "texel_estimator",
    "traced_atlas",
    "BakeSettings",
    "BakeCancelled",
    "BakeError",
    "MIN_ADAPTIVE_PASSES",
    "NOISE_FLOOR",
    "RR_START",
    "RR_MAX_SURVIVAL",
    "RR_SURVIVAL_POWER",
    "RR_REFERENCE",
    "TexelEstimator",
    "TraceScene",
    "WorkUnit",
    "Statistics",
    "Reduced",
]


def bake(
    points: BakePoints,
    scene: BakeScene,
    settings: BakeSettings = BakeSettings(),
    *,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    ray_scene: RayScene | None = None,
    executor: Executor | None = None,
    runner: Callable[..., scheduler.Outcome] | None = None,
    compact: bool = False,
    spend_points: bool = False,
) -> TracedAtlas:
    """Trace every bake point; progressive passes of `pass_samples` each, each pass over the
    texels still converging (all of them unless `settings.noise_target` is set).
    `progress(fraction, message)` is called after every work unit; `cancel()` returning True
    stops within one unit and raises BakeCancelled. `ray_scene`: the Embree scene of
    `scene.triangles`, if the caller has built it already (it then shares the bake points'
    cover probe). `executor`: runs the work units (any concurrent.futures.Executor, e.g. a
    ProcessPoolExecutor; `settings.threads` should be its worker count); default a thread pool
    of `settings.threads` workers. The result does not depend on either. `runner`: runs the
    passes in place of `scheduler.run` (same arguments; `core.farm.Farm.runner`).

    `compact`: keep only what an atlas's files take (`statistics.Reduced`: the SH as float32,
    the bits the files hold, and the standard error of band 0 only, `sh_error` (P, 1, 3)), as
    `bake.run` does. Without a noise target, a time budget or a `runner`, each chunk's passes then
    run together (`scheduler.run_streamed`) and the trace never holds running statistics for
    the whole atlas (348 → 120 bytes per texel); otherwise they are reduced once traced. The
    files are the same either way. The TracedAtlas then holds the bake points as the files take
    them (`BakePoints.for_files`: 41 of their 139 bytes a texel, once the caller drops `points`),
    and its SH and standard error can be freed a part at a time as they are imaged
    (`encoding.TexelData.from_traced`).

    `spend_points` (with `compact`, streamed): `points` is this call's (`core.memory`): the
    arrays only tracing reads (`BakePoints.TRACING_ONLY`) are moved into memory given back a
    chunk of texels at a time as each chunk is traced (`memory.release_rows`), so the bake
    points and the reduced SH are not both whole at once; the caller reads none of `points`
    afterwards (the TracedAtlas holds what the files take). The same SH either way."""
    if settings.pass_samples < 4 or settings.pass_samples % 4:
        raise BakeError(f"samples per pass must be a multiple of 4, got {settings.pass_samples}")
    if settings.noise_target < 0 or settings.time_budget < 0 or not np.isfinite(settings.noise_target):
        raise BakeError("the noise target and the time budget must be ≥ 0 (0 switches them off)")
    start = time.perf_counter()
    settings = settings.resolved()
    estimator = texel_estimator(points, scene, settings, ray_scene)
    channels, sets = estimator.scene.channels, estimator.scene.sets
    if compact and runner is None and scheduler.streams(settings):
        spent = _releasable(points) if spend_points else ()
        reduced = Reduced(points.normal, channels, points.buried, bool(sets))
        outcome = scheduler.run_streamed(estimator, reduced, settings, start, progress, cancel, executor, spent)
        del spent
        trim_heap()  # what the tracer's threads freed (memory)
        return traced_atlas(points.for_files(), sets, reduced, settings, outcome, time.perf_counter() - start)
    stats = Statistics(len(points.texel), points.normal, channels)
    outcome = (runner or scheduler.run)(estimator, stats, settings, start, progress, cancel, executor)
    if compact:
        reduced = Reduced(points.normal, channels, points.buried, bool(sets))
        reduced.take_all(stats)
        del stats
        return traced_atlas(points.for_files(), sets, reduced, settings, outcome, time.perf_counter() - start)
    return traced_atlas(points, sets, stats, settings, outcome, time.perf_counter() - start)


def _releasable(points: BakePoints) -> tuple[np.ndarray, ...]:
    """The arrays of `points` only tracing reads (`BakePoints.TRACING_ONLY`), each moved into
    `memory.releasable_zeros` memory (a copy set in its place, one at a time: the original goes
    unless another reference holds it), per texel row: what a streamed trace may give back
    behind its finished chunks."""
    out = []
    for name in BakePoints.TRACING_ONLY:
        a = getattr(points, name)
        if a is None or not len(a):
            continue
        setattr(points, name, keep(a))
        del a
        out.append(getattr(points, name))
    return tuple(out)


def traced_atlas(
    points: BakePoints,
    sets: tuple[str, ...],
    stats: Statistics | Reduced,
    settings: BakeSettings,
    outcome: scheduler.Outcome,
    seconds: float,
) -> TracedAtlas:
    """The TracedAtlas of `points` from its finished running statistics `stats` (spent: the SH
    is computed in place) or their reduction (`Reduced`: a compact TracedAtlas), the light `sets`
    traced and the run's `outcome`; `seconds` of wall time. `bake`'s last step, and a farm's
    (`core.farm`), which assembles `stats` on a worker."""
    if isinstance(stats, Reduced):
        sh, sh_error, set_sh, set_sh_error = stats.sh, stats.sh_error, stats.set_sh, stats.set_sh_error
    else:
        sh, sh_error, set_sh, set_sh_error = finished(stats, points.buried, bool(sets))
    passes = int(np.max(stats.passes, initial=0))
    return TracedAtlas(
        points=points,
        sh=sh,
        sh_error=sh_error,
        sets=sets,
        set_sh=set_sh,
        set_sh_error=set_sh_error,
        texel_samples=stats.passes * settings.pass_samples,
        samples=passes * settings.pass_samples,
        passes=passes,
        rays=outcome.rays,
        seconds=seconds,
        stopped_by=outcome.stopped_by,
        threads=settings.threads,
    )


def texel_estimator(
    points: BakePoints, scene: BakeScene, settings: BakeSettings, ray_scene: RayScene | None = None
) -> TexelEstimator:
    """The estimator `bake` runs its work units on (`estimator.trace(WorkUnit(...))`)."""
    trace_scene = TraceScene(scene, settings.bounces, points.offset, ray_scene, settings.light_sets)
    return TexelEstimator(points, trace_scene, settings.pass_samples)
