"""Independent numerical integration over the sphere, hemisphere and cones, for the tests.

Product rule: Gauss–Legendre in z = cos θ over [cos α, 1] times the uniform rule in φ. It is
exact for polynomials in (x, y, z) of degree < 2·n_z in z and < n_phi in φ, so SH products up
to band 4 integrate to machine precision with the defaults; kinked integrands (clamped cosines)
converge as O(h²) and need more points.
"""

import numpy as np


def cap(cos_alpha: float = -1.0, n_z: int = 16, n_phi: int = 32):
    """Directions `(K, 3)` and weights `(K,)` for ∫ over {ω : ω_z ≥ cos_alpha}."""
    t, wt = np.polynomial.legendre.leggauss(n_z)
    z = 0.5 * (1.0 - cos_alpha) * t + 0.5 * (1.0 + cos_alpha)
    wz = 0.5 * (1.0 - cos_alpha) * wt
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(np.clip(1.0 - zz * zz, 0.0, None))
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), zz], axis=-1).reshape(-1, 3)
    weights = (wz[:, None] * np.full(n_phi, 2.0 * np.pi / n_phi)[None, :]).reshape(-1)
    return dirs, weights


def sphere(n_z: int = 16, n_phi: int = 32):
    return cap(-1.0, n_z, n_phi)


def hemisphere(n_z: int = 16, n_phi: int = 32):
    return cap(0.0, n_z, n_phi)


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniformly random proper rotations `(n, 3, 3)` (QR of Gaussian matrices)."""
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def random_dirs(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)
