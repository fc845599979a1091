"""Unwrap (xatlas) and bake-point (raster) times and memory at 10k, 100k and 1M triangles.

    python bench/unwrap_raster.py [--sizes 10000 100000 1000000]
    python bench/unwrap_raster.py --unwrap-only [--sizes ...] [--module hhd_old.core.unwrap]
    python bench/unwrap_raster.py --scenes SCENES/bedroom/bedroom.blend ... [--resolution 2048] [--padding 8]

(SCENES: the external scenes' folder, docs/conventions.md#external-scenes)

The mesh is a field of displaced, subdivided spheres (many charts, curved surfaces, like real
props; scenekit/meshes.py `sphere_field`). Atlas resolution grows with the size (1024, 2048, 4096). Peak memory is the numpy/Python
peak of each stage measured with tracemalloc. Writes bench/results/unwrap_raster.json.

--unwrap-only times the unwrap alone, from an empty chart cache and again with the charts cached
(the same mesh unwrapped again), and prints Markdown rows (bench/results/unwrap.md); --module
times another implementation with the same API (e.g. the previous one, copied out of git).
--scenes unwraps every mesh object of .blend files into one shared atlas, as Unwrap does with
all of them selected and its default padding (8 texels: 2 mip levels) (needs bpy), and counts
the texels shared between charts as the bake rasterises them.
"""

from __future__ import annotations

import argparse
import importlib
import json
import time
import tracemalloc
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bakepoints, rays, unwrap
from hhd_lightmapper.core.unwrap import data
from scenekit.meshes import sphere_field, texel_overlaps  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def measure(fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, seconds, peak / 2**20


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
    return {
        "triangles": int(len(f)),
        "resolution": resolution,
        "charts": result.charts,
        "utilisation_percent": 100 * result.utilisation[0],
        "texels": int(len(points.texel)),
        "unwrap_s": t_unwrap,
        "unwrap_peak_MiB": m_unwrap,
        "bake_points_s": t_points,
        "bake_points_peak_MiB": m_points,
        "buried_test_s": t_buried,
        "buried_texels": int(buried.sum()),
    }


RESOLUTION = {10_000: 1024, 100_000: 2048, 1_000_000: 4096}


def unwrap_only(n_triangles: int, resolution: int, module) -> str:
    """A Markdown row: triangles, atlas, charts, utilisation, unwrap seconds cold (stats), warm."""
    v, f = sphere_field(n_triangles)
    mesh = module.UnwrapMesh("field", v, f)
    if hasattr(module, "clear_chart_cache"):
        module.clear_chart_cache()
    settings = module.UnwrapSettings(resolution=resolution)
    t0 = time.perf_counter()
    result = module.unwrap([mesh], settings)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    module.unwrap([mesh], settings)
    warm = time.perf_counter() - t0
    stats = getattr(result, "stats", {})
    split = (
        (
            f"chart {stats['chart_s']:.1f} s in {stats.get('chart_processes', 0)} process(es), "
            f"pack {stats['pack_s']:.1f} s in {stats['packs']} pack(s)"
        )
        if stats
        else ""
    )
    return (
        f"| {len(f):,} | {resolution}² | {result.charts} | {100 * result.utilisation[0]:.1f}% | "
        f"{result.objects[0].texels:,.0f} | {cold:.1f} | {split} | {warm:.2f} |"
    )


def scene_meshes(path: str) -> list:
    """UnwrapMeshes (world space, with polygon indices) and loop-triangle vertex indices of
    every mesh object in the .blend at `path`, read as the Unwrap operator reads them."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(path))
    out = []
    for obj in sorted((o for o in bpy.data.objects if o.type == 'MESH'), key=lambda o: o.name):
        mesh = obj.data
        mesh.calc_loop_triangles()
        n = len(mesh.loop_triangles)
        if n == 0:
            continue
        co = np.zeros(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        tri, poly = np.zeros(n * 3, np.int64), np.zeros(n, np.int64)
        mesh.loop_triangles.foreach_get("vertices", tri)
        mesh.loop_triangles.foreach_get("polygon_index", poly)
        m = np.array(obj.matrix_world, dtype=np.float64)
        world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        mesh_ = unwrap.UnwrapMesh(obj.name, world, tri.reshape(-1, 3), polygons=poly)
        if (data.triangle_areas(world, mesh_.triangles) > 0).any():
            out.append(mesh_)
    return out


def scene_row(path: str, resolution: int, padding: int, module) -> str:
    """A Markdown row: scene, objects, triangles, atlas, charts, utilisation, seconds cold and
    warm, texels shared by two charts and texels covered twice by one chart.
    A mesh whose triangles all lack area is left out (Unwrap refuses it)."""
    meshes = scene_meshes(path)
    if module is not unwrap:
        meshes = [module.UnwrapMesh(m.name, m.positions, m.triangles) for m in meshes]
    if hasattr(module, "clear_chart_cache"):
        module.clear_chart_cache()
    settings = module.UnwrapSettings(resolution=resolution, padding=padding)
    t0 = time.perf_counter()
    try:
        result = module.unwrap(meshes, settings)
    except Exception as exc:  # the old code could not fit the bedroom
        return (
            f"| {Path(path).stem} | {len(meshes)} | {sum(len(m.triangles) for m in meshes):,} | "
            f"{resolution}², padding {padding} | failed after {time.perf_counter() - t0:.0f} s: {exc} |"
        )
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    module.unwrap(meshes, settings)
    warm = time.perf_counter() - t0
    shared, twice = _overlaps([o.uv for o in result.objects], resolution)
    stats = getattr(result, "stats", {})
    split = f"chart {stats['chart_s']:.1f} s, pack {stats['pack_s']:.1f} s ({stats['packs']} packs)" if stats else ""
    return (
        f"| {Path(path).stem} | {len(meshes)} | {sum(len(m.triangles) for m in meshes):,} | "
        f"{resolution}², padding {padding} | "
        f"{result.charts} | {100 * result.utilisation[0]:.1f}% | {sum(o.texels for o in result.objects):,.0f} | "
        f"{cold:.1f} ({split}) | {warm:.2f} | "
        f"{shared:,} | {twice:,.0f} |"
    )


def _overlaps(uvs, size):
    """(texels touched by two charts, of one object or two; texel area covered twice), the
    texels rasterised as the bake covers them (scenekit/meshes.py `texel_overlaps`)."""
    report = texel_overlaps(uvs, size, size)
    return report["objects"] + report["charts"], sum(report["summed"]) - sum(report["area"])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--unwrap-only", action="store_true")
    ap.add_argument("--module", default="hhd_lightmapper.core.unwrap")
    ap.add_argument("--scenes", nargs="+", default=[])
    ap.add_argument("--resolution", type=int, default=2048)
    ap.add_argument("--padding", type=int, default=8)
    args = ap.parse_args()
    module = importlib.import_module(args.module)
    if args.scenes:
        print(
            "| scene | objects | triangles | atlas | charts | used | texels | unwrap s | again s | "
            "texels in 2 charts | texels covered twice |"
        )
        for path in args.scenes:
            print(scene_row(path, args.resolution, args.padding, module), flush=True)
        return
    if args.unwrap_only:
        print("| triangles | atlas | charts | used | texels | unwrap s | of which | again s |")
        for n in args.sizes:
            print(unwrap_only(n, RESOLUTION.get(n, 2048), module), flush=True)
        return
    resolution = RESOLUTION
    rows = []
    print(
        f"{'triangles':>10} {'atlas':>6} {'charts':>7} {'used%':>6} {'texels':>9} {'unwrap s':>9} "
        f"{'MiB':>6} {'points s':>9} {'MiB':>7} {'buried s':>9}"
    )
    for n in args.sizes:
        r = run(n, resolution.get(n, 2048))
        rows.append(r)
        print(
            f"{r['triangles']:>10} {r['resolution']:>6} {r['charts']:>7} {r['utilisation_percent']:>6.1f} "
            f"{r['texels']:>9} {r['unwrap_s']:>9.2f} {r['unwrap_peak_MiB']:>6.0f} {r['bake_points_s']:>9.2f} "
            f"{r['bake_points_peak_MiB']:>7.0f} {r['buried_test_s']:>9.2f}",
            flush=True,
        )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "unwrap_raster.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
