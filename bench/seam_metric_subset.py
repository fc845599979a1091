"""The stitch records' seam metric on a subset of the samples, against all of them (issue 58).

    .venv/bin/python bench/seam_metric_subset.py FOLDER/ATLAS [FOLDER/ATLAS ...]

A bake's stitch stages record the seam metric before and after (`post.stitch` in the sidecar) on
at most `metrics.RECORD_SAMPLES` seam samples spread evenly (`metrics.recorded`). For each
finished bake given (its `<atlas>_sh.exr`, `_texels.exr`, `_hhd.exr` and `_seams.npz`), this
reads the metric of its raw SH (as traced) and of its HHD file with every visible sample and
with the subset, and with the subsets at other offsets of the same stride (sample
i · S // limit + k: how much the choice of subset moves the figures), timing each. Writes
bench/results/seam_metric_subset.md and .json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"
KEYS = ("mean", "p95", "interior", "edge_step", "ratio")


def _subset(seams, limit: int, offset: int):
    count = len(seams)
    keep = np.zeros(count, bool)
    keep[np.minimum(np.arange(limit, dtype=np.int64) * count // limit + offset, count - 1)] = True
    return seams.select(keep)


def _figures(metric: dict) -> dict:
    return {**{k: metric[k] for k in KEYS}, **{f"tilted {k}": metric["tilted"][k] for k in KEYS}}


def measure(atlas: Path) -> dict:
    from hhd_lightmapper.core.files import exr, lightmap_files
    from hhd_lightmapper.core.post.seams import metrics
    from hhd_lightmapper.core.post.seams.reads import hidden_texels, reader_for, reads_hidden

    files = lightmap_files.AtlasFiles(atlas.parent, atlas.name)
    data = lightmap_files.read_texel_data(files)
    seams = lightmap_files.read_seams(files, data.coverage.shape)
    assert seams is not None, f"{atlas}: no seams file"
    visible = seams.select(~reads_hidden(seams, hidden_texels(data.coverage)))
    channels, _ = exr.read(files.hhd)
    hhd = {name: exr.from_exr_rows(image) for name, image in channels.items()}
    limit = metrics.RECORD_SAMPLES
    stride = max(len(visible) // limit, 1)
    rows = []
    for label, source in (("SH as traced", data), ("HHD file", hhd)):
        read = reader_for(source)
        for name, chosen in [("all", visible)] + [
            (f"subset +{k}", _subset(visible, limit, k)) for k in range(min(stride, 4))
        ]:
            t = time.perf_counter()
            metric = metrics._metric(read, chosen, worst=0)
            rows.append(
                {"read": label, "samples": name, "count": len(chosen), "seconds": time.perf_counter() - t}
                | _figures(metric)
            )
    return {"atlas": str(atlas), "visible_samples": len(visible), "limit": limit, "rows": rows}


def report(runs: list[dict]) -> str:
    lines = [
        "# The stitch records' seam metric on a subset of the samples (issue 58)",
        "",
        "`python bench/seam_metric_subset.py FOLDER/ATLAS`: a finished bake's seam metric (`_metric`, as "
        "the stitch records read it, hidden samples left out) with every visible sample and with "
        "`metrics.recorded`'s even subset (+0: the one a bake records; +k: the same stride shifted by k "
        "samples). Relative change against all samples in brackets.",
        "",
    ]
    for run in runs:
        lines += [f"## {run['atlas']}: {run['visible_samples']} visible samples, limit {run['limit']}", ""]
        lines += ["| read | samples | count | s | " + " | ".join(KEYS) + " | tilted mean | tilted p95 |"]
        lines += ["|" + " --- |" * (6 + len(KEYS))]
        full = {}
        for row in run["rows"]:
            if row["samples"] == "all":
                full = row
            cells = []
            for k in list(KEYS) + ["tilted mean", "tilted p95"]:
                change = "" if row is full or not full[k] else f" ({(row[k] / full[k] - 1) * 100:+.1f}%)"
                cells.append(f"{row[k]:.4f}{change}")
            lines.append(
                f"| {row['read']} | {row['samples']} | {row['count']} | {row['seconds']:.2f} | "
                + " | ".join(cells)
                + " |"
            )
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("atlases", nargs="+", type=Path, help="FOLDER/ATLAS of finished bakes")
    args = parser.parse_args()
    runs = [measure(a) for a in args.atlases]
    (OUT / "seam_metric_subset.json").write_text(json.dumps(runs, indent=1))
    (OUT / "seam_metric_subset.md").write_text(report(runs))
    print(report(runs))


if __name__ == "__main__":
    main()
