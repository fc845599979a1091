"""Unwrap (xatlas) and bake-point (raster) times and memory at 10k, 100k and 1M triangles.

    python bench/unwrap_raster.py [--sizes 10000 100000 1000000]

The mesh is a field of displaced, subdivided spheres (many charts, curved surfaces, like real
props). Atlas resolution grows with the size (1024, 2048, 4096). Peak memory is the numpy/Python
peak of each stage measured with tracemalloc. Writes bench/results/unwrap_raster.json.
"""
from __future__ import annotations

import argparse
import json
import time
import tracemalloc
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bakepoints, rays, unwrap

RESULTS = Path(__file__).resolve().parent / "results"


def sphere_field(n_triangles: int, seed: int = 0):
    """Displaced UV spheres of ~2000 triangles each on a grid, ≈ n_triangles in total."""
    rng = np.random.default_rng(seed)
    rings, segments = 25, 40                                   # 2 × 40 × 24 = 1920 triangles
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    unit = np.vstack([[0, 0, 1], unit, [0, 0, -1]])
    idx = lambda r, s: 1 + r * segments + s % segments
    faces = [(0, idx(0, s), idx(0, s + 1)) for s in range(segments)]
    for r in range(rings - 2):
        for s in range(segments):
            faces += [(idx(r, s), idx(r + 1, s), idx(r + 1, s + 1)), (idx(r, s), idx(r + 1, s + 1), idx(r, s + 1))]
    faces += [(idx(rings - 2, s), len(unit) - 1, idx(rings - 2, s + 1)) for s in range(segments)]
    faces = np.array(faces)
    count = max(1, round(n_triangles / len(faces)))
    side = int(np.ceil(np.sqrt(count)))
    verts, tris = [], []
    for k in range(count):
        bump = 1.0 + 0.15 * np.sin(3 * unit[:, 0] + k) * np.cos(4 * unit[:, 1])
        verts.append(unit * bump[:, None] + [3.0 * (k % side), 3.0 * (k // side), 0.0])
        tris.append(faces + k * len(unit))
    return np.vstack(verts), np.vstack(tris)


def measure(fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, seconds, peak / 2 ** 20


def run(n_triangles: int, resolution: int) -> dict:
    v, f = sphere_field(n_triangles)
    mesh = unwrap.UnwrapMesh("field", v, f)
    result, t_unwrap, m_unwrap = measure(lambda: unwrap.unwrap([mesh], unwrap.UnwrapSettings(resolution=resolution)))
    uv = result.objects[0].uv.astype(np.float64)
    normals = np.repeat(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, None], 3, axis=1)
    surface = bakepoints.SurfaceTriangles(v[f], normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.5))
    points, t_points, m_points = measure(lambda: bakepoints.build(surface, resolution, resolution))
    scene = rays.RayScene(v[f])
    buried, t_buried, _ = measure(lambda: bakepoints.find_buried(points, scene))
    return {"triangles": int(len(f)), "resolution": resolution, "charts": result.charts,
            "utilisation_percent": 100 * result.utilisation[0], "texels": int(len(points.texel)),
            "unwrap_s": t_unwrap, "unwrap_peak_MiB": m_unwrap,
            "bake_points_s": t_points, "bake_points_peak_MiB": m_points,
            "buried_test_s": t_buried, "buried_texels": int(buried.sum())}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    args = ap.parse_args()
    resolution = {10_000: 1024, 100_000: 2048, 1_000_000: 4096}
    rows = []
    print(f"{'triangles':>10} {'atlas':>6} {'charts':>7} {'used%':>6} {'texels':>9} {'unwrap s':>9} "
          f"{'MiB':>6} {'points s':>9} {'MiB':>7} {'buried s':>9}")
    for n in args.sizes:
        r = run(n, resolution.get(n, 2048))
        rows.append(r)
        print(f"{r['triangles']:>10} {r['resolution']:>6} {r['charts']:>7} {r['utilisation_percent']:>6.1f} "
              f"{r['texels']:>9} {r['unwrap_s']:>9.2f} {r['unwrap_peak_MiB']:>6.0f} {r['bake_points_s']:>9.2f} "
              f"{r['bake_points_peak_MiB']:>7.0f} {r['buried_test_s']:>9.2f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "unwrap_raster.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
