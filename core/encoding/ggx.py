"""The GGX specular lobe the lightmap encodings reconstruct, and its L2 SH lookup table. No bpy.

The specular integral of a texel (radiance towards the viewer, W/(m²·sr)):

    S(n, v; α, F0) = ∫ L(ω) f(ω, v) max(n·ω, 0) dω,
    f = D(h) · G1(n·ω) G1(n·v) · F(v·h) / (4 (n·ω)(n·v)),   h = (ω + v)/|ω + v|,

with D the GGX (Trowbridge–Reitz) NDF of width α, G1 Smith's GGX masking (separable, as Baking
Lab's `GGX_V1`), F Schlick's Fresnel with reflectance F0 at normal incidence. **α is GGX's α**
(Baking Lab's "roughness"); a Blender Principled BSDF of Roughness R has α = R². n, v, ω are
unit vectors in one frame; v points from the surface to the viewer.

SH specular (`sh_specular`): the lobe g(ω) = f(ω, v) max(n·ω, 0) is projected onto L2 SH in a
frame z = n, x towards v (only the 6 coefficients even in y are non-zero), tabulated over
(n·v, √α) (`table`, computed once per process by quadrature over GGX's half-vector
distribution), rotated to world space and dotted with the radiance SH: S = Σ_k g_k s_k, exact
for radiance band-limited to L2 (up to the table's interpolation). Schlick's F is linear in F0,
so the table holds g = F0·A + B.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .. import sh as _sh

#: Table grid: n·v in [0, 1] and √α in [SQRT_ALPHA_MIN, 1], bilinear.
TABLE_NV, TABLE_ROUGH = 32, 32
SQRT_ALPHA_MIN = 0.1
#: The 6 SH coefficients a lobe in the frame (z = n, v in the +x half of the xz plane) can have.
LOBE_COEFFS = (0, 2, 3, 6, 7, 8)


def ndf(cos_h: np.ndarray, alpha) -> np.ndarray:
    """GGX D(h) for cos θ_h = n·h: α² / (π ((n·h)² (α² − 1) + 1)²), 1/sr."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    d = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * d * d)


def g1(cos_x: np.ndarray, alpha) -> np.ndarray:
    """Smith's GGX masking G1 = 2x / (x + √(α² + (1 − α²) x²)), 0 for x ≤ 0."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    x = np.maximum(cos_x, 0.0)
    return np.where(cos_x > 0.0, 2.0 * x / (x + np.sqrt(a2 + (1.0 - a2) * x * x) + 1e-300), 0.0)


def schlick(cos_vh: np.ndarray, f0) -> np.ndarray:
    """F = F0 + (1 − F0)(1 − v·h)⁵."""
    return f0 + (1.0 - f0) * (1.0 - np.clip(cos_vh, 0.0, 1.0)) ** 5


def brdf_cos(l: np.ndarray, v: np.ndarray, n: np.ndarray, alpha, f0=1.0) -> np.ndarray:
    """f(l, v) · max(n·l, 0) for unit rows l, v, n `(..., 3)` (broadcast) -> `(...)`, 1/sr;
    zero where n·l ≤ 0 or n·v ≤ 0."""
    h = l + v
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    nl, nv = np.sum(n * l, -1), np.sum(n * v, -1)
    nh, vh = np.sum(n * h, -1), np.sum(v * h, -1)
    ok = (nl > 0.0) & (nv > 0.0)
    value = ndf(nh, alpha) * g1(nl, alpha) * g1(nv, alpha) * schlick(vh, f0) / (4.0 * np.maximum(nv, 1e-300))
    return np.where(ok, value, 0.0)


def half_vector_quadrature(nv: float, alpha: float, nu: int = 96, nphi: int = 96):
    """Directions ω `(M, 3)` and weights `(M, 2)` such that Σ w[:, 0]·φ(ω) ≈ ∫ φ f cos dω with
    F = 1 − (1 − v·h)⁵ (the F0 part) and w[:, 1] the (1 − v·h)⁵ part, in the frame z = n,
    v = (√(1 − nv²), 0, nv): a midpoint grid over GGX's distribution of h (D(h) n·h), mapped to
    ω = reflect(v, h). Weight of a sample = G1(n·ω) G1(n·v) (v·h) / ((n·v)(n·h)) / M."""
    u = (np.arange(nu) + 0.5) / nu
    phi = 2.0 * np.pi * (np.arange(nphi) + 0.5) / nphi
    tan2 = alpha * alpha * u / (1.0 - u)
    cos_t = 1.0 / np.sqrt(1.0 + tan2)
    sin_t = np.sqrt(1.0 - cos_t * cos_t)
    ct, p = np.meshgrid(cos_t, phi, indexing="ij")
    st = np.sqrt(1.0 - ct * ct)
    h = np.stack([st * np.cos(p), st * np.sin(p), ct], -1).reshape(-1, 3)
    del sin_t
    nv = max(nv, 1e-4)
    v = np.array([np.sqrt(1.0 - nv * nv), 0.0, nv])
    vh = h @ v
    w = 2.0 * vh[:, None] * h - v
    nl = w[:, 2]
    g1v_over_nv = 2.0 / (nv + np.sqrt(alpha * alpha + (1.0 - alpha * alpha) * nv * nv))
    base = np.where((vh > 0) & (nl > 0), g1(nl, alpha) * g1v_over_nv * vh / h[:, 2], 0.0) / len(h)
    f5 = (1.0 - np.clip(vh, 0.0, 1.0)) ** 5
    return w, np.stack([base * (1.0 - f5), base * f5], -1)


@lru_cache(maxsize=1)
def table() -> np.ndarray:
    """`(TABLE_NV, TABLE_ROUGH, 6, 2)`: the SH coefficients LOBE_COEFFS of g(ω) = f cos in the
    frame z = n, x towards v, for n·v = i/(TABLE_NV − 1) and √α on a uniform grid from
    SQRT_ALPHA_MIN to 1; [..., 0] multiplies F0, [..., 1] is the F0-free part."""
    out = np.zeros((TABLE_NV, TABLE_ROUGH, len(LOBE_COEFFS), 2))
    for i, nv in enumerate(np.linspace(0.0, 1.0, TABLE_NV)):
        for j, ra in enumerate(np.linspace(SQRT_ALPHA_MIN, 1.0, TABLE_ROUGH)):
            w, wt = half_vector_quadrature(float(nv), float(ra * ra))
            out[i, j] = _sh.evaluate(w)[:, LOBE_COEFFS].T @ wt
    return out


def lobe_sh(nv: np.ndarray, alpha: np.ndarray, f0) -> np.ndarray:
    """The lobe's L2 SH `(N, 9)` in the frame z = n, x towards v (bilinear in the table)."""
    t = table()
    x = np.clip(nv, 0.0, 1.0) * (TABLE_NV - 1)
    y = (np.clip(np.sqrt(alpha), SQRT_ALPHA_MIN, 1.0) - SQRT_ALPHA_MIN) / (1.0 - SQRT_ALPHA_MIN) * (TABLE_ROUGH - 1)
    x0 = np.minimum(np.floor(x).astype(int), TABLE_NV - 2)
    y0 = np.minimum(np.floor(y).astype(int), TABLE_ROUGH - 2)
    fx, fy = (x - x0)[:, None, None], (y - y0)[:, None, None]
    lerp = (1 - fx) * ((1 - fy) * t[x0, y0] + fy * t[x0, y0 + 1]) + fx * (
        (1 - fy) * t[x0 + 1, y0] + fy * t[x0 + 1, y0 + 1]
    )
    f0 = np.broadcast_to(np.asarray(f0, dtype=np.float64), nv.shape)
    out = np.zeros((len(nv), 9))
    out[:, LOBE_COEFFS] = lerp[..., 0] * f0[:, None] + lerp[..., 1]
    return out


def view_frames(n: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Frames `(N, 3, 3)`, columns (x, y, z): z = n, x along v's part orthogonal to n (any
    perpendicular where v ∥ n: within 1e-6 of it, where unit vectors read from float32 data leave
    x as rounding noise along n itself, and the lobe is symmetric about n to that precision)."""
    x = v - np.sum(v * n, -1, keepdims=True) * n
    length = np.linalg.norm(x, axis=-1, keepdims=True)
    fallback = _sh.tangent_frames(n)[:, :, 0]
    x = np.where(length > 1e-6, x / np.maximum(length, 1e-300), fallback)
    return np.stack([x, np.cross(n, x), n], axis=-1)


def sh_specular(radiance_sh: np.ndarray, n: np.ndarray, v: np.ndarray, alpha, f0=1.0, bands: int = 3) -> np.ndarray:
    """S(n, v; α, F0) of world-space radiance SH `(N, 9, C)` (the first `bands` bands used:
    2 = L1, 3 = L2) at unit n, v `(N, 3)` -> `(N, C)`: Σ_k g_k s_k, g the lobe's SH rotated to
    world space."""
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    alpha = np.broadcast_to(np.asarray(alpha, np.float64), (len(n),))
    nv = np.sum(n * v, -1)
    local = lobe_sh(nv, alpha, f0)
    world = _sh.to_world(local, view_frames(n, v))
    k = bands * bands
    return np.einsum("nk,nkc->nc", world[:, :k], np.asarray(radiance_sh, np.float64)[:, :k])
