"""Progressive passes split into deterministic work units, run on any executor. No bpy.

The texels are cut into fixed chunks of `chunk_size` (`chunks`); each pass runs one
`WorkUnit` (seed, pass, chunk index, texel indices) per chunk over its texels still active (all
of them unless a noise target stopped some). A unit draws every random number from a generator seeded by (seed, pass, chunk), so its
result depends on nothing else: not on the executor, its workers or the order they finish in.
Results are added to the statistics strictly in unit order (`Statistics.add`), so the bake is
bit-identical whatever runs it.

Executor: any `concurrent.futures.Executor`; by default a ThreadPoolExecutor of
`settings.threads` workers (the Embree queries and the kernels release the GIL). A unit's
function is `run_unit(estimator, unit)`, both picklable, so a ProcessPoolExecutor (or any
executor that pickles its calls) runs them too: the estimator ships as `shipping.Shipped`
(serialised once per bake, unpickled once per worker process, its Embree scenes rebuilt there).
At most 2 × settings.threads units are queued ahead of the one being added, so finished
estimates never pile up: memory stays bounded whatever the atlas size.

Streamed (`run_streamed`, `tracer.bake(..., compact=True)` without a noise target or a time
budget): the same units in another order, every pass of chunk 0, then of chunk 1, …, each chunk's
statistics reduced (`statistics.Reduced`) once its last pass is added. A texel's statistics
depend only on its own estimates in pass order, so the numbers are the same, while running
statistics exist for one chunk at a time instead of the whole atlas.

Passes follow one another without waiting: a pass's units are queued while the last of the
pass before still run (an atlas of a few chunks would otherwise leave workers idle at the end of
each pass), except where the noise target must see a whole pass first (`_runs`).

Between units: progress, cancel (raises BakeCancelled within a unit), the time budget (no unit
starts after it, the first pass always completes) and, after each pass, the noise target. Its
rule is fixed so that `core/farm/` (every pass of a group of chunks in one task) gives the same
result: a texel's test depends only on its own statistics and a floor fixed once from the first
MIN_ADAPTIVE_PASSES passes over the atlas.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..errors import BakeCancelled
from ..memory import release_rows
from .settings import MIN_ADAPTIVE_PASSES, BakeSettings
from .statistics import Reduced, Statistics


@dataclass(frozen=True)
class WorkUnit:
    """One pass over one chunk of texels: seed (the bake's), pass_index, chunk (index within
    the pass), texels (n,) int64 indices of the bake points."""

    seed: int
    pass_index: int
    chunk: int
    texels: np.ndarray


@dataclass
class UnitResult:
    """A unit's estimate (n, 9, C) float64 for its texels, in order (C: 3 per light set), and
    the rays it traced."""

    estimate: np.ndarray
    rays: int


class Estimator(Protocol):
    def trace(self, unit: WorkUnit) -> UnitResult: ...


def run_unit(estimator: Estimator, unit: WorkUnit) -> UnitResult:
    """What an executor runs (module level, so it pickles by name)."""
    return estimator.trace(unit)


def chunks(settings: BakeSettings, n: int) -> list[np.ndarray]:
    """The fixed chunks of an atlas of n bake points, `settings.chunk_size(n)` texels each: chunk
    c is texels [c·size, (c + 1)·size); a pass's unit c traces the chunk's texels still active."""
    size = settings.chunk_size(n)
    return [np.arange(s, min(s + size, n)) for s in range(0, n, size)]


def units(settings: BakeSettings, pass_index: int, active: list[np.ndarray]) -> list[WorkUnit]:
    """The units of one pass: one per fixed chunk with texels still active (`active[c]`, int64
    indices of chunk c), in the order they are added."""
    return [WorkUnit(settings.seed, pass_index, c, texels) for c, texels in enumerate(active) if len(texels)]


@dataclass
class Outcome:
    """How a run ended: stopped_by "samples", "noise_target" or "time_budget"; rays traced
    (by every unit that ran, added or not)."""

    stopped_by: str
    rays: int


class _Run:
    def __init__(
        self,
        estimator: Estimator,
        stats: Statistics | None,
        settings: BakeSettings,
        start: float,
        progress: Callable[[float, str], None] | None,
        cancel: Callable[[], bool] | None,
    ):
        self.estimator, self.stats, self.settings, self.start = estimator, stats, settings, start
        self.progress, self.cancel = progress, cancel
        self.rays = self.texel_passes = 0

    def passes(self, pool: Executor) -> str:
        """Every pass over the atlas, in runs of passes no noise-target test falls between
        (`_runs`): within a run the next pass's units start while the last of the pass before
        finish, so no worker waits at the end of a pass (the units are still added in order)."""
        settings, stats = self.settings, self.stats
        assert stats is not None
        n = len(stats.passes)
        max_passes = settings.passes
        active = chunks(settings, n)
        floor = None
        for first, end in _runs(settings, max_passes):
            work = [units(settings, p, active) for p in range(first, end)]
            per_pass, converging = len(work[0]), sum(len(a) for a in active)

            def on_unit(done, of, first=first, per_pass=per_pass, converging=converging):
                p, within = first + (done - 1) // per_pass, (done - 1) % per_pass + 1
                elapsed = time.perf_counter() - self.start
                if self.progress:
                    self.progress(
                        _fraction(p, within / per_pass, max_passes, settings, elapsed),
                        _status(
                            _pass_status(p, max_passes, converging, n),
                            self.rays,
                            stats.texel_passes,
                            settings.pass_samples,
                            elapsed,
                        ),
                    )
                # the time budget: no unit starts after it, but the first pass always completes
                return not (settings.time_budget and elapsed >= settings.time_budget and (p > 0 or within == per_pass))

            flat = [unit for pass_units in work for unit in pass_units]
            if not self.run_units(pool, iter(flat), len(flat), lambda unit, r: stats.add(unit.texels, r), on_unit):
                return "time_budget"
            if settings.noise_target and end >= MIN_ADAPTIVE_PASSES:
                if floor is None:  # fixed from the first MIN_ADAPTIVE_PASSES passes (core/farm/)
                    floor = stats.floor()
                active = [a[~stats.converged(a, settings.noise_target, floor)] for a in active]
                if not any(len(a) for a in active):
                    return "noise_target"
        return "samples"

    def streamed(self, pool: Executor, reduced: Reduced, spent: tuple[np.ndarray, ...] = ()) -> str:
        """Every pass of chunk 0, then of chunk 1, …, each chunk's statistics reduced into
        `reduced` once its last pass is added, the rows of `spent` up to it then given back
        (`run_streamed`)."""
        settings = self.settings
        n = len(reduced.passes)
        max_passes = settings.passes
        size = settings.chunk_size(n)
        count = -(-n // size)
        current: dict = {}

        def work():
            for c, first in enumerate(range(0, n, size)):
                texels = np.arange(first, min(first + size, n))
                for p in range(max_passes):
                    yield WorkUnit(settings.seed, p, c, texels)

        def add(unit: WorkUnit, estimate: np.ndarray) -> None:
            first, end = int(unit.texels[0]), int(unit.texels[-1]) + 1
            if unit.pass_index == 0:
                current["stats"] = reduced.statistics(first, end)
            stats = current["stats"]
            stats.add(unit.texels - first, estimate)
            self.texel_passes += len(unit.texels)
            if unit.pass_index == max_passes - 1:  # the chunk is finished
                reduced.take(first, stats)
                del current["stats"]
                for a in spent:  # the units queued ahead are of later chunks: rows ≥ end
                    release_rows(a, end)

        def on_unit(done, of):
            if self.progress:
                elapsed = time.perf_counter() - self.start
                chunk = min((done - 1) // max_passes + 1, count)
                self.progress(
                    done / of,
                    _status(
                        f"chunk {chunk} of {count} ({max_passes} passes each)",
                        self.rays,
                        self.texel_passes,
                        settings.pass_samples,
                        elapsed,
                    ),
                )
            return True

        self.run_units(pool, work(), count * max_passes, add, on_unit)
        return "samples"

    def run_units(self, pool: Executor, work: Iterator[WorkUnit], of: int, add, on_unit) -> bool:
        """The `of` units of `work` on the pool, at most 2 × threads queued ahead of the one being
        added, each result handed to `add(unit, estimate)` in order. `on_unit(done, of)` after
        each returns False to stop early (returns False then); `cancel()` returning True raises
        BakeCancelled."""
        ahead = 2 * self.settings.threads
        queued: deque = deque()
        done = 0
        try:
            while True:
                while len(queued) < ahead:
                    unit = next(work, None)
                    if unit is None:
                        break
                    queued.append((unit, pool.submit(run_unit, self.estimator, unit)))
                if not queued:
                    return True
                if self.cancel is not None and self.cancel():
                    raise BakeCancelled("bake cancelled")
                unit, future = queued.popleft()
                result = future.result()
                self.rays += result.rays
                add(unit, result.estimate)
                done += 1
                if not on_unit(done, of):
                    return False
        finally:  # cancelled, stopped early or failed: no unit left queued
            self._drop([future for _, future in queued])

    def _drop(self, futures) -> None:
        """Cancel the units not started; wait for the running ones (no worker outlives the
        bake), counting the rays of those that finish."""
        for f in futures:
            f.cancel()
        for f in futures:
            if not f.cancelled() and f.exception() is None:
                self.rays += f.result().rays


def run(
    estimator: Estimator,
    stats: Statistics,
    settings: BakeSettings,
    start: float,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    executor: Executor | None = None,
) -> Outcome:
    """Every pass of `settings` over the texels of `stats`, adding each unit's estimate to it.
    `start`: perf_counter() at the bake's start (progress speeds, the time budget); `executor`:
    runs the units (default: a thread pool of settings.threads, shut down at the end; the
    caller's is left running)."""
    state = _Run(estimator, stats, settings, start, progress, cancel)
    with _pool(executor, settings.threads) as pool:
        stopped_by = state.passes(pool)
    return Outcome(stopped_by, state.rays)


def streams(settings: BakeSettings) -> bool:
    """Whether `run_streamed` can trace with `settings`: without a noise target or a time budget
    (the presets), every texel takes every pass whatever the others do."""
    return not settings.noise_target and not settings.time_budget


def run_streamed(
    estimator: Estimator,
    reduced: Reduced,
    settings: BakeSettings,
    start: float,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    executor: Executor | None = None,
    spent: tuple[np.ndarray, ...] = (),
) -> Outcome:
    """`run` for settings that `streams`, into `reduced` (`statistics.Reduced`, of every texel)
    instead of whole-atlas running statistics: every pass of chunk 0, then of chunk 1, and so on
    (the same units, added in another order), each chunk reduced as soon as its last pass is in.
    A texel's statistics depend only on its own estimates in pass order (`statistics_kernels.add_pass`), so
    the numbers are `run`'s, while full statistics exist for one chunk at a time. `spent`: per-texel
    arrays (`memory.releasable_zeros`') whose rows of every finished chunk are given back
    (`memory.release_rows`: no later unit reads them; `tracer.bake`'s `spend_points`)."""
    if not streams(settings):
        raise ValueError("a noise target or a time budget needs every pass over the atlas in turn: use `run`")
    state = _Run(estimator, None, settings, start, progress, cancel)
    with _pool(executor, settings.threads) as pool:
        stopped_by = state.streamed(pool, reduced, spent)
    return Outcome(stopped_by, state.rays)


@contextmanager
def _pool(executor: Executor | None, threads: int):
    if executor is not None:
        yield executor
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        yield pool


def _runs(settings: BakeSettings, max_passes: int) -> list[tuple[int, int]]:
    """The passes as runs [first, end) between which the noise target tests the texels: all
    of them in one run without a noise target; with one, passes 0 .. MIN_ADAPTIVE_PASSES − 1,
    then one pass per run (each followed by a test)."""
    if not settings.noise_target:
        return [(0, max_passes)]
    first = min(MIN_ADAPTIVE_PASSES, max_passes)
    return [(0, first)] + [(p, p + 1) for p in range(first, max_passes)]


def _fraction(p, unit_fraction, max_passes, settings, elapsed) -> float:
    fraction = (p + unit_fraction) / max_passes
    if settings.time_budget:
        fraction = max(fraction, min(elapsed / settings.time_budget, 1.0))
    return fraction


def _pass_status(p, max_passes, active, n) -> str:
    converging = f", {100 * active / max(n, 1):.0f}% of texels converging" if active < n else ""
    return f"pass {p + 1} of {max_passes}{converging}"


def _status(where: str, rays, texel_passes, pass_samples, elapsed) -> str:
    elapsed = max(elapsed, 1e-9)
    return (
        f"{where}, {rays / elapsed / 1e6:.2f} M rays/s, "
        f"{texel_passes * pass_samples / elapsed / 1e3:.0f} k texel-samples/s"
    )
