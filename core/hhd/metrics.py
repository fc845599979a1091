"""How good an encoding is: the encoder's own objective at given directions, and the
hemispherical RMSE of what a shader reconstructs, by quadrature. No bpy."""

from __future__ import annotations

import numpy as np

from .. import sh as _sh
from .encoder import gram_matrix, sanitise
from .fit import prepare
from .lobes import MIN_COS, HHDParams, ambient_lobe
from .search import arctan2


def fit_error(
    sh,
    n_v,
    direction,
    model: str = "hhd",
    gram: str = "hemisphere",
    ambient: str = "luminance",
    *,
    hemisphere_sampled: bool = True,
):
    """The encoder's objective at given world directions `(N, 3)` (d·n_v > 0): the G-weighted
    squared error between the fitted model's L2 SH and the SH irradiance, in irradiance² units
    (luminance, or the luminance-weighted sum over channels for ambient="rgb"), and the
    optimal clamped w_a `(N,)`/`(N, C)`. For measuring the search and the d·n_v floor."""
    world_sh, n, _ = sanitise(sh, n_v)
    fit, frames, *_ = prepare(
        world_sh,
        n,
        a=ambient_lobe(model),
        g=gram_matrix(gram),
        luminance=ambient == "luminance",
        hemisphere_sampled=hemisphere_sampled,
    )
    d_local = np.einsum("nji,nj->ni", frames, np.asarray(direction, dtype=np.float64))
    theta = np.arccos(np.clip(d_local[:, 2], -1.0, 1.0))
    phi = arctan2(d_local[:, 1], d_local[:, 0])
    err, w = fit.evaluate(theta, phi)
    return err * fit.scale**2, (w[:, 0] if ambient == "luminance" else w)


def hemisphere_quadrature(n_z: int = 24, n_phi: int = 48):
    """Local-frame directions `(K, 3)` and weights `(K,)` integrating over the upper hemisphere
    (Gauss–Legendre in cosθ × uniform φ; weights sum to 2π)."""
    t, wt = np.polynomial.legendre.leggauss(n_z)
    z, wz = 0.5 * (t + 1.0), 0.5 * wt
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    s = np.sqrt(1.0 - z * z)
    dirs = np.stack(
        [np.outer(s, np.cos(phi)), np.outer(s, np.sin(phi)), np.repeat(z[:, None], n_phi, axis=1)], axis=-1
    ).reshape(-1, 3)
    weights = np.repeat(wz, n_phi) * (2.0 * np.pi / n_phi)
    return dirs, weights


def hemispherical_rmse(
    sh, n_v, p: HHDParams, model: str | None = None, *, chunk: int = 4096, quadrature=None
) -> np.ndarray:
    """RMSE `(N, C)` over the upper hemisphere of n_v between reconstruct(p) and the SH irradiance
    Y(n)·i of the radiance SH, by quadrature: sqrt( (1/2π) ∫_{Ω+} (I_model - I_SH)² dn ).

    This measures what a shader reconstructs (the exact clamped-cosine lobe), not the encoder's
    internal L2-projected objective. Invalid texels count as zero error.
    """
    world_sh, n, invalid = sanitise(sh, n_v)
    dirs, wq = quadrature or hemisphere_quadrature()
    out = np.zeros((len(n), world_sh.shape[2]))
    ybasis = _sh.evaluate(dirs) * _sh.COSINE_KERNEL  # (K, 9)
    for s in range(0, len(n), chunk):
        sl = slice(s, s + chunk)
        frames = _sh.tangent_frames(n[sl])
        local = _sh.to_local(world_sh[sl], frames)
        target = np.einsum("qk,nkc->nqc", ybasis, local)  # (n, K, C)
        d_local = np.einsum("nji,nj->ni", frames, p.direction[sl])  # Rᵀ d
        w = p.ambient_weight[sl]
        w = w[:, None, :] if w.ndim == 2 else w[:, None, None]
        dz = np.maximum(d_local[:, 2], MIN_COS * 0.5)
        lobe = np.maximum(np.einsum("qi,ni->nq", dirs, d_local), 0.0) / dz[:, None]
        amb = (1.0 + dirs[:, 2]) * 0.5 if (model or p.model) == "hhd" else np.ones(len(dirs))
        model_val = p.irradz[sl][:, None, :] * (w * amb[None, :, None] + (1.0 - w) * lobe[..., None])
        out[sl] = np.sqrt(np.einsum("q,nqc->nc", wq, (model_val - target) ** 2) / (2.0 * np.pi))
    out[invalid] = 0.0
    return out
