"""The pass scheduler (core.tracer.scheduler.run): passes follow one another without a barrier
where no noise-target test falls between them, units are still added in pass and chunk order,
and the noise target and the time budget keep their rules. A small estimator whose estimate is
a function of its unit alone stands in for the tracer (the scheduler's contract); no Blender."""

from __future__ import annotations

import threading
import time

import numpy as np

from hhd_lightmapper.core.tracer import scheduler, statistics
from hhd_lightmapper.core.tracer.settings import MIN_ADAPTIVE_PASSES, BakeSettings


class Recorder:
    """Estimates each unit's texels from a generator seeded by (seed, pass, chunk) alone, after
    `seconds` of sleep (the GIL released, as Embree's queries do), logging when each unit starts."""

    def __init__(self, seconds: float = 0.02):
        self.seconds = seconds
        self.started: list[tuple[int, int]] = []
        self.events: list = []  # ("start", pass, chunk) here, ("added", rows, first texel) by LoggedStatistics
        self.lock = threading.Lock()

    def trace(self, unit: scheduler.WorkUnit) -> scheduler.UnitResult:
        with self.lock:
            self.started.append((unit.pass_index, unit.chunk))
            self.events.append(("start", unit.pass_index, unit.chunk))
        time.sleep(self.seconds)
        rng = np.random.default_rng([unit.seed, unit.pass_index, unit.chunk])
        estimate = 1.0 + 0.1 * rng.standard_normal((len(unit.texels), 9, 3))
        return scheduler.UnitResult(estimate, rays=len(unit.texels))


class LoggedStatistics(statistics.Statistics):
    """Statistics that log the order units are added in."""

    def __init__(self, n: int, log: list):
        super().__init__(n, np.tile([0.0, 0.0, 1.0], (n, 1)))
        self.log = log

    def add(self, texels, result):
        self.log.append(("added", int(result.shape[0]), int(texels[0])))
        super().add(texels, result)


def run(settings: BakeSettings, n: int, estimator=None):
    estimator = estimator or Recorder()
    log = estimator.events
    stats = LoggedStatistics(n, log)
    outcome = scheduler.run(estimator, stats, settings, time.perf_counter())
    return estimator, stats, outcome, log


def test_the_next_pass_starts_before_the_last_unit_of_a_pass_is_added_and_order_is_kept():
    """Three chunks on two workers: without a barrier, pass 1's first unit starts while pass 0's
    last runs, yet the units are added pass by pass, chunk by chunk, and the statistics are the
    ones of a one-worker run."""
    settings = BakeSettings(samples=64, pass_samples=16, chunk_texels=100, threads=2)
    estimator, stats, outcome, log = run(settings, 250)
    assert outcome.stopped_by == "samples" and outcome.rays == 4 * 250
    pass_1_starts = log.index(("start", 1, 0))
    pass_0_ends = log.index(("added", 50, 200))  # the last unit of pass 0: 50 texels from 200
    assert pass_1_starts < pass_0_ends
    assert [first for kind, _, first in log if kind == "added"] == [0, 100, 200] * 4
    _, alone, _, _ = run(BakeSettings(samples=64, pass_samples=16, chunk_texels=100, threads=1), 250)
    np.testing.assert_array_equal(stats.total, alone.total)
    np.testing.assert_array_equal(stats.passes, np.full(250, 4))


def test_with_a_noise_target_each_pass_after_the_first_few_is_tested_whole():
    """The noise target's test needs a whole pass: the first MIN_ADAPTIVE_PASSES passes flow,
    then the test runs before any later unit starts. Here every texel converges at that first
    test, so no unit of a later pass may ever have started."""
    settings = BakeSettings(samples=160, pass_samples=16, chunk_texels=100, threads=2, noise_target=0.5)
    estimator, stats, outcome, log = run(settings, 250)
    assert outcome.stopped_by == "noise_target"  # 10 % noise per pass: every texel converges
    assert (stats.passes == MIN_ADAPTIVE_PASSES).all()
    assert [(p, c) for p, c in estimator.started] == [(p, c) for p in range(MIN_ADAPTIVE_PASSES) for c in range(3)]
    assert scheduler._runs(settings, 10) == [(0, 4)] + [(p, p + 1) for p in range(4, 10)]
    assert scheduler._runs(BakeSettings(samples=160, pass_samples=16), 10) == [(0, 10)]


def test_the_time_budget_completes_the_first_pass_and_starts_nothing_after_it():
    """Three chunks of 0.04 s units on two workers: the first pass ends after two rounds (≥ 0.08
    s), past the 0.05 s budget, so the bake stops there, every texel with exactly one pass."""
    settings = BakeSettings(samples=640, pass_samples=16, chunk_texels=100, threads=2, time_budget=0.05)
    estimator, stats, outcome, log = run(settings, 250, Recorder(seconds=0.04))
    assert outcome.stopped_by == "time_budget"
    np.testing.assert_array_equal(stats.passes, np.ones(250))
    assert [first for kind, _, first in log if kind == "added"] == [0, 100, 200]


def test_a_small_atlas_is_cut_into_enough_chunks_for_every_core_and_a_large_one_is_not():
    """`BakeSettings.chunk_size` by default: CHUNK_TEXELS texels for an atlas of at least
    MIN_CHUNKS such chunks, a smaller atlas in MIN_CHUNKS chunks (of at least MIN_CHUNK_TEXELS),
    a rule of the atlas alone; a chunk_texels set is kept; `scheduler.chunks` covers every texel
    once, in order."""
    from hhd_lightmapper.core.tracer.settings import CHUNK_TEXELS, MIN_CHUNK_TEXELS, MIN_CHUNKS

    settings = BakeSettings()
    assert settings.chunk_texels == 0
    assert settings.chunk_size(MIN_CHUNKS * CHUNK_TEXELS) == CHUNK_TEXELS == settings.chunk_size(10**7)
    assert settings.chunk_size(MIN_CHUNKS * CHUNK_TEXELS - MIN_CHUNKS) == CHUNK_TEXELS - 1
    assert settings.chunk_size(4000) == 512 == MIN_CHUNK_TEXELS  # 8 chunks of a 128² atlas's texels
    assert settings.chunk_size(20000) == 2500
    assert settings.chunk_size(100) == MIN_CHUNK_TEXELS  # one chunk: too few texels to share
    assert BakeSettings(chunk_texels=100).chunk_size(20000) == 100 == BakeSettings(chunk_texels=100).chunk_size(10)
    for n in (1, 100, 4000, 20000, 70000):
        parts = scheduler.chunks(settings, n)
        assert np.array_equal(np.concatenate(parts), np.arange(n))
        assert len(parts) == -(-n // settings.chunk_size(n))
    assert BakeSettings(threads=1).chunk_size(4000) == BakeSettings(threads=2).chunk_size(4000)
