"""The stitch post stage on the SH (`stitch`): least squares over the texels the seam samples
read (`solve`), the result bounded to a plausible radiance (`_bounded`). No bpy."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ... import parallel
from ...memory import row_blocks, trim_heap
from ...progress import ticker
from .geometry import Seams, _unit
from .metrics import _brief, _metric, recorded
from .reads import FilledRows, reads_hidden, sh_reader
from .solve import SYSTEM_ROWS, _groups, _solve, _System, _system

if TYPE_CHECKING:
    from ...encoding import TexelData

#: The stitched SH's bound (`_bounded`) reaches this fraction of the tied texels' spread beyond
#: them on either side: a gutter texel half a texel past the chart's edge extends a gradient.
BOUND_SLACK = 0.5
#: A stitched texel's I_z that rounding takes below 0 is lifted to this fraction of the size of
#: its L0 and band 1 (`_bounded`): far above float32 rounding, so it is ≥ 0 as stored.
IZ_MARGIN = 1e-4
#: Unknowns `_bounded` works on at once (memory: ~1.5 kB each, float64, a few times over).
BOUND_ROWS = 1 << 15


def stitch(data: TexelData, seams: Seams, check=None, threads: int = 0) -> tuple[TexelData, dict]:
    """Least-squares seam stitching of `data`'s SH (the post stage's body; `check()` raises to
    cancel, called between solver iterations; `threads`: workers of the solver, 0 = every core,
    `parallel.resolve_threads`; the result does not depend on it). `data` is this stage's
    (`core.memory`): the stitched texels are written into `data.sh` and `data.normal`
    themselves (no copy of the atlas's SH), only after everything else is done (a cancelled
    stitch leaves them as they were).

    Unknowns: the texels the seam samples read, each starting from the value the SH file shows
    there (a gutter texel its dilated SH, a buried texel the SH it takes from its own chart).
    Left out: hidden samples (`reads_hidden`: a side inside closed geometry, left black) and
    samples reading a texel whose SH is not finite (so NaN does not spread). Equations: per
    sample, the bilinear SH read on side a equals that on side b (weight SEAM_WEIGHT × span),
    and per unknown texel its value equals its starting value (COVERED_WEIGHT for a covered
    texel, GUTTER_WEIGHT for a gutter or buried one: an invalid texel's value is a copy). All
    27 SH channels are solved at once (one matrix, 27 right-hand sides): Jacobi-preconditioned
    conjugate gradients on the normal equations. The solution is then bounded (`_bounded`):
    each texel's L0 and I_z at its normal stay in the range of the covered texels it is tied to
    and ≥ 0.

    Returns new TexelData: the SH of the unknown texels replaced; the gutter and buried texels
    among them are listed in `extra_sources` (the gutter ones with the dilated normal), so the
    encoder encodes them (and dilates from them) rather than overwriting them; coverage is
    unchanged. And the sidecar record: enabled, seams (samples), edges, texels (changed),
    groups (groups of texels tied together by seams, solved together), iterations,
    samples_dropped (not finite), samples_hidden, texels_bounded, seconds, and the SH-read
    `seam_metric` before and after, hidden samples left out (mean, p95, interior, edge_step,
    ratio; `tilted` likewise)."""
    start = time.perf_counter()
    tick = ticker(check)
    h, w = data.coverage.shape
    if (seams.height, seams.width) != tuple(data.atlas_shape):
        raise ValueError(f"seams of a {seams.width}×{seams.height} atlas, texel images of {w}×{h}")
    atlas_seams, seams = seams, seams.within(data.window)  # on the images (a window: `TexelData.window`)
    if len(seams) == 0:  # nothing to stitch: the same TexelData and record, without the image copies
        empty = {"seams": 0, "edges": 0, "texels": 0, "groups": 0, "iterations": 0}
        record0: dict[str, Any] = {"enabled": True, **empty, "samples_dropped": 0, "samples_hidden": 0}
        return data, {**record0, "texels_bounded": 0, "seconds": time.perf_counter() - start}
    fill = data.fill()
    coverage = data.coverage.reshape(-1)
    # the SH and n_v as the SH file holds them (filled), read only where stitching reads (memory)
    prior = FilledRows(data.sh.reshape(h * w, -1), fill, (h, w), keep_black=True)
    filled_normal = FilledRows(data.normal.reshape(h * w, 3), fill, (h, w))
    hidden = np.zeros(h * w, bool)
    hidden[fill.black] = True
    shown = ~reads_hidden(seams, hidden)
    del hidden
    setup, solving, rest = tick.split([0.15, 0.7, 0.15])
    setup.at(0.0, f"setting up {len(seams)} seam samples")
    system = _system(seams, coverage, prior, shown)
    trim_heap()  # the set-up's temporaries, before the solver's threads allocate (memory)
    delta, iterations = _solve(system, prior, solving, parallel.resolve_threads(threads))
    rest.at(0.0, "bounding the stitched texels")
    texels = system.texels
    outside = coverage[texels] == 0.0
    normal = np.where(outside[:, None], filled_normal[texels], data.normal.reshape(h * w, 3)[texels])
    new, bounded = _bounded(system, prior, delta, normal, data.sh.dtype)
    del delta
    sh = data.sh.reshape(h * w, -1)
    changed = int(np.count_nonzero((new != sh[texels]).any(axis=1)))
    extra = np.zeros(h * w, bool) if data.extra_sources is None else data.extra_sources.reshape(-1).copy()
    extra[texels[coverage[texels] <= 0.0]] = True
    record: dict[str, Any] = {
        "enabled": True,
        "seams": len(seams),
        "edges": seams.edges,
        "texels": changed,
        "groups": _groups(system),
        "iterations": iterations,
        "samples_dropped": system.dropped,
        "samples_hidden": int(np.count_nonzero(~shown)),
        "texels_bounded": bounded,
    }
    del system
    trim_heap()  # the system and what the solver's threads freed, before the metric's reads (memory)
    # As the SH file will read (the stitched texels are sources; no other texel the metric
    # reads changes, up to gutter texels of thin charts whose nearest source moved).
    visible = recorded(atlas_seams.select(shown))
    image = FilledRows(data.sh.reshape(h * w, 9, -1), fill, (h, w), keep_black=True)
    read = sh_reader(image).placed(data.window)
    rest.at(0.3, "measuring the seams")
    record["before"] = _brief(_metric(read, visible, worst=0))
    image.put(texels, new)  # the stitched SH, as the filled copy would read it
    rest.at(0.65, "measuring the seams")
    record["after"] = _brief(_metric(read, visible, worst=0))
    normals = data.normal.reshape(h * w, 3)
    gutter = outside.nonzero()[0]
    normals[texels[gutter]] = normal[gutter]
    sh[texels] = new
    out = replace(
        data, sh=sh.reshape(data.sh.shape), normal=normals.reshape(data.normal.shape), extra_sources=extra.reshape(h, w)
    )
    record["seconds"] = time.perf_counter() - start
    return out, record


def _bounded(s: _System, prior, delta: np.ndarray, normal: np.ndarray, dtype=np.float32) -> tuple[np.ndarray, int]:
    """The stitched SH of the unknowns `(N, 9·C)` in `dtype` (the texels'), kept a plausible
    radiance, and how many texels it held back. `prior (H·W, 9·C)` the starting SH (an array or
    `FilledRows`), `delta (N, 9·C)` the solve's change, `normal (N, 3)` each unknown's n_v.

    The least squares has no bound: a gutter texel a seam read takes with a small weight can be
    driven to whatever closes the seam, negative or far brighter than anything around it. So
    per texel and colour channel the change is scaled back (x0 + t·δ, t in [0, 1], the largest
    allowed) until its L0 (radiance, SH band 0) and I_z (irradiance at its n_v, `hhd.irradz`;
    both linear in the SH) lie in [max(lo − m, 0), hi + m]: lo, hi the smallest and largest
    starting value among the texels the samples tying it read (itself included: baked values,
    or for gutter and buried texels copies of baked ones), m = BOUND_SLACK × (hi − lo).
    Scaling the whole change back keeps the SH a blend of two consistent ones (clamping L0
    and I_z on their own leaves bands 2 moved without them: it opens the seams far more). An
    I_z that rounding to `dtype` takes below 0 (or a starting one below 0, which t = 0 cannot
    mend) is lifted to IZ_MARGIN × (|L0| + |band 1|) by the smallest change of the SH that
    does (band 1 along its gradient), so it is ≥ 0 as stored. Each texel's values are its own but for the range of the
    texels it is tied to: worked out BOUND_ROWS texels at a time (memory), the same values."""
    n, c = len(s.texels), prior.shape[1] // 9
    if n == 0:
        return np.zeros((0, prior.shape[1]), dtype), 0
    nrm = _unit(np.asarray(normal, np.float64))
    blocks = row_blocks(n, BOUND_ROWS)
    q0 = np.concatenate([_quantities(_start(prior, s.texels[rows], c), nrm[rows]) for rows in blocks])
    lo, hi = _tied_range(s, q0.reshape(n, -1))
    lo, hi = np.minimum(lo.reshape(q0.shape), q0), np.maximum(hi.reshape(q0.shape), q0)
    slack = BOUND_SLACK * (hi - lo)
    lo = np.maximum(lo - slack, 0.0)
    hi = np.maximum(hi + slack, lo)
    out, held = np.empty((n, prior.shape[1]), dtype), 0
    for rows in blocks:
        x0, step = _start(prior, s.texels[rows], c), delta[rows].reshape(-1, 9, c)
        out[rows], k = _bounded_rows(x0, step, nrm[rows], q0[rows], lo[rows], hi[rows], dtype)
        held += k
    return out, held


def _start(prior, texels: np.ndarray, c: int) -> np.ndarray:
    """The starting SH `(n, 9, C)` float64 of `texels` in `prior` (an array or `FilledRows`)."""
    return prior[texels].astype(np.float64).reshape(len(texels), 9, c)


def _quantities(x: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """`(n, 2, C)`: L0 and I_z at the unit normals `nrm (n, 3)` per colour channel of SH `x (n, 9, C)`."""
    from ...hhd import irradz

    return np.stack([x[:, 0], irradz(x, nrm)], 1)


def _bounded_rows(x0, step, nrm, q0, lo, hi, dtype) -> tuple[np.ndarray, int]:
    """`_bounded` of some texels: starting SH `x0 (n, 9, C)`, its change `step`, unit normals
    `nrm (n, 3)`, starting quantities `q0 (n, 2, C)` (`_quantities`) and their allowed range
    [lo, hi]; the bounded SH `(n, 9·C)` in `dtype` and how many texels it held back."""
    from ...hhd import irradz

    n = len(x0)
    q1 = _quantities(x0 + step, nrm)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(q1 > hi, (hi - q0) / (q1 - q0), np.where(q1 < lo, (lo - q0) / (q1 - q0), 1.0))
    t = np.clip(np.nan_to_num(t, nan=0.0), 0.0, 1.0).min(axis=1)  # (n, C)
    x = x0 + t[:, None, :] * step
    x[:, 0] = np.maximum(x[:, 0], 0.0)
    x = x.astype(dtype).astype(np.float64)  # as stored: the lift below sees its rounding
    grad = irradz(np.broadcast_to(np.eye(9), (n, 9, 9)), nrm)  # (n, 9): dI_z / d coefficient
    gg = np.einsum("nk,nk->n", grad, grad)[:, None]
    iz = irradz(x, nrm)  # (n, C)
    scale = x[:, 0] + np.linalg.norm(x[:, 1:4], axis=1)  # (n, C): the size of L0 and band 1
    short = np.where(iz < 0.0, IZ_MARGIN * scale - iz, 0.0)
    x += grad[:, :, None] * np.where(gg > 0.0, short / np.where(gg > 0.0, gg, 1.0), 0.0)[:, None, :]
    held = (t < 1.0).any(axis=1) | (short > 0.0).any(axis=1) | (x0[:, 0] + step[:, 0] < 0.0).any(axis=1)
    return x.reshape(n, -1).astype(dtype), int(np.count_nonzero(held))


def _tied_range(s: _System, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per unknown, the smallest and largest `q (N, K)` (at their starting values) among the
    texels read by the samples that take it, `(N, K)` each."""
    rows = s.taps.shape[1]
    row_lo, row_hi = np.empty((rows, q.shape[1])), np.empty((rows, q.shape[1]))  # (R, K)
    for start in range(0, rows, SYSTEM_ROWS):  # a block of rows at a time (memory: 8 taps × K a row)
        block = slice(start, start + SYSTEM_ROWS)
        live = (s.coeff[:, block] != 0.0)[:, :, None]  # (8, r, 1); fixed taps have coefficient 0
        values = q[s.taps[:, block]]  # (8, r, K)
        row_lo[block] = np.where(live, values, np.inf).min(axis=0)
        row_hi[block] = np.where(live, values, -np.inf).max(axis=0)
    lo, hi = np.full(q.shape, np.inf), np.full(q.shape, -np.inf)
    if len(s.starts):
        lo[s.owner] = np.minimum.reduceat(row_lo[s.entry_row], s.starts, axis=0)
        hi[s.owner] = np.maximum.reduceat(row_hi[s.entry_row], s.starts, axis=0)
    return lo, hi
