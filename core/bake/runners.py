"""The atlas job of a bake, points → trace → finish, behind one interface (`AtlasRunner`) that
`bake.run` calls the same way for a bake here (`LocalRunner`) and on a Dask cluster
(`FarmRunner`, `core.farm`). The same files either way. No bpy."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol

from .. import tracer
from ..bakepoints import BakePoints
from ..progress import Progress, Tick
from ..rays import RayScene
from ..scene import BakeScene
from .costs import _atlas_costs, _trace_cost, _window_texels
from .data import AtlasInput, AtlasResult, PipelineSettings, _check_cancel, atlas_result
from .finishing import Staged, finish_atlas
from .points import check_points, points_of

#: A farm bake's shares of the progress bar (bake points, tracing, finishing + writing); a bake
#: here shares it out by the stages' estimated costs (`core.progress`, `costs._atlas_costs`).
_STAGES = (0.08, 0.84, 0.08)


@dataclass
class AtlasJobs:
    """What every atlas's job of one bake shares, as `run` hands it to its runner: the atlases
    (their inward faces turned round, `points.check_inward`; without their surfaces, which only
    the bake points read), their bake points (each set to None once its atlas no longer needs
    it: memory), the scene to trace and its RayScene (None without geometry; both None once
    every atlas is traced, `traced_all`), the settings (threads resolved), the seconds the bake
    points took, and per atlas the sidecar's extra keys."""

    atlases: list[AtlasInput]
    points: list  # of BakePoints, None once dropped
    scene: BakeScene | None
    ray_scene: RayScene | None
    settings: PipelineSettings
    t_points: float
    extras: list[dict]

    def traced_all(self) -> None:
        """Every atlas is traced: the jobs let go of the scene and its RayScene, which nothing
        after the trace reads (memory: the Embree scene and the scene's triangles; a bake with
        probe volumes keeps its own reference to the scene for them, `run`)."""
        self.scene = self.ray_scene = None

    def scene_to_trace(self) -> BakeScene:
        """The scene, while some atlas is still to trace (`traced_all` lets go of it)."""
        if self.scene is None:
            raise RuntimeError("every atlas of this bake is traced: its scene was let go")
        return self.scene


class AtlasRunner(Protocol):
    """Where a bake's atlas jobs run; `run` calls, in this order: `check`, `bake_points` (then each
    function it returned, atlas by atlas), `start`, `atlases` (the files staged, then committed
    by `run`), `finished`."""

    def check(self, settings: PipelineSettings) -> None:
        """BakeError for settings this runner cannot bake."""

    def bake_points(
        self, atlases: list[AtlasInput], scene: BakeScene, ray_scene: RayScene | None, threads: int, cancel
    ) -> list[Callable[[Tick], BakePoints]]:
        """Per atlas, a function returning its bake points (checked, `points.check_points`), told
        its part of the progress (a `core.progress.Tick`, which also checks for the cancel)."""
        ...

    def start(self, jobs: AtlasJobs, out_dir) -> None:
        """Start what can run ahead of `atlases` (a farm's tracing of every atlas)."""

    def atlases(self, jobs: AtlasJobs, out: Staged, report: Progress, cancel) -> list[AtlasResult]:
        """Trace and finish every atlas, its files staged into `out`; one AtlasResult per atlas."""
        ...

    def finished(self) -> None:
        """The bake's files are committed: drop what only a resumed bake would need."""


def runner_for(farm) -> AtlasRunner:
    """The runner of a bake: on `farm` (`core.farm.Farm`), or here when it is None."""
    return LocalRunner() if farm is None else FarmRunner(farm)


class LocalRunner:
    """Every atlas's job in this process: its bake points (`points.points_of`), then atlas after
    atlas trace → `finish_atlas` (`_local_atlases`)."""

    def check(self, settings: PipelineSettings) -> None:
        """Every setting bakes here."""

    def bake_points(
        self, atlases: list[AtlasInput], scene: BakeScene, ray_scene: RayScene | None, threads: int, cancel
    ) -> list[Callable[[Tick], BakePoints]]:
        return [functools.partial(points_of, atlas, ray_scene, threads, cancel) for atlas in atlases]

    def start(self, jobs: AtlasJobs, out_dir) -> None:
        """Nothing runs ahead: each atlas is traced in `atlases`, after the one before is written."""

    def atlases(self, jobs: AtlasJobs, out: Staged, report: Progress, cancel) -> list[AtlasResult]:
        return _local_atlases(jobs, out, report, cancel)

    def finished(self) -> None:
        """Nothing kept."""


class FarmRunner:
    """Every atlas's job on a Dask cluster (`core.farm.Farm`): bake points, tracing, post stages
    and encoding on the farm's workers, this process staging the files (`_farm_atlases`)."""

    def __init__(self, farm):
        self.farm = farm

    def check(self, settings: PipelineSettings) -> None:
        self.farm.check(settings.trace)

    def bake_points(
        self, atlases: list[AtlasInput], scene: BakeScene, ray_scene: RayScene | None, threads: int, cancel
    ) -> list[Callable[[Tick], BakePoints]]:
        remote = self.farm.bake_points(atlases, scene, cancel)  # on the farm's workers
        return [functools.partial(_checked, atlas, wait) for atlas, wait in zip(atlases, remote)]

    def start(self, jobs: AtlasJobs, out_dir) -> None:
        """Every atlas's tracing starts now; `atlases` collects them in turn."""
        settings, scene, ray_scene = jobs.settings, jobs.scene_to_trace(), jobs.ray_scene
        for atlas, pts in zip(jobs.atlases, jobs.points):
            self.farm.submit(
                atlas.name, out_dir, tracer.texel_estimator(pts, scene, settings.trace, ray_scene), settings.trace
            )

    def atlases(self, jobs: AtlasJobs, out: Staged, report: Progress, cancel) -> list[AtlasResult]:
        return _farm_atlases(self.farm, jobs, out, report, cancel)

    def finished(self) -> None:
        """The farm's checkpoints of this bake go (`Farm.finished`)."""
        self.farm.finished()


def _checked(atlas: AtlasInput, wait: Callable[[], BakePoints], tick: Tick) -> BakePoints:
    """The bake points of `atlas` built on the farm, once `wait` returns them, checked."""
    tick.at(0.0, "built by the farm's workers")
    return check_points(atlas, wait())


def _local_atlases(jobs: AtlasJobs, out: Staged, report, cancel) -> list[AtlasResult]:
    """Every atlas here, one after the other: trace, then `finish_atlas`, its files staged into
    `out` as soon as it is traced (its SH lives on only as float32 images). The last atlas is
    finished without the scene (`AtlasJobs.traced_all`)."""
    # the scene and its RayScene are read from `jobs` (no reference of this function's): they go
    # once the last atlas is traced, before its finishing (`AtlasJobs.traced_all`)
    atlases, points = jobs.atlases, jobs.points
    settings, t_points, extras = jobs.settings, jobs.t_points, jobs.extras
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
        # spend_points: the bake points' tracing arrays go behind the chunks traced (memory)
        traced = tracer.bake(
            pts,
            jobs.scene_to_trace(),
            trace,
            progress=tracing.show,
            cancel=cancel,
            ray_scene=jobs.ray_scene,
            compact=True,
            spend_points=True,
        )
        del pts
        if i == len(atlases) - 1:
            jobs.traced_all()
        done_texels += n
        _check_cancel(cancel)
        _, finish = _atlas_costs(n, area, settings, len(traced.sets))
        report.plan(finish - planned_finish)  # its light sets, known now
        finishing = report.span(finish, f"'{atlas.name}'")
        info = finish_atlas(atlas, traced, settings, t_points, extras[i], out, finishing)
        results.append(atlas_result(atlas, out.out_dir, info))
        del traced
        finishing.show(1.0, "written")
    return results


def _farm_atlases(farm, jobs: AtlasJobs, out: Staged, report, cancel) -> list[AtlasResult]:
    """Every atlas on `farm` (`core.farm.Farm`, its tracing started by `FarmRunner.start`): the client
    collects the atlases' tracing in turn and starts each one's finishing task (post stages and
    encoding on a worker, `farm.finish`), staging the files of every finished one into `out` as
    it comes back. An atlas the workers cannot denoise as this process would comes back traced
    and is finished here (`finish_atlas`)."""
    atlases, points, scene, ray_scene = jobs.atlases, jobs.points, jobs.scene_to_trace(), jobs.ray_scene
    settings, t_points, extras = jobs.settings, jobs.t_points, jobs.extras
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
            answer.points = points[i]  # the traced atlas itself: `finish_atlas` spends it
            info = finish_atlas(atlas, answer, settings, t_points, extras[i], out, lambda: _check_cancel(cancel))
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

        estimator = tracer.texel_estimator(pts, scene, settings.trace, ray_scene)  # as `start` submitted it
        pending[i] = farm.finish(atlas, settings, out.out_dir, estimator, t_points, extras[i], on_trace, cancel)
        done_texels += len(pts.texel)
        for j in [j for j, handle in pending.items() if handle.done()]:
            stage(j)
    for j in sorted(pending):
        stage(j)
    return results


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
