"""Tracer throughput against raw Embree, measured in the same run.

    python bench/tracer.py [--triangles 100000] [--samples 32]

Scene: a field of displaced spheres on a ground plane (scenekit/meshes.py `sphere_field`), lit by
a sun and a constant sky, 2 bounces. Prints (a) raw embreex closest-hit rays/s for incoherent
rays in batches of 1M, on 1 and 2 threads (embreex's own API; and our binding of its Embree,
core.embree, on 2 threads); (b) the bake's rays/s (every ray it traces, shadow
rays included) and texel-samples/s on 2 threads, and its ratio to raw Embree; (c) the same
bake with one ray per Embree query (as for a library without packets: `core.embree.library().packets`
off) against 8-ray packets, after an
untimed bake, the two alternated (which goes first swaps every round), median of `--rounds`
each: one bake on this machine swings by 15% (the bakes are the same but for rays grazing a
triangle within float rounding). Writes bench/results/tracer.json.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bakepoints, embree, rays, tracer, unwrap
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit.meshes import sphere_field  # noqa: E402
from time_to_error import EmbreexRays

RESULTS = Path(__file__).resolve().parent / "results"


def raw_rate(scene, tris: np.ndarray, threads: int, batch: int = 1_000_000, rounds: int = 3, dtype=np.float64) -> float:
    """Closest-hit rays/s of `scene.intersect(origins, directions)` alone (inputs converted to
    `dtype` before timing)."""
    rng = np.random.default_rng(0)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    batches = []
    for _ in range(rounds * threads):
        o = rng.uniform(lo, hi, (batch, 3))
        d = rng.normal(size=(batch, 3))
        batches.append((o.astype(dtype), (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(dtype)))
    scene.intersect(*[a[:10] for a in batches[0]])  # builds a lazy BVH untimed
    t0 = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda od: scene.intersect(*od), batches))
    return len(batches) * batch / (time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--triangles", type=int, default=100_000)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=6, help="bakes per query mode (c)")
    args = ap.parse_args()
    v, f = sphere_field(args.triangles)
    ground = np.array([[-5, -5, -1.2], [200, -5, -1.2], [200, 200, -1.2], [-5, 200, -1.2]], float)
    v = np.vstack([v, ground])
    f = np.vstack([f, [[len(v) - 4, len(v) - 3, len(v) - 2], [len(v) - 4, len(v) - 2, len(v) - 1]]])
    tris = v[f]
    res = unwrap.unwrap([unwrap.UnwrapMesh("field", v, f)], unwrap.UnwrapSettings(resolution=args.resolution))
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    surface = bakepoints.SurfaceTriangles(
        tris, normals, res.objects[0].uv.astype(float), np.zeros(len(f), int), np.full((len(f), 3), 0.6)
    )
    ray_scene = rays.RayScene(tris)
    points = bakepoints.build(surface, args.resolution, args.resolution, occluders=ray_scene)
    scene = BakeScene(
        tris,
        np.full((len(f), 3), 0.6),
        lights=[SunLight(np.array([0.4, 0.3, 0.866]), np.full(3, 3.0))],
        world=np.array([0.3, 0.45, 0.8]),
    )
    theirs = EmbreexRays(tris)
    raw1, raw2 = raw_rate(theirs, tris, 1, dtype=np.float32), raw_rate(theirs, tris, 2, dtype=np.float32)
    ours2 = raw_rate(ray_scene, tris, 2)
    settings = tracer.BakeSettings(samples=args.samples, bounces=2, threads=2)
    tracer.bake(points, scene, settings, ray_scene=ray_scene)  # untimed: kernels loaded, memory touched
    seconds = {True: [], False: []}
    answers = embree.library().packets
    for k in range(args.rounds):
        for packets in (False, True) if k % 2 == 0 else (True, False):
            embree.library().packets = packets
            result = tracer.bake(points, scene, settings, ray_scene=ray_scene)
            seconds[packets].append(result.seconds)
    embree.library().packets = answers
    single, packet = float(np.median(seconds[False])), float(np.median(seconds[True]))
    bake_rate = result.rays / packet
    texel_samples = len(points.texel) * result.samples / packet
    row = {
        "triangles": len(f),
        "texels": len(points.texel),
        "samples": result.samples,
        "raw_rays_per_s_1_thread": raw1,
        "raw_rays_per_s_2_threads": raw2,
        "our_binding_rays_per_s_2_threads": ours2,
        "bake_rays_per_s": bake_rate,
        "bake_texel_samples_per_s": texel_samples,
        "bake_over_raw_2_threads": bake_rate / raw2,
        "bake_seconds": packet,
        "bake_seconds_one_ray_per_query": single,
        "bake_rays_per_s_one_ray_per_query": result.rays / single,
        "packets_speedup": single / packet,
        "bake_seconds_each": seconds[True],
        "bake_seconds_one_ray_per_query_each": seconds[False],
        "rays": result.rays,
    }
    for k, val in row.items():
        if isinstance(val, list):
            print(f"{k:28s} {', '.join(f'{v:.2f}' for v in val)}")
        else:
            print(f"{k:28s} {val:,.3f}" if isinstance(val, float) else f"{k:28s} {val:,}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "tracer.json").write_text(json.dumps(row, indent=2))


if __name__ == "__main__":
    main()
