"""The HHD / AHD model: its parameters, its two lobes in SH, I_z and the reconstruction. No bpy.

Model, with n_v the vertex normal, n the shading normal, d the highlight direction (d·n_v > 0):
    HHD  I(n) = I_z [ w_a (1 + n·n_v)/2 + (1 - w_a) max(n·d, 0) / (d·n_v) ]
    AHD  I(n) = I_z [ w_a               + (1 - w_a) max(n·d, 0) / (d·n_v) ]
i.e. C_a = w_a I_z and C_d = (1 - w_a) I_z / (d·n_v). I(n_v) = I_z exactly in both.
Irradiance is in the units of docs/conventions.md#irradiance-units: E(n) = (1/π) ∫ L max(n·ω, 0) dω.
Lobes are irradiance SH in the local frame z = n_v; the directional lobe also in the factorised
form d_j = f_j(θ) g_j(φ) the search evaluates (`theta_functions`, `phi_factors`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import sh as _sh

#: Floor on d·n_v. It bounds C_d = (1 - w_a) I_z / d_z (at most 50 I_z) and keeps d strictly in
#: the upper hemisphere; a light exactly on the horizon is then represented at θ = 88.85°
#: instead of 90° (its measured cost is in tests/test_hhd_papers.py and docs/encoder.md).
MIN_COS = 0.02


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
    invalid: np.ndarray | None = field(default=None)
    clamped_irradz: np.ndarray | None = field(default=None)

    @property
    def n_invalid(self) -> int:
        return int(np.count_nonzero(self.invalid)) if self.invalid is not None else 0


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
    factorised form (`phi_factors` × `theta_functions`); this direct form is its reference."""
    st = np.sin(theta)
    d = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)
    return _sh.evaluate(d) * (_sh.COSINE_KERNEL * np.pi) / d[..., 2:3]


def phi_factors(phi: np.ndarray) -> list:
    """g_j(φ) of the directional lobe d_j = f_j(θ) g_j(φ), with π and the cosine kernel folded in."""
    c, s = np.cos(phi), np.sin(phi)
    k1, k2 = np.pi * 2.0 / 3.0, np.pi * 0.25
    return [
        np.pi * _sh.Y00,
        -k1 * _sh.C1 * s,
        k1 * _sh.C1,
        -k1 * _sh.C1 * c,
        k2 * _sh.C2 * c * s,
        -k2 * _sh.C2 * s,
        k2 * _sh.C20,
        -k2 * _sh.C2 * c,
        k2 * _sh.C22 * (c * c - s * s),
    ]


#: The 9 lobe coefficients use 6 distinct θ-functions (see `theta_functions`).
FUNCTION_OF_COEFF = (0, 1, 2, 1, 3, 4, 5, 4, 3)


def theta_functions(theta: np.ndarray) -> list:
    """The θ-dependence of Y_j(d) / d_z, d_z = cos θ: [1/c, s/c, 1, s²/c, s, (3c²-1)/c]."""
    ct = np.cos(theta)
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))  # θ ∈ [0, π/2]; cheaper than sin
    inv = 1.0 / ct
    st_inv = st * inv
    return [inv, st_inv, 1.0, st * st_inv, st, (3.0 * ct * ct - 1.0) * inv]


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
        return _sh.hemisphere_irradz(sh, n_v)  # sh.IRRADZ_FROM_R10 · r_1^0
    return _sh.irradiance(sh, n_v)


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
