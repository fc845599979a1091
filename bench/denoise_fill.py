"""What the denoiser sees beside each chart: a smooth local mean, or the chart mirrored through its border.

    flock /tmp/bench.lock .venv/bin/python bench/denoise_fill.py        # classroom, staircase2 (≈ 12 min on 2 cores)
    .venv/bin/python bench/denoise_fill.py --scenes classroom --samples 64

Per scene (bench/denoise.py's scenes, receivers and 512² atlas): our reference as two halves of
`--reference` samples with their own seeds (its noise, the floor, removed in quadrature), then our
raw bake at each `--samples` (seed 0, the noise the tracer measured kept for the clamp, as a bake
runs it), denoised twice by `core.post.denoise.pages.denoise_texels`: with the smooth fill alone
(`MIRROR_RINGS` = 0, the fill until 2026-12-03) and with the chart mirrored through its border
(`MIRROR_RINGS` as shipped). Errors as bench/denoise.py measures them (relative RMSE of luminance
I_z over fully covered, unburied texels; each texel over max(reference, FLOOR × its mean)),
overall and per ring: a texel's chessboard distance to the nearest texel outside its chart
(ring 1, the chart's edge, is mostly partly covered and so not measured; ring 2 is the first
fully covered ring). Writes bench/results/denoise_fill.json and .md.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
#: Rings reported on their own; the deeper texels are reported together as "inner".
RINGS = (2, 3)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["classroom", "staircase2"])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=2)
    ap.add_argument("--reference", type=int, default=2048, help="our reference's samples, both halves")
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64, 256])
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import denoise as denoise_bench
    import hhd_lightmapper
    from hhd_lightmapper.bridge import denoiser as bridge_denoiser
    from hhd_lightmapper.core import parallel
    from hhd_lightmapper.core.post.denoise import fill, filtering

    hhd_lightmapper.register()
    denoiser = filtering.denoiser_for(bridge_denoiser.oidn_library(), parallel.resolve_threads(0))
    results = {"settings": vars(args), "mirror_rings": fill.MIRROR_RINGS, "scenes": {}}
    for name in args.scenes:
        results["scenes"][name] = measure(name, args, denoise_bench, denoiser)
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "denoise_fill.json").write_text(json.dumps(results, indent=2))
    (RESULTS / "denoise_fill.md").write_text(markdown(results))
    print(markdown(results))
    return 0


def measure(name: str, args, bench, denoiser) -> dict:
    """One scene: reference, then per sample count the raw bake and both fills' errors."""
    from hhd_lightmapper.core.post.denoise import fill

    atlas = bench.Atlas(bench.load_scene(name), args.resolution, args.padding)
    halves = [bench.our_bake(atlas, args.reference // 2, seed)[0] for seed in bench.REFERENCE_SEEDS]
    points = atlas.points
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    iz = lambda sh: bench.lum_iz(sh[keep], points.normal[keep])  # noqa: E731
    reference = bench.Reference(iz(halves[0].sh), iz(halves[1].sh), 0.0, args.reference)
    del halves
    ring = chart_rings(points)[keep]
    subsets = {"all": None, **{f"ring {r}": ring == r for r in RINGS}, "inner": ring > max(RINGS)}
    out = {
        "texels": int(len(points.texel)),
        "measured": int(keep.sum()),
        "measured_per_subset": {k: int(keep.sum() if v is None else v.sum()) for k, v in subsets.items()},
        "floor": reference.floor,
        "rows": [],
    }
    shipped = fill.MIRROR_RINGS
    for samples in args.samples:
        traced, _ = bench.our_bake(atlas, samples, 0)
        row = {"samples": samples, "raw": errors(reference, iz(traced.sh), subsets)}
        for label, rings in (("smooth", 0), ("mirrored", shipped)):
            fill.MIRROR_RINGS = rings
            try:
                t = time.perf_counter()
                clean, _, _ = bench.denoise_ours(traced, denoiser)
                row[label] = errors(reference, iz(clean), subsets)
                row[label]["seconds"] = time.perf_counter() - t
            finally:
                fill.MIRROR_RINGS = shipped
        out["rows"].append(row)
        print(
            f"[{name}] {samples} spp: "
            + ", ".join(f"{k} {row[k]['all']['rmse_corrected']:.2f}%" for k in ("raw", "smooth", "mirrored")),
            flush=True,
        )
    return out


def chart_rings(points) -> np.ndarray:
    """(P,) int: each baked texel's chessboard distance to the nearest texel outside the charts
    or the atlas (1 on a chart's edge): `core.dilate.nearest_source` grown from those texels."""
    from hhd_lightmapper.core import dilate

    covered = np.zeros(points.width * points.height, bool)
    covered[points.texel] = True
    outside = np.pad(~covered.reshape(points.height, points.width), 1, constant_values=True)
    h, w = outside.shape
    nearest = dilate.nearest_source(outside, max(h, w)).reshape(h, w)[1:-1, 1:-1].reshape(-1)[points.texel]
    y, x = np.divmod(points.texel, points.width)
    ny, nx = np.divmod(nearest, w)
    return np.maximum(np.abs(ny - 1 - y), np.abs(nx - 1 - x))


def errors(reference, x: np.ndarray, subsets: dict) -> dict:
    """bench/denoise.py's errors of I_z `x` over each subset, and its signed mean relative error (%)."""
    out = {}
    for key, subset in subsets.items():
        e = reference.errors(x, subset)
        sel = slice(None) if subset is None else subset
        e["mean_error"] = 100 * float(((x - reference.value) / reference.scale)[sel].mean())
        out[key] = e
    return out


def markdown(results: dict) -> str:
    lines = [
        "# The denoiser's fill beside each chart (`bench/denoise_fill.py`)",
        "",
        f"Smooth: the local mean of the chart's texels only (`MIRROR_RINGS` 0, until 2026-12-03); mirrored: the "
        f"chart mirrored through its border within {results['mirror_rings']} rings, then the smooth fill. "
        "Relative I_z RMSE, %, with the reference's noise removed (signed mean error in brackets), over fully "
        "covered unburied texels; ring k: chessboard distance k to the chart's edge (ring 1 is mostly partly "
        "covered, not measured).",
    ]
    for name, r in results["scenes"].items():
        subsets = list(r["measured_per_subset"])
        lines += [
            "",
            f"## {name}",
            "",
            f"{r['texels']} baked texels, {r['measured']} measured "
            f"({', '.join(f'{k} {v}' for k, v in r['measured_per_subset'].items() if k != 'all')}); "
            f"reference {results['settings']['reference']} spp, its noise {r['floor']:.2f}%.",
            "",
            "| spp | method | " + " | ".join(subsets) + " | denoise s |",
            "| ---: | --- | " + " | ".join("---:" for _ in subsets) + " | ---: |",
        ]
        for row in r["rows"]:
            for method in ("raw", "smooth", "mirrored"):
                cells = [
                    f"{row[method][k]['rmse_corrected']:.2f} ({row[method][k]['mean_error']:+.2f})" for k in subsets
                ]
                seconds = f"{row[method]['seconds']:.1f}" if "seconds" in row[method] else ""
                lines.append(f"| {row['samples']} | {method} | " + " | ".join(cells) + f" | {seconds} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
