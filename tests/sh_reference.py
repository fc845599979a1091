"""Slow, obviously-correct real spherical harmonics of any band, for the tests only. No bpy.

Built from the textbook definition (associated Legendre functions with the Condon–Shortley
phase, Y_l^m = √2 K cos(mφ) P_l^m, K P_l^0, √2 K sin(|m|φ) P_l^|m|) one direction at a time in
pure Python, sharing nothing with `sh.py` so that the two can check each other.
"""

from __future__ import annotations

import math


def legendre(l: int, m: int, x: float) -> float:
    """Associated Legendre P_l^m(x), m ≥ 0, with the Condon–Shortley phase (-1)^m."""
    pmm = 1.0
    if m > 0:
        somx2 = math.sqrt(max(0.0, (1.0 - x) * (1.0 + x)))
        fact = 1.0
        for _ in range(m):
            pmm *= -fact * somx2
            fact += 2.0
    if l == m:
        return pmm
    pmmp1 = x * (2 * m + 1) * pmm
    if l == m + 1:
        return pmmp1
    pll = 0.0
    for ll in range(m + 2, l + 1):
        pll = ((2 * ll - 1) * x * pmmp1 - (ll + m - 1) * pmm) / (ll - m)
        pmm, pmmp1 = pmmp1, pll
    return pll


def y_lm(l: int, m: int, direction) -> float:
    """Real SH Y_l^m at a unit direction (x, y, z)."""
    x, y, z = (float(c) for c in direction)
    theta = math.acos(max(-1.0, min(1.0, z)))
    phi = math.atan2(y, x)
    am = abs(m)
    k = math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - am) / math.factorial(l + am))
    p = legendre(l, am, math.cos(theta))
    if m > 0:
        return math.sqrt(2.0) * k * math.cos(m * phi) * p
    if m < 0:
        return math.sqrt(2.0) * k * math.sin(am * phi) * p
    return k * p


def basis(direction, lmax: int = 2) -> list[float]:
    """All (lmax+1)² basis values in (l, m) order, m from -l to l."""
    return [y_lm(l, m, direction) for l in range(lmax + 1) for m in range(-l, l + 1)]
