"""Where the Bake operator's time goes on a small atlas, click to files (issue 58: the fixed work
around the trace that decides the comparisons through the operators at 128² and 512²).

    PYTHONPATH=PKG .venv/bin/python bench/operator_stages.py [--scenes classroom staircase2 bedroom]
        [--resolutions 128 512] [--samples 16] [--repeats 5] [--label after]

Per scene (its receivers selected and unwrapped as `bench/time_to_error.py --operators` does, 3
bounces, denoise and stitching off, as Cycles' raw bake) and resolution: `bpy.ops.hhd.bake()`
timed `--repeats` times after one bake that warms the compiled kernels; per bake the whole
operator's seconds and the sidecar's own (`timings_seconds`: bake points with the inward-face
check and the Embree scene, trace, seams, post stages); "rest" is the operator's seconds less
those (reading the scene and the fingerprints, the imaging, encoding and files, loading the images
into Blender). Medians. Run it on another checkout (PKG: a folder whose `hhd_lightmapper` is that
checkout) under another `--label` for the peer measured on the same machine.

Writes bench/results/operator_stages.json (entries merged by scene, resolution, samples and label)
and operator_stages.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
OUT = RESULTS / "operator_stages.json"
#: the sidecar's stage timings, in the table's order
STAGES = ("bake_points", "trace", "seams", "post")


def prepare(name: str, resolution: int) -> list:
    """The scene opened, its receivers selected and unwrapped at `resolution`² (padding 2)."""
    import time_to_error  # bench/, the script's folder

    receivers = time_to_error.load_scene(name)
    time_to_error.unwrap(receivers, resolution)
    return receivers


def bake_once(receivers: list, samples: int) -> dict:
    """One operator bake into a fresh folder: its seconds, the sidecar's stage seconds, texels."""
    import bpy

    from scenekit.blender import select

    folder = Path(tempfile.mkdtemp(prefix="hhd-operator-stages-"))
    s = bpy.context.scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.noise_target = samples, 3, 0, 0.0
    s.denoise, s.stitch_seams, s.output_dir = False, False, str(folder)
    select(receivers)
    t = time.perf_counter()
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    seconds = time.perf_counter() - t
    sidecar = json.loads((folder / "Lightmap.json").read_text())
    shutil.rmtree(folder)
    stages = {k: float(sidecar["timings_seconds"].get(k, 0.0)) for k in STAGES}
    return {
        "seconds": seconds,
        **stages,
        "rest": seconds - sum(stages.values()),
        "texels": sidecar["stats"]["texels_baked"],
    }


def measure(receivers: list, samples: int, repeats: int) -> dict:
    """Medians over `repeats` bakes after a warm-up bake, and every bake's figures."""
    bake_once(receivers, samples)  # compiled kernels loaded, caches warm
    runs = [bake_once(receivers, samples) for _ in range(repeats)]
    keys = ("seconds", *STAGES, "rest")
    return {
        **{k: statistics.median(r[k] for r in runs) for k in keys},
        "texels": runs[0]["texels"],
        "runs": runs,
    }


def report(results: dict) -> str:
    lines = [
        "# The Bake operator on small atlases, click to files (issue 58: the fixed work around the trace)",
        "",
        "`bench/operator_stages.py`: the receivers of `bench/time_to_error.py --operators`, 3 bounces, "
        "denoise and stitching off; medians of the bakes after a warm-up (every bake, the machine's "
        "load and the code in the JSON). Seconds; *rest*: the operator's seconds less the sidecar's "
        "stages (scene and fingerprint reads, imaging, encoding, files, loading the images).",
        "",
        "| scene | atlas | samples | texels | label | operator s | bake points s | trace s | post s | rest s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key in sorted(results, key=lambda k: (k.split("|")[0], int(k.split("|")[1]), int(k.split("|")[2]))):
        scene, res, samples = key.split("|")
        for label, e in sorted(results[key].items()):
            lines.append(
                f"| {scene} | {res}² | {samples} | {e['texels']:,} | {label} | {e['seconds']:.3f} | "
                f"{e['bake_points']:.3f} | {e['trace']:.3f} | {e['post']:.3f} | {e['rest']:.3f} |"
            )
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["classroom", "staircase2", "bedroom"])
    ap.add_argument("--resolutions", type=int, nargs="+", default=[128, 512])
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--label", default="after")
    ap.add_argument("--report-only", action="store_true", help="rewrite the table from the JSON")
    args = ap.parse_args()
    results = json.loads(OUT.read_text()) if OUT.exists() else {}
    if not args.report_only:
        os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
        import bpy  # noqa: F401

        import hhd_lightmapper

        hhd_lightmapper.register()
        for name in args.scenes:
            for resolution in args.resolutions:
                receivers = prepare(name, resolution)
                entry = measure(receivers, args.samples, args.repeats)
                entry.update(
                    code=hhd_lightmapper.__file__,
                    load_average=os.getloadavg(),
                    date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                )
                results.setdefault(f"{name}|{resolution}|{args.samples}", {})[args.label] = entry
                print(f"{name} {resolution}² {args.label}: {entry['seconds']:.3f} s", flush=True)
                RESULTS.mkdir(exist_ok=True)
                OUT.write_text(json.dumps(results, indent=2, sort_keys=True))
    (RESULTS / "operator_stages.md").write_text(report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
