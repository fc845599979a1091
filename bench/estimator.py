"""The hemisphere estimator's variants: per-sample variance of I_z, band 0 and band 1.

    flock /tmp/bench.lock .venv/bin/python bench/estimator.py              # classroom, staircase2
    .venv/bin/python bench/estimator.py --scenes classroom --samples 4 16 64 256

Our bake against our own converged bake (two halves of `--reference` samples with their own
seeds; their noise, the floor, is removed from every error in quadrature), so the variants are
compared with each other, not with Cycles (bench/time_to_error.py does that). Scenes and atlas
as bench/time_to_error.py sets them up, BOUNCES bounces, `--resolution` atlas. Variants
(`core.tracer.hemisphere`; the parts not yet across passes drawn pass by pass by
scenekit/estimator_reference.py):

- `pass by pass`: the mixture α/(2π) + (1 − α)·cosθ/π (α ½), independent directions, β of the
  control variate from the other half's mean (`hemisphere_kernels.project_halves`), the origins
  a shifted Hammersley set per pass, the first bounce independent;
- `directions across passes`: the mixture sampled by inversion in two halves, each from its
  texel's own scrambled (0,2)-sequence stratified across all the texel's passes
  (`hemisphere_kernels.texel_hemisphere_rays`);
- `+ origins across passes`: the origins' first tries from the texel's own (0,2)-sequence too
  (`BakePoints.sample_origins`);
- `+ first bounce across passes`: each path's first bounce (its light samples and its next
  direction) from the texel's own sequences too (`paths.TexelSamples`);
- `+ α 1/3`, `+ α 0.25`, `+ α 0.1`: a third, a quarter, a tenth of the mixture uniform
  instead of half.

Until commit 054f7f8 the first row was `per pass`: the estimator until 2026-12-02, half the
directions uniform, half cosine-weighted, in four groups each Latin-hypercube stratified within
its pass, β from the other half's cosine samples (a switch of the product's, retired after that
commit with the kernels it kept); bench/results holds it as measured then (a rerun of a scene
writes `pass by pass` instead).

Every row is the mean over `--seeds` bakes with different seeds (a few heavy-tailed texels make
one bake's error swing by ±10%).

Per row: the relative RMSE (luminance, over fully covered unburied texels) of I_z, of band 0
and of band 1 (the three coefficients' errors summed in quadrature; both bands relative to the
mean |band 0|), and of what a shader computes from the HHD file (`hhd.encode` at the product's
defaults, `hhd.reconstruct`) at shading normals tilted TILTS degrees from n_v (four azimuths,
errors in quadrature, each relative to its own mean): each as per-sample variance (error² ×
samples, lower is better), and the bias of I_z (ΣI_z ratio − 1). The HHD columns' floor is
half the two reference halves' difference (the encoding is not linear). `--variants` picks
rows of VARIANTS by index. Writes bench/results/estimator.json and .md.
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
SCENES = ("classroom", "field", "staircase2", "bedroom")
#: (name, the parts drawn pass by pass (`estimator_reference.PARTS`), UNIFORM_SHARE)
VARIANTS = (
    ("pass by pass", ("directions", "origins", "first_bounce"), 0.5),
    ("directions across passes", ("origins", "first_bounce"), 0.5),
    ("+ origins across passes", ("first_bounce",), 0.5),
    ("+ first bounce across passes", (), 0.5),
    ("+ α 1/3", (), 1.0 / 3.0),
    ("+ α 0.25", (), 0.25),
    ("+ α 0.1", (), 0.1),
)
#: The α of the closed-form line at the top of the table (label, α).
IDEAL_ALPHAS = (("1/2", 0.5), ("1/3", 1.0 / 3.0), ("1/4", 0.25), ("1/10", 0.1))
#: Tilts (degrees) of the shading normals the HHD reconstruction is measured at.
TILTS = (30.0, 45.0)
#: Azimuths of the tilted shading normals, in n_v's tangent frame.
AZIMUTHS = (0.0, 90.0, 180.0, 270.0)
REFERENCE_SEEDS = (101, 102)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", choices=SCENES, default=["classroom", "staircase2"])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--reference", type=int, default=1024, help="our reference's samples, both halves")
    ap.add_argument("--samples", type=int, nargs="+", default=[4, 16, 64, 256])
    ap.add_argument("--seeds", type=int, default=4, help="bakes per row, averaged")
    ap.add_argument("--variants", type=int, nargs="+", default=list(range(len(VARIANTS))), help="indices into VARIANTS")
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    import time_to_error as tte

    hhd_lightmapper.register()
    out_json = RESULTS / "estimator.json"
    results = json.loads(out_json.read_text()) if out_json.exists() else {}
    for name in args.scenes:
        surface, bake_scene = read_scene(tte, name, args.resolution)
        results[name] = merged(results.get(name), measure(surface, bake_scene, args))
        results[name]["load_average"] = os.getloadavg()
        RESULTS.mkdir(exist_ok=True)
        out_json.write_text(json.dumps(results, indent=2))
    (RESULTS / "estimator.md").write_text(markdown(results, args))
    print((RESULTS / "estimator.md").read_text())
    return 0


def read_scene(tte, name: str, resolution: int):
    """The scene's receivers unwrapped as bench/time_to_error.py does; (surface, bake scene)."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data

    receivers = tte.load_scene(name)
    tte.unwrap(receivers, resolution)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return mesh_data.read_surface(receivers, tte.LAYER, depsgraph), scene_data.read_bake_scene(depsgraph)


def shaded(sh: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """What a shader computes from the HHD encoding of radiance SH `(P, 9, 3)` at shading normals
    tilted TILTS from the unit n_v `(P, 3)` at AZIMUTHS: luminance `(P, len(TILTS)·len(AZIMUTHS))`."""
    from hhd_lightmapper.core import hhd
    from hhd_lightmapper.core import sh as _sh
    from hhd_lightmapper.core.colour import LUMINANCE

    params = hhd.encode(sh, normal)
    frames = _sh.tangent_frames(normal)  # (P, 3, 3), columns t, b, n
    out = []
    for tilt in np.radians(TILTS):
        for azimuth in np.radians(AZIMUTHS):
            local = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
            out.append(hhd.reconstruct(params, normal, frames @ local) @ LUMINANCE)
    return np.stack(out, axis=1)


def bake(surface, bake_scene, resolution: int, samples: int, seed: int, variant) -> tuple[np.ndarray, np.ndarray]:
    """Our bake with `variant`: (I_z, L0, L1x, L1y, L1z, `shaded`…) luminance per texel (P, 5 +
    len(TILTS)·len(AZIMUTHS)) and `keep` (P,) bool (fully covered, unburied)."""
    from hhd_lightmapper.core import bake as _bake
    from hhd_lightmapper.core import hhd, tracer
    from hhd_lightmapper.core.colour import LUMINANCE
    from hhd_lightmapper.core.tracer import hemisphere
    from scenekit import estimator_reference

    _, independent, hemisphere.UNIFORM_SHARE = variant
    settings = tracer.BakeSettings.from_samples(samples, bounces=3, seed=seed)
    with estimator_reference.used(*independent):
        result = _bake.trace_surface(surface, resolution, resolution, bake_scene, settings)
    iz = hhd.irradz(result.sh, result.points.normal) @ LUMINANCE
    normal = result.points.normal / np.linalg.norm(result.points.normal, axis=1, keepdims=True)
    values = np.concatenate([iz[:, None], (result.sh @ LUMINANCE)[:, :4], shaded(result.sh, normal)], axis=1)
    keep = (result.points.coverage >= 1.0 - 1e-9) & ~result.points.buried
    return values, keep


def measure(surface, bake_scene, args) -> dict:
    reference_variant = VARIANTS[3]
    halves = []
    for seed in REFERENCE_SEEDS:
        values, keep = bake(surface, bake_scene, args.resolution, args.reference // 2, seed, reference_variant)
        halves.append(values)
    reference = 0.5 * (halves[0] + halves[1])
    scale = np.abs(reference[keep]).mean(axis=0)
    scale[1:5] = scale[1]  # both bands relative to the mean |band 0|

    def errors(values):
        return np.sqrt(np.mean((values[keep] - reference[keep]) ** 2, axis=0)) / scale

    floor = 0.5 * errors(halves[0] - halves[1] + reference)
    # the HHD columns' floor straight from the halves (the encoding is not linear in the SH)
    floor[5:] = 0.5 * np.sqrt(np.mean((halves[0][keep, 5:] - halves[1][keep, 5:]) ** 2, axis=0)) / scale[5:]
    per_tilt = len(AZIMUTHS)
    out = {
        "texels": int(keep.sum()),
        "reference": args.reference,
        "seeds": args.seeds,
        "floor": floor.tolist(),
        "rows": [],
    }
    print(
        f"reference {args.reference} spp, floors I_z / L0 / L1: {floor[0]:.4f} / {floor[1]:.4f} / {floor[2:].max():.4f}"
    )
    for variant in (VARIANTS[i] for i in args.variants):
        for samples in args.samples:
            t = time.perf_counter()
            squared, bias = np.zeros(len(floor)), 0.0
            for seed in range(args.seeds):
                values, _ = bake(surface, bake_scene, args.resolution, samples, 7 + seed, variant)
                squared += np.maximum(errors(values) ** 2 - floor**2, 0.0) / args.seeds
                bias += (values[keep, 0].sum() / reference[keep, 0].sum() - 1.0) / args.seeds
            seconds = (time.perf_counter() - t) / args.seeds
            row = {
                "variant": variant[0],
                "samples": samples,
                "seconds": seconds,
                "iz": float(squared[0] * samples),
                "band0": float(squared[1] * samples),
                "band1": float(squared[2:5].sum() * samples),
                "shaded": {
                    f"{tilt:g}": float(squared[5 + i * per_tilt : 5 + (i + 1) * per_tilt].mean() * samples)
                    for i, tilt in enumerate(TILTS)
                },
                "bias": float(bias),
            }
            out["rows"].append(row)
            print(
                f"  {variant[0]:30s} {samples:4d} spp: per-sample variance I_z {row['iz']:.4f}, band 0 "
                f"{row['band0']:.4f}, band 1 {row['band1']:.4f}, HHD at "
                + ", ".join(f"{k}° {v:.4f}" for k, v in row["shaded"].items())
                + f"; bias {row['bias']:+.4f}  ({seconds:.1f} s)",
                flush=True,
            )
    return out


def iz_variance_factor(alpha: float) -> float:
    """Per-sample variance of I_z under the mixture α/(2π) + (1 − α)·cosθ/π over pure cosine
    sampling's, for radiance whose deviation from the control variate's β is uncorrelated with
    direction: E_p[w²] / E_cos[w²] with w = cosθ / (π p), i.e. ∫₀¹ 2μ² / (a + bμ) dμ with a = α/2,
    b = 1 − α (closed form; ln 3 at α ½, → 1 as α → 0)."""
    a, b = alpha / 2.0, 1.0 - alpha
    if b <= 0.0:
        return 4.0 / 3.0
    return 2.0 * (1.0 / (2.0 * b) - a / b**2 + a**2 / b**3 * math.log((a + b) / a))


#: Hemisphere densities compared by `density_shapes`: (label, kind, parameter): "mix" the
#: mixture α/(2π) + (1 − α)·cosθ/π, "pow" (γ + 1)·cos^γ θ / (2π).
SHAPES = (
    ("α 1/2", "mix", 0.5),
    ("α 1/3", "mix", 1.0 / 3.0),
    ("α 1/4", "mix", 0.25),
    ("α 1/10", "mix", 0.1),
    ("cos^0.5", "pow", 0.5),
    ("cos^0.6", "pow", 0.6),
    ("cos^0.7", "pow", 0.7),
    ("cos^0.8", "pow", 0.8),
)


def density_shapes(n: int = 400) -> list[tuple[str, list[float]]]:
    """Idealised per-sample variance of what each hemisphere density of SHAPES estimates, over
    α ½'s, for radiance whose deviation from the control variate is uncorrelated with direction:
    ∫ K(ω)² / p(ω) dω by midpoint quadrature (n × 2n in cosθ, φ) of each estimated quantity's
    kernel K: I_z (cosθ), the SH irradiance at a shading normal tilted 15–60° from n_v (the L2
    clamped-cosine kernel, as a shader reconstructs it), band 0 and a band-1 coefficient across
    n_v. Rows (quantity, [ratio per shape])."""
    from hhd_lightmapper.core import sh

    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * np.pi
    m, f = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - m**2)
    d = np.stack([s * np.cos(f), s * np.sin(f), m], -1).reshape(-1, 3)
    dw = (1.0 / n) * (np.pi / n)
    y, z = sh.evaluate(d), d[:, 2]
    densities = [
        a / (2.0 * np.pi) + (1.0 - a) * z / np.pi if kind == "mix" else (a + 1.0) * z**a / (2.0 * np.pi)
        for _, kind, a in SHAPES
    ]
    kernels = [("I_z", z / np.pi)]
    for tilt in (15, 30, 45, 60):
        t = math.radians(tilt)
        shading = sh.evaluate(np.array([[math.sin(t), 0.0, math.cos(t)]]))[0] * sh.COSINE_KERNEL
        kernels.append((f"SH irradiance {tilt}°", y @ shading))
    kernels += [("band 0", y[:, 0]), ("band 1 across n_v", y[:, 3])]
    rows = []
    for name, k in kernels:
        v = np.array([np.sum(k**2 / p) * dw for p in densities])
        rows.append((name, (v / v[0]).tolist()))
    return rows


def merged(before: dict | None, now: dict) -> dict:
    """`now`, with the rows of `before` (the scene's previous run) of the variants and sample
    counts `now` did not measure when both ran against the same reference (same samples, texels
    and floor), in VARIANTS' order."""
    if not before or any(before.get(k) != now[k] for k in ("reference", "texels")):
        return now
    if not np.allclose(before["floor"][:5], now["floor"][:5], rtol=1e-9):
        return now
    measured = {(row["variant"], row["samples"]) for row in now["rows"]}
    rows = now["rows"] + [row for row in before["rows"] if (row["variant"], row["samples"]) not in measured]
    order = {name: i for i, (name, *_) in enumerate(VARIANTS)}
    rows.sort(key=lambda row: (order.get(row["variant"], len(order)), row["samples"]))
    return {**now, "rows": rows}


def markdown(results: dict, args) -> str:
    lines = [
        "# The hemisphere estimator's variants (`bench/estimator.py`)",
        "",
        "Per-sample variance (relative error² × samples; lower is better) of I_z, band 0 and band 1",
        "(luminance) and of the HHD file's shading at normals tilted 30° and 45° from n_v, against",
        "our own converged bake, its noise removed; bias of I_z. See the script's docstring for",
        "the variants.",
        "",
        "Idealised per-sample I_z variance of the mixture over pure cosine sampling's "
        "(`iz_variance_factor`): "
        + ", ".join(f"α {label} {iz_variance_factor(a):.3f}" for label, a in IDEAL_ALPHAS)
        + " (in that model no split gains I_z more than 9% on α 1/2).",
        "",
        "The same model for other densities and what else the SH serves (`density_shapes`; per-"
        "sample variance over α 1/2's): each cos^γ density is beaten on I_z and at 30–60° at once by some α.",
        "",
        "| quantity | " + " | ".join(label for label, _, _ in SHAPES) + " |",
        "| --- |" + " ---: |" * len(SHAPES),
        *(f"| {name} | " + " | ".join(f"{v:.3f}" for v in values) + " |" for name, values in density_shapes()),
        "",
    ]
    for name, r in results.items():
        f = r["floor"]
        lines += [
            f"## {name}: {r['texels']} texels, reference {r['reference']} spp (floor I_z {f[0]:.4f}), "
            f"{r.get('seeds', 1)} seeds per row, "
            f"load {tuple(round(v, 1) for v in r.get('load_average', ()))}",
            "",
            "| variant | spp | I_z | band 0 | band 1 | HHD 30° | HHD 45° | bias |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for row in r["rows"]:
            tilted = row.get("shaded", {})
            lines.append(
                f"| {row['variant']} | {row['samples']} | {row['iz']:.4f} | {row['band0']:.4f} | "
                f"{row['band1']:.4f} | "
                + " | ".join(f"{tilted[k]:.4f}" if k in tilted else "" for k in ("30", "45"))
                + f" | {row['bias']:+.4f} |"
            )
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
