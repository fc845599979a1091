"""Light sets measured: the 2024 talk's "Blending HHD" slide in numbers, and what an extra set costs.

    flock /tmp/bench.lock .venv/bin/python bench/light_sets.py     # everything (a few minutes on 2 shared cores)
    .venv/bin/python bench/light_sets.py --quick                   # a smoke run: 64² atlas, few samples
    .venv/bin/python bench/light_sets.py --replot                  # light_sets.md from the saved JSON

Scene (core only, no Blender): a 2 m floor (the receiver, its own 0–1 lightmap UVs), a box standing
on it and a back wall (occluders and bounce), lit by two point lights in two light groups: a warm
lamp `A` at the left and a cool lamp `B` at the right, so the two sets' highlight directions
diverge over most of the floor (the case the talk's slide shows). One `core.bake.trace_surface`
gives each set's radiance SH (`TracedAtlas.set_sh`, (K, P, 9, 3)); each set is encoded to HHD
(`core.hhd.encode`, the default searched direction).

Blend accuracy: for every weight pair (w_A, w_B) of WEIGHTS (RGB weights included), at shading
normals tilted 0°, 30°, 60° and 80° from n_v (four azimuths each, in the texel's tangent frame), the
irradiance reconstructed (`core.hhd.reconstruct`) from
  (a) `light_sets.blend`: the talk's runtime blend through linear SH,
  (b) `scenekit.light_set_reference.parameter_blend`: blending the HHD parameters (what the talk warns against),
  (c) `hhd.encode` of the weighted SH Σ w_k set_sh_k: the best a single HHD texel can do (the
      encoder's fit, as if the blended lighting had been baked),
against (d) the irradiance of that SH itself (`core.sh.irradiance`, the L2 cosine convolution).
Error: RMSE over texels, channels and azimuths relative to the mean of (d); (a) and (b) also
against (c). At 0° every HHD gives I_z exactly (linear in the weights), and (d) differs from I_z
by the L2 truncation of the hemisphere-masked radiance: that row is the reference's own floor.

Cost: the same scene with four lamps traced (same samples, seed, threads) with no light groups,
with all lamps in one group (1 set), in two (2 sets) and in four (4 sets), and with four groups
but `BakeSettings.light_sets` off; each REPEATS times in fresh processes (warmed up by a small
trace first), interleaved: wall and CPU seconds (medians), peak traced heap during the trace
(tracemalloc, numpy's arrays) and the peak RSS growth (ru_maxrss − RSS before the trace), as
ratios to the 1-set bake.

Writes bench/results/light_sets.json, light_sets.md and light_sets.png (rows: reference (d),
direct encode (c), linear-SH blend (a), parameter blend (b); columns: weight pairs; the floor's
texels shaded with a bump normal map tilting the normal up to 60°).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"

from hhd_lightmapper.core import bake, bakepoints, hhd, light_sets, sh, tracer  # noqa: E402
from hhd_lightmapper.core.scene import BakeScene, PointLight  # noqa: E402
from scenekit import light_set_reference, meshes  # noqa: E402

SCALARS = (0.0, 0.25, 0.5, 1.0, 2.0)
#: (w_A, w_B) RGB weight pairs: the scalar grid (both 0 left out) and three coloured pairs
WEIGHTS = [((a,) * 3, (b,) * 3) for a in SCALARS for b in SCALARS if a or b] + [
    ((1.0, 0.6, 0.3), (0.3, 0.6, 1.0)),
    ((2.0, 1.0, 0.5), (0.0, 0.5, 1.0)),
    ((0.2, 0.2, 1.5), (1.5, 0.5, 0.1)),
]
TILTS = (0, 30, 60, 80)
AZIMUTHS = (0, 90, 180, 270)
METHODS = ("linear_sh_blend", "parameter_blend", "direct_encode")
#: figure columns (indices into WEIGHTS): A alone, B alone, both, B dimmed, a coloured pair
FIGURE_WEIGHTS = (WEIGHTS.index(((1.0,) * 3, (0.0,) * 3)), WEIGHTS.index(((0.0,) * 3, (1.0,) * 3)))
FIGURE_WEIGHTS += (WEIGHTS.index(((1.0,) * 3, (1.0,) * 3)), WEIGHTS.index(((2.0,) * 3, (0.25,) * 3)), len(WEIGHTS) - 3)
#: the cost runs: name → light group of each of the four lamps (and whether sets are kept)
COST_RUNS = {
    "no groups": (("", "", "", ""), True),
    "1 set": (("A", "A", "A", "A"), True),
    "2 sets": (("A", "A", "B", "B"), True),
    "4 sets": (("A", "B", "C", "D"), True),
    "4 groups, sets off": (("A", "B", "C", "D"), False),
}
REPEATS = 4


# --- the scene ----------------------------------------------------------------------------------


def geometry():
    """(receiver SurfaceTriangles-ready floor (positions, uv), all triangles (T, 3, 3), albedo (T, 3))."""
    fv, ff = meshes.plane(2.0)
    floor = fv[ff]
    box_v, box_f = meshes.cube(0.5, centre=(1.0, 0.9, 0.25))
    wall_v, wall_f = meshes.plane(2.0)
    wall = wall_v[wall_f][:, :, [0, 2, 1]] + [0.0, 2.0, 0.0]  # the plane stood up at y = 2
    tris = np.concatenate([floor, box_v[box_f], wall])
    albedo = np.concatenate([np.full((2, 3), 0.7), np.full((12, 3), [0.6, 0.5, 0.4]), np.full((2, 3), [0.5, 0.6, 0.7])])
    uv = floor[:, :, :2] / 2.0 * 0.998 + 0.001
    return floor, uv, tris, albedo


def lamps(groups, radius=0.05):
    """Point lights of `radius` m: the warm lamp A (left), the cool lamp B (right), two more when
    4 are asked."""
    spec = [
        ((0.35, 0.7, 0.8), (300.0, 190.0, 90.0)),
        ((1.7, 1.3, 0.6), (60.0, 110.0, 240.0)),
        ((1.0, 0.2, 1.2), (120.0, 120.0, 120.0)),
        ((0.3, 1.7, 0.9), (80.0, 150.0, 80.0)),
    ]
    return [
        PointLight(np.array(p), np.array(w), radius=radius, group=g) for (p, w), g in zip(spec[: len(groups)], groups)
    ]


def scene(groups, radius=0.05):
    """(SurfaceTriangles of the floor, BakeScene lit by `lamps(groups, radius)`)."""
    floor, uv, tris, albedo = geometry()
    surface = bakepoints.SurfaceTriangles(floor, np.tile([0.0, 0.0, 1.0], (2, 3, 1)), uv, np.zeros(2, int), albedo[:2])
    return surface, BakeScene(tris, albedo, lights=lamps(groups, radius))


def trace(groups, resolution, samples, bounces, light_sets_on=True, radius=0.05):
    surface, bake_scene = scene(groups, radius)
    settings = tracer.BakeSettings(samples=samples, bounces=bounces, seed=0, light_sets=light_sets_on)
    return bake.trace_surface(surface, resolution, resolution, bake_scene, settings)


# --- blend accuracy -----------------------------------------------------------------------------


def tilted_normals(n_v, degrees, azimuth):
    """Unit normals `(N, 3)` at `degrees` from n_v, at `azimuth` degrees in its tangent frame."""
    t, a = np.radians(degrees), np.radians(azimuth)
    local = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
    return np.einsum("nij,j->ni", sh.tangent_frames(n_v), local)


def rel_rmse(x, ref):
    """RMSE of x against ref (any equal shapes) over its mean."""
    return float(np.sqrt(np.mean((x - ref) ** 2)) / max(np.mean(ref), 1e-30))


def blended(set_params, set_sh, n_v, w):
    """The three HHD of the weighted sets, by method, and the weighted SH `(P, 9, 3)`."""
    weighted = np.einsum("kc,kpjc->pjc", w, set_sh)
    return {
        "linear_sh_blend": light_sets.blend(set_params, n_v, w),
        "parameter_blend": light_set_reference.parameter_blend(set_params, w),
        "direct_encode": hhd.encode(weighted, n_v),
    }, weighted


def errors_of(methods, weighted, n_v):
    """{tilt: {method: error vs (d), method_vs_direct: error vs (c)}} at TILTS × AZIMUTHS."""
    out = {}
    for tilt in TILTS:
        normals = [tilted_normals(n_v, tilt, a) for a in AZIMUTHS]
        ref = np.stack([sh.irradiance(weighted, n) for n in normals])
        rec = {m: np.stack([hhd.reconstruct(p, n_v, n) for n in normals]) for m, p in methods.items()}
        row = {m: rel_rmse(r, ref) for m, r in rec.items()}
        for m in ("linear_sh_blend", "parameter_blend"):
            row[m + "_vs_direct"] = rel_rmse(rec[m], rec["direct_encode"])
        out[tilt] = row
    return out


def accuracy(traced):
    """Per weight pair, the errors of `errors_of`, over the valid texels."""
    keep = traced.valid
    n_v = traced.points.normal[keep]
    set_sh = traced.set_sh[:, keep]
    set_params = [hhd.encode(s, n_v) for s in set_sh]
    rows = []
    for wa, wb in WEIGHTS:
        w = np.array([wa, wb])
        methods, weighted = blended(set_params, set_sh, n_v, w)
        rows.append({"weights": [list(wa), list(wb)], "errors": errors_of(methods, weighted, n_v)})
    return rows


# --- direct light against the truth ---------------------------------------------------------


def direct_truth(points, keep):
    """Per lamp of the two-set scene (true points, no bounce): unit direction to it `(N, 3)` and
    the irradiance `(N, 3)` it gives a surface facing it, P / (4π² d²) (core/scene.py), 0 where
    shadowed (one shadow ray from the bake point) or below n_v's horizon."""
    from hhd_lightmapper.core import rays

    _, _, tris, _ = geometry()
    occluders = rays.RayScene(tris)
    x, n_v = points.position[keep], points.normal[keep]
    origins = x + n_v * rays.ray_offset(tris.reshape(-1, 3))
    out = []
    for lamp in lamps(("A", "B"), radius=0.0):
        to = lamp.position - origins
        dist = np.linalg.norm(to, axis=1)
        l = to / dist[:, None]
        lit = ~occluders.occluded(origins, l, dist) & (np.einsum("ni,ni->n", l, n_v) > 0)
        out.append((l, lit[:, None] * lamp.power[None] / (4 * np.pi**2 * dist[:, None] ** 2)))
    return out


def direct_accuracy(traced):
    """Point lights of radius 0, no bounce: each set is one delta light, the sum of two is not of
    HHD form. Errors of (a), (b), (c) and of (d) against the true irradiance at the tilted normals
    (both lamps' clamped cosines, weighted), per weight pair and tilt."""
    keep = traced.valid
    n_v, set_sh = traced.points.normal[keep], traced.set_sh[:, keep]
    truth = direct_truth(traced.points, keep)
    set_params = [hhd.encode(s, n_v) for s in set_sh]
    rows = []
    for wa, wb in WEIGHTS:
        w = np.array([wa, wb])
        methods, weighted = blended(set_params, set_sh, n_v, w)
        errors = {}
        for tilt in TILTS:
            normals = [tilted_normals(n_v, tilt, a) for a in AZIMUTHS]
            true = np.stack([sum(wk * e * clamped_cos(n, l) for wk, (l, e) in zip(w, truth)) for n in normals])
            row = {
                m: rel_rmse(np.stack([hhd.reconstruct(p, n_v, n) for n in normals]), true) for m, p in methods.items()
            }
            row["sh_irradiance"] = rel_rmse(np.stack([sh.irradiance(weighted, n) for n in normals]), true)
            errors[tilt] = row
        rows.append({"weights": [list(wa), list(wb)], "errors": errors})
    return rows


def clamped_cos(n, l):
    return np.maximum(np.einsum("ni,ni->n", n, l), 0.0)[:, None]


# --- the figure ---------------------------------------------------------------------------------


def bump_normals(position, n_v, max_tilt=60.0, waves=3.0):
    """A bump normal map over the floor: h = A sin(kx) sin(ky), its steepest tilt `max_tilt`°."""
    k = 2 * np.pi * waves / 2.0
    amp = np.tan(np.radians(max_tilt)) / k
    x, y = position[:, 0], position[:, 1]
    gx, gy = amp * k * np.cos(k * x) * np.sin(k * y), amp * k * np.sin(k * x) * np.cos(k * y)
    n = np.stack([-gx, -gy, np.ones_like(x)], axis=1) + 0 * n_v
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def figure(traced, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keep = traced.valid
    pts = traced.points
    n_v, set_sh = pts.normal[keep], traced.set_sh[:, keep]
    normals = bump_normals(pts.position[keep], n_v)
    set_params = [hhd.encode(s, n_v) for s in set_sh]
    rows = ("reference (SH irradiance)", "direct encode", "linear-SH blend (talk)", "parameter blend")
    fig, axes = plt.subplots(len(rows), len(FIGURE_WEIGHTS), figsize=(2.6 * len(FIGURE_WEIGHTS), 2.7 * len(rows)))
    for col, index in enumerate(FIGURE_WEIGHTS):
        w = np.array(WEIGHTS[index])
        methods, weighted = blended(set_params, set_sh, n_v, w)
        ref = sh.irradiance(weighted, normals)
        images = [ref] + [hhd.reconstruct(methods[m], n_v, normals) for m in METHODS[::-1][:1] + METHODS[:2]]
        exposure = 0.5 / max(np.mean(ref), 1e-30)
        for row, values in enumerate(images):
            ax = axes[row, col]
            ax.imshow(texel_image(pts, keep, values * exposure), origin="lower")
            ax.set_xticks([]), ax.set_yticks([])
            err = "" if row == 0 else f"\nRMSE {rel_rmse(values, ref):.1%}"
            ax.set_title(f"{label(w)}{err}" if row == 0 else err.strip(), fontsize=8)
            if col == 0:
                ax.set_ylabel(rows[row], fontsize=8)
    fig.suptitle("Two light sets blended, floor under a bump map (tilts up to 60°)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    shrink_png(path)


def shrink_png(path):
    """Re-save a PNG with a 256-colour palette (the noisy texel images compress badly as RGB)."""
    from PIL import Image

    with Image.open(path) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    small.save(path, optimize=True)


def texel_image(points, keep, values):
    """`(H, W, 3)` sRGB-ish image of per-texel linear values (clipped, gamma 2.2), rows bottom-up."""
    img = np.zeros((points.height * points.width, 3))
    img[points.texel[keep]] = values
    return np.clip(img.reshape(points.height, points.width, 3), 0, 1) ** (1 / 2.2)


def label(w):
    return f"A×{fmt_weight(w[0])}, B×{fmt_weight(w[1])}"


# --- cost ---------------------------------------------------------------------------------------


def rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def cost_child(name, resolution, samples, bounces, heap):
    """One cost sample in this (fresh) process: a warm-up trace (imports, compiled kernels), one
    timed trace (wall and CPU seconds, peak RSS growth over the RSS before it), and with `heap`
    one more under tracemalloc (its peak traced heap)."""
    groups, keep_sets = COST_RUNS[name]
    trace(groups, 32, 8, 1, keep_sets)
    before, cpu = rss_bytes(), cpu_seconds()
    start = time.perf_counter()
    traced = trace(groups, resolution, samples, bounces, keep_sets)
    out = {
        "sets": list(traced.sets),
        "rays": traced.rays,
        "seconds": time.perf_counter() - start,
        "cpu_seconds": cpu_seconds() - cpu,
        "rss_growth_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before) / 2**20,
    }
    if heap:
        del traced
        tracemalloc.start()
        trace(groups, resolution, samples, bounces, keep_sets)
        out["heap_peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    return out


def cpu_seconds():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def cost(resolution, samples, bounces):
    """COST_RUNS, REPEATS rounds of one fresh process each, the runs interleaved within a round (the
    machine is shared: load changes between rounds hit every run alike). Per run the median and
    the least wall and CPU seconds, the peak RSS growth, the traced heap of the first round; ratios
    of the medians to the 1-set run."""
    samples_of = {name: [] for name in COST_RUNS}
    for round_ in range(REPEATS):
        for name in COST_RUNS:
            cmd = [sys.executable, __file__, "--cost-child", name, "--resolution", str(resolution)]
            cmd += ["--samples", str(samples), "--bounces", str(bounces)] + (["--heap"] if round_ == 0 else [])
            done = subprocess.run(cmd, check=True, capture_output=True, text=True)
            samples_of[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(round_, name, samples_of[name][-1], flush=True)
    out = {name: summary(runs) for name, runs in samples_of.items()}
    base = out["1 set"]
    for run in out.values():
        for key in ("seconds", "cpu_seconds", "heap_peak_mb", "rss_growth_mb"):
            run[key + "_ratio"] = run[key] / base[key]
    return out


def summary(runs):
    """One run's samples → median (and least) seconds and CPU seconds, max RSS growth, heap."""
    wall, cpu = [r["seconds"] for r in runs], [r["cpu_seconds"] for r in runs]
    return {
        "sets": runs[0]["sets"],
        "rays": runs[0]["rays"],
        "seconds": float(np.median(wall)),
        "seconds_min": min(wall),
        "cpu_seconds": float(np.median(cpu)),
        "cpu_seconds_min": min(cpu),
        "rss_growth_mb": max(r["rss_growth_mb"] for r in runs),
        "heap_peak_mb": runs[0]["heap_peak_mb"],
        "samples": runs,
    }


# --- report -------------------------------------------------------------------------------------


def markdown(results):
    cfg = results["config"]
    lines = [
        "# Light sets: blend accuracy and cost",
        "",
        "Made by `bench/light_sets.py` (its docstring has the method). Scene: a 2 m floor, a box and a back",
        f"wall, two point lights in two light groups; {cfg['resolution']}² atlas, {cfg['samples']} samples,",
        f"{cfg['bounces']} bounces; {results['texels']} valid texels. Each set encoded with `hhd.encode`"
        " (searched direction).",
        "",
        "## Blend accuracy",
        "",
        *findings(results),
        "Irradiance RMSE relative to the mean, against (d) the weighted SH's own irradiance; (a) and (b)",
        "also against (c). Mean over the weight pairs, per tilt of the shading normal from n_v:",
        "",
        "| tilt | (a) linear-SH blend | (b) parameter blend | (c) direct encode | (a) vs (c) | (b) vs (c) |",
        "|---|---|---|---|---|---|",
    ]
    keys = ("linear_sh_blend", "parameter_blend", "direct_encode", "linear_sh_blend_vs_direct")
    keys += ("parameter_blend_vs_direct",)
    for tilt in TILTS:
        vals = [np.mean([r["errors"][str(tilt)][k] for r in results["accuracy"]]) for k in keys]
        lines.append(f"| {tilt}° | " + " | ".join(f"{v:.2%}" for v in vals) + " |")
    lines += ["", "Per weight pair (tilt 30° / 60°; 0° in the JSON):", ""]
    lines += [
        "| w_A | w_B | (a) 30° | (b) 30° | (c) 30° | (a) 60° | (b) 60° | (c) 60° | (a) vs (c) 60° | (b) vs (c) 60° |"
    ]
    lines += ["|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["accuracy"]:
        e30, e60 = r["errors"]["30"], r["errors"]["60"]
        wa, wb = (fmt_weight(w) for w in r["weights"])
        vals = (
            [e30[m] for m in METHODS]
            + [e60[m] for m in METHODS]
            + [e60["linear_sh_blend_vs_direct"], e60["parameter_blend_vs_direct"]]
        )
        lines.append(f"| {wa} | {wb} | " + " | ".join(f"{v:.2%}" for v in vals) + " |")
    lines += ["", "![blend](light_sets.png)", ""] + direct_markdown(results) + ["", "## Cost of extra sets", ""]
    lines += [
        f"Four lamps, {cfg['cost_resolution']}² atlas, {cfg['cost_samples']} samples, {cfg['bounces']} bounces,"
        f" same seed and threads; each run {REPEATS} times in fresh processes, interleaved (the",
        "machine is shared); medians, ratios to the 1-set run. CPU = user + system seconds of the trace;",
        "traced heap = tracemalloc's peak during one trace (numpy's arrays); RSS = peak resident set growth",
        "over the RSS before the trace (set by the largest stage, not necessarily the sets' arrays).",
        "`no groups` and `4 groups, sets off` trace exactly the rays of `1 set` (rays: "
        + ", ".join(f"{run['rays']:,}" for run in results["cost"].values())
        + "): their distance from ratio 1.00 is this run's timing noise; seconds differences smaller than",
        "it are not resolved. The traced heap is deterministic: "
        + f"{extra_heap_per_set(results):.1f} MB per extra set here "
        + f"({extra_heap_per_set(results) * 2**20 / results['cost_texels']:.0f} bytes per texel per set)."
        if "cost_texels" in results
        else "",
        "",
        "| run | sets | wall s (least) | ratio | CPU s (least) | ratio | traced heap MB | ratio | RSS growth MB | ratio |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, run in results["cost"].items():
        lines.append(
            f"| {name} | {len(run['sets'])} | {run['seconds']:.2f} ({run['seconds_min']:.2f}) | "
            f"{run['seconds_ratio']:.2f} | {run['cpu_seconds']:.2f} ({run['cpu_seconds_min']:.2f}) | "
            f"{run['cpu_seconds_ratio']:.2f} | {run['heap_peak_mb']:.1f} | {run['heap_peak_mb_ratio']:.2f} | "
            f"{run['rss_growth_mb']:.1f} | {run['rss_growth_mb_ratio']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def extra_heap_per_set(results):
    """Least-squares slope of the traced heap (MB) over the number of sets (1, 2, 4)."""
    runs = [results["cost"][k] for k in ("1 set", "2 sets", "4 sets")]
    return float(np.polyfit([len(r["sets"]) for r in runs], [r["heap_peak_mb"] for r in runs], 1)[0])


def findings(results):
    """The headline numbers: each blend's distance from the direct encode, mean over weight pairs."""

    def mean(key, tilt):
        return np.mean([r["errors"][str(tilt)][key] for r in results["accuracy"]])

    return [
        "**Reading.** Against the direct encode of the blended lighting (c), the talk's linear-SH blend",
        f"stays {mean('linear_sh_blend_vs_direct', 60):.1%} away at 60° ({mean('linear_sh_blend_vs_direct', 80):.1%}"
        f" at 80°), the parameter blend {mean('parameter_blend_vs_direct', 60):.1%}"
        f" ({mean('parameter_blend_vs_direct', 80):.1%}): the slide's claim holds, more so on steep normals.",
        "Against the lighting itself (d, and the true irradiance below), all three HHD are far off when two",
        "diverging lights are blended: one HHD direction cannot hold two lobes, and that model error",
        f"({mean('direct_encode', 60):.1%} at 60° for (c)) dwarfs the difference between the blends.",
        "",
    ]


def direct_markdown(results):
    keys = METHODS + ("sh_irradiance",)
    lines = [
        "## Direct light only, against the true irradiance",
        "",
        "The same scene with the lamps as true points (radius 0) and no bounce: each set is one delta",
        "light (shadowed by the box), so the true irradiance at a tilted normal is known (the lamps'",
        "clamped cosines, weighted, one shadow ray from the bake point). RMSE relative to the mean of",
        "the truth, mean over the weight pairs:",
        "",
        "| tilt | (a) linear-SH blend | (b) parameter blend | (c) direct encode | (d) SH irradiance |",
        "|---|---|---|---|---|",
    ]
    for tilt in TILTS:
        vals = [np.mean([r["errors"][str(tilt)][k] for r in results["direct"]]) for k in keys]
        lines.append(f"| {tilt}° | " + " | ".join(f"{v:.2%}" for v in vals) + " |")
    lines += ["", "Per weight pair at 60°:", "", "| w_A | w_B | (a) | (b) | (c) | (d) |", "|---|---|---|---|---|---|"]
    for r in results["direct"]:
        e = r["errors"]["60"]
        wa, wb = (fmt_weight(w) for w in r["weights"])
        lines.append(f"| {wa} | {wb} | " + " | ".join(f"{e[k]:.2%}" for k in keys) + " |")
    return lines


def fmt_weight(w):
    """A weight for a table: its number when grey, else its RGB triple."""
    return f"{w[0]:g}" if len(set(w)) == 1 else "(" + ", ".join(f"{x:g}" for x in w) + ")"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=2)
    ap.add_argument("--cost-resolution", type=int, default=256)
    ap.add_argument("--cost-samples", type=int, default=64)
    ap.add_argument("--quick", action="store_true", help="64² atlases, 16 samples")
    ap.add_argument("--replot", action="store_true", help="light_sets.md from the saved JSON")
    ap.add_argument("--cost-only", action="store_true", help="rerun the cost runs into the saved JSON")
    ap.add_argument("--cost-child", help=argparse.SUPPRESS)
    ap.add_argument("--heap", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cost_child:
        print(json.dumps(cost_child(args.cost_child, args.resolution, args.samples, args.bounces, args.heap)))
        return 0
    if args.replot:
        (RESULTS / "light_sets.md").write_text(markdown(json.loads((RESULTS / "light_sets.json").read_text())))
        return 0
    if args.quick:
        args.resolution = args.cost_resolution = 64
        args.samples = args.cost_samples = 16
    if args.cost_only:
        results = json.loads((RESULTS / "light_sets.json").read_text())
        results["cost"] = cost(args.cost_resolution, args.cost_samples, args.bounces)
        results["config"].update(cost_resolution=args.cost_resolution, cost_samples=args.cost_samples)
        return write(results)
    traced = trace(("A", "B"), args.resolution, args.samples, args.bounces)
    assert traced.sets == ("A", "B") and traced.set_sh is not None, traced.sets
    results = {
        "config": vars(args) | {"weights": WEIGHTS, "tilts": TILTS, "azimuths": AZIMUTHS},
        "texels": int(traced.valid.sum()),
        "trace_seconds": traced.seconds,
        "cost_texels": int(traced.valid.sum()) if args.cost_resolution == args.resolution else None,
        "accuracy": json.loads(json.dumps(accuracy(traced))),  # str keys, as --replot reads them
    }
    direct = trace(("A", "B"), args.resolution, 16, 0, radius=0.0)
    results["direct"] = json.loads(json.dumps(direct_accuracy(direct)))
    figure(traced, RESULTS / "light_sets.png")
    results["cost"] = cost(args.cost_resolution, args.cost_samples, args.bounces)
    return write(results)


def write(results) -> int:
    (RESULTS / "light_sets.json").write_text(json.dumps(results, indent=1))
    (RESULTS / "light_sets.md").write_text(markdown(results))
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
