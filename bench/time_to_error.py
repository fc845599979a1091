"""Time to equal error: our bake against Cycles' Diffuse bake, plus ray rates and memory.

    flock /tmp/bench.lock .venv/bin/python bench/time_to_error.py                  # the four scenes
    .venv/bin/python bench/time_to_error.py --scenes staircase2 bedroom [--resolution 512]

Scenes: `classroom` (of the external scenes, docs/conventions.md#external-scenes; 104k triangles,
OBJ; its environment map is not
shipped, so it is lit by a sun and a sky colour through the windows; receivers: the 6 largest room
meshes with few charts; the backdrop and furniture only occlude), `field` (a procedural
~1M-triangle field of spheres on a ground plane, sun + sky; receivers: the ground) (both
scenekit/scenes.py), and the two external interiors lit by emissive meshes,
`staircase2` (8 emitters) and `bedroom` (receivers as bench/denoise.py picks them: the largest
meshes by area that are not emitters or glass). On request (`--scenes`), two rooms like the
held-out ones of issue 23: `emissive-room` (scenekit's `emissive` scene: a ceiling light box and
a glow strip, no sky), `door-room` (a closed room lit only through a door gap by a sun and a
sky colour: nearly all indirect) and `area-lamp-room` (Blender area lights, two of them facing the
ceiling and a wall a few centimetres away) and `lamp-grid-room` (nine point, spot and area
lamps that all light most of the room). For each: (a) raw embreex closest-hit rays/s
(embreex's own TriangleMesh + run(); incoherent, 2 threads, median of 5, same run; and the same
for our binding of the same Embree library, core.embree), (b) our bake's rays/s (all rays, shadow
rays included) and texel-samples/s, (c) I_z error against a long Cycles Diffuse bake (Direct +
Indirect, Color off, BOUNCES bounces, sample clamps off, all cores) for our bake and Cycles at
increasing sample counts, and the time each needs to reach three error levels (log-log
interpolation; a bake shorter than REPEAT_BELOW seconds is timed REPEATS times and its median
kept, on both sides); our time counts the Embree scene, the bake points and the tracing (Cycles' counts
its whole bake operator); both are warm (Cycles by the reference bake, ours by loading the
compiled kernels first, which a Blender session does once).

Errors: relative RMSE of I_z's luminance over fully covered, unburied texels, relative to the
Cycles reference's mean. Each engine is measured against its own converged bake: two bakes of
half the reference samples each with other seeds than the rows'; their mean is the reference
and half their RMS difference is its own noise (the floor), which is removed from each row's
error in quadrature (sqrt(e² − floor²)), so levels near the reference's noise stay measurable
(the floor is printed; a level below ~the floor is not). Why its own: the two converged bakes
differ at a few geometric corner cases where Cycles' texel differs from ours (a texel whose
footprint a wall crosses, light off coincident faces: bench/leaks.py sets them aside by rule);
on staircase2 that difference is ~8% RMS, nearly all of it in 1% of the texels, so against
Cycles' reference neither engine's noise below ~8% could be seen. The difference itself is
reported ("systematic": RMS with both floors removed, mean ratio, share in the top 1%), and so
is our time to each level against Cycles' reference. `--uncrossed` compares only the texels
no geometry crosses (`BakePoints.crossed`): where a wall or a lamp's base crosses a texel we
average the part of it the bake point sees and Cycles the whole texel (bench/leaks.py), so
there the engines bake different quantities; next to an emitter those texels are also the
heaviest-tailed ones, which on `bedroom` swamp every other texel's error.
`--bounces` (both engines) and `--uniform-share` (our hemisphere mixture's α) are for
diagnosis; an entry run with them, or at another `--resolution`, is stored under the scene's
name with them in brackets, e.g. `door-room (256², 0 bounces, α 0.1)`.
Per-sample variance: at each sample count both engines ran, (corrected error)² × samples, ours
over Cycles' (< 1: our samples are worth more); time to error ≈ the texel-sample rate ratio over
that variance ratio. The peak RSS of this run is recorded; a 4096² atlas's peak memory is
bench/memory.py's job. Writes bench/results/time_to_error.json (and a per-scene entry is kept
from an earlier run when `--scenes` leaves it out).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
LAYER = "HHD_Lightmap"
BOUNCES = 3
SCENES = ("classroom", "field", "staircase2", "bedroom")
#: Sample counts both engines bake at by default (`--ours`, `--cycles`).
SAMPLES = [4, 8, 16, 32, 64, 256]
#: A bake shorter than this many seconds is repeated (up to REPEATS times in all) and its median
#: time kept, on both sides: single timings of 1–2 s bakes swing by tens of percent.
REPEAT_BELOW, REPEATS = 5.0, 5
#: Scenes measured on request (`--scenes`): rooms like the held-out ones issue 23 reports.
EXTRA_SCENES = ("emissive-room", "door-room", "area-lamp-room", "lamp-grid-room", "bulb-hall", "panel-room")
#: Cycles seeds of the reference's two halves (the rows use seed 0: Cycles' samples for one seed
#: are nested, so a row must not share its samples with the reference)
REFERENCE_SEEDS = (9173, 9174)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", choices=SCENES + EXTRA_SCENES, default=list(SCENES))
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=2, help="texels between charts (the classroom has ~2000 charts)")
    ap.add_argument("--reference-samples", type=int, default=2048, help="Cycles' reference, both halves together")
    # every octave up to 64: the levels fall between 4 and 64 samples on the sun-lit scenes, and a
    # set-up cost makes time against error bend, which log-log interpolation over 4x gaps overstates
    ap.add_argument("--ours", type=int, nargs="+", default=SAMPLES)
    ap.add_argument("--cycles", type=int, nargs="+", default=SAMPLES)
    ap.add_argument("--levels", type=float, nargs="+", default=[0.20, 0.10, 0.05])
    ap.add_argument(
        "--uncrossed",
        action="store_true",
        help="compare only texels no geometry crosses (BakePoints.crossed), stored as '<scene> (uncrossed)'",
    )
    ap.add_argument("--bounces", type=int, default=3, help="both engines' bounces (0: direct light only)")
    ap.add_argument(
        "--operators",
        action="store_true",
        help="time both engines as the artist does, from the click to the files: our Bake operator "
        "(denoise and seam stitching off) against Cycles' bake operator and the image saved as EXR; "
        "stored as '<scene> (operators)'",
    )
    ap.add_argument(
        "--uniform-share", type=float, default=None, help="our hemisphere mixture's α (hemisphere.UNIFORM_SHARE)"
    )
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper

    hhd_lightmapper.register()
    globals()["BOUNCES"] = args.bounces  # our_bake's and cycles_bake's
    variant = [f"{args.resolution}²"] if args.resolution != 512 else []
    variant += [f"{args.bounces} bounces"] if args.bounces != 3 else []
    if args.uniform_share is not None:
        from hhd_lightmapper.core.tracer import hemisphere

        hemisphere.UNIFORM_SHARE = args.uniform_share
        variant.append(f"α {args.uniform_share:g}")
    if args.uncrossed:
        variant.append("uncrossed")
    if args.operators:
        variant.append("operators")
        # the Bake operator's Samples property has a floor: a request below it would bake the floor
        floor = bpy.types.Scene.bl_rna.properties["hhd"].fixed_type.properties["samples"].hard_min
        if any(n < floor for n in args.ours):
            print(
                f"  ours: Samples is at least {floor} in the Bake operator; dropped {[n for n in args.ours if n < floor]}"
            )
            args.ours = [n for n in args.ours if n >= floor]
    out = RESULTS / "time_to_error.json"
    results = json.loads(out.read_text()) if out.exists() else {}
    # an entry without "floor" is from before the two-half reference (kept as it was measured)
    for name in args.scenes:
        receivers = load_scene(name)
        key = f"{name} ({', '.join(variant)})" if variant else name
        results[key] = measure(receivers, args)
        results[key]["load_average"] = os.getloadavg()
        print_table(key, results[key], args.levels)
        RESULTS.mkdir(exist_ok=True)
        out.write_text(json.dumps(results, indent=2))
    return 0


def load_scene(name: str) -> list:
    """The scene opened or built; its receivers."""
    from scenekit import scenes

    if name == "classroom":
        return scenes.classroom()
    if name == "field":
        return scenes.field()
    if name == "emissive-room":
        return scenes.emissive_room()
    if name == "door-room":
        return scenes.door_room()
    if name == "area-lamp-room":
        return scenes.area_lamp_room()
    if name == "lamp-grid-room":
        return scenes.lamp_grid_room()
    if name == "bulb-hall":
        return scenes.bulb_hall()
    if name == "panel-room":
        return scenes.panel_room()
    import denoise

    return denoise.load_scene(name)


# ---- measurement --------------------------------------------------------------------------
def unwrap(receivers: list, resolution: int, padding: int = 2) -> None:
    """The receivers selected and unwrapped with the Unwrap operator into one `resolution`² atlas
    on LAYER (the atlas at `resolution` even below the panel's 256: UVs are in [0, 1]²)."""
    import bpy

    from scenekit.blender import select

    scene = bpy.context.scene
    scene.hhd.uv_layer, scene.hhd.resolution, scene.hhd.texel_density = LAYER, resolution, 0.0
    scene.hhd.padding = padding
    select(receivers)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    for obj in receivers:
        obj.hhd.atlas_width = obj.hhd.atlas_height = resolution


def measure(receivers, args) -> dict:
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data
    from hhd_lightmapper.core import bakepoints, rays
    from hhd_lightmapper.core.colour import LUMINANCE

    unwrap(receivers, args.resolution, args.padding)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    surface = mesh_data.read_surface(receivers, LAYER, depsgraph)
    bake_scene = scene_data.read_bake_scene(depsgraph)
    ray_scene = rays.RayScene(bake_scene.triangles)
    points = bakepoints.build(surface, args.resolution, args.resolution, occluders=ray_scene)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    if args.uncrossed and points.crossed is not None:
        keep &= ~points.crossed
    out = {
        "compared_texels": int(keep.sum()),
        "triangles": int(len(bake_scene.triangles)),
        "texels": int(len(points.texel)),
        "raw_rays_per_s": raw_rate(EmbreexRays(bake_scene.triangles), bake_scene.triangles, dtype=np.float32),
        "raw_ours_rays_per_s": raw_rate(ray_scene, bake_scene.triangles),
    }
    warm_up(points, bake_scene, ray_scene)
    t = time.perf_counter()
    halves = [cycles_bake(receivers, points, args.reference_samples // 2, seed=s) @ LUMINANCE for s in REFERENCE_SEEDS]
    reference = 0.5 * (halves[0] + halves[1])
    mean = float(reference[keep].mean())
    floor = 0.5 * rmse(halves[0], halves[1], keep, mean)
    out["reference"] = {"samples": args.reference_samples, "seconds": time.perf_counter() - t, "mean_iz": mean}
    out["floor"] = floor
    print(f"  reference: Cycles {args.reference_samples} spp, its own noise (floor) {100 * floor:.2f}%", flush=True)
    t = time.perf_counter()
    own = [
        our_bake(surface, bake_scene, args.reference_samples // 2, points, seed=s)[0] @ LUMINANCE
        for s in REFERENCE_SEEDS
    ]
    own_reference = 0.5 * (own[0] + own[1])
    own_floor = 0.5 * rmse(own[0], own[1], keep, mean)
    out["own_reference"] = {"samples": args.reference_samples, "seconds": time.perf_counter() - t, "floor": own_floor}
    out["systematic"] = systematic(own_reference, reference, keep, mean, own_floor, floor)
    print(
        f"  our reference: {args.reference_samples} spp, floor {100 * own_floor:.2f}%; converged ours vs Cycles: "
        f"{100 * out['systematic']['rmse']:.2f}% RMS (noise removed), mean ratio {out['systematic']['mean_ratio']:.4f}, "
        f"{100 * out['systematic']['top_percent_share']:.0f}% of it in 1% of the texels",
        flush=True,
    )
    out["ours"], out["cycles"] = [], []
    ours = (
        functools.partial(operator_bake, receivers)
        if args.operators
        else functools.partial(our_bake, surface, bake_scene)
    )
    theirs = functools.partial(cycles_bake, save=args.operators)
    for samples in args.ours:
        iz, seconds, result = ours(samples, points)
        timings = repeated(seconds, lambda s=samples: ours(s, points)[1])
        iz = iz @ LUMINANCE
        out["ours"].append(
            {
                "samples": samples,
                "seconds": float(np.median(timings)),
                "timings": timings,
                "setup_seconds": result.setup_seconds,
                "rays_per_s": result.rays / result.seconds,
                "texel_samples_per_s": len(points.texel) * result.samples / result.seconds,
                **errors(iz, own_reference, keep, mean, own_floor),
                "against_cycles": errors(iz, reference, keep, mean, floor),
            }
        )
        print(
            f"  ours   {samples:5d} spp {out['ours'][-1]['seconds']:7.1f} s (scene + bake points {result.setup_seconds:.1f} s)  "
            f"RMSE {out['ours'][-1]['measured']:.4f} -> {out['ours'][-1]['rmse']:.4f} "
            f"(against Cycles' reference {out['ours'][-1]['against_cycles']['rmse']:.4f})",
            flush=True,
        )
    for samples in args.cycles:
        t = time.perf_counter()
        iz = theirs(receivers, points, samples)
        timings = repeated(time.perf_counter() - t, lambda s=samples: timed(theirs, receivers, points, s))
        seconds = float(np.median(timings))
        out["cycles"].append(
            {
                "samples": samples,
                "seconds": seconds,
                "timings": timings,
                **errors(iz @ LUMINANCE, reference, keep, mean, floor),
                "texel_samples_per_s": len(points.texel) * samples / seconds,
            }
        )
        print(
            f"  cycles {samples:5d} spp {seconds:7.1f} s  RMSE {out['cycles'][-1]['measured']:.4f} -> "
            f"{out['cycles'][-1]['rmse']:.4f}",
            flush=True,
        )
    against_cycles = [{**r, **r["against_cycles"]} for r in out["ours"]]
    out["time_to_error"] = {
        f"{level:g}": {
            "ours": time_at(out["ours"], level),
            "cycles": time_at(out["cycles"], level),
            "ours_against_cycles_reference": time_at(against_cycles, level),
        }
        for level in args.levels
    }
    out["variance_per_sample"] = variance_ratios(out["ours"], out["cycles"])
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def repeated(first: float, again) -> list[float]:
    """Seconds of a bake timed `first`, and of repeats (`again()` → seconds) while it is shorter
    than REPEAT_BELOW, REPEATS in all: the row's time is their median. The same seed each time,
    so the errors are the first bake's."""
    timings = [first]
    while first < REPEAT_BELOW and len(timings) < REPEATS:
        timings.append(again())
    return timings


def timed(fn, *args) -> float:
    t = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t


def warm_up(points, bake_scene, ray_scene) -> None:
    """Load (or, after an edit, compile) our compiled kernels before anything is timed, as the
    long reference bake warms Cycles up: a Blender session pays this once (~0.8 s)."""
    from hhd_lightmapper.core import tracer

    few = np.arange(min(64, len(points.texel)))
    tracer.texel_estimator(points, bake_scene, tracer.BakeSettings(pass_samples=4), ray_scene).trace(
        tracer.WorkUnit(0, 0, 0, few)
    )


class EmbreexRays:
    """embreex's own API on the same triangles (the issue's "raw embreex"): `TriangleMesh`
    copies them into Embree, `run()` traces a float32 batch."""

    def __init__(self, tris):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcore_scene.EmbreeScene()
        self.mesh = TriangleMesh(self.scene, np.ascontiguousarray(tris, dtype=np.float32))

    def intersect(self, origins, directions):
        return self.scene.run(origins, directions, output=True)


def raw_rate(ray_scene, tris, batch=1_000_000, rounds=5, dtype=np.float64) -> float:
    """Closest-hit rays/s of a ray scene alone on 2 threads: random origins in the scene's box,
    random directions (`dtype`, converted before timing), 1M rays per call; the median of
    `rounds` timings of 2 calls per thread (one timing swings from 8 to 14 M/s on the classroom
    on this machine)."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(0)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    batches = []
    for _ in range(4):
        d = rng.normal(size=(batch, 3))
        batches.append(
            (
                rng.uniform(lo, hi, (batch, 3)).astype(dtype),
                (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(dtype),
            )
        )
    ray_scene.intersect(*[a[:10] for a in batches[0]])  # builds a lazy BVH untimed
    rates = []
    with ThreadPoolExecutor(2) as pool:
        for _ in range(rounds):
            t = time.perf_counter()
            list(pool.map(lambda od: ray_scene.intersect(*od), batches))
            rates.append(len(batches) * batch / (time.perf_counter() - t))
    return float(np.median(rates))


def our_bake(surface, bake_scene, samples, points_before, seed=0):
    """Everything our Bake button does after reading the scene, except writing files: the Embree
    scene, the bake points (rasterisation, buried and cover probes) and the tracing, timed
    together, as Cycles' time includes its scene sync, BVH and texel setup. Returns (I_z,
    seconds, tracer result)."""
    from hhd_lightmapper.core import bake, hhd, tracer

    t = time.perf_counter()
    settings = tracer.BakeSettings.from_samples(samples, bounces=BOUNCES, seed=seed)
    result = bake.trace_surface(surface, points_before.width, points_before.height, bake_scene, settings)
    points = result.points
    iz = hhd.irradz(result.sh, points.normal)
    seconds = time.perf_counter() - t
    assert np.array_equal(points.texel, points_before.texel)
    result.setup_seconds = seconds - result.seconds  # Embree scene + bake points
    return iz, seconds, result


class OperatorResult:
    """What `operator_bake` knows of the bake it timed: the sidecar's tracer figures."""

    def __init__(self, sidecar: dict, seconds: float):
        self.rays, self.samples = sidecar["bake"]["rays"], sidecar["bake"]["mean_samples_per_texel"]
        self.seconds = sidecar["timings_seconds"].get("trace", seconds)
        self.setup_seconds = seconds - self.seconds


def operator_bake(receivers, samples, points, seed=0):
    """Our Bake operator from the click to the files (scene read, Embree scene, bake points,
    trace, encoding, EXR writes, preview images; denoise and stitching off, as Cycles' raw bake),
    with the bake's own sample count and BOUNCES: (I_z (P, 3) read back from the HHD file at the
    bake points' texels, seconds, OperatorResult)."""
    import bpy

    from hhd_lightmapper.core.files import exr
    from scenekit.blender import select

    folder = Path(tempfile.mkdtemp(prefix="hhd-tte-"))
    s = bpy.context.scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.noise_target = samples, BOUNCES, seed, 0.0
    s.denoise, s.stitch_seams, s.output_dir = False, False, str(folder)
    select(receivers)
    t = time.perf_counter()
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    seconds = time.perf_counter() - t
    channels, _ = exr.read(folder / "Lightmap_hhd.exr")
    iz = np.stack([channels[f"Iz.{c}"] for c in "RGB"], axis=-1)[::-1]  # EXR rows top-down, texels bottom-up
    iz = iz.reshape(-1, 3).astype(np.float64)
    result = OperatorResult(json.loads((folder / "Lightmap.json").read_text()), seconds)
    shutil.rmtree(folder)
    return iz[points.texel], seconds, result


def cycles_bake(receivers, points, samples, seed=0, save=False) -> np.ndarray:
    """Cycles' Diffuse bake (Direct + Indirect, Color off, sample clamps off) of the same texels, I_z (P, 3). The
    reference uses another seed: Cycles' samples for one seed are nested, so a low-sample bake
    would otherwise share its first samples with the reference and look better than it is."""
    import bpy

    from scenekit.blender import select

    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.render.threads_mode = 'AUTO'  # all cores, as ours
    scene.cycles.device, scene.cycles.samples, scene.cycles.seed = 'CPU', samples, seed
    scene.cycles.use_denoising = scene.cycles.use_adaptive_sampling = False
    # unbiased: Cycles' default indirect clamp (10) darkens indirect-lit rooms by up to ~19%
    scene.cycles.sample_clamp_direct = scene.cycles.sample_clamp_indirect = 0.0
    scene.cycles.max_bounces = scene.cycles.diffuse_bounces = BOUNCES
    scene.cycles.glossy_bounces = scene.cycles.transmission_bounces = 0
    w, h = points.width, points.height
    image = bpy.data.images.get("bench_bake") or bpy.data.images.new("bench_bake", w, h, float_buffer=True)
    for obj in receivers:
        for mat in obj.data.materials:
            node = mat.node_tree.nodes.get("bench_target") or mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.name, node.image = "bench_target", image
            mat.node_tree.nodes.active = node
    select(receivers)
    bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT'}, margin=0, use_clear=True, uv_layer=LAYER)
    px = np.array(image.pixels[:], dtype=np.float64).reshape(w * h, 4)[:, :3]
    if save:  # to a file, as the artist's bake ends; the next bake makes a new image
        path = Path(tempfile.mkdtemp(prefix="hhd-tte-cycles-")) / "bake.exr"
        image.filepath_raw, image.file_format = str(path), 'OPEN_EXR'
        image.save()
        bpy.data.images.remove(image)
        shutil.rmtree(path.parent)
    return px[points.texel]


def rmse(iz, reference, keep, mean) -> float:
    """Relative RMSE of `iz` (P,) against `reference` (P,) over `keep`, relative to `mean`."""
    return float(np.sqrt(np.mean((iz[keep] - reference[keep]) ** 2)) / mean)


def errors(iz, reference, keep, mean, floor) -> dict:
    """A row's error: `measured` (relative RMSE), `rmse` (the reference's floor removed in
    quadrature: what time_at interpolates) and `bias` (ΣI_z / Σ reference − 1)."""
    e = rmse(iz, reference, keep, mean)
    return {
        "measured": e,
        "rmse": float(np.sqrt(max(e * e - floor * floor, 0.0))),
        "bias": float(iz[keep].sum() / reference[keep].sum() - 1.0),
    }


def systematic(ours, cycles, keep, mean, own_floor, floor) -> dict:
    """How our converged bake differs from Cycles' (both references, (P,) I_z luminance): the
    relative RMS difference with both references' noise removed in quadrature, the mean ratio,
    and the share of the squared difference carried by the 1% of texels that differ most."""
    e = rmse(ours, cycles, keep, mean)
    excess = np.sort((ours[keep] - cycles[keep]) ** 2)[::-1]
    top = excess[: max(1, len(excess) // 100)].sum() / max(excess.sum(), 1e-300)
    return {
        "measured": e,
        "rmse": float(np.sqrt(max(e * e - floor * floor - own_floor * own_floor, 0.0))),
        "mean_ratio": float(ours[keep].sum() / cycles[keep].sum()),
        "top_percent_share": float(top),
    }


def variance_ratios(ours: list[dict], cycles: list[dict]) -> dict:
    """Per sample count both ran: our per-sample I_z variance (corrected error² × samples) over
    Cycles', and our texel-sample rate over Cycles'."""
    theirs = {r["samples"]: r for r in cycles}
    out = {}
    for r in ours:
        c = theirs.get(r["samples"])
        if c and c["rmse"] > 0:
            out[str(r["samples"])] = {
                "variance": (r["rmse"] / c["rmse"]) ** 2,
                "rate": r["texel_samples_per_s"] / c["texel_samples_per_s"],
            }
    return out


def time_at(rows, level):
    """Seconds to reach relative RMSE `level`, interpolated in log-log; None if never reached."""
    pts = sorted((r["rmse"], r["seconds"]) for r in rows)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:]):
        if e0 <= level <= e1:
            f = np.log(level / e1) / np.log(e0 / e1) if e0 != e1 else 0.0
            return float(np.exp(np.log(t1) + f * (np.log(t0) - np.log(t1))))
    return None


def print_table(name, r, levels):
    ours = r["ours"][-1]
    print(
        f"\n{name}: {r['triangles']} triangles, {r['texels']} texels; raw embreex {r['raw_rays_per_s'] / 1e6:.1f} M rays/s "
        f"(our binding alone {r['raw_ours_rays_per_s'] / 1e6:.1f}); "
        f"our bake {ours['rays_per_s'] / 1e6:.2f} M rays/s ({100 * ours['rays_per_s'] / r['raw_rays_per_s']:.0f}% of raw), "
        f"{ours['texel_samples_per_s'] / 1e6:.2f} M texel-samples/s; reference: Cycles {r['reference']['samples']} spp"
    )
    print(f"  reference noise (floor) {100 * r['floor']:.2f}%, load average {r.get('load_average')}")
    for spp, v in r["variance_per_sample"].items():
        print(
            f"  {spp:>5s} spp: per-sample variance ours / Cycles {v['variance']:.2f}, texel-sample rate {v['rate']:.2f}"
        )
    if "systematic" in r:
        sy = r["systematic"]
        print(
            f"  converged ours vs converged Cycles: {100 * sy['rmse']:.2f}% RMS, mean ratio {sy['mean_ratio']:.4f}, "
            f"{100 * sy['top_percent_share']:.0f}% of it in 1% of the texels (each engine's errors below: against its own reference)"
        )
    print(f"{'I_z RMSE':>10s} {'ours (s)':>10s} {'Cycles (s)':>11s} {'ratio':>7s} {'ours vs Cycles ref (s)':>23s}")
    for level in levels:
        row = r["time_to_error"][f"{level:g}"]
        o, c, x = row["ours"], row["cycles"], row.get("ours_against_cycles_reference")
        ratio = f"{c / o:.2f}×" if o and c else "—"
        print(
            f"{level:10.0%} {o if o is None else round(o, 1)!s:>10s} {c if c is None else round(c, 1)!s:>11s} "
            f"{ratio:>7s} {x if x is None else round(x, 1)!s:>23s}"
        )


if __name__ == "__main__":
    sys.exit(main())
