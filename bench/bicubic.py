"""Bicubic against bilinear sampling of a low-resolution lightmap at a sharp shadow edge (issue 59, part 3).

    python bench/bicubic.py [--samples 256] [--low 64] [--high 1024] [--out DIR]

Scene: a 4 m floor (the only receiver), a thin 1 m square plate 0.5 m above it turned 25° about
z (its shadow's edges run oblique to the texel grid), a sun of angle 0 at 50° elevation (a hard
shadow), no world, no bounces (the sun's direct light alone: the texels' only noise is where
their footprint samples fall), denoising off. The floor is unwrapped and baked through the
extension (bpy.ops.hhd.unwrap / bake) at --low² and at --high² texels (a texel density of
--low / 4 m: the atlas, at least 256², holds the floor's chart of --low² texels), the same samples
per texel.

On a grid of points of the floor at least 4 low-resolution texels inside its chart, I_z (red) is
sampled from the low bake bilinearly (core.textures.sample_bilinear) and bicubically
(sample_bicubic: Catmull-Rom, and the cubic B-spline), and from the high bake bilinearly (the
reference). The UV of a floor point in each atlas is the affine map the floor's lightmap UVs
define. Errors (RMS and mean absolute, relative to the lit floor's I_z) in bands of ±k reference
texels around the shadow's edge (the points within k texels of an edge texel of the reference:
one between 10% and 90% of the lit I_z, or differing from a 4-neighbour's by more than a quarter
of the lit/shadow contrast)
and over all points; the ratio bicubic / bilinear.

Writes bench/results/bicubic.md and bicubic_profile.png (a profile across the edge).
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
BANDS = (16, 32, 64)  # ± reference texels
KERNELS = ("catmull_rom", "bspline")
#: The samplings compared (besides bilinear): the two kernels on the texels, and the B-spline of
#: the prefiltered coefficients (`core.textures.bspline_coefficients`, the preview's Filter
#: 'B-spline (prefiltered)').
METHODS = (*KERNELS, "prefiltered")
LABELS = {"catmull_rom": "Catmull-Rom", "bspline": "B-spline", "prefiltered": "prefiltered B-spline"}


def build_scene(angle: float):
    """The floor, the plate and the sun of angular diameter `angle` (degrees) (module doc); returns the floor."""
    import bpy

    from scenekit import blender as kit

    kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4.0, kit.material("Floor", (0.8, 0.8, 0.8)))
    plate = kit.box("Plate", (0.0, 0.0, 0.5), (1.0, 1.0, 0.02), kit.material("Plate", (0.8, 0.8, 0.8)))
    plate.rotation_euler = (0.0, 0.0, math.radians(25.0))
    kit.sun(50.0, 200.0, 3.0, angle)
    bpy.context.view_layer.update()
    return floor


def bake(floor, resolution: int, samples: int, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Unwrap the floor alone at resolution / 4 m texels per metre (its chart resolution² texels) and bake it into `folder`; (I_z (H, W, 3) rows
    bottom-up, the 3 × 2 affine map of world (x, y, 1) → its lightmap uv)."""
    import bpy

    from hhd_lightmapper.core.files import exr, lightmap_files
    from scenekit import blender as kit

    s = bpy.context.scene.hhd
    s.samples, s.bounces, s.denoise, s.noise_target = samples, 0, False, 0.0
    s.output_dir = str(folder)
    kit.unwrap([floor], texel_density=resolution / 4.0)  # atlases start at 256²: the floor's chart is resolution²
    kit.select([floor])
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    (sidecar,) = [p for p in folder.glob("*.json") if p.stem != "probes"]
    channels, _ = exr.read(lightmap_files.AtlasFiles(folder, sidecar.stem).hhd)
    iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64)
    mesh = floor.data
    loops = list(range(len(mesh.loops)))
    world = np.array([(floor.matrix_world @ mesh.vertices[mesh.loops[i].vertex_index].co)[:2] for i in loops])
    uv = np.array([mesh.uv_layers[s.uv_layer].data[i].uv for i in loops])
    affine = np.linalg.lstsq(np.column_stack([world, np.ones(len(world))]), uv, rcond=None)[0]
    return iz, affine


def edge_distance_mask(reference: np.ndarray, k: int) -> np.ndarray:
    """(H, W) bool: texels within k (chessboard) of an edge texel of `reference` (H, W) (module doc)."""
    lit = np.percentile(reference, 95)
    step = 0.25 * (lit - np.percentile(reference, 5))
    edge = (reference > 0.1 * lit) & (reference < 0.9 * lit)  # a penumbra's texels
    dy = np.abs(np.diff(reference, axis=0)) > step
    dx = np.abs(np.diff(reference, axis=1)) > step
    edge[1:] |= dy
    edge[:-1] |= dy
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    grown = edge.copy()
    for _ in range(k):  # chessboard growth, one ring a step
        g = grown.copy()
        g[1:] |= grown[:-1]
        g[:-1] |= grown[1:]
        g[:, 1:] |= g[:, :-1].copy()
        g[:, :-1] |= g[:, 1:].copy()
        grown = g
    return grown


def measure(low, low_map, high, high_map, low_res: int, grid: int = 700) -> tuple[dict, dict]:
    """Errors per band and kernel (module doc) and the profile data."""
    from hhd_lightmapper.core.textures import sample_bilinear

    def uv_of(points, affine):
        return np.column_stack([points, np.ones(len(points))]) @ affine

    margin = 4 * 4.0 / low_res * 1.2  # ≥ 4 low texels of the chart (≈ the floor's width / low_res each)
    axis = np.linspace(-2.0 + margin, 2.0 - margin, grid)
    x, y = np.meshgrid(axis, axis)
    points = np.column_stack([x.ravel(), y.ravel()])
    ref = sample_bilinear(high, uv_of(points, high_map), clamp=True)[:, 0]
    lit = float(np.percentile(ref, 95))
    est = {"bilinear": sample_bilinear(low, uv_of(points, low_map), clamp=True)[:, 0]}
    for method in METHODS:
        est[method] = sampled(low, low_map, uv_of(points, low_map), method)
    h, w = high.shape[:2]
    huv = uv_of(points, high_map)
    hi = np.clip((huv[:, 1] * h).astype(int), 0, h - 1), np.clip((huv[:, 0] * w).astype(int), 0, w - 1)
    rows = {}
    for k in (*BANDS, None):
        mask = edge_distance_mask(high[..., 0], k)[hi] if k is not None else np.ones(len(points), bool)
        row = {"points": int(mask.sum())}
        for name, value in est.items():
            e = (value - ref)[mask] / lit
            row[name] = (float(np.sqrt(np.mean(e**2))), float(np.mean(np.abs(e))))
        rows[k] = row
    rows["overshoot"] = {m: float(np.percentile(v, 99.9) / lit - 1.0) for m, v in est.items()}
    return rows, {"points": points, "ref": ref, "est": est, "lit": lit}


def floor_texels(image: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """(H, W) bool: the atlas texels whose centre lies on the 4 m floor (its chart), by the
    inverse of the floor's world → uv map (the coverage, without the bake's files)."""
    h, w = image.shape[:2]
    j, i = np.mgrid[0:h, 0:w]
    uv = np.column_stack([(i.ravel() + 0.5) / w, (j.ravel() + 0.5) / h])
    world = np.linalg.solve(affine[:2].T, (uv - affine[2]).T).T
    return (np.abs(world) <= 2.0).all(axis=1).reshape(h, w)


def sampled(low: np.ndarray, low_map: np.ndarray, uv: np.ndarray, method: str) -> np.ndarray:
    """I_z (red) of the low bake at `uv` by `method` (METHODS), clamped at 0 as the runtime does."""
    from hhd_lightmapper.core.textures import bspline_coefficients, sample_bicubic

    if method == "prefiltered":
        coefficients = bspline_coefficients(low, floor_texels(low, low_map))
        return sample_bicubic(coefficients, uv, clamp=True, kernel="bspline", nonnegative=True)[:, 0]
    return sample_bicubic(low, uv, clamp=True, kernel=method, nonnegative=True)[:, 0]


def profile(low, low_map, high, high_map, path: Path, low_res: int) -> None:
    """PNG: I_z along a line across the shadow's edge, reference and the low bake's samplings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhd_lightmapper.core.textures import sample_bilinear

    t = np.linspace(-1.6, 1.6, 1600)
    points = np.column_stack([t, np.full_like(t, 0.37)])  # along x at y = 0.37: crosses both sides' edges

    def uv_of(affine):
        return np.column_stack([points, np.ones(len(points))]) @ affine

    fig, ax = plt.subplots(figsize=(9, 4.2))
    ax.plot(t, sample_bilinear(high, uv_of(high_map), clamp=True)[:, 0], "k", lw=1.6, label="1024² reference")
    ax.plot(t, sample_bilinear(low, uv_of(low_map), clamp=True)[:, 0], "C0", lw=1.1, label=f"{low_res}² bilinear")
    for method, colour in zip(METHODS, ("C3", "C2", "C1")):
        value = sampled(low, low_map, uv_of(low_map), method)
        ax.plot(t, value, colour, lw=1.1, label=f"{low_res}² {LABELS[method]}")
    ax.set_xlabel("x (m) along y = 0.37 m")
    ax.set_ylabel("I_z (red)")
    ax.set_title("Sharp shadow edge: a 64² bake sampled four ways against a 1024² bake")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def report(rows: dict, args, seconds: dict, angle: float) -> list[str]:
    penumbra = 0.5 / math.sin(math.radians(50.0)) * math.radians(angle) / math.sin(math.radians(50.0))
    lines = [
        f"## Sun angle {angle:g}° (penumbra ≈ {penumbra * args.low / 4.0:.1f} low texels)",
        "",
        f"Bake seconds: {seconds['low']:.1f} ({args.low}²), {seconds['high']:.1f} ({args.high}²).",
        "",
    ]
    overshoot = rows.pop("overshoot")
    lines += [
        "Overshoot (99.9th percentile of the sampled I_z over the lit floor's): "
        + ", ".join(f"{LABELS.get(m, m)} {v:+.1%}" for m, v in overshoot.items())
        + ".",
        "",
    ]
    for stat, title in ((0, "RMS"), (1, "mean abs")):
        head = " | ".join(f"{LABELS[m]} | ratio" for m in METHODS)
        lines += [f"| region | points | bilinear {title} | {head} |", "| --- " * (3 + 2 * len(METHODS)) + "|"]
        for k, row in rows.items():
            base = row["bilinear"][stat]
            cells = " | ".join(f"{row[m][stat]:.4f} | {row[m][stat] / base:.3f}" for m in METHODS)
            lines.append(
                f"| {'edge ±' + str(k) if k is not None else 'all'} | {row['points']} | {base:.4f} | {cells} |"
            )
        lines.append("")
    return lines


def linear_bound(trials: int = 20000, taps: int = 6, seed: int = 1) -> float:
    """RMS error ratio (to bilinear) of the best linear reconstruction of a hard step from its
    box-averaged texels, in 1-D within one texel of the step: for each tenth of a texel of the
    sampling point's position, the `taps` texels' weights fitted by least squares over steps at
    uniform positions (so the bound holds for every linear filter of that footprint, Catmull-Rom
    and the prefiltered B-spline included)."""
    rng = np.random.default_rng(seed)
    edge = rng.uniform(0.0, 1.0, trials) + taps // 2  # the step inside texel taps/2 (texels 0 … taps-1)
    x = edge + rng.uniform(-1.0, 1.0, trials)  # the sampling point, within a texel of the step
    cells = np.arange(taps)[None, :]
    means = np.clip(cells + 1 - edge[:, None], 0.0, 1.0)  # each texel's lit share (lit past the step)
    truth = (x > edge).astype(np.float64)
    p = x - 0.5
    base, f = np.floor(p).astype(int), p - np.floor(p)
    rows = np.arange(trials)
    bilinear = means[rows, base] * (1 - f) + means[rows, base + 1] * f
    local = np.stack([means[rows, np.clip(base + o, 0, taps - 1)] for o in range(-(taps // 2) + 1, taps // 2 + 1)], 1)
    best = np.empty(trials)
    for b in range(10):
        m = np.minimum((f * 10).astype(int), 9) == b
        w, *_ = np.linalg.lstsq(local[m], truth[m], rcond=None)
        best[m] = local[m] @ w
    return float(np.sqrt(np.mean((best - truth) ** 2)) / np.sqrt(np.mean((bilinear - truth) ** 2)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--low", type=int, default=64)
    ap.add_argument("--high", type=int, default=1024)
    ap.add_argument("--angles", type=float, nargs="+", default=[0.0, 4.0], help="sun angular diameters (degrees)")
    ap.add_argument("--reuse", action="store_true", help="measure the bakes an earlier run left in --out")
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-bicubic-")))
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import hhd_lightmapper

    hhd_lightmapper.register()
    lines = [
        "# Bicubic vs bilinear sampling of a low-resolution lightmap (bench/bicubic.py)",
        "",
        f"A 4 m floor baked at {args.low}² and {args.high}² texels, {args.samples} samples per texel, a sun only, "
        "no bounces, no denoising; the shadow of a plate 0.5 m above it, its edges oblique to the texels. "
        "Errors of I_z (red) sampled from the low bake against the high bake sampled bilinearly, relative to "
        "the lit floor's I_z, at a grid of floor points; bands: points within ±k reference texels "
        f"of the shadow's edge ({args.high // args.low} reference texels = 1 low texel). Ratio: bicubic / bilinear.",
        "",
        "Prefiltered B-spline: the B-spline of the coefficients whose B-spline has each texel's mean as its mean "
        "over the texel (core.textures.bspline_coefficients; the preview's Filter 'B-spline (prefiltered)').",
        "",
        f"A bound for a hard edge: in 1-D, the best linear reconstruction from 6 box-averaged texels "
        f"(least squares per tenth of a texel, `linear_bound`) has {linear_bound():.3f}× bilinear's RMS error "
        "within one texel of a hard step; a 2-D edge oblique to the texels gives a filter more to go on.",
        "",
    ]
    for n, angle in enumerate(args.angles):
        saved = args.out / f"bakes_{angle:g}.npz"
        if args.reuse and saved.is_file():
            d = np.load(saved)
            (low, low_map), (high, high_map) = (d["low"], d["low_map"]), (d["high"], d["high_map"])
            seconds = {"low": float(d["seconds"][0]), "high": float(d["seconds"][1])}
            lines += report(measure(low, low_map, high, high_map, args.low)[0], args, seconds, angle)
            if n == 0:
                profile(low, low_map, high, high_map, RESULTS / "bicubic_profile.png", args.low)
                lines += [f"![profile across the edge, sun angle {angle:g}°](bicubic_profile.png)", ""]
            continue
        floor = build_scene(angle)
        seconds, maps = {}, {}
        for key, res in (("low", args.low), ("high", args.high)):
            t = time.perf_counter()
            maps[key] = bake(floor, res, args.samples, args.out / f"{angle:g}" / key)
            seconds[key] = time.perf_counter() - t
            print(f"baked {res}² in {seconds[key]:.1f} s", flush=True)
        (low, low_map), (high, high_map) = maps["low"], maps["high"]
        secs = np.array([seconds["low"], seconds["high"]])
        np.savez(saved, low=low, low_map=low_map, high=high, high_map=high_map, seconds=secs)
        rows, _ = measure(low, low_map, high, high_map, args.low)
        lines += report(rows, args, seconds, angle)
        if n == 0:
            profile(low, low_map, high, high_map, RESULTS / "bicubic_profile.png", args.low)
            lines += [f"![profile across the edge, sun angle {angle:g}°](bicubic_profile.png)", ""]
    RESULTS.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines)
    (RESULTS / "bicubic.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
