"""The bake's parallel stages on 1 thread against every core, measured in the same run.

    python bench/threads.py [--triangles 20000] [--resolution 512] [--samples 32] [--repeats 5]

Scene: the tracer bench's (bench/tracer.py): a field of displaced spheres on a ground plane, one
xatlas atlas, a sun and a constant sky, 2 bounces. For 1 thread and for `parallel.machine_threads()`
(and twice that, oversubscribed) it times, best of `--repeats` (other work on the machine only
ever slows a run down, so the fastest run is the least disturbed):
  * tracing: texel-samples/s and rays/s of `tracer.bake`;
  * bake points: `bakepoints.build` with the buried and near-cover probe passes;
  * EXR writing: the SH EXR of the atlas (27 float32 channels, ZIP) through `exr.write_file`
    after `exr.set_threads`.
Also checks that every thread count gives the same SH, bit for bit. Prints the table and writes
bench/results/threads.md (with the machine's load average, since other work skews it).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bakepoints, encoding, parallel, rays, tracer, unwrap
from hhd_lightmapper.core.encoding.stage import raw_images
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit.meshes import sphere_field  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def scene_and_surface(n_triangles: int, resolution: int):
    """(BakeScene, SurfaceTriangles, RayScene) of the sphere field on a ground plane."""
    v, f = sphere_field(n_triangles)
    ground = np.array([[-5, -5, -1.2], [200, -5, -1.2], [200, 200, -1.2], [-5, 200, -1.2]], float)
    v = np.vstack([v, ground])
    f = np.vstack([f, [[len(v) - 4, len(v) - 3, len(v) - 2], [len(v) - 4, len(v) - 2, len(v) - 1]]])
    tris = v[f]
    res = unwrap.unwrap([unwrap.UnwrapMesh("field", v, f)], unwrap.UnwrapSettings(resolution=resolution))
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    surface = bakepoints.SurfaceTriangles(
        tris, normals, res.objects[0].uv.astype(float), np.zeros(len(f), int), np.full((len(f), 3), 0.6)
    )
    scene = BakeScene(
        tris,
        np.full((len(f), 3), 0.6),
        lights=[SunLight(np.array([0.4, 0.3, 0.866]), np.full(3, 3.0))],
        world=np.array([0.3, 0.45, 0.8]),
    )
    return scene, surface, rays.RayScene(tris)


def seconds(fn):
    """(fn(), its wall-clock seconds)."""
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def run_once(threads: int, scene, surface, ray_scene, args, folder: Path) -> dict:
    """The three stages once on `threads` workers: their seconds, the SH and the EXR bytes."""
    points, points_s = seconds(
        lambda: bakepoints.build(surface, args.resolution, args.resolution, occluders=ray_scene, threads=threads)
    )
    result = tracer.bake(
        points, scene, tracer.BakeSettings(samples=args.samples, bounces=2, threads=threads), ray_scene=ray_scene
    )
    data = encoding.TexelData.from_points(points, result.sh)
    channels = lightmap_files.exr_channels(encoding.SH_FILE, raw_images(encoding.SH_FILE, data.layers(), data.fill()))
    exr.set_threads(threads)
    path = folder / f"sh_{threads}.exr"
    _, write_s = seconds(lambda: exr.write_file(path, channels))
    return {
        "threads": threads,
        "texels": len(points.texel),
        "samples": result.samples,
        "rays": result.rays,
        "trace_s": result.seconds,
        "bake_points_s": points_s,
        "exr_write_s": write_s,
        "sh": result.sh,
        "exr": path.read_bytes(),
    }


def measure(counts: list[int], scene, surface, ray_scene, args, folder: Path) -> list[dict]:
    """One row per thread count: the fastest of `args.repeats` runs of each stage. The counts take
    turns within every round, so a burst of other work cannot land on one count's runs only."""
    runs = {n: [] for n in counts}
    for _ in range(args.repeats):
        for n in counts:
            runs[n].append(run_once(n, scene, surface, ray_scene, args, folder))
    rows = []
    for n in counts:
        row = dict(runs[n][-1])
        row.update({k: min(r[k] for r in runs[n]) for k in ("trace_s", "bake_points_s", "exr_write_s")})
        row.update(
            texel_samples_per_s=row["texels"] * row["samples"] / row["trace_s"],
            rays_per_s=row["rays"] / row["trace_s"],
            identical=all(
                np.array_equal(r["sh"], runs[counts[0]][0]["sh"]) and r["exr"] == runs[counts[0]][0]["exr"]
                for r in runs[n]
            ),
        )
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    base = rows[0]
    lines = [
        "| threads | tracing texel-samples/s | rays/s | × 1 thread | bake points s | × | SH EXR write s | × |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['threads']} | {r['texel_samples_per_s'] / 1e6:.2f} M | {r['rays_per_s'] / 1e6:.2f} M | "
            f"{r['texel_samples_per_s'] / base['texel_samples_per_s']:.2f} | {r['bake_points_s']:.2f} | "
            f"{base['bake_points_s'] / r['bake_points_s']:.2f} | {r['exr_write_s']:.3f} | "
            f"{base['exr_write_s'] / r['exr_write_s']:.2f} |"
        )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--triangles", type=int, default=20_000)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    scene, surface, ray_scene = scene_and_surface(args.triangles, args.resolution)
    warm = bakepoints.build(surface, 64, 64, occluders=ray_scene)  # compiles / loads the kernels
    tracer.bake(warm, scene, tracer.BakeSettings(samples=4, pass_samples=4), ray_scene=ray_scene)
    all_threads = parallel.machine_threads()
    counts = sorted({1, all_threads, 2 * all_threads})
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        rows = measure(counts, scene, surface, ray_scene, args, Path(tmp))
    identical = all(r["identical"] for r in rows)
    text = table(rows)
    head = (
        f"# Threads: 1 against every core\n\n`python bench/threads.py --triangles {args.triangles} "
        f"--resolution {args.resolution} --samples {args.samples} --repeats {args.repeats}`: "
        f"{len(surface.positions)} triangles, {rows[0]['texels']} texels, {rows[0]['samples']} samples, 2 bounces; "
        f"best of {args.repeats}.\n\nMachine: {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} logical CPUs, {all_threads} usable (`parallel.machine_threads()`); load average "
        f"before the run {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}.\n"
        f"SH and EXR bytes identical for every thread count: {'yes' if identical else 'NO'}.\n\n"
    )
    print(head + text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "threads.md").write_text(head + text + "\n")


if __name__ == "__main__":
    main()
