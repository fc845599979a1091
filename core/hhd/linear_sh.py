"""HHD ↔ world-space linear (L1) radiance SH, in closed form: runtime blending of light sets
(2024 paper, "HHD and linear SH"). No bpy."""

from __future__ import annotations

import numpy as np

from .. import sh as _sh
from .fit import channel_weights
from .lobes import MIN_COS, HHDParams


def to_linear_sh(p: HHDParams, n_v) -> np.ndarray:
    """World-space linear radiance SH `(N, 4, C)` of the HHD lighting (hemisphere light of
    radiance C_a around n_v + directional light of irradiance C_d = (1 − w_a) I_z / max(d·n_v,
    MIN_COS/2) along d, the floor as in `reconstruct`):
        √π/2 [2C_a + C_d, -√3 b_y, √3 b_z, -√3 b_x],  b = C_a n_v + C_d d."""
    n_v = np.asarray(n_v, dtype=np.float64)
    n_v = n_v / np.linalg.norm(n_v, axis=1, keepdims=True)
    w = p.ambient_weight if p.ambient_weight.ndim == 2 else p.ambient_weight[:, None]
    # floored as `reconstruct` floors it: a filtered or quantised d may reach the horizon
    dz = np.maximum(np.einsum("ni,ni->n", p.direction, n_v), MIN_COS * 0.5)[:, None]
    ca = w * p.irradz
    cd = (1.0 - w) * p.irradz / dz
    b = ca[:, None, :] * n_v[:, :, None] + cd[:, None, :] * p.direction[:, :, None]  # (N,3,C)
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
    bc = k * l1[:, 0]  # (N, C)
    bxyz = k / r3 * np.stack([-l1[:, 3], -l1[:, 1], l1[:, 2]], axis=1)  # (N, 3, C)
    iz = np.maximum(np.einsum("nic,ni->nc", bxyz, n_v), 0.0)
    lum = channel_weights(l1.shape[2])
    bc_l, b_l, iz_l = bc @ lum, bxyz @ lum, iz @ lum
    p_ = 2.0 * bc_l - iz_l
    disc = np.maximum(p_ * p_ - 3.0 * (bc_l * bc_l - (b_l * b_l).sum(axis=1)), 0.0)
    ca = np.clip((p_ - np.sqrt(disc)) / 3.0, 0.0, iz_l)
    dvec = b_l - ca[:, None] * n_v
    length = np.linalg.norm(dvec, axis=1)
    d = np.where(
        length[:, None] > 1e-12 * np.maximum(iz_l, 1e-300)[:, None], dvec / np.maximum(length, 1e-300)[:, None], n_v
    )
    d = clamp_to_cone(d, n_v, min_cos)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(iz_l > 0.0, ca / iz_l, 1.0)
    return HHDParams(
        irradz=iz,
        ambient_weight=np.clip(w, 0.0, 1.0),
        direction=d,
        model="hhd",
        invalid=np.zeros(len(n_v), bool),
        clamped_irradz=np.zeros(len(n_v), bool),
    )


def clamp_to_cone(d: np.ndarray, n_v: np.ndarray, min_cos: float) -> np.ndarray:
    """Tilt directions `(N, 3)` with d·n_v < min_cos up to d·n_v = min_cos, keeping their azimuth."""
    cos = np.einsum("ni,ni->n", d, n_v)
    tangent = d - cos[:, None] * n_v
    tl = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.where(tl > 1e-12, tangent / np.maximum(tl, 1e-300), _sh.tangent_frames(n_v)[:, :, 0])
    clamped = min_cos * n_v + np.sqrt(1.0 - min_cos**2) * tangent
    return np.where((cos < min_cos)[:, None], clamped, d)
