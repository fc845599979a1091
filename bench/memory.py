"""Peak memory of a 4096² atlas bake (bake points + tracer + encode + files), run by hand.

    python bench/memory.py [--resolution 4096] [--fill 0.6] [--samples 4]

A 200 × 200-quad wavy sheet (80k triangles) mapped as one chart covering 60% of the atlas, lit by
a sun and a sky;
prints texels, seconds and peak resident memory after each stage, writes bench/results/memory.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import bake, bakepoints, rays, tracer
from hhd_lightmapper.core.scene import BakeScene, SunLight

RESULTS = Path(__file__).resolve().parent / "results"


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def sheet(n=200, size=20.0):
    u = np.linspace(0, size, n + 1)
    x, y = np.meshgrid(u, u)
    z = 0.3 * np.sin(x) * np.cos(0.7 * y)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 2, i.ravel() + n + 1
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=4096)
    ap.add_argument(
        "--fill", type=float, default=0.6, help="fraction of the atlas the sheet covers (xatlas typically packs 60%)"
    )
    ap.add_argument("--samples", type=int, default=4)
    args = ap.parse_args()
    v, f = sheet()
    rows = {}
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
    t = time.perf_counter()
    points = bakepoints.build(surface, width, height, occluders=rays.RayScene(tris))
    rows["bake_points"] = (time.perf_counter() - t, peak_mb())
    t = time.perf_counter()
    result = tracer.bake(
        points, scene, tracer.BakeSettings(samples=args.samples, pass_samples=min(16, args.samples), bounces=1)
    )
    rows["trace"] = (time.perf_counter() - t, peak_mb())
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        from hhd_lightmapper.core import encoding, exr

        data = encoding.TexelData.from_points(points, result.sh)
        del result  # as bake.run: the SH lives on as float32 images only
        encoded = encoding.encode_atlas(data, encoding.for_settings(bake.EncoderSettings()))
        del data
        with exr.Staging() as staging:
            bake.lightmap_files.write_atlas(staging, bake.lightmap_files.AtlasFiles(Path(out), "Lightmap"), encoded, {})
            staging.commit()
    rows["encode_and_write"] = (time.perf_counter() - t, peak_mb())
    print(f"{width}×{height} atlas, {len(points.texel)} texels, {len(f)} triangles, {args.samples} spp")
    for stage, (seconds, mb) in rows.items():
        print(f"  {stage:18s} {seconds:7.1f} s   peak RSS so far {mb / 1024:6.2f} GB")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "memory.json").write_text(
        json.dumps(
            {
                "resolution": args.resolution,
                "texels": int(len(points.texel)),
                "stages": {k: {"seconds": s, "peak_rss_mb": m} for k, (s, m) in rows.items()},
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
