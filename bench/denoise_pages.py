"""How the denoiser packs charts into pages, and how far its noise clamp lets it move a texel.

    flock /tmp/bench.lock .venv/bin/python bench/denoise_pages.py        # classroom, staircase2 (≈ 15 min on 2 cores)
    .venv/bin/python bench/denoise_pages.py --scenes classroom --samples 64 --seeds 0

Per scene (bench/denoise.py's scenes, receivers and 512² atlas): our reference as two halves of
`--reference` samples with their own seeds (its noise, the floor, removed in quadrature), then our
raw bake at each `--samples` and `--seeds` (the noise the tracer measured kept for the clamp, as a
bake runs it), denoised by `core.post.denoise.pages.denoise_texels` in each of VARIANTS, each one change on
the one before it, but the last two, which each leave one of `shipped`'s changes out:

- `shelves`: charts shelf-packed (rows as tall as their first, tallest chart, 512 texels wide; the
  packing until 2026-12-03, `shelves` below) and the noise clamp the same on every texel, its
  standard error the spread between passes as measured (`spread`);
- `skyline`: charts skyline-packed into square pages (`denoise._skyline`, as shipped);
- `small-chart`: and the clamp tightened on charts under `SMALL_CHART` baked texels;
- `shipped`: and the clamp EDGE_CLAMP as wide within EDGE_RINGS of a chart's edge, and the standard
  error widened for its own degrees of freedom (`TracedAtlas.noise`);
- `no-edge`: shipped but the edge; `no-widening`: shipped but the widening.

Errors as bench/denoise.py measures them (relative RMSE of luminance I_z over fully covered,
unburied texels, each over max(reference, FLOOR × its mean), the reference's noise removed), per
seed and their mean; the denoise stage's seconds (median over the seeds) and its page texels.
Layouts differ in which charts sit beside which, so a layout's error moves a little with it
whatever its density: `--seeds` averages the sampling noise, not that. Writes
bench/results/denoise_pages.json and .md.
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
VARIANTS = ("shelves", "skyline", "small-chart", "shipped", "no-edge", "no-widening")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["classroom", "staircase2"])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=2)
    ap.add_argument("--reference", type=int, default=2048, help="our reference's samples, both halves")
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 3, 4])
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import denoise as denoise_bench
    import hhd_lightmapper
    from hhd_lightmapper.bridge import denoiser as bridge_denoiser
    from hhd_lightmapper.core import parallel
    from hhd_lightmapper.core.post.denoise import filtering, noise_clamp

    hhd_lightmapper.register()
    denoiser = filtering.denoiser_for(bridge_denoiser.oidn_library(), parallel.resolve_threads(0))
    results = {
        "settings": vars(args),
        "small_chart": noise_clamp.SMALL_CHART,
        "edge_rings": noise_clamp.EDGE_RINGS,
        "edge_clamp": noise_clamp.EDGE_CLAMP,
        "scenes": {},
    }
    for name in args.scenes:
        results["scenes"][name] = measure(name, args, denoise_bench, denoiser)
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "denoise_pages.json").write_text(json.dumps(results, indent=2))
    (RESULTS / "denoise_pages.md").write_text(markdown(results))
    print(markdown(results))
    return 0


def measure(name: str, args, bench, denoiser) -> dict:
    """One scene: reference, then per sample count and seed the raw bake and each variant's error."""
    atlas = bench.Atlas(bench.load_scene(name), args.resolution, args.padding)
    halves = [bench.our_bake(atlas, args.reference // 2, seed)[0] for seed in bench.REFERENCE_SEEDS]
    points = atlas.points
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    iz = lambda sh: bench.lum_iz(sh[keep], points.normal[keep])  # noqa: E731
    reference = bench.Reference(iz(halves[0].sh), iz(halves[1].sh), 0.0, args.reference)
    del halves
    out = {"texels": int(len(points.texel)), "measured": int(keep.sum()), "floor": reference.floor, "rows": []}
    for samples in args.samples:
        row: dict = {"samples": samples, "raw": []} | {
            v: {"error": [], "seconds": [], "page_texels": 0} for v in VARIANTS
        }
        for seed in args.seeds:
            traced, _ = bench.our_bake(atlas, samples, seed)
            row["raw"].append(reference.errors(iz(traced.sh))["rmse_corrected"])
            for v in VARIANTS:
                with variant(v):
                    t = time.perf_counter()
                    clean, report, _ = bench.denoise_ours(traced, denoiser)
                    row[v]["seconds"].append(time.perf_counter() - t)
                row[v]["error"].append(reference.errors(iz(clean))["rmse_corrected"])
                row[v]["page_texels"] = report.page_texels
        out["rows"].append(row)
        print(
            f"[{name}] {samples} spp: raw {np.mean(row['raw']):.2f}%, "
            + ", ".join(f"{v} {np.mean(row[v]['error']):.2f}% {np.median(row[v]['seconds']):.2f} s" for v in VARIANTS),
            flush=True,
        )
    return out


class variant:
    """Context: the denoiser switched to `name` of VARIANTS, put back as shipped on leaving."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        from hhd_lightmapper.core import stages
        from hhd_lightmapper.core.post.denoise import layout, noise_clamp

        self.saved = (layout._skyline, noise_clamp.SMALL_CHART, noise_clamp.EDGE_CLAMP, stages.TracedAtlas.noise)
        if self.name == "shelves":
            layout._skyline = shelves
        if self.name in ("shelves", "skyline"):
            noise_clamp.SMALL_CHART = 1
        if self.name in ("shelves", "skyline", "small-chart", "no-edge"):
            noise_clamp.EDGE_CLAMP = 1.0
        if self.name in ("shelves", "skyline", "small-chart", "no-widening"):
            stages.TracedAtlas.noise = spread
        return self

    def __exit__(self, *exc):
        from hhd_lightmapper.core import stages
        from hhd_lightmapper.core.post.denoise import layout, noise_clamp

        layout._skyline, noise_clamp.SMALL_CHART, noise_clamp.EDGE_CLAMP, stages.TracedAtlas.noise = self.saved
        return False


def spread(traced) -> np.ndarray:
    """`TracedAtlas.noise` until 2026-12-03 (pm): the standard error of the luminance L0 as the
    spread between passes measures it, not widened; NaN below NOISE_PASSES passes."""
    from hhd_lightmapper.core import stages
    from hhd_lightmapper.core.colour import LUMINANCE

    per_pass = traced.samples // traced.passes if traced.passes else 1
    error = traced.sh_error[:, 0, :].astype(np.float64) @ LUMINANCE
    known = traced.texel_samples >= stages.NOISE_PASSES * per_pass
    return np.where(known, error, np.nan).astype(np.float32)


def shelves(charts: np.ndarray, rh, rw, ry, rx, width: int) -> list:
    """The packing until 2026-12-03: `charts` (sorted by decreasing height) left to right in
    shelves as tall as their first chart, pages at most `width` wide (or the widest chart), a
    page closed once its shelves reach PAGE_SIZE."""
    from hhd_lightmapper.core.post.denoise import layout

    width = max(width, int(rw[charts].max()))
    pages: list = []
    page, x, y, shelf = None, 0, 0, 0
    for c in charts.tolist():
        if page is None or x + rw[c] > width:
            y, x = y + shelf, 0
            shelf = int(rh[c])
            if page is None or y >= layout.PAGE_SIZE:
                page, y = layout.Page((0, 0)), 0
                pages.append(page)
        page.charts.append(c)
        page.rects.append((int(ry[c]), int(rx[c]), int(rh[c]), int(rw[c])))
        page.corners.append((y, x))
        x += int(rw[c])
        page.shape = (max(page.shape[0], y + shelf), max(page.shape[1], x))
    return pages


def markdown(results: dict) -> str:
    lines = [
        "# The denoiser's pages and its noise clamp (`bench/denoise_pages.py`)",
        "",
        "Shelves: rows as tall as their tallest chart (the packing until 2026-12-03), the noise clamp alike on "
        "every texel, its standard error the spread between passes; skyline: square pages, each chart where it "
        f"lands lowest; small-chart: and the clamp tightened by √(texels / {results['small_chart']}) on smaller "
        f"charts; shipped: and the clamp {results.get('edge_clamp', 1.0)}× as wide within "
        f"{results.get('edge_rings', 0)} texels of a chart's edge, the standard error widened by √(ν / (ν − 2)) "
        "for its ν = passes − 1 degrees of freedom; no-edge / no-widening: shipped without one of the two. "
        "Relative I_z RMSE, %, with the reference's noise removed, per seed (their mean in bold); denoise "
        "seconds: median over the seeds.",
    ]
    for name, r in results["scenes"].items():
        lines += [
            "",
            f"## {name}",
            "",
            f"{r['texels']} baked texels, {r['measured']} measured; reference "
            f"{results['settings']['reference']} spp, its noise {r['floor']:.2f}%; seeds "
            f"{', '.join(map(str, results['settings']['seeds']))}.",
            "",
            "| spp | raw | "
            + " | ".join(VARIANTS)
            + " | "
            + " | ".join(f"{v}: s / page texels" for v in VARIANTS)
            + " |",
            "| ---: | ---: | " + " | ".join(["---:"] * (2 * len(VARIANTS))) + " |",
        ]
        for row in r["rows"]:
            cells = [f"{np.mean(row['raw']):.2f}"]
            cells += [
                " / ".join(f"{e:.2f}" for e in row[v]["error"]) + f" **{np.mean(row[v]['error']):.2f}**"
                for v in VARIANTS
            ]
            cells += [f"{np.median(row[v]['seconds']):.2f} / {row[v]['page_texels']}" for v in VARIANTS]
            lines.append(f"| {row['samples']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
