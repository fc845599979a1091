"""The fit of HHD / AHD to one texel's SH at a given direction: Gram-weighted error and the
closed-form, clamped w_a, evaluated quickly at many directions. No bpy.

With a = SH of the ambient lobe, d = SH of the directional lobe (both 1 at z = n_v), i the SH
irradiance (target) and G the hemisphere or sphere Gram matrix, the error of w is
    E(w) = ‖I_z (d + w (a - d)) - i‖²_G,
a quadratic in w minimised by w = (a-d)ᵀG(i - I_z d) / (I_z (a-d)ᵀG(a-d)) — the 2024 paper's
formula with its i/r_0 corrected to i/I_z. The 2018 paper's non-negativity (C_a ≥ 0, C_d ≥ 0)
is exactly 0 ≤ w ≤ 1 here, and for a 1D convex quadratic clamping the minimiser is the
constrained optimum.
"""

from __future__ import annotations

import numpy as np

from .. import sh as _sh
from ..colour import LUMINANCE
from .lobes import FUNCTION_OF_COEFF, irradz, phi_factors, theta_functions


def channel_weights(c: int) -> np.ndarray:
    """`(C,)` weights combining per-channel errors: Rec.709 luminance for RGB, else equal."""
    return LUMINANCE if c == 3 else np.full(c, 1.0 / c)


class Fit:
    """Per-texel quantities for evaluating the objective E(w*(θ, φ)) quickly at any direction.

    Channels K: 1 (luminance fit) or C (per-channel fit); `weights (K,)` combine the channels'
    errors into the direction's objective. Targets are normalised per texel by the caller so
    the search behaves identically for radiance 1e-8 and 1e8.

    Speed: the directional lobe's coefficients factor as d_j = f_j(θ) g_j(φ) (`theta_functions`,
    `phi_factors`), so for a fixed φ per texel (`at_phi`) every product with G, a and the
    target is precomputed once, and each θ evaluation is a few dozen vector operations.
    """

    def __init__(
        self,
        target: np.ndarray,
        iz: np.ndarray,
        a: np.ndarray,
        g: np.ndarray,
        weights: np.ndarray,
        scale: np.ndarray | None = None,
    ):
        self.scale = np.ones(len(iz)) if scale is None else scale  # per-texel normalisation undone by fit_error
        self.g = g
        self.ga = g @ a
        self.aga = float(a @ self.ga)
        self.iz = iz  # (N, K)
        self.gt = np.einsum("ij,njk->nik", g, target)  # (N, 9, K)
        self.tgt = np.einsum("njk,njk->nk", target, self.gt)
        self.gat = np.einsum("j,njk->nk", self.ga, target)
        self.weights = weights
        self.black = iz <= 0.0
        self.pairs = [
            (i, j, g[i, j] * (1.0 if i == j else 2.0)) for i in range(9) for j in range(i, 9) if g[i, j] != 0.0
        ]

    def at_phi(self, phi: np.ndarray) -> FitAtPhi:
        return FitAtPhi(self, phi)

    def evaluate(self, theta: np.ndarray, phi: np.ndarray):
        return self.at_phi(phi).evaluate(theta)


class FitAtPhi:
    """`Fit` with φ fixed per texel: evaluate(θ) -> (objective (N,), w (N, K)).

    Products with G, a and the target are grouped by θ-function (and pair of θ-functions for
    dᵀGd) once here, so an evaluation costs ~50 vector operations.
    """

    def __init__(self, fit: Fit, phi: np.ndarray):
        g = phi_factors(phi)
        self.fit = fit
        n_fn = 6
        self.hg = [0.0] * n_fn  # Σ g_j (G t)_j by function
        self.ag = [0.0] * n_fn  # Σ g_j (G a)_j by function
        for j in range(9):
            f = FUNCTION_OF_COEFF[j]
            self.hg[f] = self.hg[f] + g[j] * fit.gt[:, j, :].T  # (K, N)
            self.ag[f] = self.ag[f] + g[j] * fit.ga[j]
        pairs: dict[tuple, np.ndarray] = {}
        for i, j, coef in fit.pairs:
            key = tuple(sorted((FUNCTION_OF_COEFF[i], FUNCTION_OF_COEFF[j])))
            pairs[key] = pairs.get(key, 0.0) + coef * g[i] * g[j]
        self.pairs = list(pairs.items())

    def evaluate(self, theta: np.ndarray):
        fit = self.fit
        f = theta_functions(theta)
        dgt = sum(fi * h for fi, h in zip(f, self.hg)).T  # dᵀG t, (N, K)
        agd = sum(fi * h for fi, h in zip(f, self.ag))  # aᵀG d
        dgd = sum(coef * (f[i] * f[j]) for (i, j), coef in self.pairs)  # dᵀG d
        q = (fit.aga - 2.0 * agd + dgd)[:, None]  # (a-d)ᵀG(a-d)
        iz = fit.iz
        b = fit.gat - dgt - iz * (agd - dgd)[:, None]  # (a-d)ᵀG (t - I_z d)
        c = fit.tgt - 2.0 * iz * dgt + iz * iz * dgd[:, None]  # ‖t - I_z d‖²_G
        with np.errstate(divide="ignore", invalid="ignore"):
            w = b / (iz * np.maximum(q, 1e-300))
        w = np.clip(np.where(fit.black | ~np.isfinite(w), 1.0, w), 0.0, 1.0)
        izw = iz * w
        err = np.maximum(izw * (izw * q - 2.0 * b) + c, 0.0)
        objective = np.zeros(len(err))
        for k, weight in enumerate(fit.weights):  # channel by channel, in order (as search_kernels)
            objective = objective + err[:, k] * weight
        return objective, w


def prepare(world_sh, n, *, a, g, luminance, hemisphere_sampled):
    """Set-up of a chunk of sanitised texels (`(N, 9, C)` float64 world SH, unit normals `(N, 3)`):
    (fit, frames `(N, 3, 3)`, local SH used by the fit, I_z `(N, C)` ≥ 0, clamped `(N,)` bool,
    channel weights of the fit)."""
    iz = irradz(world_sh, n, hemisphere_sampled)  # (N, C)
    clamped = (iz < 0.0).any(axis=1)
    iz = np.maximum(iz, 0.0)
    lum = channel_weights(world_sh.shape[2])
    frames = _sh.tangent_frames(n)
    if luminance:  # rotation is linear: rotate only the luminance, fit one channel
        local = _sh.to_local(world_sh @ lum, frames)[..., None]  # (N, 9, 1)
        iz_fit, weights, lum_fit = (iz @ lum)[:, None], np.ones(1), np.ones(1)
    else:
        local = _sh.to_local(world_sh, frames)  # (N, 9, C)
        iz_fit, weights, lum_fit = iz, lum, lum
    target = _sh.convolve_cosine(local)
    # Normalise each texel so the fit is scale-free (1e-8 and 1e8 behave alike, no overflow).
    scale = np.maximum(np.abs(target).max(axis=(1, 2)), iz_fit.max(axis=1))
    scale = np.where(scale > 0.0, scale, 1.0)
    fit = Fit(target / scale[:, None, None], iz_fit / scale[:, None], a, g, weights, scale)
    return fit, frames, local, iz, clamped, lum_fit
