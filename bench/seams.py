"""Seam stitching measured: how visible the seams are before and after, what it costs the interior.

    flock /tmp/bench.lock .venv/bin/python bench/seams.py     # everything (10–18 min on 2 shared cores)
    .venv/bin/python bench/seams.py --quick                   # a smoke run: 256² atlases, few samples
    .venv/bin/python bench/seams.py --replot                  # seams.md from the saved JSON
    .venv/bin/python bench/seams.py --scenes shapes bedroom

Scenes: `shapes` (a smooth UV sphere and a smooth cylinder, flat caps, on a floor under
scenekit's `sun_and_sky`: every seam of the sphere and the cylinder's side is smooth), `staircase2`
and `bedroom` (external scenes: docs/conventions.md#external-scenes; emissive-lit interiors;
receivers as bench/denoise.py picks them:
its RECEIVERS largest meshes that are not emitters or glass) and the `classroom` (sun + sky through
the windows, its 6 receivers, all flat with hard edges: no smooth seam, so CLASSROOM_EXTRA, two
meshes with curved smooth parts, receive too). Per scene one shared atlas (`--resolution`, `--padding` texels
between charts; doubled until the receivers fit one atlas) unwrapped by the extension's
`bpy.ops.hhd.unwrap`; BOUNCES diffuse bounces.

Per scene, the atlas's seams (`core.post.seams.geometry.find_seams` on the bake points' mesh, timed), then:

- rows: the SH the encoder sees and the HHD file it writes with stitching off and on
  (`core.post.seams.stitching.stitch` after the other post stages, then `core.post.seams.encoded_stitch.stitch_encoded` on the
  encoded layers, as `core.post` runs them), for the bake at `--samples` raw and denoised (the
  PRODUCTION preset's pipeline: OIDN's lightmap filter, then stitching) and for the reference.
- seam metric (`core.post.seams.metrics.seam_metric`, read as the preview reads the lightmap): length-weighted
  mean and P95 of the luminance relative difference across the seams, the interior step (the
  same one texel inside the charts) and their ratio (1: no more visible than the texel grid);
  the same with the normal tilted by 30° four ways (`tilted`); read from the SH (L2 irradiance)
  and from the encoded HHD file's images, also after the SH stitch alone (how far the non-linear
  encoding re-opens the seam before its own stitch). Hidden samples (a side reads a buried texel
  the encoder leaves black: `core.post.seams.reads.reads_hidden`) are left out of the metric (and the stitch).
- interior error: luminance I_z at n_v against the reference (two halves of `--reference`
  samples with other seeds; half their RMS difference is its own noise, the floor), relative
  RMSE over fully covered, unburied texels (each texel's error over max(reference, FLOOR × the
  reference's mean), bench/tradeoff.py's rule), of the SH and of the HHD file's I_z, before and
  after stitching, over all of them and
  over the texels stitching changed; the goal is at most 1% worse (after / before ≤ 1.01).
- cost: stitching's seconds (the `stitch` and `stitch_encoded` calls, their own before/after
  metrics included), per megatexel of atlas and per thousand seam samples; one `seam_metric` of the SH on its own (two
  run inside each stitch); finding the seams' seconds.

Writes bench/results/seams.json and seams.md (the tables).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
SCENES = ("shapes", "staircase2", "bedroom", "classroom")
BOUNCES = 3
#: errors are relative per texel to max(reference, FLOOR × the reference's mean) (bench/tradeoff.py)
FLOOR = 0.1
#: the bake's seed and the reference halves' seeds
SEED = 0
REFERENCE_SEEDS = (101, 102)
#: the acceptance goals: seam ratio after stitching, interior error after / before
GOAL = {"ratio": 1.5, "interior_worse": 0.01}
METRIC_KEYS = ("mean", "p95", "interior", "ratio")
#: classroom meshes with smooth seams (758 m and 36 m of them), added to its receivers
CLASSROOM_EXTRA = ("Mesh064", "Mesh026")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=2, help="texels between charts (as bench/denoise.py)")
    ap.add_argument("--samples", type=int, default=64, help="the bake's samples (the PRODUCTION preset's)")
    ap.add_argument("--reference", type=int, default=1024, help="the reference's samples (two halves)")
    ap.add_argument("--quick", action="store_true", help="256² atlases, few samples, a small reference")
    ap.add_argument("--replot", action="store_true", help="seams.md from the saved JSON")
    ap.add_argument("--out", type=Path, help="folder of the results (default bench/results; --quick: a temporary one)")
    args = ap.parse_args()
    global RESULTS
    if args.replot:
        RESULTS = args.out or RESULTS
        results = json.loads((RESULTS / "seams.json").read_text())
        (RESULTS / "seams.md").write_text(markdown(results))
        return 0
    if args.quick:
        args.resolution, args.samples, args.reference = 256, 16, 128
        args.out = args.out or Path(tempfile.mkdtemp(prefix="hhd-bench-seams-"))
    RESULTS = args.out or RESULTS
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    from hhd_lightmapper.bridge import denoiser as bridge_denoiser
    from hhd_lightmapper.core import parallel
    from hhd_lightmapper.core.post.denoise import filtering

    hhd_lightmapper.register()
    t_run = time.perf_counter()
    threads = parallel.resolve_threads(0)
    denoiser = filtering.denoiser_for(bridge_denoiser.oidn_library(), threads)
    results = {
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "replot"},
        "bounces": BOUNCES,
        "threads": threads,
        "oidn_version": denoiser.version,
        "goal": GOAL,
        "load_average_start": os.getloadavg(),
        "scenes": {},
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "seams.json"
    for name in args.scenes:
        results["scenes"][name] = measure_scene(name, args, denoiser)
        print_scene(name, results["scenes"][name])
        out.write_text(json.dumps(results, indent=2))
    results["wall_seconds"] = time.perf_counter() - t_run
    results["load_average_end"] = os.getloadavg()
    out.write_text(json.dumps(results, indent=2))
    (RESULTS / "seams.md").write_text(markdown(results))
    print(f"wall time {results['wall_seconds'] / 60:.1f} min; results in {out} and seams.md", flush=True)
    return 0


# ---- scenes ---------------------------------------------------------------------------------
def shapes() -> list:
    """A smooth UV sphere and a cylinder (smooth side, flat caps: hard rims) on a floor, sun + sky;
    returns the receivers."""
    import bpy

    from scenekit import blender as kit
    from scenekit import scenes

    kit.clear_data(worlds=True)
    grey = kit.material("Grey", (0.7, 0.7, 0.7))
    floor = kit.plane("Floor", (0, 0, 0), 6.0, grey)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.8, location=(-1.0, 0.0, 0.8))
    sphere = bpy.context.active_object
    sphere.name = "Sphere"
    bpy.ops.object.shade_smooth()
    bpy.ops.mesh.primitive_cylinder_add(vertices=32, radius=0.6, depth=1.6, location=(1.0, 0.2, 0.8))
    cylinder = bpy.context.active_object
    cylinder.name = "Cylinder"
    bpy.ops.object.shade_smooth_by_angle(angle=math.radians(30.0))
    for obj in (sphere, cylinder):
        obj.data.materials.append(kit.material(f"{obj.name} paint", (0.8, 0.45, 0.3)))
    scenes.sun_and_sky()
    return [floor, sphere, cylinder]


def load_scene(name: str) -> list:
    import bpy

    import denoise as denoise_bench

    if name == "shapes":
        return shapes()
    receivers = denoise_bench.load_scene(name)
    if name == "classroom":
        receivers += [bpy.data.objects[n] for n in CLASSROOM_EXTRA]
    return receivers


# ---- measures -------------------------------------------------------------------------------
def lum_iz(sh: np.ndarray, normal: np.ndarray) -> np.ndarray:
    from hhd_lightmapper.core import hhd

    return hhd.irradz(sh.astype(np.float64), normal.astype(np.float64)) @ hhd.LUMINANCE


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def brief(metric: dict) -> dict:
    """A seam_metric's headline numbers: mean, p95, interior, ratio, and the same tilted."""
    return {
        **{k: metric[k] for k in METRIC_KEYS},
        "samples": metric["samples"],
        "invalid": metric["invalid"],
        "hidden": metric.get("hidden", 0),
        "tilted": {k: metric["tilted"][k] for k in METRIC_KEYS},
        "worst_edges": metric.get("worst_edges", [])[:3],
    }


class Interior:
    """The interior error of SH images against the reference, over the `keep` texels (P,) of
    the bake points: luminance I_z at n_v, relative to max(reference, FLOOR × its mean)."""

    def __init__(self, points, keep: np.ndarray, a: np.ndarray, b: np.ndarray):
        self.texel, self.normal = points.texel[keep], points.normal[keep]
        ia, ib = lum_iz(a[keep], self.normal), lum_iz(b[keep], self.normal)
        self.value = 0.5 * (ia + ib)
        self.scale = np.maximum(self.value, FLOOR * self.value.mean())
        self.floor = 100 * 0.5 * rms((ia - ib) / self.scale)

    def of(self, sh_image: np.ndarray) -> np.ndarray:
        """Per kept texel relative error (P',) of an SH image `(H, W, 9, 3)`."""
        sh = sh_image.reshape(-1, 9, 3)[self.texel]
        return (lum_iz(sh, self.normal) - self.value) / self.scale

    def compare(self, before: np.ndarray, after: np.ndarray) -> dict:
        """RMSE (%) before and after stitching of SH images `(H, W, 9, 3)`, over all kept texels
        and over those stitching changed."""
        changed = (before.reshape(-1, 27)[self.texel] != after.reshape(-1, 27)[self.texel]).any(axis=1)
        return self.errors(self.of(before), self.of(after), changed)

    def compare_iz(self, before: np.ndarray, after: np.ndarray) -> dict:
        """The same for luminance I_z images `(H, W)` (the HHD file's)."""
        b, a = before.reshape(-1)[self.texel], after.reshape(-1)[self.texel]
        return self.errors((b - self.value) / self.scale, (a - self.value) / self.scale, b != a)

    def errors(self, e0: np.ndarray, e1: np.ndarray, changed: np.ndarray) -> dict:
        out = {"floor": self.floor, "texels": int(len(e0)), "changed_texels": int(changed.sum())}
        for key, sel in (("all", slice(None)), ("changed", changed)):
            b, a = 100 * rms(e0[sel]), 100 * rms(e1[sel])
            out[key] = {"before": b, "after": a, "worse": (a / b - 1.0) if b > 0 else 0.0}
        return out


def encode(data):
    """`data` encoded with the default encoder (the HHD file's images, no raw files); `data` kept
    (`encode_atlas` takes the SH out of a TexelData of its own)."""
    from dataclasses import replace

    from hhd_lightmapper.core import encoding

    return encoding.encode_atlas(replace(data), encoding.for_settings(encoding.EncoderSettings()), raw=False)


def stitch_row(data, seams_, interior: Interior | None) -> dict:
    """Stitching `data` (TexelData) as the pipeline does (`core.post`: the SH, then the encoded
    layers): the seam metric of the SH and of the HHD file before and after (and after the SH
    stitch alone), the interior error of the SH and of the HHD file's I_z, and the time."""
    from hhd_lightmapper.core import memory
    from hhd_lightmapper.core.post.seams import encoded_stitch, metrics, stitching

    t = time.perf_counter()
    stitched, record = stitching.stitch(memory.keep(data), seams_)
    sh_seconds = time.perf_counter() - t
    unstitched, sh_only = encode(data), encode(stitched)
    spent = encode(stitched)  # the encoded stitch writes into the atlas it is handed: not `sh_only`
    t = time.perf_counter()
    final, encoded_record = encoded_stitch.stitch_encoded(spent, seams_, stitched.coverage)
    encoded_seconds = time.perf_counter() - t
    t = time.perf_counter()
    sh_before = brief(metrics.seam_metric(data, seams_))
    metric_seconds = time.perf_counter() - t
    row = {
        "stitch_seconds": sh_seconds + encoded_seconds,
        "sh_stitch_seconds": sh_seconds,
        "encoded_stitch_seconds": encoded_seconds,
        "metric_seconds": metric_seconds,
        "record": {k: v for k, v in record.items() if k not in ("before", "after")},
        "implausible": implausible(data, stitched),
        "encoded_record": {k: v for k, v in encoded_record.items() if k not in ("before", "after")},
        "sh": {"before": sh_before, "after": brief(metrics.seam_metric(stitched, seams_))},
        "hhd": {
            "before": brief(metrics.seam_metric(unstitched, seams_, coverage=data.coverage)),
            "after_sh_stitch": brief(metrics.seam_metric(sh_only, seams_, coverage=data.coverage)),
            "after": brief(metrics.seam_metric(final, seams_, coverage=data.coverage)),
        },
    }
    if interior is not None:
        row["interior_error"] = interior.compare(data.sh, stitched.sh)
        row["interior_error_hhd"] = interior.compare_iz(iz_image(unstitched), iz_image(final))
    return row


def implausible(data, stitched) -> dict:
    """Among the texels stitching changed: how many have a negative L0 or I_z at their normal."""
    from hhd_lightmapper.core import hhd

    changed = (stitched.sh != data.sh).reshape(-1, 27).any(axis=1)
    sh = stitched.sh.reshape(-1, 9, 3)[changed].astype(np.float64)
    n = stitched.normal.reshape(-1, 3)[changed].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = hhd.irradz(sh, n / np.linalg.norm(n, axis=1, keepdims=True))
    return {
        "changed": int(changed.sum()),
        "negative_l0": int((sh[:, 0] < 0).any(axis=1).sum()),
        "negative_iz": int((iz < 0).any(axis=1).sum()),
        "zero_or_negative_iz": int((iz <= 0).any(axis=1).sum()),
    }


def iz_image(encoded) -> np.ndarray:
    """The luminance of the HHD file's I_z `(H, W)` (rows bottom-up)."""
    from hhd_lightmapper.core import hhd
    from hhd_lightmapper.core.post.seams import reads

    images = reads.encoded_images(encoded)
    return np.stack([images[f"Iz.{c}"] for c in "RGB"], -1).astype(np.float64) @ hhd.LUMINANCE


def measure_scene(name: str, args, denoiser) -> dict:
    import denoise as denoise_bench
    from hhd_lightmapper.core import bake, encoding, memory, tracer
    from hhd_lightmapper.core.post.denoise import pages
    from hhd_lightmapper.core.post.seams import geometry

    t_scene = time.perf_counter()
    receivers = load_scene(name)
    resolution = args.resolution
    while True:  # one atlas: the texels of several would overlap in one image
        atlas = denoise_bench.Atlas(receivers, resolution, args.padding)
        if len({o.hhd.atlas for o in receivers}) == 1:
            break
        resolution *= 2
    print(f"[{name}] receivers {[o.name for o in receivers]}; {atlas.unwrap_summary}", flush=True)

    def trace(samples: int, seed: int):
        settings = tracer.BakeSettings.from_samples(samples, bounces=BOUNCES, seed=seed)
        t = time.perf_counter()
        traced = bake.trace_surface(atlas.surface, atlas.size, atlas.size, atlas.bake_scene, settings)
        return traced, time.perf_counter() - t

    traced, bake_seconds = trace(args.samples, SEED)
    points = traced.points
    t = time.perf_counter()
    seams_ = geometry.find_seams(points.mesh, atlas.size, atlas.size)
    find_seconds = time.perf_counter() - t
    halves, ref_seconds = [], 0.0
    for seed in REFERENCE_SEEDS:
        half, s = trace(args.reference // 2, seed)
        assert np.array_equal(half.points.texel, points.texel)
        halves.append(half.sh)
        ref_seconds += s
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    interior = Interior(points, keep, halves[0], halves[1])
    print(
        f"[{name}] {len(points.texel)} texels, {len(seams_)} seam samples on {seams_.edges} edges "
        f"(found in {find_seconds:.2f} s); bake {args.samples} spp {bake_seconds:.0f} s, reference "
        f"{args.reference} spp {ref_seconds:.0f} s, floor {interior.floor:.2f}%",
        flush=True,
    )
    raw = encoding.TexelData.from_points(points, traced.sh)
    t = time.perf_counter()
    denoised, _ = pages.denoise_texels(memory.keep(raw), denoiser)
    denoise_seconds = time.perf_counter() - t
    reference = encoding.TexelData.from_points(points, 0.5 * (halves[0] + halves[1]))
    rows = {}
    for label, data, against in (
        ("raw", raw, interior),
        ("denoised", denoised, interior),
        ("reference", reference, None),
    ):
        rows[label] = stitch_row(data, seams_, against)
        print_row(name, label, rows[label])
    megatexels = atlas.size * atlas.size / 1e6
    stitch_seconds = rows["denoised"]["stitch_seconds"]
    return {
        "receivers": [o.name for o in receivers],
        "unwrap": atlas.unwrap_summary,
        "resolution": atlas.size,
        "triangles": int(len(atlas.bake_scene.triangles)),
        "receiver_triangles": int(len(points.mesh.positions)),
        "texels": int(len(points.texel)),
        "measured_texels": int(keep.sum()),
        "seam_samples": len(seams_),
        "seam_edges": seams_.edges,
        "seam_length_m": float(seams_.weight.sum()),
        "find_seams_seconds": find_seconds,
        "bake": {"samples": args.samples, "seconds": bake_seconds, "denoise_seconds": denoise_seconds},
        "reference": {"samples": args.reference, "seconds": ref_seconds, "floor": interior.floor},
        "rows": rows,
        "cost": {
            "stitch_seconds": stitch_seconds,
            "seconds_per_megatexel": stitch_seconds / megatexels,
            "seconds_per_1000_samples": 1000.0 * stitch_seconds / max(len(seams_), 1),
            "stitched_texels": rows["denoised"]["record"]["texels"],
            "bounded_texels": rows["denoised"]["record"]["texels_bounded"],
            "metric_seconds": rows["denoised"]["metric_seconds"],
            "sh_stitch_seconds": rows["denoised"]["sh_stitch_seconds"],
            "encoded_stitch_seconds": rows["denoised"]["encoded_stitch_seconds"],
        },
        "scene_seconds": time.perf_counter() - t_scene,
    }


# ---- output ---------------------------------------------------------------------------------
def print_row(name: str, label: str, row: dict) -> None:
    sh, hhd = row["sh"], row["hhd"]
    text = (
        f"[{name}] {label:9s} seam ratio SH {sh['before']['ratio']:.2f} -> {sh['after']['ratio']:.2f}, "
        f"HHD {hhd['before']['ratio']:.2f} -> {hhd['after']['ratio']:.2f} (tilted {hhd['before']['tilted']['ratio']:.2f} "
        f"-> {hhd['after']['tilted']['ratio']:.2f}); stitch {row['stitch_seconds']:.2f} s"
    )
    if "interior_error" in row:
        e = row["interior_error"]
        eh = row["interior_error_hhd"]
        text += (
            f"; interior SH {e['all']['before']:.2f}% -> {e['all']['after']:.2f}% ({100 * e['all']['worse']:+.2f}%), "
            f"HHD I_z {eh['all']['before']:.2f}% -> {eh['all']['after']:.2f}% ({100 * eh['all']['worse']:+.2f}%)"
        )
    print(text, flush=True)


def print_scene(name: str, r: dict) -> None:
    c = r["cost"]
    print(
        f"[{name}] done in {r['scene_seconds']:.0f} s; stitching {c['stitch_seconds']:.2f} s = "
        f"{c['seconds_per_megatexel']:.2f} s/Mtexel of atlas",
        flush=True,
    )


def fmt(x: float, digits: int = 2) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def markdown(results: dict) -> str:
    s = results["settings"]
    lines = [
        "# Seam stitching (`bench/seams.py`)",
        "",
        f"{s['resolution']}² atlases (larger where noted), {results['bounces']} bounces, bake {s['samples']} spp (raw, and denoised as "
        f"the PRODUCTION preset), reference {s['reference']} spp; {results['threads']} threads; "
        f"wall {results.get('wall_seconds', 0) / 60:.1f} min. Seam metric: length-weighted mean and P95 of the "
        "luminance relative difference across the seams, read as the preview reads the lightmap; ratio = mean / "
        "the same one texel inside the charts (≤ 1: no more visible than the texel grid). Tilted: the normal "
        "tilted by 30° four ways. Hidden samples (one side reads a buried texel the encoder leaves black: no "
        "unburied texel in its chart, the surface is inside closed geometry) are left out of the metric and "
        "of the stitch; the seam samples column gives them in brackets. Goal: ratio ≤ "
        f"{results['goal']['ratio']} after stitching, interior error ≤ {100 * results['goal']['interior_worse']:.0f}% worse.",
        "",
        "## Seams before → after stitching (HHD file as the preview reads it; SH ratio for comparison)",
        "",
        "| scene | row | seam samples (hidden) | mean % | P95 % | ratio | tilted ratio | ratio, SH stitch only | SH ratio |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results["scenes"].items():
        for label, row in r["rows"].items():
            b, a = row["hhd"]["before"], row["hhd"]["after"]
            sb, sa = row["sh"]["before"], row["sh"]["after"]
            lines.append(
                f"| {name} | {label} | {r['seam_samples']} ({b.get('hidden', 0)}) | {fmt(100 * b['mean'])} → {fmt(100 * a['mean'])} | "
                f"{fmt(100 * b['p95'])} → {fmt(100 * a['p95'])} | {fmt(b['ratio'])} → {fmt(a['ratio'])} | "
                f"{fmt(b['tilted']['ratio'])} → {fmt(a['tilted']['ratio'])} | "
                f"{fmt(row['hhd']['after_sh_stitch']['ratio'])} | {fmt(sb['ratio'])} → {fmt(sa['ratio'])} |"
            )
    lines += [
        "",
        "## Interior error against the reference (luminance I_z, relative RMSE %)",
        "",
        "| scene | row | of | reference floor % | all texels before → after | worse | texels changed | "
        "changed: before → after |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results["scenes"].items():
        for label in ("raw", "denoised"):
            for of, key in (("SH", "interior_error"), ("HHD I_z", "interior_error_hhd")):
                e = r["rows"][label][key]
                lines.append(
                    f"| {name} | {label} | {of} | {fmt(e['floor'])} | {fmt(e['all']['before'])} → "
                    f"{fmt(e['all']['after'])} | {100 * e['all']['worse']:+.2f}% | {e['changed_texels']} of "
                    f"{e['texels']} | {fmt(e['changed']['before'])} → {fmt(e['changed']['after'])} |"
                )
    lines += [
        "",
        "## Cost",
        "",
        "| scene | atlas | texels baked | seam edges | seam samples | find seams s | stitch s (SH + encoded) | "
        "s per Mtexel of atlas | one SH metric s | texels stitched | held by the bound | L0 < 0 / I_z < 0 after |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results["scenes"].items():
        c = r["cost"]
        bad = r["rows"]["denoised"].get("implausible", {})
        lines.append(
            f"| {name} | {r['resolution']}² | {r['texels']} | {r['seam_edges']} | {r['seam_samples']} | {fmt(r['find_seams_seconds'], 3)} | "
            f"{fmt(c['stitch_seconds'])} ({fmt(c['sh_stitch_seconds'])} + {fmt(c['encoded_stitch_seconds'])}) | "
            f"{fmt(c['seconds_per_megatexel'])} | {fmt(c['metric_seconds'])} | "
            f"{c['stitched_texels']} | {c.get('bounded_texels', '–')} | {bad.get('negative_l0', '–')} / "
            f"{bad.get('negative_iz', '–')} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
