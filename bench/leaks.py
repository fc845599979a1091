"""Leak audit: texels that receive light they should not, before and after the leak fixes, against
Cycles' Diffuse bake of the same texels.

    flock /tmp/bench.lock .venv/bin/python bench/leaks.py           # everything (≈ 10 min on 2 cores)
    .venv/bin/python bench/leaks.py --quick                          # 256² scenes, few samples
    .venv/bin/python bench/leaks.py --fixtures thin_wall_rooms --scenes

"Before" is the bake with `bakepoints.SETTLE` off (the bake points and their samples as they
were: a texel averages its whole footprint, both sides of a wall standing on it included, and
samples starting under a coplanar face receive nothing); "after" the default. Both are judged
as the files hold them: buried (invalid) texels filled as the encoder fills them.

Fixtures (scenekit/leak_fixtures.py, built here in Blender so Cycles bakes them too): a wall
through a floor, a box resting on a floor, a 5 mm wall between a sunlit and a closed dark room,
a 5 mm table top. One sun of zero angle, no world: each judged texel has an exact answer (0 in
shadow or in the dark room, fully lit S·cosθ/π; texels a shadow edge of the fixture's own
crosses, and those hidden under geometry whose visible neighbours disagree, are not judged). A
texel leaks light when it exceeds its answer by more than 1e-3 of the fully lit value; it is a
dark halo when it falls short by as much. The same rule judges Cycles' bake.

Scenes (`bedroom`, `staircase2` of ../shared/scenes and the classroom, loaded and unwrapped as
bench/denoise.py does, BOUNCES diffuse bounces): no exact answer, so ours is judged against
Cycles. Each engine bakes twice (seeds 1, 2); per texel the mean of the two and its standard
error, |a − b|/2, floored at the median relative standard error of the POOL × POOL texels
around it × the texel's level (a one-degree-of-freedom estimate is often near 0 by chance). A texel *leaks* when ours exceeds
Cycles by more than K standard errors (both combined) AND by more than X of the local level,
max(Cycles, FLOOR × Cycles' mean); it is *darker* when Cycles exceeds ours by as much. Compared:
fully covered texels that are valid (not buried) in both of our bakes and that Cycles wrote.
Cycles averages a texel's whole footprint (Blender ≥ 5.2.1), so where a wall stands on a texel
it mixes both sides: where ours is darker there, it is usually Cycles that leaks (see the
fixtures, where the truth is known).

Writes bench/results/leaks.json and leaks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
LAYER = "HHD_Lightmap"
BOUNCES = 3
SCENES = ("classroom", "staircase2", "bedroom")
K = 5.0  # standard errors
X = 0.25  # of the local level
FLOOR = 0.1  # × Cycles' mean: the local level of near-black texels
POOL = 5  # texels: the window whose median relative error floors a texel's own
SEEDS = (1, 2)
#: per-texel arrays of each scene's audit, for diagnosis (not a result)
ARRAYS = Path(tempfile.gettempdir()) / "hhd-bench-leaks-arrays"
FINE = 4  # Cycles' resolution for the visible part of texels a wall crosses, × the atlas's


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fixtures", nargs="*", default=None, help="default: all")
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--resolution", type=int, default=512, help="the scenes' atlas (fixtures: 256)")
    ap.add_argument("--samples", type=int, default=128, help="ours, per seed")
    ap.add_argument("--cycles-samples", type=int, default=128, help="Cycles, per seed")
    ap.add_argument("--fixture-samples", type=int, default=64)
    ap.add_argument("--quick", action="store_true", help="256² scenes, 32 samples")
    ap.add_argument(
        "--out", type=Path, default=None, help="results folder (default bench/results; --quick: a temporary one)"
    )
    args = ap.parse_args()
    if args.quick:
        args.resolution, args.samples, args.cycles_samples, args.fixture_samples = 256, 32, 32, 16
        args.out = args.out or Path(tempfile.mkdtemp(prefix="hhd-bench-leaks-"))
    out = args.out or RESULTS
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    sys.path[:0] = [str(ROOT), str(ROOT / "bench")]  # scenekit; denoise (the scenes' loading)
    import bpy  # noqa: F401

    import hhd_lightmapper
    from scenekit import leak_fixtures

    hhd_lightmapper.register()
    names = list(leak_fixtures.fixtures()) if args.fixtures is None else args.fixtures
    t0 = time.perf_counter()
    results = {"settings": {k: str(v) for k, v in vars(args).items()}, "rule": rule(), "fixtures": {}, "scenes": {}}
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        results["fixtures"][name] = audit_fixture(leak_fixtures.fixtures()[name], args.fixture_samples)
        print(name, json.dumps(results["fixtures"][name]), flush=True)
        (out / "leaks.json").write_text(json.dumps(results, indent=2))
    for name in args.scenes:
        results["scenes"][name] = audit_scene(name, args)
        print(name, json.dumps(results["scenes"][name]), flush=True)
        (out / "leaks.json").write_text(json.dumps(results, indent=2))
    results["wall_seconds"] = time.perf_counter() - t0
    (out / "leaks.json").write_text(json.dumps(results, indent=2))
    (out / "leaks.md").write_text(markdown(results))
    print(f"results in {out}", flush=True)
    return 0


def rule() -> dict:
    return {"K": K, "X": X, "FLOOR": FLOOR, "bounces": BOUNCES, "seeds": list(SEEDS)}


# ---- fixtures --------------------------------------------------------------------------------
def build_fixture(fixture) -> list:
    """The fixture in Blender (test scene settings, 256² shared atlas): its receivers, unwrapped."""
    import bpy

    from scenekit import blender as kit
    from scenekit import leak_fixtures

    kit.clear_scene()
    grey = kit.material("Grey", (leak_fixtures.ALBEDO,) * 3)
    receivers = []
    for part in fixture.parts:
        v, f = part.mesh()
        mesh = bpy.data.meshes.new(part.name)
        mesh.from_pydata(v.tolist(), [], f.tolist())
        mesh.materials.append(grey)
        obj = bpy.data.objects.new(part.name, mesh)
        bpy.context.scene.collection.objects.link(obj)
        if part.receiver:
            receivers.append(obj)
    elevation, azimuth, strength = fixture.sun
    kit.sun(elevation, azimuth, strength, 0.0)
    kit.unwrap(receivers)
    return receivers


def audit_fixture(fixture, samples: int) -> dict:
    """Ours before and after, Cycles: leak and dark-halo counts against the exact answer."""
    from scenekit import leak_fixtures as lf
    from scenekit.blender import RES

    receivers = build_fixture(fixture)
    out = {"what": fixture.what, "bounces": fixture.bounces, "samples": samples, "resolution": RES}
    for state in ("before", "after"):
        t = time.perf_counter()
        traced, surface_scene = our_bake(receivers, RES, samples, fixture.bounces, seed=1, settle=state == "after")
        points = traced.points
        iz = lf.filled(points, luminance(traced))
        truth = lf.expected(fixture, points)
        full = fixture.full(points.face_normal)
        out[state] = lf.judge(iz, truth, full) | {
            "buried": int(points.buried.sum()),
            "crossed": int(points.crossed.sum()) if points.crossed is not None else 0,
            "seconds": time.perf_counter() - t,
        }
    image = cycles_bake(receivers, RES, samples, fixture.bounces, seed=1)
    cyc = (image.reshape(-1, 3) @ LUMINANCE)[points.texel]
    out["cycles"] = lf.judge(cyc, truth, full)
    return out


# ---- the shared scenes -----------------------------------------------------------------------
def audit_scene(name: str, args) -> dict:
    import denoise

    denoise.BOUNCES = BOUNCES
    receivers = denoise.load_scene(name)
    atlas = denoise.Atlas(receivers, args.resolution, 2)
    ours = {}
    for state in ("before", "after"):
        runs = []
        for seed in SEEDS:
            traced, _ = our_bake(atlas, args.resolution, args.samples, BOUNCES, seed, settle=state == "after")
            runs.append(traced)
        ours[state] = runs
    points = ours["after"][0].points
    images = [cycles_bake(atlas.receivers, args.resolution, args.cycles_samples, BOUNCES, seed) for seed in SEEDS]
    written = np.all([(im.reshape(-1, 3)[points.texel] >= 0).all(axis=1) for im in images], axis=0)
    cyc = [(im.reshape(-1, 3) @ LUMINANCE)[points.texel] for im in images]
    keep = (points.coverage >= 1.0 - 1e-9) & written
    for runs in ours.values():
        keep &= ~runs[0].points.buried
    fine = visible_parts(atlas, points, args)
    crossed = points.crossed & fine["found"]
    keep &= ~points.crossed | crossed
    whole = mean_and_error(*cyc, keep, points)
    cyc = [np.where(crossed, part, c) for part, c in zip(fine["values"], cyc)]
    c_mean, c_se = mean_and_error(*cyc, keep, points)
    out = {
        "receivers": [o.name for o in atlas.receivers],
        "resolution": args.resolution,
        "texels": int(len(points.texel)),
        "compared": int(keep.sum()),
        "samples": args.samples,
        "cycles_samples": args.cycles_samples,
        "cycles_mean": float(c_mean[keep].mean()),
        "crossed_compared": int((keep & crossed).sum()),
        "fine_resolution": fine["resolution"],
        "fine_cycles_samples": fine["samples"],
        "cycles_whole_footprint": compare(*whole, c_mean, c_se, keep, crossed),
    }
    arrays = {"keep": keep, "crossed": crossed, "cycles": c_mean, "cycles_se": c_se, "cycles_whole": whole[0]}
    arrays |= {"position": points.position, "near_cover": points.near_cover, "object": points.object_index}
    for state, runs in ours.items():
        o = [luminance(r) for r in runs]
        o_mean, o_se = mean_and_error(*o, keep, points)
        arrays |= {state: o_mean, f"{state}_se": o_se, f"{state}_position": runs[0].points.position}
        out[state] = compare(o_mean, o_se, c_mean, c_se, keep, crossed) | {
            "buried": int(runs[0].points.buried.sum()),
            "crossed": int(runs[0].points.crossed.sum()) if runs[0].points.crossed is not None else 0,
            "near_cover": int(runs[0].points.near_cover.sum()),
            "seconds": float(np.mean([r.seconds for r in runs])),
        }
    ARRAYS.mkdir(exist_ok=True)
    np.savez_compressed(ARRAYS / f"{name}.npz", **arrays)
    return out


def visible_parts(atlas, points, args) -> dict:
    """Cycles' answer for the part of each texel its bake point sees: Cycles bakes the same UVs
    at FINE × the resolution, and a texel's value is the mean of the fine texels in its block
    whose centres the bake point (after settling) sees (a segment test against the scene).
    Returns values [(P,) per seed] (NaN where none is seen), found (P,) bool, and the settings."""
    from hhd_lightmapper.core import bakepoints
    from hhd_lightmapper.core.rays import RayScene

    n = min(FINE * args.resolution, 2048)
    scale = n // args.resolution
    samples = max(args.cycles_samples // scale, 4)
    fine = bakepoints.build(atlas.surface, n, n)
    coarse = ((fine.texel // n) // scale) * args.resolution + (fine.texel % n) // scale
    where = np.full(args.resolution**2, -1)
    where[points.texel] = np.arange(len(points.texel))
    owner = where[coarse]
    rows = np.flatnonzero((owner >= 0) & points.crossed[np.maximum(owner, 0)])
    anchor = points.origins(owner[rows])
    ray = fine.position[rows] + fine.face_normal[rows] * points.offset - anchor
    length = np.linalg.norm(ray, axis=1)
    seen = ~RayScene(atlas.bake_scene.triangles).occluded(anchor, ray / np.maximum(length, 1e-300)[:, None], length)
    values = []
    for seed in SEEDS:
        image = cycles_bake(atlas.receivers, n, samples, BOUNCES, seed)
        value = image[fine.texel[rows]] @ LUMINANCE
        ok = seen & (image[fine.texel[rows]] >= 0).all(axis=1)
        total = np.bincount(owner[rows], weights=np.where(ok, value, 0.0), minlength=len(points.texel))
        count = np.bincount(owner[rows], weights=ok.astype(float), minlength=len(points.texel))
        values.append(np.where(count > 0, total / np.maximum(count, 1), np.nan))
    return {
        "values": values,
        "found": np.isfinite(values[0]) & np.isfinite(values[1]),
        "resolution": n,
        "samples": samples,
    }


def mean_and_error(a: np.ndarray, b: np.ndarray, keep: np.ndarray, points) -> tuple[np.ndarray, np.ndarray]:
    """Per texel the mean of two runs and its standard error: |a − b|/2 (one degree of freedom:
    often near 0 by chance), floored at the median relative error of the compared texels in the
    POOL × POOL texels around it × max(mean, FLOOR × the mean over `keep`)."""
    mean = 0.5 * (a + b)
    level = np.maximum(mean, FLOOR * mean[keep].mean())
    se = 0.5 * np.abs(a - b)
    relative = points.image(np.where(keep, se / level, np.nan), fill=np.nan)
    r = POOL // 2
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(relative, r, constant_values=np.nan), (POOL, POOL))
    with warnings.catch_warnings():  # all-NaN windows (outside the compared texels)
        warnings.simplefilter("ignore", RuntimeWarning)
        pooled = np.nanmedian(windows.reshape(relative.shape + (-1,)), axis=-1).reshape(-1)[points.texel]
    pooled = np.where(np.isfinite(pooled), pooled, np.median((se / level)[keep]))
    return mean, np.maximum(se, pooled * level)


def compare(o, o_se, c, c_se, keep, crossed) -> dict:
    """Texels where ours exceeds Cycles (leaks) or falls short of it (darker) by more than K
    combined standard errors and X of the local level; also counted among the `crossed` ones."""
    level = np.maximum(c, FLOOR * c[keep].mean())
    sigma = np.hypot(o_se, c_se)
    excess = o - c
    leak = keep & (excess > K * sigma) & (excess > X * level)
    dark = keep & (-excess > K * sigma) & (-excess > X * level)
    return {
        "leaking": int(leak.sum()),
        "darker": int(dark.sum()),
        "leaking_crossed": int((leak & crossed).sum()),
        "darker_crossed": int((dark & crossed).sum()),
        "ratio_sum": float(o[keep].sum() / c[keep].sum()),
        "leak_excess_share": float(excess[leak].sum() / c[keep].sum()),
    }


# ---- the two engines -------------------------------------------------------------------------
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def luminance(traced) -> np.ndarray:
    from hhd_lightmapper.core import hhd

    return hhd.irradz(traced.sh, traced.points.normal) @ LUMINANCE


def our_bake(receivers_or_atlas, size: int, samples: int, bounces: int, seed: int, settle: bool):
    """Our bake (stages 1–2) with `bakepoints.SETTLE` as given. Returns (TracedAtlas, seconds)."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data
    from hhd_lightmapper.core import bake, bakepoints, tracer

    if isinstance(receivers_or_atlas, list):
        depsgraph = bpy.context.evaluated_depsgraph_get()
        surface = mesh_data.read_surface(receivers_or_atlas, LAYER, depsgraph)
        scene = scene_data.read_bake_scene(depsgraph)
    else:
        surface, scene = receivers_or_atlas.surface, receivers_or_atlas.bake_scene
    settings = tracer.BakeSettings(samples=samples, pass_samples=min(16, samples), bounces=bounces, seed=seed)
    old = bakepoints.SETTLE
    bakepoints.SETTLE = settle
    try:
        t = time.perf_counter()
        traced = bake.trace_surface(surface, size, size, scene, settings)
        return traced, time.perf_counter() - t
    finally:
        bakepoints.SETTLE = old


def cycles_bake(receivers, size: int, samples: int, bounces: int, seed: int) -> np.ndarray:
    """Cycles' Diffuse bake (Direct + Indirect, Color off, sample clamps off, no adaptive
    sampling or denoising) into a float image first set to -1: (size², 3) rows bottom-up."""
    import bpy

    from scenekit.blender import select

    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device, c.use_denoising, c.use_adaptive_sampling = 'CPU', False, False
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.max_bounces = c.diffuse_bounces = bounces
    c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0
    c.samples, c.seed = samples, seed
    name = f"leak_audit_{size}"
    image = bpy.data.images.get(name) or bpy.data.images.new(name, size, size, float_buffer=True)
    for obj in receivers:
        for mat in obj.data.materials:
            node = mat.node_tree.nodes.get("leak_target") or mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.name, node.image = "leak_target", image
            mat.node_tree.nodes.active = node
    select(receivers)
    image.pixels.foreach_set(np.full(size * size * 4, -1.0, np.float32))
    bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT'}, margin=0, use_clear=False, uv_layer=LAYER)
    px = np.empty(size * size * 4, np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(size * size, 4)[:, :3].astype(np.float64)


# ---- the report ------------------------------------------------------------------------------
def markdown(results: dict) -> str:
    lines = ["# Leak audit (`bench/leaks.py`)", ""]
    lines += [
        "Before: bake points and samples as they were (`bakepoints.SETTLE` off); after: the default "
        "(bake points moved out of solids, samples hidden from the bake point replaced, texels whose "
        "bake point stays under a coplanar face invalid, invalid texels filled from their own chart). "
        "Rules: the module docstring of bench/leaks.py.",
        "",
        "## Fixtures (exact answers)",
        "",
        "| fixture | judged (should be 0) | ours before: leaking / dark halo | ours after: leaking / dark halo | Cycles: leaking / dark halo |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, r in results["fixtures"].items():
        b, a, c = r["before"], r["after"], r["cycles"]
        lines.append(
            f"| {name} | {a['judged']} ({a['zero']}) | {b['light']} / {b['dark']} | {a['light']} / {a['dark']} "
            f"| {c['light']} / {c['dark']} |"
        )
    lines += ["", *[f"- {name}: {r['what']}." for name, r in results["fixtures"].items()], ""]
    if results["scenes"]:
        rule = results["rule"]
        lines += [
            "## Shared scenes (against Cycles)",
            "",
            f"A texel leaks when ours exceeds Cycles by > {rule['K']:g} combined standard errors and > "
            f"{rule['X']:.0%} of max(Cycles, {rule['FLOOR']:g} × Cycles' mean); darker: the reverse. "
            f"{rule['bounces']} bounces, two seeds per engine.",
            "",
            "Where geometry crosses a texel (`crossed`), the reference is Cycles' bake at "
            f"{FINE}× the resolution averaged over the fine texels the bake point sees (the visible "
            "part); elsewhere Cycles' own texel. The last column judges Cycles' own texels (its whole "
            "footprint) by the same rule.",
            "",
            "Counts: all compared texels (in brackets: the crossed ones among them).",
            "",
            "| scene | atlas, texels compared (crossed) | spp ours / Cycles | before: leaking / darker, ΣI ratio | after: leaking / darker, ΣI ratio | buried before → after | Cycles' texels: leaking / darker |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for name, r in results["scenes"].items():
            b, a = r["before"], r["after"]
            w = r["cycles_whole_footprint"]
            lines.append(
                f"| {name} | {r['resolution']}², {r['compared']} ({r['crossed_compared']}) | {r['samples']} / "
                f"{r['cycles_samples']} | {counts(b)}, {b['ratio_sum']:.4f} | {counts(a)}, {a['ratio_sum']:.4f} "
                f"| {b['buried']} → {a['buried']} | {counts(w)} |"
            )
    if "wall_seconds" in results:
        lines += ["", f"Wall time {results['wall_seconds'] / 60:.1f} min."]
    lines.append("")
    return "\n".join(lines)


def counts(r: dict) -> str:
    """'leaking (crossed) / darker (crossed)'."""
    if "leaking_crossed" not in r:
        return f"{r['leaking']} / {r['darker']}"
    return f"{r['leaking']} ({r['leaking_crossed']}) / {r['darker']} ({r['darker_crossed']})"


if __name__ == "__main__":
    sys.exit(main())
