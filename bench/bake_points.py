"""Bake points alone, phase by phase, at 1024², 2048² and 4096² (issue 23 part 5); run by hand.

    python bench/bake_points.py [--resolutions 1024 2048 4096] [--threads 0] [--compare]

The scene is bench/memory.py's: its 200 × 200-quad wavy sheet (80k triangles) mapped as one chart
covering `--fill` (60%) of the atlas, with the sheet itself as the occluders (10.07 M texels at
4096²). `bakepoints.build` runs as `bake.points_of` runs it; its phases are timed by wrapping
the functions it calls (wall and CPU seconds of the whole process, every thread; the machine is
shared, so the 1-min load average is recorded beside them): rasterise (`raster.rasterise`),
choose per texel (`raster.choose_per_texel`), footprint others (`bakepoints.other_triangles`),
fill points (`_fill_points` over the chunks), settle, buried probe (`find_buried`), near-cover
probe (`find_near_cover`), other (the rest: the surface mesh and its weld, the cover probe's
BVH, built afresh for each run, the last cover check). Inside the phases, the CPU seconds of
the Embree queries (`RayScene.intersect` / `occluded`, every thread's own) and of settle's
`_spoke_targets` are counted apart.

`--compare` also runs the code path before issue 23 part 5 compiled it (the numpy rasteriser,
per-texel choice, footprint triangles, point fill, texel points, settle spokes and probes of
scenekit/raster_reference.py, patched in for that run) on the same scene in the same process,
checks that every array of the two `BakePoints` is identical (reporting the largest difference
otherwise) and reports old / new ratios. Results: bench/results/bake_points.json and .md (or
--out).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from hhd_lightmapper.core import bake, bakepoints, raster  # noqa: E402
from hhd_lightmapper.core.bakepoints import covers, settling  # noqa: E402
from hhd_lightmapper.core.rays import RayScene  # noqa: E402
from hhd_lightmapper.core.scene import BakeScene  # noqa: E402
from memory import sheet  # noqa: E402
from scenekit import raster_reference  # noqa: E402

RESULTS = ROOT / "bench" / "results"
PHASES = (
    "rasterise",
    "choose per texel",
    "footprint others",
    "fill points",
    "settle",
    "buried probe",
    "near-cover probe",
    "other",
)


def sheet_surface(resolution: int, fill: float = 0.6) -> tuple[bakepoints.SurfaceTriangles, np.ndarray]:
    """bench/memory.py's sheet as it bakes it: one planar chart (the sheet's xy) covering `fill`
    of the atlas, face normals as vertex normals. Returns the surface and its triangles."""
    v, f = sheet()
    tris = v[f]
    uv = 0.02 + np.sqrt(fill) * (tris[..., :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    surface = bakepoints.SurfaceTriangles(tris, normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.6))
    return surface, tris


class Phases:
    """Wall and CPU seconds per phase: the wrapped functions start a phase when no other phase is
    running (calls nested in a phase count to it)."""

    def __init__(self):
        self.wall = dict.fromkeys(PHASES, 0.0)
        self.cpu = dict.fromkeys(PHASES, 0.0)
        self.active: str | None = None
        self.parts: dict = {}  # (phase, part) -> CPU seconds of the calls (their threads' own)
        self._lock = threading.Lock()
        self._undo: list = []

    def part(self, owner, attr: str, name: str) -> None:
        """Count the CPU time of `owner.attr`'s calls (on whichever thread) to the running phase."""
        f = getattr(owner, attr)

        def timed(*args, **kwargs):
            c = time.thread_time()
            try:
                return f(*args, **kwargs)
            finally:
                with self._lock:
                    key = (self.active or "other", name)
                    self.parts[key] = self.parts.get(key, 0.0) + time.thread_time() - c

        self._undo.append((owner, attr, f))
        setattr(owner, attr, timed)

    def wrap(self, owner, attr: str, name: str) -> None:
        f = getattr(owner, attr)

        def timed(*args, **kwargs):
            if self.active is not None:
                return f(*args, **kwargs)
            self.active = name
            t, c = time.perf_counter(), time.process_time()
            try:
                return f(*args, **kwargs)
            finally:
                self.wall[name] += time.perf_counter() - t
                self.cpu[name] += time.process_time() - c
                self.active = None

        self._undo.append((owner, attr, f))
        setattr(owner, attr, timed)

    def undo(self) -> None:
        for owner, attr, f in reversed(self._undo):
            setattr(owner, attr, f)
        self._undo.clear()


def patch_old() -> list:
    """Put the pre-compilation numpy path in place (scenekit/raster_reference.py); returns the undo list."""
    ref = raster_reference
    undo = []
    for owner, attr, f in (
        (raster, "rasterise", ref.rasterise),
        (raster, "choose_per_texel", ref.choose_per_texel),
        (bakepoints, "other_triangles", ref.other_triangles),
        (bakepoints, "settle", ref.settle),
        (bakepoints, "_fill_points", ref._fill_points),
        (bakepoints, "find_near_cover", ref.find_near_cover),
        (bakepoints, "find_buried", ref.find_buried),
        (bakepoints.BakePoints, "texel_points", ref.texel_points),
    ):
        undo.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, f)
    return undo


def run(surface, scene: RayScene, resolution: int, threads: int) -> tuple[bakepoints.BakePoints, dict]:
    """One `bakepoints.build` (as `bake.points_of` calls it), timed phase by phase."""
    phases = Phases()
    phases.wrap(raster, "rasterise", "rasterise")
    phases.wrap(raster, "choose_per_texel", "choose per texel")
    phases.wrap(bakepoints, "other_triangles", "footprint others")
    phases.wrap(bakepoints, "_for_chunks", "fill points")  # the one called outside the probes
    phases.wrap(bakepoints, "settle", "settle")
    phases.wrap(bakepoints, "find_buried", "buried probe")
    phases.wrap(bakepoints, "find_near_cover", "near-cover probe")
    phases.part(RayScene, "intersect", "embree")
    phases.part(RayScene, "occluded", "embree")
    phases.part(settling, "_spoke_targets", "_spoke_targets")
    phases.part(raster_reference, "_spoke_targets", "_spoke_targets")  # the old path's
    covers._shared.clear()  # each run builds its own cover probe (`build` would reuse the last run's)
    load = os.getloadavg()[0]
    t, c = time.perf_counter(), time.process_time()
    try:
        points = bakepoints.build(surface, resolution, resolution, occluders=scene, threads=threads)
    finally:
        phases.undo()
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    phases.wall["other"] = wall - sum(phases.wall.values())
    phases.cpu["other"] = cpu - sum(phases.cpu.values())
    row = {
        "wall": phases.wall,
        "cpu": phases.cpu,
        "total_wall": wall,
        "total_cpu": cpu,
        "load_before": load,
        "load_after": os.getloadavg()[0],
        "texels": len(points.texel),
        "parts_cpu": {f"{phase}: {part}": cpu for (phase, part), cpu in sorted(phases.parts.items())},
    }
    return points, row


def differences(a: bakepoints.BakePoints, b: bakepoints.BakePoints) -> dict:
    """Per array field: 'identical' or the largest absolute difference (and how many differ)."""
    out = {}
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if not isinstance(x, np.ndarray):
            if field.name == "mesh":
                continue
            out[field.name] = "identical" if x == y else f"{x} vs {y}"
            continue
        if x.shape != y.shape:
            out[field.name] = f"shapes {x.shape} vs {y.shape}"
        elif np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            out[field.name] = "identical"
        else:
            bad = x != y
            diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
            out[field.name] = f"{int(bad.sum())} differ, largest {np.nanmax(diff):.3g}"
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[1024, 2048, 4096])
    ap.add_argument("--fill", type=float, default=0.6)
    ap.add_argument("--threads", type=int, default=0, help="0 = every core")
    ap.add_argument("--compare", action="store_true", help="also run the numpy path before issue 23 part 5")
    ap.add_argument("--out", type=Path, default=RESULTS / "bake_points.json")
    args = ap.parse_args()

    warm, tris = sheet_surface(64, args.fill)  # compiles (or loads the cached) kernels outside the timing
    bakepoints.build(warm, 64, 64, occluders=RayScene(tris), threads=args.threads)
    report: dict = {"cpus": os.cpu_count(), "threads": args.threads, "fill": args.fill, "runs": []}
    for resolution in args.resolutions:
        surface, tris = sheet_surface(resolution, args.fill)
        scene = bake.ray_scene_of(BakeScene(tris, np.full((len(tris), 3), 0.6)))
        points, new = run(surface, scene, resolution, args.threads)
        entry = {"resolution": resolution, "texels": new["texels"], "new": new}
        print(_line(resolution, "new", new))
        if args.compare:
            undo = patch_old()
            try:
                old_points, old = run(surface, scene, resolution, args.threads)
            finally:
                for owner, attr, f in undo:
                    setattr(owner, attr, f)
            entry["old"] = old
            entry["identity"] = differences(old_points, points)
            del old_points
            print(_line(resolution, "old", old))
            print("   identity:", entry["identity"])
        del points
        report["runs"].append(entry)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    args.out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    return 0


def _line(resolution: int, which: str, row: dict) -> str:
    parts = ", ".join(f"{k} {row['wall'][k]:.2f} ({row['cpu'][k]:.2f})" for k in PHASES)
    inside = ", ".join(f"{k} {v:.2f}" for k, v in row["parts_cpu"].items())
    return (
        f"{resolution}² {which}: {row['total_wall']:.2f} s wall ({row['total_cpu']:.2f} s cpu), "
        f"load {row['load_before']:.1f}→{row['load_after']:.1f}; {parts}\n   cpu inside: {inside}"
    )


def markdown(report: dict) -> str:
    lines = [
        "# Bake points alone (issue 23 part 5): `bench/bake_points.py`",
        "",
        f"bench/memory.py's wavy sheet (80k triangles, one chart, {report['fill']:.0%} of the atlas), "
        f"`bakepoints.build` with the sheet as occluders, threads {report['threads']} (0 = all "
        f"{report['cpus']} cores). Seconds are wall (CPU, every thread); the load is the 1-min "
        "average at the start → end of each run. Old: the numpy path before the compiled kernels "
        "(scenekit/raster_reference.py), run in the same process after the new one.",
        "",
    ]
    for entry in report["runs"]:
        new, old = entry["new"], entry.get("old")
        lines += [f"## {entry['resolution']}²: {entry['texels']:,} texels", ""]
        load = f"new: load {new['load_before']:.1f} → {new['load_after']:.1f}"
        if old:
            load += f" · old: load {old['load_before']:.1f} → {old['load_after']:.1f}"
        lines += [load, ""]
        if old:
            lines += [
                "| phase | old s (cpu s) | new s (cpu s) | ratio wall | ratio cpu |",
                "| --- | ---: | ---: | ---: | ---: |",
            ]
        else:
            lines += ["| phase | s (cpu s) |", "| --- | ---: |"]
        rows = [(k, new["wall"][k], new["cpu"][k], old and old["wall"][k], old and old["cpu"][k]) for k in PHASES]
        rows.append(
            ("**total**", new["total_wall"], new["total_cpu"], old and old["total_wall"], old and old["total_cpu"])
        )
        for name, w, c, ow, oc in rows:
            if old:
                lines.append(
                    f"| {name} | {ow:.2f} ({oc:.2f}) | {w:.2f} ({c:.2f}) | {ow / max(w, 1e-9):.1f}× "
                    f"| {oc / max(c, 1e-9):.1f}× |"
                )
            else:
                lines.append(f"| {name} | {w:.2f} ({c:.2f}) |")
        for which, row in (("new", new), ("old", old)):
            if row and row.get("parts_cpu"):
                parts = "; ".join(f"{k} {v:.2f}" for k, v in row["parts_cpu"].items())
                lines += ["", f"CPU seconds inside ({which}): {parts}."]
        if "identity" in entry:
            same = [k for k, v in entry["identity"].items() if v == "identical"]
            differ = {k: v for k, v in entry["identity"].items() if v != "identical"}
            lines += ["", f"Identical arrays (old vs new): {', '.join(same)}."]
            if differ:
                lines.append(f"Differing: {differ}.")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
