"""Encoder benchmark: reconstruction error and throughput of every encoder variant.

    python bench/encoder.py [--texels 2000] [--throughput 1000000]

Prints three tables and writes bench/results/encoder.json and bench/results/encoder_error.png:
  1. hemispherical RMSE (relative to the mean I_z, %) per environment and variant, over random
     vertex normals, with hemisphere-sampled SH as a bake produces it;
  2. how close the golden-section search gets to a brute-force θ scan (same φ), and what the
     d·n_v floor costs;
  3. encode throughput (texels/s, one core) per variant.
Run by hand; numbers depend on the machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: numpy's BLAS stays single-threaded
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from hhd_lightmapper.core import hhd, sh  # noqa: E402
from scenekit import synthetic  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

VARIANTS = {
    "OL + sphere G (baseline)": dict(direction="optimal_linear", gram="sphere"),
    "OL + hemi G": dict(direction="optimal_linear"),
    "searched + sphere G": dict(gram="sphere"),
    "searched + hemi G (default)": dict(),
    "searched + hemi G + phi": dict(phi_search=True),
    "AHD searched + hemi G": dict(model="ahd"),
    "AHD OL + sphere G": dict(model="ahd", direction="optimal_linear", gram="sphere"),
    "RGB w_a, searched + hemi G": dict(ambient="rgb"),
}


def error_table(n_texels: int, rng: np.random.Generator) -> dict:
    normals = synthetic.random_normals(rng, n_texels)
    table = {}
    for env in synthetic.benchmark_set():
        s = synthetic.hemisphere_sh(env, normals)
        row = {}
        for name, kw in VARIANTS.items():
            p = hhd.encode(s, normals, **kw)
            rmse = hhd.hemispherical_rmse(s, normals, p)
            row[name] = float(100.0 * (rmse @ hhd.LUMINANCE).mean() / (p.irradz @ hhd.LUMINANCE).mean())
        table[env.name] = row
    return table


def search_accuracy(n_texels: int, rng: np.random.Generator) -> dict:
    """Objective of the golden-section result vs a 2001-point θ scan at the same φ, and the
    floor's cost vs letting θ reach 89.99°."""
    normals = synthetic.random_normals(rng, n_texels)
    out = {}
    for env in synthetic.benchmark_set():
        s = synthetic.hemisphere_sh(env, normals)
        p = hhd.encode(s, normals)
        e_search, _ = hhd.fit_error(s, normals, p.direction)
        frames = sh.tangent_frames(normals)
        d_local = np.einsum("nji,nj->ni", frames, p.direction)
        phi = np.arctan2(d_local[:, 1], d_local[:, 0])
        best = np.full(len(normals), np.inf)
        best_any = np.full(len(normals), np.inf)
        for theta in np.linspace(0.0, np.radians(89.99), 2001):
            loc = np.stack(
                [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.full_like(phi, np.cos(theta))], 1
            )
            e, _ = hhd.fit_error(s, normals, np.einsum("nij,nj->ni", frames, loc))
            best_any = np.minimum(best_any, e)
            if np.cos(theta) >= hhd.MIN_COS:
                best = np.minimum(best, e)
        out[env.name] = {
            "search excess over brute force (mean, %)": float(
                100 * np.mean((e_search - best) / np.maximum(best, 1e-30))
            ),
            "search excess over brute force (max, %)": float(100 * np.max((e_search - best) / np.maximum(best, 1e-30))),
            # relative to the total objective: per-texel ratios blow up where the optimum is ~0
            "floor cost (total objective increase, %)": float(100 * (best - best_any).sum() / best_any.sum()),
        }
    return out


def throughput(n_texels: int, rng: np.random.Generator) -> dict:
    normals = synthetic.random_normals(rng, 4096)
    base = synthetic.hemisphere_sh(synthetic.interior(), normals)
    idx = rng.integers(0, len(normals), n_texels)
    s = (base[idx] * rng.uniform(0.5, 2.0, (n_texels, 1, 1))).astype(np.float32)
    n = normals[idx].astype(np.float32)
    out = {}
    for name, kw in VARIANTS.items():
        count = n_texels // 20 if kw.get("phi_search") else n_texels
        t0 = time.perf_counter()
        hhd.encode(s[:count], n[:count], **kw)
        out[name] = count / (time.perf_counter() - t0)
    return out


def print_table(title, rows: dict, fmt="{:9.2f}"):
    cols = list(next(iter(rows.values())).keys())
    print(f"\n{title}")
    width = max(len(r) for r in rows) + 2
    for c in cols:
        print(f"  {c}")
    print(" " * width + "".join(f"{i:>10d}" for i in range(len(cols))))
    for r, vals in rows.items():
        print(f"{r:<{width}}" + "".join(f" {fmt.format(vals[c])}" for c in cols))


def plot(table: dict, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = list(table)
    variants = list(next(iter(table.values())))
    fig, ax = plt.subplots(figsize=(12, 5))
    width = 0.8 / len(variants)
    for i, v in enumerate(variants):
        ax.bar(np.arange(len(envs)) + i * width, [table[e][v] for e in envs], width, label=v)
    ax.set_xticks(np.arange(len(envs)) + 0.4 - width / 2)
    ax.set_xticklabels(envs, rotation=20, ha="right")
    ax.set_ylabel("hemispherical RMSE / mean I_z (%)")
    ax.set_title("HHD/AHD encoder error vs SH irradiance (luminance)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--texels", type=int, default=2000)
    ap.add_argument("--throughput", type=int, default=1_000_000)
    args = ap.parse_args()
    rng = np.random.default_rng(2024)
    RESULTS.mkdir(exist_ok=True)

    table = error_table(args.texels, rng)
    print_table("Hemispherical RMSE, % of mean I_z (columns = variants listed above)", table)
    search = search_accuracy(min(args.texels, 500), rng)
    print_table("Search accuracy and floor cost", search, "{:9.4f}")
    rate = throughput(args.throughput, rng)
    print(f"\nEncode throughput, one core, {args.throughput} texels (phi search on 1/20 of them)")
    for name, r in rate.items():
        print(f"  {name:<32s} {r / 1e6:6.3f} M texels/s   ({args.throughput / r:6.2f} s per {args.throughput} texels)")

    (RESULTS / "encoder.json").write_text(
        json.dumps(
            {
                "error_percent": table,
                "search": search,
                "texels_per_second": rate,
                "texels": args.texels,
                "min_cos": hhd.MIN_COS,
            },
            indent=2,
        )
    )
    plot(table, RESULTS / "encoder_error.png")
    print(f"\nwrote {RESULTS / 'encoder.json'} and {RESULTS / 'encoder_error.png'}")


if __name__ == "__main__":
    main()
