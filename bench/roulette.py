"""Russian roulette: how paths are ended, and what each way costs in noise and in rays.

    flock /tmp/bench.lock .venv/bin/python bench/roulette.py                 # the four scenes, 3 bounces
    .venv/bin/python bench/roulette.py --scenes classroom bedroom --bounces 8

The scenes and atlases of bench/time_to_error.py (512²). For each way of ending paths
(`paths.RR_START`, `RR_SURVIVAL_POWER`, `RR_REFERENCE`, `RR_MAX_SURVIVAL`: a path survives from
bounce RR_START on with probability min((max(throughput) / reference)^power, max survival)), `--seeds` bakes of `--samples` spp on
every core, the ways interleaved seed by seed (this machine's speed drifts): the per-sample I_z
variance (luminance, over fully covered unburied texels, relative to the mean²: the spread across
seeds × samples), the rays traced and the trace seconds (median). Efficiency is variance × cost,
against the first way's: below 1, the same error sooner. Rays are the steadier cost; seconds
also count the light sampling per vertex. Writes bench/results/roulette.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
SCENES = ("classroom", "field", "staircase2", "bedroom")
#: (name, RR_START, RR_SURVIVAL_POWER, RR_REFERENCE, RR_MAX_SURVIVAL): the first is the baseline
#: the others are compared with.
WAYS = (
    ("√throughput, from bounce 2 (Cycles' rule)", 2, 0.5, 1.0, 0.95),
    ("√(throughput / ½), from bounce 2, none ended above ½", 2, 0.5, 0.5, 1.0),
    ("√(throughput / ¼), from bounce 2, none ended above ¼", 2, 0.5, 0.25, 1.0),
    ("√throughput, from bounce 3", 3, 0.5, 1.0, 0.95),
    ("none (every path to the last bounce)", 1000, 1.0, 1.0, 1.0),
)
_KNOBS = ("RR_START", "RR_SURVIVAL_POWER", "RR_REFERENCE", "RR_MAX_SURVIVAL")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--resolution", type=int, default=512)
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    from trace_profile import read_scene

    hhd_lightmapper.register()
    out_path = RESULTS / "roulette.json"
    results = json.loads(out_path.read_text()) if out_path.exists() else {}
    for name in args.scenes:
        surface, bake_scene = read_scene(name, args.resolution)
        key = f"{name}, {args.bounces} bounces, {args.samples} spp"
        results[key] = measure(surface, bake_scene, args)
        results[key]["load_average"] = os.getloadavg()
        print(table({key: results[key]}), flush=True)
        RESULTS.mkdir(exist_ok=True)
        out_path.write_text(json.dumps(results, indent=2))
    (RESULTS / "roulette.md").write_text(table(results))
    return 0


def measure(surface, bake_scene, args) -> dict:
    from hhd_lightmapper.core import bake, hhd, rays, tracer
    from hhd_lightmapper.core.colour import LUMINANCE
    from hhd_lightmapper.core.tracer import paths

    ray_scene = rays.RayScene(bake_scene.triangles)
    n = args.resolution
    objects = [str(k) for k in range(int(surface.object_index.max(initial=-1)) + 1)]
    points = bake.points_of(bake.AtlasInput("atlas", n, n, surface, objects), ray_scene)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    iz = {way[0]: [] for way in WAYS}
    traced = {way[0]: [] for way in WAYS}
    seconds = {way[0]: [] for way in WAYS}
    saved = [getattr(paths, knob) for knob in _KNOBS]
    try:
        for seed in range(-1, args.seeds):  # seed -1: untimed, compiles and warms
            for way, *values in WAYS:
                for knob, value in zip(_KNOBS, values):
                    setattr(paths, knob, value)
                settings = tracer.BakeSettings.from_samples(args.samples, bounces=args.bounces, seed=100 + seed)
                result = tracer.bake(points, bake_scene, settings, ray_scene=ray_scene)
                if seed < 0:
                    continue
                iz[way].append((hhd.irradz(result.sh, points.normal) @ LUMINANCE)[keep])
                traced[way].append(result.rays)
                seconds[way].append(result.seconds)
    finally:
        for knob, value in zip(_KNOBS, saved):
            setattr(paths, knob, value)
    rows = {}
    for way, start, power, reference, max_survival in WAYS:
        a = np.array(iz[way])
        mean = float(a.mean())
        rows[way] = {
            "rr_start": start,
            "survival_power": power,
            "survival_reference": reference,
            "max_survival": max_survival,
            "mean_iz": mean,
            "variance": float(a.var(axis=0, ddof=1).mean() / mean**2 * args.samples),
            "rays": float(np.median(traced[way])),
            "seconds": float(np.median(seconds[way])),
        }
    base = rows[WAYS[0][0]]
    for row in rows.values():
        row["efficiency_rays"] = row["variance"] * row["rays"] / (base["variance"] * base["rays"])
        row["efficiency_seconds"] = row["variance"] * row["seconds"] / (base["variance"] * base["seconds"])
    return {"texels": int(keep.sum()), "seeds": args.seeds, "ways": rows}


def table(results: dict) -> str:
    lines = [
        "# Russian roulette (`bench/roulette.py`)",
        "",
        "Per-sample I_z variance (relative to the mean²), rays and trace seconds (medians, all cores); "
        "efficiency = variance × cost against the first way's (below 1: the same error sooner).",
        "",
        "| scene | way | mean I_z | variance | rays | seconds | variance × rays | variance × seconds |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for key, r in results.items():
        for way, row in r["ways"].items():
            lines.append(
                f"| {key} | {way} | {row['mean_iz']:.4g} | {row['variance']:.4g} | {row['rays'] / 1e6:.2f} M "
                f"| {row['seconds']:.2f} s | {row['efficiency_rays']:.3f} | {row['efficiency_seconds']:.3f} |"
            )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
