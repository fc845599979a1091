"""The bake's settings as one value, read from Blender: `scene_settings` builds the core
`PipelineSettings` (its trace's samples per pass, pass count and thread count are
`core.tracer.BakeSettings`'s) from a scene's HHD settings (`scene.hhd`), for the operators and,
through an `Overridden` view of those settings, for the command line, which never writes its
options into the scene to read them back (only `--save` keeps them: cli/overrides.py).
"""

from __future__ import annotations

import numpy as np

from ..core import bake as core_bake
from ..core import encoding as core_encoding
from ..core import parallel, presets, tracer
from . import denoiser


def scene_threads(scene) -> int:
    """The bake's thread setting (0 = every core) from Blender's Render > Performance > Threads
    of `scene` (`parallel.blender_threads`)."""
    return parallel.blender_threads(scene.render.threads_mode, scene.render.threads)


def scene_settings(scene, threads: int | None = None, settings=None) -> core_bake.PipelineSettings:
    """The bake's settings from `scene`'s HHD settings, or from `settings` (an `Overridden` view
    of them: the CLI's options); `threads`: worker threads, 0 = every core, None = the scene's
    Render > Performance > Threads (`scene_threads`); resolved (`PipelineSettings.resolved`), so
    the count is the one the bake starts and records. Raises BakeError for a negative count."""
    if threads is None:
        threads = scene_threads(scene)
    return pipeline_settings(scene.hhd if settings is None else settings, threads).resolved()


def pipeline_settings(settings, threads: int = 0) -> core_bake.PipelineSettings:
    """The core settings from HHD settings `settings` (`scene.hhd` or an `Overridden` view);
    `threads`: worker threads as given (0 = every core, not resolved). Denoising goes through the
    OIDN library of the running Blender (`denoiser.oidn_library`)."""
    trace = tracer.BakeSettings.from_samples(
        settings.samples,
        bounces=settings.bounces,
        seed=settings.seed,
        noise_target=settings.noise_target / 100.0,
        time_budget=settings.time_budget,
        threads=threads,
    )
    return core_bake.PipelineSettings(
        trace=trace,
        encoder=encoder_settings(settings),
        denoise=settings.denoise,
        denoiser_library=denoiser.oidn_library() if settings.denoise else "",
        stitch_seams=settings.stitch_seams,
        inward_faces=settings.inward_faces,
    )


def encoder_settings(settings) -> core_encoding.EncoderSettings:
    """The encoder's settings from HHD settings `settings` (`scene.hhd` or an `Overridden` view)."""
    return core_encoding.EncoderSettings(
        model=settings.model.lower(),
        direction=settings.direction.lower(),
        ambient=settings.ambient.lower(),
        phi_search=settings.phi_search,
        golden_iterations=settings.golden_iterations,
        solve=settings.solve.lower(),
    )


class Overridden:
    """A read-only view of HHD settings `settings` (`scene.hhd`) with some of them replaced:
    `values` {setting: value}, each as the scene would hold it once set (`stored`). Reads fall
    through to `settings` for the others; the scene is never written."""

    def __init__(self, settings, values: dict):
        object.__setattr__(self, "_settings", settings)
        object.__setattr__(self, "_values", {k: stored(settings, k, v) for k, v in values.items()})
        if KNOBS & set(values):
            object.__setattr__(self, "_values", {**self._values, **_preset_state(self)})

    def __getattr__(self, name: str):
        values = object.__getattribute__(self, "_values")
        if name in values:
            return values[name]
        return getattr(object.__getattribute__(self, "_settings"), name)

    def __setattr__(self, name: str, value) -> None:
        raise AttributeError(f"the overridden settings are read-only (setting {name!r})")


def with_preset(name: str, values: dict) -> dict:
    """`values` after the knobs preset `name` sets (`core.presets`), as choosing the preset in the
    scene sets them (properties.py): the preset first, then `values`, which override it."""
    samples, bounces, noise, denoise = presets.get(name).knobs()
    knobs = {"samples": samples, "bounces": bounces, "noise_target": 100.0 * noise, "denoise": denoise}
    return {"preset": name.upper(), **knobs, **values}


def stored(settings, name: str, value):
    """`value` as setting `name` of `settings` holds it once set: a float setting keeps single
    precision (Blender's FloatProperty), so the view reads what the scene would."""
    prop = settings.bl_rna.properties.get(name)
    if prop is not None and prop.type == 'FLOAT' and not getattr(prop, "is_array", False):
        return float(np.float32(value))
    return value


#: The settings a preset sets.
KNOBS = {"samples", "bounces", "noise_target", "denoise"}


def _preset_state(view: Overridden) -> dict:
    """{"preset": 'CUSTOM'} when the view's knobs (some overridden) differ from its preset's, as
    the scene's update callbacks would switch it (properties.py), else {}."""
    preset = view.preset
    if preset == 'CUSTOM':
        return {}
    knobs = (view.samples, view.bounces, round(view.noise_target / 100.0, 6), view.denoise)
    return {"preset": 'CUSTOM'} if presets.get(preset).knobs() != knobs else {}
