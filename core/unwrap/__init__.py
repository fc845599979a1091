"""Lightmap UVs with xatlas: chart and pack meshes into one shared atlas or one per object. No bpy.

Input meshes are triangle lists in world space (metres), so texel density is per metre of the
object as it stands in the scene (object scale included; negative scale is fine: only lengths
and areas matter), with the polygon (quad, n-gon) each triangle comes from. Output UVs are per
triangle corner in [0, 1]² of the object's atlas, with texel centres at (i + 0.5)/width; the
triangles of one polygon are always in one chart and the corners of one polygon that share a
vertex always get the same UV, so the UVs can be written per loop exactly. Polygons with no area
get no chart (UV (0, 0), skipped by the rasteriser).

Two stages, each in child processes (`xatlas_worker`, so a crash in xatlas's threads is a retry,
not a lost session): charting, once per mesh content and cached (`chart_key`), in parallel
processes when there is enough work; then packing of the cached charts, re-packed with a smaller
density (never re-charted) until they fit the atlas.

The modules: `data` (the meshes in, the settings, the UVs out, the cached charts), `charting`
(charts per mesh content, cached, in parallel children), `packing` (packing and fitting the charts
into atlases, spilling over several, each object's UVs), `instance_packing` (linked duplicates and
collection instances sharing one layer), `worker_runs` (running `xatlas_worker` in a child
process, retried), `xatlas_worker` (the child's script: charting) with
`xatlas_packing` (packing and fitting, also run here), `instances` (instance groups, blocks and
their layout), `atlas_limits`, `uv_problems`, `texel_density`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from .. import deps
from . import atlas_limits, instances
from .charting import _CACHE, chart_key, chart_meshes
from .data import MAX_RESOLUTION, UnwrapMesh, UnwrapResult, UnwrapSettings, _check_scale, validate
from .instance_packing import _add_instances, _instance_atlases, _representatives
from .packing import _PACKED, _object_uv, _pack, _spill, _upright
from .worker_runs import _check

#: Objects below this many covered texels get a warning: too few to show any lighting detail.
FEW_TEXELS = 64


def unwrap(
    meshes: list[UnwrapMesh],
    settings: UnwrapSettings,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> UnwrapResult:
    """Chart and pack `meshes`: one shared atlas, or one per object when settings.per_object or
    an object overrides resolution/density (overridden objects get their own atlas).

    progress(fraction in [0, 1], message) is called from the calling thread only (charting up to
    0.8, packing the rest, 1.0 at the end). cancel() may be called from any thread, every
    CANCEL_POLL seconds while a child runs: once it returns True the running children are killed
    and BakeCancelled is raised; nothing of a cancelled unwrap enters the caches."""
    for m in meshes:
        validate(m)
    inst_groups = instances.instance_groups(
        [m.instance_of for m in meshes], {m.instance_of for m in meshes if m.bundle and m.instance_of}
    )
    reps = _representatives(meshes, inst_groups)
    held = {i for g in inst_groups for i in g}
    groups = _group(meshes, settings, held)
    for _, resolution, density, _ in groups:
        _check_scale(resolution, density)
    atlas_limits.check_density(meshes, settings.texel_density, MAX_RESOLUTION)  # before xatlas meets it
    deps.require("xatlas")  # a missing wheel is a clear message here, not in the child
    stats: dict = {"packs": 0, "tries": []}
    t0 = time.perf_counter()
    charted = [i for i in range(len(meshes)) if i not in held] + reps  # an instanced mesh once
    keys: list[bytes] = [b""] * len(meshes)
    for i in charted:
        keys[i] = chart_key(meshes[i])
    _check(cancel)
    charts: list = [None] * len(meshes)
    done = chart_meshes(
        [meshes[i] for i in charted], stats, _stage(progress, 0.0, 0.8), [keys[i] for i in charted], cancel
    )
    for i, c in zip(charted, done):
        charts[i] = c
    for g, r in zip(inst_groups, reps):
        for i in g:
            charts[i] = charts[r]
    stats["chart_s"] = time.perf_counter() - t0
    result = UnwrapResult([None] * len(meshes), [], [], 0, stats=stats)  # type: ignore[list-item]  # filled below
    for gi, (indices, resolution, density, shared) in enumerate(groups):
        stage = _stage(progress, 0.8 + 0.2 * gi / len(groups), 0.2 / len(groups))
        if stage:
            stage(0.0, f"xatlas: packing atlas {gi + 1} of {len(groups)}")

        def pack(part, stage=stage, resolution=resolution, density=density):
            _check(cancel)
            return _pack(
                [meshes[i] for i in part],
                [charts[i] for i in part],
                [keys[i] for i in part],
                resolution,
                density,
                settings.padding,
                stage,
                cancel,
            )

        for k, (part, atlas) in enumerate(_spill(indices, pack, charts, resolution, density, settings.padding)):
            # a density-driven atlas is xatlas's own size; a fixed one is resolution² (charts fit in it)
            turn = _upright(atlas)
            w, h = (atlas["width"], atlas["height"]) if density is not None else (resolution, resolution)
            if turn:
                w, h = h, w
            _add_atlas(result, atlas, (w, h), shared, k)
            for j, i in enumerate(part):
                result.objects[i] = _object_uv(meshes[i], atlas, j, len(result.atlas_sizes) - 1, w, h, turn)
    for part_groups, resolution, density in _instance_atlases(inst_groups, reps, settings, meshes):
        _check(cancel)
        _add_instances(result, meshes, charts, part_groups, resolution, density, settings.padding, cancel)
    stats["pack_s"] = time.perf_counter() - t0 - stats["chart_s"]
    if progress:
        progress(1.0, "xatlas: done")
    result.warnings = _warnings(meshes, charts, result.objects)
    return result


def _add_atlas(result: UnwrapResult, atlas: dict, size, shared: bool, part: int) -> None:
    result.atlas_sizes.append(size)
    result.utilisation.append(atlas["utilisation"])
    result.shared.append(shared)
    result.part.append(part)
    result.instanced.append(False)
    result.charts += atlas["charts"]
    result.stats["packs"] += atlas["packs"]
    result.stats["tries"].append(atlas.get("tries", []))


def _warnings(meshes, charts, objects) -> list[str]:
    """Objects with polygons that fold over themselves, and objects with too few texels."""
    out = [
        f"'{m.name}': {c.folded} polygon(s) overlap themselves when flattened (twisted or "
        "self-intersecting faces), so their lightmap texels overlap: triangulate them (Face > "
        "Triangulate Faces) or fix their shape"
        for m, c in zip(meshes, charts)
        if c.folded
    ]
    return out + [
        f"'{o.name}' gets only {o.texels:.0f} lightmap texels: raise the resolution or its texel "
        "density to see lighting detail on it"
        for o in objects
        if o.texels < FEW_TEXELS
    ]


def _stage(progress, start, span):
    """A progress callback mapping [0, 1] onto [start, start + span] of `progress` (or None)."""
    if progress is None:
        return None
    return lambda f, msg: progress(start + span * f, msg)


def _group(meshes, settings, held=frozenset()):
    """[(mesh indices, resolution, density, shared)] per atlas to build (before any spill):
    the shared atlas first, then one per object with its own (shared False). Instances (`held`)
    are in none: they get atlases of their own (`_instance_atlases`)."""
    shared = [
        i
        for i, m in enumerate(meshes)
        if not settings.per_object and m.resolution is None and m.texel_density is None and i not in held
    ]
    groups = [(shared, settings.resolution, settings.texel_density, True)] if shared else []
    for i, m in enumerate(meshes):
        if i not in shared and i not in held:
            groups.append(
                (
                    [i],
                    m.resolution or settings.resolution,
                    m.texel_density
                    if m.texel_density is not None
                    else (None if m.resolution is not None else settings.texel_density),
                    False,
                )
            )
    return groups


def clear_chart_cache() -> None:
    """Forget every cached chart set and packed atlas (the next unwrap charts every mesh again)."""
    _CACHE.clear()
    _PACKED.clear()
