"""The stages after the trace, stage by stage, on a finished bake's files: a re-encode timed (issue 58, parts 2 and 4).

    .venv/bin/python bench/reencode_stages.py LIGHTMAPS_DIR --label after [--atlas Lightmap]
    PYTHONPATH=/tmp/old .venv/bin/python bench/reencode_stages.py LIGHTMAPS_DIR --label before   # another version's code

A re-encode (`core.bake.reencode`: read the raw SH and texels files → denoise → stitch → encode →
stitch the encoded layers → write the encoded file, its preview images and the sidecar) runs the
post stages, the encoder and the writers of a bake on the real atlas without tracing, in minutes
instead of a bake's tens. The folder is copied to a scratch folder first (never changed). Each
stage function (`WRAPPED`, by module and name, the ones a code version has) is wrapped to record
its wall seconds, the CPU seconds of the whole process over it (every thread: CPU / wall is the
cores it used, robust to other jobs on the machine, unlike the wall time) and the peak RSS of the
process tree while it ran (sampled every 20 ms). Denoise on (Blender's OIDN library from the bpy
module, as bench/memory.py finds it), stitching on, the sidecar's encoder settings.

Results are merged by label into bench/results/reencode_stages.json, and
bench/results/reencode_stages.md is written from all labels (a table per label, then a
comparison of the first two).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import psutil

RESULTS = Path(__file__).resolve().parent / "results"

#: (modules, function, label): the stages, outermost first (a stage inside another is indented).
#: A function is wrapped in every module (of `modules`, "|"-separated) that looks it up by name.
WRAPPED = [
    ("files.lightmap_files", "read_texel_data", "read raw files"),
    ("files.lightmap_files", "read_seams", "read seams"),
    ("post", "apply", "post stages"),
    ("post.denoise.pages", "denoise_texels", "denoise"),
    ("post.seams.stitching", "stitch", "stitch SH"),
    ("encoding", "encode_atlas", "encode"),
    ("encoding.stage", "encode_images", "encode texels + fill layers"),
    ("encoding.TexelData", "fill", "dilation (TexelData.fill)"),
    ("post.seams.encoded_stitch", "stitch_encoded", "stitch encoded layers"),
    ("post.seams.encoded_stitch", "hidden_texels", "hidden texels"),
    ("post.seams.stitching|post.seams.encoded_stitch", "_metric", "seam metric"),
    ("post.seams.stitching|post.seams.encoded_stitch", "_solve", "CG solve"),
    ("files.lightmap_files", "write_atlas", "write"),
    ("files.lightmap_files", "stage_preview", "preview images"),
]


class Meter:
    """Wall, CPU seconds and peak tree RSS of nested calls."""

    def __init__(self):
        self.me = psutil.Process()
        self.open: list[list] = []
        self.rows: list[dict] = []
        self.peak = 0.0
        self.stop = False
        threading.Thread(target=self._sample, daemon=True).start()

    def rss(self) -> float:
        total = 0
        for p in [self.me, *self.me.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        return total / 2**20

    def _sample(self) -> None:
        while not self.stop:
            mb = self.rss()
            self.peak = max(self.peak, mb)
            for frame in list(self.open):
                frame[1] = max(frame[1], mb)
            time.sleep(0.02)

    def cpu(self) -> float:
        t = self.me.cpu_times()
        return t.user + t.system

    def wrap(self, owner, name: str, label: str) -> None:
        f = getattr(owner, name)

        @functools.wraps(f)
        def timed(*args, **kwargs):
            frame = [label, self.rss(), time.perf_counter(), self.cpu(), len(self.open)]
            self.open.append(frame)
            try:
                return f(*args, **kwargs)
            finally:
                self.open.remove(frame)
                wall, cpu = time.perf_counter() - frame[2], self.cpu() - frame[3]
                row = {"stage": label, "depth": frame[4], "seconds": wall, "cpu_seconds": cpu, "peak_mb": frame[1]}
                self.rows.append(row)
                print(f"{'  ' * frame[4]}{label}: {wall:.1f} s, {cpu:.1f} CPU s, peak {frame[1]:.0f} MB", flush=True)

        setattr(owner, name, timed)


def _owner(name: str):
    import importlib

    from hhd_lightmapper.core import encoding

    if name == "encoding.TexelData":
        return encoding.TexelData
    return importlib.import_module(f"hhd_lightmapper.core.{name}")


def run(folder: Path, atlas: str, scratch: Path, keep: Path | None = None) -> dict:
    import memory as memory_bench  # bench/memory.py: Blender's OIDN library without importing bpy
    from hhd_lightmapper.core import bake
    from hhd_lightmapper.core.encoding import EncoderSettings
    from hhd_lightmapper.core.files import lightmap_files

    work = scratch / "lightmaps"
    shutil.copytree(folder, work)
    meter = Meter()
    for modules, name, label in WRAPPED:
        for module in modules.split("|"):
            owner = _owner(module)
            if hasattr(owner, name):
                meter.wrap(owner, name, label)
    files = lightmap_files.AtlasFiles(work, atlas)
    encoder = EncoderSettings(**json.loads(files.sidecar.read_text())["encoder"])
    load = os.getloadavg()[0]
    t, cpu = time.perf_counter(), meter.cpu()
    bake.reencode(files, encoder, denoise=True, denoiser_library=memory_bench._denoiser_library(), stitch_seams=True)
    total, cpu = time.perf_counter() - t, meter.cpu() - cpu
    meter.stop = True
    if keep is not None:
        shutil.copytree(work, keep, dirs_exist_ok=True)
    return {
        "folder": str(folder),
        "rows": meter.rows,
        "seconds": total,
        "cpu_seconds": cpu,
        "peak_mb": meter.peak,
        "load": [load, os.getloadavg()[0]],
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


def _ordered(rows: list[dict]) -> list[dict]:
    """Rows by stage in WRAPPED order, each stage's calls summed (calls, seconds, CPU, peak)."""
    out = []
    for _, _, label in WRAPPED:
        mine = [r for r in rows if r["stage"] == label]
        if mine:
            out.append(
                {
                    "stage": label,
                    "depth": min(r["depth"] for r in mine),
                    "calls": len(mine),
                    "seconds": sum(r["seconds"] for r in mine),
                    "cpu_seconds": sum(r["cpu_seconds"] for r in mine),
                    "peak_mb": max(r["peak_mb"] for r in mine),
                }
            )
    return out


def report(results: dict) -> str:
    labels = sorted(results, key=lambda label: not label.startswith("before"))  # "before …" first
    lines = [
        "# The stages after the trace on the real atlas: a re-encode, stage by stage (issue 58, parts 2 and 4)",
        "",
        "`python bench/reencode_stages.py LIGHTMAPS_DIR --label L`: `core.bake.reencode` of a finished bake "
        "(read → denoise → stitch → encode → stitch encoded → write), the folder copied first; per stage "
        "(calls summed; an indented stage runs inside the one above) wall seconds, CPU seconds of the whole "
        "process over it (all threads; CPU / wall = the cores it used) and the peak RSS of the process tree while "
        "it ran. Other jobs shared the 2 cores (load averages below): under load the wall seconds are upper bounds "
        "and the CPU seconds grow too (contention: compare a stage whose code did not change, such as the write); "
        "the memory holds.",
        "",
    ]
    for label in labels:
        r = results[label]
        lines += [
            f"## {label}",
            "",
            f"{r['folder']}, {r['date']}, load average {r['load'][0]:.1f} → {r['load'][1]:.1f} on 2 cores: "
            f"**{r['seconds']:.0f} s**, {r['cpu_seconds']:.0f} CPU s ({r['cpu_seconds'] / r['seconds']:.2f} cores), "
            f"peak **{r['peak_mb']:.0f} MB**.",
            "",
            "| stage | calls | s | CPU s | cores | peak MB |",
            "|---|---|---|---|---|---|",
        ]
        for row in _ordered(r["rows"]):
            name = "  " * row["depth"] + row["stage"] if row["depth"] else row["stage"]
            name = name.replace("  ", "&nbsp;&nbsp;")
            cores = row["cpu_seconds"] / row["seconds"] if row["seconds"] > 0 else 0.0
            lines.append(
                f"| {name} | {row['calls']} | {row['seconds']:.1f} | {row['cpu_seconds']:.1f} | {cores:.2f} | "
                f"{row['peak_mb']:.0f} |"
            )
        lines.append("")
    if len(labels) >= 2:
        a, b = labels[0], labels[1]
        ra, rb = (
            {x["stage"]: x for x in _ordered(results[a]["rows"])},
            {x["stage"]: x for x in _ordered(results[b]["rows"])},
        )
        lines += [
            f"## {a} → {b}",
            "",
            f"| stage | {a} CPU s | {b} CPU s | {a} peak MB | {b} peak MB |",
            "|---|---|---|---|---|",
        ]
        for _, _, label in WRAPPED:
            if label in ra or label in rb:
                x, y = ra.get(label, {}), rb.get(label, {})
                lines.append(
                    f"| {label} | {x.get('cpu_seconds', 0.0):.1f} | {y.get('cpu_seconds', 0.0):.1f} | "
                    f"{x.get('peak_mb', 0.0):.0f} | {y.get('peak_mb', 0.0):.0f} |"
                )
        lines.append(
            f"| **whole re-encode** | {results[a]['cpu_seconds']:.0f} | {results[b]['cpu_seconds']:.0f} | "
            f"{results[a]['peak_mb']:.0f} | {results[b]['peak_mb']:.0f} |"
        )
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, nargs="?", help="a finished bake's lightmaps folder")
    ap.add_argument("--label", default="after")
    ap.add_argument("--atlas", default="Lightmap")
    ap.add_argument("--scratch", type=Path, help="work folder (default: a temporary one)")
    ap.add_argument("--keep", type=Path, help="copy the re-encoded folder here (to compare the files)")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args()
    path = RESULTS / "reencode_stages.json"
    if not args.report_only:
        if args.folder is None:
            ap.error("the folder is needed")
        with tempfile.TemporaryDirectory(dir=args.scratch) as scratch:
            result = run(args.folder, args.atlas, Path(scratch), args.keep)
        results = json.loads(path.read_text()) if path.is_file() else {}  # read now: another run may have written
        results[args.label] = result
        path.write_text(json.dumps(results, indent=1))
    results = json.loads(path.read_text()) if path.is_file() else {}
    (RESULTS / "reencode_stages.md").write_text(report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
