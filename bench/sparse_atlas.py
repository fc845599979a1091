"""Peak memory and time of an almost empty atlas, stage by stage (issue 53, part 5); run by hand.

    python bench/sparse_atlas.py [--resolution 8192] [--preset draft] [--label before] [--dense] [--whole-reencode]

One 100 m × 1 cm quad, its lightmap UVs a strip one atlas long and two texels tall (~16k texels
at 8192²), lit by a sun and a sky, baked with a quality preset (Draft by default: no denoiser;
seams stitched, as every preset) through the product's own path (`bench/memory.py`'s stages:
bake points, trace, then `bake.finishing._write`: seams, image, raw files, post stages, encode, write),
with the raw files' and the encoded file's writes and their preview images timed apart.
`--dense`: `bench/memory.py`'s wavy sheet instead (one chart covering 60% of the atlas), the
check that a full atlas costs no more than before. Then the atlas is re-encoded from its files
(`bake.reencode`, the `encode` command's and the Re-encode operator's core), timed as the stage
"reencode" (not in the bake's total); `--whole-reencode` reads the files whole, as before
re-encoding read the window of their texels (`lightmap_files.texel_window` answering None).

Per stage: wall and CPU seconds and the stage's own peak RSS (VmHWM, reset at each stage start),
as `bench/memory.py` measures them; the machine is shared, so the load averages are recorded.
Appends a row per stage (and a "total") to bench/results/sparse_atlas.json under `--label`
(bench/results/sparse_atlas.md: the before → after), and with `--keep DIR` keeps the files (to
compare the bytes of two runs).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import memory as _memory  # noqa: E402  (bench/memory.py: the stage timer and the wavy sheet)
from hhd_lightmapper.core import bake, bakepoints, encoding, post, presets, tracer
from hhd_lightmapper.core import stages as stages_module  # noqa: E402
from hhd_lightmapper.core.bake import finishing  # noqa: E402
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.post.seams import geometry as seams
from hhd_lightmapper.core.scene import BakeScene, SunLight  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def quad(resolution: int, length: float = 100.0, width: float = 0.01):
    """The long thin quad (two triangles in the z = 0 plane) and its UVs: u along its length
    from texel 2 to resolution − 2, v over rows ~resolution/2 ± 0.7 (two texel rows)."""
    v = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0], [length, width, 0.0], [0.0, width, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    u0, u1 = 2.0 / resolution, 1.0 - 2.0 / resolution
    y0, y1 = (resolution / 2 - 0.7) / resolution, (resolution / 2 + 0.7) / resolution
    uv_v = np.array([[u0, y0], [u1, y0], [u1, y1], [u0, y1]])
    return v, f, uv_v[f]


def dense(resolution: int, fill: float = 0.6):
    """bench/memory.py's wavy sheet, one chart covering `fill` of the atlas."""
    v, f = _memory.sheet()
    tris = v[f]
    uv = 0.02 + np.sqrt(fill) * (tris[..., :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    return v, f, uv


class Nested(_memory.Stages):
    """`memory.Stages` with stages inside stages: `enter(name)` starts `name`, `leave()` returns
    to the stage it interrupted (each stage's figures are its own)."""

    def __init__(self):
        super().__init__()
        self.stack: list[str | None] = []

    def enter(self, name: str) -> None:
        self.stack.append(self.name)
        self.mark(name)

    def leave(self) -> None:
        self.mark(self.stack.pop())


def _nest(stages: Nested, owner, attr: str, name: str) -> None:
    f = getattr(owner, attr)

    def timed(*args, **kwargs):
        stages.enter(name)
        try:
            return f(*args, **kwargs)
        finally:
            stages.leave()

    setattr(owner, attr, staticmethod(timed) if isinstance(owner, type) else timed)


def table_rows(run: dict) -> list[dict]:
    """One run as the rows of bench/results/sparse_atlas.json: per stage (then "total") its wall
    and CPU seconds and peak RSS, with the run's label, scene, size, preset and load."""
    keys = ("label", "scene", "resolution", "texels", "preset", "exr_threads")
    head = {k: run[k] for k in keys}
    load = [round(x, 2) for x in run["load_average_before"]]
    rows = [
        {
            **head,
            "stage": name,
            "seconds": round(row["seconds"], 2),
            "cpu_seconds": round(row["cpu_seconds"], 2),
            "peak_rss_gb": round(row["peak_rss_mb"] / 1024, 3),
            "load_1min": load[0],
        }
        for name, row in run["stages"].items()
    ]
    total = {
        "seconds": round(run["seconds"], 2),
        "cpu_seconds": round(sum(r["cpu_seconds"] for r in rows), 2),
        "peak_rss_gb": round(run["peak_rss_mb"] / 1024, 3),
    }
    rows.append({**head, "stage": "total", **total, "load_1min": load[0]})
    if "reencode" in run:  # after the bake, apart from its total
        r = run["reencode"]
        figures = {k: round(r[k], 2) for k in ("seconds", "cpu_seconds")}
        stage = "reencode (whole files)" if r["whole"] else "reencode"
        rows.append(
            {**head, "stage": stage, **figures, "peak_rss_gb": round(r["peak_rss_mb"] / 1024, 3), "load_1min": load[0]}
        )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=8192)
    ap.add_argument("--preset", default="draft")
    ap.add_argument("--dense", action="store_true", help="bench/memory.py's sheet (60%% of the atlas) instead")
    ap.add_argument("--label", default="", help="the run's name in the results (e.g. before, after)")
    ap.add_argument("--out", type=Path, default=RESULTS / "sparse_atlas.json")
    ap.add_argument("--keep", type=Path, help="write the atlas's files into this folder (default: a temporary one)")
    ap.add_argument("--whole-reencode", action="store_true", help="re-encode from the whole files (as before windows)")
    args = ap.parse_args()
    load_before = os.getloadavg()
    v, f, uv = dense(args.resolution) if args.dense else quad(args.resolution)
    tris = v[f]
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    surface = bakepoints.SurfaceTriangles(tris, normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.6))
    scene = BakeScene(
        tris,
        np.full((len(f), 3), 0.6),
        lights=[SunLight(np.array([0.5, 0.3, 0.81]), np.full(3, 3.0))],
        world=np.array([0.3, 0.45, 0.7]),
    )
    preset = presets.get(args.preset)
    samples, bounces, noise_target, denoise = preset.knobs()
    library = _memory._denoiser_library() if denoise else ""
    settings = bake.PipelineSettings(
        trace=tracer.BakeSettings.from_samples(samples, bounces=bounces, noise_target=noise_target),
        denoise=denoise,
        denoiser_library=library,
    )
    atlas = bake.AtlasInput("Lightmap", args.resolution, args.resolution, surface, ["quad"])
    exr.set_threads(settings.trace.worker_threads)  # as `bake.run`
    stages = Nested()
    originals = [
        (owner, attr, getattr(owner, attr))
        for owner, attr in (
            (stages_module.TracedAtlas, "noise"),
            (seams, "find_seams"),
            (post, "apply"),
            (encoding, "encode_atlas"),
            (post, "stitch_encoded"),
            (lightmap_files, "write_atlas"),
            (bake.Staged, "raw"),
            (lightmap_files, "stage_preview"),
        )
    ]
    _memory._mark_at(stages, stages_module.TracedAtlas, "noise", "image")
    for module, attr, name in (
        (seams, "find_seams", "seams"),
        (post, "apply", "post"),
        (encoding, "encode_atlas", "encode"),
        (post, "stitch_encoded", "stitch_encoded"),
        (lightmap_files, "write_atlas", "write"),
    ):
        _memory._wrap(stages, module, attr, name, "files_other")
    _memory._wrap_method(stages, bake.Staged, "raw", "write_raw", "files_other")
    _nest(stages, lightmap_files, "stage_preview", "preview")  # inside write_raw and write
    t0 = time.perf_counter()
    stages.mark("ray_scene")
    ray_scene = bake.ray_scene_of(scene)
    stages.mark("bake_points")
    points = bake.points_of(atlas, ray_scene, 0)
    stages.mark("trace")
    traced = tracer.bake(points, scene, settings.trace, ray_scene=ray_scene, compact=True)
    texels = len(points.texel)
    del points
    stages.mark("files_other")
    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep or tmp
        with exr.Staging() as staging:
            result = finishing._write(staging, atlas, traced, settings, Path(out), 0.0, {})
            del traced
            staging.commit()
        stages.mark(None)
        total = time.perf_counter() - t0
        for owner, attr, f in originals:  # the re-encode is one stage: unwrap the bake's
            setattr(owner, attr, f)
        if args.whole_reencode:
            lightmap_files.texel_window = lambda files, shape: None
        stages.mark("reencode")
        bake.reencode(
            lightmap_files.AtlasFiles(Path(out), atlas.name),
            settings.encoder,
            settings.trace.threads,
            denoise=denoise,
            denoiser_library=library,
        )
        stages.mark(None)
    reencode = stages.rows.pop("reencode")
    run = {
        "label": args.label,
        "scene": "sheet" if args.dense else "quad",
        "resolution": args.resolution,
        "texels": int(texels),
        "preset": args.preset,
        "exr_threads": settings.trace.worker_threads,
        "seconds": total,
        "peak_rss_mb": max(r["peak_rss_mb"] for r in stages.rows.values()),
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "cpus": os.cpu_count(),
        "warnings": result.warnings,
        "stages": stages.rows,
        "reencode": {**reencode, "whole": args.whole_reencode},
    }
    print(f"{args.resolution}² {run['scene']}, {texels} texels, {args.preset}: {total:.1f} s")
    print(f"  load {load_before} → {run['load_average_after']}")
    for stage, row in stages.rows.items():
        print(
            f"  {stage:15s} {row['seconds']:7.1f} s  cpu {row['cpu_seconds']:7.1f} s   "
            f"peak {row['peak_rss_mb'] / 1024:6.2f} GB  after {row['rss_after_mb'] / 1024:6.2f} GB"
        )
    print(f"  peak RSS over the stages {run['peak_rss_mb'] / 1024:.2f} GB")
    print(
        f"  re-encode{' (whole files)' if args.whole_reencode else ''}: {reencode['seconds']:.2f} s  "
        f"cpu {reencode['cpu_seconds']:.2f} s   peak {reencode['peak_rss_mb'] / 1024:.2f} GB"
    )
    rows = json.loads(args.out.read_text()) if args.out.is_file() else []
    rows += table_rows(run)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
