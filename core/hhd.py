"""IrradZ encoding of L2 SH lighting into HHD / AHD, and its reconstruction. No bpy.

Sources: Roughton, Sloan, Silvennoinen, Shirley 2024, "Hemispherical Lighting Insights" (HHD,
hemispherical Gram matrix, searched direction, HHD from linear SH, self-bounce) and Sloan &
Silvennoinen 2018, "Directional Lightmap Encoding Insights" (IrradZ re-parameterisation,
luminance ambient ratio, non-negative fit in the null space of the I_z constraint).

Model, with n_v the vertex normal, n the shading normal, d the highlight direction (d·n_v > 0):
    HHD  I(n) = I_z [ w_a (1 + n·n_v)/2 + (1 - w_a) max(n·d, 0) / (d·n_v) ]
    AHD  I(n) = I_z [ w_a               + (1 - w_a) max(n·d, 0) / (d·n_v) ]
i.e. C_a = w_a I_z and C_d = (1 - w_a) I_z / (d·n_v). I(n_v) = I_z exactly in both.
Irradiance is in DESIGN.md units: E(n) = (1/π) ∫ L max(n·ω, 0) dω.

The fit, per texel, in the frame z = n_v (all vectorised over texels):
  * I_z is the exact irradiance at n_v (the IrradZ constraint), see `irradz`.
  * Target: the SH irradiance i = cosine-convolved radiance SH. Model and target are compared
    as L2 SH with a Gram matrix G (hemisphere: error over the upper hemisphere only; sphere:
    the classic spherical least squares). With a = SH of the ambient lobe (normalised to 1 at
    z), d = SH of the directional lobe (π/d_z)·conv(Y(d)), the error is
        E(w) = ‖I_z (d + w (a - d)) - i‖²_G,
    a quadratic in w whose minimiser is w = (a-d)ᵀG(i - I_z d) / (I_z (a-d)ᵀG(a-d)) — the
    paper's formula with its i/r_0 corrected to i/I_z. The 2018 paper's non-negativity
    (C_a ≥ 0, C_d ≥ 0, i.e. the feasible interval of its null-space parameter t) is
    exactly 0 ≤ w ≤ 1 here, and for a 1D convex quadratic clamping the minimiser is the
    constrained optimum.
  * The direction: "optimal_linear" takes the SH linear band's direction (the baseline games
    shipped); "searched" scans θ ∈ [0, θ_max] at the optimal linear direction's φ, then refines
    the best bracket by golden-section search (a fixed number of iterations for all texels),
    keeping the best of scan, search and the optimal linear θ; `phi_search` adds an outer
    scan + golden-section over φ. θ_max = arccos(MIN_COS): the floor on d·n_v.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import gram as _gram
from . import sh as _sh

#: Rec.709 luminance weights (DESIGN.md).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

#: Floor on d·n_v. It bounds C_d = (1 - w_a) I_z / d_z (at most 50 I_z) and keeps d strictly in
#: the upper hemisphere; a light exactly on the horizon is then represented at θ = 88.85°
#: instead of 90° (its measured cost is in tests/test_hhd_papers.py and docs/encoder.md).
MIN_COS = 0.02

#: I_z·(exact) for hemisphere-sampled SH: I_z = (1/π)∫_{Ω+} L cosθ = r_1^0 / (π C1) = 2/√(3π) r_1^0.
IRRADZ_FROM_R10 = 2.0 / np.sqrt(3.0 * np.pi)

SCAN_STEPS = 9          # θ samples of the coarse scan, end points included
GOLDEN_ITERATIONS = 14  # bracket 2θ_max/8 · 0.618^14 ≈ 5e-4 rad
PHI_SCAN_STEPS = 8
PHI_GOLDEN_ITERATIONS = 8

_INV_PHI = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass
class HHDParams:
    """Encoded texels. Arrays are float64, one row per texel.

    irradz          (N, C)  I_z, irradiance at the vertex normal, ≥ 0
    ambient_weight  (N,) for ambient="luminance", (N, C) for "rgb"; in [0, 1]
    direction       (N, 3)  highlight direction, world space, unit, d·n_v ≥ MIN_COS
    model           "hhd" or "ahd"
    invalid         (N,) bool: input had NaN/Inf SH or a zero/non-finite normal; such texels
                    are encoded black (I_z = 0, w_a = 1, d = n_v or +z)
    clamped_irradz  (N,) bool: I_z came out negative (SH ringing of full-sphere input, noise)
                    and was clamped to 0
    """
    irradz: np.ndarray
    ambient_weight: np.ndarray
    direction: np.ndarray
    model: str = "hhd"
    invalid: np.ndarray = field(default=None)
    clamped_irradz: np.ndarray = field(default=None)

    @property
    def n_invalid(self) -> int:
        return int(np.count_nonzero(self.invalid)) if self.invalid is not None else 0


# --------------------------------------------------------------------------------------------
# Lobes in SH, local frame (z = n_v)

def ambient_lobe(model: str) -> np.ndarray:
    """Irradiance SH `(9,)` of the ambient term, normalised to 1 at z.

    HHD: a hemisphere light of radiance 1 (radiance SH [√π, 0, √(3π)/2, 0, ...]), irradiance
    exactly (1 + n_z)/2.  AHD: constant irradiance 1 (radiance SH [2√π, 0, ...]).
    """
    a = np.zeros(9)
    if model == "hhd":
        a[0], a[2] = np.sqrt(np.pi), np.sqrt(3.0 * np.pi) / 2.0
    elif model == "ahd":
        a[0] = 2.0 * np.sqrt(np.pi)
    else:
        raise ValueError(f"model must be 'hhd' or 'ahd', not {model!r}")
    return _sh.convolve_cosine(a)


def directional_lobe(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Irradiance SH `(N, 9)` of a directional light at (θ, φ) scaled to irradiance 1 at z:
    (π / d_z) conv(Y(d)). Only its L2 projection, as in the paper's fit. The search uses the
    factorised form (`_phi_factors` × `_theta_functions`); this direct form is its reference."""
    st = np.sin(theta)
    d = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)
    return _sh.evaluate(d) * (_sh.COSINE_KERNEL * np.pi) / d[..., 2:3]


# --------------------------------------------------------------------------------------------
# Input handling

def _check_shapes(sh, n_v) -> None:
    shape, n_shape = np.shape(sh), np.shape(n_v)
    if len(shape) not in (2, 3) or shape[1] != 9:
        raise ValueError(f"sh must have shape (N, 9, C), got {shape}")
    if n_shape != (shape[0], 3):
        raise ValueError(f"n_v must have shape ({shape[0]}, 3), got {n_shape}")


def _sanitise(sh: np.ndarray, n_v: np.ndarray):
    """float64 copies with non-finite rows zeroed and normals normalised; plus the invalid mask."""
    _check_shapes(sh, n_v)
    sh = np.asarray(sh, dtype=np.float64)
    n_v = np.asarray(n_v, dtype=np.float64)
    if sh.ndim == 2:
        sh = sh[..., None]
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.linalg.norm(n_v, axis=1)
    invalid = (~np.isfinite(sh).reshape(len(sh), -1).all(axis=1) | ~np.isfinite(length)
               | (length < 1e-12))
    if invalid.any():
        sh = sh.copy()
        sh[invalid] = 0.0
    safe_len = np.where(invalid, 1.0, length)
    n_v = np.where(invalid[:, None], np.array([0.0, 0.0, 1.0]), n_v / safe_len[:, None])
    return sh, n_v, invalid


def _channel_weights(c: int) -> np.ndarray:
    return LUMINANCE if c == 3 else np.full(c, 1.0 / c)


def irradz(sh: np.ndarray, n_v: np.ndarray, hemisphere_sampled: bool = True) -> np.ndarray:
    """Exact irradiance at n_v from world-space radiance SH `(N, 9, C)`, unit n_v `(N, 3)` -> `(N, C)`.

    hemisphere_sampled=True (a lightmap bake: radiance integrated over the hemisphere of n_v
    only, zero below): I_z = (1/π)∫_{Ω+} L cosθ dω = 2/√(3π) r_1^0 with r_1^0 the tangent-space
    zonal band-1 coefficient, exact whatever the SH truncation (cosθ lies in band 1's span).
    In world space r_1^0 = v·n_v with v = (-r_1^1, -r_1^-1, r_1^0).
    hemisphere_sampled=False (full-sphere SH, e.g. a probe): I_z = Y(n_v)·i, the irradiance of
    the band-limited radiance; it can be negative from ringing (encode clamps it to 0).
    """
    if hemisphere_sampled:
        r10 = -sh[:, 3] * n_v[:, 0:1] - sh[:, 1] * n_v[:, 1:2] + sh[:, 2] * n_v[:, 2:3]
        return IRRADZ_FROM_R10 * r10
    return _sh.irradiance(sh, n_v)


# --------------------------------------------------------------------------------------------
# The fit

class _Fit:
    """Per-texel quantities for evaluating the objective E(w*(θ, φ)) quickly at any direction.

    Channels K: 1 (luminance fit) or C (per-channel fit); `weights (K,)` combine the channels'
    errors into the direction's objective. Targets are normalised per texel by the caller so
    the search behaves identically for radiance 1e-8 and 1e8.

    Speed: the directional lobe's coefficients factor as d_j = f_j(θ) g_j(φ) (`_theta_functions`,
    `_phi_factors`), so for a fixed φ per texel (`at_phi`) every product with G, a and the
    target is precomputed once, and each θ evaluation is a few dozen vector operations.
    """

    def __init__(self, target: np.ndarray, iz: np.ndarray, a: np.ndarray, g: np.ndarray,
                 weights: np.ndarray, scale: np.ndarray | None = None):
        self.scale = np.ones(len(iz)) if scale is None else scale   # per-texel normalisation undone by fit_error
        self.g = g
        self.ga = g @ a
        self.aga = float(a @ self.ga)
        self.iz = iz                                      # (N, K)
        self.gt = np.einsum("ij,njk->nik", g, target)     # (N, 9, K)
        self.tgt = np.einsum("njk,njk->nk", target, self.gt)
        self.gat = np.einsum("j,njk->nk", self.ga, target)
        self.weights = weights
        self.black = iz <= 0.0
        self.pairs = [(i, j, g[i, j] * (1.0 if i == j else 2.0))
                      for i in range(9) for j in range(i, 9) if g[i, j] != 0.0]

    def at_phi(self, phi: np.ndarray) -> "_FitAtPhi":
        return _FitAtPhi(self, phi)

    def evaluate(self, theta: np.ndarray, phi: np.ndarray):
        return self.at_phi(phi).evaluate(theta)


def _phi_factors(phi: np.ndarray) -> list:
    """g_j(φ) of the directional lobe d_j = f_j(θ) g_j(φ), with π and the cosine kernel folded in."""
    c, s = np.cos(phi), np.sin(phi)
    k1, k2 = np.pi * 2.0 / 3.0, np.pi * 0.25
    return [np.pi * _sh.Y00, -k1 * _sh.C1 * s, k1 * _sh.C1, -k1 * _sh.C1 * c,
            k2 * _sh.C2 * c * s, -k2 * _sh.C2 * s, k2 * _sh.C20, -k2 * _sh.C2 * c,
            k2 * _sh.C22 * (c * c - s * s)]


#: The 9 lobe coefficients use 6 distinct θ-functions (see `_theta_functions`).
_FUNCTION_OF_COEFF = (0, 1, 2, 1, 3, 4, 5, 4, 3)


def _theta_functions(theta: np.ndarray) -> list:
    """The θ-dependence of Y_j(d) / d_z, d_z = cos θ: [1/c, s/c, 1, s²/c, s, (3c²-1)/c]."""
    ct = np.cos(theta)
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))      # θ ∈ [0, π/2]; cheaper than sin
    inv = 1.0 / ct
    st_inv = st * inv
    return [inv, st_inv, 1.0, st * st_inv, st, (3.0 * ct * ct - 1.0) * inv]


class _FitAtPhi:
    """`_Fit` with φ fixed per texel: evaluate(θ) -> (objective (N,), w (N, K)).

    Products with G, a and the target are grouped by θ-function (and pair of θ-functions for
    dᵀGd) once here, so an evaluation costs ~50 vector operations.
    """

    def __init__(self, fit: _Fit, phi: np.ndarray):
        g = _phi_factors(phi)
        self.fit = fit
        n_fn = 6
        self.hg = [0.0] * n_fn                                       # Σ g_j (G t)_j by function
        self.ag = [0.0] * n_fn                                       # Σ g_j (G a)_j by function
        for j in range(9):
            f = _FUNCTION_OF_COEFF[j]
            self.hg[f] = self.hg[f] + g[j] * fit.gt[:, j, :].T       # (K, N)
            self.ag[f] = self.ag[f] + g[j] * fit.ga[j]
        pairs = {}
        for i, j, coef in fit.pairs:
            key = tuple(sorted((_FUNCTION_OF_COEFF[i], _FUNCTION_OF_COEFF[j])))
            pairs[key] = pairs.get(key, 0.0) + coef * g[i] * g[j]
        self.pairs = list(pairs.items())

    def evaluate(self, theta: np.ndarray):
        fit = self.fit
        f = _theta_functions(theta)
        dgt = sum(fi * h for fi, h in zip(f, self.hg)).T             # dᵀG t, (N, K)
        agd = sum(fi * h for fi, h in zip(f, self.ag))               # aᵀG d
        dgd = sum(coef * (f[i] * f[j]) for (i, j), coef in self.pairs)   # dᵀG d
        q = (fit.aga - 2.0 * agd + dgd)[:, None]                     # (a-d)ᵀG(a-d)
        iz = fit.iz
        b = fit.gat - dgt - iz * (agd - dgd)[:, None]                # (a-d)ᵀG (t - I_z d)
        c = fit.tgt - 2.0 * iz * dgt + iz * iz * dgd[:, None]        # ‖t - I_z d‖²_G
        with np.errstate(divide="ignore", invalid="ignore"):
            w = b / (iz * np.maximum(q, 1e-300))
        w = np.clip(np.where(fit.black | ~np.isfinite(w), 1.0, w), 0.0, 1.0)
        izw = iz * w
        err = izw * (izw * q - 2.0 * b) + c
        return np.maximum(err, 0.0) @ fit.weights, w


def _golden(f, lo: np.ndarray, hi: np.ndarray, iterations: int):
    """Vectorised golden-section minimisation of f over [lo, hi] per texel.
    f maps `(N,)` parameters to `(N,)` values. Returns the best point and value seen."""
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(iterations):
        left = f1 < f2                          # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x_new = np.where(left, hi - _INV_PHI * (hi - lo), lo + _INV_PHI * (hi - lo))
        f_new = f(x_new)
        x1, x2, f1, f2 = (np.where(left, x_new, x2), np.where(left, x1, x_new),
                          np.where(left, f_new, f2), np.where(left, f1, f_new))
    best_is_1 = f1 < f2
    return np.where(best_is_1, x1, x2), np.where(best_is_1, f1, f2)


def _search_theta(fit: _Fit, phi: np.ndarray, theta_start: np.ndarray, theta_max: float,
                  iterations: int = GOLDEN_ITERATIONS):
    """Best θ at fixed φ: coarse scan of [0, θ_max], golden-section in the best bracket, and the
    starting θ (the optimal linear one) as a candidate. Returns (θ, objective)."""
    n = len(phi)
    at = fit.at_phi(phi)
    grid = np.linspace(0.0, theta_max, SCAN_STEPS)
    scan = np.stack([at.evaluate(np.full(n, t))[0] for t in grid], axis=1)   # (N, S)
    k = np.argmin(scan, axis=1)
    step = grid[1] - grid[0]
    lo = np.clip(grid[k] - step, 0.0, theta_max)
    hi = np.clip(grid[k] + step, 0.0, theta_max)
    theta, err = _golden(lambda t: at.evaluate(t)[0], lo, hi, iterations)
    candidates = np.stack([theta, grid[k], theta_start], axis=1)
    errors = np.stack([err, scan[np.arange(n), k], at.evaluate(theta_start)[0]], axis=1)
    best = np.argmin(errors, axis=1)
    rows = np.arange(n)
    return candidates[rows, best], errors[rows, best]


def _search_phi(fit: _Fit, phi0: np.ndarray, theta0: np.ndarray, theta_max: float,
                iterations: int = GOLDEN_ITERATIONS):
    """Outer search over φ (scan of the full circle, then golden-section around the best), with
    the inner θ search at each φ. Returns (θ, φ)."""
    n = len(phi0)
    offsets = np.arange(PHI_SCAN_STEPS) * (2.0 * np.pi / PHI_SCAN_STEPS)
    results = [_search_theta(fit, phi0 + o, theta0, theta_max, iterations) for o in offsets]
    errs = np.stack([r[1] for r in results], axis=1)
    k = np.argmin(errs, axis=1)
    half = np.pi / PHI_SCAN_STEPS
    phi_best_scan = phi0 + offsets[k]
    phi, _ = _golden(lambda p: _search_theta(fit, p, theta0, theta_max, iterations)[1],
                     phi_best_scan - half, phi_best_scan + half, PHI_GOLDEN_ITERATIONS)
    theta, err = _search_theta(fit, phi, theta0, theta_max, iterations)
    scan_theta = np.stack([r[0] for r in results], axis=1)[np.arange(n), k]
    better_scan = errs[np.arange(n), k] < err
    return np.where(better_scan, scan_theta, theta), np.where(better_scan, phi_best_scan, phi)


def optimal_linear_angles(local_sh: np.ndarray, channel_weights: np.ndarray, theta_max: float):
    """(θ, φ) `(N,)` of the SH linear band's direction (-r_1^1, -r_1^-1, r_1^0), luminance-weighted,
    with θ clamped to θ_max; +z where the band is zero."""
    v = np.stack([-local_sh[:, 3], -local_sh[:, 1], local_sh[:, 2]], axis=1) @ channel_weights
    theta = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    phi = np.arctan2(v[:, 1], v[:, 0])
    return np.minimum(theta, theta_max), phi


def encode(sh, n_v, model: str = "hhd", direction: str = "searched", gram: str = "hemisphere",
           ambient: str = "luminance", *, hemisphere_sampled: bool = True, phi_search: bool = False,
           min_cos: float = MIN_COS, golden_iterations: int = GOLDEN_ITERATIONS) -> HHDParams:
    """Fit HHD or AHD to world-space radiance SH, per texel.

    sh   `(N, 9, C)` world-space radiance SH (any float dtype; C = 3 for RGB)
    n_v  `(N, 3)` vertex normals (normalised here)
    model "hhd" | "ahd";  direction "searched" | "optimal_linear";  gram "hemisphere" | "sphere";
    ambient "luminance" (one w_a fitted to the luminance, as the 2018 paper's L(C_a)/L(I_z)) |
    "rgb" (w_a per channel).
    hemisphere_sampled: True (default) for a lightmap bake, whose SH holds radiance over the
    hemisphere of n_v only: I_z = 2/√(3π) r_1^0 exactly. Pass False for full-sphere SH (a probe):
    I_z = Y(n_v)·i, the SH irradiance, clamped to ≥ 0 (clamps counted in `clamped_irradz`). The
    target of the fit is the SH irradiance i either way.
    phi_search: add the outer φ search (≈ 20× the cost, a slight error decrease).
    min_cos: floor on d·n_v.
    golden_iterations: golden-section steps of the θ search (each shrinks the bracket by 0.618;
    0 keeps the best of the coarse scan and the optimal-linear θ).

    NaN/Inf in a texel's SH or normal, or a zero normal, marks it `invalid` and encodes it
    black rather than raising: one bad texel must not lose a bake. Callers report `n_invalid`.
    Output never contains NaN or Inf.
    """
    if direction not in ("searched", "optimal_linear"):
        raise ValueError(f"direction must be 'searched' or 'optimal_linear', not {direction!r}")
    if gram not in ("hemisphere", "sphere"):
        raise ValueError(f"gram must be 'hemisphere' or 'sphere', not {gram!r}")
    if ambient not in ("luminance", "rgb"):
        raise ValueError(f"ambient must be 'luminance' or 'rgb', not {ambient!r}")
    options = dict(a=ambient_lobe(model), g=_gram.hemisphere() if gram == "hemisphere" else _gram.sphere(),
                   searched=direction == "searched", luminance=ambient == "luminance",
                   hemisphere_sampled=hemisphere_sampled, phi_search=phi_search,
                   theta_max=float(np.arccos(min_cos)), iterations=max(0, int(golden_iterations)))
    _check_shapes(sh, n_v)
    parts = [_encode_chunk(*_sanitise(sh[s:s + CHUNK], n_v[s:s + CHUNK]), **options)
             for s in range(0, len(n_v), CHUNK)] or [_encode_chunk(*_sanitise(sh, n_v), **options)]
    iz, w, d, clamped, invalid = (np.concatenate(x) for x in zip(*parts))
    return HHDParams(irradz=iz, ambient_weight=w, direction=d, model=model,
                     invalid=invalid, clamped_irradz=clamped)


#: Texels per chunk: small enough that the fit's (N,) temporaries stay in cache.
CHUNK = 8192


def _prepare(world_sh, n, *, a, g, luminance, hemisphere_sampled):
    """Shared set-up of a chunk: (fit, frames, local SH used by the fit, I_z, clamped, channel weights)."""
    iz = irradz(world_sh, n, hemisphere_sampled)                         # (N, C)
    clamped = (iz < 0.0).any(axis=1)
    iz = np.maximum(iz, 0.0)
    lum = _channel_weights(world_sh.shape[2])
    frames = _sh.tangent_frames(n)
    if luminance:   # rotation is linear: rotate only the luminance, fit one channel
        local = _sh.to_local(world_sh @ lum, frames)[..., None]         # (N, 9, 1)
        iz_fit, weights, lum_fit = (iz @ lum)[:, None], np.ones(1), np.ones(1)
    else:
        local = _sh.to_local(world_sh, frames)                           # (N, 9, C)
        iz_fit, weights, lum_fit = iz, lum, lum
    target = _sh.convolve_cosine(local)
    # Normalise each texel so the fit is scale-free (1e-8 and 1e8 behave alike, no overflow).
    scale = np.maximum(np.abs(target).max(axis=(1, 2)), iz_fit.max(axis=1))
    scale = np.where(scale > 0.0, scale, 1.0)
    fit = _Fit(target / scale[:, None, None], iz_fit / scale[:, None], a, g, weights, scale)
    return fit, frames, local, iz, clamped, lum_fit


def _encode_chunk(world_sh, n, invalid, *, searched, phi_search, theta_max, iterations, **prepare):
    """encode() on one chunk of sanitised texels -> (I_z, w_a, d_world, clamped, invalid)."""
    fit, frames, local, iz, clamped, lum_fit = _prepare(world_sh, n, **prepare)
    theta, phi = optimal_linear_angles(local, lum_fit, theta_max)
    if searched:
        if phi_search:
            theta, phi = _search_phi(fit, phi, theta, theta_max, iterations)
        else:
            theta, _ = _search_theta(fit, phi, theta, theta_max, iterations)
    _, w = fit.evaluate(theta, phi)
    # Where the fit is all ambient (w = 1 up to rounding) the direction is irrelevant: store
    # n_v, which keeps the direction texture smooth for filtering.
    all_ambient = (w >= 1.0 - 1e-9).all(axis=1)
    theta = np.where(all_ambient, 0.0, theta)
    w = np.where(all_ambient[:, None], 1.0, w)

    st = np.sin(theta)
    d_local = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=1)
    d_world = np.einsum("nij,nj->ni", frames, d_local)
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    return iz, (w[:, 0] if prepare["luminance"] else w), d_world, clamped, invalid


def fit_error(sh, n_v, direction, model: str = "hhd", gram: str = "hemisphere",
              ambient: str = "luminance", *, hemisphere_sampled: bool = True):
    """The encoder's objective at given world directions `(N, 3)` (d·n_v > 0): the G-weighted
    squared error between the fitted model's L2 SH and the SH irradiance, in irradiance² units
    (luminance, or the luminance-weighted sum over channels for ambient="rgb"), and the
    optimal clamped w_a `(N,)`/`(N, C)`. For measuring the search and the d·n_v floor."""
    world_sh, n, _ = _sanitise(sh, n_v)
    fit, frames, *_ = _prepare(world_sh, n, a=ambient_lobe(model),
                                g=_gram.hemisphere() if gram == "hemisphere" else _gram.sphere(),
                                luminance=ambient == "luminance", hemisphere_sampled=hemisphere_sampled)
    d_local = np.einsum("nji,nj->ni", frames, np.asarray(direction, dtype=np.float64))
    theta = np.arccos(np.clip(d_local[:, 2], -1.0, 1.0))
    phi = np.arctan2(d_local[:, 1], d_local[:, 0])
    err, w = fit.evaluate(theta, phi)
    return err * fit.scale ** 2, (w[:, 0] if ambient == "luminance" else w)


# --------------------------------------------------------------------------------------------
# Reconstruction and error

def reconstruct(p: HHDParams, n_v, n, model: str | None = None, albedo=None) -> np.ndarray:
    """Irradiance `(N, C)` at shading normals n `(N, 3)` (what a game shader computes).

    model defaults to p.model. albedo `(N, C)` or `(C,)` adds the 2024 paper's self-bounce,
    albedo · I_z · (1 - n·n_v)/2 (light reflected by the surface's own lower hemisphere).
    """
    model = model or p.model
    n_v = np.asarray(n_v, dtype=np.float64)
    n_v = n_v / np.linalg.norm(n_v, axis=1, keepdims=True)
    n = np.asarray(n, dtype=np.float64)
    w = p.ambient_weight if p.ambient_weight.ndim == 2 else p.ambient_weight[:, None]
    d = p.direction
    cos_nv = np.einsum("ni,ni->n", n, n_v)[:, None]
    dz = np.maximum(np.einsum("ni,ni->n", d, n_v), MIN_COS * 0.5)[:, None]
    lobe = np.maximum(np.einsum("ni,ni->n", n, d), 0.0)[:, None] / dz
    amb = (1.0 + cos_nv) * 0.5 if model == "hhd" else 1.0
    out = p.irradz * (w * amb + (1.0 - w) * lobe)
    if albedo is not None:
        out = out + np.asarray(albedo) * p.irradz * (1.0 - cos_nv) * 0.5
    return out


def hemisphere_quadrature(n_z: int = 24, n_phi: int = 48):
    """Local-frame directions `(K, 3)` and weights `(K,)` integrating over the upper hemisphere
    (Gauss–Legendre in cosθ × uniform φ; weights sum to 2π)."""
    t, wt = np.polynomial.legendre.leggauss(n_z)
    z, wz = 0.5 * (t + 1.0), 0.5 * wt
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    s = np.sqrt(1.0 - z * z)
    dirs = np.stack([np.outer(s, np.cos(phi)), np.outer(s, np.sin(phi)),
                     np.repeat(z[:, None], n_phi, axis=1)], axis=-1).reshape(-1, 3)
    weights = np.repeat(wz, n_phi) * (2.0 * np.pi / n_phi)
    return dirs, weights


def hemispherical_rmse(sh, n_v, p: HHDParams, model: str | None = None, *, chunk: int = 4096,
                       quadrature=None) -> np.ndarray:
    """RMSE `(N, C)` over the upper hemisphere of n_v between reconstruct(p) and the SH irradiance
    Y(n)·i of the radiance SH, by quadrature: sqrt( (1/2π) ∫_{Ω+} (I_model - I_SH)² dn ).

    This measures what a shader reconstructs (the exact clamped-cosine lobe), not the encoder's
    internal L2-projected objective. Invalid texels count as zero error.
    """
    world_sh, n, invalid = _sanitise(sh, n_v)
    dirs, wq = quadrature or hemisphere_quadrature()
    out = np.zeros((len(n), world_sh.shape[2]))
    ybasis = _sh.evaluate(dirs) * _sh.COSINE_KERNEL                    # (K, 9)
    for s in range(0, len(n), chunk):
        sl = slice(s, s + chunk)
        frames = _sh.tangent_frames(n[sl])
        local = _sh.to_local(world_sh[sl], frames)
        target = np.einsum("qk,nkc->nqc", ybasis, local)                # (n, K, C)
        d_local = np.einsum("nji,nj->ni", frames, p.direction[sl])      # Rᵀ d
        w = p.ambient_weight[sl]
        w = w[:, None, :] if w.ndim == 2 else w[:, None, None]
        dz = np.maximum(d_local[:, 2], MIN_COS * 0.5)
        lobe = np.maximum(np.einsum("qi,ni->nq", dirs, d_local), 0.0) / dz[:, None]
        amb = (1.0 + dirs[:, 2]) * 0.5 if (model or p.model) == "hhd" else np.ones(len(dirs))
        model_val = p.irradz[sl][:, None, :] * (w * amb[None, :, None] + (1.0 - w) * lobe[..., None])
        out[sl] = np.sqrt(np.einsum("q,nqc->nc", wq, (model_val - target) ** 2) / (2.0 * np.pi))
    out[invalid] = 0.0
    return out


# --------------------------------------------------------------------------------------------
# HHD <-> linear SH (runtime blending of light sets, 2024 paper "HHD and linear SH")

def to_linear_sh(p: HHDParams, n_v) -> np.ndarray:
    """World-space linear radiance SH `(N, 4, C)` of the HHD lighting (hemisphere light of
    radiance C_a around n_v + directional light of irradiance C_d along d):
        √π/2 [2C_a + C_d, -√3 b_y, √3 b_z, -√3 b_x],  b = C_a n_v + C_d d."""
    n_v = np.asarray(n_v, dtype=np.float64)
    n_v = n_v / np.linalg.norm(n_v, axis=1, keepdims=True)
    w = p.ambient_weight if p.ambient_weight.ndim == 2 else p.ambient_weight[:, None]
    dz = np.einsum("ni,ni->n", p.direction, n_v)[:, None]
    ca = w * p.irradz
    cd = (1.0 - w) * p.irradz / dz
    b = ca[:, None, :] * n_v[:, :, None] + cd[:, None, :] * p.direction[:, :, None]   # (N,3,C)
    k = np.sqrt(np.pi) / 2.0
    r3 = np.sqrt(3.0)
    return np.stack([k * (2.0 * ca + cd), -k * r3 * b[:, 1], k * r3 * b[:, 2], -k * r3 * b[:, 0]], axis=1)


def from_linear_sh(l1, n_v, min_cos: float = MIN_COS) -> HHDParams:
    """HHD from world-space linear radiance SH `(N, 4, C)` of hemispherical lighting, in closed
    form (2024 paper), solved on the luminance; I_z per channel. With
        [b_c, b_x, b_y, b_z] = 2/√π [l0, -l_1^1/√3, -l_1^-1/√3, l_1^0/√3],
        I_z = b_xyz·n_v,
        C_a = ((2b_c - I_z) - √((2b_c - I_z)² - 3(b_c² - |b_xyz|²))) / 3,
        C_d = |b_xyz - C_a n_v|,  d = (b_xyz - C_a n_v) / C_d.
    (The slide's "C_d = ‖b_x, b_y, b_z‖ - C_a n" is a typo for the norm of the difference.)
    A negative discriminant (data not of HHD form) is clamped to 0; C_a is clamped to [0, I_z]
    and d to d·n_v ≥ min_cos.
    """
    l1 = np.asarray(l1, dtype=np.float64)
    n_v = np.asarray(n_v, dtype=np.float64)
    n_v = n_v / np.linalg.norm(n_v, axis=1, keepdims=True)
    k = 2.0 / np.sqrt(np.pi)
    r3 = np.sqrt(3.0)
    bc = k * l1[:, 0]                                                          # (N, C)
    bxyz = k / r3 * np.stack([-l1[:, 3], -l1[:, 1], l1[:, 2]], axis=1)       # (N, 3, C)
    iz = np.maximum(np.einsum("nic,ni->nc", bxyz, n_v), 0.0)
    lum = _channel_weights(l1.shape[2])
    bc_l, b_l, iz_l = bc @ lum, bxyz @ lum, iz @ lum
    p_ = 2.0 * bc_l - iz_l
    disc = np.maximum(p_ * p_ - 3.0 * (bc_l * bc_l - (b_l * b_l).sum(axis=1)), 0.0)
    ca = np.clip((p_ - np.sqrt(disc)) / 3.0, 0.0, iz_l)
    dvec = b_l - ca[:, None] * n_v
    length = np.linalg.norm(dvec, axis=1)
    d = np.where(length[:, None] > 1e-12 * np.maximum(iz_l, 1e-300)[:, None],
                 dvec / np.maximum(length, 1e-300)[:, None], n_v)
    d = _clamp_to_cone(d, n_v, min_cos)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(iz_l > 0.0, ca / iz_l, 1.0)
    return HHDParams(irradz=iz, ambient_weight=np.clip(w, 0.0, 1.0), direction=d, model="hhd",
                     invalid=np.zeros(len(n_v), bool), clamped_irradz=np.zeros(len(n_v), bool))


def _clamp_to_cone(d: np.ndarray, n_v: np.ndarray, min_cos: float) -> np.ndarray:
    """Tilt directions with d·n_v < min_cos up to d·n_v = min_cos, keeping their azimuth."""
    cos = np.einsum("ni,ni->n", d, n_v)
    tangent = d - cos[:, None] * n_v
    tl = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.where(tl > 1e-12, tangent / np.maximum(tl, 1e-300), _sh.tangent_frames(n_v)[:, :, 0])
    clamped = min_cos * n_v + np.sqrt(1.0 - min_cos ** 2) * tangent
    return np.where((cos < min_cos)[:, None], clamped, d)
