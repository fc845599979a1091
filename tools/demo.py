"""The README's demo: build the demo scene with bpy and run the pipeline stages that exist.

    python tools/demo.py --out out/demo        (or: make demo)

Stages, in pipeline order:
  scene    build the room (window, sun, sky, red wall, normal-mapped panel), save demo.blend
  render   Cycles reference render of the camera view (reference_cycles.png)
  bake     headless, as a build machine runs it (a subprocess):
               python -m hhd_lightmapper.cli demo.blend bake --unwrap --denoise --out lightmaps --save
           = xatlas UVs (512² atlas), bake points, Embree path-traced L2 SH (sun + sky, 2 bounces),
           Open Image Denoise's lightmap filter (Blender's own library; the weights are fetched
           first, tools/fetch_oidn_weights.py), HHD encoding, lightmaps/Lightmap_hhd.exr + _sh.exr
           (as traced) + _texels.exr + .json; the images are loaded into demo.blend, which is saved
  encode   reads the files back: irradz.png (I_z), encoder.png (HHD vs baseline over one texel's
           hemisphere) and the encoder's hemispherical error on 4000 texels
  export   python -m hhd_lightmapper.cli demo.blend export --glb demo.glb: glTF 2.0 through Blender's
           exporter with the HHD_lightmap extension (docs/gltf.md) -> demo.glb
  preview  reopens demo.blend, Show Preview (HHD node group on every material), EEVEE render
           preview_eevee.png, saves demo.blend with the preview shown (Hide Preview restores it)
Exits 0 and prints a summary; writes summary.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
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

    import bpy

    from scenekit import blender, scenes

    timings, stages = {}, {}
    t = time.perf_counter()
    scenes.demo_room()
    blender.externalise_images(out)
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "demo.blend"))
    timings["scene"] = time.perf_counter() - t
    stages["scene"] = f"{len(bpy.data.objects)} objects -> demo.blend"

    t = time.perf_counter()
    render_reference(bpy, out / "reference_cycles.png", args.render_samples)
    timings["render"] = time.perf_counter() - t
    stages["render"] = "Cycles reference -> reference_cycles.png"

    # Unwrap + bake headless, exactly as a build machine would:
    #   python -m hhd_lightmapper.cli demo.blend bake --unwrap --denoise --out lightmaps --save
    weights_note = fetch_weights()
    meshes = sorted(o.name for o in bpy.context.scene.objects if o.type == "MESH")
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "demo.blend"))
    command = [
        sys.executable,
        "-m",
        "hhd_lightmapper.cli",
        str(out / "demo.blend"),
        "bake",
        "--unwrap",
        "--resolution",
        "512",
        "--out",
        str(out / "lightmaps"),
        "--samples",
        str(args.samples),
        "--bounces",
        "2",
        "--denoise",
        "--objects",
        *meshes,
        "--save",
    ]
    print("$ " + " ".join(command[2:]), flush=True)
    t = time.perf_counter()
    code = subprocess.call(command)
    timings["bake"] = time.perf_counter() - t
    if code != 0:
        print(f"demo: the headless bake failed with exit code {code}")
        return code
    sidecar = json.loads((out / "lightmaps" / "Lightmap.json").read_text())
    bake = sidecar["bake"]
    stages["bake"] = (
        f"unwrap + {bake['samples_taken']} samples/texel, {bake['rays'] / 1e6:.1f} M rays, "
        f"{sidecar['stats']['texels_baked']} texels, {denoised_text(sidecar, weights_note)} "
        "-> lightmaps/Lightmap_hhd.exr, _sh.exr, .json"
    )

    # glTF 2.0 with the lightmaps (docs/gltf.md), through Blender's exporter and the HHD hook:
    #   python -m hhd_lightmapper.cli demo.blend export --glb demo.glb
    t = time.perf_counter()
    command = [
        sys.executable,
        "-m",
        "hhd_lightmapper.cli",
        str(out / "demo.blend"),
        "export",
        "--glb",
        str(out / "demo.glb"),
    ]
    print("$ " + " ".join(command[2:]), flush=True)
    code = subprocess.call(command)
    timings["export"] = time.perf_counter() - t
    if code != 0:
        print(f"demo: the glTF export failed with exit code {code}")
        return code
    stages["export"] = f"glTF with HHD_lightmap, {(out / 'demo.glb').stat().st_size / 1e6:.2f} MB -> demo.glb"

    t = time.perf_counter()
    encoded = plot_results(out / "lightmaps", out / "irradz.png", out / "encoder.png")
    timings["encode"] = time.perf_counter() - t
    stages["encode"] = (
        f"{encoded['texels']} texels, hemispherical RMSE {encoded['rmse_percent']:.2f}% of I_z "
        f"(optimal-linear + sphere Gram baseline: {encoded['baseline_rmse_percent']:.2f}%) "
        "-> irradz.png, encoder.png"
    )
    t = time.perf_counter()
    stages["preview"] = show_preview(bpy, out)
    timings["preview"] = time.perf_counter() - t

    summary = {"stages": stages, "seconds": timings, "out": str(out)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print("\nHHD Lightmapper demo")
    for name, text in stages.items():
        secs = f"{timings[name]:6.1f} s" if name in timings else "       "
        print(f"  {name:8s} {secs}  {text}")
    print(f"  output folder: {out}")
    return 0


def fetch_weights() -> str:
    """OIDN's lightmap weights into oidn_weights/ (hash-checked; a no-op when present). Returns ""
    or, if they cannot be had, why (the bake then runs undenoised and says so)."""
    import fetch_oidn_weights

    try:
        fetch_oidn_weights.fetch()
    except (SystemExit, subprocess.CalledProcessError, OSError) as e:
        print(f"demo: OIDN lightmap weights unavailable ({e}): the bake will not be denoised", flush=True)
        return f"weights unavailable: {e}"
    return ""


def denoised_text(sidecar: dict, weights_note: str) -> str:
    """'denoised (OIDN x.y.z, s)' or 'not denoised: why' from the sidecar's post section."""
    record = sidecar.get("post", {}).get("denoise", {})
    if record.get("applied"):
        return f"denoised (OIDN {record['oidn_version']}, {record['seconds']:.1f} s)"
    return f"not denoised: {record.get('warning') or weights_note or 'denoise off'}"


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


def show_preview(bpy, out: Path) -> str:
    """Open the baked demo.blend, Show Preview (HHD) on every mesh, render the camera view with
    EEVEE (preview_eevee.png) and save: opening demo.blend shows the baked lighting."""
    import hhd_lightmapper

    bpy.ops.wm.open_mainfile(filepath=str(out / "demo.blend"))
    hhd_lightmapper.register()
    scene = bpy.context.scene
    for o in scene.objects:
        o.select_set(o.type == "MESH")
    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    from hhd_lightmapper import blender_compat

    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 200, 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(out / "preview_eevee.png")
    bpy.ops.render.render(write_still=True)
    bpy.ops.wm.save_mainfile()
    materials = sum("hhd_preview" in m for m in bpy.data.materials)
    return f"Show Preview (HHD) on {materials} materials, EEVEE render -> preview_eevee.png; saved in demo.blend"


def plot_results(folder: Path, irradz_png: Path, encoder_png: Path) -> dict:
    """Read the bake's files back (as a game engine would): I_z image, and the encoder's error
    on a sample of texels (re-encoded from the SH EXR, with the baseline for comparison)."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhd_lightmapper.core import hhd
    from hhd_lightmapper.core.files import exr, lightmap_files

    channels, _ = exr.read(folder / "Lightmap_hhd.exr")
    iz = np.stack([channels[f"Iz.{c}"].astype(float) for c in "RGB"], axis=-1)
    plt.imsave(irradz_png, np.clip(iz / (1.0 + iz), 0, 1))  # EXR rows are top-down already
    data = lightmap_files.read_texel_data(lightmap_files.AtlasFiles(folder, "Lightmap"))
    sh, normal = data.sh[data.baked], data.normal[data.baked]
    p = hhd.encode(sh, normal)
    rng = np.random.default_rng(0)
    lit = np.nonzero(p.irradz @ hhd.LUMINANCE > 1e-3)[0]
    pick = rng.choice(lit, size=min(4000, len(lit)), replace=False)
    base = hhd.encode(sh[pick], normal[pick], direction="optimal_linear", gram="sphere")
    lum = hhd.LUMINANCE
    mean_iz = (p.irradz[pick] @ lum).mean()
    sub = hhd.HHDParams(p.irradz[pick], p.ambient_weight[pick], p.direction[pick])
    rmse = (hhd.hemispherical_rmse(sh[pick], normal[pick], sub) @ lum).mean() / mean_iz
    rmse_base = (hhd.hemispherical_rmse(sh[pick], normal[pick], base) @ lum).mean() / mean_iz
    brightest = pick[np.argmax(p.irradz[pick] @ lum)]
    plot_hemisphere(sh[brightest : brightest + 1], normal[brightest : brightest + 1], encoder_png)
    return {"texels": int(len(sh)), "rmse_percent": 100 * rmse, "baseline_rmse_percent": 100 * rmse_base}


def plot_hemisphere(s, n_v, png: Path, size: int = 96) -> None:
    """Images over the upper hemisphere (orthographic view from above) of one texel with
    radiance SH s (1, 9, 3) and vertex normal n_v (1, 3)."""
    import matplotlib
    import numpy as np

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
    for name, kw in (
        ("HHD searched + hemi G", {}),
        ("optimal linear + sphere G", dict(direction="optimal_linear", gram="sphere")),
    ):
        p = hhd.encode(s, n_v, **kw)
        rep = hhd.HHDParams(np.repeat(p.irradz, k, 0), np.repeat(p.ambient_weight, k, 0), np.repeat(p.direction, k, 0))
        images[name] = hhd.reconstruct(rep, np.repeat(n_v, k, 0), world) @ hhd.LUMINANCE
    fig, axes = plt.subplots(1, 5, figsize=(15, 3.2))
    panels = (
        [("SH irradiance (reference)", target)]
        + [(n, v) for n, v in images.items()]
        + [(f"|error| {n.split()[0]}", np.abs(v - target)) for n, v in images.items()]
    )
    vmax = max(target.max(), *(v.max() for v in images.values()))
    for ax, (title, values) in zip(axes, panels):
        img = np.full(x.shape, np.nan)
        img[inside] = values
        ax.imshow(img, vmin=0, vmax=vmax if "error" not in title else vmax * 0.25, cmap="magma")
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.suptitle(
        "Baked lighting over the hemisphere of the demo's brightest texel (luminance, view from above the normal)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(png, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
