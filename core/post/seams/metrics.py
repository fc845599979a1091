"""The seam metric: how visible the seams are, read as the preview reads the lightmap, against
the texel-to-texel step inside the charts (`seam_metric`; `_metric` on a `Reader`). No bpy."""

from __future__ import annotations

from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ... import parallel
from ...colour import LUMINANCE
from ...memory import row_blocks
from .geometry import Seams, _unit
from .reads import Reader, blend, hidden_texels, reader_for, reads_hidden

#: Relative errors divide by max(mean luminance of the two reads, REL_FLOOR × the mean over all
#: samples): near-black samples, whose relative noise nobody can see, do not dominate.
REL_FLOOR = 0.1
#: Normals tilted by this angle (towards ± the edge and ± across it) show directional seams.
TILT = np.radians(30.0)
#: Where the metric reads, texels inward from the seam: the noise floor between reads at
#: INTERIOR (one texel apart, clear of the border texels stitching moves), the step next to the
#: border between reads at EDGE_STEP.
INTERIOR = (1.5, 2.5)
EDGE_STEP = (0.5, 1.5)
#: Seam samples a worker reads at once (`_luminances`; memory: a read holds each sample's filtered
#: texels, float64, a few times over: ~1 kB a sample).
READ_SAMPLES = 1 << 14
#: Seam samples the stitch stages' records measure at most (`recorded`): their before and after
#: metrics are statistics of the samples (means, a 95th percentile), which an even subset of
#: this size gives to within a few per cent of every sample's (bench/results/seam_metric_subset.md)
#: at a fraction of the reads. `seam_metric` (benches, tests) reads every sample.
RECORD_SAMPLES = 1 << 16


def seam_metric(source, seams: Seams, worst: int = 10, tilt: float = TILT, coverage: np.ndarray | None = None) -> dict:
    """How visible the seams of `source` are (a TexelData, an EncodedAtlas, HHD channel images
    or an SH image: see `reader_for`). With the atlas's `coverage (H, W)` (a TexelData's own
    by default) the hidden samples (`reads_hidden`: one side is inside closed geometry, read
    black) are left out; `hidden` counts them.

    At every seam sample, the irradiance read on side a and on side b at the sample's normal,
    to luminance (Rec.709), relative difference |L_a − L_b| / max(their mean, REL_FLOOR × the
    mean over all samples): `mean` (weighted by the world length of the samples) and `p95`.
    The noise floor `interior` is the same statistic between two reads of one chart one texel
    apart, one texel inside the border (at 1½ and 2½ texels inward, on both sides): the step
    every texel shows its neighbour, which a seam is judged against; `ratio` = mean / interior
    (≤ 1: the seam is no more visible than the texel grid). `edge_step`: the same between ½ and
    1½ texels inward (the border texels, which stitching moves). `worst_edges`: the `worst`
    seam edges by mean error ({"edge", "error", "length" in metres}). `tilted`: mean, p95,
    interior, edge_step and ratio with the normal tilted by `tilt` towards ± the edge and
    ± across it (four reads pooled): a mismatch of the directional part shows there.
    Samples whose reads are not finite are left out (`invalid` counts them)."""
    from ...encoding import TexelData

    if coverage is None and isinstance(source, TexelData):
        coverage = source.coverage
    hidden = np.zeros(len(seams), bool) if coverage is None else reads_hidden(seams, hidden_texels(coverage))
    return {**_metric(reader_for(source), seams.select(~hidden), worst, tilt), "hidden": int(hidden.sum())}


def _metric(read: Reader, seams: Seams, worst: int = 10, tilt: float = TILT) -> dict:
    keys = ("mean", "p95", "interior", "interior_p95", "edge_step", "ratio")
    if len(seams) == 0:
        empty = dict.fromkeys(keys, 0.0)
        return {**empty, "samples": 0, "edges": 0, "invalid": 0, "worst_edges": [], "tilted": dict(empty)}
    n = seams.normal
    t = _unit(seams.tangent - np.einsum("si,si->s", seams.tangent, n)[:, None] * n)
    across = _unit(np.cross(n, t))
    tilted = [_unit(np.cos(tilt) * n + sign * np.sin(tilt) * v) for v in (t, across) for sign in (1.0, -1.0)]
    lum = _luminances(read, seams, [n, *tilted])
    seam_err, seam_w, inner, edge, valid = _errors(lum.pop(0), seams)
    out: dict = {"samples": len(seams), "edges": seams.edges, "invalid": int(np.count_nonzero(~valid))}
    out.update(_summary(seam_err, seam_w, inner, edge))
    out["worst_edges"] = _worst_edges(seams, seam_err, seam_w, valid, worst)
    del seam_err, seam_w, inner, edge
    # the tilted normals' errors pooled: (seam errors, weights, interior's, edge step's) as columns,
    # each normal's luminances dropped once its errors are taken, each column once joined (memory)
    columns: list[list[np.ndarray]] = [[] for _ in range(6)]
    while lum:
        err, w, inner_n, edge_n, _ = _errors(lum.pop(0), seams)
        for column, part in zip(columns, (err, w, *inner_n, *edge_n)):
            column.append(part)
    pooled = [_joined(column) for column in columns]
    out["tilted"] = _summary(pooled[0], pooled[1], (pooled[2], pooled[3]), (pooled[4], pooled[5]))
    return out


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """`np.concatenate(parts)`, emptying the list `parts` (its arrays go once joined: memory)."""
    out = np.concatenate(parts)
    parts.clear()
    return out


def _luminances(read: Reader, seams: Seams, normals: list[np.ndarray]) -> list[dict]:
    """The luminance of the irradiance the metric reads, per shading normal of `normals` (each
    `(S, 3)`; n_v is the seams' normal), by place: 'a', 'b' (the seam) and (side, offset)
    inward: `[{place: (S,)}]`, one dict per normal. The texels the places' bilinear reads take
    are gathered once (`_texels`: places overlap, and a texel's value may cost a look-up, as
    `FilledRows`'), then each place is read from them (`reads.blend`: the values `read(xy)`
    gives) and evaluated at every normal, in blocks of at most READ_SAMPLES samples
    (`memory.row_blocks`: a sample's values are its own, whatever block it is read in); the
    blocks are read on every core (`parallel.resolve_threads`: numpy's gathers let go of the
    GIL), each worker holding one block's filtered texels at a time."""
    places: list[tuple[Any, np.ndarray, float, np.ndarray | None]] = [
        ("a", seams.a, 0.0, None),
        ("b", seams.b, 0.0, None),
    ]
    for side, xy, inward in (("a", seams.a, seams.inward_a), ("b", seams.b, seams.inward_b)):
        for offset in sorted(set(INTERIOR + EDGE_STEP)):
            places.append(((side, offset), xy, offset, inward))
    index, texels = _texels(read, (_points(place, slice(None)) for place in places))
    out: list[dict] = [{key: np.empty(len(seams)) for key, *_ in places} for _ in normals]

    def evaluate(job: tuple[Any, np.ndarray, float, np.ndarray | None, slice]) -> None:
        key, xy, offset, inward, rows = job
        taps, weight = read.taps(_points((key, xy, offset, inward), rows))
        at = read.shade(blend(texels, np.searchsorted(index, taps), weight))
        for lum, n in zip(out, normals):
            lum[key][rows] = at(seams.normal[rows], n[rows]) @ LUMINANCE

    jobs = [(*place, rows) for place in places for rows in row_blocks(len(seams), READ_SAMPLES)]
    with ThreadPoolExecutor(max_workers=min(parallel.resolve_threads(0), len(jobs))) as pool:
        list(pool.map(evaluate, jobs))  # each block written into its rows
    return out


def _points(place: tuple[Any, np.ndarray, float, np.ndarray | None], rows: slice) -> np.ndarray:
    """The points `(R, 2)` (texel units) of a `_luminances` place (key, seam points, offset,
    inward directions or None) at the samples `rows`: the seam's own, or `offset` texels inward
    (per sample: a block's are the whole's rows)."""
    _, xy, offset, inward = place
    return xy[rows] if inward is None else xy[rows] + offset * inward[rows]


def _texels(read: Reader, points: Iterable[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The texels the bilinear reads of `read` at each of `points` (`(S, 2)` each) take: their
    flat indices `(T,)` sorted, unique, and their rows `read.texels[index]` `(T, ...)`."""
    h, w = read.grid
    taken = np.zeros(h * w, bool)
    for xy in points:
        taken[read.taps(xy)[0]] = True
    index = np.flatnonzero(taken)
    del taken
    return index, read.texels[index]


def _errors(lum: dict, seams: Seams):
    """Relative luminance errors from the luminances `lum` at one normal (`_luminances`): across
    the seam (errors, weights), the interior and edge steps ((errors, weights) over both sides),
    and the (S,) mask of finite seam reads."""
    valid = np.isfinite(lum["a"]) & np.isfinite(lum["b"])
    seam_err, seam_w = _relative(lum["a"], lum["b"], seams.weight, valid)
    steps = []
    for near, far in (INTERIOR, EDGE_STEP):
        x = np.concatenate([lum["a", near], lum["b", near]])
        y = np.concatenate([lum["a", far], lum["b", far]])
        steps.append(_relative(x, y, np.concatenate([seams.weight, seams.weight]), np.isfinite(x) & np.isfinite(y)))
    return seam_err, seam_w, steps[0], steps[1], valid


def _relative(x: np.ndarray, y: np.ndarray, weight: np.ndarray, valid: np.ndarray):
    """|x − y| / max(½|x + y|, REL_FLOOR × weighted mean of ½|x + y|) over the `valid` rows, and their weights."""
    x, y, w = x[valid], y[valid], weight[valid]
    level = np.abs(0.5 * (x + y))
    mean = _weighted_mean(level, w)
    denominator = np.maximum(level, REL_FLOOR * mean)
    err = np.abs(x - y) / np.where(denominator > 0.0, denominator, 1.0)
    return err, w


def _summary(seam_err, seam_w, inner: tuple, edge: tuple) -> dict:
    mean = _weighted_mean(seam_err, seam_w)
    interior = _weighted_mean(inner[0], inner[1])
    return {
        "mean": mean,
        "p95": _weighted_quantile(seam_err, seam_w, 0.95),
        "interior": interior,
        "interior_p95": _weighted_quantile(inner[0], inner[1], 0.95),
        "edge_step": _weighted_mean(edge[0], edge[1]),
        "ratio": mean / interior if interior > 0.0 else (0.0 if mean == 0.0 else float("inf")),
    }


def _worst_edges(seams: Seams, err: np.ndarray, w: np.ndarray, valid: np.ndarray, worst: int) -> list[dict]:
    e = seams.edge[valid]
    total = np.bincount(e, weights=w, minlength=seams.edges)
    mean = np.bincount(e, weights=err * w, minlength=seams.edges) / np.where(total > 0, total, 1.0)
    length = np.bincount(seams.edge, weights=seams.weight, minlength=seams.edges)
    top = np.argsort(-mean, kind="stable")[:worst]
    return [{"edge": int(k), "error": float(mean[k]), "length": float(length[k])} for k in top]


def _weighted_mean(x: np.ndarray, w: np.ndarray) -> float:
    total = float(w.sum())
    return float((x * w).sum() / total) if total > 0 else 0.0


def _weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    if len(x) == 0 or w.sum() <= 0:
        return 0.0
    order = np.argsort(x, kind="stable")
    cum = np.cumsum(w[order])
    return float(x[order][min(int(np.searchsorted(cum, q * cum[-1])), len(x) - 1)])


def recorded(seams: Seams, limit: int | None = None) -> Seams:
    """The samples a stitch stage's record measures: all of `seams` up to `limit` of them
    (default RECORD_SAMPLES), else `limit` spread evenly over them (sample i · S // limit: the
    samples run edge by edge, so every part of the atlas keeps its share)."""
    limit = RECORD_SAMPLES if limit is None else limit
    count = len(seams)
    if count <= limit:
        return seams
    keep = np.zeros(count, bool)
    keep[np.arange(limit, dtype=np.int64) * count // limit] = True
    return seams.select(keep)


def _brief(metric: dict) -> dict:
    """A stitch record's summary of a `_metric`: its statistics (of `samples` seam samples read)."""
    keys = ("mean", "p95", "interior", "edge_step", "ratio")
    return {
        **{k: metric[k] for k in keys},
        "samples": metric["samples"],
        "tilted": {k: metric["tilted"][k] for k in keys},
    }
