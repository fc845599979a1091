"""What reading a scene costs before a bake starts (issue 58: the fixed work around the trace).

    PYTHONPATH=PKG .venv/bin/python bench/mesh_reads.py [--scenes classroom staircase2 bedroom]
        [--label after] [--session-only] [--repeats 5]

Per scene (every mesh object selected, unwrapped at 512², as `bench/time_to_error.py` opens it):

* each mesh array two ways, summed over the scene's evaluated meshes (`to_mesh`, as the bake
  reads them), median of `--repeats`: Blender's RNA properties read with foreach_get (the
  corners' `vertex_index`, the loop triangles' `vertices`, the polygons' `material_index`: item
  by item inside Blender) against what `bridge.mesh_data` reads now (the `.corner_vert` and
  `material_index` attributes in one copy; a triangle's vertices through its corners);
* the whole read a bake does before its first stage (`BakeSession(context)`: the scene's
  triangles, materials and lights, the receivers' surfaces, the fingerprints), median of
  `--repeats`, stored under `--label` (run it on another checkout with `--session-only` for its
  figure: the peer measured on the same machine).

Writes bench/results/mesh_reads.json (entries merged by scene and label) and mesh_reads.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
OUT = RESULTS / "mesh_reads.json"


def rna_reads(mesh, n_tri: int) -> dict[str, float]:
    """Seconds of each RNA read (the way the arrays were read before)."""
    seconds = {}
    t = time.perf_counter()
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    seconds["corner vertices"] = time.perf_counter() - t
    t = time.perf_counter()
    verts = np.empty(n_tri * 3, np.int64)
    mesh.loop_triangles.foreach_get("vertices", verts)
    seconds["triangle vertices"] = time.perf_counter() - t
    t = time.perf_counter()
    mats = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("material_index", mats)
    seconds["material indices"] = time.perf_counter() - t
    return seconds


def attribute_reads(mesh, loops: np.ndarray) -> dict[str, float]:
    """Seconds of each read as `bridge.mesh_data` does it now."""
    from hhd_lightmapper.bridge import mesh_data

    seconds = {}
    t = time.perf_counter()
    corners = mesh_data.corner_vertices(mesh)
    seconds["corner vertices"] = time.perf_counter() - t
    t = time.perf_counter()
    _ = mesh_data.corner_vertices(mesh)[loops]
    seconds["triangle vertices"] = time.perf_counter() - t
    t = time.perf_counter()
    mesh_data.polygon_materials(mesh)
    seconds["material indices"] = time.perf_counter() - t
    assert len(corners) == len(mesh.loops)
    return seconds


def array_reads(repeats: int) -> dict:
    """Both ways of reading, summed over the scene's meshes, median of `repeats`."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data

    depsgraph = bpy.context.evaluated_depsgraph_get()
    runs: dict[str, list[dict[str, float]]] = {"rna": [], "attributes": []}
    for _ in range(repeats):
        totals: dict[str, dict[str, float]] = {"rna": {}, "attributes": {}}
        for instance in depsgraph.object_instances:
            obj = instance.object
            if obj.type != 'MESH':
                continue
            mesh = obj.to_mesh()
            try:
                mesh.calc_loop_triangles()
                n_tri = len(mesh.loop_triangles)
                loops = mesh_data.triangle_corners(mesh, n_tri)
                for way, seconds in (("rna", rna_reads(mesh, n_tri)), ("attributes", attribute_reads(mesh, loops))):
                    for key, value in seconds.items():
                        totals[way][key] = totals[way].get(key, 0.0) + value
            finally:
                obj.to_mesh_clear()
        for way in runs:
            runs[way].append(totals[way])
    return {
        way: {key: statistics.median(r[key] for r in rows) for key in rows[0]} for way, rows in runs.items() if rows
    }


def session_read(repeats: int) -> dict:
    """Seconds of `BakeSession(context)` (median and all), and what it read."""
    import bpy

    from hhd_lightmapper.bridge.bake_session import BakeSession

    bpy.context.scene.hhd.output_dir = tempfile.mkdtemp(prefix="hhd-mesh-reads-")
    timings = []
    for _ in range(repeats):
        t = time.perf_counter()
        session = BakeSession(bpy.context)
        timings.append(time.perf_counter() - t)
    return {
        "seconds": statistics.median(timings),
        "timings": timings,
        "triangles": int(len(session.scene.triangles)),
        "receivers": len(session.receivers),
    }


def prepare(name: str) -> None:
    """The scene opened, every mesh selected and unwrapped at 512² (padding 2)."""
    import time_to_error  # bench/, the script's folder

    time_to_error.unwrap(time_to_error.load_scene(name), 512)


def report(results: dict) -> str:
    lines = [
        "# Reading the scene before a bake (issue 58: fixed work around the trace)",
        "",
        "`bench/mesh_reads.py`: every mesh object of the scene selected and unwrapped at 512²; seconds "
        "summed over the scene's evaluated meshes, medians (machine and load in the JSON).",
        "",
        "## Mesh arrays: RNA properties (item by item) against the attribute arrays `bridge.mesh_data` reads",
        "",
        "| scene | array | RNA s | attribute s | ratio |",
        "|---|---|---|---|---|",
    ]
    for scene, entry in sorted(results.items()):
        reads = entry.get("arrays")
        if not reads:
            continue
        for key, rna in reads["rna"].items():
            new = reads["attributes"][key]
            lines.append(f"| {scene} | {key} | {rna:.4f} | {new:.4f} | {rna / max(new, 1e-9):.0f}× |")
    lines += [
        "",
        "## The whole read before the first stage (`BakeSession(context)`)",
        "",
        "| scene | label | triangles | receivers | median s | runs s |",
        "|---|---|---|---|---|---|",
    ]
    for scene, entry in sorted(results.items()):
        for label, s in sorted(entry.get("session", {}).items()):
            runs = ", ".join(f"{t:.3f}" for t in s["timings"])
            lines.append(f"| {scene} | {label} | {s['triangles']:,} | {s['receivers']} | {s['seconds']:.3f} | {runs} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["classroom", "staircase2", "bedroom"])
    ap.add_argument("--label", default="after")
    ap.add_argument("--session-only", action="store_true", help="only the BakeSession read (another checkout)")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper

    hhd_lightmapper.register()
    results = json.loads(OUT.read_text()) if OUT.exists() else {}
    for name in args.scenes:
        prepare(name)
        entry = results.setdefault(name, {})
        if not args.session_only:
            entry["arrays"] = array_reads(args.repeats)
        entry.setdefault("session", {})[args.label] = {
            **session_read(args.repeats),
            "code": hhd_lightmapper.__file__,
            "load_average": os.getloadavg(),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        }
        print(name, json.dumps(entry["session"][args.label]["seconds"]), flush=True)
    RESULTS.mkdir(exist_ok=True)
    OUT.write_text(json.dumps(results, indent=2, sort_keys=True))
    (RESULTS / "mesh_reads.md").write_text(report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
