"""What stands between the stages after the trace and issue 58's targets, on a finished bake's files.

    .venv/bin/python bench/post_floor.py LIGHTMAPS_DIR [--atlas Lightmap] [--label L]

Two questions, answered from a real atlas (e.g. the bedroom at 4096², `bench/end_to_end.py
--scratch DIR`'s lightmaps folder), without tracing:

1. **Memory**: the post stages work on `encoding.TexelData`, dense images of the atlas's window.
   After reading the raw files (`lightmap_files.read_texel_data`, as a re-encode does) it reports
   the process's RSS and each image's bytes, against the bytes the same values take stored per
   baked texel (9 × 3 float32 SH, 3 float32 normal, plus a 4-byte index per texel).
2. **Denoise**: `denoise.pages.denoise_texels` on that data with every OIDN call timed (wall and
   the process's CPU seconds over the call, pixels handed to it) against the whole stage, and the
   page layout's efficiency: lit chart texels (the ones OIDN denoises), the charts' rectangles
   with their margins, and the pages' pixels (what OIDN is paid for, five calls per page).

Results are merged by label into bench/results/post_floor.json; bench/results/post_floor.md is
written from every label.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import psutil

from hhd_lightmapper.core.colour import LUMINANCE
from hhd_lightmapper.core.files import lightmap_files
from hhd_lightmapper.core.post.denoise import filtering, layout, pages
from hhd_lightmapper.core.post.denoise.oidn import find_library

RESULTS = Path(__file__).resolve().parent / "results"
MB = 2**20


def _oidn_library() -> str:
    """Blender's OIDN library from the bpy module's folders, found without importing bpy."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        return ""
    module = Path(spec.origin).parent
    path = find_library([module / "lib", module])
    return "" if path is None else str(path)


def memory(data, rss_mb: float) -> dict:
    """The TexelData's images against the same values per baked texel."""
    baked = int(data.baked.sum())
    images = {k: getattr(data, k) for k in ("sh", "normal", "coverage", "noise", "extra_sources")}
    dense = {k: round(v.nbytes / MB, 1) for k, v in images.items() if v is not None}
    compact_sh = baked * 9 * 3 * 4 / MB
    compact_normal = baked * 3 * 4 / MB
    index = baked * 4 / MB
    return {
        "window": list(data.coverage.shape),
        "baked_texels": baked,
        "rss_after_read_mb": round(rss_mb, 1),
        "dense_mb": dense,
        "per_texel_mb": {
            "sh": round(compact_sh, 1),
            "normal": round(compact_normal, 1),
            "texel index": round(index, 1),
        },
        "sh_and_normal_saved_mb": round(dense["sh"] + dense["normal"] - compact_sh - compact_normal - index, 1),
    }


def page_efficiency(data) -> dict:
    """Lit chart texels, the rectangles' area with their margins, and the pages' pixels."""
    h, w = data.coverage.shape
    labels, n = layout.label_charts(data.coverage != 0.0)
    labels = np.where(data.baked, labels, -1)
    flat = labels.reshape(-1)
    texels = np.flatnonzero(flat >= 0)
    lum = data.sh.reshape(h * w, 9, 3)[texels, 0, :].astype(np.float64) @ LUMINANCE
    count = np.bincount(flat[texels], minlength=n)
    brightness = np.bincount(flat[texels], lum, minlength=n) / np.maximum(count, 1)
    lit = brightness > layout.BLACK
    chart_pages = layout.layout(labels, n, brightness, data.atlas_shape[1])
    rect_area = sum(r[2] * r[3] for p in chart_pages for r in p.rects)
    page_px = sum(p.shape[0] * p.shape[1] for p in chart_pages)
    return {
        "charts": int(n),
        "lit_charts": int(lit.sum()),
        "lit_texels": int(count[lit].sum()),
        "rectangles_px": int(rect_area),
        "pages": len(chart_pages),
        "page_px": int(page_px),
        "page_px_per_lit_texel": round(page_px / max(int(count[lit].sum()), 1), 3),
    }


def denoise(data) -> dict:
    """The denoise stage with its OIDN calls timed."""
    denoiser = filtering.denoiser_for(_oidn_library(), 0)
    me = psutil.Process()
    cpu = lambda: sum(me.cpu_times()[:2])  # noqa: E731
    calls = {"calls": 0, "seconds": 0.0, "cpu_seconds": 0.0, "pixels": 0}
    plain = denoiser.denoise

    def timed(image, **kwargs):
        t, c = time.perf_counter(), cpu()
        out = plain(image, **kwargs)
        calls["calls"] += 1
        calls["seconds"] += time.perf_counter() - t
        calls["cpu_seconds"] += cpu() - c
        calls["pixels"] += image.shape[0] * image.shape[1]
        return out

    denoiser.denoise = timed
    try:
        t, c = time.perf_counter(), cpu()
        _, report = pages.denoise_texels(data, denoiser, in_place=True)
        wall, spent = time.perf_counter() - t, cpu() - c
    finally:
        del denoiser.denoise
    return {
        "seconds": round(wall, 2),
        "cpu_seconds": round(spent, 2),
        "oidn_calls": calls["calls"],
        "oidn_seconds": round(calls["seconds"], 2),
        "oidn_cpu_seconds": round(calls["cpu_seconds"], 2),
        "oidn_mpx": round(calls["pixels"] / 1e6, 2),
        "oidn_share": round(calls["seconds"] / wall, 3) if wall else None,
        "oidn_cpu_seconds_per_mpx": round(calls["cpu_seconds"] / max(calls["pixels"] / 1e6, 1e-9), 2),
        "report": report.sidecar(),
    }


def report(results: dict) -> str:
    lines = [
        "# What stands between the stages after the trace and issue 58's targets",
        "",
        "`python bench/post_floor.py LIGHTMAPS_DIR --label L` (the module docstring has the method). Per label:",
        "",
    ]
    for label, r in results.items():
        m, p, d = r["memory"], r["pages"], r["denoise"]
        lines += [
            f"## {label}",
            "",
            f"{r['folder']}, {r['date']}, load {r['load'][0]:.2f} → {r['load_after'][0]:.2f} on {r['cpus']} cores.",
            "",
            f"**Memory.** Window {m['window'][0]}×{m['window'][1]}, {m['baked_texels']} baked texels; "
            f"RSS after reading the raw files {m['rss_after_read_mb']:.0f} MB.",
            "",
            "| image | dense MB | per baked texel MB |",
            "|---|---|---|",
        ]
        for k, v in m["dense_mb"].items():
            lines.append(f"| {k} | {v:.0f} | {m['per_texel_mb'].get(k, '–')} |")
        lines += [
            f"| texel index | – | {m['per_texel_mb']['texel index']} |",
            "",
            f"SH and normal stored per baked texel would take {m['sh_and_normal_saved_mb']:.0f} MB less.",
            "",
            f"**Denoise.** {d['seconds']:.1f} s, {d['cpu_seconds']:.1f} CPU s; OIDN: {d['oidn_calls']} calls, "
            f"{d['oidn_mpx']:.1f} Mpx, {d['oidn_seconds']:.1f} s ({d['oidn_share']:.0%} of the stage), "
            f"{d['oidn_cpu_seconds']:.1f} CPU s ({d['oidn_cpu_seconds_per_mpx']:.2f} CPU s per Mpx).",
            "",
            f"**Pages.** {p['lit_charts']} lit charts of {p['charts']}, {p['lit_texels']} lit texels; their "
            f"rectangles with margins {p['rectangles_px']} px; {p['pages']} pages, {p['page_px']} px "
            f"({p['page_px_per_lit_texel']:.2f} page pixels per lit texel).",
            "",
        ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="a finished bake's lightmaps folder")
    ap.add_argument("--atlas", default="Lightmap")
    ap.add_argument("--label", default="bedroom 4096²")
    args = ap.parse_args()
    import os

    load = os.getloadavg()
    files = lightmap_files.AtlasFiles(args.folder, args.atlas)
    data = lightmap_files.read_texel_data(files, crop=True)
    entry = {
        "folder": str(args.folder),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "load": list(load),
        "cpus": os.cpu_count(),
        "memory": memory(data, psutil.Process().memory_info().rss / MB),
        "pages": page_efficiency(data),
    }
    entry["denoise"] = denoise(data)
    entry["load_after"] = list(os.getloadavg())
    out = RESULTS / "post_floor.json"
    results = json.loads(out.read_text()) if out.exists() else {}
    results[args.label] = entry
    out.write_text(json.dumps(results, indent=1, ensure_ascii=False) + "\n")
    (RESULTS / "post_floor.md").write_text(report(results))
    print(report({args.label: entry}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
