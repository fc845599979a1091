"""H-basis (Habel & Wimmer 2010) encodings of irradiance: the math `hbasis_l1` (4 coefficients)
and `hbasis_l2` (6) share. No bpy.

The H-basis is orthonormal over the upper hemisphere (z ≥ 0) of the tangent frame of n_v
(`basis.frames`). With (x, y, z) a unit direction in that frame, in the sign convention of
our SH (docs/conventions.md#sh-basis), as Baking Lab writes them:

    H0 = 1/√(2π)
    H1 = −√(3/(2π)) y        H2 = √(3/(2π)) (2z − 1)        H3 = −√(3/(2π)) x
    H4 = √(15/(2π)) x y      H5 = ½ √(15/(2π)) (x² − y²)

(Baking Lab's shader evaluates H4 with ½√(15/(2π)), whose norm over the hemisphere is ½, not
1; here it is normalised, which `tests/test_encodings_basis.py` checks by quadrature.)

Encoding, as Baking Lab's H4/H6 bakers do: the irradiance SH (radiance SH × 1, 2/3, 1/4, in the
tangent frame) projected onto the H-basis over the hemisphere,
    h_i = ∫_{Ω+} H_i(ω) E(ω) dω = Σ_j M_ij e_j,    M_ij = ∫_{Ω+} H_i Y_j dω,
M computed once by a quadrature exact for these polynomials (Gauss–Legendre in z, uniform in
φ); reconstruction I(n) = Σ_i h_i H_i(n_t), n_t = n in the tangent frame: the least-squares
fit of the L2 irradiance over the hemisphere in the span of the first K functions. No specular.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .. import sh as _sh
from .basis import CoefficientEncoding, frames, layers, to_frame
from .spec import FileSpec

_K1 = np.sqrt(3.0 / (2.0 * np.pi))
_K2 = np.sqrt(15.0 / (2.0 * np.pi))


def evaluate(d: np.ndarray) -> np.ndarray:
    """The 6 H-basis functions at unit directions `d (N, 3)` in the tangent frame -> `(N, 6)`."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack(
        [
            np.full_like(x, 1.0 / np.sqrt(2.0 * np.pi)),
            -_K1 * y,
            _K1 * (2.0 * z - 1.0),
            -_K1 * x,
            _K2 * x * y,
            0.5 * _K2 * (x * x - y * y),
        ],
        axis=-1,
    )


def hemisphere_rule(nz: int = 12, nphi: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Directions `(M, 3)` and weights `(M,)` integrating polynomials of degree ≤ 2·nz − 1 in z
    (and trigonometric ones of order < nphi in φ) over the upper hemisphere exactly."""
    t, w = np.polynomial.legendre.leggauss(nz)
    z, wz = 0.5 * (t + 1.0), 0.5 * w
    phi = 2.0 * np.pi * np.arange(nphi) / nphi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1.0 - zz * zz)
    d = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    return d, np.repeat(wz * 2.0 * np.pi / nphi, nphi)


@lru_cache(maxsize=1)
def sh_to_h() -> np.ndarray:
    """M `(6, 9)`: M_ij = ∫_{Ω+} H_i Y_j dω (tangent frame)."""
    d, w = hemisphere_rule()
    return (evaluate(d) * w[:, None]).T @ _sh.evaluate(d)


class HBasis:
    """H-basis with `count` functions (4: L1, 6: L2)."""

    SPECULAR = False

    def __init__(self, count: int):
        self.count = count
        self.name = f"hbasis_l{1 if count == 4 else 2}"

    def coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> np.ndarray:
        irr_local = _sh.to_local(_sh.convolve_cosine(np.asarray(sh, np.float64)), frames(n_v))
        return np.einsum("ij,njc->nic", sh_to_h()[: self.count], irr_local)

    def irradiance(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray) -> np.ndarray:
        h = evaluate(to_frame(frames(n_v), np.asarray(n, np.float64)))[:, : self.count]
        return np.einsum("nk,nkc->nc", h, c)

    def specular(self, c, n_v, n, v, alpha, f0=1.0):
        raise NotImplementedError("the H-basis holds irradiance only: no specular")


MEANING = "H-basis coefficient i of the irradiance over n_v's tangent-frame hemisphere (docs/format.md), RGB"


def file_of(count: int, key: str) -> FileSpec:
    return FileSpec(key, f"_{key}.exr", layers("H", count, MEANING, key))


def encoding_of(basis: HBasis, file: FileSpec, settings) -> CoefficientEncoding:
    return CoefficientEncoding(basis, file, {"model": settings.model})
