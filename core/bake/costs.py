"""The estimated costs of a bake's stages (`core.progress`: units of the progress bar), from the
texels each works on: tracing, finishing (seams, image, raw files, post stages, encode, write),
probe volumes. No bpy."""

from __future__ import annotations

from .. import encoding, tracer
from .. import progress as meter
from ..bakepoints import BakePoints
from ..stages import TracedAtlas
from .data import AtlasInput, PipelineSettings


def _window_texels(atlas: AtlasInput | None, pts: BakePoints) -> int:
    """The texels of the images the stages after the trace work on and write (`window_of`)."""
    window = encoding.stage.window_of(pts.texel, pts.height, pts.width)
    return pts.width * pts.height if window is None else window.h * window.w


def _window_texels_of(traced: TracedAtlas) -> int:
    return _window_texels(None, traced.points)


def _trace_cost(texels: int, trace: tracer.BakeSettings) -> float:
    """The estimated cost of tracing `texels` (`core.progress`): its samples, at most its time budget."""
    samples = trace.passes * trace.pass_samples
    cost = meter.COST_SAMPLE * texels * samples * (1.0 + trace.bounces / 2)
    return min(cost, trace.time_budget * 1e6) if trace.time_budget else cost


def _write_channels(spec) -> int:
    """EXR channels of a file of `spec` and of its preview images (RGB each)."""
    return sum(len(ch.exr_names) + (3 if ch.preview is not None else 0) for ch in spec.channels)


def _set_costs(texels: int, area: int, settings: PipelineSettings) -> dict[str, float]:
    """The estimated costs (`core.progress`) of the stages after the trace for one atlas's SH (or
    one light set's), in the order they run (`_finish_files`): `texels` baked, `area` texels in
    the images written."""
    raw = sum(_write_channels(spec) for spec in encoding.RAW_FILES)
    encoded = _write_channels(encoding.for_settings(settings.encoder).file)
    stitch = meter.COST_STITCH if settings.stitch_seams else 0.0
    return {
        "image": meter.COST_IMAGE * texels,
        "raw": meter.COST_WRITE * area * raw,
        "post": (meter.COST_DENOISE if settings.denoise else 0.0) * texels + 0.6 * stitch * texels,
        "encode": meter.COST_ENCODE * texels,
        "stitch encoded": 0.4 * stitch * texels,
        "write": meter.COST_WRITE_ENCODED * area * encoded,
    }


def _atlas_costs(texels: int, area: int, settings: PipelineSettings, sets: int = 0) -> tuple[float, float]:
    """The estimated costs of tracing one atlas and of finishing it (`finish_atlas`; `sets`: its
    light sets, each finished as the atlas is)."""
    finish = meter.COST_SEAMS * texels + (1 + sets) * sum(_set_costs(texels, area, settings).values())
    return _trace_cost(texels, settings.trace), finish


def _probes_cost(grids, trace: tracer.BakeSettings) -> float:
    samples = trace.passes * trace.pass_samples
    return sum(meter.COST_PROBE * g.count * samples * (1.0 + trace.bounces / 2) for g in grids)
