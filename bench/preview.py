"""EEVEE preview against Cycles: image RMSE of each lightmap reconstruction, and a side-by-side PNG.

    python bench/preview.py [--samples 256] [--cycles-samples 256] [--resolution 512]

The demo room (scenekit/scenes.py `demo_room`: sun through a window, sky, red wall, normal-mapped panel) is
unwrapped and baked with the extension; Cycles renders the camera view as ground truth, diffuse
only: (Diffuse Direct + Diffuse Indirect) × Diffuse Color, same lights, normal maps on, the same
bounce count (render passes are not written by the bpy module, so "diffuse only" is set in the
materials: specular, coat, sheen off). EEVEE then renders the same view with the preview shown in each mode (HHD, AHD after
an AHD re-encode, L1 SH, L2 SH, scalar I_z). Reported per mode: RMSE over the receivers' pixels,
relative to the reference's mean, also split into the normal-mapped panel and the rest.
Writes bench/results/preview.json and preview_side_by_side.png (reference | HHD | |error| × 4).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
MODES = ("HHD", "AHD", "L1", "L2", "SCALAR")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=256, help="bake samples per texel")
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--cycles-samples", type=int, default=256)
    ap.add_argument("--resolution", type=int, default=512, help="lightmap atlas size")
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-preview-")))
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy

    import hhd_lightmapper
    from scenekit import blender, scenes

    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    scenes.demo_room()
    blender.externalise_images(out)
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "scene.blend"))
    hhd_lightmapper.register()
    scene = bpy.context.scene
    meshes = [o for o in scene.objects if o.type == 'MESH']
    for o in scene.objects:
        o.select_set(o.type == 'MESH')
    bpy.context.view_layer.objects.active = meshes[0]
    s = scene.hhd
    s.resolution, s.samples, s.bounces, s.output_dir = args.resolution, args.samples, args.bounces, "//lightmaps"
    timings = {}
    t = time.perf_counter()
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    timings["unwrap_and_bake"] = time.perf_counter() - t

    t = time.perf_counter()
    reference, mask, panel = cycles_reference(bpy, scene, out, args.cycles_samples, args.bounces)
    timings["cycles"] = time.perf_counter() - t
    rows, images = {}, {}
    for mode in MODES:
        s.model = 'AHD' if mode == 'AHD' else 'HHD'
        if mode in ("AHD", "L1"):  # re-encode when the model changes
            assert bpy.ops.hhd.encode() == {'FINISHED'}
        s.preview_mode = mode
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        t = time.perf_counter()
        images[mode] = eevee_render(bpy, scene, out / f"eevee_{mode.lower()}.exr")
        timings[f"eevee_{mode.lower()}"] = time.perf_counter() - t
        bpy.ops.hhd.preview_hide()
        rows[mode] = {
            name: rmse(images[mode], reference, m)
            for name, m in (("all", mask), ("normal_mapped_panel", mask & panel), ("rest", mask & ~panel))
        }
    print(
        f"\nEEVEE preview vs Cycles diffuse ({args.samples} bake spp, {args.bounces} bounces, "
        f"{args.resolution}² atlas, Cycles {args.cycles_samples} spp); RMSE % of the reference mean"
    )
    print(f"{'mode':8s} {'all':>8s} {'panel':>8s} {'rest':>8s}")
    for mode, r in rows.items():
        print(f"{mode:8s} {r['all']:8.2f} {r['normal_mapped_panel']:8.2f} {r['rest']:8.2f}")
    png = RESULTS / "preview_side_by_side.png"
    side_by_side(reference, images["HHD"], mask, png)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "preview.json").write_text(
        json.dumps({"settings": vars(args) | {"out": str(out)}, "rmse_percent": rows, "seconds": timings}, indent=2)
    )
    print(f"side by side: {png}\ntimings: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()))
    return 0


def cycles_reference(bpy, scene, out: Path, samples: int, bounces: int):
    """(diffuse reference (H, W, 3), receiver mask, normal-mapped-panel mask). Render passes are
    not written to files by the bpy module here, so "diffuse only" is made in the materials:
    Principled BSDFs with specular, coat and sheen off (Lambert diffuse, roughness 1); a
    transparent film gives the receiver mask, a 1-sample render of the panel alone its mask."""
    diffuse_cycles(bpy, scene, samples, bounces)
    scene.render.film_transparent = True
    configure_output(scene)
    reference = render(bpy, scene, out / "cycles.exr", alpha=True)
    mask = reference[..., 3] > 0.999
    hidden = [o for o in scene.objects if o.type == 'MESH' and "Normal-mapped" not in o.name]
    for o in hidden:
        o.hide_render = True
    scene.cycles.samples = 1
    panel = render(bpy, scene, out / "panel_mask.exr", alpha=True)[..., 3] > 0.5
    for o in hidden:
        o.hide_render = False
    scene.render.film_transparent = False
    return reference[..., :3], mask, panel


def diffuse_cycles(bpy, scene, samples: int, bounces: int) -> None:
    """Cycles on the CPU rendering diffuse light only: Principled BSDFs made Lambertian
    (specular, coat, sheen, metallic off, roughness 1), diffuse bounces only, no denoising and
    no sample clamping (Cycles clamps indirect samples to 10 by default: a bias)."""
    for mat in bpy.data.materials:
        for node in mat.node_tree.nodes if mat.node_tree else []:
            if node.type == 'BSDF_PRINCIPLED':
                for name, value in (
                    ("Specular IOR Level", 0.0),
                    ("Coat Weight", 0.0),
                    ("Sheen Weight", 0.0),
                    ("Roughness", 1.0),
                    ("Metallic", 0.0),
                ):
                    node.inputs[name].default_value = value
    scene.render.engine = 'CYCLES'
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = 'CPU', samples, False
    scene.cycles.max_bounces = scene.cycles.diffuse_bounces = bounces
    scene.cycles.glossy_bounces = scene.cycles.transmission_bounces = 0
    scene.cycles.sample_clamp_direct = scene.cycles.sample_clamp_indirect = 0.0


def render(bpy, scene, path: Path, alpha=False) -> np.ndarray:
    from hhd_lightmapper.core.files import exr

    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    channels, _ = exr.read(path)
    return np.stack([exr.from_exr_rows(channels[c]) for c in ("RGBA" if alpha else "RGB")], -1).astype(np.float64)


def configure_output(scene):
    settings = scene.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = 'OPEN_EXR', 'RGBA', '32'
    scene.view_settings.view_transform = 'Standard'
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 200, 100


def eevee_render(bpy, scene, path: Path) -> np.ndarray:
    from hhd_lightmapper import blender_compat

    scene.render.engine = blender_compat.eevee_engine()
    scene.eevee.taa_render_samples = 16
    configure_output(scene)
    return render(bpy, scene, path)


def rmse(image, reference, mask) -> float:
    if not mask.any():
        return float("nan")
    return float(100 * np.sqrt(np.mean((image[mask] - reference[mask]) ** 2)) / reference[mask].mean())


def side_by_side(reference, hhd_image, mask, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tone = lambda x: np.clip(x / (1.0 + x), 0, 1) ** (1 / 2.2)
    error = np.where(mask[..., None], np.abs(hhd_image - reference), 0.0)
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6))
    for ax, (title, img) in zip(
        axes,
        (
            ("Cycles diffuse (reference)", tone(reference)),
            ("EEVEE preview, HHD lightmap", tone(hhd_image)),
            ("|error| × 4", tone(4 * error)),
        ),
    ):
        ax.imshow(img[::-1])
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    png.parent.mkdir(exist_ok=True)
    fig.savefig(png, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
