"""Which HDR packing of I_z goes into the glTF export's PNGs (docs/gltf.md): measured.

    .venv/bin/python bench/gltf_packing.py DIR[:LABEL] ... [--out bench/results/gltf_packing.md]

DIR is a bake's output folder (its `<atlas>_hhd.exr` and `<atlas>_texels.exr`). For every atlas
and every packing of `core.encoding.web_packing` (range = the atlas's largest I_z, as the
exporter sets it), I_z is packed, written as PNG (the exporter's writer), read back and decoded,
and compared per baked texel (Coverage > 0) with the float EXR: the relative error
max_c |decoded − exr| / max(luminance(exr), FLOOR × mean luminance) (the floor keeps black
contact shadows from dominating), its median, p95 and p99, and the PNG's bytes per texel (all
texels of the atlas, gutters included). The direction texture's angular error (8-bit octahedral)
is reported too.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from hhd_lightmapper.core.encoding import web_packing as wp  # noqa: E402
from hhd_lightmapper.core.files import exr  # noqa: E402

FLOOR = 0.01
LUM = np.array([0.2126, 0.7152, 0.0722])


def measure(folder: Path, label: str) -> list[dict]:
    rows = []
    for sidecar in sorted(folder.glob("*.json")):
        doc = json.loads(sidecar.read_text())
        if doc.get("format") != "hhd-lightmap" or "light_set" in doc:
            continue
        name = doc["atlas"]
        ch, _ = exr.read(folder / f"{name}_hhd.exr")
        tx, _ = exr.read(folder / f"{name}_texels.exr")
        iz = np.stack([ch[f"Iz.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
        baked = tx["Coverage.V"] > 0
        ref = iz[baked]
        lum = ref @ LUM
        denom = np.maximum(lum, FLOOR * lum.mean())
        range_ = float(iz.max())
        for packing in wp.PACKINGS:
            packed = wp.encode(iz, packing, range_)
            blob = wp.png_encode(packed)
            back = wp.png_decode(blob)
            assert np.array_equal(back, packed), packing
            dec = wp.decode(back, packing, range_)[baked]
            err = np.abs(dec - ref).max(axis=1) / denom
            rows.append(
                {
                    "scene": label,
                    "atlas": name,
                    "texels": int(baked.sum()),
                    "packing": packing,
                    "median": float(np.median(err)),
                    "p95": float(np.percentile(err, 95)),
                    "p99": float(np.percentile(err, 99)),
                    "max": float(err.max()),
                    "bytes_per_texel": len(blob) / iz[..., 0].size,
                    "range": range_,
                }
            )
        d_exr = np.stack([ch["Direction.X"], ch["Direction.Y"]], axis=-1).astype(np.float64)
        from hhd_lightmapper.core import octahedral

        d = octahedral.decode(d_exr.reshape(-1, 2)).reshape(iz.shape)
        d8, _ = wp.decode_direction(wp.encode_direction(d, None))
        ang = np.degrees(np.arccos(np.clip((d8 * d).sum(-1)[baked], -1, 1)))
        rows.append(
            {
                "scene": label,
                "atlas": name,
                "texels": int(baked.sum()),
                "packing": "direction oct8",
                "median_deg": float(np.median(ang)),
                "p95_deg": float(np.percentile(ang, 95)),
                "max_deg": float(ang.max()),
            }
        )
    return rows


def table(rows: list[dict]) -> str:
    out = [
        "| scene | atlas | baked texels | packing | median | p95 | p99 | max | PNG bytes/texel |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "median" in r:
            out.append(
                f"| {r['scene']} | {r['atlas']} | {r['texels']} | {r['packing']} | {100 * r['median']:.3f}% | "
                f"{100 * r['p95']:.3f}% | {100 * r['p99']:.3f}% | {100 * r['max']:.2f}% | {r['bytes_per_texel']:.2f} |"
            )
    out += ["", "| scene | atlas | direction, 8-bit octahedral | median | p95 | max |", "|---|---|---|---|---|---|"]
    for r in rows:
        if "median_deg" in r:
            out.append(
                f"| {r['scene']} | {r['atlas']} | RG of the direction PNG | {r['median_deg']:.3f}° | "
                f"{r['p95_deg']:.3f}° | {r['max_deg']:.3f}° |"
            )
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "gltf_packing.md")
    args = ap.parse_args()
    rows = []
    for item in args.folders:
        folder, _, label = item.partition(":")
        rows += measure(Path(folder), label or Path(folder).name)
    text = (
        "# I_z packings for the glTF export (bench/gltf_packing.py)\n\n"
        f"Relative error per baked texel: max over RGB of |decoded − EXR| / max(luminance, {FLOOR} × mean "
        "luminance); range = the atlas's largest I_z. rgb16 is a 16-bit PNG (browsers load PNGs as 8 bits: "
        f"listed for comparison only). The export writes **{wp.CHOSEN}**.\n\n" + table(rows) + "\n"
    )
    args.out.write_text(text)
    (args.out.with_suffix(".json")).write_text(json.dumps(rows, indent=1) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
