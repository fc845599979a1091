"""Leak audit: texels that receive light they should not, before and after the leak fixes, against
Cycles' Diffuse bake of the same texels.

    flock /tmp/bench.lock .venv/bin/python bench/leaks.py           # everything (≈ 10 min on 2 cores)
    .venv/bin/python bench/leaks.py --quick                          # 256² scenes, few samples
    .venv/bin/python bench/leaks.py --fixtures thin_wall_rooms --scenes

"Before" is the bake with the leak fixes off (the bake points not settled,
scenekit/bakepoint_reference.py, and `bakepoints.FOOTPRINT_TRIANGLES` = 1: the bake points and
their samples as they were: a texel averages its whole footprint on its own triangle, both
sides of a wall standing on it included, samples starting under a coplanar face receive
nothing, and a texel straddling a triangle edge averages only its own triangle's part);
"after" the default. Both are judged as the files hold
them: buried (invalid) texels filled as the encoder fills them.

Fixtures (scenekit/leak_fixtures.py, built here in Blender so Cycles bakes them too): a wall
through a floor, a box resting on a floor, a 5 mm wall between a sunlit and a closed dark room,
a 5 mm table top. One sun of zero angle, no world: each judged texel has an exact answer (0 in
shadow or in the dark room, fully lit S·cosθ/π; texels a shadow edge of the fixture's own
crosses, and those hidden under geometry whose visible neighbours disagree, are not judged). A
texel leaks light when it exceeds its answer by more than 1e-3 of the fully lit value; it is a
dark halo when it falls short by as much. The same rule judges Cycles' bake.

Scenes (`bedroom`, `staircase2` of the external scenes, docs/conventions.md#external-scenes, and
the classroom, loaded and unwrapped as
bench/denoise.py does, BOUNCES diffuse bounces): no exact answer, so ours is judged against
Cycles. Each engine bakes twice (seeds 1, 2); per texel the mean of the two and its standard
error, |a − b|/2, floored at the median relative standard error of the POOL × POOL texels
around it × the texel's level (a one-degree-of-freedom estimate is often near 0 by chance). A texel *leaks* when ours exceeds
Cycles by more than K standard errors (both combined) AND by more than X of the local level,
max(Cycles, FLOOR × Cycles' mean); it is *darker* when Cycles exceeds ours by as much. Compared:
fully covered texels that are valid (not buried) in both of our bakes and that Cycles wrote.
Cycles averages a texel's whole footprint (Blender ≥ 5.2.1), so where a wall stands on a texel
it mixes both sides: where ours is darker there, it is usually Cycles that leaks (see the
fixtures, where the truth is known). Crossed texels are therefore judged against Cycles at FINE ×
the resolution over the fine texels their bake point sees wholly (a fine texel the crossing
geometry straddles mixes both sides in Cycles too; a crossed texel with none is not compared),
and texels straddling a triangle edge against the same fine bake over their whole footprint:
Cycles' own texel samples only the triangle under its centre (on a wall split along a line of
texel centres, the half on one side of the edge).

The two-seed rule flags; two causes then set flagged texels aside, each shown per texel in
bench/results/leaks.md's notes: (1) a coincident twin (`Coincident`): another triangle lies in
the texel's plane at its bake point, facing the same way (duplicated geometry, z-fighting);
Cycles' bake rays start on the surface and skip only their own triangle, so they hit the twin at
distance 0 and Cycles bakes the texel black (exactly 0 in both seeds on staircase2's wall, whose
neighbours are 0.15–0.25), while the surface anyone sees is lit; (2) noise: the two-seed standard
error has one degree of freedom, so the rule selects texels where both seeds happen to lie on the
same side, and our estimator's dim, indirectly lit texels are heavy-tailed; every other flagged
texel is re-traced by the bake's own estimator (CONFIRM_SAMPLES, an independent seed, the standard
error from the spread of its passes) and counts only if the re-measure is flagged by the same rule;
(3) light off duplicated geometry: Cycles' bake loses all light bounced off a surface that has a
coincident twin (its path vertex there starts its rays on the surface and they hit the twin at
distance 0; measured, bench/results/leaks.md, Notes), so a confirmed leak is re-traced with the
same samples, those whose first hit lies on duplicated geometry bringing nothing
(`light_off_duplicates`), and is set aside if that is not flagged; (4) noise in Cycles: a texel
still flagged whose reference is Cycles' own texel is re-judged against Cycles' mean of four
seeds (SEEDS + MORE_SEEDS) and set aside if that is not flagged (the two-seed rule has one degree
of freedom on Cycles' side too).

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
MORE_SEEDS = (3, 4)  # Cycles' seeds re-measuring the texels still flagged after our re-measure
#: per-texel arrays of each scene's audit, for diagnosis (not a result)
ARRAYS = Path(tempfile.gettempdir()) / "hhd-bench-leaks-arrays"
FINE = 4  # Cycles' resolution for the visible part of texels a wall crosses, × the atlas's
SUB = 4  # points per side of a fine texel tested for visibility from a crossed texel's bake point
#: texels the two-seed rule flags are re-traced by our estimator with this many samples and an
#: independent seed; a leak (or darker texel) counts only if the re-measured value is flagged too
CONFIRM_SAMPLES = 1024
CONFIRM_SEED = 1009
CONFIRM_PASS = 16  # samples per pass: the re-measure's standard error comes from the spread of passes
#: a triangle other than the texel's own lies in its plane (normals this parallel) within the
#: ray offset of the bake point: duplicated geometry (z-fighting), where Cycles' bake rays,
#: starting on the surface and skipping only their own triangle, hit the twin at distance 0
COINCIDENT_COS = 0.99


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
    return {
        "K": K,
        "X": X,
        "FLOOR": FLOOR,
        "bounces": BOUNCES,
        "seeds": list(SEEDS),
        "confirm_samples": CONFIRM_SAMPLES,
        "coincident_cos": COINCIDENT_COS,
        "more_cycles_seeds": list(MORE_SEEDS),
        "fine": FINE,
        "fine_sub": SUB,
    }


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
    straddling = (points.others >= 0).any(axis=1) & ~points.crossed
    fine = visible_parts(atlas, points, args, straddling)
    crossed = points.crossed & fine["found"]
    straddling &= fine["found"]
    keep &= ~points.crossed | crossed
    whole = mean_and_error(*cyc, keep, points)
    cyc = [np.where(crossed | straddling, part, c) for part, c in zip(fine["values"], cyc)]
    c_mean, c_se = mean_and_error(*cyc, keep, points)
    twin = Coincident(atlas.bake_scene.triangles)
    own = ~(crossed | straddling)  # texels whose reference is Cycles' own texel
    more: dict = {}

    def cycles_again(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cycles' reference at the texels `rows` re-measured: where it is Cycles' own texel, the
        mean of four seeds (SEEDS and MORE_SEEDS) and its standard error (the two pairs' errors
        combined); elsewhere (the fine reference) as it was."""
        if not more:
            extra = [cycles_bake(atlas.receivers, args.resolution, args.cycles_samples, BOUNCES, s) for s in MORE_SEEDS]
            m34, se34 = mean_and_error(*[(im.reshape(-1, 3) @ LUMINANCE)[points.texel] for im in extra], keep, points)
            more["mean"], more["se"] = 0.5 * (c_mean + m34), 0.5 * np.hypot(c_se, se34)
        mine = own[rows]
        return np.where(mine, more["mean"][rows], c_mean[rows]), np.where(mine, more["se"][rows], c_se[rows])

    out = {
        "receivers": [o.name for o in atlas.receivers],
        "resolution": args.resolution,
        "texels": int(len(points.texel)),
        "compared": int(keep.sum()),
        "samples": args.samples,
        "cycles_samples": args.cycles_samples,
        "cycles_mean": float(c_mean[keep].mean()),
        "crossed_compared": int((keep & crossed).sum()),
        "straddling_compared": int((keep & straddling).sum()),
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
        flagged = compare(o_mean, o_se, c_mean, c_se, keep, crossed)
        causes, masks = explain(
            runs[0].points,
            atlas.bake_scene,
            twin,
            o_mean,
            o_se,
            c_mean,
            c_se,
            keep=keep,
            crossed=crossed,
            cycles_again=cycles_again,
        )
        arrays |= {f"{state}_{k}": v for k, v in masks.items()}
        if state == "after":  # against Cycles' own texels, the whole footprint of crossed ones
            out["after_vs_cycles_texels"] = compare(o_mean, o_se, *whole, keep, crossed)
        out[state] = compare(o_mean, o_se, c_mean, c_se, keep & ~masks["excluded"], crossed) | {
            "two_seed_rule": flagged,
            "causes": causes,
            "buried": int(runs[0].points.buried.sum()),
            "crossed": int(runs[0].points.crossed.sum()) if runs[0].points.crossed is not None else 0,
            "near_cover": int(runs[0].points.near_cover.sum()),
            "seconds": float(np.mean([r.seconds for r in runs])),
        }
    ARRAYS.mkdir(exist_ok=True)
    np.savez_compressed(ARRAYS / f"{name}.npz", **arrays)
    return out


def visible_parts(atlas, points, args, straddling) -> dict:
    """Cycles' answer for the part of each crossed texel its bake point sees, and for the whole
    footprint of each texel `straddling` (P,) bool a triangle edge (Cycles' own texel is the
    part of the footprint on the triangle under the texel's centre only: half of it where the
    centre lies on the edge): Cycles bakes the same UVs at FINE × the resolution, and a texel's
    value is the mean of the fine texels in its block; for a crossed texel, of those its bake
    point (after settling) sees wholly (SUB × SUB points of each, segment tests against the
    scene): a fine texel the crossing geometry straddles averages both sides in Cycles (its dark
    halo, or the lit far side), so it cannot stand for the visible part. A crossed texel with no
    wholly seen fine texel is not compared: the reference does not resolve its visible part.
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
    rows = np.flatnonzero((owner >= 0) & (points.crossed | straddling)[np.maximum(owner, 0)])
    test = points.crossed[owner[rows]]
    rays = RayScene(atlas.bake_scene.triangles)

    def seen_from_bake_point(at: np.ndarray, of: np.ndarray) -> np.ndarray:
        """(len(of),) bool: ray origins `at` (len(of), 3) seen from the bake points of texels `of`."""
        anchor = points.origins(of)
        ray = at - anchor
        length = np.linalg.norm(ray, axis=1)
        return ~rays.occluded(anchor, ray / np.maximum(length, 1e-300)[:, None], length)

    crossed_rows = rows[test]
    grid = (np.stack(np.meshgrid(np.arange(SUB), np.arange(SUB)), axis=-1).reshape(-1, 2) + 0.5) / SUB
    sub = fine.texel_points(crossed_rows, grid)  # (n, SUB², 3), off the surface
    seen = np.ones(len(rows), bool)  # the whole fine texel
    seen[test] = (
        seen_from_bake_point(sub.reshape(-1, 3), np.repeat(owner[crossed_rows], len(grid)))
        .reshape(len(crossed_rows), -1)
        .all(axis=1)
    )
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


def flags(o, o_se, c, c_se, keep) -> tuple[np.ndarray, np.ndarray]:
    """(leaking, darker) (P,) bool by the rule of `compare`."""
    level = np.maximum(c, FLOOR * c[keep].mean())
    sigma = np.hypot(o_se, c_se)
    excess = o - c
    return keep & (excess > K * sigma) & (excess > X * level), keep & (-excess > K * sigma) & (-excess > X * level)


def explain(points, scene, twin, o, o_se, c, c_se, *, keep, crossed, cycles_again=None) -> tuple[dict, dict]:
    """Why the texels the two-seed rule flags differ from Cycles. Each flagged texel is first
    checked for a coincident twin (`Coincident`: duplicated geometry, where Cycles' own bake is
    the artefact: its rays start on the surface and hit the twin at distance 0, so it bakes such
    texels black or dim whatever lights them, while the surface anyone sees is lit); the others
    are re-traced (`retrace`: CONFIRM_SAMPLES, an independent seed, the standard error from the
    spread of passes: many degrees of freedom, where the two-seed estimate has one and our
    estimator's dim, indirectly lit texels are heavy-tailed). A texel the re-measure does not
    flag by the same rule was noise. A leaking texel the re-measure confirms is re-traced once
    more with the same samples, its light off duplicated geometry taken out as Cycles' bake
    takes it out (`light_off_duplicates`: first hits only); if that is not flagged, the excess
    is Cycles' artefact. Last, `cycles_again(rows)` (if given) re-measures Cycles at the texels
    still flagged whose reference is Cycles' own texel (two more seeds: (mean, standard error)
    of the four); a texel that re-measure does not flag was noise in Cycles (its two seeds both
    on one side). Returns (counts per cause and side, masks (P,) bool: `excluded` = the union of
    the causes, and each cause)."""
    leak, dark = flags(o, o_se, c, c_se, keep)
    rows = np.flatnonzero(leak | dark)
    kind = twin.kind(points, rows)
    same = np.zeros(len(o), bool)
    same[rows[kind > 0]] = True
    rest = rows[kind <= 0]
    m, se = retrace(points, scene, rest)
    o2, se2 = o.copy(), o_se.copy()
    o2[rest], se2[rest] = m, se
    leak2, dark2 = flags(o2, se2, c, c_se, keep)
    noise = np.zeros(len(o), bool)
    noise[rest] = ~(leak2 | dark2)[rest]
    left = rest[leak2[rest]]
    with light_off_duplicates(Duplicated(scene.triangles, points.offset), scene.emission):
        m3, se3 = retrace(points, scene, left)
    o3, s3 = o2.copy(), se2.copy()
    o3[left], s3[left] = m3, se3
    duplicates = np.zeros(len(o), bool)
    duplicates[left] = ~flags(o3, s3, c, c_se, keep)[0][left]
    cycles_noise = np.zeros(len(o), bool)
    if cycles_again is not None:
        left = np.flatnonzero((leak2 | dark2) & ~duplicates & ~same)
        if len(left):
            c4, c4_se = c.copy(), c_se.copy()
            c4[left], c4_se[left] = cycles_again(left)
            leak4, dark4 = flags(o2, se2, c4, c4_se, keep)
            cycles_noise[left] = ~(leak4 | dark4)[left]
    excluded = same | noise | duplicates | cycles_noise
    masks = {
        "coincident": same,
        "noise": noise,
        "duplicates": duplicates,
        "cycles_noise": cycles_noise,
        "excluded": excluded,
    }
    causes = {}
    for side, mask in (("leaking", leak), ("darker", dark)):
        causes[side] = {
            "two_seed_rule": int(mask.sum()),
            "coincident_twin": int((mask & same).sum()),
            "noise": int((mask & noise).sum()),
            "light_off_duplicates": int((mask & duplicates).sum()),
            "cycles_noise": int((mask & cycles_noise).sum()),
            "confirmed": int((mask & ~excluded).sum()),
            "confirmed_crossed": int((mask & ~excluded & crossed).sum()),
        }
    causes["opposite_cover_among_flagged"] = int((kind < 0).sum())
    causes["retraced"] = int(len(rest))
    causes["retrace_samples"] = CONFIRM_SAMPLES
    return causes, masks


def retrace(points, scene, rows: np.ndarray, samples: int = CONFIRM_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """Luminance I_z of the texels `rows` traced again by the bake's own estimator
    (`tracer.texel_estimator`, BOUNCES, seed CONFIRM_SEED), samples // CONFIRM_PASS passes:
    (mean (n,), standard error (n,) from the spread of the passes)."""
    from hhd_lightmapper.core import bake, hhd, tracer
    from hhd_lightmapper.core.tracer.scheduler import WorkUnit

    if len(rows) == 0:
        return np.zeros(0), np.zeros(0)
    settings = tracer.BakeSettings(samples=samples, pass_samples=CONFIRM_PASS, bounces=BOUNCES, seed=CONFIRM_SEED)
    estimator = tracer.texel_estimator(points, scene, settings, bake.ray_scene_of(scene))
    passes = samples // CONFIRM_PASS
    chunk = 256
    values = np.empty((passes, len(rows)))
    for p in range(passes):
        for c, s in enumerate(range(0, len(rows), chunk)):
            sl = rows[s : s + chunk]
            est = estimator.trace(WorkUnit(CONFIRM_SEED, p, c, sl)).estimate
            rgb = est.reshape(len(sl), 9, -1, 3).sum(axis=2)  # light sets summed
            values[p, s : s + chunk] = hhd.irradz(rgb, points.normal[sl]) @ LUMINANCE
    return values.mean(axis=0), values.std(axis=0, ddof=1) / np.sqrt(passes)


class Coincident:
    """Triangles lying in a texel's own plane at its bake point (within the ray offset), found
    by brute force over the scene's triangles whose bounding box holds the point (only for the
    few texels asked about)."""

    def __init__(self, triangles: np.ndarray):
        self.tri = np.asarray(triangles, np.float64)
        self.lo, self.hi = self.tri.min(axis=1), self.tri.max(axis=1)
        n = np.cross(self.tri[:, 1] - self.tri[:, 0], self.tri[:, 2] - self.tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.normal = np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def kind(self, points, rows: np.ndarray) -> np.ndarray:
        """(len(rows),) int: 1 where another triangle facing the same way holds the bake point
        (a duplicate: z-fighting), -1 where only one facing the other way does (a cover, which
        the bake handles: core.bakepoints.covers), 0 where none does. The texel's own triangle is the one
        with its corners; an exact copy of it counts as a duplicate (two with its corners)."""
        out = np.zeros(len(rows), int)
        tol = points.offset
        for j, i in enumerate(rows):
            p, n = points.position[i], points.face_normal[i]
            own = points.mesh.positions[points.triangle[i]]
            cand = np.flatnonzero(((self.lo - tol) <= p).all(axis=1) & ((self.hi + tol) >= p).all(axis=1))
            tri, nrm = self.tri[cand], self.normal[cand]
            is_own = np.abs(tri - own).max(axis=(1, 2)) <= 1e-6 * max(1.0, np.abs(own).max())
            dist = np.einsum("ci,ci->c", p - tri[:, 0], nrm)
            q = p - dist[:, None] * nrm
            bary = _barycentric3(q, tri)
            inside = (np.abs(dist) <= tol) & (bary.min(axis=1) > 1e-4) & ~is_own
            cos = nrm @ n
            if (inside & (cos > COINCIDENT_COS)).any() or is_own.sum() > 1:
                out[j] = 1
            elif (inside & (cos < -COINCIDENT_COS)).any():
                out[j] = -1
        return out


class Duplicated:
    """Points on duplicated geometry: another triangle lies in the plane of the triangle a point
    is on (normals this parallel, COINCIDENT_COS, facing either way), within `tol` of the point,
    and holds it (two coincident faces of a wall and its reveal, a slab and the lintel against
    it). Cycles bakes no light bounced off such a point: a path vertex there starts its bounce
    and shadow rays on the surface, skipping only its own triangle, and they hit the twin at
    distance 0 (`light_off_duplicates`). Partners are found once per triangle asked about."""

    def __init__(self, triangles: np.ndarray, tol: float):
        self.tri = np.asarray(triangles, np.float64)
        self.lo, self.hi = self.tri.min(axis=1), self.tri.max(axis=1)
        n = np.cross(self.tri[:, 1] - self.tri[:, 0], self.tri[:, 2] - self.tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.normal = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        self.tol = tol
        self._partners: dict[int, np.ndarray] = {}

    def partners(self, prim: int) -> np.ndarray:
        """Triangles (other than `prim`) parallel to it, in its plane within `tol`, whose
        bounding boxes meet its own."""
        if prim not in self._partners:
            tol, n = self.tol, self.normal[prim]
            near = ((self.lo - tol) <= self.hi[prim]).all(axis=1) & ((self.hi + tol) >= self.lo[prim]).all(axis=1)
            cand = np.flatnonzero(near)
            cand = cand[(cand != prim) & (np.abs(self.normal[cand] @ n) > COINCIDENT_COS)]
            dist = np.abs((self.tri[cand] - self.tri[prim, 0]) @ n).max(axis=1)
            self._partners[prim] = cand[dist <= tol]
        return self._partners[prim]

    def on(self, q: np.ndarray, prim: np.ndarray) -> np.ndarray:
        """(R,) bool: the points q (R, 3) on triangles prim (R,) (-1: none) lie on duplicated
        geometry."""
        out = np.zeros(len(q), bool)
        for p in np.unique(prim[prim >= 0]):
            partners = self.partners(int(p))
            if len(partners) == 0:
                continue
            rows = np.flatnonzero(prim == p)
            tri = np.repeat(self.tri[partners][None], len(rows), axis=0).reshape(-1, 3, 3)
            pts = np.repeat(q[rows], len(partners), axis=0)
            bary = _barycentric3(pts, tri).reshape(len(rows), len(partners), 3)
            normal = np.repeat(self.normal[partners][None], len(rows), axis=0).reshape(-1, 3)
            dist = np.abs(np.einsum("ri,ri->r", pts - tri[:, 0], normal)).reshape(len(rows), len(partners))
            out[rows] = ((bary.min(axis=2) >= -1e-6) & (dist <= self.tol)).any(axis=1)
        return out


class light_off_duplicates:
    """Within this context every texel sample whose first hit lies on duplicated geometry
    (`Duplicated`, not an emitter) brings no light, as in Cycles' bake: measured on a floor lit
    by the sun and by a wall facing it (bench/results/leaks.md, Notes), a coincident twin of the
    wall, facing either way, takes all of the wall's bounce light out of Cycles' floor (0.880 →
    0.637 = the sun alone), and none out of ours. Only first hits: light Cycles loses at later
    path vertices on duplicated geometry is kept, so the emulation errs towards our value."""

    def __init__(self, duplicated: Duplicated, emission: np.ndarray | None):
        self.duplicated = duplicated
        self.emissive = (
            np.zeros(len(duplicated.tri), bool) if emission is None else (np.asarray(emission) > 0).any(axis=1)
        )

    def __enter__(self):
        from hhd_lightmapper.core.tracer.paths import Paths

        self.original = original = Paths.radiance
        duplicated, emissive = self.duplicated, self.emissive

        def radiance(paths, rng, origins, dirs, pdf, start=None, *args, **kwargs):
            out = original(paths, rng, origins, dirs, pdf, start, *args, **kwargs)
            t, prim, _ = paths.scene.rays.intersect(origins, dirs)
            hit = prim >= 0
            q = origins + dirs * np.where(hit, t, 0.0)[:, None]
            dark = duplicated.on(q, prim) & hit & ~emissive[np.maximum(prim, 0)]
            if start is not None:
                dark &= start
            out[dark] = 0.0
            return out

        Paths.radiance = radiance
        return self

    def __exit__(self, *exc):
        from hhd_lightmapper.core.tracer.paths import Paths

        Paths.radiance = self.original
        return False


def _barycentric3(q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (C, 3) of points q (C, 3) in the planes of triangles (C, 3, 3)."""
    e0, e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], q - tri[:, 0]
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(den > 0, den, np.inf)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - w, v, w], axis=1)


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
        "ratio_sum_crossed": float(o[keep & crossed].sum() / max(c[keep & crossed].sum(), 1e-300)),
        "ratio_sum_not_crossed": float(o[keep & ~crossed].sum() / c[keep & ~crossed].sum()),
        "rmse_relative": float(np.sqrt(np.mean((o - c)[keep] ** 2)) / c[keep].mean()),
        "leak_excess_share": float(excess[leak].sum() / c[keep].sum()),
    }


# ---- the two engines -------------------------------------------------------------------------
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def luminance(traced) -> np.ndarray:
    from hhd_lightmapper.core import hhd

    return hhd.irradz(traced.sh, traced.points.normal) @ LUMINANCE


def our_bake(receivers_or_atlas, size: int, samples: int, bounces: int, seed: int, settle: bool):
    """Our bake (stages 1–2) with the leak fixes (`settle`: the default) or without them (the
    bake points not settled, scenekit/bakepoint_reference.py, and `bakepoints.FOOTPRINT_TRIANGLES`
    1). Returns (TracedAtlas, seconds)."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data
    from hhd_lightmapper.core import bake, bakepoints, tracer
    from scenekit import bakepoint_reference

    if isinstance(receivers_or_atlas, list):
        depsgraph = bpy.context.evaluated_depsgraph_get()
        surface = mesh_data.read_surface(receivers_or_atlas, LAYER, depsgraph)
        scene = scene_data.read_bake_scene(depsgraph)
    else:
        surface, scene = receivers_or_atlas.surface, receivers_or_atlas.bake_scene
    settings = tracer.BakeSettings.from_samples(samples, bounces=bounces, seed=seed)
    trace = bake.trace_surface if settle else bakepoint_reference.trace_unsettled
    old = bakepoints.FOOTPRINT_TRIANGLES
    bakepoints.FOOTPRINT_TRIANGLES = old if settle else 1
    try:
        t = time.perf_counter()
        traced = trace(surface, size, size, scene, settings)
        return traced, time.perf_counter() - t
    finally:
        bakepoints.FOOTPRINT_TRIANGLES = old


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
        "Before: bake points and samples as they were (not settled: scenekit/bakepoint_reference.py; "
        "`bakepoints.FOOTPRINT_TRIANGLES` = 1); after: the default (bake points moved out of solids, "
        "samples hidden from the bake point replaced, texels whose bake point stays under a coplanar "
        "face invalid, invalid texels filled from their own chart, a texel's samples over its whole "
        "footprint across the triangles covering it). Rules: the module docstring of bench/leaks.py.",
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
            f"A texel is flagged when ours exceeds Cycles by > {rule['K']:g} combined standard errors and > "
            f"{rule['X']:.0%} of max(Cycles, {rule['FLOOR']:g} × Cycles' mean) (leaking; darker: the reverse), "
            f"{rule['bounces']} bounces, two seeds per engine. A flagged texel on duplicated geometry (a "
            "coincident twin, where Cycles' bake is the artefact) is set aside, the others are re-traced by "
            f"our estimator ({rule.get('confirm_samples', CONFIRM_SAMPLES)} samples, an independent seed, "
            "the standard error from the spread of its passes) and count only if the re-measure is "
            "flagged by the same rule; a confirmed leak whose re-measure without the light its "
            "samples' first hits take off duplicated geometry (which Cycles' bake loses: Notes) is not "
            "flagged is set aside as Cycles' artefact; the texels still flagged whose reference is "
            "Cycles' own texel are re-judged against Cycles' mean of four seeds "
            f"({', '.join(str(x) for x in SEEDS + MORE_SEEDS)}) and set aside as noise in Cycles if "
            "that is not flagged.",
            "",
            "Where geometry crosses a texel (`crossed`), the reference is Cycles' bake at "
            f"{FINE}× the resolution averaged over the fine texels the bake point sees wholly ({SUB}×{SUB} "
            "points each; a fine texel the crossing geometry straddles averages both sides in Cycles), "
            "a crossed texel with none not compared; where a texel straddles a triangle edge, the same fine bake over the whole "
            "footprint (Cycles' own texel covers only the triangle under its centre); elsewhere "
            "Cycles' own texel. The last column judges Cycles' own texels (its whole footprint) by "
            "the two-seed rule.",
            "",
            "Counts: all compared texels (in brackets: the crossed ones among them).",
            "",
            "| scene | atlas, texels compared (crossed, straddling) | spp ours / Cycles | before: leaking / darker, ΣI ratio | after: leaking / darker, ΣI ratio | buried before → after | Cycles' texels: leaking / darker |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for name, r in results["scenes"].items():
            b, a = r["before"], r["after"]
            w = r["cycles_whole_footprint"]
            lines.append(
                f"| {name} | {r['resolution']}², {r['compared']} ({r['crossed_compared']}, "
                f"{r.get('straddling_compared', 0)}) | {r['samples']} / "
                f"{r['cycles_samples']} | {counts(b)}, {b['ratio_sum']:.4f} | {counts(a)}, {a['ratio_sum']:.4f} "
                f"| {b['buried']} → {a['buried']} | {counts(w)} |"
            )
        lines += [
            "",
            "Why the texels the two-seed rule flags differ (leaking / darker):",
            "",
            "| scene | state | flagged | coincident twin (Cycles' artefact) | noise (not confirmed) "
            "| light off duplicated geometry (Cycles' artefact) | noise in Cycles | confirmed (crossed) |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for name, r in results["scenes"].items():
            for state in ("before", "after"):
                c = r[state].get("causes")
                if c is None:
                    continue
                lk, dk = c["leaking"], c["darker"]
                lines.append(
                    f"| {name} | {state} | {lk['two_seed_rule']} / {dk['two_seed_rule']} | "
                    f"{lk['coincident_twin']} / {dk['coincident_twin']} | {lk['noise']} / {dk['noise']} | "
                    f"{lk.get('light_off_duplicates', 0)} / {dk.get('light_off_duplicates', 0)} | "
                    f"{lk.get('cycles_noise', 0)} / {dk.get('cycles_noise', 0)} | "
                    f"{lk['confirmed']} ({lk['confirmed_crossed']}) / {dk['confirmed']} ({dk['confirmed_crossed']}) |"
                )
        lines += [
            "",
            "Agreement with Cycles over the compared texels (after; ΣI ratio = Σ ours / Σ Cycles, "
            "RMSE relative to Cycles' mean; crossed texels against the visible part, the rest against "
            "Cycles' texel or the whole footprint):",
            "",
            "| scene | ΣI ratio all | crossed | not crossed | RMSE | against Cycles' own texels: ΣI ratio, crossed |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for name, r in results["scenes"].items():
            a, w = r["after"], r["cycles_whole_footprint"]
            if "ratio_sum_crossed" not in a:
                continue
            lines.append(
                f"| {name} | {a['ratio_sum']:.4f} | {a['ratio_sum_crossed']:.4f} | {a['ratio_sum_not_crossed']:.4f} "
                f"| {a['rmse_relative']:.3f} | {r.get('after_vs_cycles_texels', {}).get('ratio_sum', float('nan')):.4f}, "
                f"{r.get('after_vs_cycles_texels', {}).get('ratio_sum_crossed', float('nan')):.4f} |"
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
