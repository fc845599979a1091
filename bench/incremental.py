"""Bake what changed on the bedroom (issue 57, part 1): incremental bakes against a full rebake; run by hand.

    python bench/incremental.py [--scratch DIR] [--resolution 1024] [--preset draft]

On a copy of the shared bedroom (every mesh a receiver, unwrapped at --resolution, baked with
--preset through the CLI in this process), two edits, each from the same first bake:
- "move furniture": WoodFurniture_Mesh030 (720 triangles; the bedroom has no object named chair)
  moved 0.3 m along x;
- "lamp off": one of the bedroom's two emissive quads (Light_trianglemesh.001, its lamps' light; the
  LampEmitter_* meshes do not emit) hidden from render.
After each edit, three bakes of the edited scene, timed in the same run: `bake --changed`,
`bake --changed --influenced` (each into a copy of the first bake's folder) and a full bake
(into a folder of its own). Per incremental bake: seconds, the texels re-traced as a share of
the atlases' texels, the fixed overhead (its seconds minus share × the full bake's seconds), and
its error against the full rebake over every baked texel with a known noise: the share of texels
whose luminance L0 (SH file) differs from the full rebake's by at most 3 σ, σ from the texels
files' Noise.V: σ_full alone, and σ = √(σ_inc² + σ_full²) (two independent bakes: the
difference's own noise); the same over the re-traced texels only.

Writes bench/results/incremental.json and incremental.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
BEDROOM = Path("/work/shared/scenes/bedroom/bedroom.blend")
MOVED = "WoodFurniture_Mesh030"
LAMP = "Light_trianglemesh.001"  # one of the bedroom's two emitters (its lamps' light quads)
LUMA = (0.2126, 0.7152, 0.0722)


def atlases(folder: Path) -> list[str]:
    return sorted(
        p.stem for p in folder.glob("*.json") if "light_set" not in json.loads(p.read_text()) and p.stem != "probes"
    )


def maps(folder: Path, name: str):
    from hhd_lightmapper.core.files import exr

    sh, _ = exr.read(folder / f"{name}_sh.exr")
    tx, _ = exr.read(folder / f"{name}_texels.exr")
    lum = sum(w * sh[f"SH0.{c}"].astype(np.float64) for w, c in zip(LUMA, "RGB"))
    return lum, tx["Noise.V"].astype(np.float64), tx["Coverage.V"].astype(np.float64)


def compare(inc: Path, full: Path, retraced_masks: dict) -> dict:
    """Shares of texels within 3σ of the full rebake (module doc)."""
    counts = {"all": [0, 0, 0], "retraced": [0, 0, 0]}
    for name in atlases(full):
        a, sa, cov = maps(inc, name)
        b, sb, _ = maps(full, name)
        known = (cov > 0) & (sa >= 0) & (sb >= 0)
        d = np.abs(a - b)
        for key, mask in (("all", known), ("retraced", known & retraced_masks.get(name, np.zeros_like(known)))):
            counts[key][0] += int(mask.sum())
            counts[key][1] += int((d[mask] <= 3 * sb[mask]).sum())
            counts[key][2] += int((d[mask] <= 3 * np.hypot(sa[mask], sb[mask])).sum())
    return {
        f"{k}_{m}": (v[i] / v[0] if v[0] else float("nan"))
        for k, v in counts.items()
        for i, m in ((1, "within_3sigma_full"), (2, "within_3sigma_both"))
    } | {"texels_compared": counts["all"][0], "retraced_compared": counts["retraced"][0]}


def retraced(before: Path, after: Path) -> dict:
    """Per atlas, the texels whose raw SH changed (EXR rows), i.e. those re-traced or rewritten."""
    from hhd_lightmapper.core.files import exr

    out = {}
    for name in atlases(before):
        a, _ = exr.read(before / f"{name}_sh.exr")
        b, _ = exr.read(after / f"{name}_sh.exr")
        out[name] = np.any([a[k] != b[k] for k in a], axis=0)
    return out


def run_cli(*args) -> float:
    from hhd_lightmapper import cli

    t = time.perf_counter()
    code = cli.main([str(a) for a in args])
    if code != cli.EXIT_OK:
        raise SystemExit(f"cli {args} failed with {code}")
    return time.perf_counter() - t


def record(folder: Path) -> dict:
    texels = traced = 0
    for name in atlases(folder):
        doc = json.loads((folder / f"{name}.json").read_text())
        texels += sum(o["texels"] for o in doc["objects"])
        inc = doc.get("incremental")  # absent where this bake re-traced nothing of the atlas
        if inc:
            traced += inc["texels_traced"]
    return {"texels": texels, "traced": traced}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scratch", type=Path, default=None)
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--preset", default="draft")
    parser.add_argument("--edits", nargs="+", default=["move furniture", "lamp off"], help="the edits to run")
    parser.add_argument(
        "--samples", type=int, default=64, help="64: 4 passes of 16, the fewest with a known noise (Noise.V)"
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="time the merge stage only (post stages + encode, whole atlas against its region): `merge_bench`",
    )
    args = parser.parse_args()
    if args.merge:
        merge_bench(args)
        return
    import bpy

    import hhd_lightmapper

    hhd_lightmapper.register()
    scratch = args.scratch or Path(tempfile.mkdtemp(prefix="hhd_incremental_"))
    scratch.mkdir(parents=True, exist_ok=True)
    blend = scratch / "bedroom.blend"
    shutil.copyfile(BEDROOM, blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    meshes = sorted(o.name for o in bpy.data.objects if o.type == 'MESH')
    base = scratch / "base"
    shutil.rmtree(base, ignore_errors=True)
    common = ["--preset", args.preset, "--samples", args.samples]
    t_unwrap = run_cli("unwrap", "--resolution", args.resolution, "--objects", *meshes)
    t_first = run_cli("bake", *common, "--objects", *meshes, "--out", base)
    rows = []
    edits = {
        "move furniture": (
            lambda: setattr(
                bpy.data.objects[MOVED],
                "location",
                bpy.data.objects[MOVED].location + type(bpy.data.objects[MOVED].location)((0.3, 0, 0)),
            ),
            lambda: setattr(
                bpy.data.objects[MOVED],
                "location",
                bpy.data.objects[MOVED].location - type(bpy.data.objects[MOVED].location)((0.3, 0, 0)),
            ),
        ),
        "lamp off": (
            lambda: setattr(bpy.data.objects[LAMP], "hide_render", True),
            lambda: setattr(bpy.data.objects[LAMP], "hide_render", False),
        ),
    }
    for edit, (do, undo) in [(k, v) for k, v in edits.items() if k in args.edits]:
        do()
        bpy.context.view_layer.update()
        full = scratch / f"full {edit}"
        shutil.rmtree(full, ignore_errors=True)
        modes = {}
        for mode, flags in (("changed", ["--changed"]), ("changed + influenced", ["--changed", "--influenced"])):
            folder = scratch / f"{mode} {edit}"
            shutil.rmtree(folder, ignore_errors=True)
            shutil.copytree(base, folder)
            seconds = run_cli("bake", *common, *flags, "--out", folder)
            modes[mode] = (folder, seconds)
        t_full = run_cli("bake", *common, "--objects", *meshes, "--out", full)
        for mode, (folder, seconds) in modes.items():
            counts = record(folder)
            share = counts["traced"] / max(counts["texels"], 1)
            metrics = compare(folder, full, retraced(base, folder))
            rows.append(
                {
                    "edit": edit,
                    "mode": mode,
                    "seconds": seconds,
                    "full_seconds": t_full,
                    "texels": counts["texels"],
                    "texels_traced": counts["traced"],
                    "share_traced": share,
                    "overhead_seconds": seconds - share * t_full,
                    **metrics,
                }
            )
            print(json.dumps(rows[-1]), flush=True)
        undo()
        bpy.context.view_layer.update()
    doc = {
        "resolution": args.resolution,
        "preset": args.preset,
        "samples": args.samples,
        "unwrap_seconds": t_unwrap,
        "first_bake_seconds": t_first,
        "rows": rows,
    }
    RESULTS.mkdir(exist_ok=True)
    kept = RESULTS / "incremental.json"  # the edits not run now keep their rows
    if kept.is_file() and set(args.edits) != set(edits):
        doc["rows"] = [r for r in json.loads(kept.read_text())["rows"] if r["edit"] not in args.edits] + rows
    (RESULTS / "incremental.json").write_text(json.dumps(doc, indent=1) + "\n")
    (RESULTS / "incremental.md").write_text(markdown(doc))
    print(markdown(doc))


def merge_bench(args) -> None:
    """`--merge`: the merge stage of `bake --only MOVED` (`core.incremental.merge._merge_files`: the post
    stages and the encoder, then the files staged) timed over the whole atlas and over the region
    of its touched texels (`core.incremental.merge.merge_region`, forced whatever its share), each from the same first bake (denoised and
    stitched, `--samples` with the preset's other knobs; kept in --scratch and reused when its
    resolution matches). Writes bench/results/incremental_merge.json and .md (rows per resolution
    kept from earlier runs)."""
    import bpy

    import hhd_lightmapper
    from hhd_lightmapper.core.incremental import merge as core_merge
    from hhd_lightmapper.core.incremental import subset

    hhd_lightmapper.register()
    scratch = args.scratch or Path(tempfile.gettempdir()) / f"hhd_incremental_merge_{args.resolution}"
    scratch.mkdir(parents=True, exist_ok=True)
    blend, base = scratch / "bedroom.blend", scratch / "base"
    common = ["--preset", args.preset, "--samples", args.samples, "--denoise", "--stitch"]
    if not (base / "Lightmap.json").is_file() or not blend.is_file():
        shutil.copyfile(BEDROOM, blend)
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        meshes = sorted(o.name for o in bpy.data.objects if o.type == 'MESH')
        run_cli("unwrap", "--resolution", args.resolution, "--objects", *meshes)
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        shutil.rmtree(base, ignore_errors=True)
        run_cli("bake", *common, "--objects", *meshes, "--out", base)
    else:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
    timings: list[dict] = []
    merge = subset._merge_files

    def timed(staging, files, data, sidecar, settings, atlas_seams, mask, *, update, cancel):
        t = time.perf_counter()
        out = merge(staging, files, data, sidecar, settings, atlas_seams, mask, update=update, cancel=cancel)
        timings.append({"file": files.name, "seconds": time.perf_counter() - t})
        return out

    rows = []
    share_max = core_merge.WINDOW_SHARE_MAX
    for way, limit in (("whole", 0.0), ("region", 1.0), ("whole", 0.0), ("region", 1.0)):
        folder = scratch / way
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(base, folder)
        core_merge.WINDOW_SHARE_MAX = limit
        subset._merge_files = timed
        timings.clear()
        try:
            seconds = run_cli("bake", *common, "--only", MOVED, "--out", folder)
        finally:
            subset._merge_files, core_merge.WINDOW_SHARE_MAX = merge, share_max
        docs = [json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))]
        doc = next(d for d in docs if "incremental" in d)  # the moved object's atlas (bedroom: no light sets)
        rows.append(
            {
                "resolution": args.resolution,
                "way": way,
                "bake_seconds": seconds,
                "merge_seconds": sum(t["seconds"] for t in timings),
                "files": len(timings),
                "texels_traced": doc["incremental"]["texels_traced"],
                "texels_written": doc["incremental"]["texels_written"],
                "window_share": doc["incremental"].get("merge", {}).get("share", 1.0),
                "region_texels": doc["incremental"].get("merge", {}).get("texels", 0),
                "why": doc["incremental"].get("merge", {}).get("why", ""),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    kept = RESULTS / "incremental_merge.json"
    old = json.loads(kept.read_text())["rows"] if kept.is_file() else []
    doc = {
        "preset": args.preset,
        "samples": args.samples,
        "rows": [r for r in old if r["resolution"] != args.resolution] + rows,
    }
    kept.write_text(json.dumps(doc, indent=1) + "\n")
    (RESULTS / "incremental_merge.md").write_text(merge_markdown(doc))
    print(merge_markdown(doc))


def merge_markdown(doc: dict) -> str:
    lines = [
        "# Bake what changed: the merge's post stages and encode on the touched region (issue 57)",
        "",
        f"`python bench/incremental.py --merge --resolution N`: the shared bedroom, every mesh a receiver, "
        f"{doc['preset'].title()} with {doc['samples']} samples, denoised and stitched; from the same first bake, "
        f"`bake --only {MOVED}` with the merge stage (`core/incremental/merge.py` `_merge_files`: raw files, denoise, "
        "stitch, encode, staging the touched texels of each file) over the whole atlas and over the region of "
        "the touched texels and their charts (`merge_region`, forced whatever its share), each twice, in the same run. "
        "Merge s: that stage's seconds summed over the atlas's files; region share: the region's chart texels over the "
        "atlas's (the whole atlas runs above `WINDOW_SHARE_MAX`).",
        "",
        "| atlas | merge over | bake s | merge s | texels traced | texels written | region texels | region share |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        lines.append(
            f"| {r['resolution']}² | {r['way']} | {r['bake_seconds']:.1f} | {r['merge_seconds']:.2f} | "
            f"{r['texels_traced']} | {r['texels_written']} | {r['region_texels']} | {100 * r['window_share']:.1f}% |"
        )
    return "\n".join(lines) + "\n"


def markdown(doc: dict) -> str:
    lines = [
        "# Bake what changed on the bedroom (issue 57, part 1)",
        "",
        f"`python bench/incremental.py`: the shared bedroom, every mesh a receiver, {doc['resolution']}² "
        f"{doc['preset'].title()} with {doc['samples']} samples (4 passes: the noise is known), first bake {doc['first_bake_seconds']:.1f} s. Each edit is baked three ways "
        "from the same first bake, in the same run: `bake --changed`, `bake --changed --influenced` and a full "
        "bake. Share re-traced: the texels traced over the atlases' texels; overhead: the incremental "
        "bake's seconds minus share × the full bake's. Error: the share of baked texels (noise known) whose "
        "L0 luminance is within 3σ of the full rebake's, σ the full rebake's Noise.V, and σ = √(σ_inc² + "
        "σ_full²) (two independent bakes); on all texels, and on the texels the incremental bake re-traced. "
        "Rows of an edit run alone (`--edits`) come from a run with its own unwrap (the atlas texels differ).",
        "",
        "| edit | atlas texels | mode | seconds | full bake s | share re-traced | overhead s | all: ≤3σ_full | all: ≤3σ_both | re-traced: ≤3σ_full | re-traced: ≤3σ_both |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        lines.append(
            f"| {r['edit']} | {r['texels']} | {r['mode']} | {r['seconds']:.1f} | {r['full_seconds']:.1f} | {100 * r['share_traced']:.1f}% | "
            f"{r['overhead_seconds']:.1f} | {100 * r['all_within_3sigma_full']:.2f}% | {100 * r['all_within_3sigma_both']:.2f}% | "
            f"{100 * r['retraced_within_3sigma_full']:.2f}% | {100 * r['retraced_within_3sigma_both']:.2f}% |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
