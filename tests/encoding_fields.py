"""Analytic radiance fields over a texel's hemisphere and their quadrature references, for the
coefficient encodings' tests and bench (tests/test_encodings_basis.py, bench/encodings_basis.py).

A field is radiance L(ω) (RGB) above the hemisphere of n_v, zero below (what a lightmap texel
sees). Three: a narrow SG lobe, a sky gradient, two directional ("point-like") lights. Each
gives its L2 radiance SH by quadrature (or exactly, for the lights) and its irradiance and GGX
specular by brute-force quadrature on a dense Fibonacci sphere (or exactly, for the lights),
independently of the encodings' own integration rules.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hhd_lightmapper.core import sh
from hhd_lightmapper.core.encoding import ggx
from quadrature import cap

N_V = np.array([0.3, -0.2, 0.933])
N_V = N_V / np.linalg.norm(N_V)
COLOUR = np.array([1.0, 0.7, 0.4])


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame() -> np.ndarray:
    return sh.tangent_frames(N_V[None])[0]


def local_dir(theta_deg: float, phi_deg: float) -> np.ndarray:
    """World direction at θ from n_v, azimuth φ in n_v's tangent frame."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return _frame() @ np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@lru_cache(maxsize=1)
def dense_sphere(count: int = 150_000) -> tuple[np.ndarray, float]:
    """Fibonacci sphere `(count, 3)` and its weight 4π/count."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1), 4.0 * np.pi / count


@dataclass
class Field:
    name: str
    radiance: object = None  # callable dirs (M, 3) -> (M, 3), or None for the lights
    lights: tuple = ()  # ((direction, irradiance RGB (project unit)), ...)

    def masked(self, d: np.ndarray) -> np.ndarray:
        return self.radiance(d) * (d @ N_V > 0.0)[:, None]

    def sh(self) -> np.ndarray:
        """L2 radiance SH `(9, 3)` of the field (zero below n_v's horizon)."""
        if self.lights:
            return sum(np.pi * sh.evaluate(d[None])[0][:, None] * e[None, :] for d, e in self.lights)
        d, w = cap(0.0, 96, 192)
        d = d @ _frame().T
        return sh.project(d, self.masked(d), w)

    def irradiance(self, n: np.ndarray) -> np.ndarray:
        """(1/π) ∫ L max(n·ω, 0) dω at unit normals `(M, 3)` -> `(M, 3)`."""
        if self.lights:
            return sum(np.maximum(n @ d, 0.0)[:, None] * e[None, :] for d, e in self.lights)
        d, w = dense_sphere()
        lm = self.masked(d)
        return np.stack([w * (np.maximum(d @ m, 0.0) @ lm) for m in n]) / np.pi

    def specular(self, n: np.ndarray, v: np.ndarray, alpha: float) -> np.ndarray:
        """∫ L f(ω, v) max(n·ω, 0) dω (ggx's f, F0 = 1) -> `(M, 3)`."""
        if self.lights:
            out = 0.0
            for d, e in self.lights:
                out = out + np.pi * ggx.brdf_cos(np.broadcast_to(d, n.shape), v, n, alpha)[:, None] * e[None, :]
            return out
        d, w = dense_sphere()
        lm = self.masked(d)
        return np.stack([w * (ggx.brdf_cos(d, vi[None], ni[None], alpha) @ lm) for ni, vi in zip(n, v)])


def fields() -> list[Field]:
    mu = local_dir(35.0, 40.0)
    up = unit([0.1, 0.2, 1.0])
    return [
        Field("narrow lobe", radiance=lambda d: 4.0 * np.exp(40.0 * (d @ mu - 1.0))[:, None] * COLOUR),
        Field(
            "sky gradient",
            radiance=lambda d: (0.2 + 0.8 * np.clip(d @ up, 0.0, 1.0) ** 2)[:, None] * np.array([0.5, 0.7, 1.0]),
        ),
        Field(
            "two lights",
            lights=((local_dir(30.0, 0.0), 1.5 * COLOUR), (local_dir(60.0, 150.0), np.array([0.3, 0.5, 1.0]))),
        ),
    ]


def normals() -> np.ndarray:
    """Shading normals in n_v's hemisphere: n_v and four tilted by 30° and 60°."""
    return np.stack([N_V, local_dir(30, 10), local_dir(30, 190), local_dir(60, 100), local_dir(60, 280)])


def views(n: np.ndarray) -> np.ndarray:
    """One view per normal, 40° from it (towards a fixed azimuth)."""
    f = sh.tangent_frames(n)
    t = np.radians(40.0)
    return np.einsum("nij,j->ni", f, np.array([np.sin(t), 0.0, np.cos(t)]))


def relative_rms(estimate: np.ndarray, reference: np.ndarray) -> float:
    """RMS over rows and colours of the error, / RMS of the reference."""
    return float(np.sqrt(np.mean((estimate - reference) ** 2)) / max(np.sqrt(np.mean(reference**2)), 1e-300))
