"""Compiled (numba) kernels of the texel estimator (`tracer.hemisphere`): directions over a texel's
hemisphere, origins hidden from the bake point replaced, radiance projected to SH. No bpy.

What happens per sample between two Embree queries is written here as loops over samples and
compiled, one pass over memory instead of a dozen numpy temporaries. Conventions: directions
world space, unit; SH basis and frames as `core.sh` (`sh_basis` is `sh.basis` compiled, the
function `sh.evaluate` uses). Nothing compiles until `get()` (`core.compiled`).
"""

from __future__ import annotations

import math

import numpy as np

from .. import compiled, sampling, sh
from ..sampling import local_to_world, mixture_cos, sobol_pair, stream_key, uniform

_Y00 = sh.Y00
_C1 = sh.C1
_INV_PI = 1.0 / math.pi
_TWO_PI = 2.0 * math.pi

#: The 9 real SH basis values at direction (x, y, z), as a tuple (not array arguments: a view
#: per call costs more than the arithmetic); `get()` rebinds it to its compiled version.
sh_basis = sh.basis


#: The first stream number of `texel_hemisphere_rays`' two halves (`stream_key`), apart from
#: the dimensions `texel_sequence` draws for lights.
_DIRECTION_STREAMS = 64


def texel_hemisphere_rays(normals, k, texels, first, seed, uniform_share):
    """k directions per texel over the hemisphere of its unit normal (normals (n, 3)) drawn
    from the mixture p(ω) = α/(2π) + (1 − α)·cosθ/π (α = uniform_share) by inverting its
    cumulative distribution in cosθ (`mixture_cos`), in two independent halves of k/2 (the
    control variate's, `project_halves`). Each half's (u1, u2) come from its texel's own
    (0,2)-sequence (`sobol_pair`; one per (seed, texel id, half))
    at indices first/2 .. first/2 + k/2 − 1: `first` is the pass's first sample (pass × k),
    so a texel's samples are stratified across all its passes, not only within each.
    texels (n,): the texels' global ids. Returns directions (n·k, 3) and the density per
    steradian (n·k,)."""
    n = normals.shape[0]
    half = k // 2
    start = first // 2
    dirs = np.empty((n * k, 3))
    pdf = np.empty(n * k)
    for t in range(n):
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        for h in range(2):
            key = stream_key(seed, texels[t], _DIRECTION_STREAMS + h)
            for i in range(half):
                s = t * k + h * half + i
                u1, u2 = sobol_pair(start + i, key)
                z = mixture_cos(u1, uniform_share)
                r = math.sqrt(max(1.0 - z * z, 0.0))
                phi = _TWO_PI * u2
                dirs[s, 0], dirs[s, 1], dirs[s, 2] = local_to_world(nx, ny, nz, r * math.cos(phi), r * math.sin(phi), z)
                pdf[s] = uniform_share * 0.5 * _INV_PI + (1.0 - uniform_share) * z * _INV_PI
    return dirs, pdf


def replace_hidden(hidden, k, seed):
    """For k samples per texel (hidden (n·k,) bool, True where a sample's origin is hidden from
    its texel's anchor): the sample each one takes its origin from (n·k,) int, itself when
    visible, else a visible sample of the same texel drawn uniformly (the hidden part of the
    footprint is dropped and the visible part keeps uniform density), -1 when none is visible
    (the caller then uses the anchor)."""
    state = np.uint64(seed)
    n = hidden.shape[0] // k
    out = np.empty(n * k, np.int64)
    visible = np.empty(k, np.int64)
    for t in range(n):
        m = 0
        for j in range(k):
            if not hidden[t * k + j]:
                visible[m] = t * k + j
                m += 1
        for j in range(k):
            s = t * k + j
            if not hidden[s]:
                out[s] = s
            elif m == 0:
                out[s] = -1
            else:
                state, u = uniform(state)
                out[s] = visible[min(int(u * m), m - 1)]
    return out


def project_halves(dirs, radiance, pdf, normals, k):
    """Radiance SH (n, 9, C) of each texel's k samples (directions (n·k, 3), radiance (n·k, C):
    C = 3 per light set, pdf (n·k,)), in two independent halves of k/2 (`texel_hemisphere_rays`),
    with a constant (per column) as control variate.

    Plain estimate: Σ L Y / (k p) over all k samples (every coefficient, I_z's included, uses
    every sample). Each half subtracts a constant β and adds back its exact integral β·∫Y over
    the hemisphere of the texel's normal (normals (n, 3); ∫Y: band 0 2π·Y00, band 1 π·C1·n,
    band 2 zero, its basis functions being traceless quadratic forms and ∫ ωωᵀ dω = (2π/3)·I
    over a hemisphere), with β the mean radiance of the *other* half: independent of this
    half's samples, so the estimate stays unbiased, and constant radiance is reproduced exactly
    (the furnace test) while near-constant skies lose most of the pdf-shape noise."""
    n = normals.shape[0]
    half = k // 2
    cols = radiance.shape[1]
    out = np.zeros((n, 9, cols))
    beta = np.empty((2, cols))
    band0 = _TWO_PI * _Y00
    band1 = _C1 * math.pi
    for t in range(n):
        base = t * k
        for c in range(cols):
            sa = 0.0
            sb = 0.0
            for i in range(half):
                sa += radiance[base + half + i, c]  # half B: β for half A
                sb += radiance[base + i, c]  # half A: β for half B
            beta[0, c] = sa / half
            beta[1, c] = sb / half
        for j in range(k):
            s = base + j
            h = 0 if j < half else 1
            w = 1.0 / (pdf[s] * k)
            y = sh_basis(dirs[s, 0], dirs[s, 1], dirs[s, 2])
            for c in range(cols):
                v = (radiance[s, c] - beta[h, c]) * w
                for m in range(9):
                    out[t, m, c] += y[m] * v
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        for c in range(cols):
            b = 0.5 * (beta[0, c] + beta[1, c])
            out[t, 0, c] += band0 * b
            out[t, 1, c] += -band1 * ny * b
            out[t, 2, c] += band1 * nz * b
            out[t, 3, c] += -band1 * nx * b
    return out


def accumulate_grouped(dirs, values, weights, k, out):
    """out[t] += Σ_{s<k} weights[s'] values[s'] Y(dirs[s']), s' = t·k + s: dirs (n·k, 3), values
    (n·k, 3), weights (n·k,), out (n, 9, 3) (in place); dirs and values may be broadcast rows
    (stride 0: a sun's direction and irradiance). Samples of weight 0 cost nothing."""
    for s in range(dirs.shape[0]):
        w = weights[s]
        if w == 0.0:
            continue
        v0, v1, v2 = values[s, 0] * w, values[s, 1] * w, values[s, 2] * w
        y = sh_basis(dirs[s, 0], dirs[s, 1], dirs[s, 2])
        t = s // k
        for m in range(9):
            out[t, m, 0] += y[m] * v0
            out[t, m, 1] += y[m] * v1
            out[t, m, 2] += y[m] * v2


KERNELS = compiled.KernelSet(
    __name__,
    kernels=("texel_hemisphere_rays", "replace_hidden", "project_halves", "accumulate_grouped"),
    helpers=("sh_basis",),
    uses=(sampling.KERNELS,),
)
get = KERNELS.get
