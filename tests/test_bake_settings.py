"""The trace's settings as a value (`core.tracer.BakeSettings`): the samples-per-pass rule, the
pass count and the thread count, defined once. No bpy."""

import dataclasses

import pytest

from hhd_lightmapper.core import bake, parallel, tracer
from hhd_lightmapper.core.errors import BakeError


@pytest.mark.parametrize(
    ("samples", "pass_samples", "passes"),
    [(1, 4, 1), (4, 4, 1), (5, 8, 1), (8, 8, 1), (13, 16, 1), (16, 16, 1), (20, 16, 2), (256, 16, 16), (2048, 16, 128)],
)
def test_samples_per_pass_rule_and_pass_count(samples, pass_samples, passes):
    settings = tracer.BakeSettings.from_samples(samples, bounces=2, seed=5)
    assert (settings.samples, settings.pass_samples, settings.passes) == (max(4, samples), pass_samples, passes)
    assert (settings.bounces, settings.seed) == (2, 5)
    assert settings.pass_samples % 4 == 0 and settings.pass_samples <= tracer.settings.MAX_PASS_SAMPLES


def test_a_pass_count_rounds_up_to_whole_passes():
    assert tracer.BakeSettings(samples=24, pass_samples=16).passes == 2
    assert tracer.BakeSettings(samples=0, pass_samples=16).passes == 1  # the first pass always runs


def test_thread_count_is_resolved_once_and_recorded():
    assert tracer.BakeSettings(threads=0).worker_threads == parallel.machine_threads()
    assert tracer.BakeSettings(threads=3).resolved().threads == 3
    settings = bake.PipelineSettings(trace=tracer.BakeSettings(threads=0)).resolved()
    assert settings.trace.threads == parallel.machine_threads()
    with pytest.raises(BakeError, match="≥ 0"):
        tracer.BakeSettings(threads=-1).resolved()


def test_settings_are_values():
    settings = bake.PipelineSettings(trace=tracer.BakeSettings.from_samples(64))
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.trace.samples = 8  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.denoise = True  # type: ignore[misc]
    assert settings == bake.PipelineSettings(trace=tracer.BakeSettings.from_samples(64))
