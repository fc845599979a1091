"""Instances against single-user copies (issue 57, part 2): the same lighting, fewer meshes.

    python bench/instances.py [--resolution 512] [--samples 64] [--copies 20] [--out DIR]

Three meshes (a cube, a cylinder, an ico sphere) × `copies` linked duplicates in rows on a floor,
half of each row under a roof, each copy turned and scaled a little, a sun and a sky colour. Run A
unwraps them as instances (one UV layer per mesh, a rectangle per object, `core.unwrap.instances`) and
bakes; run C places the same copies as collection instances (each mesh alone in a collection, an
Empty per copy: `bridge.collection_instances`); run B is the same scene with every object made
single user and unwrapped fresh (ordinary objects in the shared atlas), baked with the same
settings and seed. Per object: the
area-weighted mean I_z luminance over its surface in each run (`object_stats`), their relative
difference, and that difference over its standard error (the two runs' combined). Also the mesh
datablocks, the saved .blend's size, unwrap and bake times. Writes bench/results/instances.md.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
LUM = np.array([0.2126, 0.7152, 0.0722])


def build(bpy, kit, copies: int, collections: bool = False):
    """The scene (module docstring); returns (the receivers, the objects to select). With
    `collections`, each mesh sits alone in a collection (excluded from the view layer) and each copy
    is an Empty showing it, with the copy's transform: the same surfaces as collection instances."""
    kit.clear_scene()
    grey = kit.material("grey", (0.6, 0.6, 0.6))
    span = 1.2 * copies
    kit.plane("Floor", (0, 0, 0), span + 4.0, grey)
    kit.plane("Roof", (-span / 4 - 0.6, 0, 2.0), span / 2 + 1.0, grey)
    bpy.ops.mesh.primitive_cube_add(size=0.6)
    cube = bpy.context.active_object
    bpy.ops.mesh.primitive_cylinder_add(vertices=16, radius=0.3, depth=0.6)
    cylinder = bpy.context.active_object
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.35)
    ico = bpy.context.active_object
    scene = bpy.context.scene
    receivers = []
    for row, (src, colour) in enumerate(((cube, (0.8, 0.3, 0.2)), (cylinder, (0.3, 0.8, 0.3)), (ico, (0.7, 0.7, 0.8)))):
        src.data.materials.append(kit.material(f"m{row}", colour))
        if collections:
            shown = bpy.data.collections.new(f"{src.data.name}Set")
            scene.collection.children.link(shown)
            for c in list(src.users_collection):
                c.objects.unlink(src)
            shown.objects.link(src)
            scene.view_layers[0].layer_collection.children[shown.name].exclude = True
        for k in range(copies):
            if collections:
                obj = bpy.data.objects.new(f"{src.data.name}_{k:02d}", None)
                obj.instance_type, obj.instance_collection = 'COLLECTION', shown
                scene.collection.objects.link(obj)
            else:
                obj = src if k == 0 else bpy.data.objects.new(f"{src.data.name}.{k}", src.data)
                if k:
                    scene.collection.objects.link(obj)
                obj.name = f"{src.data.name}_{k:02d}"
            obj.location = (-span / 2 + 1.2 * k + 0.6, -2.0 + 2.0 * row, 0.4)
            obj.rotation_euler = (0.0, 0.0, 0.3 * k)
            obj.scale = (1.0 + 0.02 * (k % 5),) * 3
            receivers.append(obj)
    kit.sun(55.0, 30.0, 3.0, 2.0)
    kit.world((0.1, 0.12, 0.15))
    if collections:
        from hhd_lightmapper.bridge import collection_instances

        return collection_instances.receivers(receivers), receivers
    return receivers, receivers


#: Barycentric sample points inside each triangle (the centroids of its 16 sub-triangles at 4
#: subdivisions), so the lookups stay off chart edges.
def _barycentric(n: int = 4) -> np.ndarray:
    pts = []
    for i in range(n):
        for j in range(n - i):
            pts.append(((i + 1 / 3) / n, (j + 1 / 3) / n))
            if i + j < n - 1:
                pts.append(((i + 2 / 3) / n, (j + 2 / 3) / n))
    b = np.array(pts)
    return np.column_stack([1.0 - b.sum(1), b])


def object_stats(objects, folder: Path, uv_layer: str, lightmap_files, exr) -> dict[str, tuple[float, float]]:
    """Per object: (area-weighted mean I_z luminance over its surface, sampled bilinearly at 16
    points per triangle through its atlas UVs (an instance's rectangle applied), relative standard
    error of that mean: the texels' median Noise.V / SH0 luminance at those points over
    sqrt(the object's texels)). Texel layouts differ between the runs, so texel masks would not
    compare (a single-user object's texel box holds other objects' charts)."""
    from hhd_lightmapper.core.textures import sample_bilinear

    atlas = objects[0].hhd.atlas
    files = lightmap_files.AtlasFiles(folder, atlas)
    doc = lightmap_files.read_sidecar(files.sidecar)
    texels = {o["name"]: o["texels"] for o in doc["objects"]}
    hhd, _ = exr.read(files.hhd)
    iz = np.stack([exr.from_exr_rows(hhd[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64) @ LUM
    sh, _ = exr.read(files.sh)
    sh0 = np.stack([exr.from_exr_rows(sh[f"SH0.{c}"]) for c in "RGB"], -1).astype(np.float64) @ LUM
    tx, _ = exr.read(files.texels)
    noise = exr.from_exr_rows(tx["Noise.V"]).astype(np.float64)
    bary = _barycentric()
    out = {}
    for obj in objects:
        mesh = obj.data
        mesh.calc_loop_triangles()
        loops = np.array([t.loops[:] for t in mesh.loop_triangles])
        verts = np.array([t.vertices[:] for t in mesh.loop_triangles])
        uv = np.zeros(len(mesh.loops) * 2)
        mesh.uv_layers[uv_layer].data.foreach_get("uv", uv)
        rect = np.array(obj.hhd.lightmap_rect, np.float64)
        uv = (uv.reshape(-1, 2) * rect[:2] + rect[2:])[loops]  # (T, 3, 2) atlas UVs
        co = np.array([obj.matrix_world @ v.co for v in mesh.vertices])[verts]  # (T, 3, 3) metres
        area = 0.5 * np.linalg.norm(np.cross(co[:, 1] - co[:, 0], co[:, 2] - co[:, 0]), axis=1)
        points = np.einsum("pk,tkc->tpc", bary, uv).reshape(-1, 2)
        weight = np.repeat(area, len(bary))
        value = sample_bilinear(iz[..., None], points, clamp=True)[:, 0]
        sigma = sample_bilinear(noise[..., None], points, clamp=True)[:, 0]
        level = sample_bilinear(sh0[..., None], points, clamp=True)[:, 0]
        ok = (sigma >= 0) & (level > 0)
        rel = float(np.median(sigma[ok] / level[ok])) / math.sqrt(texels[obj.name]) if ok.any() else float("nan")
        out[obj.name] = (float((value * weight).sum() / weight.sum()), rel)
    return out


def run(bpy, kit, args, out: Path, single: bool, collections: bool = False) -> dict:
    """Build, (make single user), unwrap, bake, save; the run's figures (per object keyed by the
    copy's name: a collection instance's Empty is named as the linked duplicate it replaces)."""
    from hhd_lightmapper.core.files import exr, lightmap_files

    receivers, selected = build(bpy, kit, args.copies, collections)
    if single:
        for obj in receivers:
            if obj.data.users > 1:
                obj.data = obj.data.copy()
    scene = bpy.context.scene
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.resolution, s.samples, s.bounces, s.seed, s.denoise = args.resolution, args.samples, 2, 0, False
    name = "single" if single else "collections" if collections else "instances"
    s.output_dir = str(out / name)
    t0 = time.perf_counter()
    kit.unwrap(selected)
    unwrap_s = time.perf_counter() - t0
    atlases = {o.hhd.atlas for o in receivers}
    assert len(atlases) == 1, atlases
    kit.select(selected)
    t0 = time.perf_counter()
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    bake_s = time.perf_counter() - t0
    blend = out / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), compress=False)
    stats = object_stats(receivers, Path(s.output_dir), s.uv_layer, lightmap_files, exr)
    return {
        "meshes": len(bpy.data.meshes),
        "blend_bytes": blend.stat().st_size,
        "unwrap_s": unwrap_s,
        "bake_s": bake_s,
        "atlas": atlases.pop(),
        "objects": {key.split("/")[0]: value for key, value in stats.items()},
        "summary": s.unwrap_summary,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=512, help="lightmap atlas size")
    ap.add_argument("--samples", type=int, default=64, help="samples per texel (≥ 4 passes for Noise.V)")
    ap.add_argument("--copies", type=int, default=20, help="linked duplicates per mesh")
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-instances-")))
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy

    import hhd_lightmapper
    from scenekit import blender as kit

    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    hhd_lightmapper.register()
    warm = argparse.Namespace(copies=1, resolution=256, samples=4)  # compile the kernels first: not timed
    run(bpy, kit, warm, out / "warm-up", single=False)
    a = run(bpy, kit, args, out, single=False)
    c = run(bpy, kit, args, out, single=False, collections=True)
    b = run(bpy, kit, args, out, single=True)
    rows, summaries = [], []
    for label, x in (("A", a), ("C", c)):
        rel, z = [], []
        for name in sorted(b["objects"]):
            (mx, sx), (mb, sb) = x["objects"][name], b["objects"][name]
            se = math.hypot(sx, sb)
            rel.append((mx - mb) / mb)
            z.append(rel[-1] / se if se > 0 else float("nan"))
        rel_x, z_x = np.abs(rel), np.abs(z)
        summaries.append(
            f"{label} against B, per object area-weighted mean I_z luminance over its surface: |{label} − B| / B median "
            f"{100 * np.median(rel_x):.2f}%, max {100 * rel_x.max():.2f}%; over the standard error (σ) "
            f"median {np.nanmedian(z_x):.2f}, max {np.nanmax(z_x):.2f}; "
            f"{int((rel_x <= 0.005).sum())} of {len(rel_x)} within 0.5%, {int((z_x <= 3).sum())} within 3σ."
        )
    for name in sorted(b["objects"]):
        (ma, sa), (mc, _), (mb, sb) = a["objects"][name], c["objects"][name], b["objects"][name]
        rows.append(
            f"| {name} | {ma:.4g} | {mc:.4g} | {mb:.4g} | {100 * (ma - mb) / mb:+.2f}% | {100 * (mc - mb) / mb:+.2f}% "
            f"| {100 * math.hypot(sa, sb):.2f}% |"
        )
    lines = [
        "# Instances against single-user copies (bench/instances.py)",
        "",
        f"3 meshes × {args.copies} copies (half under a roof), atlas {args.resolution}², "
        f"{args.samples} samples, 2 bounces, seed 0, no denoise (times after a warm-up bake). A: linked duplicates as "
        "instances (one UV layer per mesh, a rectangle per object); C: the same copies as collection instances "
        "(each mesh alone in a collection, an Empty per copy with its transform); B: the linked duplicates made "
        "single user and unwrapped fresh.",
        "",
        "| | linked duplicates (A) | collection instances (C) | single user (B) |",
        "| --- | --- | --- | --- |",
        f"| mesh datablocks | {a['meshes']} | {c['meshes']} | {b['meshes']} |",
        f"| .blend size (uncompressed) | {a['blend_bytes'] / 1024:.0f} KiB | {c['blend_bytes'] / 1024:.0f} KiB "
        f"| {b['blend_bytes'] / 1024:.0f} KiB |",
        f"| unwrap | {a['unwrap_s']:.2f} s | {c['unwrap_s']:.2f} s | {b['unwrap_s']:.2f} s |",
        f"| bake | {a['bake_s']:.2f} s | {c['bake_s']:.2f} s | {b['bake_s']:.2f} s |",
        f"| atlas | {a['atlas']} | {c['atlas']} | {b['atlas']} |",
        "",
        f"Load average (1 min) at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores: the times compare "
        "only on an otherwise idle machine.",
        "",
        f"Unwrap A: {a['summary']}",
        "",
        f"Unwrap C: {c['summary']}",
        "",
        f"Unwrap B: {b['summary']}",
        "",
        *[line for summary in summaries for line in (summary, "")],
        "| object | mean I_z A | mean I_z C | mean I_z B | (A − B) / B | (C − B) / B | σ of a difference (relative) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
        "",
    ]
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "instances.md").write_text("\n".join(lines))
    print("\n".join(lines[:20]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
