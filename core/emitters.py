"""Light sampling of emissive triangles. No bpy.

A triangle is picked with probability ∝ its power (area × emitted luminance; emission is
two-sided, so both sides count alike), then a uniform point on it. `pdf` gives the density per
steradian seen from the shading point for any hit on an emitter, so rays that reach an emitter
by BSDF sampling can be MIS-weighted against this strategy.
"""
from __future__ import annotations

import numpy as np

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


class EmitterSampler:
    """triangles (T, 3, 3) world space; emission (T, 3) radiance (zero for non-emitters)."""

    def __init__(self, triangles: np.ndarray, emission: np.ndarray):
        self.triangles = np.asarray(triangles, np.float64)
        self.emission = np.asarray(emission, np.float64)
        cross = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        self.area = 0.5 * np.linalg.norm(cross, axis=1)
        power = self.area * np.maximum(self.emission @ _LUMINANCE, 0.0)
        self.index = np.nonzero(power > 0.0)[0]
        self.probability = np.zeros(len(self.triangles))
        if len(self.index):
            self.probability[self.index] = power[self.index] / power[self.index].sum()
        self.cdf = np.cumsum(self.probability[self.index])
        if len(self.cdf):
            self.cdf /= self.cdf[-1]
        self.normal = cross / np.maximum(2.0 * self.area, 1e-300)[:, None]

    def __bool__(self) -> bool:
        return len(self.index) > 0

    def sample(self, rng: np.random.Generator, x: np.ndarray):
        """One point per shading point x (R, 3): directions (R, 3), distances (R,), emitted
        radiance (R, 3) and the pdf per steradian (R,) (0 for a grazing or coincident point)."""
        r = len(x)
        pick = self.index[np.minimum(np.searchsorted(self.cdf, rng.random(r), side="right"), len(self.index) - 1)]
        u1, u2 = rng.random(r), rng.random(r)
        s = np.sqrt(u1)
        tri = self.triangles[pick]
        p = tri[:, 0] * (1.0 - s)[:, None] + tri[:, 1] * (s * (1.0 - u2))[:, None] + tri[:, 2] * (s * u2)[:, None]
        to = p - x
        dist = np.linalg.norm(to, axis=1)
        dirs = to / np.maximum(dist, 1e-300)[:, None]
        return dirs, dist, self.emission[pick], self.pdf(pick, dirs, dist)

    def pdf(self, prim: np.ndarray, dirs: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Density per steradian of sampling the point at distance `dist` along `dirs` on
        triangle `prim` (an emitter or not: 0 for non-emitters)."""
        cos = np.abs(np.einsum("ri,ri->r", dirs, self.normal[prim]))
        with np.errstate(divide="ignore", invalid="ignore"):
            density = self.probability[prim] / self.area[prim] * dist * dist / cos
        return np.where((cos > 1e-12) & np.isfinite(density), density, 0.0)
