"""The bake on a Dask cluster (core/farm.py) on this machine: 1 against 2 worker processes, the
cost of a task, and a projection for a real farm from the measured costs.

    python bench/farm.py [--triangles 20000] [--resolution 512] [--samples 64] [--bounces 2] [--repeats 2]

Scene: the threads bench's (bench/threads.py): a field of displaced spheres on a ground plane in
one xatlas atlas, a sun and a sky. Measured, best of `--repeats` after one cold run:
  * the local bake's tracing (`tracer.bake`, a thread pool of 1 and of 2 threads);
  * the farm's on a LocalCluster (127.0.0.1) of 1 and of 2 single-threaded worker processes:
    wall-clock seconds, the tasks' own seconds (on the workers), and the first (cold) run's, which
    also ships the scene and builds its Embree scene and loads the kernels on every worker;
    the SH is checked bit-identical to the local bake's;
  * a task's overhead: the wall-clock of one worker running N tasks minus their own seconds, per
    task; and the round trip of an empty Dask task;
  * the bake points of the atlas on one farm worker (`Farm.bake_points`), checked equal to the
    local ones;
  * a local `bake.run`'s post stages + encoding + writing per texel (what the client did per
    atlas before the finishing tasks), denoised when the bpy module's OIDN is found;
  * the same atlas through `bake.run` on the farm (1 worker, `--finish-samples` samples: the
    finishing does not depend on them), warm (the second run): the finishing task's own seconds
    on the worker (seams, post stages, encoding), the bytes it returns and the client's
    writing; the files are checked byte-identical to the local `bake.run`'s;
  * bytes: the estimator shipped once per atlas (per texel), a task's result (per texel).
Then projects 30 atlases of 1024² (this atlas's coverage) on 320 single-threaded workers.
Prints the tables and writes bench/results/farm.md and farm.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
from hhd_lightmapper.core import bake, bakepoints, farm, tracer  # noqa: E402
from threads import scene_and_surface  # noqa: E402

RESULTS = HERE / "results"


def best(runs):
    return min(runs, key=lambda r: r["seconds"])


def local_trace(points, scene, ray_scene, settings, threads, repeats):
    runs = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        result = tracer.bake(points, scene, settings_with(settings, threads), ray_scene=ray_scene)
        runs.append({"seconds": time.perf_counter() - t0, "sh": result.sh, "rays": result.rays})
    return runs[0], best(runs[1:])


def settings_with(settings, threads):
    from dataclasses import replace

    return replace(settings, threads=threads)


def farm_trace(points, scene, ray_scene, settings, workers, repeats, chunks_per_task, atlas=None):
    import distributed

    runs = []
    with (
        distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0"
        ) as cluster,
        farm.connect(cluster.scheduler_address, chunks_per_task=chunks_per_task) as f,
    ):
        for _ in range(repeats + 1):
            f.tasks = []
            with tempfile.TemporaryDirectory() as folder:  # no checkpoint of an earlier run
                t0 = time.perf_counter()
                result = tracer.bake(points, scene, settings, ray_scene=ray_scene, runner=f.runner("bench", folder))
                seconds = time.perf_counter() - t0
            runs.append(
                {
                    "seconds": seconds,
                    "task_seconds": sum(t["seconds"] for t in f.tasks),
                    "tasks": len(f.tasks),
                    "sh": result.sh,
                }
            )
        # an empty task's round trip (scheduler + comms), 200 of them one after the other
        t0 = time.perf_counter()
        for _ in range(200):
            f.client.submit(int, 0, pure=False).result()
        empty = (time.perf_counter() - t0) / 200
        digest, payload = farm.names.ship(tracer.texel_estimator(points, scene, settings, ray_scene))
        remote_points = []
        if atlas is not None:  # the bake points on one worker (one thread), best of repeats + 1
            for _ in range(repeats + 1):
                t0 = time.perf_counter()
                [wait] = f.bake_points([atlas], scene)
                got = wait()
                remote_points.append(time.perf_counter() - t0)
            assert np.array_equal(got.position, points.position) and np.array_equal(got.buried, points.buried)
    return runs[0], best(runs[1:]), empty, len(payload), min(remote_points, default=None)


def pipeline(settings, library: str):
    """The bench's PipelineSettings: denoised with `library` (Blender's OIDN) when found."""
    return bake.PipelineSettings(trace=settings, denoise=bool(library), denoiser_library=library)


def exr_bytes(folder) -> dict:
    return {p.name: p.read_bytes() for p in sorted(Path(folder).glob("*.exr"))}


def client_costs(scene, surface, resolution, settings, library):
    """A local bake.run's per-stage seconds for one atlas, and its EXR files' bytes."""
    atlas = bake.AtlasInput("bench", resolution, resolution, surface, ["field"])
    with tempfile.TemporaryDirectory() as folder:
        [result] = bake.run([atlas], scene, pipeline(settings, library), folder)
        files = exr_bytes(folder)
    return result.seconds, result.texels, files


def farm_finish(scene, surface, resolution, settings, library, local_files):
    """The same atlas through bake.run on a 1-worker farm, twice (the second warm): the
    finishing task's record (seconds on the worker, bytes returned, where it ran), the client's
    seconds writing the files, and whether the files are the local bake's."""
    import distributed

    atlas = bake.AtlasInput("bench", resolution, resolution, surface, ["field"])
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0"
        ) as cluster,
        farm.connect(cluster.scheduler_address) as f,
    ):
        for _ in range(2):
            f.finishing = []
            with tempfile.TemporaryDirectory() as folder:
                t0 = time.perf_counter()
                [result] = bake.run([atlas], scene, pipeline(settings, library), folder, farm=f)
                seconds = time.perf_counter() - t0
                same = exr_bytes(folder) == local_files
    [record] = f.finishing
    return {**record, "write_seconds": result.seconds["write"], "bake_seconds": seconds, "identical": same}


def oidn_library() -> str:
    """The bpy module's OIDN library (as tests/test_oidn.py finds it), "" if none."""
    import importlib.util

    from hhd_lightmapper.core.post.denoise import oidn

    spec = importlib.util.find_spec("bpy")
    dirs = [Path(d) / "lib" for d in (spec.submodule_search_locations or [])] if spec else []
    found = oidn.find_library(dirs)
    return "" if found is None else str(found)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--triangles", type=int, default=20000)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--chunks-per-task", type=int, default=1)
    ap.add_argument("--farm-atlases", type=int, default=30)
    ap.add_argument("--farm-resolution", type=int, default=1024)
    ap.add_argument("--farm-cores", type=int, default=320)
    ap.add_argument("--farm-samples", type=int, default=256)
    ap.add_argument("--finish-samples", type=int, default=4)
    args = ap.parse_args()
    load_before = os.getloadavg()[0]
    scene, surface, ray_scene = scene_and_surface(args.triangles, args.resolution)
    settings = tracer.BakeSettings(samples=args.samples, bounces=args.bounces, seed=1, chunk_texels=8192)
    points = bakepoints.build(surface, args.resolution, args.resolution, occluders=ray_scene)
    n = len(points.texel)
    print(f"{len(scene.triangles)} triangles, {n} texels, {args.samples} samples, {args.bounces} bounces")

    rows, record = [], {"texels": n, "args": vars(args)}
    for threads in (1, 2):
        cold, warm = local_trace(points, scene, ray_scene, settings, threads, args.repeats)
        rows.append(("local", f"{threads} thread(s)", cold["seconds"], warm["seconds"], None, None, True))
        record[f"local_{threads}"] = {"cold": cold["seconds"], "warm": warm["seconds"]}
        reference = warm["sh"]
    atlas = bake.AtlasInput("bench", args.resolution, args.resolution, surface, ["field"])
    for workers in (1, 2):
        cold, warm, empty, payload, remote_points = farm_trace(
            points,
            scene,
            ray_scene,
            settings,
            workers,
            args.repeats,
            args.chunks_per_task,
            atlas if workers == 1 else None,
        )
        if remote_points is not None:
            record["remote_points_seconds"] = remote_points
        same = bool(np.array_equal(cold["sh"], reference) and np.array_equal(warm["sh"], reference))
        rows.append(
            (
                "farm",
                f"{workers} worker(s)",
                cold["seconds"],
                warm["seconds"],
                warm["task_seconds"],
                warm["tasks"],
                same,
            )
        )
        record[f"farm_{workers}"] = {
            "cold": cold["seconds"],
            "warm": warm["seconds"],
            "task_seconds": warm["task_seconds"],
            "cold_task_seconds": cold["task_seconds"],
            "tasks": warm["tasks"],
            "identical": same,
            "empty_task_seconds": empty,
            "payload_bytes": payload,
        }
    one = record["farm_1"]
    overhead = max(one["warm"] - one["task_seconds"], 0.0) / one["tasks"]
    cpu_per_texel_sample = one["task_seconds"] / (n * args.samples)
    library = oidn_library()
    quick = settings_with(settings, 2)
    from dataclasses import replace

    quick = replace(quick, samples=args.finish_samples)
    seconds, texels, local_files = client_costs(scene, surface, args.resolution, quick, library)
    client_per_texel = {k: v / texels for k, v in seconds.items() if k not in ("trace", "bake_points")}
    finish = farm_finish(scene, surface, args.resolution, quick, library, local_files)
    record["denoised"] = bool(library)
    record["finish"] = finish
    channels = 3
    result_bytes = n * (9 * channels * (8 + 4) + 3 * 8)

    # projection: 30 atlases of 1024² with this atlas's coverage, 256 samples, 320 cores
    coverage = n / args.resolution**2
    farm_texels = int(coverage * args.farm_resolution**2)
    per_task = args.chunks_per_task * settings.chunk_texels
    tasks_per_atlas = math.ceil(farm_texels / per_task)
    tasks = args.farm_atlases * tasks_per_atlas
    task_seconds = per_task * args.farm_samples * cpu_per_texel_sample + overhead
    waves = math.ceil(tasks / args.farm_cores)
    tracing = waves * task_seconds
    # the bake points: one task per atlas on the workers, all at once (one thread each)
    client_points = record["remote_points_seconds"] / n * farm_texels
    # before: the client ran seams, post stages, encoding and writing of every atlas in turn
    client_write_before = sum(client_per_texel.values()) * farm_texels
    # now: a finishing task per atlas on one worker thread, the client only writes (serially)
    finish_seconds = finish["seconds"] / n * farm_texels
    client_write = finish["write_seconds"] / n * farm_texels
    # every atlas's tracing tasks start together; each atlas's finishing task takes a worker once
    # its tracing is done (ahead of queued tracing tasks), so the farm's work is the tracing plus
    # the finishing, and the last atlas's finishing runs after the last wave
    work = tasks * task_seconds + args.farm_atlases * finish_seconds
    farm_waves = math.ceil(work / task_seconds / args.farm_cores)
    farm_seconds = farm_waves * task_seconds + finish_seconds
    # the client collects (1 GB/s + a checkpoint write per task), receives the finished images
    # (1 GB/s) and writes the atlases in turn
    client_collect = tasks * (result_bytes / n * per_task / 1e9 + 0.01)
    client_receive = finish["bytes"] / n * farm_texels / 1e9
    points_waves = math.ceil(args.farm_atlases / args.farm_cores)
    client_serial = client_collect + args.farm_atlases * (client_receive + client_write)
    total = points_waves * client_points + max(farm_seconds, client_serial) + client_receive + client_write
    total_before = (
        points_waves * client_points
        + max(tracing, (args.farm_atlases - 1) * client_write_before + client_collect)
        + client_write_before
    )
    record["projection"] = {
        "atlases": args.farm_atlases,
        "resolution": args.farm_resolution,
        "texels_per_atlas": farm_texels,
        "samples": args.farm_samples,
        "cores": args.farm_cores,
        "tasks": tasks,
        "task_seconds": task_seconds,
        "waves": waves,
        "tracing_seconds": tracing,
        "points_seconds_per_atlas": client_points,
        "finish_seconds_per_atlas": finish_seconds,
        "farm_seconds": farm_seconds,
        "client_write_seconds_per_atlas": client_write,
        "client_receive_seconds_per_atlas": client_receive,
        "client_collect_seconds": client_collect,
        "client_serial_seconds": client_serial,
        "total_seconds": total,
        "client_finishing_seconds_per_atlas": client_write_before,
        "total_seconds_client_finishing": total_before,
        "one_core_seconds": args.farm_atlases * farm_texels * args.farm_samples * cpu_per_texel_sample,
    }
    record.update(
        overhead_per_task=overhead,
        cpu_per_texel_sample=cpu_per_texel_sample,
        client_per_texel=client_per_texel,
        result_bytes_per_texel=result_bytes / n,
        load_before=load_before,
        load_after=os.getloadavg()[0],
        machine=f"{platform.machine()}, {os.cpu_count()} logical CPUs",
    )
    md = report(record, rows, args, n, len(scene.triangles))
    print(md)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "farm.md").write_text(md)
    (RESULTS / "farm.json").write_text(json.dumps(record, indent=1) + "\n")


def report(r, rows, args, n, triangles) -> str:
    p, f = r["projection"], r["finish"]
    lines = [
        "# The bake on a Dask cluster: 1 against 2 workers, task costs, a projection",
        "",
        f"`python bench/farm.py --triangles {args.triangles} --resolution {args.resolution} --samples {args.samples} "
        f"--bounces {args.bounces} --repeats {args.repeats} --chunks-per-task {args.chunks_per_task}`: {triangles} "
        f"triangles, {n} texels, {args.samples} samples, {args.bounces} bounces, chunks of 8192 texels, "
        f"{args.chunks_per_task} chunk(s) per task; a LocalCluster on 127.0.0.1 of single-threaded worker processes.",
        "",
        f"Machine: {r['machine']}; load average before the run {r['load_before']:.2f}, after {r['load_after']:.2f} "
        "(the 2 cores are shared with other engineers' jobs, which ran meanwhile: read differences under ~1.3× "
        "as noise, and every second as an upper bound).",
        "",
        "| run | on | cold s | warm s (best) | tasks' own s | tasks | SH bit-identical to local |",
        "| --- | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for kind, on, cold, warm, own, tasks, same in rows:
        lines.append(
            f"| {kind} | {on} | {cold:.2f} | {warm:.2f} | {'' if own is None else f'{own:.2f}'} | "
            f"{'' if tasks is None else tasks} | {'yes' if same else 'NO'} |"
        )
    f1, f2 = r["farm_1"], r["farm_2"]
    lines += [
        "",
        f"- 2 workers against 1: {f1['warm'] / f2['warm']:.2f}× (local 2 threads against 1: "
        f"{r['local_1']['warm'] / r['local_2']['warm']:.2f}×).",
        f"- Per task: {1000 * r['overhead_per_task']:.0f} ms of overhead beyond its own seconds (one worker's "
        f"wall-clock minus its tasks' seconds, per task); an empty Dask task's round trip "
        f"{1000 * f1['empty_task_seconds']:.1f} ms.",
        f"- Cold run: {f1['cold'] - f1['warm']:.2f} s more than warm on 1 worker (the estimator shipped, "
        f"{f1['payload_bytes'] / 1e6:.1f} MB = {f1['payload_bytes'] / n:.0f} B per texel; the Embree scene built; "
        "the kernels loaded from numba's cache).",
        f"- A task's result: {r['result_bytes_per_texel']:.0f} B per texel (one light set).",
        f"- Tracing cost: {1e9 * r['cpu_per_texel_sample']:.0f} ns of one worker per texel-sample.",
        "- A local `bake.run`'s stages after tracing per texel (seams, post stages, encoding + writing; "
        f"{'denoised' if r['denoised'] else 'not denoised: no OIDN found'}): "
        + ", ".join(f"{k} {1e6 * v:.2f} µs" for k, v in r["client_per_texel"].items())
        + ".",
        f"- On the farm (1 worker, warm, {args.finish_samples} samples): the finishing task took "
        f"{f['seconds']:.2f} s on the worker ({1e6 * f['seconds'] / n:.2f} µs per texel; finished on the "
        f"{f['finished_on']}) and returned {f['bytes'] / 1e6:.1f} MB ({f['bytes'] / n:.0f} B per texel); the "
        f"client wrote the files in {f['write_seconds']:.2f} s ({1e6 * f['write_seconds'] / n:.2f} µs per texel); "
        f"files byte-identical to the local bake's: {'yes' if f['identical'] else 'NO'}.",
        "",
        f"## Projection: {p['atlases']} atlases of {p['resolution']}² on {p['cores']} cores",
        "",
        f"{p['texels_per_atlas']} texels per atlas (this atlas's coverage), {p['samples']} samples, "
        f"{args.bounces} bounces, from the costs above:",
        "",
        f"- {p['tasks']} tracing tasks of {p['task_seconds']:.1f} s each, in {p['waves']} wave(s) on {p['cores']} "
        f"single-threaded workers: tracing {p['tracing_seconds']:.0f} s (one core alone: "
        f"{p['one_core_seconds'] / 3600:.1f} h).",
        f"- The bake points: {p['points_seconds_per_atlas']:.1f} s per atlas on one worker thread "
        f"(measured {r['remote_points_seconds']:.2f} s for this atlas on the farm), every atlas at once.",
        f"- Finishing (seams, post stages, encoding): {p['finish_seconds_per_atlas']:.1f} s per atlas on one "
        f"worker thread, each atlas's once its tracing is done; tracing and finishing together "
        f"{p['farm_seconds']:.0f} s on the farm.",
        f"- The client: {p['client_collect_seconds']:.0f} s collecting and checkpointing tracing results, and per "
        f"atlas {p['client_receive_seconds_per_atlas']:.1f} s receiving the finished images (1 GB/s) and "
        f"{p['client_write_seconds_per_atlas']:.1f} s writing them: {p['client_serial_seconds']:.0f} s in all, "
        "in turn.",
        f"- In all about **{p['total_seconds']:.0f} s ({p['total_seconds'] / 60:.1f} min)**: the bake points first, "
        "then the longer of the farm's tracing + finishing and the client's serial collecting and writing, then "
        f"the last atlas's writing. With the finishing on the client (before): "
        f"{p['client_finishing_seconds_per_atlas']:.1f} s per atlas in turn, about "
        f"{p['total_seconds_client_finishing']:.0f} s ({p['total_seconds_client_finishing'] / 60:.1f} min).",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
