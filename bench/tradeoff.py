"""The speed/accuracy trade end to end: every knob's wall time, peak memory and error.

    python bench/tradeoff.py                 # all three scenes, every knob (the longest run)
    python bench/tradeoff.py --quick         # fewer points, small references (a smoke run)
    python bench/tradeoff.py --replot        # presets and plots again from the saved results
    python bench/tradeoff.py --scenes emissive
    python bench/tradeoff.py --knobs samples denoise   # these knobs again, merged into the saved results

Scenes (scenekit/scenes.py `build`): outdoor sun + sky, an interior lit through a window, a room lit by
emissive surfaces only. Per scene, at a base texel density:

- reference: our bake at `--reference-samples` spp, 8 bounces, undenoised, as two half bakes with
  different seeds (their mean is the reference; half their RMS difference is its own noise,
  reported as the floor under every I_z error).
- knobs, one axis at a time around the base (256 spp, 4 bounces, default encoder, no denoiser):
  samples per texel, bounces, a few (samples, bounces) pairs, noise target (adaptive stopping),
  time budget, texel density, encoder settings (optimal-linear vs searched direction, φ search,
  golden-section iterations, luminance vs RGB ambient weight, AHD vs HHD; re-encoding the base
  bake and the reference), and the denoiser (`core.post.denoise`, OIDN's lightmap filter): samples
  per texel with it on, and a few (samples, bounces) pairs with it on (fewer bounces, and 8).
  Every point sets the scene's Denoise explicitly (off unless the point says on; the scene's
  default is on); OIDN is loaded (one denoise) before the timed bakes, as the tracer is warm.
- per point: wall time of the bake as the Bake button runs it (bake points, trace, denoise,
  encode, files; the denoise stage's own seconds from the sidecar as `denoise_seconds`),
  peak memory (numpy allocations, tracemalloc, measured once per texel density, and once with the
  denoiser at the base density, by separate bakes: it depends on the texel count only), and three
  relative errors, each the RMS over texels (pixels) of error / max(reference, FLOOR × the
  reference's mean), FLOOR = 0.1 (the noise target's rule): I_z (luminance) against the
  reference; the hemispherical RMSE of the encoded texels (the HHD reconstruction at every normal
  of the hemisphere against the reference's SH irradiance); the EEVEE preview image against a
  Cycles render of the camera view (diffuse only, normal maps on, 8 bounces; emitters' own pixels
  left out), with the Cycles reference's own noise as its floor.
  The errors are of the SH that was encoded: the raw `_sh.exr` keeps the SH as traced, so a
  denoised point's SH read back from it is denoised again here with the bake's thread count
  (`core.post.denoise.pages.denoise_texels`, deterministic); every point checks that the I_z it encodes from
  that SH equals the Iz channels of the written `_hhd.exr` (`encoded_iz_mismatch`: the largest
  relative difference, half-float rounding).
  Points at another texel density have no texel-wise I_z error (other texels); their image error
  is the comparable figure.

`--knobs` measures only the listed knobs (all scenes, or `--scenes`) and merges the new rows into
the saved bench/results/tradeoff.json: a row with the same knob and label is replaced, the other
rows (and the scenes not measured) are kept; a measured scene's reference, Cycles render and
memory are this run's. The references use fixed seeds, so the errors of kept rows stay
comparable as long as the tracer and the scenes have not changed (the merge prints the saved and
new reference noise to check); their timings come from the runs that measured them (each row's
`run` says when; `runs` lists the runs), on the same machine but under other load.

Writes bench/results/tradeoff.json, tradeoff_iz.png and tradeoff_image.png (per scene: error vs
wall time, log-log, a line per knob, the Pareto front over all knobs, denoised points included,
dashed), tradeoff.md (the README's tables) and presets.json: for each error level the cheapest
measured setting (samples, bounces, noise target, denoise) whose worst-scene I_z RMSE is within
it (core/presets.py holds these; tests/test_presets.py checks they agree).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
#: pixels of the camera view rendered by Cycles and EEVEE (Cycles is most of the scene's set-up time)
VIEW = (192, 120)
BASE = dict(samples=256, bounces=4, noise_target=0.0, time_budget=0.0, denoise=False)
ALL_SCENES = ("outdoor", "interior", "emissive")
#: texels per metre giving 12-20k texels in each scene (a 256-512² atlas)
DENSITY = {"outdoor": 5.0, "interior": 7.0, "emissive": 7.0}
#: hemisphere quadrature of the hemispherical RMSE: 16 × 32 directions (the default 24 × 48
#: gives the same RMSE to 0.01% of its value and costs 2.8× more on every point)
QUADRATURE = None
#: errors are relative per texel (per pixel) to max(reference, FLOOR × the reference's mean): a
#: relative error as the eye sees it, without near-black texels dominating (the noise target's rule)
FLOOR = 0.1
#: preset name -> worst-scene relative I_z RMSE (%) it must reach
#: (chosen from the data, in its gaps: the rooms (interior, emissive) are the hardest scenes;
#: Production's level lies below the floor that 4 bounces leave there however many samples,
#: denoised or not, so it takes 8 bounces, and above what the denoised 8-bounce points reach)
PRESET_LEVELS = {"DRAFT": 55.0, "PREVIEW": 30.0, "PRODUCTION": 10.0, "REFERENCE": 6.0}
#: presets that may not be denoised: a reference is what the denoiser's result is judged against
#: (its bias is not measurable against a reference that has it)
UNDENOISED_PRESETS = ("REFERENCE",)
ENCODERS = {
    "searched (default)": {},
    "optimal linear": dict(direction="OPTIMAL_LINEAR"),
    "φ search": dict(phi_search=True),
    "golden 0": dict(golden_iterations=0),
    "golden 4": dict(golden_iterations=4),
    "RGB ambient": dict(ambient="RGB"),
    "AHD": dict(model="AHD"),
}


#: the knobs in the order they are measured and listed (the encoder re-encodes the base bake)
KNOBS = (
    "samples",
    "bounces",
    "samples × bounces",
    "noise target",
    "time budget",
    "texel density",
    "denoise",
    "encoder",
)


def knob_points(quick: bool, knobs=KNOBS) -> list[dict]:
    """The bake settings measured, each {"knob", "label", settings...} (every knob but the
    encoder's, which re-encodes the base bake: `encoder_rows`), of the knobs in `knobs`."""
    pts = []
    add = lambda knob, label, **kw: pts.append({"knob": knob, "label": label, **BASE, **kw})
    for s in [4, 16, 64, 256] if quick else [4, 16, 64, 256, 1024]:
        add("samples", f"{s} spp", samples=s)
    for b in (1, 2, 8):
        add("bounces", f"{b} bounces", bounces=b)
    for s, b in [] if quick else [(16, 1), (64, 2), (1024, 2)]:
        add("samples × bounces", f"{s} spp, {b} bounces", samples=s, bounces=b)
    for t in [0.1] if quick else [0.2, 0.1, 0.05, 0.025]:
        add("noise target", f"target {100 * t:g}%", samples=2048, noise_target=t)
    for sec in [3.0] if quick else [3.0, 15.0]:
        add("time budget", f"budget {sec:g} s", samples=2048, time_budget=sec)
    for f in [2.0] if quick else [0.5, 2.0]:
        add("texel density", f"density × {f:g}", density_factor=f)
    for s in [4, 16, 64, 256] if quick else [4, 16, 64, 256, 1024]:
        add("denoise", f"{s} spp denoised", samples=s, denoise=True)
    for s, b in [] if quick else [(16, 1), (64, 2), (64, 8), (256, 8)]:
        add("denoise", f"{s} spp, {b} bounces denoised", samples=s, bounces=b, denoise=True)
    return [p for p in pts if p["knob"] in knobs]


def row_order(quick: bool = False) -> list[tuple[str, str]]:
    """(knob, label) of every row a full run measures, in its order (merged rows are sorted by it)."""
    keys = [(p["knob"], p["label"]) for p in knob_points(quick)]
    return keys + [("encoder", label) for label in ENCODERS]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(ALL_SCENES), choices=ALL_SCENES)
    ap.add_argument("--reference-samples", type=int, default=2048)
    ap.add_argument("--cycles-samples", type=int, default=512, help="Cycles render of the view (two halves)")
    ap.add_argument("--replot", action="store_true", help="presets and plots from bench/results/tradeoff.json")
    ap.add_argument("--memory-only", action="store_true", help="measure peak memory into the saved results")
    ap.add_argument(
        "--images-only",
        action="store_true",
        help="render the Cycles references again and recompute the image errors of the saved "
        "EEVEE renders in --out (a run's folder)",
    )
    ap.add_argument("--quick", action="store_true", help="fewer points and a 512-spp reference")
    ap.add_argument(
        "--knobs",
        nargs="+",
        choices=KNOBS,
        metavar="KNOB",
        help="measure only these knobs (" + ", ".join(f'"{k}"' for k in KNOBS) + ") and merge the new "
        "rows into the saved results (rows of the same knob and label replaced, the rest kept)",
    )
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-tradeoff-")))
    args = ap.parse_args()
    if args.replot:
        return finish(json.loads((RESULTS / "tradeoff.json").read_text()))
    if args.quick:
        args.reference_samples, args.cycles_samples = min(args.reference_samples, 512), min(args.cycles_samples, 128)
    global QUADRATURE
    from hhd_lightmapper.core import hhd

    QUADRATURE = hhd.hemisphere_quadrature(16, 32)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper

    hhd_lightmapper.register()
    if args.memory_only:
        return memory_only(args)
    if args.images_only:
        return images_only(args)
    run = {
        "date": time.strftime("%Y-%m-%d %H:%M"),
        **{k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
    }
    args.run_date = run["date"]  # each measured row's `run`
    results = {"settings": run, "runs": [run], "base": BASE, "scenes": {}}
    saved = RESULTS / "tradeoff.json"
    previous = json.loads(saved.read_text()) if saved.is_file() else None
    if args.knobs and previous is None:
        ap.error("--knobs merges into bench/results/tradeoff.json, which does not exist: run every knob first")
    if args.knobs and previous["settings"]["reference_samples"] != args.reference_samples:
        ap.error(
            f"the saved results' reference has {previous['settings']['reference_samples']} spp, this run's "
            f"{args.reference_samples}: their errors would not compare (run every knob, or match it)"
        )
    if previous is not None and (args.knobs or set(args.scenes) < set(ALL_SCENES)):
        # measuring some knobs or scenes again: keep the others
        results["runs"] = previous.get("runs", [previous["settings"]]) + [run]
        results["scenes"] = dict(previous["scenes"])
    for name in args.scenes:
        new = measure_scene(name, args)
        results["scenes"][name] = merge_scene(results["scenes"].get(name), new) if args.knobs else new
        results["scenes"] = {k: results["scenes"][k] for k in ALL_SCENES if k in results["scenes"]}
        print_table(name, results["scenes"][name])
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "tradeoff.json").write_text(json.dumps(results, indent=2))
    return finish(results)


def merge_scene(old: dict | None, new: dict) -> dict:
    """The scene's result of a `--knobs` run (`new`) merged into the saved one (`old`): new rows
    replace old rows of the same knob and label, the other old rows are kept; the scene's
    reference, Cycles render and memory are the new run's (every row's memory attached again)."""
    if old is None:
        return new
    if old["texels"] != new["texels"]:
        print(
            f"WARNING: {new['texels']} texels now, {old['texels']} in the saved results: the kept rows' "
            "I_z and hemispherical errors are of other texels",
            flush=True,
        )
    for key in ("iz_noise_floor", "cycles_noise_floor", "mean_iz"):
        print(f"  {key}: saved {old[key]:.4g}, now {new[key]:.4g}", flush=True)
    rows = {(r["knob"], r["label"]): r for r in old["rows"]}
    rows.update({(r["knob"], r["label"]): r for r in new["rows"]})
    order = {key: i for i, key in enumerate(row_order())}
    merged = {**old, **new, "rows": sorted(rows.values(), key=lambda r: order.get((r["knob"], r["label"]), len(order)))}
    attach_memory(merged, merged["memory"])
    return merged


def finish(results: dict) -> int:
    results["adaptive"] = {name: adaptive_vs_fixed(res) for name, res in results["scenes"].items()}
    (RESULTS / "tradeoff.json").write_text(json.dumps(results, indent=2))
    print_adaptive(results["adaptive"])
    presets = derive_presets(results)
    (RESULTS / "presets.json").write_text(json.dumps(presets, indent=2))
    plot(results, presets)
    print_presets(presets)
    (RESULTS / "tradeoff.md").write_text(markdown(results, presets))
    print(f"tables for the README: {RESULTS / 'tradeoff.md'}")
    return 0


def markdown(results: dict, presets: dict) -> str:
    """The README's tables: knobs per scene, denoised against raw, encoders, adaptive stopping, presets."""
    scenes = list(results["scenes"])
    cell = lambda row, k, f="{:.1f}": "—" if row is None or row.get(k) is None else f.format(row[k])
    by_key = {s: {(r["knob"], r["label"]): r for r in results["scenes"][s]["rows"]} for s in scenes}
    keys = list(dict.fromkeys(k for s in scenes for k in by_key[s]))  # every scene's rows, in order
    out = [
        "| knob | setting | " + " | ".join(f"{s}: time s / I_z % / image %" for s in scenes) + " |",
        "| --- | --- | " + " | ".join("---" for _ in scenes) + " |",
    ]
    for knob, label in keys:
        if knob == "encoder":
            continue
        cells = []
        for s in scenes:
            r = by_key[s].get((knob, label))
            cells.append(f"{cell(r, 'seconds')} / {cell(r, 'iz_rmse')} / {cell(r, 'image_rmse')}")
        out.append(f"| {knob} | {label} | " + " | ".join(cells) + " |")
    refs = [results["scenes"][s]["reference"] for s in scenes]
    out.append(
        "| reference | "
        + refs[0]["label"]
        + " | "
        + " | ".join(f"{cell(r, 'seconds')} / {cell(r, 'iz_rmse')} (its noise) / {cell(r, 'image_rmse')}" for r in refs)
        + " |"
    )
    out += [
        "",
        "| scene | setting | time s: raw / denoised (of which denoise) | I_z %: raw / denoised | "
        "hemispherical %: raw / denoised | image %: raw / denoised |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for s in scenes:
        for d in (r for r in results["scenes"][s]["rows"] if r["knob"] == "denoise"):
            raw = undenoised_twin(results["scenes"][s]["rows"], d)
            setting = d["label"].removesuffix(" denoised")
            out.append(
                f"| {s} | {setting} | {cell(raw, 'seconds')} / {cell(d, 'seconds')} ({cell(d, 'denoise_seconds', '{:.2f}')}) | "
                + " | ".join(f"{cell(raw, k)} / {cell(d, k)}" for k in ("iz_rmse", "hemispherical_rmse", "image_rmse"))
                + " |"
            )
    out += [
        "",
        "| encoder | " + " | ".join(f"{s}: hemispherical % (reference SH) / encode s" for s in scenes) + " |",
        "| --- | " + " | ".join("---" for _ in scenes) + " |",
    ]
    for knob, label in keys:
        if knob != "encoder":
            continue
        rs = [by_key[s].get((knob, label)) for s in scenes]
        out.append(
            f"| {label} | "
            + " | ".join(
                f"{cell(r, 'hemispherical_rmse_of_reference', '{:.2f}')} / {cell(r, 'reencode_seconds', '{:.2f}')}"
                for r in rs
            )
            + " |"
        )
    out += [
        "",
        "| scene | setting | time s | mean spp | I_z % | fixed counts: time to the same error | speed-up |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for s, rows in results.get("adaptive", {}).items():
        for r in rows:
            t = (
                "out of range"
                if r["fixed_seconds_same_error"] is None
                else (f"{'~' if r['extrapolated'] else ''}{r['fixed_seconds_same_error']:.1f} s")
            )
            sp = "—" if r["speedup"] is None else f"{r['speedup']:.2f}×"
            out.append(
                f"| {s} | {r['label']} | {r['seconds']:.1f} | {r['mean_samples'] or 0:.0f} | {r['iz_rmse']:.1f} | {t} | {sp} |"
            )
    out += [
        "",
        "| preset | worst-scene I_z ≤ | samples | bounces | noise target | denoise | "
        + " | ".join(f"{s}: time s / I_z % / image % / memory MB" for s in scenes)
        + " |",
        "| --- | --- | --- | --- | --- | --- | " + " | ".join("---" for _ in scenes) + " |",
    ]
    for name, p in presets.items():
        if not p["found"]:
            out.append(
                f"| {name.title()} | {p['level']:g}% | not reached | | | | " + " | ".join("" for _ in scenes) + " |"
            )
            continue
        cells = [
            f"{cell(r, 'seconds')} / {cell(r, 'iz_rmse')} / {cell(r, 'image_rmse')} / {cell(r, 'peak_memory_mb', '{:.0f}')}"
            for r in p["per_scene"].values()
        ]
        out.append(
            f"| {name.title()} | {p['level']:g}% | {p['samples']} | {p['bounces']} | "
            f"{100 * p['noise_target']:g}% | {'on' if p['denoise'] else 'off'} | " + " | ".join(cells) + " |"
        )
    return "\n".join(out) + "\n"


def undenoised_twin(rows: list[dict], row: dict) -> dict | None:
    """The undenoised row of the same samples, bounces and noise target as `row` (base density,
    default encoder), if one was measured."""
    for r in rows:
        if r["knob"] in ("samples", "bounces", "samples × bounces") and not r.get("denoise"):
            if (r["samples"], r["bounces"], r["noise_target"]) == (row["samples"], row["bounces"], row["noise_target"]):
                return r
    return None


# ---- one scene ------------------------------------------------------------------------------
class Scene:
    """The built scene in its folder, its Cycles reference image and our reference bake."""

    def __init__(self, name: str, args):
        import bpy

        from preview import configure_output
        from scenekit import blender, scenes

        self.name, self.args = name, args
        self.folder = (args.out / name).resolve()
        self.folder.mkdir(parents=True, exist_ok=True)
        scenes.build(name)
        blender.externalise_images(self.folder)
        bpy.ops.wm.save_as_mainfile(filepath=str(self.folder / "scene.blend"))
        self.scene = bpy.context.scene
        configure_output(self.scene)
        self.scene.render.resolution_x, self.scene.render.resolution_y = VIEW
        self.meshes = [o for o in self.scene.objects if o.type == 'MESH' and o.name not in scenes.EMITTERS]
        for o in self.scene.objects:
            o.select_set(o in self.meshes)
        bpy.context.view_layer.objects.active = self.meshes[0]
        self.density = None

    def unwrap(self, density: float) -> None:
        import bpy

        if density == self.density:
            return
        s = self.scene.hhd
        s.texel_density, s.padding = density, 2
        assert bpy.ops.hhd.unwrap() == {'FINISHED'}
        self.density = density

    def bake(self, folder: Path, point: dict, trace_memory: bool = False) -> dict:
        """Bake with the point's settings into folder; returns timings, the texel data that was
        encoded (for a denoised point: the raw SH file's, denoised again as the bake did), the
        atlas's files and, with trace_memory, the peak of numpy's allocations during the bake
        (tracemalloc; kept off for timed bakes)."""
        import bpy

        from hhd_lightmapper.bridge import bake_session, denoiser
        from hhd_lightmapper.core.files import lightmap_files
        from hhd_lightmapper.core.post.denoise import filtering, pages

        s = self.scene.hhd
        s.preset = 'CUSTOM'
        s.samples, s.bounces, s.seed = point["samples"], point["bounces"], point.get("seed", 0)
        s.noise_target, s.time_budget = 100.0 * point["noise_target"], point["time_budget"]
        s.denoise = point.get("denoise", False)  # always set: the scene's default is on
        s.output_dir = str(folder)
        set_encoder(s, {})
        session = bake_session.BakeSession(bpy.context)
        if trace_memory:
            tracemalloc.start()
        t = time.perf_counter()
        results = session.run()
        seconds = time.perf_counter() - t
        peak = tracemalloc.get_traced_memory()[1] if trace_memory else 0
        tracemalloc.stop()
        session.finish()
        files = results[0].files
        sidecar = json.loads(files.sidecar.read_text())
        record = sidecar["post"]["denoise"]
        data = lightmap_files.read_texel_data(files)  # the SH as traced
        if s.denoise:
            if not record.get("applied"):
                raise RuntimeError(f"the bake in {folder} was not denoised: {record.get('warning')}")
            # what the bake encoded: the same denoiser (library, threads) on the same SH
            threads = session.settings.trace.threads
            data, _ = pages.denoise_texels(data, filtering.denoiser_for(denoiser.oidn_library(), threads))
        return {
            "seconds": seconds,
            "peak_memory_mb": peak / 2**20 if trace_memory else None,
            "texels": results[0].texels,
            "rays": results[0].rays,
            "mean_samples": sidecar["bake"]["mean_samples_per_texel"],
            "stopped_by": sidecar["bake"]["stopped_by"],
            "denoise_seconds": record.get("seconds"),
            "data": data,
            "files": files,
        }

    def eevee(self, mode: str, folder: Path, tag: str) -> np.ndarray:
        import bpy

        from preview import render

        s = self.scene.hhd
        s.output_dir, s.preview_mode = str(folder), mode
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        try:
            from hhd_lightmapper import blender_compat

            self.scene.render.engine = blender_compat.eevee_engine()
            self.scene.eevee.taa_render_samples = 8
            return render(bpy, self.scene, self.folder / f"eevee_{tag}.exr")
        finally:
            bpy.ops.hhd.preview_hide()


def measure_scene(name: str, args) -> dict:
    from hhd_lightmapper.core import hhd

    sc = Scene(name, args)
    t = time.perf_counter()
    cycles, cycles_floor, mask = cycles_reference(sc, args.cycles_samples)
    cycles_seconds = time.perf_counter() - t
    density = DENSITY[name]
    sc.unwrap(density)
    print(
        f"[{name}] Cycles view reference {args.cycles_samples} spp: {cycles_seconds:.0f} s, "
        f"noise floor {cycles_floor:.2f}%",
        flush=True,
    )

    half = dict(BASE, samples=args.reference_samples // 2, bounces=8)
    ref_a = sc.bake(sc.folder / "reference_a", dict(half, seed=1))
    ref_b = sc.bake(sc.folder / "reference_b", dict(half, seed=2))
    baked = ref_a["data"].baked
    ref_sh = 0.5 * (ref_a["data"].sh[baked] + ref_b["data"].sh[baked])
    n_v = ref_a["data"].normal[baked]
    ref_iz = lum_iz(ref_sh, n_v)
    mean_iz = ref_iz.mean()
    scale = np.maximum(ref_iz, FLOOR * mean_iz)  # what errors are relative to, per texel
    iz_floor = 100 * 0.5 * rms((lum_iz(ref_a["data"].sh[baked], n_v) - lum_iz(ref_b["data"].sh[baked], n_v)) / scale)
    print(
        f"[{name}] {ref_a['texels']} texels; reference {args.reference_samples} spp, 8 bounces: "
        f"{ref_a['seconds'] + ref_b['seconds']:.0f} s; its I_z noise {iz_floor:.2f}%",
        flush=True,
    )

    def errors(data, encoder=None, mode="HHD", folder=None, tag="", files=None):
        """I_z and hemispherical errors of `data` (the SH encoded), the image error of the EEVEE
        preview of the files in `folder`; with `files` (the atlas's), the check that the I_z
        encoded from `data` is what its `_hhd.exr` holds."""
        row = {}
        if data is not None:
            sh = data.sh[baked]
            row["iz_rmse"] = 100 * rms((lum_iz(sh, n_v) - ref_iz) / scale)
            t = time.perf_counter()
            params = hhd.encode(sh, n_v, **(encoder or {}))
            row["encode_seconds"] = time.perf_counter() - t
            hemi = hhd.hemispherical_rmse(ref_sh, n_v, params, quadrature=QUADRATURE) @ hhd.LUMINANCE
            row["hemispherical_rmse"] = 100 * rms(hemi / scale)
            if files is not None:
                row["encoded_iz_mismatch"] = encoded_iz_mismatch(files, params.irradz, baked)
        if folder is not None:
            t = time.perf_counter()
            image = sc.eevee(mode, folder, tag)
            row["image_rmse"] = image_rmse(image, cycles, mask)
            row["eevee_seconds"] = time.perf_counter() - t
        return row

    rows = []
    knobs = args.knobs or KNOBS
    base_bake = None
    if "denoise" in knobs:  # OIDN loaded before timing, as the tracer is warm from the reference
        warm_denoiser(sc.scene, ref_a["data"])
    for point in knob_points(args.quick, knobs):
        folder = sc.folder / slug(point["label"])
        sc.unwrap(density * point.get("density_factor", 1.0))
        b = sc.bake(folder, point)
        same_texels = point.get("density_factor", 1.0) == 1.0
        row = {**point, "run": args.run_date, **{k: v for k, v in b.items() if k not in ("data", "files")}}
        row.update(
            errors(
                b["data"] if same_texels else None,
                folder=folder,
                tag=slug(point["label"]),
                files=b["files"] if same_texels else None,
            )
        )
        rows.append(row)
        print(f"[{name}] {point['knob']:18s} {point['label']:28s} {fmt_row(row)}", flush=True)
        if point["knob"] == "samples" and point["samples"] == BASE["samples"]:
            base_bake = (b, folder)
    sc.unwrap(density)
    if "encoder" in knobs:
        if base_bake is None:  # the samples knob was not measured: bake the base for the encoders
            folder = sc.folder / "base"
            base_bake = (sc.bake(folder, BASE), folder)
        rows += [{**r, "run": args.run_date} for r in encoder_rows(sc, base_bake, ref_sh, n_v, scale, errors)]
    reference_row = {
        "knob": "reference",
        "run": args.run_date,
        "label": f"{args.reference_samples} spp, 8 bounces",
        "seconds": ref_a["seconds"] + ref_b["seconds"],
        "peak_memory_mb": ref_a["peak_memory_mb"],
        "iz_rmse": iz_floor,
        **errors(None, folder=sc.folder / "reference_a", tag="reference"),
    }
    result = {
        "texels": ref_a["texels"],
        "density": density,
        "mean_iz": float(mean_iz),
        "cycles_seconds": cycles_seconds,
        "cycles_noise_floor": cycles_floor,
        "iz_noise_floor": iz_floor,
        "reference": reference_row,
        "rows": rows,
    }
    attach_memory(result, memory_by_density(sc, density))
    return result


def encoder_rows(sc, base_bake, ref_sh, n_v, scale, errors) -> list[dict]:
    """Encoder settings: re-encode the base bake (files + EEVEE; undenoised, as it was baked) and
    the reference SH (the pure encoding error, `hemispherical_rmse_of_reference`)."""
    import bpy

    from hhd_lightmapper.core import hhd

    b, folder = base_bake
    rows = []
    for label, enc in ENCODERS.items():
        s = sc.scene.hhd
        s.output_dir, s.denoise = str(folder), False  # Re-encode runs the scene's post stages
        set_encoder(s, enc)
        t = time.perf_counter()
        assert bpy.ops.hhd.encode() == {'FINISHED'}
        seconds = time.perf_counter() - t
        core_kwargs = {k: (v.lower() if isinstance(v, str) else v) for k, v in enc.items()}
        default_seconds = rows[0]["reencode_seconds"] if rows else seconds
        # the bake as if it had encoded with these settings: its time with the encode swapped
        row = {
            "knob": "encoder",
            "label": label,
            **BASE,
            "encoder": core_kwargs,
            "seconds": b["seconds"] + seconds - default_seconds,
            "reencode_seconds": seconds,
            "peak_memory_mb": b["peak_memory_mb"],
        }
        row.update(errors(b["data"], core_kwargs, mode=enc.get("model", "HHD"), folder=folder, tag=slug(label)))
        params = hhd.encode(ref_sh, n_v, **core_kwargs)
        row["hemispherical_rmse_of_reference"] = 100 * rms(
            hhd.hemispherical_rmse(ref_sh, n_v, params, quadrature=QUADRATURE) @ hhd.LUMINANCE / scale
        )
        rows.append(row)
        print(f"[{sc.name}] {'encoder':18s} {label:28s} {fmt_row(row)}", flush=True)
    set_encoder(sc.scene.hhd, {})
    return rows


def warm_denoiser(scene, data) -> None:
    """Load OIDN (library, device, weights) for the bakes' thread count and run it once on `data`."""
    from hhd_lightmapper.bridge import denoiser, settings
    from hhd_lightmapper.core import memory
    from hhd_lightmapper.core.post.denoise import filtering, pages

    threads = settings.scene_settings(scene).trace.threads
    pages.denoise_texels(memory.keep(data), filtering.denoiser_for(denoiser.oidn_library(), threads))


def encoded_iz_mismatch(files, irradz: np.ndarray, baked: np.ndarray) -> float:
    """Largest relative difference (relative to max(|I_z|, FLOOR × the mean) per channel) between
    `irradz` (N, 3) of the baked texels and the Iz channels of the atlas's written `_hhd.exr`:
    half-float rounding (< 1e-3) when the errors are of the SH the bake encoded. Raises if not."""
    from hhd_lightmapper.core.encoding.hhd import IZ
    from hhd_lightmapper.core.files import exr

    channels, _ = exr.read(files.hhd)
    written = np.stack([exr.from_exr_rows(channels[n]) for n in IZ.exr_names], -1)[baked]
    written = written.astype(np.float64)
    floor = np.maximum(np.abs(written), FLOOR * np.abs(written).mean(axis=0))
    mismatch = float(np.max(np.abs(irradz - written) / floor))
    if not mismatch < 1e-2:
        raise RuntimeError(
            f"{files.hhd}: the SH measured is not what was encoded (I_z differs by {100 * mismatch:.2f}%)"
        )
    return mismatch


def set_encoder(settings, enc: dict) -> None:
    settings.model, settings.direction = enc.get("model", "HHD"), enc.get("direction", "SEARCHED")
    settings.ambient, settings.phi_search = enc.get("ambient", "LUMINANCE"), enc.get("phi_search", False)
    settings.golden_iterations = enc.get("golden_iterations", 14)


def cycles_reference(sc: Scene, samples: int):
    """(Cycles render of the view (H, W, 3), its noise floor in %, receiver mask): diffuse only
    (bench/preview.py), 8 bounces, two halves with different seeds."""
    import bpy

    from preview import diffuse_cycles, render

    scene = sc.scene
    diffuse_cycles(bpy, scene, samples // 2, 8)
    scene.render.film_transparent = True
    halves = []
    for seed in (1, 2):
        scene.cycles.seed = seed
        halves.append(render(bpy, scene, sc.folder / f"cycles_{seed}.exr", alpha=True))
    scene.render.film_transparent = False
    mask = (halves[0][..., 3] > 0.999) & (halves[1][..., 3] > 0.999)
    image = 0.5 * (halves[0][..., :3] + halves[1][..., :3])
    floor = 0.5 * image_rmse(halves[0][..., :3], halves[1][..., :3], mask)  # σ of the mean of two halves
    return image, floor, mask & ~emitter_mask(sc)


def emitter_mask(sc: Scene) -> np.ndarray:
    """Pixels of the emitting objects (not receivers: their look is their emission), from a
    1-sample render of them alone on a transparent film."""
    import bpy

    from preview import render
    from scenekit import scenes

    emitters = [o for o in sc.scene.objects if o.type == 'MESH' and o.name in scenes.EMITTERS]
    if not emitters:
        return np.zeros((sc.scene.render.resolution_y, sc.scene.render.resolution_x), bool)
    others = [o for o in sc.scene.objects if o.type == 'MESH' and o not in emitters]
    for o in others:
        o.hide_render = True
    sc.scene.cycles.samples, sc.scene.render.film_transparent = 1, True
    alpha = render(bpy, sc.scene, sc.folder / "emitter_mask.exr", alpha=True)[..., 3]
    for o in others:
        o.hide_render = False
    sc.scene.render.film_transparent = False
    return alpha > 0.01


# ---- measures -------------------------------------------------------------------------------
def lum_iz(sh, n_v):
    from hhd_lightmapper.core import hhd

    return hhd.irradz(sh, n_v) @ hhd.LUMINANCE


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def image_rmse(image, reference, mask) -> float:
    """Per-pixel relative RMSE (%), relative to max(reference, FLOOR × its mean), per channel."""
    ref = reference[mask]
    return float(100 * rms((image[mask] - ref) / np.maximum(ref, FLOOR * ref.mean(axis=0))))


def memory_by_density(sc: Scene, density: float, factors=(0.5, 1.0, 2.0)) -> dict:
    """Peak memory (MB, numpy allocations; Embree's BVH of these scenes is a few MB more, OIDN's
    own buffers are not counted) of a 32-spp bake at each texel density factor, and of one with
    the denoiser at the base density (key "denoise"). The tracer works in fixed chunks, so the
    peak does not depend on samples (≥ 16 per pass), bounces, noise target, time budget or
    encoder: only on the texel count (and on whether the denoiser runs)."""
    out = {}
    for f in factors:
        sc.unwrap(density * f)
        b = sc.bake(sc.folder / f"memory_{f:g}", dict(BASE, samples=32), trace_memory=True)
        out[f] = {"texels": b["texels"], "peak_memory_mb": b["peak_memory_mb"]}
    sc.unwrap(density)
    b = sc.bake(sc.folder / "memory_denoise", dict(BASE, samples=32, denoise=True), trace_memory=True)
    out["denoise"] = {"texels": b["texels"], "peak_memory_mb": b["peak_memory_mb"]}
    return out


def attach_memory(res: dict, memory: dict) -> None:
    """Every row's peak memory from its density's measurement (or the denoised bake's)."""
    res["memory"] = memory = {str(k): v for k, v in memory.items()}
    for row in res["rows"] + [res["reference"]]:
        key = "denoise" if row.get("denoise") else str(float(row.get("density_factor", 1.0)))
        row["peak_memory_mb"] = memory[key]["peak_memory_mb"] if key in memory else None


def images_only(args) -> int:
    """Image errors of the EEVEE renders a run left in args.out against fresh Cycles references."""
    from hhd_lightmapper.core.files import exr

    results = json.loads((RESULTS / "tradeoff.json").read_text())
    for name, res in results["scenes"].items():
        sc = Scene(name, args)
        t = time.perf_counter()
        cycles, floor, mask = cycles_reference(sc, args.cycles_samples)
        res["cycles_seconds"], res["cycles_noise_floor"] = time.perf_counter() - t, floor
        for row in res["rows"] + [res["reference"]]:
            tag = "reference" if row is res["reference"] else slug(row["label"])
            channels, _ = exr.read(sc.folder / f"eevee_{tag}.exr")
            image = np.stack([exr.from_exr_rows(channels[c]) for c in "RGB"], -1).astype(np.float64)
            row["image_rmse"] = image_rmse(image, cycles, mask)
        print(f"[{name}] Cycles {args.cycles_samples} spp again: noise floor {floor:.2f}%", flush=True)
        print_table(name, res)
    return finish(results)


def memory_only(args) -> int:
    """Measure memory per scene and density and attach it to the saved results."""
    results = json.loads((RESULTS / "tradeoff.json").read_text())
    for name in results["scenes"]:
        sc = Scene(name, args)
        memory = memory_by_density(sc, DENSITY[name])
        attach_memory(results["scenes"][name], memory)
        print(
            f"[{name}] peak memory: "
            + ", ".join(
                f"{'denoised' if f == 'denoise' else f'density × {f:g}'}: {m['texels']} texels, "
                f"{m['peak_memory_mb']:.0f} MB"
                for f, m in memory.items()
            ),
            flush=True,
        )
    return finish(results)


def slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label).strip("_")


def fmt_row(row: dict) -> str:
    f = lambda k: f"{row[k]:7.2f}" if row.get(k) is not None else "      —"
    denoise = f" (denoise {row['denoise_seconds']:.2f} s)" if row.get("denoise_seconds") is not None else ""
    return (
        f"{row['seconds']:8.1f} s {f('peak_memory_mb')} MB  I_z {f('iz_rmse')}%  "
        f"hemi {f('hemispherical_rmse')}%  image {f('image_rmse')}%{denoise}"
    )


def print_table(name: str, res: dict) -> None:
    print(
        f"\n{name}: {res['texels']} texels at {res['density']:g} texels/m; relative RMSE in %; "
        f"floors: reference I_z noise {res['iz_noise_floor']:.2f}%, Cycles image noise {res['cycles_noise_floor']:.2f}%"
    )
    print(f"{'knob':18s} {'setting':28s} {'time':>10s} {'memory':>10s} {'I_z':>12s} {'hemi':>13s} {'image':>14s}")
    for row in res["rows"] + [res["reference"]]:
        print(f"{row['knob']:18s} {row['label']:28s} {fmt_row(row)}")


# ---- adaptive stopping against fixed counts ---------------------------------------------------
def adaptive_vs_fixed(res: dict) -> list[dict]:
    """Per noise-target and time-budget point: the time fixed sample counts (same bounces) need
    for the same I_z error, and the error they reach in the same time (log-log interpolation
    along the samples axis; None outside its range)."""
    fixed = sorted((r for r in res["rows"] if r["knob"] == "samples"), key=lambda r: r["seconds"])
    t = np.log([r["seconds"] for r in fixed])
    e = np.log([r["iz_rmse"] for r in fixed])
    out = []
    for r in res["rows"]:
        if r["knob"] not in ("noise target", "time budget"):
            continue
        le, lt = np.log(r["iz_rmse"]), np.log(r["seconds"])
        order = np.argsort(e)
        time_same_error = float(np.exp(np.interp(le, e[order], t[order]))) if e.min() <= le <= e.max() else None
        extrapolated = time_same_error is None and le < e[-1] and e[-2] > e[-1]
        if extrapolated:  # beyond the most samples measured: continue the last segment's slope
            time_same_error = float(np.exp(t[-1] + (le - e[-1]) * (t[-1] - t[-2]) / (e[-1] - e[-2])))
        error_same_time = float(np.exp(np.interp(lt, t, e))) if t.min() <= lt <= t.max() else None
        out.append(
            {
                "label": r["label"],
                "seconds": r["seconds"],
                "iz_rmse": r["iz_rmse"],
                "mean_samples": r.get("mean_samples"),
                "stopped_by": r.get("stopped_by"),
                "fixed_seconds_same_error": time_same_error,
                "fixed_error_same_time": error_same_time,
                "speedup": time_same_error / r["seconds"] if time_same_error else None,
                "extrapolated": bool(extrapolated),
            }
        )
    return out


def print_adaptive(adaptive: dict) -> None:
    print("\nAdaptive stopping and time budgets against fixed sample counts (same bounces):")
    print(
        f"{'scene':10s} {'setting':14s} {'time':>8s} {'mean spp':>9s} {'I_z':>7s} {'fixed: time for it':>19s} "
        f"{'speed-up':>9s} {'fixed: error in it':>19s}"
    )
    for scene, rows in adaptive.items():
        for r in rows:
            fs = f"{r['fixed_seconds_same_error']:.1f} s" if r["fixed_seconds_same_error"] else "out of range"
            fs = f"~{fs} (extrap.)" if r.get("extrapolated") else fs
            sp = f"{r['speedup']:.2f}×" if r["speedup"] else "—"
            fe = f"{r['fixed_error_same_time']:.2f}%" if r["fixed_error_same_time"] else "out of range"
            print(
                f"{scene:10s} {r['label']:14s} {r['seconds']:7.1f}s {r['mean_samples'] or 0:9.0f} "
                f"{r['iz_rmse']:6.2f}% {fs:>19s} {sp:>9s} {fe:>19s}"
            )


# ---- presets and plots ----------------------------------------------------------------------
def derive_presets(results: dict) -> dict:
    """For each level of PRESET_LEVELS: among the settings (samples, bounces, noise target,
    denoise) measured on every scene at the base density and default encoder, denoised points
    included (except for UNDENOISED_PRESETS), the one with the least total time whose worst-scene
    I_z RMSE is within the level."""
    by_setting = {}
    for scene, res in results["scenes"].items():
        for row in res["rows"]:
            if row["knob"] in ("encoder", "texel density", "time budget") or row.get("iz_rmse") is None:
                continue
            key = (row["samples"], row["bounces"], row["noise_target"], bool(row.get("denoise", False)))
            by_setting.setdefault(key, {})[scene] = row
        # the reference setting itself (its error: its own noise; its bias is not measurable here)
        by_setting.setdefault((results["settings"]["reference_samples"], 8, 0.0, False), {})[scene] = res["reference"]
    n_scenes = len(results["scenes"])
    complete = {k: v for k, v in by_setting.items() if len(v) == n_scenes}
    presets = {}
    for name, level in PRESET_LEVELS.items():
        ok = [
            (sum(r["seconds"] for r in v.values()), k, v)
            for k, v in complete.items()
            if max(r["iz_rmse"] for r in v.values()) <= level and not (k[3] and name in UNDENOISED_PRESETS)
        ]
        if not ok:
            presets[name] = {"level": level, "found": False}
            continue
        _, (samples, bounces, noise, denoise), rows = min(ok, key=lambda x: x[0])
        presets[name] = {
            "level": level,
            "found": True,
            "samples": samples,
            "bounces": bounces,
            "noise_target": noise,
            "denoise": denoise,
            "per_scene": {
                s: {
                    k: r.get(k)
                    for k in (
                        "seconds",
                        "peak_memory_mb",
                        "iz_rmse",
                        "hemispherical_rmse",
                        "image_rmse",
                        "mean_samples",
                        "denoise_seconds",
                    )
                }
                for s, r in rows.items()
            },
        }
    return presets


def print_presets(presets: dict) -> None:
    print("\nPresets (cheapest measured setting within each worst-scene I_z RMSE level):")
    for name, p in presets.items():
        if not p["found"]:
            print(f"  {name:10s} ≤ {p['level']:g}%: no measured setting reaches it")
            continue
        scenes = ", ".join(
            f"{s} {r['seconds']:.1f} s / {r['iz_rmse']:.1f}% / image {r['image_rmse']:.1f}%"
            for s, r in p["per_scene"].items()
        )
        print(
            f"  {name:10s} ≤ {p['level']:g}%: {p['samples']} spp, {p['bounces']} bounces, "
            f"noise target {100 * p['noise_target']:g}%, {'denoised' if p['denoise'] else 'not denoised'}  ({scenes})"
        )


def plot(results: dict, presets: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(results["scenes"])
    knobs = list(dict.fromkeys(r["knob"] for res in results["scenes"].values() for r in res["rows"]))
    for metric, label in (
        ("iz_rmse", "relative I_z RMSE (%)"),
        ("image_rmse", "EEVEE image vs Cycles, relative RMSE (%)"),
    ):
        fig, axes = plt.subplots(1, len(scenes), figsize=(5.2 * len(scenes), 4.2), squeeze=False)
        for ax, scene in zip(axes[0], scenes):
            res = results["scenes"][scene]
            for knob in knobs:
                rows = [r for r in res["rows"] if r["knob"] == knob and r.get(metric) is not None]
                rows.sort(key=lambda r: r["seconds"])
                if knob == "denoise":  # a line along the samples at the base bounces, the pairs apart
                    others = [r for r in rows if r["bounces"] != BASE["bounces"]]
                    rows = [r for r in rows if r["bounces"] == BASE["bounces"]]
                if rows:
                    style = "s-" if knob == "denoise" else "o-"
                    (line,) = ax.plot([r["seconds"] for r in rows], [r[metric] for r in rows], style, ms=4, label=knob)
                if knob == "denoise" and others:
                    ax.plot(
                        [r["seconds"] for r in others],
                        [r[metric] for r in others],
                        "s",
                        mfc="none",
                        color=line.get_color() if rows else None,
                        ms=6,
                        label="denoise, other bounces",
                    )
            ref = res["reference"]
            if ref.get(metric) is not None:
                ax.plot([ref["seconds"]], [ref[metric]], "k*", ms=9, label="reference")
            front = pareto([r for r in res["rows"] if r.get(metric) is not None], metric)
            ax.plot(
                [r["seconds"] for r in front], [r[metric] for r in front], "k--", lw=1, alpha=0.6, label="Pareto front"
            )
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(f"{scene} ({res['texels']} texels)", fontsize=10)
            ax.set_xlabel("wall time of the bake (s)")
            ax.set_ylabel(label)
            ax.grid(True, which="both", alpha=0.3)
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(RESULTS / f"tradeoff_{'iz' if metric == 'iz_rmse' else 'image'}.png", dpi=100)
        plt.close(fig)


def pareto(rows: list[dict], metric: str) -> list[dict]:
    """Rows no other row beats on both time and the metric, by increasing time."""
    front, best = [], float("inf")
    for r in sorted(rows, key=lambda r: (r["seconds"], r[metric])):
        if r[metric] < best:
            front.append(r)
            best = r[metric]
    return front


if __name__ == "__main__":
    sys.exit(main())
