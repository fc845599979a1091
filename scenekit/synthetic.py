"""Synthetic lighting environments as hemisphere-sampled radiance SH, for tests, benchmarks and
the demo. No bpy.

Each environment is a radiance function L(ω) over world directions (Z up) plus optional delta
lights. `hemisphere_sh` integrates L·Y over the hemisphere of each normal by quadrature in the
normal's own frame (smooth integrand, no mask seam), which is what a converged lightmap bake
stores: radiance over the hemisphere of n_v only, zero below.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hhd_lightmapper.core import sh as _sh
from hhd_lightmapper.core.hhd import hemisphere_quadrature


@dataclass
class DeltaLight:
    """A light from one direction (sun, small distant source).

    direction (3,) unit, towards the light; irradiance (3,) RGB: the irradiance
    (docs/conventions.md#irradiance-units, E = (1/π)∫ L cos) it gives a surface facing it. Its
    radiance SH is π E Y(direction).
    """

    direction: np.ndarray
    irradiance: np.ndarray


@dataclass
class Environment:
    name: str
    radiance: Callable[[np.ndarray], np.ndarray]  # (K, 3) world dirs -> (K, 3) RGB radiance
    lights: list = field(default_factory=list)


def hemisphere_sh(
    env: Environment, normals: np.ndarray, n_z: int = 32, n_phi: int = 64, chunk: int = 2048
) -> np.ndarray:
    """Radiance SH `(N, 9, 3)` of `env` integrated over the hemisphere of each normal `(N, 3)`."""
    normals = np.asarray(normals, dtype=np.float64)
    local, wq = hemisphere_quadrature(n_z, n_phi)
    out = np.zeros((len(normals), 9, 3))
    for s in range(0, len(normals), chunk):
        frames = _sh.tangent_frames(normals[s : s + chunk])
        world = np.einsum("nij,qj->nqi", frames, local)  # (n, K, 3)
        flat = world.reshape(-1, 3)
        rad = env.radiance(flat).reshape(world.shape[0], -1, 3)
        y = _sh.evaluate(flat).reshape(world.shape[0], -1, 9)
        out[s : s + chunk] = np.einsum("nqk,nqc,q->nkc", y, rad, wq)
    for light in env.lights:
        l = np.asarray(light.direction, dtype=np.float64)
        l = l / np.linalg.norm(l)
        visible = (normals @ l) > 0.0
        out += (
            visible[:, None, None]
            * (np.pi * _sh.evaluate(l[None])[0][:, None] * np.asarray(light.irradiance)[None, :])[None]
        )
    return out


def sky(sun_elevation_deg: float, sun_azimuth_deg: float = 30.0, sun_irradiance=(8.0, 7.2, 6.0)) -> Environment:
    """Blue sky brightening to the horizon, a dim brown ground, and a sun (delta light)."""

    def radiance(d):
        z = d[:, 2]
        up = np.clip(z, 0.0, 1.0)[:, None]
        sky_col = np.array([0.25, 0.45, 1.0]) * (0.6 + 0.8 * (1.0 - up))
        ground = np.array([0.12, 0.09, 0.06]) * np.ones_like(up)
        return np.where(z[:, None] >= 0.0, sky_col, ground)

    e, a = np.radians(sun_elevation_deg), np.radians(sun_azimuth_deg)
    sun = DeltaLight(
        np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]),
        np.asarray(sun_irradiance, dtype=np.float64),
    )
    return Environment(f"sky+sun {sun_elevation_deg:g}°", radiance, [sun])


def interior() -> Environment:
    """A room seen from its middle: a bright window on the +x wall, warm lamp area on the
    ceiling, dim coloured walls, a darker floor."""

    def radiance(d):
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        out = np.where((z < -0.3)[:, None], [0.08, 0.07, 0.06], [0.18, 0.17, 0.15])
        out = np.where(((y > 0.6) & (z > -0.3))[:, None], [0.30, 0.08, 0.06], out)  # red wall
        window = (x > 0.8) & (np.abs(y) < 0.45) & (z > -0.1) & (z < 0.5)
        out = np.where(window[:, None], [6.0, 7.0, 9.0], out)
        lamp = z > 0.93
        return np.where(lamp[:, None], [12.0, 9.0, 6.0], out)

    return Environment("interior", radiance)


def random_smooth(seed: int, lmax: int = 3, contrast: float = 1.5) -> Environment:
    """exp of a random band-limited function: positive, smooth, with a random dominant lobe."""
    rng = np.random.default_rng(seed)
    terms = [(l, m) for l in range(lmax + 1) for m in range(-l, l + 1)]
    coeffs = rng.normal(size=(len(terms), 3)) * contrast / np.sqrt(len(terms))
    coeffs[1:4] += rng.normal(size=(3, 1)) * contrast  # a lobe shared by the channels

    def radiance(d):
        basis = np.stack([_ylm_vec(l, m, d) for l, m in terms], axis=1)
        return np.exp(basis @ coeffs - contrast)

    return Environment(f"random smooth #{seed}", radiance)


def _ylm_vec(l: int, m: int, d: np.ndarray) -> np.ndarray:
    """Real SH Y_l^m for many directions (vectorised twin of sh_reference.y_lm, l ≤ 4)."""
    from math import factorial

    z = np.clip(d[:, 2], -1.0, 1.0)
    phi = np.arctan2(d[:, 1], d[:, 0])
    am = abs(m)
    p = np.polynomial.legendre.Legendre.basis(l).deriv(am)(z) * (1.0 - z * z) ** (am / 2.0) * (-1.0) ** am
    k = np.sqrt((2 * l + 1) / (4 * np.pi) * factorial(l - am) / factorial(l + am))
    if m > 0:
        return np.sqrt(2.0) * k * np.cos(m * phi) * p
    if m < 0:
        return np.sqrt(2.0) * k * np.sin(am * phi) * p
    return k * p


def benchmark_set() -> list[Environment]:
    """The environments the encoder bench and tests sweep."""
    return [sky(e) for e in (5.0, 20.0, 45.0, 80.0)] + [interior()] + [random_smooth(s) for s in range(3)]


def random_normals(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)
