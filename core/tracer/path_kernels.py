"""The compiled (numba) wavefront step of `tracer.paths`: what happens to every live path between
two closest-hit queries (`advance_paths`). No bpy. Nothing compiles until `get()`
(`core.compiled`); the sequences are `core.sampling`'s.
"""

from __future__ import annotations

import math

import numpy as np

from .. import compiled, sampling
from ..sampling import local_to_world, uniform

_INV_PI = 1.0 / math.pi
_TWO_PI = 2.0 * math.pi


_NO_NUMBERS = np.zeros((2, 0))  # advance_paths without given numbers


def advance_paths(
    live,
    acc,
    throughput,
    o,
    d,
    t,
    prim,
    ng,
    tri_albedo,
    row_albedo,
    sky,
    radiance,
    offset,
    roulette,
    max_survival,
    survival_power,
    survival_reference,
    seed,
    u_dir=_NO_NUMBERS,
):
    """One wavefront step after a closest-hit query of the rays o + t·d (R, 3), (R,), one row per
    live path: `live` (R,) its sample index, `acc` (R, C) radiance gathered so far (C = 3 per
    light set: RGB of set 0, RGB of set 1, ...), `throughput` (R, 3). A ray that missed (prim < 0)
    adds throughput × `sky` (its row of sky (R, C), or sky[0] for all if sky has one row), its
    path ends and writes acc into `radiance[live]` (R', C) (in place). At a hit: throughput × albedo (`row_albedo` (R, 3) if it has rows, else
    tri_albedo[prim]), the unit normal n facing the ray (surfaces are two-sided; ng (R, 3) is
    Embree's, not unit) and the next origin x = hit + offset·n; then, if `roulette`, the path
    survives with probability p = min((max(throughput) / survival_reference)^survival_power,
    max_survival): a path whose throughput is at least the reference is kept (with max_survival
    1), and a power below 1 ends fewer of the others than their throughput alone. A survivor gets a
    cosine-distributed direction around n (pdf cosθ/π) and the weight 1/p for what follows.
    u_dir (2, R), if it has
    columns: the uniform numbers of each row's new direction (else drawn from `seed`'s stream).

    Returns the hits compacted, survivors first: (live, acc, throughput, x, n, directions, pdf,
    weight, s) with s survivors; directions and pdf are set for survivors only, weight (s,).
    The caller adds this vertex's light for every hit, then ends the rows from s on (roulette
    decided before but applied after the vertex's light: its victims keep that light too)."""
    state = np.uint64(seed)
    r = o.shape[0]
    cols = acc.shape[1]
    per_row_sky = sky.shape[0] == r and r > 1
    per_row_albedo = row_albedo.shape[0] > 0
    tp = np.empty((r, 3))
    survive = np.zeros(r)  # 0: missed; > 0 survives with it; < 0: roulette victim
    survivors = 0
    victims = 0
    for i in range(r):
        if prim[i] < 0:
            s = i if per_row_sky else 0
            for c in range(cols):
                radiance[live[i], c] = acc[i, c] + throughput[i, c % 3] * sky[s, c]
            continue
        for c in range(3):
            albedo = row_albedo[i, c] if per_row_albedo else tri_albedo[prim[i], c]
            tp[i, c] = throughput[i, c] * albedo
        p = 1.0
        if roulette:
            p = min((max(tp[i, 0], tp[i, 1], tp[i, 2]) / survival_reference) ** survival_power, max_survival)
            state, u = uniform(state)
            if u >= p:
                p = -1.0
        survive[i] = p
        if p > 0.0:
            survivors += 1
        else:
            victims += 1
    m = survivors + victims
    out_live = np.empty(m, live.dtype)
    out_acc = np.empty((m, cols))
    out_tp = np.empty((m, 3))
    x = np.empty((m, 3))
    n = np.empty((m, 3))
    nd = np.zeros((m, 3))
    pdf = np.zeros(m)
    weight = np.empty(survivors)
    js, jv = 0, survivors
    for i in range(r):
        if survive[i] == 0.0:
            continue
        if survive[i] > 0.0:
            j = js
            js += 1
        else:
            j = jv
            jv += 1
        out_live[j] = live[i]
        for c in range(cols):
            out_acc[j, c] = acc[i, c]
        for c in range(3):
            out_tp[j, c] = tp[i, c]
        gx, gy, gz = float(ng[i, 0]), float(ng[i, 1]), float(ng[i, 2])
        length = math.sqrt(gx * gx + gy * gy + gz * gz)
        if length == 0.0:  # a degenerate triangle: face the ray
            gx, gy, gz, length = d[i, 0], d[i, 1], d[i, 2], 1.0
        scale = 1.0 / length
        if gx * d[i, 0] + gy * d[i, 1] + gz * d[i, 2] > 0.0:
            scale = -scale
        gx, gy, gz = gx * scale, gy * scale, gz * scale
        n[j, 0], n[j, 1], n[j, 2] = gx, gy, gz
        ti = float(t[i])
        x[j, 0] = o[i, 0] + d[i, 0] * ti + gx * offset
        x[j, 1] = o[i, 1] + d[i, 1] * ti + gy * offset
        x[j, 2] = o[i, 2] + d[i, 2] * ti + gz * offset
        if j >= survivors:
            continue
        weight[j] = 1.0 / survive[i]
        if u_dir.shape[1] > 0:
            u1, u2 = u_dir[0, i], u_dir[1, i]
        else:
            state, u1 = uniform(state)
            state, u2 = uniform(state)
        rr = math.sqrt(u1)
        phi = _TWO_PI * u2
        lz = math.sqrt(max(1.0 - u1, 0.0))
        nd[j, 0], nd[j, 1], nd[j, 2] = local_to_world(gx, gy, gz, rr * math.cos(phi), rr * math.sin(phi), lz)
        pdf[j] = lz * _INV_PI
    return out_live, out_acc, out_tp, x, n, nd, pdf, weight, survivors


KERNELS = compiled.KernelSet(__name__, kernels=("advance_paths",), uses=(sampling.KERNELS,))
get = KERNELS.get
