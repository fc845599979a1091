"""The README's demo: build the demo scene with bpy and run the pipeline stages that exist.

    python tools/demo.py --out out/demo        (or: make demo)

Stages, in pipeline order. Each later issue replaces a "pending" stage with the real one:
  scene    build the room (window, sun, sky, red wall, normal-mapped panel), save demo.blend
  render   Cycles reference render of the camera view (reference_cycles.png)
  unwrap   bpy.ops.hhd.unwrap(): xatlas lightmap UVs for every mesh in one atlas
  points   lightmap texels -> bake points (position, n_v, albedo, coverage, buried flag),
           atlas.png shows n_v per texel
  bake     Embree path-traced L2 SH of every texel (sun + sky, 2 bounces), irradz.png
  encode   HHD IrradZ encoding of the baked SH (core.hhd), error vs the SH irradiance;
           encoder.png compares HHD and the baseline over one texel's hemisphere
  output   pending: EXR + JSON sidecar (issue 6);  preview: pending: EEVEE node groups (issue 7)
Exits 0 and prints a summary; writes summary.json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "demo")
    ap.add_argument("--render-samples", type=int, default=32)
    ap.add_argument("--samples", type=int, default=32, help="bake samples per texel")
    args = ap.parse_args()
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    # Never touch the user's real Blender configuration.
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-demo-blender-"))
    sys.path.insert(0, str(ROOT / "tools"))

    import bpy
    import demo_scene

    timings, stages = {}, {}
    t = time.perf_counter()
    demo_scene.build()
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "demo.blend"))
    timings["scene"] = time.perf_counter() - t
    stages["scene"] = f"{len(bpy.data.objects)} objects -> demo.blend"

    t = time.perf_counter()
    render_reference(bpy, out / "reference_cycles.png", args.render_samples)
    timings["render"] = time.perf_counter() - t
    stages["render"] = "Cycles reference -> reference_cycles.png"

    import hhd_lightmapper
    hhd_lightmapper.register()            # the add-on's operators, as Blender would register them
    t = time.perf_counter()
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    for o in bpy.context.scene.objects:
        o.select_set(o.type == "MESH")
    bpy.context.view_layer.objects.active = meshes[0]
    bpy.context.scene.hhd.resolution = 512
    bpy.ops.hhd.unwrap()
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "demo.blend"))
    timings["unwrap"] = time.perf_counter() - t
    stages["unwrap"] = bpy.context.scene.hhd.unwrap_summary.split("; texels")[0]

    t = time.perf_counter()
    points = demo_bake_points(bpy, meshes, out / "atlas.png")
    timings["points"] = time.perf_counter() - t
    stages["points"] = (f"{len(points.texel)} texels, {int(points.buried.sum())} buried, "
                        f"ray offset {points.offset * 1000:.3f} mm -> atlas.png")
    t = time.perf_counter()
    baked = demo_bake(bpy, points, out / "irradz.png", args.samples)
    timings["bake"] = time.perf_counter() - t
    stages["bake"] = (f"{args.samples} samples/texel, {baked.rays / 1e6:.1f} M rays, "
                      f"{baked.rays / baked.seconds / 1e6:.2f} M rays/s -> irradz.png")

    t = time.perf_counter()
    encoded = encode_baked(baked.sh, points, out / "encoder.png")
    timings["encode"] = time.perf_counter() - t
    stages["encode"] = (f"{encoded['texels']} texels, hemispherical RMSE {encoded['rmse_percent']:.2f}% of I_z "
                        f"(optimal-linear + sphere Gram baseline: {encoded['baseline_rmse_percent']:.2f}%) -> encoder.png")
    stages["output"] = "pending (issue 6: EXR + JSON sidecar)"
    stages["preview"] = "pending (issue 7: EEVEE node groups)"

    summary = {"stages": stages, "seconds": timings, "out": str(out)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print("\nHHD Lightmapper demo")
    for name, text in stages.items():
        secs = f"{timings[name]:6.1f} s" if name in timings else "       "
        print(f"  {name:8s} {secs}  {text}")
    print(f"  output folder: {out}")
    return 0


def demo_bake_points(bpy, meshes, png: Path):
    """Bake points of the demo atlas, with the buried test against all scene geometry."""
    import numpy as np
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from hhd_lightmapper.core import bakepoints, rays
    from hhd_lightmapper.operators import mesh_data

    settings = bpy.context.scene.hhd
    surface = mesh_data.read_surface(meshes, settings.uv_layer, bpy.context.evaluated_depsgraph_get())
    points = bakepoints.build(surface, settings.resolution, settings.resolution,
                              occluders=rays.RayScene(surface.positions))
    image = points.image(points.normal * 0.5 + 0.5, fill=0.0)
    image[points.image(points.buried.astype(float)) > 0] = (1.0, 0.0, 1.0)
    plt.imsave(png, np.clip(image[::-1], 0, 1))
    return points


def render_reference(bpy, path: Path, samples: int) -> None:
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.render.resolution_x, scene.render.resolution_y = 320, 200
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def demo_bake(bpy, points, png: Path, samples: int):
    """Bake the demo atlas with the extension's tracer; plot I_z (tone-mapped) per texel."""
    import numpy as np
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from hhd_lightmapper.core import hhd, tracer
    from hhd_lightmapper.operators import scene_data

    scene = scene_data.read_bake_scene(bpy.context.evaluated_depsgraph_get())
    last = [0.0]

    def progress(fraction, message):
        if fraction - last[0] >= 0.25 or fraction >= 1.0:
            print(f"  bake {100 * fraction:5.1f}%  {message}", flush=True)
            last[0] = fraction
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=samples, bounces=2), progress=progress)
    iz = hhd.irradz(result.sh, points.normal)
    image = points.image(iz / (1.0 + iz))
    plt.imsave(png, np.clip(image[::-1], 0, 1))
    return result


def encode_baked(sh, points, png: Path) -> dict:
    """Encode the baked SH; measure the hemispherical error on a sample of texels."""
    import numpy as np
    from hhd_lightmapper.core import hhd

    p = hhd.encode(sh, points.normal)
    rng = np.random.default_rng(0)
    lit = np.nonzero(p.irradz @ hhd.LUMINANCE > 1e-3)[0]
    pick = rng.choice(lit, size=min(4000, len(lit)), replace=False)
    base = hhd.encode(sh[pick], points.normal[pick], direction="optimal_linear", gram="sphere")
    lum = hhd.LUMINANCE
    mean_iz = (p.irradz[pick] @ lum).mean()
    sub = hhd.HHDParams(p.irradz[pick], p.ambient_weight[pick], p.direction[pick])
    rmse = (hhd.hemispherical_rmse(sh[pick], points.normal[pick], sub) @ lum).mean() / mean_iz
    rmse_base = (hhd.hemispherical_rmse(sh[pick], points.normal[pick], base) @ lum).mean() / mean_iz
    brightest = pick[np.argmax(p.irradz[pick] @ lum)]
    plot_hemisphere(sh[brightest:brightest + 1], points.normal[brightest:brightest + 1], png)
    return {"texels": len(points.texel), "rmse_percent": 100 * rmse, "baseline_rmse_percent": 100 * rmse_base}


def plot_hemisphere(s, n_v, png: Path, size: int = 96) -> None:
    """Images over the upper hemisphere (orthographic view from above) of one texel with
    radiance SH s (1, 9, 3) and vertex normal n_v (1, 3)."""
    import numpy as np
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from hhd_lightmapper.core import hhd, sh

    frames = sh.tangent_frames(n_v)[0]
    u = np.linspace(-1, 1, size)
    x, y = np.meshgrid(u, -u)
    inside = x * x + y * y < 1.0
    local = np.stack([x[inside], y[inside], np.sqrt(1 - x[inside] ** 2 - y[inside] ** 2)], 1)
    world = local @ frames.T
    k = len(world)
    target = sh.irradiance(np.repeat(s, k, 0), world) @ hhd.LUMINANCE
    images = {}
    for name, kw in (("HHD searched + hemi G", {}), ("optimal linear + sphere G", dict(direction="optimal_linear", gram="sphere"))):
        p = hhd.encode(s, n_v, **kw)
        rep = hhd.HHDParams(np.repeat(p.irradz, k, 0), np.repeat(p.ambient_weight, k, 0), np.repeat(p.direction, k, 0))
        images[name] = hhd.reconstruct(rep, np.repeat(n_v, k, 0), world) @ hhd.LUMINANCE
    fig, axes = plt.subplots(1, 5, figsize=(15, 3.2))
    panels = [("SH irradiance (reference)", target)] + [(n, v) for n, v in images.items()] + \
             [(f"|error| {n.split()[0]}", np.abs(v - target)) for n, v in images.items()]
    vmax = max(target.max(), *(v.max() for v in images.values()))
    for ax, (title, values) in zip(axes, panels):
        img = np.full(x.shape, np.nan)
        img[inside] = values
        ax.imshow(img, vmin=0, vmax=vmax if "error" not in title else vmax * 0.25, cmap="magma")
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.suptitle("Baked lighting over the hemisphere of the demo's brightest texel (luminance, view from above the normal)", fontsize=9)
    fig.tight_layout()
    fig.savefig(png, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
