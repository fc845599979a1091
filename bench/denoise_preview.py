"""The denoiser as the artist sees it: the EEVEE preview against Cycles, raw and denoised, on the
classroom, staircase2 and the bedroom.

    flock /tmp/bench.lock .venv/bin/python bench/denoise_preview.py     # the three scenes (≈ 65 min on 2 cores)
    .venv/bin/python bench/denoise_preview.py --scenes bedroom --samples 16 256 --cycles-samples 256
    ... --cycles-cache /tmp/hhd-cycles    # keep the Cycles renders (25 of ~65 min) for the next run

Issue 21 asks for the EEVEE-preview image error against Cycles, raw vs denoised, at 4 … 1024
samples on the trade-off scenes (bench/tradeoff.py measures those) and on the classroom,
staircase2 and the bedroom: this bench. The scenes, their receivers and their atlas are
bench/denoise.py's (512², padding 2, texel density 0, BOUNCES bounces in both engines). The view is
each scene's own camera, from the files the scenes were converted from (CAMERAS: the classroom's
Mitsuba `to_world`, staircase2's and the bedroom's pbrt `Transform`, turned Z-up as the meshes were;
pbrt's world is left-handed, so those two views are mirror images of their TungstenRender.png).

Cycles renders the view diffuse only (bench/preview.py's `diffuse_cycles`: the same bounces, sample
clamps off) in two halves with different seeds: their mean is the reference and half their RMS
difference its own noise (the floor, removed from each error in quadrature). Compared pixels: those
where the camera sees a receiver, from a render with every other object a holdout (emitters,
glass and the furniture that is not lightmapped are left out). Per sample count: one bake through
the Bake operator with Denoise on and its preview (Show Preview, HHD, normal maps on) rendered by
EEVEE; then Re-encode with Denoise off (the raw SH of the same bake, nothing traced again) rendered
again. Raw and denoised thus differ by the denoiser alone. Error: image RMSE relative per pixel to
max(reference, 0.1 × its mean) (bench/tradeoff.py's `image_rmse`), raw and floor-corrected; and the
same without the OUTLIERS share of the pixels where the most-sampled denoised preview differs most
from Cycles (`without_outliers`: geometry finer than a texel decides the whole RMSE otherwise).

Writes bench/results/denoise_preview.{json,md} and denoise_preview.png (per scene: Cycles | raw |
denoised at `--figure-samples`, and the PREVIEW preset's samples when measured).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
SCENES = ("classroom", "staircase2", "bedroom")
#: Each scene's camera as its source file gives it: (matrix kind, 16 numbers, field of view in
#: degrees, the image axis that angle spans, render size). Mitsuba's `to_world` is camera-to-world,
#: row by row; pbrt's `Transform` before WorldBegin is world-to-camera, column by column. Both
#: cameras look along their +z with +y up; both files are Y-up.
CAMERAS = {
    "classroom": (
        "camera_to_world_rows",
        [-0.988479, -0.00428443, 0.151294, -1.69049, 9.42177e-10, 0.999599, 0.0283071, 1.27158]
        + [-0.151355, 0.027981, -0.988083, 5.88653, 0, 0, 0, 1],
        60.0,
        "HORIZONTAL",
        (384, 216),
    ),
    "staircase2": (
        "world_to_camera_columns",
        [0.435523, -4.21474e-8, -0.900177, 0, 0, 1, -4.68212e-8, 0]
        + [-0.900177, -2.03917e-8, -0.435524, 0, -0.711083, -1.65163, 7.33425, 1],
        70.0,
        "VERTICAL",
        (288, 288),
    ),
    "bedroom": (
        "world_to_camera_columns",
        [0.653592, -0.0128556, -0.756738, 0, -9.31322e-10, 0.999856, -0.0169858, 0]
        + [-0.756847, -0.0111018, -0.653498, 0, 0.238273, -1.13121, 4.79143, 1],
        39.430485,
        "VERTICAL",
        (384, 216),
    ),
}
#: The source files' Y-up world to Blender's Z-up, as the meshes were turned: (x, y, z) → (x, −z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
EEVEE_SAMPLES = 16
#: Share of the compared pixels left out of the second set of errors (`without_outliers`).
OUTLIERS = 0.01


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--samples", type=int, nargs="+", default=[4, 16, 64, 256, 1024])
    ap.add_argument("--cycles-samples", type=int, default=1024, help="the reference's samples (two halves)")
    ap.add_argument("--figure-samples", type=int, default=64)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--out", type=Path, help="folder of the results (default bench/results)")
    ap.add_argument(
        "--cycles-cache",
        type=Path,
        help="folder keeping the Cycles renders per scene and samples (<scene>-<samples>spp/): read when "
        "there, rendered into it when not; the views and settings must not have changed since",
    )
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper

    hhd_lightmapper.register()
    results_dir = args.out or RESULTS
    results_dir.mkdir(parents=True, exist_ok=True)
    t_run = time.perf_counter()
    results = {
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items() if k != "out"},
        "scenes": {},
    }
    results["load_average_start"] = os.getloadavg()
    figures = {}
    for name in args.scenes:
        results["scenes"][name], figures[name] = measure_scene(name, args)
        print_scene(name, results["scenes"][name])
        (results_dir / "denoise_preview.json").write_text(json.dumps(results, indent=2))
    results["wall_seconds"] = time.perf_counter() - t_run
    results["load_average_end"] = os.getloadavg()
    (results_dir / "denoise_preview.json").write_text(json.dumps(results, indent=2))
    (results_dir / "denoise_preview.md").write_text(markdown(results))
    figure(figures, results_dir / "denoise_preview.png")
    print(f"wall time {results['wall_seconds'] / 60:.1f} min; results in {results_dir}", flush=True)
    return 0


def measure_scene(name: str, args) -> tuple[dict, dict]:
    """Unwrap, render the Cycles reference and the receiver mask, then per sample count bake
    (denoised), render the preview, re-encode raw and render it again. Returns the scene's entry
    and its figure's images."""
    import bpy

    import denoise
    from scenekit.blender import select

    t_scene = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix=f"hhd-bench-denoise-preview-{name}-"))
    receivers = denoise.load_scene(name)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / f"{name}.blend"))  # "//" paths land here
    scene = bpy.context.scene
    place_camera(scene, name)
    s = scene.hhd
    s.uv_layer, s.resolution, s.texel_density, s.padding = denoise.LAYER, args.resolution, 0.0, 2
    select(receivers)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    t = time.perf_counter()
    cache = args.cycles_cache / f"{name}-{args.cycles_samples}spp" if args.cycles_cache else folder
    cached = all(p.exists() for p in reference_paths(cache))
    reference, floor, mask, halves = cycles_reference(scene, receivers, args.cycles_samples, cache)
    entry = {
        "receivers": [o.name for o in receivers],
        "resolution": list(CAMERAS[name][4]),
        "compared_pixels": int(mask.sum()),
        "reference": {
            "samples": args.cycles_samples,
            "floor": floor,
            "seconds": time.perf_counter() - t,
            "cached": cached,
        },
        "rows": [],
    }
    print(
        f"[{name}] Cycles {args.cycles_samples} spp in {entry['reference']['seconds']:.0f} s, its noise "
        f"{floor:.2f}%; {entry['compared_pixels']} receiver pixels",
        flush=True,
    )
    images = {"Cycles": reference, "mask": mask}
    renders = {}
    for samples in args.samples:
        row = {"samples": samples}
        for label, denoised in (("denoised", True), ("raw", False)):
            t = time.perf_counter()
            bake_or_reencode(scene, folder / f"lightmaps_{samples}", samples, denoised)
            seconds = time.perf_counter() - t
            image = renders[samples, label] = eevee(scene, folder / f"eevee_{samples}_{label}.exr")
            row[label] = {"seconds": seconds, **errors(image, reference, mask, floor)}
            if samples == args.figure_samples:
                images[label] = image
        entry["rows"].append(row)
        print(
            f"[{name}] {samples:5d} spp  raw {row['raw']['corrected']:6.2f}%  denoised "
            f"{row['denoised']['corrected']:6.2f}%  (bake {row['denoised']['seconds']:.1f} s)",
            flush=True,
        )
    entry["without_outliers"] = without_outliers(entry["rows"], renders, halves, mask, max(args.samples))
    entry["seconds"] = time.perf_counter() - t_scene
    return entry, images


def without_outliers(rows: list, renders: dict, halves: tuple, mask, most: int) -> dict:
    """The errors again without the OUTLIERS share of the compared pixels where the most-sampled
    denoised preview differs most from Cycles (the same pixels for every row): where even the
    converged lightmap differs (texels a wall or a fixture crosses, contact lines finer than a
    texel), which no sample count or denoiser changes and which otherwise decide the RMSE."""
    from tradeoff import FLOOR

    reference = 0.5 * (halves[0] + halves[1])
    converged = renders[most, "denoised"]
    ref = reference[mask]
    e2 = np.square((converged[mask] - ref) / np.maximum(ref, FLOOR * ref.mean(axis=0))).mean(axis=1)
    cut = np.sort(e2)[::-1][max(1, int(OUTLIERS * len(e2))) - 1]
    inliers = mask.copy()
    inliers[mask] = e2 < cut
    floor = 0.5 * image_error(halves[0], halves[1], inliers)
    out = {
        "share": OUTLIERS,
        "squared_error_share": float(e2[e2 >= cut].sum() / max(e2.sum(), 1e-300)),
        "floor": floor,
        "rows": [],
    }
    for row in rows:
        s = row["samples"]
        out["rows"].append(
            {"samples": s, **{k: errors(renders[s, k], reference, inliers, floor) for k in ("raw", "denoised")}}
        )
    return out


def place_camera(scene, name: str) -> None:
    """The scene's camera (CAMERAS) as Blender's "Camera", Z-up, with its field of view and size."""
    import bpy

    from scenekit import blender

    kind, numbers, fov, axis, (width, height) = CAMERAS[name]
    m = np.array(numbers, dtype=np.float64).reshape(4, 4)
    to_world = m if kind == "camera_to_world_rows" else np.linalg.inv(m.T)
    position = Y_UP_TO_Z_UP @ to_world[:3, 3]
    forward = Y_UP_TO_Z_UP @ to_world[:3, 2]
    for obj in [o for o in scene.objects if o.type == 'CAMERA']:
        bpy.data.objects.remove(obj)
    cam = blender.camera(tuple(position), tuple(forward / np.linalg.norm(forward)))
    cam.data.sensor_fit, cam.data.angle = axis, math.radians(fov)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100


def cycles_reference(scene, receivers, samples: int, folder: Path):
    """(reference (H, W, 3), its noise floor in %, mask (H, W) of the pixels where the camera sees
    a receiver, the two halves (H, W, 3)). Diffuse only, BOUNCES bounces, two halves of samples / 2
    with different seeds. The scene is set up for them either way (its materials made Lambertian,
    which the EEVEE previews rely on too); the renders are read from `folder` when all three are
    there."""
    import bpy

    import denoise
    from preview import configure_output, diffuse_cycles

    diffuse_cycles(bpy, scene, samples // 2, denoise.BOUNCES)
    size = scene.render.resolution_x, scene.render.resolution_y
    configure_output(scene)
    scene.render.resolution_x, scene.render.resolution_y = size
    paths = reference_paths(folder)
    if all(p.exists() for p in paths):
        images = [read_rgba(p) for p in paths]
    else:
        folder.mkdir(parents=True, exist_ok=True)
        images = render_reference(scene, receivers, paths)
    halves, seen = images[:2], images[2][..., 3]
    mask = (seen > 0.999) & (halves[0][..., 3] > 0.999) & (halves[1][..., 3] > 0.999)
    image = 0.5 * (halves[0][..., :3] + halves[1][..., :3])
    floor = 0.5 * image_error(halves[0][..., :3], halves[1][..., :3], mask)  # σ of the mean of the halves
    return image, floor, mask, (halves[0][..., :3], halves[1][..., :3])


def reference_paths(folder: Path) -> list[Path]:
    """The two Cycles halves and the receiver mask, as `cycles_reference` keeps them in `folder`."""
    return [folder / "cycles_1.exr", folder / "cycles_2.exr", folder / "receiver_mask.exr"]


def read_rgba(path: Path) -> np.ndarray:
    """(H, W, 4) float64 of an RGBA OpenEXR file, as bench/preview.py's `render` returns it."""
    from hhd_lightmapper.core.files import exr

    channels, _ = exr.read(path)
    return np.stack([exr.from_exr_rows(channels[c]) for c in "RGBA"], -1).astype(np.float64)


def render_reference(scene, receivers, paths: list[Path]) -> list[np.ndarray]:
    """Render the two Cycles halves (seeds 1 and 2) and the receiver mask (every other mesh a
    holdout) to `paths`, the scene set up by `cycles_reference`; returns them as (H, W, 4)."""
    import bpy

    from preview import render

    scene.render.film_transparent = True
    images = []
    for seed, path in zip((1, 2), paths[:2]):
        scene.cycles.seed = seed
        images.append(render(bpy, scene, path, alpha=True))
    others = [o for o in scene.objects if o.type == 'MESH' and o not in receivers]
    for o in others:
        o.is_holdout = True
    scene.cycles.samples = 16
    images.append(render(bpy, scene, paths[2], alpha=True))
    for o in others:
        o.is_holdout = False
    scene.render.film_transparent = False
    return images


def bake_or_reencode(scene, folder: Path, samples: int, denoised: bool) -> None:
    """Denoised: bake `samples` per texel into `folder` through the Bake operator with Denoise on
    (and check the sidecar says it was applied). Raw: Re-encode the same files with Denoise off."""
    import bpy

    import denoise

    s = scene.hhd
    s.output_dir, s.denoise = str(folder), denoised
    if denoised:
        s.preset = 'CUSTOM'
        s.samples, s.bounces, s.seed, s.noise_target, s.time_budget = samples, denoise.BOUNCES, 0, 0.0, 0.0
        assert bpy.ops.hhd.bake() == {'FINISHED'}
        sidecar = json.loads(next(folder.glob("*.json")).read_text())
        if not sidecar["post"]["denoise"].get("applied"):
            raise RuntimeError(f"the bake in {folder} was not denoised: {sidecar['post']['denoise']}")
    else:
        assert bpy.ops.hhd.encode() == {'FINISHED'}


def eevee(scene, path: Path) -> np.ndarray:
    """The view rendered by EEVEE with the preview shown (HHD), (H, W, 3)."""
    import bpy

    from hhd_lightmapper import blender_compat
    from preview import render

    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    try:
        scene.render.engine = blender_compat.eevee_engine()
        scene.eevee.taa_render_samples = EEVEE_SAMPLES
        return render(bpy, scene, path)
    finally:
        bpy.ops.hhd.preview_hide()


def image_error(image, reference, mask) -> float:
    from tradeoff import image_rmse

    return image_rmse(image, reference, mask)


def errors(image, reference, mask, floor) -> dict:
    e = image_error(image, reference, mask)
    return {"measured": e, "corrected": math.sqrt(max(e * e - floor * floor, 0.0))}


def print_scene(name: str, entry: dict) -> None:
    w = entry["without_outliers"]
    print(
        f"\n{name}: EEVEE preview vs Cycles, image RMSE % (its noise {entry['reference']['floor']:.2f}% removed); "
        f"right: without the {100 * OUTLIERS:g}% of pixels the converged preview misses most "
        f"({100 * w['squared_error_share']:.0f}% of its squared error)"
    )
    for row, rest in zip(entry["rows"], w["rows"]):
        print(
            f"  {row['samples']:5d} spp  raw {row['raw']['corrected']:6.2f}  denoised {row['denoised']['corrected']:6.2f}"
            f"   |   raw {rest['raw']['corrected']:6.2f}  denoised {rest['denoised']['corrected']:6.2f}"
        )


def markdown(results: dict) -> str:
    lines = [
        "# The denoiser in the EEVEE preview: image error against Cycles (`bench/denoise_preview.py`)",
        "",
        "Image RMSE (%, relative per pixel to max(reference, 0.1 × its mean)) over the pixels where the "
        "camera sees a receiver, the Cycles reference's own noise removed in quadrature (measured in "
        "brackets); raw and denoised are the same bake, re-encoded without the denoiser.",
        "",
        *table_head(results),
    ]
    for name, entry in results["scenes"].items():
        cells = [
            f"{r['raw']['corrected']:.1f} → **{r['denoised']['corrected']:.1f}** "
            f"({r['raw']['measured']:.1f} → {r['denoised']['measured']:.1f})"
            for r in entry["rows"]
        ]
        lines.append(f"| {name} | {entry['reference']['floor']:.1f}% | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Without the {100 * OUTLIERS:g}% of those pixels where the most-sampled denoised preview differs most "
        "from Cycles (the same pixels in every column: geometry finer than a texel, which no sample count "
        "changes; the share of the squared error they carry there in brackets):",
        "",
        *table_head(results),
    ]
    for name, entry in results["scenes"].items():
        w = entry["without_outliers"]
        cells = [f"{r['raw']['corrected']:.1f} → **{r['denoised']['corrected']:.1f}**" for r in w["rows"]]
        lines.append(
            f"| {name} ({100 * w['squared_error_share']:.0f}%) | {w['floor']:.1f}% | " + " | ".join(cells) + " |"
        )
    if any(e["reference"].get("cached") for e in results["scenes"].values()):
        lines += [
            "",
            f"The Cycles renders were read from `--cycles-cache` ({results['settings'].get('cycles_cache')}).",
        ]
    lines += ["", f"Load average {results['load_average_start']} → {results.get('load_average_end')}.", ""]
    return "\n".join(lines)


def table_head(results: dict) -> list[str]:
    """The two header lines of a table with a column per sample count (the first scene's)."""
    rows = next(iter(results["scenes"].values()))["rows"]
    return [
        "| scene | reference noise | " + " | ".join(f"{r['samples']} spp raw → denoised" for r in rows) + " |",
        "| --- | --- | " + " | ".join("---" for _ in rows) + " |",
    ]


def figure(figures: dict, png: Path) -> None:
    """Per scene a row: Cycles | raw | denoised (the figure's sample count), receivers only."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def tone(x, mask):
        return np.where(mask[..., None], np.clip(x / (1.0 + x), 0, 1) ** (1 / 2.2), 0.15)

    names = [n for n, f in figures.items() if "raw" in f]
    if not names:
        return
    fig, axes = plt.subplots(len(names), 3, figsize=(12, 2.6 * len(names)), squeeze=False)
    for row, name in zip(axes, names):
        f = figures[name]
        scale = 0.4 / max(float(f["Cycles"][f["mask"]].mean()), 1e-12)  # each scene exposed alike
        for ax, key in zip(row, ("Cycles", "raw", "denoised")):
            ax.imshow(tone(scale * f[key], f["mask"])[::-1])
            ax.set_title(f"{name}: {key}", fontsize=9)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(png, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
