"""The bake pipeline over atlases: bake points → trace → image → raw files → post stages → encode →
write; and the re-encode of a bake's files. No bpy.

`run` is what the Bake operator (modal or not) and the command line both call, after the bpy side
has read the scene into plain data (`AtlasInput`, `BakeScene`). It never touches the scene: its
only effect is the files of each atlas, which are staged under temporary names and renamed over
any previous bake only once every atlas is finished. A cancel or an error leaves the previous
files as they were.

Threads: `settings.trace.threads` (0 = every core, `parallel`) is resolved once per run and used
by every parallel stage: the bake points' probes, the tracer and the EXR compression (encoding
itself stays on one thread: numpy holds the GIL for most of it, so a pool gained too little to
keep). The sidecar records the count under `bake` → `threads`; the files do not depend on it.

The modules: `data` (the atlases in, the settings, the results out), `points` (stage 1 of each
atlas: its bake points, the Embree scene every stage shares, faces that point inward),
`runners` (the atlas job, points → trace → finish, run here, `LocalRunner`, or on a Dask
cluster, `FarmRunner`), `finishing` (an atlas's last stages after its trace: seams → image → raw
files → post stages → encode, its files staged), `costs` (the stages' estimated costs, which
share out the progress bar), `reencoding` (a re-encode of one atlas's files).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from .. import parallel, probes, tracer
from .. import progress as meter
from ..bakepoints import BakePoints, SurfaceTriangles, inward
from ..encoding import EncoderSettings
from ..errors import BakeError
from ..files import exr, lightmap_files
from ..progress import Progress
from ..rays import RayScene
from ..scene import BakeScene
from ..stages import TracedAtlas
from . import runners
from .costs import _atlas_costs, _probes_cost, _window_texels
from .data import AtlasInput, AtlasResult, PipelineSettings, _check_cancel
from .finishing import Staged
from .points import _inward_sidecar, check_inward, points_of, ray_scene_of
from .reencoding import _reencode_files


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
    *,
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
    `settings.trace.worker_threads` worker threads. `farm`: a
    `core.farm.Farm` building the bake points, tracing the atlases and running their post stages
    and encoding on a Dask cluster, this process writing the files (`runners.FarmRunner`; the
    same files; its checkpoints go when the files are committed); without, all of it here
    (`runners.LocalRunner`). Both run each atlas's job the same way (`runners.AtlasRunner`).

    Progress (`core.progress.Progress`): every stage has its share of the range, estimated
    from the texels it works on (`_atlas_costs`), and reports within it (per tracer chunk,
    denoiser band, stitch iteration, encode chunk, band of written rows), its name in the
    message; the fraction never goes back and is 1.0 only once the files are committed. A
    cancel is honoured at the same grain.

    Memory (`core.memory`): `atlases` and `scene` are only read, and this function lets go of its
    own references to them, and to what it makes of them (the Embree scene, the inward-turned
    copies), as soon as what is left of the bake no longer reads them: each atlas's surface once
    every bake point is built, the scene and the Embree scene once the last atlas is traced,
    before its finishing (unless probe volumes follow). A caller that hands them over without
    keeping a reference (`bridge.bake_session.BakeSession.run`) lets that memory go then."""
    if not atlases and not probe_grids:
        raise BakeError("nothing to bake: no target objects")
    runner = runners.runner_for(farm)
    runner.check(settings)
    settings = settings.resolved()
    exr.set_threads(settings.trace.threads)
    report = Progress(progress, cancel)
    t0 = time.perf_counter()
    # until the bake points are known, half of each atlas's texels is a guess of its baked texels
    guess = [a.width * a.height // 2 for a in atlases]
    inward_cost = meter.COST_INWARD * sum(len(a.surface.positions) for a in atlases)
    report.plan(inward_cost + sum(meter.COST_POINTS * n + sum(_atlas_costs(n, 2 * n, settings)) for n in guess))
    report.plan(_probes_cost(probe_grids or [], settings.trace))
    checking = report.span(inward_cost, "faces that point in")
    atlases, found, scene = check_inward(atlases, scene, settings.inward_faces, checking, settings.trace.threads)
    ray_scene = ray_scene_of(scene)
    build = runner.bake_points(atlases, scene, ray_scene, settings.trace.threads, cancel)
    points = _built_points(atlases, build, found, guess, report, cancel)
    t_points = time.perf_counter() - t0
    # the surfaces were the bake points' (memory: nothing after them reads a surface)
    atlases = [atlas.without_surface() for atlas in atlases]
    # what is left, from the texels now known
    report.left = sum(sum(_atlas_costs(len(p.texel), _window_texels(a, p), settings)) for a, p in zip(atlases, points))
    report.plan(_probes_cost(probe_grids or [], settings.trace))
    extras = [_inward_sidecar(extra_sidecar or {}, f, settings.inward_faces) for f in found]
    jobs = runners.AtlasJobs(atlases, points, scene, ray_scene, settings, t_points, extras)
    # from here the jobs hold the scene and its RayScene, and let go of them once every atlas is
    # traced (`AtlasJobs.traced_all`); this function keeps the scene only for the probe volumes
    probe_scene = scene if probe_grids else None
    del scene, ray_scene
    runner.start(jobs, out_dir)  # a farm's tracing of every atlas starts now; `atlases` collects them in turn
    with exr.Staging() as staging:
        results = runner.atlases(jobs, Staged(staging, Path(out_dir)), report, cancel)
        for result, items in zip(results, found):
            result.inward = [item.message(settings.inward_faces) for item in items]
            result.warnings[:0] = result.inward
        if probe_grids:
            assert probe_scene is not None
            results.extend(_bake_probes(staging, probe_grids, probe_scene, settings, Path(out_dir), report, cancel))
        _check_cancel(cancel)
        staging.commit()
    runner.finished()
    report.finish(f"baked {_counted(len(atlases), 'atlas', 'atlases')}")
    return results


def _built_points(atlases, build: list, found, guess: list[int], report: Progress, cancel) -> list[BakePoints]:
    """Each atlas's bake points, in turn (`build`: the runner's functions, `AtlasRunner.bake_points`,
    each let go of once called: it holds its atlas's surface), their texels counted in its
    inward faces' records (`found`); `guess`: its planned texels."""
    points = []
    for i, atlas in enumerate(atlases):
        tick = report.span(meter.COST_POINTS * guess[i], f"bake points of '{atlas.name}'")
        _check_cancel(cancel)
        points.append(build.pop(0)(tick))
        inward.count_texels(found[i], points[-1].triangle)
        tick.show(1.0, f"{len(points[-1].texel)} texels")
    return points


def _counted(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


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
