"""The finishing of one atlas's files, after its trace: seams → image → raw files → post stages
→ encode (`finish_atlas`), handed to where they go (`Staged`: staged on this machine; a farm
worker keeps them instead, `core.farm.finishing`). No bpy."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .. import encoding, light_sets, memory, post, tracer
from .. import progress as meter
from ..files import exr, lightmap_files
from ..post.seams import geometry
from ..progress import Tick, ticker
from ..stages import TracedAtlas
from .costs import _set_costs, _window_texels, _window_texels_of
from .data import AtlasInput, AtlasResult, PipelineSettings, _check_cancel, atlas_result


class Staged:
    """Where finished atlases' files go on this machine: staged in `staging` (committed with
    every other atlas's at the end) under `out_dir`."""

    def __init__(self, staging: exr.Staging, out_dir: Path):
        self.staging, self.out_dir = staging, Path(out_dir)
        self._tables: dict[str, dict] = {}  # per atlas: the channel tables of its raw files

    def _files(self, name: str, parent: str = "") -> lightmap_files.AtlasFiles:
        return lightmap_files.AtlasFiles(self.out_dir, name, parent)

    def raw(self, name: str, parent: str, images_of: dict, tick: Tick | None = None) -> None:
        """Stage the raw files of one atlas or light set now (`encoding.raw_files`'s images), before its
        post stages; `atlas` adds their channel tables to its sidecar. `tick`: progress and cancel
        per band of rows written."""
        self._tables[name] = lightmap_files.stage_files(self.staging, self._files(name, parent), images_of, tick)

    def traced_sh(self, name: str, parent: str) -> np.ndarray:
        """The SH image `(H, W, 9, 3)` float32 of the raw SH file `raw` staged for `name`, read back
        (a denoiser that failed half-way puts the traced SH back from it: `post.apply`'s `raw_sh`)."""
        files = self._files(name, parent)
        return lightmap_files.read_sh(self.staging.staged(files.sh))

    def atlas(
        self, name: str, parent: str, encoded: encoding.EncodedAtlas, sidecar: dict, tick: Tick | None = None
    ) -> None:
        """Stage the files of one atlas or light set (`parent`: the atlas of a light set, else "")."""
        sidecar = {**sidecar, "channels": {**sidecar.get("channels", {}), **self._tables.pop(name, {})}}
        lightmap_files.write_atlas(self.staging, self._files(name, parent), encoded, sidecar, tick)

    def seams(self, name: str, atlas_seams: geometry.Seams) -> None:
        """Stage the seams file of atlas `name`."""
        lightmap_files.stage_seams(self.staging, self._files(name), atlas_seams)


def _write(
    staging,
    atlas: AtlasInput,
    traced: TracedAtlas,
    settings: PipelineSettings,
    out_dir: Path,
    t_points: float,
    extra: dict,
    cancel=None,
) -> AtlasResult:
    """The last stages of one atlas here (`finish_atlas`, which spends `traced`), its files
    staged in `staging`."""
    check = lambda: _check_cancel(cancel)  # noqa: E731
    info = finish_atlas(atlas, traced, settings, t_points, extra, Staged(staging, out_dir), check)
    return atlas_result(atlas, out_dir, info)


def finish_atlas(
    atlas: AtlasInput,
    traced: TracedAtlas,
    settings: PipelineSettings,
    t_points: float,
    extra: dict,
    out,
    check: Callable[[], None] = lambda: None,
    *,
    recorded: tracer.BakeSettings | None = None,
) -> dict:
    """The last stages of one atlas: seams → image → raw files → post stages → encode, its files
    handed to `out` (`Staged` here; a farm worker keeps them to return, `core.farm`): `out.raw(name,
    parent, images)` once imaged, `out.atlas(name, parent, encoded, sidecar)` per file set as soon
    as it is encoded, `out.seams(name, seams)`.
    The raw SH file keeps the SH as traced; the seams file is written whether or not this bake
    stitches (a re-encode may). With light sets, the same stages then run for each set's SH
    into its own atlas files (`light_sets.set_atlas_name`), listed in the atlas's sidecar.
    `check()` raises to cancel; `recorded`: the tracer settings the sidecar records (default
    `settings.trace`; a farm worker computes with its own thread count). Returns the
    atlas's summary: texels, rays, seconds per stage, warnings, light sets. `check` may be a
    `core.progress.Tick` (a bake's): each stage gets its part, by `_set_costs`, and reports in it.

    `traced` is spent (`core.memory`): its SH and standard error, the largest arrays of a bake,
    go as they are imaged, its bake points once the last image is made (`TexelData.from_traced`);
    its light sets' SH (`set_sh`, `set_sh_error`: plain memory, `tracer.statistics.Reduced`, which
    `memory.release_rows` leaves alone) is only read. A caller that needs `traced` afterwards
    hands over a copy of its SH and standard error (`memory.keep`).
    """
    t = time.perf_counter()
    texels = len(traced.points.texel)
    tick = ticker(check)
    costs = _set_costs(texels, _window_texels(atlas, traced.points), settings)
    seams_part, *set_parts = tick.split(
        [meter.COST_SEAMS * texels] + [sum(costs.values())] * (1 + len(traced.sets)),
        [f"seams {tick.name}".strip()] + [None] * (1 + len(traced.sets)),
    )
    seams_part.at(0.0, "finding the seams")
    atlas_seams = geometry.find_seams(traced.points.mesh, atlas.width, atlas.height)
    seconds = {"bake_points": t_points, "trace": traced.seconds, "seams": time.perf_counter() - t}
    t = time.perf_counter()
    sidecar = dict(extra)
    sidecar.update(
        {
            "bake": {
                **asdict(recorded or settings.trace),
                "samples_taken": traced.samples,
                "passes": traced.passes,
                "mean_samples_per_texel": traced.mean_samples,
                "stopped_by": traced.stopped_by,
                "rays": traced.rays,
            },
            "objects": lightmap_files.object_rects(traced.points, atlas.objects, atlas.instances),
            "timings_seconds": seconds,
        }
    )
    set_names = [light_sets.set_atlas_name(atlas.name, s) for s in traced.sets]
    if traced.sets:
        sidecar["light_sets"] = [{"name": s, "atlas": n} for s, n in zip(traced.sets, set_names)]
    # each set's own TracedAtlas (sharing the bake points: they go once the last one is imaged)
    sets = [traced.light_set(k) for k in range(len(traced.sets))]
    warnings = _finish_files(out, atlas.name, "", traced, settings, sidecar, atlas_seams, seconds, check=set_parts[0])
    out.seams(atlas.name, atlas_seams)
    for k, (name, set_name) in enumerate(zip(traced.sets, set_names)):
        set_sidecar = {key: v for key, v in sidecar.items() if key not in ("light_sets", "timings_seconds")}
        set_sidecar["light_set"] = {"name": name, "of": atlas.name}
        set_parts[k + 1].name = f"'{set_name}'"
        set_traced = sets.pop(0)
        warnings += _finish_files(
            out, set_name, atlas.name, set_traced, settings, set_sidecar, atlas_seams, seconds, check=set_parts[k + 1]
        )
        del set_traced
    seconds["encode_and_write"] = time.perf_counter() - t - seconds["post"]
    warnings = [f"atlas '{atlas.name}', {w}" for w in dict.fromkeys(warnings)]
    rays = traced.rays
    return {"texels": texels, "rays": rays, "seconds": seconds, "warnings": warnings, "sets": traced.sets}


def _finish_files(
    out,
    name: str,
    parent: str,
    traced: TracedAtlas,
    settings,
    sidecar: dict,
    atlas_seams,
    seconds: dict,
    *,
    check,
) -> list[str]:
    """Image → raw files (`out.raw`) → post stages → encode of one atlas's SH (the atlas's own, or
    one light set's), handed to `out.atlas`; adds the post stages' seconds to seconds["post"];
    returns their warnings. `traced` is spent (`TexelData.from_traced`). `check` may be a
    `core.progress.Tick`: split among the stages by `_set_costs`, each named ("encode 'Lightmap'")."""
    t = time.perf_counter()
    tick = ticker(check)
    costs = _set_costs(len(traced.points.texel), _window_texels_of(traced), settings)
    parts = dict(
        zip(
            costs,
            tick.split(list(costs.values()), [f"{k} {tick.name}".strip() if k != "post" else None for k in costs]),
        )
    )
    parts["image"].at(0.0, "imaging the texels")
    # image (of the standard error only the luminance L0's, `noise`: the SH's is as large as the SH);
    # an almost empty atlas: the window of its texels (the files are the same)
    raw = encoding.TexelData.from_traced(traced, crop=True)
    del traced
    # the raw files first, as traced: then `raw` is the post stages' (they write into its SH)
    fill = raw.fill()
    parts["raw"].at(0.0, "raw files")
    with encoding.raw_files(raw, fill) as images_of:
        out.raw(name, parent, images_of, *_tick_for(out, parts["raw"]))
    del images_of, fill  # the encoder finds its own (memory: a stitch makes another meanwhile)
    memory.trim_heap()  # the writer's bands of rows (memory)
    raw_sh = lambda: out.traced_sh(name, parent)  # a denoiser failing half-way reads it back
    data, sidecar["post"] = post.apply(raw, settings, parts["post"], atlas_seams, raw_sh)
    seconds["post"] = seconds.get("post", 0.0) + time.perf_counter() - t
    del raw  # the post stages': `data` holds the SH now, denoised in place or as traced
    data = replace(data, noise=None)  # in the texels file already; the encoder does not read it
    memory.trim_heap()  # what the post stages' threads freed (memory)
    parts["encode"].at(0.0, "encoding")
    encoded = encoding.encode_atlas(
        data,
        encoding.for_settings(settings.encoder),
        raw=False,
        tick=parts["encode"],
        threads=settings.trace.threads,
        release_sh=True,  # `data` is spent: nothing reads its SH after the encoder (memory)
    )
    parts["stitch encoded"].at(0.0)
    encoded = post.stitch_encoded(
        encoded, data.coverage, settings, atlas_seams, sidecar["post"], parts["stitch encoded"]
    )
    del data
    parts["write"].at(0.0, "encoded files")
    out.atlas(name, parent, encoded, sidecar, *_tick_for(out, parts["write"]))  # write (here) or keep (a farm worker)
    return post.warnings(sidecar["post"])


def _tick_for(out, tick: Tick) -> tuple:
    """The optional tick argument of `out.raw` / `out.atlas`: `Staged` writes and reports; other
    keepers of the files (a farm worker's) take none."""
    return (tick,) if isinstance(out, Staged) else ()
