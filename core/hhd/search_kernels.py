"""The compiled (numba) θ search of the encoder (`search.search_theta`): per texel, the coarse scan,
the golden-section search in the best bracket and the choice among it, the scan's best and the
starting θ, then the fit's w at the chosen θ. No bpy. Nothing compiles until `get()`
(`core.compiled`).

It computes what the numpy expressions of `fit.FitAtPhi.evaluate`, `lobes.theta_functions` and
`search.golden` compute, operation for operation in their order (the sums of products from 0,
left to right; numpy's clip, maximum and argmin, NaN included), so a texel gets the bits the
vectorised code gives it: one pass over each texel's few numbers instead of some fifty vector
operations over the chunk per evaluation, about 27 evaluations per texel, and no GIL between
them (the encoder's worker threads run side by side).

Arrays (N texels, K fitted channels, P pairs of θ-functions): `hg (6, K, N)`, `ag (6, N)`:
`FitAtPhi`'s products with G t and G a grouped by θ-function; `pair_f (P, 2)` int64 (the two
θ-functions of a pair) and `pair_coef (P, N)`: its dᵀGd terms; `iz`, `gat`, `tgt (N, K)` and
`black (N, K)` bool: `Fit`'s; `weights (K,)`; `grid (S,)`: the scan's θ.
"""

from __future__ import annotations

import math

import numpy as np

from .. import compiled


def search_theta(
    hg,
    ag,
    pair_f,
    pair_coef,
    aga,
    iz,
    gat,
    tgt,
    black,
    weights,
    grid,
    theta_start,
    theta_max,
    iterations,
    inv_phi,
    theta_out,
    err_out,
    w_out,
):
    """`search.search_theta` (module docstring): the chosen θ `theta_out (N,)`, its objective
    `err_out (N,)` and the fit's w there `w_out (N, K)`. BLOCK texels at a time go through each
    step of the search together, each step a loop over the block (as numpy's over the chunk): a
    texel's steps depend on one another, the block's texels do not, so the processor overlaps
    their work (one texel at a time, each evaluation is a single chain of dependent operations)."""
    n_k = iz.shape[1]
    state = np.zeros((9, BLOCK))
    theta, obj, e_best, lo, hi, x1, x2, f1, f2 = state  # per texel of the block
    k_best = np.zeros(BLOCK, np.int64)
    fv = np.zeros((6, BLOCK))  # the six θ-functions of `lobes.theta_functions`
    sums = np.zeros((3, BLOCK))  # aᵀG d, dᵀG d, (a-d)ᵀG(a-d)
    w = np.zeros((n_k, BLOCK))
    step = grid[1] - grid[0]
    for start in range(0, theta_start.shape[0], BLOCK):
        m = min(BLOCK, theta_start.shape[0] - start)
        args = (start, m, theta, hg, ag, pair_f, pair_coef, aga, iz, gat, tgt, black, weights, fv, sums, w, obj)
        for s in range(grid.shape[0]):  # the scan
            theta[:m] = grid[s]
            _evaluate(*args)
            for i in range(m):
                if s == 0 or (obj[i] < e_best[i] or (obj[i] != obj[i] and e_best[i] == e_best[i])):
                    k_best[i], e_best[i] = s, obj[i]
        for i in range(m):  # the golden section in the best bracket
            lo[i] = _clip(grid[k_best[i]] - step, 0.0, theta_max)
            hi[i] = _clip(grid[k_best[i]] + step, 0.0, theta_max)
            x1[i] = hi[i] - inv_phi * (hi[i] - lo[i])
            x2[i] = lo[i] + inv_phi * (hi[i] - lo[i])
        theta[:m] = x1[:m]
        _evaluate(*args)
        f1[:m] = obj[:m]
        theta[:m] = x2[:m]
        _evaluate(*args)
        f2[:m] = obj[:m]
        for _ in range(iterations):
            for i in range(m):
                left = f1[i] < f2[i]  # the minimum in [lo, x2]
                hi[i] = x2[i] if left else hi[i]
                lo[i] = lo[i] if left else x1[i]
                theta[i] = hi[i] - inv_phi * (hi[i] - lo[i]) if left else lo[i] + inv_phi * (hi[i] - lo[i])
            _evaluate(*args)
            for i in range(m):
                left = f1[i] < f2[i]
                x1[i], x2[i], f1[i], f2[i] = (
                    (theta[i], x1[i], obj[i], f1[i]) if left else (x2[i], theta[i], f2[i], obj[i])
                )
        theta[:m] = theta_start[start : start + m]
        _evaluate(*args)
        for i in range(m):  # the best of the search, the scan's best and the start, in that order
            best, err = (x1[i], f1[i]) if f1[i] < f2[i] else (x2[i], f2[i])
            if e_best[i] < err or (e_best[i] != e_best[i] and err == err):
                best, err = grid[k_best[i]], e_best[i]
            if obj[i] < err or (obj[i] != obj[i] and err == err):
                best, err = theta[i], obj[i]
            theta_out[start + i], err_out[start + i] = best, err
            theta[i] = best
        _evaluate(*args)
        for i in range(m):
            for k in range(n_k):
                w_out[start + i, k] = w[k, i]


def _evaluate(start, m, theta, hg, ag, pair_f, pair_coef, aga, iz, gat, tgt, black, weights, fv, sums, w, obj):
    """`FitAtPhi.evaluate` at `theta[i]` of texels start + i, i < m: the objective in `obj[i]`,
    the clamped w of each channel in `w[k, i]` (`fv`, `sums`: scratch)."""
    for i in range(m):  # libm's cos, as numpy's: one texel at a time
        fv[2, i] = math.cos(theta[i])
    for i in range(m):
        ct = fv[2, i]
        s2 = 1.0 - ct * ct
        st = math.sqrt(s2 if (s2 >= 0.0 or s2 != s2) else 0.0)  # numpy's maximum, as all here
        inv = 1.0 / ct
        st_inv = st * inv
        fv[0, i], fv[1, i], fv[3, i], fv[4, i], fv[5, i] = inv, st_inv, st * st_inv, st, (3.0 * ct * ct - 1.0) * inv
        fv[2, i] = 1.0
    for i in range(m):
        n = start + i
        agd = 0.0
        for f in range(6):
            agd = agd + fv[f, i] * ag[f, n]
        sums[0, i] = agd
        sums[1, i] = 0.0
    for p in range(pair_f.shape[0]):
        a, b = pair_f[p, 0], pair_f[p, 1]
        for i in range(m):
            sums[1, i] = sums[1, i] + pair_coef[p, start + i] * (fv[a, i] * fv[b, i])
    for i in range(m):
        sums[2, i] = aga - 2.0 * sums[0, i] + sums[1, i]
        obj[i] = 0.0
    for k in range(iz.shape[1]):
        for i in range(m):
            n = start + i
            dgt = 0.0
            for f in range(6):
                dgt = dgt + fv[f, i] * hg[f, k, n]
            agd, dgd, q = sums[0, i], sums[1, i], sums[2, i]
            z = iz[n, k]
            b = gat[n, k] - dgt - z * (agd - dgd)
            c = tgt[n, k] - 2.0 * z * dgt + z * z * dgd
            wk = b / (z * (q if (q >= 1e-300 or q != q) else 1e-300))
            wk = 1.0 if (black[n, k] or not wk - wk == 0.0) else wk  # black or not finite
            wk = wk if wk > 0.0 else 0.0  # numpy's clip (wk is finite here)
            wk = wk if wk < 1.0 else 1.0
            w[k, i] = wk
            zw = z * wk
            err = zw * (zw * q - 2.0 * b) + c
            obj[i] = obj[i] + (err if (err >= 0.0 or err != err) else 0.0) * weights[k]


def _clip(a, lo, hi):
    """numpy's clip of a float: a NaN stays; else `max` then `min`, each returning the bound
    when equal (so -0.0 clips to a bound of +0.0)."""
    if a != a:
        return a
    a = a if a > lo else lo
    return a if a < hi else hi


#: Texels that go through the search's steps together (`search_theta`).
BLOCK = 64
KERNELS = compiled.KernelSet(__name__, kernels=("search_theta",), helpers=("_evaluate", "_clip"))
get = KERNELS.get
