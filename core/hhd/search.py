"""The direction search of the encoder: the optimal linear direction, the θ scan + golden-section
search at fixed φ, and the optional outer φ search. No bpy.

"optimal_linear" takes the SH linear band's direction (the baseline games shipped); "searched"
scans θ ∈ [0, θ_max] at the optimal linear direction's φ, then refines the best bracket by
golden-section search (a fixed number of iterations for all texels), keeping the best of scan,
search and the optimal linear θ; `phi_search` adds an outer scan + golden-section over φ.
θ_max = arccos(MIN_COS): the floor on d·n_v. Everything is vectorised over texels.
"""

from __future__ import annotations

import numpy as np

from . import search_kernels
from .fit import Fit, FitAtPhi

SCAN_STEPS = 9  # θ samples of the coarse scan, end points included
GOLDEN_ITERATIONS = 14  # bracket 2θ_max/8 · 0.618^14 ≈ 5e-4 rad
PHI_SCAN_STEPS = 8
PHI_GOLDEN_ITERATIONS = 8

_INV_PHI = (np.sqrt(5.0) - 1.0) / 2.0


def golden(f, lo: np.ndarray, hi: np.ndarray, iterations: int):
    """Vectorised golden-section minimisation of f over [lo, hi] per texel.
    f maps `(N,)` parameters to `(N,)` values. Returns the best point and value seen."""
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(iterations):
        left = f1 < f2  # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x_new = np.where(left, hi - _INV_PHI * (hi - lo), lo + _INV_PHI * (hi - lo))
        f_new = f(x_new)
        x1, x2, f1, f2 = (
            np.where(left, x_new, x2),
            np.where(left, x1, x_new),
            np.where(left, f_new, f2),
            np.where(left, f1, f_new),
        )
    best_is_1 = f1 < f2
    return np.where(best_is_1, x1, x2), np.where(best_is_1, f1, f2)


def search_theta(
    fit: Fit,
    phi: np.ndarray,
    theta_start: np.ndarray,
    theta_max: float,
    iterations: int = GOLDEN_ITERATIONS,
    at: FitAtPhi | None = None,
):
    """Best θ at fixed φ: coarse scan of [0, θ_max], golden-section in the best bracket, and the
    starting θ (the optimal linear one) as a candidate. Returns (θ, objective) `(N,)` and the
    fit's w `(N, K)` there (`FitAtPhi.evaluate`'s). `at`: `fit.at_phi(phi)`, if the caller has
    it. Per texel in the compiled kernel (`search_kernels`: the bits of the vectorised `golden`
    over `FitAtPhi.evaluate`)."""
    n = len(phi)
    at = fit.at_phi(phi) if at is None else at
    theta, err = np.empty(n), np.empty(n)
    w = np.empty((n, fit.iz.shape[1]))
    if n:
        grid = np.linspace(0.0, theta_max, SCAN_STEPS)
        search_kernels.get().search_theta(
            *_kernel_arrays(at), grid, np.ascontiguousarray(theta_start, np.float64), float(theta_max),
            int(iterations), float(_INV_PHI), theta, err, w,
        )  # fmt: skip
    return theta, err, w


def _kernel_arrays(at: FitAtPhi) -> tuple:
    """`FitAtPhi`'s products and `Fit`'s per-texel arrays as the kernel takes them (float64,
    contiguous; a product that is one number for every texel broadcast): hg `(6, K, N)`, ag
    `(6, N)`, pair_f `(P, 2)`, pair_coef `(P, N)`, aga, iz, gat, tgt, black `(N, K)`, weights `(K,)`."""
    fit = at.fit
    n = len(fit.iz)
    per_texel = lambda v: np.broadcast_to(np.asarray(v, np.float64), (n,))  # noqa: E731
    hg = np.stack([np.broadcast_to(np.asarray(h, np.float64), fit.iz.shape[::-1]) for h in at.hg])
    ag = np.stack([per_texel(a) for a in at.ag])
    pair_f = np.array([key for key, _ in at.pairs], np.int64).reshape(-1, 2)
    pair_coef = np.stack([per_texel(c) for _, c in at.pairs]) if at.pairs else np.zeros((0, n))
    c = np.ascontiguousarray
    return (
        hg, ag, pair_f, pair_coef, float(fit.aga), c(fit.iz, np.float64), c(fit.gat, np.float64),
        c(fit.tgt, np.float64), c(fit.black), c(fit.weights, np.float64),
    )  # fmt: skip


def search_phi(fit: Fit, phi0: np.ndarray, theta0: np.ndarray, theta_max: float, iterations: int = GOLDEN_ITERATIONS):
    """Outer search over φ (scan of the full circle, then golden-section around the best), with
    the inner θ search at each φ. Returns (θ, φ), each `(N,)`."""
    n = len(phi0)
    offsets = np.arange(PHI_SCAN_STEPS) * (2.0 * np.pi / PHI_SCAN_STEPS)
    results = [search_theta(fit, phi0 + o, theta0, theta_max, iterations) for o in offsets]
    errs = np.stack([r[1] for r in results], axis=1)
    k = np.argmin(errs, axis=1)
    half = np.pi / PHI_SCAN_STEPS
    phi_best_scan = phi0 + offsets[k]
    phi, _ = golden(
        lambda p: search_theta(fit, p, theta0, theta_max, iterations)[1],
        phi_best_scan - half,
        phi_best_scan + half,
        PHI_GOLDEN_ITERATIONS,
    )
    theta, err, _ = search_theta(fit, phi, theta0, theta_max, iterations)
    scan_theta = np.stack([r[0] for r in results], axis=1)[np.arange(n), k]
    better_scan = errs[np.arange(n), k] < err
    return np.where(better_scan, scan_theta, theta), np.where(better_scan, phi_best_scan, phi)


def arctan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """`np.arctan2(y, x)` of `(N,)` arrays, float64, bit for bit the same wherever the arrays lie.

    numpy 1.x on AVX-512 CPUs (bpy 4.2's) computes arctan2 with SVML's vector routine only where
    it can tell the output from the inputs, else with libm's scalar one; the two differ in the last
    bit for about a third of the values. Its test is conservative: a strided input (a column of an
    `(N, 3)` array) counts as reaching past its buffer's end, so a new output the heap happens to
    put right behind it takes the scalar route, in one process out of a few. The encoder's
    direction search (an almost flat objective on near-ambient texels) turns that last bit into
    another highlight direction, so a bake and its re-encode differed. Here the output is an
    input's own memory (which numpy accepts) and the other input lies apart in the same buffer:
    the route never depends on the heap (numpy 2 takes the vector one either way)."""
    n = len(y)
    rows = np.zeros((2, n + 1))  # the padding element keeps the two rows apart
    out, other = rows[0, :n], rows[1, :n]
    out[:], other[:] = y, x
    return np.arctan2(out, other, out=out)


def optimal_linear_angles(local_sh: np.ndarray, channel_weights: np.ndarray, theta_max: float):
    """(θ, φ) `(N,)` of the SH linear band's direction (-r_1^1, -r_1^-1, r_1^0), luminance-weighted,
    with θ clamped to θ_max; +z where the band is zero. local_sh `(N, 9, K)`, channel_weights `(K,)`."""
    v = np.stack([-local_sh[:, 3], -local_sh[:, 1], local_sh[:, 2]], axis=1) @ channel_weights
    theta = arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    phi = arctan2(v[:, 1], v[:, 0])
    return np.minimum(theta, theta_max), phi
