"""Post stages: what runs on a traced atlas between tracing and encoding. No bpy.

A post stage is a function `TracedAtlas -> TracedAtlas` (`stages.PostStage`) that returns new SH
(and standard error) for the same texels: a denoiser, seam stitching. `stages_for(settings)` is
the one place that decides which run, in order, from the pipeline settings; `core.bake.run`
applies them to every atlas with `apply`. A new post stage is a module with its function and
a line here (and the setting that switches it on in `bake.PipelineSettings`).
"""

from __future__ import annotations

from .stages import PostStage, TracedAtlas


def stages_for(settings) -> list[PostStage]:
    """The post stages `settings` (a `bake.PipelineSettings`) switch on, in the order they run.
    None exist yet: a traced atlas goes to the encoder as traced."""
    return []


def apply(traced: TracedAtlas, settings) -> TracedAtlas:
    """`traced` after every post stage of `settings`, in order."""
    for stage in stages_for(settings):
        traced = stage(traced)
    return traced
