"""The bake pipeline over atlases: bake points → trace → image → raw files → post stages → encode →
write. No bpy.

`run` is what the Bake operator (modal or not) and the command line both call, after the bpy side
has read the scene into plain data (`AtlasInput`, `BakeScene`). It never touches the scene: its
only effect is the files of each atlas, which are staged under temporary names and renamed over
any previous bake only once every atlas is finished. A cancel or an error leaves the previous
files as they were.

Threads: `settings.trace.threads` (0 = every core, `parallel`) is resolved once per run and used
by every parallel stage: the bake points' probes, the tracer and the EXR compression (encoding
itself stays on one thread: numpy holds the GIL for most of it, so a pool gained too little to
keep). The sidecar records the count under `bake` → `threads`; the files do not depend on it.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from . import bakepoints, encoding, light_sets, parallel, post, probes, stages, tracer
from . import progress as meter
from .bakepoints import BakePoints, SurfaceTriangles, inward
from .encoding import EncoderSettings  # re-exported: core.bake.EncoderSettings (operators, CLI, tests)
from .errors import BakeCancelled, BakeError, InwardFacesRefused
from .files import exr, lightmap_files
from .post.seams import geometry
from .progress import Progress, Tick, ticker
from .rays import RayScene
from .scene import BakeScene
from .stages import TracedAtlas

#: A farm bake's shares of the progress bar (bake points, tracing, finishing + writing); a bake
#: here shares it out by the stages' estimated costs (`core.progress`, `_atlas_costs`).
_STAGES = (0.08, 0.84, 0.08)


@dataclass
class AtlasInput:
    """One atlas to bake: its name (file stem), size in texels, the receiving triangles and the
    names of the objects they belong to (`surface.object_index` indexes `objects`); instances:
    {object name: {"mesh", "scale", "offset"}} of the objects that share their mesh's lightmap
    UVs (`core.unwrap.instances`; the surface's UVs are already atlas UVs), recorded in the sidecar."""

    name: str
    width: int
    height: int
    surface: SurfaceTriangles
    objects: list[str]
    instances: dict = field(default_factory=dict)


@dataclass
class PipelineSettings:
    """trace: the tracer's settings; encoder: the encoding and its options (`core.encoding`);
    denoise: run the denoise post stage (`core.post`), through the Open Image Denoise library at
    `denoiser_library` (the bpy side finds Blender's; "" = none: the bake is then undenoised, with
    a warning); stitch_seams: run the stitch post stage (`core.post.seams`) after it, so a smooth
    surface split between charts reads the same on both sides of the split. A bake writes the
    atlas's seams file either way, so a re-encode can switch stitching on or off. inward_faces:
    what to do with faces that point into their own object (`core.bakepoints.inward`: OPEN_SIDE bakes them
    from the side light reaches, AS_MODELLED as they are, with a warning; REFUSE: InwardFacesRefused)."""

    trace: tracer.BakeSettings = field(default_factory=tracer.BakeSettings)
    encoder: EncoderSettings = field(default_factory=EncoderSettings)
    denoise: bool = False
    denoiser_library: str = ""
    stitch_seams: bool = True
    inward_faces: str = inward.OPEN_SIDE


@dataclass
class AtlasResult:
    """One written atlas (kind "atlas") or probe volume (kind "probes": texels are its probes):
    seconds per stage; warnings: what a post stage could not do (e.g. no denoiser), and `inward`;
    sets: its light sets (`core.light_sets`; none without light groups); inward: one message per
    object with faces that point into it (`core.bakepoints.inward`)."""

    name: str
    files: lightmap_files.AtlasFiles
    texels: int
    rays: int
    seconds: dict
    warnings: list[str] = field(default_factory=list)
    sets: tuple[str, ...] = ()
    kind: str = "atlas"
    inward: list[str] = field(default_factory=list)


def _check_cancel(cancel) -> None:
    if cancel is not None and cancel():
        raise BakeCancelled("bake cancelled")


def points_of(atlas: AtlasInput, ray_scene: RayScene | None, threads: int = 0, cancel=None) -> BakePoints:
    """Stage 1 for one atlas: its bake points (buried and near-cover probes against `ray_scene`,
    all the scene's geometry). Raises BakeError naming an object whose UVs cover no texel.
    `threads`: workers of the probe passes (0 = every core)."""
    points = bakepoints.build(
        atlas.surface,
        atlas.width,
        atlas.height,
        occluders=ray_scene,
        check=lambda: _check_cancel(cancel),
        threads=threads,
        albedo=False,  # the tracer takes albedo from the scene's triangles
    )
    stages.trim_heap()  # what the probe threads freed (memory)
    return check_points(atlas, points)


def check_points(atlas: AtlasInput, points: BakePoints) -> BakePoints:
    """`points`, or BakeError naming an object of `atlas` whose UVs cover no texel."""
    counts = np.bincount(points.object_index, minlength=len(atlas.objects))
    empty = [atlas.objects[k] for k in np.unique(atlas.surface.object_index) if counts[k] == 0]
    if empty:
        raise BakeError(
            f"{', '.join(repr(n) for n in empty)}: the lightmap UVs cover no texel of "
            f"atlas '{atlas.name}' (zero-area UVs): run Unwrap again"
        )
    return points


def ray_scene_of(scene: BakeScene) -> RayScene | None:
    """The Embree scene every stage of one bake shares (bake-point probes, tracing); None for a
    scene without geometry. Its BVH builds on Embree's threads while the bake points rasterise."""
    return RayScene(scene.triangles) if len(scene.triangles) else None


def trace_surface(
    surface: SurfaceTriangles,
    width: int,
    height: int,
    scene: BakeScene,
    settings: tracer.BakeSettings,
    *,
    ray_scene: RayScene | None = None,
    progress=None,
    cancel=None,
    executor=None,
) -> TracedAtlas:
    """Stages 1–2 for receivers that do not need files (tests, benches): bake points of
    `surface` in a width × height atlas, traced in `scene`. `ray_scene`: the scene's RayScene if
    already built; `executor`: see `tracer.bake`."""
    ray_scene = ray_scene if ray_scene is not None else ray_scene_of(scene)
    atlas = AtlasInput(
        "atlas", width, height, surface, [str(k) for k in range(int(surface.object_index.max(initial=-1)) + 1)]
    )
    points = points_of(atlas, ray_scene, settings.threads, cancel)
    return tracer.bake(
        points, scene, settings, progress=progress, cancel=cancel, ray_scene=ray_scene, executor=executor
    )


def run(
    atlases: list[AtlasInput],
    scene: BakeScene,
    settings: PipelineSettings,
    out_dir,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    extra_sidecar: dict | None = None,
    probe_grids: list[probes.ProbeGrid] | None = None,
    farm=None,
) -> list[AtlasResult]:
    """Bake every atlas and write its files into `out_dir`: bake points of every atlas first
    (so a bad object fails before any tracing), then per atlas trace → post stages → image →
    encode → write; then every probe volume of `probe_grids` (`core.probes`: files and
    `probes.json`, committed with the atlases'). `progress(fraction, message)` is called often
    (at least once per tracer chunk); `cancel()` returning True stops within a chunk (raises
    BakeCancelled) with no file replaced. Every stage uses
    `parallel.resolve_threads(settings.trace.threads)` worker threads. `farm`: a
    `core.farm.Farm` building the bake points, tracing the atlases and running their post stages
    and encoding on a Dask cluster, this process writing the files (`_farm_atlases`; the same
    files; its checkpoints go when the files are committed).

    Progress (`core.progress.Progress`): every stage has its share of the range, estimated
    from the texels it works on (`_atlas_costs`), and reports within it (per tracer chunk,
    denoiser band, stitch iteration, encode chunk, band of written rows), its name in the
    message; the fraction never goes back and is 1.0 only once the files are committed. A
    cancel is honoured at the same grain."""
    if not atlases and not probe_grids:
        raise BakeError("nothing to bake: no target objects")
    if farm is not None:
        farm.check(settings.trace)
    threads = parallel.resolve_threads(settings.trace.threads)
    settings = replace(settings, trace=replace(settings.trace, threads=threads))
    exr.set_threads(threads)
    report = Progress(progress, cancel)
    t0 = time.perf_counter()
    atlases, found, scene = check_inward(atlases, scene, settings.inward_faces)
    ray_scene = ray_scene_of(scene)
    points = []
    # until the bake points are known, half of each atlas's texels is a guess of its baked texels
    guess = [a.width * a.height // 2 for a in atlases]
    report.plan(sum(meter.COST_POINTS * n + sum(_atlas_costs(n, 2 * n, settings)) for n in guess))
    report.plan(_probes_cost(probe_grids or [], settings.trace))
    remote = farm.bake_points(atlases, scene, cancel) if farm is not None else None  # on the farm's workers
    for i, atlas in enumerate(atlases):
        tick = report.span(meter.COST_POINTS * guess[i])
        _check_cancel(cancel)
        points.append(check_points(atlas, remote[i]()) if remote else points_of(atlas, ray_scene, threads, cancel))
        inward.count_texels(found[i], points[-1].triangle)
        tick.show(1.0, f"bake points of '{atlas.name}': {len(points[-1].texel)} texels")
    t_points = time.perf_counter() - t0
    # what is left, from the texels now known
    report.left = sum(sum(_atlas_costs(len(p.texel), _window_texels(a, p), settings)) for a, p in zip(atlases, points))
    report.plan(_probes_cost(probe_grids or [], settings.trace))
    if farm is not None:  # every atlas's tracing starts now; the loop below collects them in turn
        for atlas, pts in zip(atlases, points):
            farm.submit(
                atlas.name, out_dir, tracer.texel_estimator(pts, scene, settings.trace, ray_scene), settings.trace
            )
    extras = [_inward_sidecar(extra_sidecar or {}, f, settings.inward_faces) for f in found]
    with exr.Staging() as staging:
        args = (atlases, points, scene, ray_scene, settings, t_points, extras, report, cancel)
        if farm is not None:  # post stages and encoding on the workers too; this process writes
            results = _farm_atlases(farm, Staged(staging, Path(out_dir)), *args)
        else:
            results = _local_atlases(Staged(staging, Path(out_dir)), *args)
        for result, items in zip(results, found):
            result.inward = [item.message(settings.inward_faces) for item in items]
            result.warnings[:0] = result.inward
        if probe_grids:
            results.extend(_bake_probes(staging, probe_grids, scene, settings, Path(out_dir), report, cancel))
        _check_cancel(cancel)
        staging.commit()
    if farm is not None:
        farm.finished()
    report.finish(f"baked {_counted(len(atlases), 'atlas', 'atlases')}")
    return results


def _counted(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _window_texels(atlas: AtlasInput | None, pts: BakePoints) -> int:
    """The texels of the images the stages after the trace work on and write (`window_of`)."""
    window = encoding.stage.window_of(pts.texel, pts.height, pts.width)
    return pts.width * pts.height if window is None else window.h * window.w


def _window_texels_of(traced: TracedAtlas) -> int:
    return _window_texels(None, traced.points)


def _trace_cost(texels: int, trace: tracer.BakeSettings) -> float:
    """The estimated cost of tracing `texels` (`core.progress`): its samples, at most its time budget."""
    samples = -(-trace.samples // trace.pass_samples) * trace.pass_samples
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
        "write": meter.COST_WRITE * area * encoded,
    }


def _atlas_costs(texels: int, area: int, settings: PipelineSettings, sets: int = 0) -> tuple[float, float]:
    """The estimated costs of tracing one atlas and of finishing it (`finish_atlas`; `sets`: its
    light sets, each finished as the atlas is)."""
    finish = meter.COST_SEAMS * texels + (1 + sets) * sum(_set_costs(texels, area, settings).values())
    return _trace_cost(texels, settings.trace), finish


def _probes_cost(grids, trace: tracer.BakeSettings) -> float:
    samples = -(-trace.samples // trace.pass_samples) * trace.pass_samples
    return sum(meter.COST_PROBE * g.count * samples * (1.0 + trace.bounces / 2) for g in grids)


def check_inward(
    atlases: list[AtlasInput], scene: BakeScene, mode: str = inward.OPEN_SIDE
) -> tuple[list[AtlasInput], list[list[inward.InwardObject]], BakeScene]:
    """Faces that point into their own object (`core.bakepoints.inward`), found before any bake point:
    (the atlases to bake: with `mode` OPEN_SIDE those faces' normals turned round, else as
    given; per atlas the objects found; the scene to trace: with OPEN_SIDE those faces' winding
    turned round, `inward.flip_scene`). REFUSE with any found: InwardFacesRefused naming them."""
    if mode not in inward.MODES:
        raise BakeError(f"inward faces: unknown setting {mode!r} (one of {', '.join(inward.MODES)})")
    lights = inward.light_points(scene)
    found = [inward.find(atlas.surface, atlas.objects, lights) for atlas in atlases]
    if mode == inward.REFUSE and any(found):
        raise InwardFacesRefused([item.message(mode) for items in found for item in items])
    if mode == inward.OPEN_SIDE and any(found):
        flipped = [np.concatenate([x.triangles for x in f]) if f else np.zeros(0, np.int64) for f in found]
        positions = np.concatenate([a.surface.positions[rows] for a, rows in zip(atlases, flipped)])
        scene = inward.flip_scene(scene, positions)
        atlases = [replace(a, surface=inward.flip(a.surface, rows)) for a, rows in zip(atlases, flipped)]
    return atlases, found, scene


def _inward_sidecar(extra: dict, found: list[inward.InwardObject], mode: str) -> dict:
    """The sidecar's extra keys of one atlas: `extra`, plus (only when some of its objects have
    faces that point in) their messages in "notes" and their records in "inward_faces"."""
    if not found:
        return extra
    notes = list(extra.get("notes", [])) + [item.message(mode) for item in found]
    return {**extra, "notes": notes, "inward_faces": [item.note(mode) for item in found]}


def _local_atlases(
    out: Staged,
    atlases,
    points,
    scene: BakeScene,
    ray_scene,
    settings: PipelineSettings,
    t_points,
    extras,
    report,
    cancel,
) -> list[AtlasResult]:
    """Every atlas here, one after the other: trace, then `finish_atlas`, its files staged into
    `out` as soon as it is traced (its SH lives on only as float32 images)."""
    total_texels = sum(len(p.texel) for p in points)
    results, done_texels = [], 0
    t_trace = time.perf_counter()
    for i, atlas in enumerate(atlases):
        pts, points[i] = points[i], None  # held by the traced atlas only: freed once it is imaged
        n, area = len(pts.texel), _window_texels(atlas, pts)
        trace = _atlas_settings(settings.trace, time.perf_counter() - t_trace, n, total_texels - done_texels)
        planned_trace, planned_finish = _atlas_costs(n, area, settings)
        report.left += _trace_cost(n, trace) - planned_trace  # its share of a time budget is known now
        tracing = report.span(_trace_cost(n, trace), f"'{atlas.name}'")
        # compact: the SH the files take (float32) and L0's standard error, streamed chunk by chunk
        traced = tracer.bake(pts, scene, trace, progress=tracing.show, cancel=cancel, ray_scene=ray_scene, compact=True)
        del pts
        done_texels += n
        _check_cancel(cancel)
        _, finish = _atlas_costs(n, area, settings, len(traced.sets))
        report.plan(finish - planned_finish)  # its light sets, known now
        finishing = report.span(finish, f"'{atlas.name}'")
        info = finish_atlas(atlas, traced, settings, t_points, extras[i], out, finishing, release=True)
        results.append(atlas_result(atlas, out.out_dir, info))
        del traced
        finishing.show(1.0, "written")
    return results


def _farm_atlases(
    farm,
    out: Staged,
    atlases,
    points,
    scene: BakeScene,
    ray_scene,
    settings: PipelineSettings,
    t_points,
    extras,
    report,
    cancel,
) -> list[AtlasResult]:
    """Every atlas on `farm` (`core.farm.Farm`, its tracing started by `run`): the client
    collects the atlases' tracing in turn and starts each one's finishing task (post stages and
    encoding on a worker, `farm.finish`), staging the files of every finished one into `out` as
    it comes back. An atlas the workers cannot denoise as this process would comes back traced
    and is finished here (`finish_atlas`)."""
    total = sum(len(p.texel) for p in points)
    results: list = [None] * len(atlases)
    pending: dict = {}
    done_texels = 0

    def fraction() -> float:
        written = sum(r is not None for r in results) / len(atlases)
        return _STAGES[0] + _STAGES[1] * done_texels / total + _STAGES[2] * written

    def stage(i: int) -> None:
        atlas = atlases[i]
        report.report(fraction(), f"'{atlas.name}': {_post_message(settings)} on the farm")
        kind, answer = farm.result(pending.pop(i), cancel)
        t = time.perf_counter()
        if kind == "traced":  # no worker denoises as this process does: finish it here
            report.report(fraction(), f"'{atlas.name}': {_post_message(settings)} here (no farm worker has this OIDN)")
            answer.points = points[i]  # the traced atlas itself, so that `release` frees its SH
            info = finish_atlas(
                atlas, answer, settings, t_points, extras[i], out, lambda: _check_cancel(cancel), release=True
            )
        else:
            for method, args in answer["out"]:
                getattr(out, method)(*args)
            info = answer["summary"]
            info["seconds"]["write"] = time.perf_counter() - t
        results[i] = atlas_result(atlas, out.out_dir, info)
        points[i] = None  # written: its bake points may go
        report.report(fraction(), f"wrote '{atlas.name}'")

    for i, (atlas, pts) in enumerate(zip(atlases, points)):

        def on_trace(f, msg, base=done_texels, n=len(pts.texel), name=atlas.name):
            written = sum(r is not None for r in results) / len(atlases)
            frac = (base + f * n) / total
            report.report(_STAGES[0] + _STAGES[1] * frac + _STAGES[2] * written, f"'{name}': {msg}")

        estimator = tracer.texel_estimator(pts, scene, settings.trace, ray_scene)  # as `run` submitted it
        pending[i] = farm.finish(atlas, settings, out.out_dir, estimator, t_points, extras[i], on_trace, cancel)
        done_texels += len(pts.texel)
        for j in [j for j, handle in pending.items() if handle.done()]:
            stage(j)
    for j in sorted(pending):
        stage(j)
    return results


def _bake_probes(staging, grids, scene: BakeScene, settings: PipelineSettings, out_dir: Path, report, cancel):
    """Trace every probe volume and stage its files and `probes.json`; one AtlasResult per volume
    (its files: the volume's EXR; texels: its probes)."""
    baked = []
    for grid in grids:
        tick = report.span(_probes_cost([grid], settings.trace), f"probes of '{grid.name}'")
        baked.append(probes.bake(grid, scene, settings.trace, progress=tick.show, cancel=cancel))
        _check_cancel(cancel)
    report.report(report.shown, "writing the probe volumes")
    probes.write(staging, out_dir, baked)
    return [
        AtlasResult(
            b.grid.name,
            lightmap_files.AtlasFiles(out_dir, probes.file_stem(b.grid.name)),
            b.grid.count,
            b.rays,
            {"probes": b.seconds},
            b.warnings,
            b.sets,
            kind="probes",
        )
        for b in baked
    ]


def _post_message(settings: PipelineSettings) -> str:
    """The status line while an atlas's post stages and encoding run."""
    steps = [word for word, on in (("denoising", settings.denoise), ("stitching", settings.stitch_seams)) if on]
    return f"{', '.join(steps)} and encoding" if steps else "encoding"


def _atlas_settings(trace: tracer.BakeSettings, spent: float, texels: int, texels_left: int) -> tracer.BakeSettings:
    """The tracer settings of one atlas: a time budget is shared among the atlases still to
    bake in proportion to their texels."""
    if not trace.time_budget:
        return trace
    share = max(trace.time_budget - spent, 0.0) * texels / max(texels_left, 1)
    return replace(trace, time_budget=max(share, 1e-3))


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
        (a denoiser that failed half-way restores the traced SH from it)."""
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
    """The last stages of one atlas here (`finish_atlas`, releasing `traced`'s SH as a bake does),
    its files staged in `staging`."""
    check = lambda: _check_cancel(cancel)  # noqa: E731
    info = finish_atlas(atlas, traced, settings, t_points, extra, Staged(staging, out_dir), check, release=True)
    return atlas_result(atlas, out_dir, info)


def atlas_result(atlas: AtlasInput, out_dir, info: dict) -> AtlasResult:
    """The AtlasResult of one atlas written into `out_dir` from `finish_atlas`'s summary."""
    files = lightmap_files.AtlasFiles(Path(out_dir), atlas.name)
    return AtlasResult(atlas.name, files, info["texels"], info["rays"], info["seconds"], info["warnings"], info["sets"])


def finish_atlas(
    atlas: AtlasInput,
    traced: TracedAtlas,
    settings: PipelineSettings,
    t_points: float,
    extra: dict,
    out,
    check: Callable[[], None] = lambda: None,
    recorded: tracer.BakeSettings | None = None,
    release: bool = False,
) -> dict:
    """The last stages of one atlas: seams → image → raw files → post stages → encode, its files
    handed to `out` (`Staged` here; a farm worker keeps them to return, `core.farm`): `out.raw(name,
    parent, images)` once imaged, `out.atlas(name, parent, encoded, sidecar)` per file set as soon
    as it is encoded, `out.seams(name, seams)`.
    The raw SH file keeps the SH as traced; the seams file is written whether or not this bake
    stitches (a re-encode may). With light sets, the same stages then run for each set's SH
    into its own atlas files (`light_sets.set_atlas_name`), listed in the atlas's sidecar.
    `check()` raises to cancel; `recorded`: the tracer settings the sidecar records (default
    `settings.trace`; a farm worker computes with its own thread count). `release`: drop
    `traced`'s SH and standard error once they are imaged (`TracedAtlas.release_sh`; the caller
    no longer needs them, and they are the largest arrays of a bake), and without light sets its
    bake points too (`TracedAtlas.release_points`: the sets' images need them later). Returns the
    atlas's summary: texels, rays, seconds per stage, warnings, light sets. `check` may be a
    `core.progress.Tick` (a bake's): each stage gets its part, by `_set_costs`, and reports in it.
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
    warnings = _finish_files(
        out,
        atlas.name,
        "",
        traced,
        settings,
        sidecar,
        atlas_seams,
        seconds,
        set_parts[0],
        release,
        last=not traced.sets,
    )
    out.seams(atlas.name, atlas_seams)
    for k, (name, set_name) in enumerate(zip(traced.sets, set_names)):
        set_sidecar = {key: v for key, v in sidecar.items() if key not in ("light_sets", "timings_seconds")}
        set_sidecar["light_set"] = {"name": name, "of": atlas.name}
        set_parts[k + 1].name = f"'{set_name}'"
        warnings += _finish_files(
            out,
            set_name,
            atlas.name,
            traced.light_set(k),
            settings,
            set_sidecar,
            atlas_seams,
            seconds,
            set_parts[k + 1],
        )
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
    check,
    release: bool = False,
    last: bool = False,
) -> list[str]:
    """Image → raw files (`out.raw`) → post stages → encode of one atlas's SH (the atlas's own, or
    one light set's), handed to `out.atlas`; adds the post stages' seconds to seconds["post"];
    returns their warnings.
    `release`: `traced.release_sh()` once imaged, and with `last` (no image of these bake points
    follows) `traced.release_points()`. `check` may be a `core.progress.Tick`: split among the
    stages by `_set_costs`, each named ("encode 'Lightmap'")."""
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
    # the bake points go before the SH is imaged when nothing else needs them
    raw = encoding.TexelData.from_points(
        traced.points,
        traced.sh,
        noise=traced.noise(),
        release=traced.release_points if release and last else None,
        release_sh=traced.release_sh_rows if release else None,
        crop=True,  # an almost empty atlas: the window of its texels (the files are the same)
    )
    if release:
        traced.release_sh()
    # the raw files first, as traced: then the post stages may write into `raw`'s SH (memory)
    fill = raw.fill()
    parts["raw"].at(0.0, "raw files")
    with encoding.raw_files(raw, fill) as images_of:
        out.raw(name, parent, images_of, *_tick_for(out, parts["raw"]))
    del images_of
    restore = functools.partial(_restore_sh, raw.sh, fill.valid, out, name, parent, raw.window)
    data, sidecar["post"] = post.apply(raw, settings, parts["post"], atlas_seams, in_place=True, restore=restore)
    seconds["post"] = seconds.get("post", 0.0) + time.perf_counter() - t
    del raw, restore  # `data` holds the SH now, denoised in place or as traced
    data = replace(data, noise=None)  # in the texels file already; the encoder does not read it
    stages.trim_heap()  # what the post stages' threads freed (memory)
    parts["encode"].at(0.0, "encoding")
    encoded = encoding.encode_atlas(
        data,
        encoding.for_settings(settings.encoder),
        raw=False,
        fill=_same_fill(fill, data),
        spend=True,
        tick=parts["encode"],
        threads=settings.trace.threads,
    )
    parts["stitch encoded"].at(0.0)
    encoded = post.stitch_encoded(
        encoded, data.coverage, settings, atlas_seams, sidecar["post"], parts["stitch encoded"], in_place=True
    )
    del data, fill
    parts["write"].at(0.0, "encoded files")
    out.atlas(name, parent, encoded, sidecar, *_tick_for(out, parts["write"]))  # write (here) or keep (a farm worker)
    return post.warnings(sidecar["post"])


def _tick_for(out, tick: Tick) -> tuple:
    """The optional tick argument of `out.raw` / `out.atlas`: `Staged` writes and reports; other
    keepers of the files (a farm worker's) take none."""
    return (tick,) if isinstance(out, Staged) else ()


def _restore_sh(sh: np.ndarray, valid: np.ndarray, out, name: str, parent: str, window=None) -> None:
    """Put the traced SH of the baked texels (flat indices `valid`) back into `sh` `(H, W, 9, 3)`
    from the raw SH file staged (or kept) in `out`: a denoiser that failed half-way through
    writing it (the file's other texels are dilated; the denoiser writes baked texels only).
    `window`: the rectangle of the atlas `sh` is (`TexelData.window`), None for the whole."""
    h, w = sh.shape[:2]
    traced = out.traced_sh(name, parent)
    if window is not None:
        traced = traced[window.y0 : window.y0 + window.h, window.x0 : window.x0 + window.w]
    sh.reshape(h * w, -1)[valid] = np.ascontiguousarray(traced).reshape(h * w, -1)[valid]


def _same_fill(fill, data: encoding.TexelData):
    """`fill` (the traced atlas's) if it is `data`'s too: no post stage gave texels outside the charts
    a value of their own (seam stitching's `extra_sources`), else None (the encoder finds `data`'s)."""
    return fill if data.extra_sources is None else None


def reencode(
    files: lightmap_files.AtlasFiles,
    encoder: EncoderSettings,
    threads: int = 0,
    denoise: bool = False,
    denoiser_library: str = "",
    stitch_seams: bool = True,
) -> tuple[float, list[str]]:
    """Encode an atlas again from its raw SH and texel EXRs (the SH as traced) with other encoder
    or post-stage settings (no tracing): read → post stages → encode → write, the stages of a
    bake; replaces the encoded EXR and the sidecar atomically (the raw files and the seams file
    stay), for the atlas and each of its light sets. A blend of the light sets (`light_sets.blend_atlas`)
    is undone: the atlas's file holds their sum again. Stitching reads the atlas's seams file; a bake without one (made before seams files)
    is encoded unstitched, with a warning. `threads` (0 = every core) read and compress the EXRs
    and run the denoiser; the sidecar records it as `reencode_threads`. Returns the seconds it
    took and the post stages' warnings."""
    t = time.perf_counter()
    threads = parallel.resolve_threads(threads)
    exr.set_threads(threads)
    settings = PipelineSettings(
        trace=tracer.BakeSettings(threads=threads),
        encoder=encoder,
        denoise=denoise,
        denoiser_library=denoiser_library,
        stitch_seams=stitch_seams,
    )
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    warnings: list[str] = []
    with exr.Staging() as staging:
        for atlas in [files, *files.light_sets(sidecar)]:
            warnings += _reencode_files(staging, atlas, settings, threads)
        staging.commit()
    return time.perf_counter() - t, [f"atlas '{files.name}', {w}" for w in dict.fromkeys(warnings)]


class _RawFiles:
    """The raw files a re-encode read, as `_restore_sh` asks for the traced SH (`Staged.traced_sh`)."""

    def __init__(self, files: lightmap_files.AtlasFiles):
        self.files = files

    def traced_sh(self, name: str, parent: str) -> np.ndarray:
        return lightmap_files.read_sh(self.files.sh)


def _reencode_files(staging, files: lightmap_files.AtlasFiles, settings: PipelineSettings, threads: int) -> list[str]:
    """Read → post stages → encode → stage the encoded file and sidecar of one atlas (or light set)."""
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    sidecar.pop("blend", None)
    data = lightmap_files.read_texel_data(files, crop=True)  # an almost empty atlas: its texels' window
    sidecar["reencoded_from_sh"] = True
    sidecar["reencode_threads"] = threads
    atlas_seams = lightmap_files.read_seams(files, data.atlas_shape) if settings.stitch_seams else None
    # the post stages write into the images read (memory: no second copy of the atlas's SH)
    restore = functools.partial(_restore_sh, data.sh, np.flatnonzero(data.baked), _RawFiles(files), "", "", data.window)
    data, sidecar["post"] = post.apply(data, settings, seams=atlas_seams, in_place=True, restore=restore)
    del restore
    encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False, threads=threads)
    encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, sidecar["post"], in_place=True)
    del data
    lightmap_files.write_atlas(staging, files, encoded, sidecar)
    return post.warnings(sidecar["post"])
