"""The denoiser on real scenes: our bake raw and denoised against Cycles' Diffuse bake raw and denoised.

    flock /tmp/bench.lock .venv/bin/python bench/denoise.py     # everything (≈ 29 min on 2 cores)
    .venv/bin/python bench/denoise.py --quick                   # a smoke run: 256² atlases, few samples
    .venv/bin/python bench/denoise.py --replot                  # tables and error plot from the saved JSON
    .venv/bin/python bench/denoise.py --scenes bedroom --no-edge
    .venv/bin/python bench/denoise.py --scenes bedroom --no-edge --reference 16384 --ours 4 16 64 256 1024 2048 4096

Scenes: `classroom` (scenekit/scenes.py: sun + sky through the windows, its 6 receivers) and the
two emissive-lit interiors of the external scenes (docs/conventions.md#external-scenes),
`staircase2` and `bedroom`: their receivers are the
RECEIVERS largest mesh objects by world-space area that are not emitters (`Light_*`) or glass
(`Glass*`, `LampGlass*`) and have fewer than MAX_POLYGONS polygons. Per scene one shared atlas
(`--resolution`, texel density 0: the atlas is filled; `--padding` texels between charts),
unwrapped by the extension's `bpy.ops.hhd.unwrap`, BOUNCES diffuse bounces in both engines.

Per scene:

- references: ours as two halves of PLAN's reference samples with different seeds (their mean is
  the reference; half their RMS difference is its own noise, the *floor*), Cycles' Diffuse bake
  (Direct + Indirect, Color off = irradiance, sample clamps off, all cores) the same way; their
  agreement (ratio of the I_z sums, relative RMSE with both floors removed; also without the
  texels our bake points flag `near_cover`, and without those differing by more than 50%). The
  denoiser is also run on our reference itself: what it changes on converged input (untimed; it
  warms OIDN up).
- rows: ours raw and denoised (`core.post.denoise.pages.denoise_texels`, chart by chart, with the noise the
  tracer measured for its clamp, as a bake runs it) at PLAN's sample
  counts; Cycles raw and "denoised as The Lightmapper's users get it" (the baked atlas, its empty
  texels dilated by `core.dilate`, the whole atlas through RTLightmap in HDR mode in one call) at
  `--cycles` sample counts; and, for comparison of the two ways of filtering, our raw I_z through
  that same whole-atlas call (`EXTRA`). Time: ours as bench/time_to_error.py counts it (Embree scene, bake
  points, tracing; the scene read excluded), Cycles' bake operator and reading its pixels; the
  denoised rows add their denoise (reported separately too). Warm: both engines bake their
  reference first.
- errors, over fully covered, unburied texels, of luminance I_z: relative RMSE, each texel's error
  over max(reference, FLOOR × the reference's mean) (bench/tradeoff.py's rule), raw and with the
  reference's floor removed in quadrature (sqrt(max(err² − floor², 0))); mean bias = ΣI_z / Σ
  reference I_z − 1. Each row against its own engine's reference (the headline) and the other's
  (over the texels not flagged `near_cover`, where the engines treat a coplanar cover differently).
- time to each `--levels` error (floor-corrected, log-log interpolation as
  time_to_error.time_at; below the first point: at most that time; past the last: extrapolated
  along the last segment, flagged, only within EXTRAPOLATE_MAX × the longest time) and the speed-ups: ours denoised vs ours raw, ours denoised vs
  Cycles denoised, ours raw vs Cycles raw. The acceptance goal checked: ours denoised ≥ 4× faster
  than ours raw to 5% with |bias| ≤ 2%.
- the denoiser's own time per megatexel (baked texels, and the page texels it filters).

Shadow edges (`edge_fixture`): tests/test_bake_cycles.py's `floor` fixture (a 2 m floor, a box
floating above it, a sun of zero angle: a hard shadow) plus a box resting on the floor and a dim
sky (so shadows are not black and the contact has an occlusion gradient), BOUNCES bounces, 256²:
raw and denoised at `--edge-samples` and a reference (two halves). The blocker's shadow outline is
computed from the geometry; per method the mean (signed) and RMS relative error of the texels
within 2 texels of the shadow edge, the 10–90% width of the edge profile (texels binned by signed
distance to the edge, normalised by the reference's shadow and lit levels), and the same errors
for the texels within 2 texels of the resting box's contact line.

A scene's `note` in the JSON (set by hand when its entry is kept from an earlier run, e.g. after
`--scenes` re-measured the others) is printed under its heading.

Writes bench/results/denoise.json, denoise.md (the tables), denoise_error.png (error vs time per
scene, log-log), denoise_side_by_side.png (raw | denoised | reference I_z of `--figure-scene` at
the PREVIEW preset's sample count, cropped) and denoise_edge.png (the edge profiles); the
per-texel I_z of each scene's references and rows go to ARRAYS (a temporary folder) for diagnosis.
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
SHARED = ROOT.parent / "shared" / "scenes"
LAYER = "HHD_Lightmap"
BOUNCES = 3
#: errors are relative per texel to max(reference, FLOOR × the reference's mean) (bench/tradeoff.py)
FLOOR = 0.1
SCENES = ("classroom", "staircase2", "bedroom")
#: receivers of the .blend scenes: the largest by area of the meshes that are not emitters or glass
RECEIVERS = 8
MAX_POLYGONS = 20_000
NOT_RECEIVERS = ("Light_", "Glass", "LampGlass")
#: per scene: our reference's samples (two halves), Cycles' reference's samples (two halves), our
#: sample counts (chosen so the whole run fits ~35 min on 2 cores; see the docstring)
PLAN = {
    "classroom": {"reference": 2048, "cycles_reference": 1024, "ours": [4, 16, 64, 256, 1024]},
    "staircase2": {"reference": 2048, "cycles_reference": 512, "ours": [4, 16, 64, 256, 1024]},
    "bedroom": {"reference": 4096, "cycles_reference": 256, "ours": [4, 16, 64, 256, 1024]},
}
QUICK_PLAN = {"reference": 128, "cycles_reference": 64, "ours": [4, 16, 64]}
#: seeds: our rows 0, our reference halves, Cycles' rows 0 and its reference halves (Cycles'
#: samples for one seed are nested: a low-sample bake must not share the reference's)
REFERENCE_SEEDS = (101, 102)
CYCLES_REFERENCE_SEEDS = (9173, 9174)
GOAL = {"level": 0.05, "speedup": 4.0, "bias": 0.02}
METHODS = ("ours raw", "ours denoised", "Cycles raw", "Cycles denoised")
#: an extra row per sample count: our bake's I_z through the Cycles rows' whole-atlas denoise (not the SH)
EXTRA = "ours I_z, whole-atlas denoise"
#: how far (× the longest measured time) a time to error may be extrapolated
EXTRAPOLATE_MAX = 10.0
#: per-texel I_z of the references and rows, per scene, for diagnostics (not a result)
ARRAYS = Path(tempfile.gettempdir()) / "hhd-bench-denoise-arrays"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=2, help="texels between charts (as bench/time_to_error.py)")
    ap.add_argument("--cycles", type=int, nargs="+", default=[4, 16, 64, 256])
    ap.add_argument("--levels", type=float, nargs="+", default=[0.20, 0.10, 0.05])
    ap.add_argument("--edge-samples", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--edge-reference", type=int, default=2048)
    ap.add_argument("--no-edge", action="store_true", help="skip the shadow-edge fixture")
    ap.add_argument("--figure-scene", default="staircase2", choices=SCENES)
    ap.add_argument("--ours", type=int, nargs="+", help="our sample counts, for every scene run (default: PLAN's)")
    ap.add_argument("--reference", type=int, help="our reference's samples (two halves), for every scene run")
    ap.add_argument("--quick", action="store_true", help="256² atlases, few samples, small references")
    ap.add_argument("--replot", action="store_true", help="denoise.md and denoise_error.png from the JSON")
    ap.add_argument("--out", type=Path, help="folder of the results (default bench/results; --quick: a temporary one)")
    args = ap.parse_args()
    global RESULTS
    if args.replot:
        RESULTS = args.out or RESULTS
        results = json.loads((RESULTS / "denoise.json").read_text())
        for r in results["scenes"].values():
            derive(r, results["settings"]["levels"])
        (RESULTS / "denoise.json").write_text(json.dumps(results, indent=2))
        finish(results)
        return 0
    if args.quick:
        args.resolution, args.cycles, args.edge_reference = 256, [4, 16], 256
        args.out = args.out or Path(tempfile.mkdtemp(prefix="hhd-bench-denoise-"))
    RESULTS = args.out or RESULTS
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    from hhd_lightmapper.bridge import denoiser as bridge_denoiser
    from hhd_lightmapper.core import parallel
    from hhd_lightmapper.core.post.denoise import filtering

    hhd_lightmapper.register()
    t_run = time.perf_counter()
    threads = parallel.resolve_threads(0)
    denoiser = filtering.denoiser_for(bridge_denoiser.oidn_library(), threads)
    out = RESULTS / "denoise.json"
    results = {
        "settings": {k: v for k, v in vars(args).items() if k not in ("replot", "out")},
        "plan": {s: plan_of(s, args) for s in args.scenes},
        "bounces": BOUNCES,
        "oidn": {"version": denoiser.version, "library": str(denoiser.library), "threads": threads},
        "load_average_start": os.getloadavg(),
        "scenes": {},
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    for name in args.scenes:
        results["scenes"][name] = measure_scene(name, args, denoiser)
        print_scene(name, results["scenes"][name])
        out.write_text(json.dumps(results, indent=2))
    if not args.no_edge:
        results["edge"] = edge_fixture(args, denoiser)
        print_edge(results["edge"])
    results["wall_seconds"] = time.perf_counter() - t_run
    results["load_average_end"] = os.getloadavg()
    out.write_text(json.dumps(results, indent=2))
    finish(results)
    print(f"wall time {results['wall_seconds'] / 60:.1f} min; results in {out}", flush=True)
    return 0


def plan_of(name: str, args) -> dict:
    """The scene's PLAN (QUICK_PLAN with --quick), with --ours and --reference in its place."""
    plan = dict(QUICK_PLAN if args.quick else PLAN[name])
    if args.ours:
        plan["ours"] = sorted(args.ours)
    if args.reference:
        plan["reference"] = args.reference
    return plan


# ---- scenes ---------------------------------------------------------------------------------
def load_scene(name: str) -> list:
    """Open or build the scene; its receivers (largest first for the .blend scenes)."""
    import bpy

    from scenekit import scenes

    if name == "classroom":
        return scenes.classroom()
    bpy.ops.wm.open_mainfile(filepath=str(SHARED / name / f"{name}.blend"))
    meshes = [
        o
        for o in bpy.context.scene.objects
        if o.type == 'MESH' and not o.name.startswith(NOT_RECEIVERS) and len(o.data.polygons) < MAX_POLYGONS
    ]
    return sorted(meshes, key=world_area, reverse=True)[:RECEIVERS]


def world_area(obj) -> float:
    m = obj.matrix_world
    total = 0.0
    for p in obj.data.polygons:
        v = [m @ obj.data.vertices[i].co for i in p.vertices]
        for a, b in zip(v[1:-1], v[2:]):
            total += 0.5 * (a - v[0]).cross(b - v[0]).length
    return total


def set_up_cycles(scene) -> None:
    """Cycles as every comparison here runs it: CPU, all cores, no adaptive sampling, no
    denoising, sample clamps off, BOUNCES diffuse bounces only."""
    scene.render.engine = 'CYCLES'
    scene.render.threads_mode = 'AUTO'
    c = scene.cycles
    c.device, c.use_denoising, c.use_adaptive_sampling = 'CPU', False, False
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.max_bounces = c.diffuse_bounces = BOUNCES
    c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0


class Atlas:
    """One scene's receivers unwrapped into one atlas, the scene read for our tracer, and the
    texels errors are measured over."""

    def __init__(self, receivers, resolution: int, padding: int):
        import bpy

        from hhd_lightmapper.bridge import mesh_data, scene_data
        from scenekit.blender import select

        scene = bpy.context.scene
        s = scene.hhd
        s.uv_layer, s.resolution, s.texel_density, s.padding, s.atlas_mode = LAYER, resolution, 0.0, padding, 'SHARED'
        select(receivers)
        t = time.perf_counter()
        assert bpy.ops.hhd.unwrap() == {'FINISHED'}
        self.unwrap_seconds = time.perf_counter() - t
        self.unwrap_summary = s.unwrap_summary
        set_up_cycles(scene)
        self.receivers, self.size = receivers, resolution
        depsgraph = bpy.context.evaluated_depsgraph_get()
        self.surface = mesh_data.read_surface(receivers, LAYER, depsgraph)
        self.bake_scene = scene_data.read_bake_scene(depsgraph)
        self.points = None
        self.keep = None


def our_bake(atlas: Atlas, samples: int, seed: int):
    """Our bake of the atlas (Embree scene, bake points, tracing; timed together as
    time_to_error.our_bake). Returns (TracedAtlas, seconds)."""
    from hhd_lightmapper.core import bake, tracer

    settings = tracer.BakeSettings.from_samples(samples, bounces=BOUNCES, seed=seed)
    t = time.perf_counter()
    traced = bake.trace_surface(atlas.surface, atlas.size, atlas.size, atlas.bake_scene, settings)
    seconds = time.perf_counter() - t
    if atlas.points is None:
        atlas.points = traced.points
    assert np.array_equal(traced.points.texel, atlas.points.texel)
    return traced, seconds


def cycles_bake(atlas: Atlas, samples: int, seed: int):
    """Cycles' Diffuse bake (Direct + Indirect, Color off) of the receivers into a float image
    first set to -1 and not cleared, so the texels Cycles wrote are known. Returns ((H, W, 3)
    irradiance, (H, W) bool written, seconds of the bake operator and reading the pixels)."""
    import bpy

    from scenekit.blender import select

    scene = bpy.context.scene
    scene.cycles.samples, scene.cycles.seed = samples, seed
    n = atlas.size
    image = bpy.data.images.get("bench_denoise") or bpy.data.images.new("bench_denoise", n, n, float_buffer=True)
    for obj in atlas.receivers:
        for mat in obj.data.materials:
            node = mat.node_tree.nodes.get("bench_target") or mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.name, node.image = "bench_target", image
            mat.node_tree.nodes.active = node
    select(atlas.receivers)
    image.pixels.foreach_set(np.full(n * n * 4, -1.0, np.float32))
    t = time.perf_counter()
    bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT'}, margin=0, use_clear=False, uv_layer=LAYER)
    px = np.empty(n * n * 4, np.float32)
    image.pixels.foreach_get(px)
    seconds = time.perf_counter() - t
    px = px.reshape(n, n, 4)
    return px[..., :3].astype(np.float64), px[..., 0] != -1.0, seconds


def denoise_ours(traced, denoiser):
    """The denoise post stage on a bake: (denoised SH (P, 9, 3), DenoiseReport, seconds incl. the
    texel images)."""
    from hhd_lightmapper.core import encoding
    from hhd_lightmapper.core.post.denoise import pages

    t = time.perf_counter()
    data = encoding.TexelData.from_points(traced.points, traced.sh, noise=traced.noise())
    clean, report = pages.denoise_texels(data, denoiser)
    seconds = time.perf_counter() - t
    return clean.sh.reshape(-1, 9, 3)[traced.points.texel].astype(np.float64), report, seconds


def mean_error(halves) -> np.ndarray:
    """The standard error (P, 9, 3) of the mean of two independent halves' SH."""
    return (0.5 * np.sqrt(np.square(halves[0].sh_error, dtype=np.float64) + np.square(halves[1].sh_error))).astype(
        np.float32
    )


def denoise_cycles(image: np.ndarray, written: np.ndarray, denoiser):
    """The Lightmapper's way: the baked atlas with its empty texels dilated, through RTLightmap
    (HDR, OIDN's auto-exposure) as one image. Returns ((H, W, 3), seconds)."""
    from hhd_lightmapper.core import dilate

    t = time.perf_counter()
    filled = dilate.dilate(np.where(written[..., None], image, 0.0).astype(np.float32), written)
    clean = denoiser.denoise(filled).astype(np.float64)
    return clean, time.perf_counter() - t


# ---- measures -------------------------------------------------------------------------------
def lum_iz(sh, normal) -> np.ndarray:
    from hhd_lightmapper.core import hhd

    return hhd.irradz(sh, normal) @ hhd.LUMINANCE


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


class Reference:
    """Luminance I_z of two half references `a`, `b` over the kept texels: their mean, the
    per-texel scale of relative errors and the floor (the mean's own relative RMS noise, %)."""

    def __init__(self, a: np.ndarray, b: np.ndarray, seconds: float, samples: int):
        self.a, self.b = a, b
        self.value = 0.5 * (a + b)
        self.scale = np.maximum(self.value, FLOOR * self.value.mean())
        self.floor = self.floor_over(None)
        self.seconds, self.samples = seconds, samples

    def floor_over(self, subset: np.ndarray | None, scale: np.ndarray | None = None) -> float:
        """The floor (%) over `subset` of the kept texels (None: all), relative to `scale`."""
        d = (self.a - self.b) / (self.scale if scale is None else scale)
        return 100 * 0.5 * rms(d if subset is None else d[subset])

    def errors(self, x: np.ndarray, subset: np.ndarray | None = None) -> dict:
        """rmse (%), rmse_corrected (floor removed in quadrature, %), bias (%), over `subset` (None: all)."""
        sel = slice(None) if subset is None else subset
        e = 100 * rms(((x - self.value) / self.scale)[sel])
        floor = self.floor if subset is None else self.floor_over(subset)
        return {
            "rmse": e,
            "rmse_corrected": math.sqrt(max(e * e - floor**2, 0.0)),
            "bias": 100 * (float(x[sel].sum()) / float(self.value[sel].sum()) - 1.0),
        }

    def summary(self) -> dict:
        return {
            "samples": self.samples,
            "seconds": self.seconds,
            "floor": self.floor,
            "mean_iz": float(self.value.mean()),
        }


def measure_scene(name: str, args, denoiser) -> dict:
    from hhd_lightmapper.core import hhd, presets

    plan = plan_of(name, args)
    t_scene = time.perf_counter()
    receivers = load_scene(name)
    atlas = Atlas(receivers, args.resolution, args.padding)
    print(f"[{name}] receivers {[o.name for o in receivers]}; unwrap {atlas.unwrap_seconds:.1f} s", flush=True)
    # our reference: two halves (the first bake also loads the compiled kernels)
    halves, seconds = [], 0.0
    for seed in REFERENCE_SEEDS:
        traced, s = our_bake(atlas, plan["reference"] // 2, seed)
        halves.append(traced)
        seconds += s
    points = atlas.points
    # Cycles' reference: two halves with other seeds (warms Cycles up)
    cyc_halves, cyc_seconds = [], 0.0
    for seed in CYCLES_REFERENCE_SEEDS:
        image, written, s = cycles_bake(atlas, plan["cycles_reference"] // 2, seed)
        cyc_halves.append(image)
        cyc_seconds += s
    written_texels = written.reshape(-1)[points.texel]
    full = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    keep = full & written_texels
    atlas.keep = keep
    iz = lambda sh: lum_iz(sh[keep], points.normal[keep])  # noqa: E731
    cyc_iz = lambda image: image.reshape(-1, 3)[points.texel[keep]] @ hhd.LUMINANCE  # noqa: E731
    ours_ref = Reference(iz(halves[0].sh), iz(halves[1].sh), seconds, plan["reference"])
    cyc_ref = Reference(cyc_iz(cyc_halves[0]), cyc_iz(cyc_halves[1]), cyc_seconds, plan["cycles_reference"])
    ref_sh = 0.5 * (halves[0].sh + halves[1].sh)
    near_cover = points.near_cover[keep]
    cross = ~near_cover  # texels compared across engines (see `agreement_of`)
    agreement = agreement_of(ours_ref, cyc_ref, near_cover)
    arrays = {
        "keep": keep,
        "texel": points.texel,
        "object": points.object_index,
        "near_cover": points.near_cover,
        "ours_reference": np.stack([ours_ref.a, ours_ref.b]),
        "cycles_reference": np.stack([cyc_ref.a, cyc_ref.b]),
    }
    print(
        f"[{name}] {len(points.texel)} texels, {int(keep.sum())} measured; our reference {plan['reference']} spp "
        f"{seconds:.0f} s, floor {ours_ref.floor:.2f}%; Cycles' {plan['cycles_reference']} spp {cyc_seconds:.0f} s, "
        f"floor {cyc_ref.floor:.2f}%; Cycles / ours {agreement['mean_ratio']:.4f}, "
        f"RMSE {agreement['rmse']:.2f}% ({agreement['rmse_corrected']:.2f}% without the floors)",
        flush=True,
    )
    # the denoiser on the converged reference (untimed; loads OIDN's weights)
    ref_traced = halves[0].with_sh(ref_sh, mean_error(halves))
    clean_ref, ref_report, ref_denoise_seconds = denoise_ours(ref_traced, denoiser)
    filter_on_reference = ours_ref.errors(iz(clean_ref))
    filter_on_reference.update(report=ref_report.sidecar(), seconds=ref_denoise_seconds)
    arrays["ours_reference_denoised"] = iz(clean_ref)
    del halves, cyc_halves, ref_traced
    preview_samples = presets.get("PREVIEW").samples
    figure = {"reference": texel_image(points, ref_sh)} if name == args.figure_scene else None

    rows = {m: [] for m in (*METHODS, EXTRA)}
    for samples in plan["ours"]:
        traced, s = our_bake(atlas, samples, seed=0)
        raw = iz(traced.sh)
        rows["ours raw"].append(
            {
                "samples": samples,
                "seconds": s,
                "trace_seconds": traced.seconds,
                "setup_seconds": s - traced.seconds,
                **both(raw, ours_ref, cyc_ref, cross),
            }
        )
        clean_sh, report, d = denoise_ours(traced, denoiser)
        clean = iz(clean_sh)
        rows["ours denoised"].append(
            {
                "samples": samples,
                "seconds": s + d,
                "denoise_seconds": d,
                "report": report.sidecar(),
                "baked_texels": int((~points.buried).sum()),
                **both(clean, ours_ref, cyc_ref, cross),
            }
        )
        image = texel_image(points, traced.sh).astype(np.float64)
        whole, d_whole = denoise_cycles(image, points.image(~points.buried, fill=False, dtype=bool), denoiser)
        whole_iz = whole.reshape(-1, 3)[points.texel[keep]] @ hhd.LUMINANCE
        rows[EXTRA].append(
            {
                "samples": samples,
                "seconds": s + d_whole,
                "denoise_seconds": d_whole,
                **both(whole_iz, ours_ref, cyc_ref, cross),
            }
        )
        arrays[f"ours_raw_{samples}"], arrays[f"ours_denoised_{samples}"] = raw, clean
        arrays[f"ours_whole_atlas_{samples}"] = whole_iz
        if figure is not None and samples == preview_samples:
            figure["raw"], figure["denoised"] = texel_image(points, traced.sh), texel_image(points, clean_sh)
        print_rows(name, samples, rows["ours raw"][-1], rows["ours denoised"][-1], "ours")
    for samples in args.cycles:
        image, written_now, s = cycles_bake(atlas, samples, seed=0)
        rows["Cycles raw"].append({"samples": samples, "seconds": s, **both(cyc_iz(image), cyc_ref, ours_ref, cross)})
        clean, d = denoise_cycles(image, written_now, denoiser)
        rows["Cycles denoised"].append(
            {
                "samples": samples,
                "seconds": s + d,
                "denoise_seconds": d,
                "atlas_texels": atlas.size * atlas.size,
                **both(cyc_iz(clean), cyc_ref, ours_ref, cross),
            }
        )
        arrays[f"cycles_raw_{samples}"], arrays[f"cycles_denoised_{samples}"] = cyc_iz(image), cyc_iz(clean)
        print_rows(name, samples, rows["Cycles raw"][-1], rows["Cycles denoised"][-1], "Cycles")
    result = {
        "receivers": [o.name for o in receivers],
        "unwrap": atlas.unwrap_summary,
        "unwrap_seconds": atlas.unwrap_seconds,
        "triangles": int(len(atlas.bake_scene.triangles)),
        "resolution": atlas.size,
        "texels": int(len(points.texel)),
        "buried_texels": int(points.buried.sum()),
        "measured_texels": int(keep.sum()),
        "full_texels_not_written_by_cycles": int((full & ~written_texels).sum()),
        "cycles_written_texels": int(written.sum()),
        "reference": ours_ref.summary(),
        "cycles_reference": cyc_ref.summary(),
        "agreement": agreement,
        "filter_on_reference": filter_on_reference,
        "rows": rows,
        "scene_seconds": time.perf_counter() - t_scene,
    }
    derive(result, args.levels)
    ARRAYS.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(ARRAYS / f"{name}.npz", **arrays)
    result["arrays"] = str(ARRAYS / f"{name}.npz")
    if figure is not None:
        side_by_side(name, figure, points, preview_samples)
    return result


def both(x: np.ndarray, own: Reference, other: Reference, cross: np.ndarray) -> dict:
    """Errors against the row's own engine's reference (the headline, all measured texels) and
    the other's (over the `cross` texels: not near a coplanar cover, see `agreement_of`)."""
    return {**own.errors(x), "vs_other_reference": other.errors(x, cross)}


def agreement_of(ours: Reference, cycles: Reference, near_cover: np.ndarray) -> dict:
    """Cycles' reference against ours: ratio of the I_z sums, relative RMSE (per texel over our
    reference's scale) and that RMSE with both references' floors (over the same texels, same
    scale) removed; over all measured texels, without those our bake points flag `near_cover`
    (part of the texel may lie under a coplanar face: the engines treat it differently), and
    without the texels differing by more than 50% (how many, and their share of the squared
    difference)."""
    d = (cycles.value - ours.value) / ours.scale

    def over(subset):
        e = 100 * rms(d[subset])
        floor2 = ours.floor_over(subset) ** 2 + cycles.floor_over(subset, ours.scale) ** 2
        ratio = float(cycles.value[subset].sum() / ours.value[subset].sum())
        return {
            "texels": int(subset.sum()),
            "mean_ratio": ratio,
            "rmse": e,
            "rmse_corrected": math.sqrt(max(e * e - floor2, 0.0)),
        }

    everything = np.ones(len(d), bool)
    large = np.abs(d) > 0.5
    return {
        **over(everything),
        "without_near_cover": over(~near_cover),
        "over_50pct": {"texels": int(large.sum()), "share": float(np.sum(d[large] ** 2) / np.sum(d**2))},
        "without_over_50pct": over(~large),
    }


def texel_image(points, sh) -> np.ndarray:
    """RGB I_z `(H, W, 3)` float32 of per-point SH (0 outside the texels)."""
    from hhd_lightmapper.core import hhd

    return points.image(hhd.irradz(sh, points.normal), dtype=np.float32)


def time_at(rows: list[dict], level: float, key: str = "rmse_corrected") -> dict:
    """Seconds to reach `level` (%) of `key`: {"seconds", "how"}; how = "interpolated" (log-log,
    time_to_error.time_at), "at most" (the first, cheapest row is already below it),
    "extrapolated" (past the last row along the last segment, if there the error falls at least
    as time^-0.25 and the level is reached within EXTRAPOLATE_MAX × the last time) or "not
    reached" ("best": the least error measured)."""
    import time_to_error

    pts = sorted((r["seconds"], max(r[key], 1e-6)) for r in rows)
    if pts[0][1] <= level:
        return {"seconds": pts[0][0], "how": "at most"}
    t = time_to_error.time_at([{"rmse": e, "seconds": s} for s, e in pts], level)
    if t is not None:
        return {"seconds": t, "how": "interpolated"}
    best = min(e for _, e in pts)
    (t0, e0), (t1, e1) = pts[-2], pts[-1]
    if level < e1 < e0:
        alpha = math.log(e0 / e1) / math.log(t1 / t0)  # error ∝ time^-alpha on the last segment
        t = t1 * (e1 / level) ** (1.0 / alpha)
        if alpha >= 0.25 and t <= EXTRAPOLATE_MAX * t1:
            return {"seconds": t, "how": "extrapolated", "best": best}
    return {"seconds": None, "how": "not reached", "best": best}


def derive(result: dict, levels: list[float]) -> None:
    """A scene's figures derived from its rows: times to each error level and speed-ups (own
    references, and ours for all), the goal, the denoiser's rate."""
    rows = result["rows"]
    result["time_to_error"] = time_to_error(rows, levels)
    result["time_to_error_our_reference"] = time_to_error(common_reference(rows), levels)
    result["goal"] = goal(result)
    result["denoise_rate"] = denoise_rate(rows)


def common_reference(rows: dict) -> dict:
    """The rows with every error against our reference (Cycles' rows take their `vs_other_reference`)."""
    out = {}
    for m, rs in rows.items():
        out[m] = [{**r, **r["vs_other_reference"]} if m.startswith("Cycles") else r for r in rs]
    return out


def time_to_error(rows: dict, levels: list[float]) -> dict:
    out = {}
    for level in levels:
        pct = 100 * level
        t = {m: time_at(rows[m], pct) for m in (*METHODS, EXTRA) if rows.get(m)}
        ratios = {}
        for label, fast, slow in (
            ("ours denoised vs ours raw", "ours denoised", "ours raw"),
            ("ours denoised vs Cycles denoised", "ours denoised", "Cycles denoised"),
            ("ours raw vs Cycles raw", "ours raw", "Cycles raw"),
        ):
            a, b = t[fast], t[slow]
            if a["seconds"] and b["seconds"]:
                flags = sorted({a["how"], b["how"]} - {"interpolated"})
                ratios[label] = {"speedup": b["seconds"] / a["seconds"], "flags": flags, "bound": bound(a, b)}
            else:
                ratios[label] = {"speedup": None, "flags": ["not reached"], "bound": None}
        out[f"{level:g}"] = {"times": t, "speedups": ratios}
    return out


def bound(fast: dict, slow: dict) -> str:
    """What a speed-up slow / fast is when a time is only a bound ("at most": the first row was
    already below the level): "≥" if only the fast one is, "≤" if only the slow one is, "?" if
    both; "" for two interpolated or extrapolated times."""
    a, b = fast["how"] == "at most", slow["how"] == "at most"
    return "?" if a and b else "≥" if a else "≤" if b else ""


def goal(result: dict) -> dict:
    """Ours denoised ≥ GOAL speedup × faster than ours raw to GOAL level, with |bias| ≤ GOAL bias
    (the bias of the denoised row that reaches the level first, and the largest of all denoised rows)."""
    level = f"{GOAL['level']:g}"
    tt = result["time_to_error"].get(level)
    if tt is None:
        return {"checked": False}
    s = tt["speedups"]["ours denoised vs ours raw"]
    den = result["rows"]["ours denoised"]
    reached = [r for r in den if r["rmse_corrected"] <= 100 * GOAL["level"]]
    bias_at = reached[0]["bias"] if reached else None
    worst = max(abs(r["bias"]) for r in den)
    met = (
        s["speedup"] is not None
        and s["bound"] in ("", "≥")
        and s["speedup"] >= GOAL["speedup"]
        and bias_at is not None
        and abs(bias_at) <= 100 * GOAL["bias"]
    )
    return {
        "checked": True,
        "speedup": s["speedup"],
        "flags": s["flags"],
        "bound": s["bound"],
        "bias_where_reached": bias_at,
        "worst_abs_bias": worst,
        "met": bool(met),
    }


def denoise_rate(rows: dict) -> dict:
    """The denoiser's seconds per million baked texels and per million page texels (ours, median
    over the rows), and per million atlas texels for the whole-atlas Cycles denoise."""
    ours = rows["ours denoised"]
    cyc = rows["Cycles denoised"]
    return {
        "ours_s_per_mtexel_baked": float(np.median([r["denoise_seconds"] / (r["baked_texels"] / 1e6) for r in ours])),
        "ours_s_per_mtexel_pages": float(
            np.median([r["report"]["seconds"] / (r["report"]["page_texels"] / 1e6) for r in ours])
        ),
        "ours_pages": ours[0]["report"]["pages"],
        "ours_charts": ours[0]["report"]["charts"],
        "ours_page_texels": ours[0]["report"]["page_texels"],
        "ours_seconds": float(np.median([r["denoise_seconds"] for r in ours])),
        "cycles_s_per_mtexel_atlas": float(
            np.median([r["denoise_seconds"] / (r["atlas_texels"] / 1e6) for r in cyc]) if cyc else float("nan")
        ),
        "cycles_seconds": float(np.median([r["denoise_seconds"] for r in cyc])) if cyc else None,
    }


# ---- shadow edges -----------------------------------------------------------------------------
EDGE_BLOCKER = ((0.2, 0.1, 0.35), (0.4, 0.4, 0.3))  # tests/test_bake_cycles.py's `floor` fixture
RESTING_BOX = ((-0.6, -0.55, 0.125), (0.3, 0.3, 0.25))  # centre, size: standing on the floor
SKY = ((0.4, 0.5, 0.7), 0.3)


def edge_fixture(args, denoiser) -> dict:
    """The shadow-edge and contact figures (module docstring)."""
    import bpy
    from mathutils import Vector

    from scenekit import blender as kit

    t_fixture = time.perf_counter()
    kit.clear_scene()
    grey = kit.material("Floor", (0.8, 0.8, 0.8))
    floor = kit.plane("Floor", (0, 0, 0), 2.0, grey)
    blocker = kit.box("Blocker", *EDGE_BLOCKER, kit.material("Blocker", (0.6, 0.5, 0.4)))
    kit.box("Resting box", *RESTING_BOX, kit.material("Box", (0.6, 0.5, 0.4)))
    sun = kit.light('SUN', rotation=(math.radians(30), math.radians(10), 0), energy=3.0, angle=0.0)
    kit.world(SKY[0], SKY[1])
    bpy.context.view_layer.update()
    towards_ground = np.array(sun.matrix_world.to_3x3() @ Vector((0.0, 0.0, -1.0)))
    corners = np.array([blocker.matrix_world @ Vector(c) for c in blocker.bound_box])
    shadow = convex_hull(corners[:, :2] - corners[:, 2:3] / towards_ground[2] * towards_ground[:2])
    atlas = Atlas([floor], kit.RES, bpy.context.scene.hhd.padding)
    samples = [8, 16] if args.quick else args.edge_samples
    halves, seconds = [], 0.0
    for seed in REFERENCE_SEEDS:
        traced, s = our_bake(atlas, args.edge_reference // 2, seed)
        halves.append(traced)
        seconds += s
    points = atlas.points
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    ts = points.texel_size[keep]
    xy = points.position[keep, :2]
    edge_d, usable = signed_distance(xy, shadow, 3.0 * ts)
    edge_d /= ts
    lo = np.array(RESTING_BOX[0][:2]) - np.array(RESTING_BOX[1][:2]) / 2
    hi = np.array(RESTING_BOX[0][:2]) + np.array(RESTING_BOX[1][:2]) / 2
    box_d = np.hypot(*np.maximum(np.maximum(lo - xy, xy - hi), 0.0).T) / ts
    far_from_box = box_d * ts > 0.15
    edge = usable & (np.abs(edge_d) <= 2.0) & far_from_box
    profile_set = usable & (np.abs(edge_d) <= 6.0) & far_from_box
    contact = (box_d > 0.0) & (box_d <= 2.0)
    iz = lambda sh: lum_iz(sh[keep], points.normal[keep])  # noqa: E731
    a, b = iz(halves[0].sh), iz(halves[1].sh)
    ref = Reference(a, b, seconds, args.edge_reference)
    ref_sh = 0.5 * (halves[0].sh + halves[1].sh)
    clean_ref, _, _ = denoise_ours(halves[0].with_sh(ref_sh, mean_error(halves)), denoiser)
    bins = np.arange(-6.0, 6.001, 0.25)
    levels = profile_levels(ref.value, edge_d, profile_set)
    out = {
        "texels": int(len(points.texel)),
        "measured_texels": int(keep.sum()),
        "edge_texels": int(edge.sum()),
        "contact_texels": int(contact.sum()),
        "reference": ref.summary(),
        "edge_floor": subset_floor(a, b, ref, edge),
        "contact_floor": subset_floor(a, b, ref, contact),
        "bins": bins.tolist(),
        "levels": levels,
        "rows": [],
    }
    methods = [
        ("reference", args.edge_reference, ref.value),
        ("reference denoised", args.edge_reference, iz(clean_ref)),
    ]
    for n in samples:
        traced, s = our_bake(atlas, n, seed=0)
        clean_sh, _, d = denoise_ours(traced, denoiser)
        methods += [("raw", n, iz(traced.sh)), ("denoised", n, iz(clean_sh))]
    for label, n, x in methods:
        prof = profile(x, edge_d, profile_set, bins, levels)
        out["rows"].append(
            {
                "method": label,
                "samples": n,
                "edge": subset_errors(x, ref, edge, out["edge_floor"]),
                "contact": subset_errors(x, ref, contact, out["contact_floor"]),
                "width_10_90": edge_width(bins, prof),
                "profile": [None if not np.isfinite(p) else float(p) for p in prof],
            }
        )
    out["seconds"] = time.perf_counter() - t_fixture
    plot_edge(out)
    return out


def convex_hull(p: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull `(k, 2)` of 2-D points (monotone chain)."""
    pts = sorted(map(tuple, p))
    cross = lambda o, a, b: (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])  # noqa: E731
    lower, upper = [], []
    for q in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    for q in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def signed_distance(xy: np.ndarray, hull: np.ndarray, corner_margin: np.ndarray):
    """Signed distance (metres; negative inside) of points `(N, 2)` to a counter-clockwise convex
    polygon's outline, and whether the nearest outline point is at least `corner_margin` (N,)
    from the polygon's corners (there the distance is a 1-D profile across one straight edge)."""
    best = np.full(len(xy), np.inf)
    usable = np.zeros(len(xy), bool)
    inside = np.ones(len(xy), bool)
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        ab = b - a
        length = float(np.hypot(*ab))
        u = np.clip(((xy - a) @ ab) / (length * length), 0.0, 1.0)
        d = np.hypot(*(xy - (a + u[:, None] * ab)).T)
        closer = d < best
        best = np.where(closer, d, best)
        along = u * length
        usable = np.where(closer, (along >= corner_margin) & (length - along >= corner_margin), usable)
        inside &= (ab[0] * (xy[:, 1] - a[1]) - ab[1] * (xy[:, 0] - a[0])) >= 0.0
    return np.where(inside, -best, best), usable


def profile_levels(ref: np.ndarray, d: np.ndarray, subset: np.ndarray) -> dict:
    """The reference's mean I_z in shadow (3–6 texels inside the edge) and lit (3–6 outside)."""
    return {
        "shadow": float(ref[subset & (d <= -3.0)].mean()),
        "lit": float(ref[subset & (d >= 3.0)].mean()),
    }


def profile(x: np.ndarray, d: np.ndarray, subset: np.ndarray, bins: np.ndarray, levels: dict) -> np.ndarray:
    """Mean of `x` per bin of signed distance (texels) over `subset`, normalised so the reference's
    shadow level is 0 and its lit level 1."""
    idx = np.digitize(d[subset], bins) - 1
    n = len(bins) - 1
    sums = np.bincount(idx[(idx >= 0) & (idx < n)], x[subset][(idx >= 0) & (idx < n)], minlength=n)
    counts = np.bincount(idx[(idx >= 0) & (idx < n)], minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / counts
    return (mean - levels["shadow"]) / (levels["lit"] - levels["shadow"])


def edge_width(bins: np.ndarray, prof: np.ndarray) -> float | None:
    """Distance (texels) between the 10% and 90% crossings of a profile (bin centres; made
    monotone by a running maximum)."""
    centres = 0.5 * (bins[1:] + bins[:-1])
    ok = np.isfinite(prof)
    c, p = centres[ok], np.maximum.accumulate(prof[ok])
    if p.min() > 0.1 or p.max() < 0.9:
        return None
    crossing = lambda level: float(np.interp(level, p + np.arange(len(p)) * 1e-9, c))  # noqa: E731
    return crossing(0.9) - crossing(0.1)


def subset_floor(a: np.ndarray, b: np.ndarray, ref: Reference, subset: np.ndarray) -> float:
    return 100 * 0.5 * rms(((a - b) / ref.scale)[subset])


def subset_errors(x: np.ndarray, ref: Reference, subset: np.ndarray, floor: float) -> dict:
    """Over `subset`: mean signed relative error (%), RMS relative error (%) raw and without the
    reference's floor there, and the bias of the sum (%)."""
    e = (x - ref.value)[subset] / ref.scale[subset]
    r = 100 * rms(e)
    return {
        "mean": 100 * float(e.mean()),
        "rmse": r,
        "rmse_corrected": math.sqrt(max(r * r - floor**2, 0.0)),
        "bias": 100 * (float(x[subset].sum()) / float(ref.value[subset].sum()) - 1.0),
    }


# ---- output ---------------------------------------------------------------------------------
def print_rows(name, samples, raw, den, engine) -> None:
    print(
        f"[{name}] {engine:6s} {samples:5d} spp  raw {raw['seconds']:7.1f} s {raw['rmse']:6.2f}% "
        f"(→{raw['rmse_corrected']:6.2f}%) bias {raw['bias']:+6.2f}%  |  denoised {den['seconds']:7.1f} s "
        f"(denoise {den['denoise_seconds']:.1f} s) {den['rmse']:6.2f}% (→{den['rmse_corrected']:6.2f}%) "
        f"bias {den['bias']:+6.2f}%",
        flush=True,
    )


def fmt_time(t: dict) -> str:
    if t["seconds"] is None:
        return f"not reached (best {t['best']:.1f}%)" if "best" in t else "not reached"
    prefix = {"at most": "≤ ", "extrapolated": "~"}.get(t["how"], "")
    suffix = " (extrap.)" if t["how"] == "extrapolated" else ""
    return f"{prefix}{t['seconds']:.1f} s{suffix}"


def fmt_speedup(s: dict) -> str:
    if s["speedup"] is None:
        return "—"
    if s.get("bound") == "?":
        return "? (both below the level at their fewest samples)"
    extrapolated = " (extrap.)" if "extrapolated" in s["flags"] else ""
    return f"{s.get('bound') or ''}{s['speedup']:.2f}×{extrapolated}"


def print_scene(name: str, r: dict) -> None:
    print(f"\n{name}: time to error (floor-corrected I_z RMSE)")
    for level, tt in r["time_to_error"].items():
        times = ", ".join(f"{m} {fmt_time(t)}" for m, t in tt["times"].items())
        speed = "; ".join(f"{k} {fmt_speedup(v)}" for k, v in tt["speedups"].items())
        print(f"  {100 * float(level):g}%: {times}\n        {speed}")
    g = r["goal"]
    print(f"  goal (≥ 4× to 5%, |bias| ≤ 2%): {'MET' if g.get('met') else 'NOT met'} {g}")
    print(f"  denoise rate {r['denoise_rate']}\n", flush=True)


def print_edge(e: dict) -> None:
    print(f"\nshadow-edge fixture: {e['edge_texels']} edge texels, {e['contact_texels']} contact texels")
    for r in e["rows"]:
        w = "—" if r["width_10_90"] is None else f"{r['width_10_90']:.2f}"
        print(
            f"  {r['method']:18s} {r['samples']:5d} spp  edge mean {r['edge']['mean']:+6.2f}% RMS "
            f"{r['edge']['rmse']:6.2f}%  width {w} texels | contact mean {r['contact']['mean']:+6.2f}% "
            f"RMS {r['contact']['rmse']:6.2f}%",
            flush=True,
        )


def finish(results: dict) -> None:
    plot_errors(results)
    (RESULTS / "denoise.md").write_text(markdown(results))
    print(f"tables: {RESULTS / 'denoise.md'}", flush=True)


def row_cell(row: dict | None) -> str:
    if row is None:
        return ""
    d = f" ({row['denoise_seconds']:.1f})" if "denoise_seconds" in row else ""
    return f"{row['seconds']:.1f}{d} / {row['rmse']:.1f} → {row['rmse_corrected']:.1f} / {row['bias']:+.2f}"


def agreement_text(ag: dict) -> str:
    if "without_near_cover" not in ag:
        return ""
    nc, big, nb = ag["without_near_cover"], ag["over_50pct"], ag["without_over_50pct"]
    return (
        f"without the {ag['texels'] - nc['texels']} texels our bake points flag as near a coplanar cover: "
        f"ΣI_z ratio {nc['mean_ratio']:.4f}, RMSE {nc['rmse']:.2f}% ({nc['rmse_corrected']:.2f}%); "
        f"{big['texels']} texels differ by more than 50% and carry {100 * big['share']:.0f}% of the squared "
        f"difference, without them {nb['rmse']:.2f}% ({nb['rmse_corrected']:.2f}%). Cross-engine errors "
        f"(the \"vs our reference\" columns and the \"ours for all\" rows) leave the near-cover texels out."
    )


def markdown(results: dict) -> str:
    f = lambda v, p=1: "—" if v is None else f"{v:.{p}f}"  # noqa: E731
    out = [
        "# Denoising on real scenes (`bench/denoise.py`)",
        "",
        f"{results['bounces']} bounces in both engines; OIDN {results['oidn']['version']} "
        f"({results['oidn']['threads']} threads); load average at start / end "
        f"{results['load_average_start'][0]:.1f} / {results.get('load_average_end', [float('nan')])[0]:.1f}; "
        f"wall time {results.get('wall_seconds', float('nan')) / 60:.1f} min. Errors: relative RMSE of luminance I_z "
        "over fully covered, unburied texels (per texel over max(reference, 0.1 × its mean)), % — "
        "measured / with the reference's own noise removed in quadrature; bias = ΣI_z / Σreference − 1. "
        "Ours against our reference, Cycles against Cycles' (the other engine's reference in the JSON).",
        "",
    ]
    for name, r in results["scenes"].items():
        ref, cref, ag = r["reference"], r["cycles_reference"], r["agreement"]
        fr = r["filter_on_reference"]
        out += [
            f"## {name}",
            "",
            *([f"*{r['note']}*", ""] if r.get("note") else []),
            f"{r['triangles']} triangles; receivers {', '.join(r['receivers'])}; {r['resolution']}² atlas, "
            f"{r['texels']} texels ({r['buried_texels']} buried), {r['measured_texels']} measured. "
            f"Our reference {ref['samples']} spp ({ref['seconds']:.0f} s), its noise {ref['floor']:.2f}%; "
            f"Cycles' {cref['samples']} spp ({cref['seconds']:.0f} s), its noise {cref['floor']:.2f}%. "
            f"References: Cycles / ours ΣI_z = {ag['mean_ratio']:.4f}, RMSE {ag['rmse']:.2f}% "
            f"({ag['rmse_corrected']:.2f}% without both noises); {agreement_text(ag)} "
            f"The denoiser changes our reference itself by {fr['rmse']:.2f}% RMS (the reference's own noise: "
            f"{ref['floor']:.2f}%), bias {fr['bias']:+.2f}%.",
            "",
            "| spp | ours raw: s / err % / bias % | ours denoised: s (denoise s) / err % / bias % "
            "| Cycles raw: s / err % / bias % | Cycles denoised: s (denoise s) / err % / bias % "
            "| Cycles raw vs our reference: err % / bias % | Cycles denoised vs our reference "
            f"| {EXTRA}: s (denoise s) / err % / bias % |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        by = {m: {row["samples"]: row for row in r["rows"].get(m, [])} for m in (*METHODS, EXTRA)}
        for n in sorted(set().union(*[set(v) for v in by.values()])):
            cells = []
            for m in METHODS:
                cells.append(row_cell(by[m].get(n)))
            for m in ("Cycles raw", "Cycles denoised"):
                row = by[m].get(n)
                o = row and row["vs_other_reference"]
                cells.append("" if o is None else f"{o['rmse']:.1f} → {o['rmse_corrected']:.1f} / {o['bias']:+.2f}")
            cells.append(row_cell(by[EXTRA].get(n)))
            out.append(f"| {n} | " + " | ".join(cells) + " |")
        out += [
            "",
            "| references | error | ours raw | ours denoised | Cycles raw | Cycles denoised | ours denoised vs ours raw "
            f"| ours denoised vs Cycles denoised | ours raw vs Cycles raw | {EXTRA} |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for key, label in (("time_to_error", "own"), ("time_to_error_our_reference", "ours for all")):
            for level, tt in r[key].items():
                extra = fmt_time(tt["times"][EXTRA]) if EXTRA in tt["times"] else ""
                out.append(
                    f"| {label} | {100 * float(level):g}% | "
                    + " | ".join(fmt_time(tt["times"][m]) for m in METHODS)
                    + " | "
                    + " | ".join(fmt_speedup(v) for v in tt["speedups"].values())
                    + f" | {extra} |"
                )
        g, dr = r["goal"], r["denoise_rate"]
        out += [
            "",
            f"Goal (ours denoised ≥ 4× faster than ours raw to 5%, |bias| ≤ 2%): **{'met' if g.get('met') else 'not met'}** "
            f"(speed-up {g.get('bound') or ''}{f(g.get('speedup'), 2)}×{' ' + ', '.join(g.get('flags', [])) if g.get('flags') else ''}; "
            f"bias where 5% is reached {f(g.get('bias_where_reached'), 2)}%, worst |bias| of the denoised rows "
            f"{f(g.get('worst_abs_bias'), 2)}%). Denoiser: {dr['ours_charts']} charts in {dr['ours_pages']} pages "
            f"({dr['ours_page_texels']} page texels), {dr['ours_seconds']:.2f} s = "
            f"{dr['ours_s_per_mtexel_baked']:.1f} s per M baked texels, {dr['ours_s_per_mtexel_pages']:.1f} s per M page "
            f"texels; Cycles' whole-atlas denoise {f(dr['cycles_seconds'], 2)} s = "
            f"{dr['cycles_s_per_mtexel_atlas']:.1f} s per M atlas texels.",
            "",
        ]
    e = results.get("edge")
    if e:
        out += [
            "## Shadow edges and contact shadows",
            "",
            f"tests/test_bake_cycles.py's `floor` fixture (2 m floor, floating box, sun of zero angle) plus a box "
            f"resting on the floor and a dim sky; {results['bounces']} bounces, {e['texels']} texels. Reference "
            f"{e['reference']['samples']} spp, its noise {e['reference']['floor']:.2f}% overall, "
            f"{e['edge_floor']:.2f}% on the {e['edge_texels']} texels within 2 texels of the shadow edge, "
            f"{e['contact_floor']:.2f}% on the {e['contact_texels']} within 2 texels of the contact line. "
            "Errors relative to the reference (signed mean / RMS → without the reference's noise), %; "
            "10–90% width of the edge profile in texels.",
            "",
            "| method | spp | edge: mean / RMS % | edge 10–90% width | contact: mean / RMS % |",
            "| --- | --- | --- | --- | --- |",
        ]
        for row in e["rows"]:
            ed, co = row["edge"], row["contact"]
            out.append(
                f"| {row['method']} | {row['samples']} | {ed['mean']:+.2f} / {ed['rmse']:.2f} → {ed['rmse_corrected']:.2f} "
                f"| {f(row['width_10_90'], 2)} | {co['mean']:+.2f} / {co['rmse']:.2f} → {co['rmse_corrected']:.2f} |"
            )
        out.append("")
    return "\n".join(out)


def plot_errors(results: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    scenes = list(results["scenes"])
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.2 * len(scenes), 4.3), squeeze=False)
    style = {
        "ours raw": "C0o--",
        "ours denoised": "C0o-",
        "Cycles raw": "C3s--",
        "Cycles denoised": "C3s-",
        EXTRA: "C2^:",
    }
    for ax, name in zip(axes[0], scenes):
        r = results["scenes"][name]
        for m in (*METHODS, EXTRA):
            rows = sorted(r["rows"].get(m, []), key=lambda x: x["seconds"])
            ys = [max(x["rmse_corrected"], 0.1) for x in rows]
            ax.plot([x["seconds"] for x in rows], ys, style[m], ms=4, lw=1.0 if m == EXTRA else 1.5, label=m)
            for x, y in zip(rows if m != EXTRA else [], ys):
                ax.annotate(str(x["samples"]), (x["seconds"], y), fontsize=6, xytext=(2, 2), textcoords="offset points")
        for level in results["settings"]["levels"]:
            ax.axhline(100 * level, color="k", lw=0.6, alpha=0.4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(f"{name} ({r['texels']} texels)", fontsize=10)
        ax.set_xlabel("time incl. denoise (s)")
        ax.set_ylabel("relative I_z RMSE, reference noise removed (%)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "denoise_error.png", dpi=100)
    plt.close(fig)


def side_by_side(name: str, images: dict, points, samples: int) -> None:
    """raw | denoised | reference I_z, tone-mapped with one exposure, cropped to the window of
    the atlas with the most baked, lit, varied texels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhd_lightmapper.core import hhd

    baked = points.image(~points.buried, fill=False, dtype=bool)
    ref = images["reference"]
    lum = ref @ hhd.LUMINANCE
    exposure = 1.0 / np.percentile(lum[baked], 99)
    tone = lambda img: np.where(baked[..., None], np.clip(img * exposure, 0.0, 1.0) ** (1 / 2.2), 0.08)  # noqa: E731
    h, w = baked.shape
    win = min(h, w, 176)
    t_ref = tone(ref) @ hhd.LUMINANCE
    best, corner = -1.0, (0, 0)
    for y in range(0, h - win + 1, 16):
        for x in range(0, w - win + 1, 16):
            m = baked[y : y + win, x : x + win]
            if m.mean() < 0.5:
                continue
            v = t_ref[y : y + win, x : x + win][m]
            score = m.mean() * v.mean() * v.std()
            if score > best:
                best, corner = score, (y, x)
    y, x = corner
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4))
    titles = (f"ours raw, {samples} spp", f"ours denoised, {samples} spp", "reference (mean of two halves)")
    for ax, key, title in zip(axes, ("raw", "denoised", "reference"), titles):
        crop = tone(images[key])[y : y + win, x : x + win][::-1]  # rows bottom-up
        ax.imshow(crop, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.suptitle(f"{name}: I_z lightmap texels, atlas rows {y}–{y + win}, columns {x}–{x + win} (same exposure)")
    fig.tight_layout()
    fig.savefig(RESULTS / "denoise_side_by_side.png", dpi=110)
    plt.close(fig)


def plot_edge(e: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = np.array(e["bins"])
    centres = 0.5 * (bins[1:] + bins[:-1])
    fig, ax = plt.subplots(figsize=(6, 4))
    for row in e["rows"]:
        p = np.array([np.nan if v is None else v for v in row["profile"]])
        ls = "-" if "denoised" in row["method"] else "--"
        lw = 2.0 if row["method"] == "reference" else 1.0
        ax.plot(centres, p, ls, lw=lw, label=f"{row['method']} {row['samples']} spp")
    ax.axhline(0.1, color="k", lw=0.5, alpha=0.4)
    ax.axhline(0.9, color="k", lw=0.5, alpha=0.4)
    ax.set_xlabel("signed distance to the shadow edge (texels; < 0 in shadow)")
    ax.set_ylabel("I_z, shadow → lit level of the reference")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "denoise_edge.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
