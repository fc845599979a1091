"""xatlas charting and packing, run in a child process by `unwrap`. No bpy, no package imports.

Why a child process: xatlas's worker threads are not robust on small machines. On 2 cores we have
seen, rarely, a SIGSEGV inside Atlas.generate() and a hang in its TaskScheduler's destructor
(both in CI, both gone on re-run; xatlas users report the same on 2-core CI machines). In a child
a crash costs one retry instead of Blender and the artist's unsaved work, and the child leaves
with os._exit() as soon as its result is written, so the destructor never runs.

This file runs as a script (`python -I xatlas_worker.py`), so it imports only numpy and xatlas.
Protocol: stdin = two pickles, the parent's sys.path (a plain list, read before anything is
imported) and {"meshes": [(positions (V, 3) float32, triangles (T, 3) uint32)], "resolution",
"density", "padding", "max_resolution"}; stdout = pickle of `pack`'s result.
"""
import os
import pickle
import sys


def pack(meshes, resolution, density, padding, max_resolution):
    """Chart and pack `meshes` into one atlas. Returns {"error": message} or {"width", "height"
    (xatlas's own atlas size), "uv": [(T, 3, 2) float32 per mesh, normalised by xatlas's size],
    "mesh_charts": [charts per mesh], "charts", "utilisation"}.

    density (texels per unit) fixes the scale; otherwise the atlas is resolution² and the density
    is found: xatlas's estimate, shrunk by the measured overshoot until every chart fits in one
    atlas of that size (each retry re-runs xatlas: its binding cannot re-pack alone; usually one)."""
    import numpy as np
    import xatlas

    def attempt(texels_per_unit, fixed_resolution):
        atlas = xatlas.Atlas()
        for positions, triangles in meshes:
            atlas.add_mesh(np.ascontiguousarray(positions, dtype=np.float32),
                           np.ascontiguousarray(triangles, dtype=np.uint32))
        options = xatlas.PackOptions()
        options.padding = int(padding)
        options.bilinear = True
        options.texels_per_unit = float(texels_per_unit)
        options.resolution = int(fixed_resolution)
        atlas.generate(pack_options=options)
        return atlas

    if density is not None:
        atlas = attempt(density, 0)
        if max(atlas.width, atlas.height) > max_resolution or atlas.atlas_count > 1:
            return {"error": f"texel density {density:g}/m needs an atlas larger than {max_resolution}²: "
                             "lower the density or split the objects into several atlases"}
        return _result(atlas, len(meshes))
    atlas = attempt(0, resolution)
    tpu = atlas.texels_per_unit
    for _ in range(12):
        if atlas.atlas_count == 1 and atlas.width <= resolution and atlas.height <= resolution:
            return _result(atlas, len(meshes))
        overshoot = max(atlas.width, atlas.height) / resolution if atlas.atlas_count == 1 else 1.0
        tpu *= min(0.97, 0.98 / max(overshoot, 1e-9))
        atlas = attempt(tpu, resolution)
    return {"error": f"could not pack the charts into one {resolution}² atlas"}


def _result(atlas, n_meshes):
    import numpy as np
    uv, mesh_charts = [], []
    for k in range(n_meshes):
        _, indices, uvs = atlas[k]
        uv.append(np.ascontiguousarray(uvs[indices], dtype=np.float32))
        mesh_charts.append(int(atlas.get_mesh_chart_count(k)))
    utilisation = atlas.utilization
    utilisation = float(np.mean(utilisation)) if np.ndim(utilisation) else float(utilisation)
    return {"width": int(atlas.width), "height": int(atlas.height), "uv": uv,
            "mesh_charts": mesh_charts, "charts": int(atlas.chart_count), "utilisation": utilisation}


def main():
    stdin = sys.stdin.buffer
    sys.path[:0] = [p for p in pickle.load(stdin) if p not in sys.path]
    job = pickle.load(stdin)
    result = pack(job["meshes"], job["resolution"], job["density"], job["padding"], job["max_resolution"])
    sys.stdout.buffer.write(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
    sys.stdout.buffer.flush()
    os._exit(0)     # skip xatlas's destructors (see the module docstring)


if __name__ == "__main__":
    main()
