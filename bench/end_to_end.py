"""The whole button, stage by stage: a CLI bake timed and measured end to end (issue 58, part 1); run by hand.

    python bench/end_to_end.py [--cases room-256-draft room-128-draft bedroom-1024-draft bedroom-4096-production]
                               [--scratch DIR] [--not-run CASE WHY] [--report-only]

Each case runs `python -m hhd_lightmapper.cli FILE.blend bake --unwrap ... --preset P --objects
<every mesh>` as a user would, in a child process, on a copy of the .blend in a scratch folder
(the shared scenes are never touched):
- room-128-draft: scenekit's demo room (`scenekit.scenes.demo_room`, as tools/demo.py builds it),
  Draft; the CLI takes `--resolution` 256–8192 only, so this small atlas is sized by texel density
  (`--texel-density 2.35`, which lets xatlas size the atlas freely: 182², ~2.4k texels baked);
- room-256-draft: the same room at the CLI's smallest `--resolution`, 256²;
- bedroom-1024-draft, bedroom-4096-production: the shared bedroom, all its meshes;
- level-4096-production: three copies of the bedroom side by side (213 meshes, 1.35M polygons),
  a level of the size of the issue's kitchen, Production at 4096²;
- bedroom-4096-post: the Production bake at 4 samples per texel: the stages around the trace as
  at 4096² Production (the same texels, denoise, stitching, files) in a fifth of the time, for
  working on them; its shares are not the Production bake's.

The child is this script (`--child`), which installs markers and then runs the CLI's own
`standalone`: each wrapped stage function prints `@e2e <stage>` on entry (unwrap `cli.commands.unwrap`,
scene read `BakeSession.__init__`, the inward-faces check `bake.check_inward`, BVH
`bake.ray_scene_of` (Embree may finish the build on its threads during the bake points), bake
points `bake.points_of` (as `bake.runners` calls it), trace `tracer.bake`, seams `seams.find_seams`, the denoise and stitch
post stages) and `@e2e other` on return, and the console
progress prints whenever its stage changes (raw files, preview images, encode, write), not only
every 5% (`core.console.ConsoleProgress`). The parent timestamps every line as it arrives; a
stage lasts from its line to the next stage's line. Lines the markers do not name go to the stage
their words name; "start" is the interpreter's start-up and the .blend's opening, "finish" the
time from the last progress line to the exit; "other before/after trace" the time between marked
stages. An atlas's stages run atlas by atlas (bake points of all first), so a bake of several
atlases adds each stage's time over them. "After the trace": seams, raw files, denoise, stitch
(with the encoded atlas's stitching), encode, write, preview images, "other after trace", finish;
the shares are given of the whole process and of the bake as the operator runs it (without the
start-up, the .blend's opening and the unwrap).

Peak memory per stage: the resident memory of the whole process tree (the child and any worker
it spawns), summed over the tree and sampled every 20 ms by a watcher thread (psutil), attributed
to the stage whose line was last seen, plus one sample at each stage change counted in both
stages. The sidecars' `timings_seconds` are recorded beside, by atlas.

Writes bench/results/end_to_end.json (cases merged by name: a case run alone replaces its entry),
end_to_end.md (the table) and end_to_end.png (seconds per stage, stacked; needs matplotlib).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SHARED_BEDROOM = Path("/work/shared/scenes/bedroom/bedroom.blend")

#: Stages in bake order (the table's rows; "other" is bookkeeping between marked stages).
STAGES = [
    "start",
    "unwrap",
    "scene read",
    "inward faces",
    "BVH",
    "bake points",
    "trace",
    "seams",
    "raw write",
    "denoise",
    "stitch",
    "encode",
    "write",
    "preview images",
    "other before trace",
    "other after trace",
    "finish",
]
#: Stages that run after the trace (the issue's "stages after the trace").
AFTER_TRACE = {
    "seams",
    "raw write",
    "denoise",
    "stitch",
    "encode",
    "write",
    "preview images",
    "other after trace",
    "finish",
}

CASES = {
    "room-256-draft": {
        "scene": "room",
        "size": ["--resolution", "256"],
        "preset": "draft",
        "label": "room 256² Draft",
    },
    "room-128-draft": {
        "scene": "room",
        "size": ["--texel-density", "2.35"],
        "preset": "draft",
        "label": "room 182² Draft (density 2.35)",
    },
    "bedroom-1024-draft": {
        "scene": "bedroom",
        "size": ["--resolution", "1024"],
        "preset": "draft",
        "label": "bedroom 1024² Draft",
    },
    "bedroom-4096-production": {
        "scene": "bedroom",
        "size": ["--resolution", "4096"],
        "preset": "production",
        "label": "bedroom 4096² Production",
    },
    "level-4096-production": {
        "scene": "level",
        "size": ["--resolution", "4096"],
        "preset": "production",
        "label": "three bedrooms 4096² Production",
    },
    "bedroom-4096-post": {
        "scene": "bedroom",
        "size": ["--resolution", "4096"],
        "preset": "production",
        "extra": ["--samples", "4"],
        "label": "bedroom 4096² Production at 4 samples",
    },
}


# ---------------------------------------------------------------- the child: the CLI with markers


def _mark(name: str) -> None:
    sys.stdout.write(f"@e2e {name}\n")
    sys.stdout.flush()


def _marked(owner, attr: str, name: str) -> None:
    """`owner.attr` (looked up at call time) prints `@e2e name` on entry and `@e2e other` on return."""
    f = getattr(owner, attr)

    def marked(*args, **kwargs):
        _mark(name)
        try:
            return f(*args, **kwargs)
        finally:
            _mark("other")

    setattr(owner, attr, marked)


def _stage_of(message: str) -> str | None:
    """The stage a console progress line names, or None (a line of the stage in progress)."""
    m = message.lower()
    if "preview" in m:
        return "preview images"
    if m.startswith("raw ") or "raw files" in m:
        return "raw write"
    if m.startswith("encode ") or "filling layer" in m:
        return "encode"
    if m.startswith("write "):
        return "write"
    if "denois" in m:
        return "denoise"
    if "stitch" in m:
        return "stitch"
    if "seams" in m:
        return "seams"
    if "chunk" in m or "rays/s" in m:
        return "trace"
    if "xatlas" in m:
        return "unwrap"
    if m.startswith("baked "):
        return "finish"
    return None


def child(argv: list[str]) -> int:
    from hhd_lightmapper import cli
    from hhd_lightmapper.bridge import bake_session
    from hhd_lightmapper.cli import commands
    from hhd_lightmapper.core import bake, console, post, tracer
    from hhd_lightmapper.core.bake import runners
    from hhd_lightmapper.core.post.seams import geometry

    _marked(commands, "unwrap", "unwrap")  # as `bake --unwrap` calls it
    _marked(bake_session.BakeSession, "__init__", "scene read")
    _marked(bake, "check_inward", "inward faces")
    _marked(bake, "ray_scene_of", "BVH")
    _marked(runners, "points_of", "bake points")
    _marked(tracer, "bake", "trace")
    _marked(geometry, "find_seams", "seams")
    for attr, name in (("denoise_stage", "denoise"), ("stitch_stage", "stitch")):
        make = getattr(post, attr)

        def wrapped(*args, _make=make, _name=name, **kwargs):
            stage = _make(*args, **kwargs)
            if not callable(stage):
                return stage

            def run(*a, **k):
                _mark(_name)
                try:
                    return stage(*a, **k)
                finally:
                    _mark("other")

            return run

        setattr(post, attr, wrapped)

    shown = console.ConsoleProgress.__call__

    def call(self, fraction, message):
        stage = _stage_of(message)
        if stage is not None and stage != getattr(self, "_e2e_stage", None):
            self._e2e_stage = stage
            self.last_fraction = -1.0  # print this line: the stage changed
        shown(self, fraction, message)

    console.ConsoleProgress.__call__ = call
    return cli.standalone(argv)


# ---------------------------------------------------------------- the parent: one timed bake


class TreeMemory(threading.Thread):
    """Samples the RSS of a process and its descendants, keeping the peak per current stage."""

    def __init__(self, pid: int, interval: float = 0.02):
        super().__init__(daemon=True)
        import psutil

        self.root = psutil.Process(pid)
        self.interval = interval
        self.stage = "start"
        self.peaks: dict[str, float] = {}
        self.peak = 0.0
        self.stopped = threading.Event()

    def sample(self) -> float:
        import psutil

        total = 0
        try:
            procs = [self.root, *self.root.children(recursive=True)]
        except psutil.Error:
            return 0.0
        for p in procs:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        return total / 2**20

    def at_change(self, old: str, new: str) -> None:
        """A sample at a stage boundary, counted in both stages (a stage shorter than the
        interval gets at least this one), then the new stage."""
        mb = self.sample()
        for stage in (old, new):
            self.peaks[stage] = max(self.peaks.get(stage, 0.0), mb)
        self.stage = new

    def run(self) -> None:
        while not self.stopped.is_set():
            mb, stage = self.sample(), self.stage
            self.peaks[stage] = max(self.peaks.get(stage, 0.0), mb)
            self.peak = max(self.peak, mb)
            self.stopped.wait(self.interval)


def _meshes(blend: Path) -> list[str]:
    code = (
        "import bpy, json, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
        "print('@names', json.dumps(sorted(o.name for o in bpy.context.scene.objects if o.type == 'MESH')))"
    )
    out = subprocess.run([sys.executable, "-c", code, str(blend)], check=True, capture_output=True, text=True).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("@names"))[7:])


def _room(folder: Path) -> Path:
    code = (
        "import sys, os, tempfile; os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp()); "
        "import bpy; from scenekit import blender, scenes; "
        "scenes.demo_room(); blender.externalise_images(sys.argv[1]); "
        "bpy.ops.wm.save_as_mainfile(filepath=os.path.join(sys.argv[1], 'room.blend'))"
    )
    subprocess.run([sys.executable, "-c", code, str(folder)], check=True, capture_output=True)
    return folder / "room.blend"


def _level(folder: Path) -> Path:
    """Three copies of the shared bedroom side by side, each object and mesh copied (213 meshes,
    1.35M polygons): a level of the size of the issue's kitchen (295 objects, 1.44M polygons)."""
    code = (
        "import sys, bpy; from mathutils import Vector; "
        "bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
        "objs = list(bpy.context.scene.objects); "
        "xs = [(o.matrix_world @ Vector(c)).x for o in objs if o.type == 'MESH' for c in o.bound_box]; "
        "width = 1.2 * (max(xs) - min(xs))\n"
        "for k in (1, 2):\n"
        "    for o in objs:\n"
        "        c = o.copy(); c.data = o.data.copy() if o.data is not None else None\n"
        "        c.location.x += k * width if o.parent is None else 0.0\n"
        "        [coll.objects.link(c) for coll in o.users_collection]\n"
        "bpy.ops.wm.save_as_mainfile(filepath=sys.argv[2])"
    )
    blend = folder / "level.blend"
    subprocess.run([sys.executable, "-c", code, str(SHARED_BEDROOM), str(blend)], check=True, capture_output=True)
    return blend


def _atlases(out: Path) -> dict:
    """The atlases' sizes, their baked texels, each sidecar's `timings_seconds` (by atlas:
    "bake_points" is the bake points of every atlas, built before the first trace, in each) and,
    where the denoiser ran, its charts, pages and page texels (OIDN's work is in page texels)."""
    sizes, texels, timings, denoise = [], 0, {}, {}
    for path in sorted(out.glob("*.json")) if out.exists() else []:
        sidecar = json.loads(path.read_text())
        if "timings_seconds" not in sidecar:
            continue
        sizes.append(f"{sidecar.get('width')}×{sidecar.get('height')}")
        texels += (sidecar.get("stats") or {}).get("texels_baked", 0)
        timings[path.stem] = {k: round(v, 3) for k, v in sidecar["timings_seconds"].items()}
        if (sidecar.get("post") or {}).get("denoise", {}).get("applied"):
            denoise[path.stem] = {k: sidecar["post"]["denoise"].get(k) for k in ("charts", "pages", "page_texels")}
    return {"atlases": sizes, "texels_baked": texels, "sidecar_timings_seconds": timings, "denoise_pages": denoise}


def _sidecar_text(timings: dict) -> str:
    """The sidecars' timings: bake points once, the other stages summed over the atlases."""
    if not timings or not all(isinstance(v, dict) for v in timings.values()):
        return json.dumps(timings)
    keys = dict.fromkeys(k for t in timings.values() for k in t)
    total = {
        k: max(t.get(k, 0.0) for t in timings.values())
        if k == "bake_points"
        else sum(t.get(k, 0.0) for t in timings.values())
        for k in keys
    }
    return ", ".join(f"{k} {v:.2f}" for k, v in total.items())


def run_case(name: str, scratch: Path) -> dict:
    case = CASES[name]
    folder = scratch / name
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    if case["scene"] == "room":
        blend = _room(folder)
    elif case["scene"] == "level":
        blend = _level(folder)
    else:
        blend = folder / "bedroom.blend"
        shutil.copyfile(SHARED_BEDROOM, blend)
        blend.chmod(0o644)
    objects = _meshes(blend)
    out = folder / "lightmaps"
    argv = [str(blend), "bake", "--unwrap", *case["size"], "--preset", case["preset"], *case.get("extra", [])]
    argv += ["--out", str(out)]
    argv += ["--objects", *objects]
    command = [sys.executable, "-u", str(Path(__file__).resolve()), "--child", "--", *argv]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    memory = TreeMemory(proc.pid)
    memory.start()
    events: list[tuple[float, str]] = [(0.0, "start")]
    log = []
    stage, traced = "start", False
    for line in proc.stdout:
        now = time.perf_counter() - t0
        line = line.rstrip("\n")
        log.append(f"{now:9.3f}  {line}")
        new = None
        if line.startswith("@e2e "):
            new = line[5:]
        elif line.startswith("["):
            new = _stage_of(line.split("]", 1)[-1].strip())
        elif line.startswith("unwrap:"):
            new = "unwrap"
        elif line.startswith("bake:") and stage == "unwrap":
            new = "other"
        if new == "other":
            new = "other after trace" if traced else "other before trace"
        traced = traced or new == "trace"
        if new is not None and new != stage:
            memory.at_change(stage, new)
            stage = new
            events.append((now, stage))
        print(f"  [{name} {now:7.1f}s] {line}"[:200], flush=True)
    code = proc.wait()
    end = time.perf_counter() - t0
    memory.stopped.set()
    memory.join()
    events.append((end, None))
    seconds: dict[str, float] = {}
    for (t, s), (t1, _) in zip(events, events[1:]):
        seconds[s] = seconds.get(s, 0.0) + t1 - t
    atlases = _atlases(out)
    (folder / "console.log").write_text("\n".join(log) + "\n")
    rows = {
        s: {
            "seconds": round(seconds.get(s, 0.0), 3),
            "peak_rss_mb": round(memory.peaks[s], 1) if s in memory.peaks else None,
        }
        for s in STAGES
        if s in seconds or s in memory.peaks
    }
    files = {p.name: p.stat().st_size for p in out.rglob("*") if p.is_file()} if out.exists() else {}
    return {
        "label": case["label"],
        "command": "python -m hhd_lightmapper.cli " + " ".join(argv[:8]) + f" --objects <{len(objects)} meshes>",
        "exit_code": code,
        "objects": len(objects),
        **atlases,
        "stages": rows,
        "total_seconds": round(end, 3),
        "peak_rss_mb": round(memory.peak, 1),
        "files_bytes": files,
        "load_before": load_before,
        "load_after": os.getloadavg(),
        "cpu_count": os.cpu_count(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


# ---------------------------------------------------------------- the report


def _shares(r: dict) -> None:
    """Totals and shares from a case's stages: the trace, the stages after it, and the same
    for the bake as the operator runs it (without the start-up, the .blend's opening and the unwrap)."""
    seconds = {s: row["seconds"] for s, row in r["stages"].items()}
    end = r["total_seconds"]
    trace = seconds.get("trace", 0.0)
    after = sum(v for s, v in seconds.items() if s in AFTER_TRACE)
    bake_only = end - seconds.get("start", 0.0) - seconds.get("unwrap", 0.0)
    r.update(
        {
            "trace_seconds": round(trace, 3),
            "after_trace_seconds": round(after, 3),
            "after_trace_share": round(after / end, 4) if end else None,
            "fixed_share": round((end - trace) / end, 4) if end else None,
            "bake_seconds": round(bake_only, 3),
            "after_trace_share_of_bake": round(after / bake_only, 4) if bake_only else None,
            "fixed_share_of_bake": round((bake_only - trace) / bake_only, 4) if bake_only else None,
        }
    )


def _table(results: dict) -> str:
    names = [n for n in CASES if n in results]
    lines = [
        "# End to end: every stage of a CLI bake (issue 58, part 1)",
        "",
        "`python bench/end_to_end.py`: `python -m hhd_lightmapper.cli FILE.blend bake --unwrap ... --preset P "
        "--objects <all meshes>`; seconds from the console lines' arrival (stage markers at each stage's "
        "entry), peak RSS of the whole process tree (sampled every 20 ms) while the stage ran. "
        "\"start\": interpreter start-up and opening the .blend; \"finish\": from the last progress line "
        "to the exit (`BakeSession.finish` loads the images into the .blend); \"other\": between marked "
        "stages (before the trace: the unwrap's UV write-back and the bake's set-up).",
        "",
    ]
    head = "| stage | " + " | ".join(f"{results[n]['label']} s | peak MB" for n in names) + " |"
    lines += [head, "|---" * (1 + 2 * len(names)) + "|"]
    for s in STAGES:
        cells = []
        present = False
        for n in names:
            r = results[n]
            row = r.get("stages", {}).get(s)
            if row is None:
                cells += ["–", "–"]
            else:
                present = True
                peak = row["peak_rss_mb"]
                cells += [f"{row['seconds']:.2f}", "–" if not peak else f"{peak:.0f}"]
        if present:
            lines.append(f"| {s} | " + " | ".join(cells) + " |")
    for key, title, fmt in (
        ("total_seconds", "**total**", "{:.2f}"),
        ("peak_rss_mb", "**peak RSS MB**", "{:.0f}"),
        ("trace_seconds", "trace s", "{:.2f}"),
        ("after_trace_seconds", "after the trace s", "{:.2f}"),
        ("after_trace_share", "after the trace, share", "{:.1%}"),
        ("fixed_share", "all but the trace, share", "{:.1%}"),
        ("bake_seconds", "bake without start-up and unwrap s", "{:.2f}"),
        ("after_trace_share_of_bake", "after the trace, share of that", "{:.1%}"),
        ("fixed_share_of_bake", "all but the trace, share of that", "{:.1%}"),
    ):
        cells = []
        for n in names:
            v = results[n].get(key)
            cells += [fmt.format(v) if v is not None else "–", ""]
        lines.append(f"| {title} | " + " | ".join(cells) + " |")
    lines += ["", "Per case:", ""]
    for n in names:
        r = results[n]
        if r.get("not_run"):
            lines.append(f"- {r['label']}: not run ({r['not_run']}).")
            continue
        lines.append(
            f"- {r['label']}: {r['objects']} objects, {len(r.get('atlases', []))} atlas(es) "
            f"{', '.join(r.get('atlases', []))}, {r.get('texels_baked')} texels baked, exit {r['exit_code']}, "
            f"load {r['load_before'][0]:.2f} → {r['load_after'][0]:.2f} on {r['cpu_count']} cores, {r['date']}; "
            f"sidecars' timings_seconds (bake points once, the rest summed over the atlases): "
            f"{_sidecar_text(r.get('sidecar_timings_seconds') or {})}"
        )
    return "\n".join(lines) + "\n"


def _plot(results: dict, png: Path) -> str:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib not available: no plot"
    names = [n for n in CASES if n in results and not results[n].get("not_run")]
    if not names:
        return "nothing to plot"
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 5), squeeze=False)
    colours = plt.get_cmap("tab20").colors
    for ax, n in zip(axes[0], names):
        r = results[n]
        bottom = 0.0
        for i, s in enumerate(STAGES):
            v = r["stages"].get(s, {}).get("seconds", 0.0)
            if v <= 0:
                continue
            ax.bar([0], [v], bottom=bottom, color=colours[i % len(colours)], label=s, width=0.6)
            if v / r["total_seconds"] > 0.04:
                peak = r["stages"][s]["peak_rss_mb"] or 0.0
                ax.text(0, bottom + v / 2, f"{s} {v:.1f}s, {peak:.0f} MB", ha="center", va="center", fontsize=7)
            bottom += v
        ax.set_title(
            f"{r['label']}\n{r['total_seconds']:.1f} s, peak {r['peak_rss_mb'] / 1024:.2f} GB, "
            f"after trace {r['after_trace_share']:.0%}",
            fontsize=9,
        )
        ax.set_xticks([])
        ax.set_ylabel("seconds")
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    order = sorted(range(len(labels)), key=lambda i: STAGES.index(labels[i]))
    fig.legend([handles[i] for i in order], [labels[i] for i in order], loc="center right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.84, 1))
    fig.savefig(png, dpi=110)
    return f"plot: {png}"


def main() -> int:
    if "--child" in sys.argv:
        argv = sys.argv[sys.argv.index("--") + 1 :]
        return child(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    ap.add_argument("--scratch", type=Path, help="work folder (default: a temporary one)")
    ap.add_argument("--not-run", nargs=2, action="append", metavar=("CASE", "WHY"), default=[])
    ap.add_argument("--report-only", action="store_true", help="rewrite the table and plot from the JSON")
    args = ap.parse_args()
    path = RESULTS / "end_to_end.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name in results:
        out = (args.scratch / name / "lightmaps") if args.scratch else None
        if args.report_only and out is not None and out.exists() and not results[name].get("not_run"):
            results[name].update(_atlases(out))  # the sidecars of a run made before they were all read
        if name in CASES:
            results[name]["label"] = CASES[name]["label"]
        if "stages" in results[name]:
            _shares(results[name])
    for name, why in args.not_run:
        results[name] = {"label": CASES[name]["label"], "not_run": why}
    if not args.report_only:
        scratch = args.scratch or Path(tempfile.mkdtemp(prefix="hhd-e2e-"))
        for name in args.cases:
            print(f"{name}: baking in {scratch / name}", flush=True)
            results = json.loads(path.read_text()) if path.exists() else results  # another run may have added
            results[name] = run_case(name, scratch)
            _shares(results[name])
            path.write_text(json.dumps(results, indent=1) + "\n")
    RESULTS.mkdir(exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")
    (RESULTS / "end_to_end.md").write_text(_table(results))
    print(_table(results))
    print(_plot(results, RESULTS / "end_to_end.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
