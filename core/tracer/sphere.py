"""The probe estimator: one pass's radiance SH over the whole sphere at points in space. No bpy.

Estimator. For each probe, k directions ω uniform over the sphere in two halves of k/2, each
stratified over the whole sphere (one direction per cell of an equal-area grid in (cos θ, φ),
jittered), and the radiance L arriving along ω from `paths.Paths.radiance` at the probe's
position. Each half h estimates the radiance SH as (4π/(k/2)) Σ (L(ω) − β_h) Y(ω) + β_h ∫Y, with
β_h the mean radiance of the *other* half (independent of h's samples: unbiased; ∫Y = 2√π for
Y00, 0 for the higher bands), and the estimate is their mean: every coefficient of finite
variance, a constant sky reproduced exactly. Lights are added by next-event estimation at
the probe as at a texel (one shadow ray per light per sample, MIS-weighted against the uniform
sphere density for lights rays can reach), over the whole sphere. Light sets: 3 columns per set
(`paths.TraceScene.channels`), as the texel estimator.

Validity (`back_face_fraction`): the share of a probe's first hits that land on the back of a
triangle; a probe inside a closed mesh or behind a wall's modelled side sees mostly back faces.
"""

from __future__ import annotations

import numpy as np

from . import hemisphere_kernels, shipping
from .paths import Paths, TraceScene, take_rows
from .scheduler import UnitResult, WorkUnit

UNIFORM_SPHERE_PDF = 1.0 / (4.0 * np.pi)


def sphere_directions(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """`(n·k, 3)` unit directions, k per group of n, each group's stratified over k equal-area
    cells (rows of cos θ × columns of φ, as square as k allows) and jittered within them."""
    rows = max(int(np.sqrt(k / 2.0)), 1)
    while k % rows:
        rows -= 1
    cols = k // rows
    cell = np.arange(k)
    u = (cell // cols + rng.random((n, k))) / rows
    v = (cell % cols + rng.random((n, k))) / cols
    z = 1.0 - 2.0 * u
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * v
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1).reshape(n * k, 3)


class ProbeEstimator(shipping.Shipped):
    """Traces work units of probes at `positions` (N, 3) world space in `scene`, `pass_samples`
    directions per probe each. Picklable (`shipping.Shipped`)."""

    def __init__(self, positions: np.ndarray, scene: TraceScene, pass_samples: int):
        self.positions = np.asarray(positions, dtype=np.float64)
        self.scene = scene
        self.pass_samples = pass_samples

    def trace(self, unit: WorkUnit) -> UnitResult:
        """Radiance SH estimate `(len(unit.texels), 9, C)` of the unit's probes (`unit.texels`
        indexes `positions`) from one pass, with its own generator seeded by (seed, pass, chunk)."""
        rng = np.random.default_rng([unit.seed, unit.pass_index, unit.chunk])
        paths = Paths(self.scene)
        k = self.pass_samples
        n = len(unit.texels)
        origins = np.repeat(self.positions[unit.texels], k, axis=0)
        dirs = sphere_directions(rng, 2 * n, k // 2)  # probe i's halves: groups 2i and 2i + 1
        pdf = np.full(len(dirs), UNIFORM_SPHERE_PDF)
        radiance = paths.radiance(rng, origins, dirs, pdf)  # (n·k, C)
        out = project_sphere(dirs, radiance, n, k)
        self._direct(paths, rng, origins, k, out)
        return UnitResult(out, paths.traced)

    def _direct(self, paths: Paths, rng, origins: np.ndarray, k: int, out: np.ndarray) -> None:
        """Next-event estimation at the probes: one shadow ray per light sampled
        (`Paths.light_samples`: one of the point, spot and area lights) from each sample's origin, projected to SH over the whole sphere into `out` (n, 9, C), in place."""
        samples = paths.light_samples(rng, origins, lambda w: np.full(len(w), UNIFORM_SPHERE_PDF))
        for (dirs, value, dist), chose, c in samples:
            weight = np.zeros(len(origins))
            rows = slice(None) if chose is None else np.flatnonzero(chose)
            weight[rows] = paths.unoccluded(origins[rows], dirs[rows], dist[rows]) * (1.0 / k)
            hemisphere_kernels.get().accumulate_grouped(dirs, value, weight, k, out[:, :, c : c + 3])


def project_sphere(dirs: np.ndarray, radiance: np.ndarray, n: int, k: int) -> np.ndarray:
    """Radiance SH `(n, 9, C)` of n probes' k samples each (directions `(n·k, 3)`, radiance
    `(n·k, C)`, two halves of k/2 uniform directions per probe), each half with the other half's
    mean radiance as control variate (see the module doc)."""
    from .. import sh as _sh

    h = k // 2
    y = _sh.evaluate(dirs).reshape(n, 2, h, 9)
    radiance = radiance.reshape(n, 2, h, -1)
    beta = radiance.mean(axis=2)[:, ::-1]  # (n, 2, C): each half's β is the other half's mean
    out = np.einsum("nshc,nshm->nmc", radiance - beta[:, :, None, :], y) * (4.0 * np.pi / h) / 2.0
    out[:, 0] += beta.mean(axis=1) * (2.0 * np.sqrt(np.pi))
    return out


def back_face_fraction(scene: TraceScene, positions: np.ndarray, rays: int, seed: int) -> np.ndarray:
    """(N,) share of `rays` stratified directions from each of `positions` (N, 3) whose first
    hit is the back of a triangle (geometric normal facing away from the ray's origin); rays
    that escape count as front."""
    rng = np.random.default_rng([seed, 0x9B0BE])
    n = len(positions)
    origins = np.repeat(np.asarray(positions, dtype=np.float64), rays, axis=0)
    dirs = sphere_directions(rng, n, rays)
    _, prim, ng = scene.rays.intersect(origins, dirs)
    hit = np.flatnonzero(prim >= 0)
    back = np.zeros(len(dirs), bool)
    back[hit] = np.einsum("ri,ri->r", take_rows(ng, hit), take_rows(dirs, hit)) > 0.0
    return back.reshape(n, rays).mean(axis=1)
