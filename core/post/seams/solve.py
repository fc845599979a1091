"""The stitching least squares: the sparse system of the seam samples' read differences over the
texels they read (`_System`, `_system`), solved by Jacobi-preconditioned conjugate gradients,
27 (or any number of) right-hand sides at once, split over threads (`_solve`, `_cg`). No bpy."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ...progress import Tick, ticker
from . import solve_kernels
from .geometry import Seams
from .reads import bilinear_taps

#: Least-squares weights: each seam sample's equation per texel of edge it stands for, and the
#: pull of a covered texel and of a gutter texel towards its value (a gutter texel is free to take
#: what the seam needs; a covered texel moves only where no gutter texel can close the seam).
SEAM_WEIGHT = 50.0
COVERED_WEIGHT = 1.0
GUTTER_WEIGHT = 0.1
#: Conjugate gradient: stop when every channel's residual is below CG_TOLERANCE of its
#: right-hand side, or after CG_MAX_ITERATIONS.
CG_TOLERANCE = 1e-3
CG_MAX_ITERATIONS = 2000


@dataclass
class _System:
    """The stitching least squares, R sample rows over N unknowns. texels (N,) flat indices of
    the unknowns; taps (8, R) the unknown each row's read difference takes (fixed texels point
    at unknown 0 with coefficient 0), coeff (8, R) its coefficients (side a +, side b −),
    seam_weight (R,), constant (C, R) the fixed texels' part of each difference; data_weight
    (N,); for Aᵀ the row-major entries sorted by unknown: entry_row, entry_coeff, and the start
    of each unknown's run (starts) with its unknown (owner); dropped: samples left out."""

    texels: np.ndarray
    taps: np.ndarray
    coeff: np.ndarray
    seam_weight: np.ndarray
    constant: np.ndarray
    data_weight: np.ndarray
    entry_row: np.ndarray
    entry_coeff: np.ndarray
    starts: np.ndarray
    owner: np.ndarray
    dropped: int


#: Seam sample rows whose read texels `_system` gathers at once (memory: each row reads 8
#: texels of every SH channel, float64 where it sums them: 8 · C · 8 bytes a row).
SYSTEM_ROWS = 1 << 15


def _rows_finite(prior, index: np.ndarray) -> np.ndarray:
    """`(S,)` bool: whether every texel row `index (S, 8)` reads from `prior` (an array or
    `FilledRows`: only the rows read are made) is finite in every channel, SYSTEM_ROWS rows at a time."""
    out = np.ones(len(index), bool)
    for start in range(0, len(index), SYSTEM_ROWS):
        rows = slice(start, start + SYSTEM_ROWS)
        out[rows] = np.isfinite(prior[index[rows]]).all(axis=(1, 2))
    return out


def _system(seams: Seams, coverage: np.ndarray, prior, use: np.ndarray | None = None) -> _System:
    """Set up the least squares of `stitch` over the flat images `coverage (HW,)`, `prior (HW, C)`
    (an array or rows read on demand: `FilledRows`, `_Stacked`),
    with the samples `use` `(S,)` bool (default all; the caller leaves hidden samples out) that
    read only finite texels. Every texel such a sample reads (with a weight > 0) is an unknown."""
    ia, wa = bilinear_taps(seams.a, seams.width, seams.height)
    ib, wb = bilinear_taps(seams.b, seams.width, seams.height)
    index = np.concatenate([ia, ib], axis=1)  # (S, 8)
    coeff = np.concatenate([wa, -wb], axis=1)
    finite = _rows_finite(prior, index)
    good = finite if use is None else finite & use
    index, coeff, span = index[good], coeff[good], seams.span[good]
    free = coeff != 0.0  # a zero weight reads nothing
    texels = np.unique(index[free])
    # each read texel's unknown: its place among the sorted `texels` (no atlas-wide lookup: memory)
    taps = np.where(free, np.searchsorted(texels, index), -1)
    del free
    fixed = taps < 0
    constant = np.zeros((prior.shape[1], len(index)))
    some = np.flatnonzero(fixed.any(axis=1))  # rows with a tap of weight 0
    for start in range(0, len(some), SYSTEM_ROWS):  # each row's own sum: the same whatever the chunk
        rows = some[start : start + SYSTEM_ROWS]
        constant[:, rows] = np.einsum(
            "rk,rkc->cr", np.where(fixed[rows], coeff[rows], 0.0), prior[index[rows]].astype(np.float64)
        )
    coeff = np.where(fixed, 0.0, coeff)
    taps = np.where(fixed, 0, taps)
    flat = np.where(fixed, -1, taps).T.reshape(-1)  # tap-major, like taps.T
    order = np.argsort(flat, kind="stable")
    order = order[flat[order] >= 0]
    sorted_taps = flat[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_taps[1:] != sorted_taps[:-1]])) if len(order) else order
    return _System(
        texels=texels,
        taps=np.ascontiguousarray(taps.T),
        coeff=np.ascontiguousarray(coeff.T, dtype=np.float32),
        seam_weight=SEAM_WEIGHT * span,
        constant=constant,
        data_weight=np.where(coverage[texels] > 0.0, COVERED_WEIGHT, GUTTER_WEIGHT),
        entry_row=order % len(index) if len(index) else order,
        entry_coeff=coeff.T.reshape(-1)[order].astype(np.float32),
        starts=starts,
        owner=sorted_taps[starts],
        dropped=int(np.count_nonzero(~finite)),
    )


def _apply_a(s: _System, x: np.ndarray) -> np.ndarray:
    """A x: each row's read difference `(C, R)` of the unknowns `x (C, N)` (in x's dtype), the
    taps added in turn (`solve_kernels.apply_a`)."""
    out = np.zeros((x.shape[0], s.taps.shape[1]), x.dtype)
    solve_kernels.get().apply_a(s.taps, s.coeff, np.ascontiguousarray(x), out)
    return out


def _apply_at(s: _System, r: np.ndarray) -> np.ndarray:
    """Aᵀ r: row values `r (C, R)` summed onto the unknowns -> `(C, N)` (in r's dtype), each
    unknown's terms as numpy's `add.reduceat` sums them (`solve_kernels.apply_at`; the few runs
    longer than its block summed by numpy itself)."""
    r = np.ascontiguousarray(r)
    out = np.zeros((r.shape[0], len(s.texels)), r.dtype)
    if not len(s.starts):
        return out
    long = np.zeros(len(s.starts), bool)
    negative_zero = np.full(1, -0.0, np.result_type(r.dtype, s.entry_coeff.dtype))
    solve_kernels.get().apply_at(s.entry_row, s.entry_coeff, s.starts, s.owner, r, out, long, negative_zero)
    ends = np.append(s.starts[1:], len(s.entry_row))
    for i in np.flatnonzero(long):
        a, b = int(s.starts[i]), int(ends[i])
        terms = np.take(r, s.entry_row[a:b], axis=1) * s.entry_coeff[a:b]
        out[:, s.owner[i]] = np.add.reduceat(terms, [0], axis=1)[:, 0]
    return out


def _solve(s: _System, prior, check=None, threads: int = 1) -> tuple[np.ndarray, int]:
    """The change `(N, C)` of the unknowns minimising Σ λ (A(x0 + δ) + c)² + Σ μ δ²: the normal
    equations (AᵀΛA + M) δ = −AᵀΛ(A x0 + c), solved by Jacobi-preconditioned CG from δ = 0,
    each channel on its own (the channels vectorised, split over `threads` workers). Returns δ
    and the most iterations a channel took. `check`: cancels (and, a `core.progress.Tick`,
    reports how far the residuals are towards the tolerance) every few iterations. `s` is
    spent in part (`core.memory`): its `constant` is read into the right-hand side, then emptied."""
    n, c = len(s.texels), prior.shape[1]
    if n == 0:
        return np.zeros((0, c)), 0
    tick = ticker(check)
    x0 = np.ascontiguousarray(prior[s.texels].T, dtype=np.float64)
    residual = _apply_a(s, x0)  # the solve starts from δ = 0: x0 is not needed past the right-hand side
    del x0
    residual += s.constant
    s.constant = np.zeros((c, 0))  # spent (memory: as large as the rows' differences)
    residual *= s.seam_weight
    b = -_apply_at(s, residual)
    del residual
    parts = np.array_split(np.arange(c), max(1, min(threads, c)))
    if len(parts) == 1:
        x, iterations = _cg(s, b, tick, _on_step(tick, n, [(0.0, 0)], 0))
        return x.T, iterations
    reached = [(0.0, 0)] * len(parts)  # each worker's fraction (its channels' mean) and iterations
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
        done = list(pool.map(lambda k: _cg(s, b[parts[k]], tick, _on_step(tick, n, reached, k)), range(len(parts))))
    return np.concatenate([x for x, _ in done]).T, max(k for _, k in done)


def _on_step(tick: Tick, unknowns: int, reached: list[tuple[float, int]], k: int):
    """`_cg`'s `on_step(fraction, iterations)` for worker `k` of `_solve`: the mean of the
    workers' fractions to `tick`, with the most iterations any has done (None when `tick`
    reports nothing: `_cg` then only checks)."""
    if not tick.reports:
        return None

    def on_step(fraction: float, iterations: int) -> None:
        reached[k] = (fraction, iterations)
        mean = sum(f for f, _ in reached) / len(reached)
        tick.at(mean, f"{unknowns} texels, iteration {max(i for _, i in reached)}")

    return on_step


def _cg(s: _System, b: np.ndarray, check=None, on_step=None) -> tuple[np.ndarray, int]:
    """Jacobi-preconditioned conjugate gradients for (AᵀΛA + M) x = b, `b (C, N)`, one
    independent solve per row of b (vectorised), in float32 (the texels' precision; the
    tolerance is far above its rounding): x `(C, N)` float64 and the iterations taken.
    Every 8 iterations `check()` (cancel), or `on_step(fraction, iterations)` if given (which
    checks too): the fraction is how far the residuals have come from ‖b‖ towards the tolerance
    (on a log scale, the channels' mean; at least iterations / CG_MAX_ITERATIONS)."""
    lam = s.seam_weight.astype(np.float32)
    mu = s.data_weight.astype(np.float32)

    def matvec(x):
        return _apply_at(s, _apply_a(s, x) * lam) + x * mu

    diag = s.data_weight + np.bincount(
        s.taps.reshape(-1), weights=(s.coeff.astype(np.float64) ** 2 * s.seam_weight).reshape(-1), minlength=len(mu)
    )
    inv_diag = (1.0 / diag).astype(np.float32)
    r = b.astype(np.float32)
    x = np.zeros_like(r)
    target = CG_TOLERANCE * np.linalg.norm(b, axis=1)
    z = r * inv_diag
    p = z.copy()
    rz = np.einsum("cn,cn->c", r, z, dtype=np.float64)
    iterations = 0
    norm = np.linalg.norm(r, axis=1)
    active = norm > target
    while iterations < CG_MAX_ITERATIONS and active.any():
        if on_step is not None and iterations % 8 == 0:
            on_step(_cg_fraction(norm, target, active, iterations), iterations)
        elif check is not None and iterations % 8 == 0:
            check()
        q = matvec(p)
        pq = np.einsum("cn,cn->c", p, q, dtype=np.float64)
        # a converged channel stops (alpha 0): each channel's result is its own, whatever it is solved with
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=active & (pq > 0.0)).astype(np.float32)
        x += alpha[:, None] * p
        r -= alpha[:, None] * q
        z = r * inv_diag
        rz_new = np.einsum("cn,cn->c", r, z, dtype=np.float64)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0.0).astype(np.float32)
        p = z + beta[:, None] * p
        rz = rz_new
        norm = np.linalg.norm(r, axis=1)
        active &= norm > target
        iterations += 1
    return x.astype(np.float64), iterations


def _cg_fraction(norm: np.ndarray, target: np.ndarray, active: np.ndarray, iterations: int) -> float:
    """How far `_cg` is: per channel log(‖r‖ / ‖b‖) / log(CG_TOLERANCE) (1 once converged), their
    mean, at least iterations / CG_MAX_ITERATIONS (progress only: nothing computed depends on it)."""
    start = target / CG_TOLERANCE  # ‖b‖
    with np.errstate(divide="ignore", invalid="ignore"):
        gone = np.log(np.maximum(norm, 1e-300) / start) / np.log(CG_TOLERANCE)
    per = np.where(active & (start > 0.0), np.clip(np.nan_to_num(gone, nan=0.0), 0.0, 1.0), 1.0)
    return max(float(per.mean()) if len(per) else 1.0, iterations / CG_MAX_ITERATIONS)


def _groups(s: _System) -> int:
    """Groups of unknowns tied together by seam samples (connected components; hook and
    pointer-jumping union-find, vectorised over the samples)."""
    n = len(s.texels)
    if n == 0:
        return 0
    live = s.coeff != 0.0  # (8, R); fixed taps have coefficient 0
    anchor = np.where(live, s.taps, n).min(axis=0)  # each row's first unknown
    u = np.broadcast_to(anchor, s.taps.shape)[live]
    v = s.taps[live]
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        if np.array_equal(pu, pv):
            break
        np.minimum.at(parent, np.maximum(pu, pv), np.minimum(pu, pv))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    return int(len(np.unique(parent)))
