"""Peak memory and time of a 4096² atlas bake, stage by stage, through the product's own path; run by hand.

    python bench/memory.py [--resolution 4096] [--fill 0.6] [--samples 4] [--no-post] [--out FILE]

A 200 × 200-quad wavy sheet (80k triangles) mapped as one chart covering 60% of the atlas, lit by
a sun and a sky. Stages as `bake.run` runs them: bake points (`bake.points_of`), trace
(`tracer.bake(..., compact=True)`, streamed), then the atlas's files (`bake.finishing._write`: seams,
image, post stages, encode, write).
Post stages as the Production preset (`core.presets`): denoised (Blender's OIDN, found as the
bpy side finds it) and stitched; `--no-post` switches both off.

Per stage: wall seconds, CPU seconds (every thread of the process; the machine is shared, so wall
time is inflated by the load, recorded beside it) and the stage's own peak resident memory (the
kernel's high-water mark VmHWM, reset at each stage start through /proc/self/clear_refs), plus the
resident memory when it ended. Writes bench/results/memory-<resolution>[-nopost].json (or --out);
bench/results/memory.json and memory.md hold the before → after of issue 23's work.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bake, bakepoints, encoding, post, presets, tracer
from hhd_lightmapper.core import stages as stages_module
from hhd_lightmapper.core.bake import finishing
from hhd_lightmapper.core.files import lightmap_files
from hhd_lightmapper.core.post.denoise import oidn
from hhd_lightmapper.core.post.seams import geometry
from hhd_lightmapper.core.scene import BakeScene, SunLight

RESULTS = Path(__file__).resolve().parent / "results"


def _status(key: str) -> float:
    """A /proc/self/status memory figure, MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Stages:
    """Seconds, CPU seconds and peak RSS per stage: `mark(name)` ends the current stage and
    starts `name` (resetting the kernel's peak RSS, so each stage's peak is its own)."""

    def __init__(self):
        self.rows: dict[str, dict] = {}
        self.name: str | None = None
        self.t = self.cpu = 0.0

    def mark(self, name: str | None) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if self.name is not None:
            row = self.rows.setdefault(self.name, {"seconds": 0.0, "cpu_seconds": 0.0, "peak_rss_mb": 0.0})
            row["seconds"] += now - self.t
            row["cpu_seconds"] += cpu - self.cpu
            row["peak_rss_mb"] = max(row["peak_rss_mb"], _status("VmHWM"))
            row["rss_after_mb"] = _status("VmRSS")
        Path("/proc/self/clear_refs").write_text("5")  # VmHWM := VmRSS
        self.name, self.t, self.cpu = name, time.perf_counter(), time.process_time()


def _wrap(stages: Stages, module, attr: str, name: str, after: str) -> None:
    """Time `module.attr` (a function the pipeline looks up at call time) as stage `name`."""
    owner, key = (module, attr) if "." not in attr else (getattr(module, attr.split(".")[0]), attr.split(".")[1])
    f = getattr(owner, key)

    def timed(*args, **kwargs):
        stages.mark(name)
        try:
            return f(*args, **kwargs)
        finally:
            stages.mark(after)

    setattr(owner, key, staticmethod(timed) if isinstance(owner, type) else timed)


def _wrap_method(stages: Stages, cls: type, attr: str, name: str, after: str) -> None:
    """Time method `cls.attr` as stage `name`, as `_wrap` times a function."""
    f = getattr(cls, attr)

    def timed(self, *args, **kwargs):
        stages.mark(name)
        try:
            return f(self, *args, **kwargs)
        finally:
            stages.mark(after)

    setattr(cls, attr, timed)


def _mark_at(stages: Stages, owner, attr: str, name: str) -> None:
    """Start stage `name` when `owner.attr` (a method the pipeline looks up at call time) is
    called, without ending it there: unlike `_wrap`, no frame of ours holds the call's arguments,
    which the callee may spend (`TexelData.from_traced` drops the bake points)."""
    f = getattr(owner, attr)

    def marked(*args, **kwargs):
        stages.mark(name)
        return f(*args, **kwargs)

    setattr(owner, attr, marked)


def sheet(n=200, size=20.0):
    u = np.linspace(0, size, n + 1)
    x, y = np.meshgrid(u, u)
    z = 0.3 * np.sin(x) * np.cos(0.7 * y)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 2, i.ravel() + n + 1
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _denoiser_library() -> str:
    """Blender's OIDN library from the bpy module's folders (`bridge.denoiser.install_dirs`),
    found without importing bpy: loading Blender adds ~0.28 GB that a bake inside Blender has
    anyway and that the runs without post stages do not load."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        return ""
    module = Path(spec.origin).parent
    path = oidn.find_library([module / "lib", module])
    return "" if path is None else str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=4096)
    ap.add_argument(
        "--fill", type=float, default=0.6, help="fraction of the atlas the sheet covers (xatlas typically packs 60%%)"
    )
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--bounces", type=int, default=1)
    ap.add_argument("--no-post", action="store_true", help="no denoiser, no seam stitching")
    ap.add_argument("--out", type=Path, help="default bench/results/memory-<resolution>[-nopost].json")
    ap.add_argument("--keep", type=Path, help="write the atlas's files into this folder (default: a temporary one)")
    args = ap.parse_args()
    if args.out is None:
        args.out = RESULTS / f"memory-{args.resolution}{'-nopost' if args.no_post else ''}.json"
    load_before = os.getloadavg()
    v, f = sheet()
    width = height = args.resolution
    tris = v[f]
    # one planar chart (the sheet's xy), covering `fill` of the atlas: xatlas at this size spends
    # minutes on retries (see bench/unwrap_raster.py for unwrap timings), memory is the point here
    uv = 0.02 + np.sqrt(args.fill) * (tris[..., :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    surface = bakepoints.SurfaceTriangles(tris, normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.6))
    scene = BakeScene(
        tris,
        np.full((len(f), 3), 0.6),
        lights=[SunLight(np.array([0.5, 0.3, 0.81]), np.full(3, 3.0))],
        world=np.array([0.3, 0.45, 0.7]),
    )
    production = presets.get("production")
    post_on = not args.no_post
    library = _denoiser_library() if post_on else ""
    settings = bake.PipelineSettings(
        trace=tracer.BakeSettings.from_samples(args.samples, bounces=args.bounces),
        denoise=post_on and production.denoise,
        denoiser_library=library,
        stitch_seams=post_on,
    )
    atlas = bake.AtlasInput("Lightmap", width, height, surface, ["sheet"])
    stages = Stages()
    # the image stage: from the noise image (`bake.finishing._finish_files` takes it first) to the post stages
    _mark_at(stages, stages_module.TracedAtlas, "noise", "image")
    for module, attr, name in (
        (geometry, "find_seams", "seams"),
        (post, "apply", "post"),
        (encoding, "encode_atlas", "encode"),
        (post, "stitch_encoded", "stitch_encoded"),
        (lightmap_files, "write_atlas", "write"),
    ):
        _wrap(stages, module, attr, name, "files_other")
    _wrap_method(stages, bake.Staged, "raw", "write_raw", "files_other")  # the raw files, before the post stages
    start_rss = _status("VmRSS")
    stages.mark("ray_scene")
    ray_scene = bake.ray_scene_of(scene)
    stages.mark("bake_points")
    points = bake.points_of(atlas, ray_scene, 0)
    stages.mark("trace")
    traced = tracer.bake(points, scene, settings.trace, ray_scene=ray_scene, compact=True)  # as `bake.run`
    texels = len(points.texel)
    del points  # as `bake.run`: the traced atlas holds them until they are imaged
    stages.mark("files_other")
    with tempfile.TemporaryDirectory() as tmp:
        from hhd_lightmapper.core.files import exr

        out = args.keep or tmp

        with exr.Staging() as staging:
            result = finishing._write(staging, atlas, traced, settings, Path(out), 0.0, {})
            del traced
            staging.commit()
        stages.mark(None)
    report = {
        "resolution": args.resolution,
        "texels": int(texels),
        "triangles": int(len(f)),
        "samples": args.samples,
        "bounces": args.bounces,
        "denoise": settings.denoise,
        "denoiser_found": bool(library),
        "stitch_seams": settings.stitch_seams,
        "warnings": result.warnings,
        "peak_rss_mb": max(r["peak_rss_mb"] for r in stages.rows.values()),
        "rss_at_start_mb": start_rss,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "cpus": os.cpu_count(),
        "stages": stages.rows,
    }
    print(f"{width}×{height} atlas, {texels} texels, {len(f)} triangles, {args.samples} spp, post {post_on}")
    print(f"  load {load_before} → {report['load_average_after']}")
    for stage, row in stages.rows.items():
        print(
            f"  {stage:15s} {row['seconds']:7.1f} s  cpu {row['cpu_seconds']:7.1f} s   "
            f"peak {row['peak_rss_mb'] / 1024:6.2f} GB  after {row['rss_after_mb'] / 1024:6.2f} GB"
        )
    print(f"  peak RSS over the stages {max(r['peak_rss_mb'] for r in stages.rows.values()) / 1024:.2f} GB")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
