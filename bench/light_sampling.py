"""What each part of the emitter sampling saves: per-sample I_z variance against Cycles' Diffuse bake.

    flock /tmp/bench.lock .venv/bin/python bench/light_sampling.py                 # staircase2, bedroom
    .venv/bin/python bench/light_sampling.py --scenes staircase2 --resolution 256 --samples 16 64

Scenes: the emissive-lit interiors of the external scenes (docs/conventions.md#external-scenes;
`staircase2`: 8 lamps, `bedroom`),
receivers and atlas as bench/time_to_error.py sets them up. Cycles' reference: two halves of
`--reference` samples with their own seeds (its noise, the floor, is removed from every error in
quadrature); Cycles' rows and ours at `--samples`, BOUNCES bounces (`--direct`: 0, light straight
from the emitters only). Our rows turn the parts of the emitter sampling on one after another
(`lights.emitters.EmissiveTriangles`; the rows before `+ stratified` draw the light samples'
numbers pass by pass, scenekit/estimator_reference.py):

- `power, area`: emitters picked by power alone, a uniform point on the triangle, independent
  random numbers per sample (the sampling before 2026-12-02);
- `+ clusters`: spatial clusters picked by power, distance and horizon per shading point;
- `+ stratified`: a texel's light samples from its own sequence, stratified across its passes;
- `+ solid angle`: triangles that subtend more than SOLID_ANGLE_RANGE[0] sampled by direction,
  and so are Blender's area lights (spherical rectangles; before it, a uniform point on the lamp);
- `+ near solid angle`: a cluster of one triangle picked by the solid angle it subtends from
  points inside its bounding sphere (`lights.emitters.NEAR_RADII`), not by power over distance²;
- `+ one lamp per point`: a shading point samples one of the point, spot and area lights,
  picked by intensity, cosine bounds and distance (`lights.choice.Choice`), not every one of them;
- `+ light tree`: clusters of more than one emitting triangle split again (`lights.emitters.FANOUT`,
  0 before), descended level by level down to single triangles, not a triangle by power within a cluster.

The rows before `+ one lamp per point` sampled every point, spot and area light at every point
(a switch, `lights.choice.CHOOSE`, retired after commit fc8bedd): on a scene with such lights
(`area-lamp-room`, `lamp-grid-room`) they are not measured any more: bench/results holds them as
measured up to fc8bedd (a rerun of those scenes writes only the rows measured now). On the
emissive-mesh scenes the switch changed nothing.

`area-lamp-room` (scenekit's `area_lamp_room`, on request): lit by Blender area lights, two of
them facing the ceiling and a wall a few centimetres away, no emissive mesh: only the last two
rows change its sampling; `lamp-grid-room` (`lamp_grid_room`): nine lamps (six ceiling panels,
two point lights, a spot) that all light most of the room, where picking one lamp per point has
the most to lose; `bulb-hall` (`bulb_hall`): 48 bulbs and 12 plaques, 3,984 emitting triangles
spread through a hall; `panel-room` (`panel_room`): a subdivided 24 × 12
ceiling panel 3 cm below the ceiling and a 60-segment LED strip 4 cm off a wall, 696 emitting
triangles a few centimetres from what they light.

Per row: relative I_z RMSE (luminance, over fully covered unburied texels, relative to the
reference's mean), with the floor removed; per-sample variance (error² × samples) over Cycles' at
the same samples (< 1: our samples are worth more); seconds and the texel-sample rate over
Cycles' (time to equal error ≈ rate ratio / variance ratio); bias (ΣI_z ratio − 1). Writes
bench/results/light_sampling.json and .md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
SCENES = ("staircase2", "bedroom")
#: on request (`--scenes`): Blender area lights beside the receivers, not emissive meshes
EXTRA_SCENES = ("area-lamp-room", "lamp-grid-room", "bulb-hall", "panel-room")
VARIANTS = (
    "power, area",
    "+ clusters",
    "+ stratified",
    "+ solid angle",
    "+ near solid angle",
    "+ one lamp per point",
    "+ light tree",
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", choices=SCENES + EXTRA_SCENES, default=list(SCENES))
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--reference", type=int, default=512, help="Cycles' reference samples, both halves")
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--direct", action="store_true", help="0 bounces: direct light only")
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    import time_to_error as tte

    hhd_lightmapper.register()
    if args.direct:
        tte.BOUNCES = 0
    out = RESULTS / "light_sampling.json"
    results = json.loads(out.read_text()) if out.exists() else {}
    key = "direct" if args.direct else f"{tte.BOUNCES} bounces"
    for name in args.scenes:
        results.setdefault(key, {})[name] = measure(tte, name, args)
        RESULTS.mkdir(exist_ok=True)
        out.write_text(json.dumps(results, indent=2))
    (RESULTS / "light_sampling.md").write_text(markdown(results))
    print(markdown(results))
    return 0


@contextlib.contextmanager
def variant(name: str) -> Iterator[None]:
    """Within: the emitter sampling of `name` of VARIANTS (each includes the ones before it; the
    point, spot and area lights are one chosen per point in every one: module doc); the
    product's own after."""
    from hhd_lightmapper.core.tracer import lights
    from scenekit import estimator_reference

    e = lights.emitters
    product = e.CLUSTERS, e.SOLID_ANGLE_RANGE, e.NEAR_RADII, e.FANOUT
    level = VARIANTS.index(name)
    e.CLUSTERS = product[0] if level >= 1 else 1
    e.SOLID_ANGLE_RANGE = product[1] if level >= 3 else (math.inf, math.inf)
    e.NEAR_RADII = product[2] if level >= 4 else 0.0
    e.FANOUT = product[3] if level >= 6 else 0
    try:
        with estimator_reference.used(*(() if level >= 2 else ("lights",))):
            yield
    finally:
        e.CLUSTERS, e.SOLID_ANGLE_RANGE, e.NEAR_RADII, e.FANOUT = product


def measured(name: str, lamps: bool) -> bool:
    """Whether row `name` of VARIANTS is measured on a scene with (`lamps`) or without point,
    spot and area lights: not the rows before `+ one lamp per point` with them (module doc)."""
    return not lamps or VARIANTS.index(name) >= VARIANTS.index("+ one lamp per point")


def measure(tte, name: str, args) -> dict:
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data
    from hhd_lightmapper.core import bakepoints, rays
    from hhd_lightmapper.core.colour import LUMINANCE
    from hhd_lightmapper.core.tracer import lights
    from scenekit.blender import select

    receivers = tte.load_scene(name)
    scene = bpy.context.scene
    scene.hhd.uv_layer, scene.hhd.resolution, scene.hhd.texel_density = tte.LAYER, args.resolution, 0.0
    scene.hhd.padding = 2
    select(receivers)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    depsgraph = bpy.context.evaluated_depsgraph_get()
    surface = mesh_data.read_surface(receivers, tte.LAYER, depsgraph)
    bake_scene = scene_data.read_bake_scene(depsgraph)
    ray_scene = rays.RayScene(bake_scene.triangles)
    points = bakepoints.build(surface, args.resolution, args.resolution, occluders=ray_scene)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    emitters = 0 if bake_scene.emission is None else int(bake_scene.emission.any(axis=1).sum())
    lamps = any(light.chosen for light in lights.build(bake_scene))
    tte.warm_up(points, bake_scene, ray_scene)
    t = time.perf_counter()
    halves = [tte.cycles_bake(receivers, points, args.reference // 2, seed=s) @ LUMINANCE for s in tte.REFERENCE_SEEDS]
    reference = 0.5 * (halves[0] + halves[1])
    mean = float(reference[keep].mean())
    floor = 0.5 * tte.rmse(halves[0], halves[1], keep, mean)
    result = {
        "texels": int(len(points.texel)),
        "emitting_triangles": emitters,
        "reference": {"samples": args.reference, "seconds": time.perf_counter() - t, "floor": floor},
        "load_average_start": os.getloadavg(),
        "rows": [],
    }
    print(f"[{name}] {len(points.texel)} texels, {emitters} emitting triangles, reference floor {100 * floor:.2f}%")
    for samples in args.samples:
        t = time.perf_counter()
        iz = tte.cycles_bake(receivers, points, samples) @ LUMINANCE
        cycles = {"method": "Cycles", "samples": samples, "seconds": time.perf_counter() - t}
        cycles.update(tte.errors(iz, reference, keep, mean, floor))
        result["rows"].append(cycles)
        for v in (v for v in VARIANTS if measured(v, lamps)):
            with variant(v):
                iz, seconds, _ = tte.our_bake(surface, bake_scene, samples, points)
            row = {"method": v, "samples": samples, "seconds": seconds}
            row.update(tte.errors(iz @ LUMINANCE, reference, keep, mean, floor))
            row["variance_vs_cycles"] = (row["rmse"] / cycles["rmse"]) ** 2
            row["rate_vs_cycles"] = cycles["seconds"] / seconds
            result["rows"].append(row)
            print(
                f"[{name}] {samples:4d} spp {v:14s} {seconds:6.1f} s  RMSE {100 * row['rmse']:.2f}%  "
                f"variance / Cycles' {row['variance_vs_cycles']:.2f}  rate / Cycles' {row['rate_vs_cycles']:.2f}",
                flush=True,
            )
    result["load_average_end"] = os.getloadavg()
    return result


def markdown(results: dict) -> str:
    lines = [
        "# Emitter sampling: per-sample I_z variance against Cycles (`bench/light_sampling.py`)",
        "",
        "Relative I_z RMSE with the Cycles reference's noise removed; variance = our error² over Cycles' at the "
        "same samples (< 1: our samples are worth more); rate = Cycles' seconds over ours (the machine is shared: "
        "seconds are noisy, variance is not); bias = ΣI_z / Σ reference − 1. Time to equal error ≈ rate / variance.",
    ]
    for key, scenes in results.items():
        for name, r in scenes.items():
            lines += [
                "",
                f"## {name}, {key}",
                "",
                f"{r['texels']} texels, {r['emitting_triangles']} emitting triangles; Cycles reference "
                f"{r['reference']['samples']} spp, its noise {100 * r['reference']['floor']:.2f}%; load "
                f"{r['load_average_start'][0]:.1f} → {r['load_average_end'][0]:.1f}.",
                "",
                "| samples | method | s | RMSE % | bias % | variance / Cycles' | rate / Cycles' | rate / variance |",
                "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
            ]
            for row in r["rows"]:
                var, rate = row.get("variance_vs_cycles"), row.get("rate_vs_cycles")
                cells = [
                    str(row["samples"]),
                    row["method"],
                    f"{row['seconds']:.1f}",
                    f"{100 * row['rmse']:.2f}",
                    f"{100 * row['bias']:+.2f}",
                    "1" if var is None else f"{var:.2f}",
                    "1" if rate is None else f"{rate:.2f}",
                    "1" if var is None else f"{rate / var:.2f}",
                ]
                lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
