"""The unwrap's reproducibility and its fit's cost (issue 58); needs bpy.

    python bench/unwrap_repro.py FILE.blend --resolution 4096 [--preset production] [--cores 2 1] [--cold]

Reads the receivers as `python -m hhd_lightmapper.cli FILE.blend bake --unwrap --resolution R
--preset P --objects <every mesh, sorted>` does (bench/end_to_end.py's command), then unwraps them
(the core unwrap, as the CLI's `_unwrap` runs it): once from an empty chart cache, then once per
core count of --cores with the unwrap told it has that many cores (`_cores`), the charts cached
(packing only) or, with --cold, charted again. A Markdown row per run: the load average before it,
wall and CPU seconds (this process and its xatlas children), chart and pack seconds, atlases,
texels (the objects' covered texel area), the first atlas's density (texels per metre) and packs,
and a hash of every object's UVs: equal hashes are byte-identical UVs. Results:
bench/results/unwrap.md, "Reproducible unwrap".
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import time


def receivers(blend: str, resolution: int, preset: str):
    """(UnwrapMeshes, UnwrapSettings) of every mesh of `blend`, read as the CLI reads them."""
    import bpy

    import hhd_lightmapper
    from hhd_lightmapper import cli
    from hhd_lightmapper.bridge import bake_session
    from hhd_lightmapper.operators import unwrap as unwrap_operator

    bpy.ops.wm.open_mainfile(filepath=blend)
    hhd_lightmapper.register()
    names = sorted(o.name for o in bpy.context.scene.objects if o.type == 'MESH')
    args = argparse.Namespace(resolution=resolution, preset=preset, objects=names)
    settings = cli._settings(bpy.context.scene, args)
    job = unwrap_operator.read_objects(bake_session.target_objects(bpy.context, names, settings), settings)
    return job.meshes, job.settings


def cpu_seconds() -> float:
    """User + system seconds of this process and its finished children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def row(label: str, meshes, settings, cold: bool) -> str:
    """One unwrap (charts from the cache unless `cold`) as a Markdown row (see the docstring)."""
    from hhd_lightmapper.core import unwrap
    from hhd_lightmapper.core.unwrap import packing

    if cold:
        unwrap.clear_chart_cache()
    else:
        packing._PACKED.clear()
    load = os.getloadavg()[0]
    start, cpu = time.perf_counter(), cpu_seconds()
    result = unwrap.unwrap(meshes, settings)
    wall, cpu = time.perf_counter() - start, cpu_seconds() - cpu
    digest = hashlib.blake2b(digest_size=8)
    for o in result.objects:
        digest.update(o.uv.tobytes())
    tries = result.stats["tries"][0]
    density = max(t for t, fits in tries if fits)
    return (
        f"| {label} | {load:.1f} | {wall:.1f} | {cpu:.1f} | {result.stats['chart_s']:.1f} | "
        f"{result.stats['pack_s']:.1f} | {len(result.atlas_sizes)} | {sum(o.texels for o in result.objects):,.0f} | "
        f"{density:.2f} ({len(tries)} packs; {result.stats['packs']} in all) | `{digest.hexdigest()}` |"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("blend")
    ap.add_argument("--resolution", type=int, required=True)
    ap.add_argument("--preset", default="production")
    ap.add_argument("--cores", type=int, nargs="*", default=[2, 1])
    ap.add_argument("--cold", action="store_true", help="chart again on every run")
    args = ap.parse_args()
    from hhd_lightmapper.core.unwrap import charting, packing

    meshes, settings = receivers(args.blend, args.resolution, args.preset)
    print(
        "| run | load | wall s | CPU s | chart s | pack s | atlases | texels | texels/m of atlas 1 (packs) | UV hash |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    )
    print(row("empty cache", meshes, settings, True), flush=True)
    for cores in args.cores:
        for module in (charting, packing):
            module._cores = lambda cores=cores: cores
        print(row(f"{cores} core(s){', charted again' if args.cold else ''}", meshes, settings, args.cold), flush=True)


if __name__ == "__main__":
    main()
