"""Gram matrices of the L2 SH basis over the hemisphere and over a cone. No bpy.

G_ij = ∫_D Y_i(ω) Y_j(ω) dω in the local frame (z = cone axis), D = {ω : ω_z ≥ cos α}.
The hemisphere is α = 90° (cos α = 0); the sphere is the identity (orthonormal basis).

Closed forms derived symbolically (sympy, integrating over φ then z = cos θ from cos α to 1)
and checked entry by entry against quadrature in tests/test_gram.py. The hemisphere matrix on
the 2024 slides is right; the cone matrix ("CONE MULTIPLIES" slide) has extraction typos,
with c = cos α:
  * G[0,2] (Y00·Y10) is √3/4 (1 - c²), not √5/4 (1 - c²);
  * G[1,1] = G[3,3] is (2 - 3c + c³)/4, not /2;
  * G[2,6] is √15/16 (1 + 2c² - 3c⁴), not √15/20 (...);
  * G[4,4] = G[8,8] is (1 - c)³ (3c² + 9c + 8)/16, not (1 - c)³ (8 + 3c)(3 + c)/16
    (the slide's form gives 3/2 at c = 0 instead of the hemisphere's 1/2);
  * G[5,5] is (2 - 5c³ + 3c⁵)/4, not (2 - 5c² + 3c⁴)/4;
  * G[7,7] is (2 - 5c³ + 3c⁵)/4, not (2 - 5c³ + 3c⁵)/2.
G[0,6], G[1,5], G[3,7], G[0,0], G[2,2] and G[6,6] on the slide are right.
"""

from __future__ import annotations

import numpy as np

SQRT3, SQRT5, SQRT15 = np.sqrt(3.0), np.sqrt(5.0), np.sqrt(15.0)


def cone(cos_alpha) -> np.ndarray:
    """Gram matrix over the cone of half-angle α around +z: `()` -> `(9, 9)`, `(K,)` -> `(K, 9, 9)`."""
    c = np.asarray(cos_alpha, dtype=np.float64)
    g = np.zeros(c.shape + (9, 9))
    one_m_c = 1.0 - c
    entries = {
        (0, 0): one_m_c / 2.0,
        (0, 2): SQRT3 / 4.0 * (1.0 - c * c),
        (0, 6): SQRT5 / 4.0 * c * (1.0 - c * c),
        (1, 1): one_m_c**2 * (c + 2.0) / 4.0,
        (1, 5): 3.0 * SQRT5 / 16.0 * (1.0 - c * c) ** 2,
        (2, 2): (1.0 - c**3) / 2.0,
        (2, 6): SQRT15 / 16.0 * (1.0 + 2.0 * c**2 - 3.0 * c**4),
        (3, 3): one_m_c**2 * (c + 2.0) / 4.0,
        (3, 7): 3.0 * SQRT5 / 16.0 * (1.0 - c * c) ** 2,
        (4, 4): one_m_c**3 * (3.0 * c * c + 9.0 * c + 8.0) / 16.0,
        (5, 5): (2.0 - 5.0 * c**3 + 3.0 * c**5) / 4.0,
        (6, 6): (4.0 - 5.0 * c + 10.0 * c**3 - 9.0 * c**5) / 8.0,
        (7, 7): (2.0 - 5.0 * c**3 + 3.0 * c**5) / 4.0,
        (8, 8): one_m_c**3 * (3.0 * c * c + 9.0 * c + 8.0) / 16.0,
    }
    for (i, j), value in entries.items():
        g[..., i, j] = value
        g[..., j, i] = value
    return g


def hemisphere() -> np.ndarray:
    """Gram matrix over the upper hemisphere (z ≥ 0), `(9, 9)`: the 2024 paper's G_Ω+."""
    return cone(0.0)


def sphere() -> np.ndarray:
    """Gram matrix over the whole sphere: the identity (the basis is orthonormal)."""
    return np.eye(9)
