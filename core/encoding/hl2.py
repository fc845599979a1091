"""Half-Life 2 basis encoding (radiosity normal mapping, as Baking Lab bakes it): 3 RGB
irradiance values along three fixed tangent-space directions, file `<name>_hl2.exr`. No bpy.

Directions, in the tangent frame of n_v (`basis.frames`: columns t, b, n_v):
    b0 = (−1/√6, −1/√2, 1/√3),  b1 = (−1/√6, 1/√2, 1/√3),  b2 = (√(2/3), 0, 1/√3)
(mutually orthogonal, each 54.7° from n_v). Coefficient i, as Baking Lab's HL2 baker
accumulates it (the cosine not clamped), in the project's irradiance unit:
    H_i = (1/π) ∫_{Ω+(n_v)} L(ω) (ω·b_i) dω
It depends only on band 1 of the hemisphere radiance SH, so it is exact from the traced SH:
H_i = (b_i^world · v) / (π c₁), v = (−s₃, −s₁, s₂). Reconstruction (Baking Lab's shader):
    I(n) = Σ_i max(n_t·b_i, 0) H_i,   n_t = n in the tangent frame
which gives I_z exactly at n = n_v and for uniform radiance everywhere on the b_i. No specular
(Baking Lab offers none for this basis).
"""

from __future__ import annotations

import numpy as np

from .. import sh as _sh
from .basis import CoefficientEncoding, frames, layers, to_frame
from .spec import FileSpec

#: The basis directions in the tangent frame, rows.
DIRECTIONS = np.array(
    [
        [-1.0 / np.sqrt(6.0), -1.0 / np.sqrt(2.0), 1.0 / np.sqrt(3.0)],
        [-1.0 / np.sqrt(6.0), 1.0 / np.sqrt(2.0), 1.0 / np.sqrt(3.0)],
        [np.sqrt(2.0 / 3.0), 0.0, 1.0 / np.sqrt(3.0)],
    ]
)


class HL2Basis:
    name = "hl2"
    count = 3
    SPECULAR = False

    def coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> np.ndarray:
        sh = np.asarray(sh, np.float64)
        v = np.stack([-sh[:, 3], -sh[:, 1], sh[:, 2]], axis=1)  # (N, 3 xyz, C): ∫ L ω dω = v / c1
        b_world = np.einsum("nij,kj->nki", frames(n_v), DIRECTIONS)  # (N, 3 dirs, 3 xyz)
        return np.einsum("nki,nic->nkc", b_world, v) / (np.pi * _sh.C1)

    def irradiance(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray) -> np.ndarray:
        w = np.maximum(to_frame(frames(n_v), np.asarray(n, np.float64)) @ DIRECTIONS.T, 0.0)
        return np.einsum("nk,nkc->nc", w, c)

    def specular(self, c, n_v, n, v, alpha, f0=1.0):
        raise NotImplementedError("the HL2 basis holds irradiance only: no specular")


BASIS = HL2Basis()
FILE = FileSpec(
    "hl2",
    "_hl2.exr",
    layers("HL2_", 3, "H_i: irradiance (1/π)∫ L (ω·b_i) dω along HL2 direction b_i of n_v's tangent frame, RGB", "hl2"),
)


def basis(settings=None) -> HL2Basis:
    return BASIS


def encoding(settings) -> CoefficientEncoding:
    return CoefficientEncoding(BASIS, FILE, {"model": settings.model})
