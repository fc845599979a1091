"""The raw SH file's storage measured: float32 vs half, and OpenEXR's compressions (issue 58, part 2).

    .venv/bin/python bench/raw_sh_file.py PATH/Lightmap_sh.exr [--scratch DIR]

Reads a bake's raw SH file (`<atlas>_sh.exr`: 27 channels, the SH as traced, float32), writes
it again with each storage choice (`CHOICES`: pixel type × compression) through the OpenEXR
binding's whole-image writer on every core (`exr.set_threads`), reads it back, and records the
file's size, the write and read seconds, and the largest error against the float32 values
(relative to each texel's |L0| luminance scale, over the texels with any non-zero value).
What a re-encode needs: the SH exactly as traced (a re-encode gives the files of the bake only
from float32 values: half rounds each coefficient to 11 bits). Writes
bench/results/raw_sh_file.md and .json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

#: (label, pixel type, OpenEXR compression name); lossless unless marked.
CHOICES = [
    ("float32, none", "FLOAT", "NO_COMPRESSION"),
    ("float32, RLE", "FLOAT", "RLE_COMPRESSION"),
    ("float32, ZIPS (1 line)", "FLOAT", "ZIPS_COMPRESSION"),
    ("float32, ZIP (16 lines; the bake's)", "FLOAT", "ZIP_COMPRESSION"),
    ("float32, PIZ", "FLOAT", "PIZ_COMPRESSION"),
    ("float32 → 24 bit, PXR24 (lossy)", "FLOAT", "PXR24_COMPRESSION"),
    ("float32, ZSTD (OpenEXR ≥ 3.4 readers only)", "FLOAT", "ZSTD_COMPRESSION"),
    ("half, ZIP", "HALF", "ZIP_COMPRESSION"),
    ("half, PIZ", "HALF", "PIZ_COMPRESSION"),
]


def measure(channels: dict[str, np.ndarray], scratch: Path, threads: int) -> list[dict]:
    import OpenEXR

    OpenEXR.set_global_thread_count(threads)
    names = list(channels)
    reference = np.stack([channels[n] for n in names], -1)  # (H, W, 27) float32
    scale = np.abs(reference[..., :3]).max(axis=-1)  # per texel: |L0| (largest colour)
    lit = scale > 0.0
    rows = []
    for label, pixel, compression in CHOICES:
        path = scratch / "sh.exr"
        dtype = np.float16 if pixel == "HALF" else np.float32
        data = {n: channels[n].astype(dtype) for n in names}
        header = {"compression": getattr(OpenEXR, compression), "type": OpenEXR.scanlineimage}
        t = time.perf_counter()
        OpenEXR.File(header, data).write(str(path))
        write = time.perf_counter() - t
        del data
        size = os.path.getsize(path)
        t = time.perf_counter()
        back = OpenEXR.File(str(path), separate_channels=True)
        pixels = {n: ch.pixels for n, ch in back.channels().items()}
        read = time.perf_counter() - t
        got = np.stack([pixels[n].astype(np.float32) for n in names], -1)
        del pixels, back
        diff = np.abs(got - reference).max(axis=-1)
        exact = bool(np.array_equal(got.view(np.uint32), reference.view(np.uint32)))
        rel = float((diff[lit] / scale[lit]).max()) if lit.any() else 0.0
        rows.append(
            {
                "choice": label,
                "bytes": size,
                "write_s": round(write, 2),
                "read_s": round(read, 2),
                "bit_exact": exact,
                "max_abs_error": float(diff.max()),
                "max_error_over_L0": rel,
            }
        )
        print(rows[-1], flush=True)
        del got, diff
        path.unlink()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sh_file", type=Path)
    ap.add_argument("--scratch", type=Path, default=Path("/tmp"))
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "raw_sh_file")
    args = ap.parse_args()
    import OpenEXR

    f = OpenEXR.File(str(args.sh_file), separate_channels=True)
    channels = {n: ch.pixels.astype(np.float32, copy=False) for n, ch in f.channels().items()}
    del f
    h, w = next(iter(channels.values())).shape
    args.scratch.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()[0]
    rows = measure(channels, args.scratch, args.threads)
    after = os.getloadavg()[0]
    doc = {
        "file": str(args.sh_file),
        "width": w,
        "height": h,
        "channels": len(channels),
        "threads": args.threads,
        "load": [load, after],
        "rows": rows,
    }
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1))
    lines = [
        "# The raw SH file: pixel type and compression (issue 58, part 2)",
        "",
        f"`python bench/raw_sh_file.py {args.sh_file.name}`: the bedroom's 4096² Production bake's raw SH file "
        f"({w}×{h}, {len(channels)} channels, the SH as traced), written again with each choice by OpenEXR's "
        f"whole-image writer on {args.threads} threads and read back; load average {load:.1f} → {after:.1f} on 2 "
        "cores (other jobs ran beside: the seconds are upper bounds). Error: largest |difference| over the "
        "float32 values, and over each texel's |L0| (its largest colour).",
        "",
        "| choice | MB | write s | read s | bit-exact | max abs error | max error / L0 |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['choice']} | {r['bytes'] / 1e6:.0f} | {r['write_s']:.1f} | {r['read_s']:.1f} | "
            f"{'yes' if r['bit_exact'] else 'no'} | {r['max_abs_error']:.3g} | {r['max_error_over_L0']:.3g} |"
        )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
