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
from dataclasses import replace

import numpy as np

from .. import parallel as _parallel
from ..bakepoints import BakePoints
from ..errors import BakeCancelled, BakeError
from ..rays import RayScene
from ..scene import BakeScene
from ..stages import TracedAtlas
from . import scheduler
from .hemisphere import TexelEstimator
from .paths import RR_MAX_SURVIVAL, RR_START, TraceScene
from .scheduler import WorkUnit
from .settings import MIN_ADAPTIVE_PASSES, NOISE_FLOOR, BakeSettings
from .statistics import Statistics

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
    "TexelEstimator",
    "TraceScene",
    "WorkUnit",
    "Statistics",
]


def bake(
    points: BakePoints,
    scene: BakeScene,
    settings: BakeSettings = BakeSettings(),
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    ray_scene: RayScene | None = None,
    executor: Executor | None = None,
    runner: Callable[..., scheduler.Outcome] | None = None,
) -> TracedAtlas:
    """Trace every bake point; progressive passes of `pass_samples` each, each pass over the
    texels still converging (all of them unless `settings.noise_target` is set).
    `progress(fraction, message)` is called after every work unit; `cancel()` returning True
    stops within one unit and raises BakeCancelled. `ray_scene`: the Embree scene of
    `scene.triangles`, if the caller has built it already (it then shares the bake points'
    cover probe). `executor`: runs the work units (any concurrent.futures.Executor, e.g. a
    ProcessPoolExecutor; `settings.threads` should be its worker count); default a thread pool
    of `settings.threads` workers. The result does not depend on either. `runner`: runs the
    passes in place of `scheduler.run` (same arguments; `core.farm.Farm.runner`)."""
    if settings.pass_samples < 4 or settings.pass_samples % 4:
        raise BakeError(f"samples per pass must be a multiple of 4, got {settings.pass_samples}")
    if settings.noise_target < 0 or settings.time_budget < 0 or not np.isfinite(settings.noise_target):
        raise BakeError("the noise target and the time budget must be ≥ 0 (0 switches them off)")
    start = time.perf_counter()
    settings = replace(settings, threads=_parallel.resolve_threads(settings.threads))
    estimator = texel_estimator(points, scene, settings, ray_scene)
    stats = Statistics(len(points.texel), points.normal, estimator.scene.channels)
    outcome = (runner or scheduler.run)(estimator, stats, settings, start, progress, cancel, executor)
    return traced_atlas(points, estimator.scene.sets, stats, settings, outcome, time.perf_counter() - start)


def traced_atlas(
    points: BakePoints,
    sets: tuple[str, ...],
    stats: Statistics,
    settings: BakeSettings,
    outcome: scheduler.Outcome,
    seconds: float,
) -> TracedAtlas:
    """The TracedAtlas of `points` from its finished running statistics `stats` (spent: the SH
    is computed in place), the light `sets` traced and the run's `outcome`; `seconds` of wall
    time. `bake`'s last step, and a farm's (`core.farm`), which assembles `stats` on a worker."""
    sh, sh_error = stats.result()
    sh[points.buried] = 0.0
    set_sh = set_sh_error = None
    if sets:
        set_sh, set_sh_error = _per_set(sh), _per_set(sh_error)
        # the sum's error as if the sets' errors were fully correlated (they share their paths)
        sh, sh_error = set_sh.sum(axis=0), set_sh_error.sum(axis=0)
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


def _per_set(a: np.ndarray) -> np.ndarray:
    """`(N, 9, 3K)` statistics → `(K, N, 9, 3)`, one block per light set."""
    n, m, c = a.shape
    return np.ascontiguousarray(a.reshape(n, m, c // 3, 3).transpose(2, 0, 1, 3))


def texel_estimator(
    points: BakePoints, scene: BakeScene, settings: BakeSettings, ray_scene: RayScene | None = None
) -> TexelEstimator:
    """The estimator `bake` runs its work units on (`estimator.trace(WorkUnit(...))`)."""
    trace_scene = TraceScene(scene, settings.bounces, points.offset, ray_scene, settings.light_sets)
    return TexelEstimator(points, trace_scene, settings.pass_samples)
