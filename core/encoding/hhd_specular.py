"""GGX specular from HHD / AHD parameters: what a shader reflects towards the viewer. No bpy.

(In core/encoding, not core/hhd, beside the GGX table it reads: core.hhd sits below encoding.)

Neither source paper gives a specular evaluation (the 2018 brief only says glossy reflectance
"can also be handled"); this module evaluates the lights the model itself describes
(docs/conventions.md#hhd-model), in the units of `core.encoding.ggx` (the `Basis.specular`
contract: S = ∫ L f cos dω, radiance, F0 = 1 GGX unless given):

    C_a = w_a I_z                    C_d = (1 − w_a) I_z / max(d·n_v, MIN_COS/2)
    S   = π C_d f(d, v) max(n·d, 0)                    the directional light along d (exact)
        + C_a E(n·v, α, F0) · V                        the ambient part

E is the GGX directional albedo ∫_{Ω+(n)} f cos dω (= F0·A + B, the DC coefficient of the GGX
lobe's SH table, `ggx.table()[..., 0, :] / Y00`). AHD's ambient is uniform radiance C_a: V = 1,
exact. HHD's is a hemisphere light of radiance C_a around n_v: V is the fraction of the
specular lobe above n_v's horizon, approximated (fitted here against quadrature over
α ∈ [0.02, 1], random n in n_v's hemisphere and v in n's: RMS 0.07 of the fraction, worst 0.24)
by

    V = saturate(½ + ½ max(1, 0.4/α) · (m·n_v)),   m = normalize(lerp(r, n, α)),  r = reflect(−v, n)

m is the lobe's dominant direction, bent from the mirror direction towards n as α grows; for
α ≥ 0.4, V = (1 + m·n_v)/2, the hemisphere light's own cosine-weighted fraction. The errors of
the whole model against quadrature of analytic fields are in bench/results/encodings_basis.md.
"""

from __future__ import annotations

import numpy as np

from .. import sh as _sh
from ..hhd.lobes import MIN_COS, HHDParams
from . import ggx

#: V's steepness: max(1, VISIBILITY_SLOPE / α).
VISIBILITY_SLOPE = 0.4


def directional_albedo(nv: np.ndarray, alpha, f0=1.0) -> np.ndarray:
    """E(n·v, α, F0) = ∫ f(ω, v) max(n·ω, 0) dω `(N,)` (F0 scalar or `(N,)`), from the GGX lobe
    table (bilinear in n·v and √α, as `ggx.lobe_sh`)."""
    nv = np.asarray(nv, np.float64)
    alpha = np.broadcast_to(np.asarray(alpha, np.float64), nv.shape)
    return ggx.lobe_sh(nv, alpha, f0)[:, 0] / _sh.Y00


def hemisphere_visibility(n: np.ndarray, v: np.ndarray, n_v: np.ndarray, alpha) -> np.ndarray:
    """V `(N,)`: the approximate fraction of the GGX lobe at (n, v) above n_v's horizon."""
    alpha = np.broadcast_to(np.asarray(alpha, np.float64), (len(n),))[:, None]
    r = 2.0 * np.sum(n * v, -1, keepdims=True) * n - v
    m = (1.0 - alpha) * r + alpha * n
    m = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
    slope = np.maximum(1.0, VISIBILITY_SLOPE / alpha[:, 0])
    return np.clip(0.5 + 0.5 * slope * np.sum(m * n_v, -1), 0.0, 1.0)


def specular(p: HHDParams, n_v, n, v, alpha, f0=1.0, model: str | None = None) -> np.ndarray:
    """S(n, v; α, F0) `(N, C)` of encoded texels at unit shading normals n and view directions v
    `(N, 3)` (v from the surface to the viewer, world space), GGX α (scalar or `(N,)`), F0
    scalar or `(N,)`; model defaults to p.model. Zero where n·v ≤ 0."""
    model = model or p.model
    n_v = np.asarray(n_v, np.float64)
    n_v = n_v / np.linalg.norm(n_v, axis=1, keepdims=True)
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    alpha = np.broadcast_to(np.asarray(alpha, np.float64), (len(n),))
    w = p.ambient_weight if p.ambient_weight.ndim == 2 else p.ambient_weight[:, None]
    d = p.direction
    dz = np.maximum(np.einsum("ni,ni->n", d, n_v), MIN_COS * 0.5)[:, None]
    c_d = (1.0 - w) * p.irradz / dz
    c_a = w * p.irradz
    f0 = np.broadcast_to(np.asarray(f0, np.float64), (len(n),))
    lobe = ggx.brdf_cos(d, v, n, alpha, f0)  # (N,)
    nv = np.sum(n * v, -1)
    ambient = directional_albedo(np.maximum(nv, 0.0), alpha, f0) * (nv > 0.0)
    if model == "hhd":
        ambient = ambient * hemisphere_visibility(n, v, n_v, alpha)
    elif model != "ahd":
        raise ValueError(f"model must be 'hhd' or 'ahd', not {model!r}")
    return np.pi * c_d * lobe[:, None] + c_a * ambient[:, None]
