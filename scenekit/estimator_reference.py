"""The texel estimator with its numbers drawn pass by pass: the reference each texel's own
sequences, stratified across all its passes, are measured against (tests/test_emitter_clusters.py,
tests/test_tracer.py, bench/estimator.py, bench/light_sampling.py). Not shipped; no bpy.

`core.tracer.hemisphere.TexelEstimator` takes four kinds of numbers from each texel's own
scrambled (0,2)-sequences, at the pass's place in them, so a texel's passes together cover its
hemisphere, footprint and lights as one long sequence would. `Independent` draws the parts
named (PARTS) pass by pass instead, everything else as the product does:

- "directions": independent directions from the same mixture density (`mixture_directions`);
- "origins": the origins' first tries a randomly shifted Hammersley set per pass
  (`BakePoints.sample_origins` without the pass's place);
- "first_bounce": the paths' first bounce from the unit's generator, as every later bounce;
- "lights": the light samples at the bake point from the unit's generator.

`used(*parts)` makes `tracer.bake` trace with it."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator

import numpy as np

from hhd_lightmapper.core import sh, tracer
from hhd_lightmapper.core.tracer import hemisphere
from hhd_lightmapper.core.tracer.scheduler import WorkUnit

PARTS = ("directions", "origins", "first_bounce", "lights")
#: A fourth key of the unit's generator seed for the independent directions, apart from the
#: generator (seed, pass, chunk) the estimator draws everything else from.
DIRECTIONS_KEY = 1


class Independent(hemisphere.TexelEstimator):
    """A TexelEstimator whose parts `independent` (of PARTS) draw their numbers pass by pass."""

    def __init__(self, points, scene, pass_samples: int, independent: frozenset[str] = frozenset(PARTS)):
        super().__init__(points, scene, pass_samples)
        unknown = set(independent) - set(PARTS)
        if unknown:
            raise ValueError(f"not a part of the estimator's numbers: {sorted(unknown)}")
        self.independent = frozenset(independent)

    def _directions(self, unit: WorkUnit, ids: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if "directions" not in self.independent:
            return super()._directions(unit, ids, normals)
        rng = np.random.default_rng([unit.seed, unit.pass_index, unit.chunk, DIRECTIONS_KEY])
        return mixture_directions(rng, normals, self.pass_samples, hemisphere.UNIFORM_SHARE)

    def _origins(self, rng: np.random.Generator, unit: WorkUnit) -> np.ndarray:
        if "origins" not in self.independent:
            return super()._origins(rng, unit)
        return self.points.sample_origins(rng, unit.texels, self.pass_samples, self.footprint)

    def _first_bounce(self, unit: WorkUnit, ids: np.ndarray):
        return None if "first_bounce" in self.independent else super()._first_bounce(unit, ids)

    def _light_stream(self, unit: WorkUnit, ids: np.ndarray):
        return 1 if "lights" in self.independent else super()._light_stream(unit, ids)  # 1: plain uniforms


@contextlib.contextmanager
def used(*parts: str) -> Iterator[None]:
    """Within: `tracer.bake` traces with `Independent` of `parts` (of PARTS; none: the
    product's numbers through the same class)."""
    old = tracer.TexelEstimator
    tracer.TexelEstimator = functools.partial(Independent, independent=frozenset(parts))
    try:
        yield
    finally:
        tracer.TexelEstimator = old


def mixture_directions(rng: np.random.Generator, normals: np.ndarray, k: int, alpha: float):
    """k independent directions per texel over the hemisphere of its unit normal (normals
    (n, 3)), from the density p(ω) = α/(2π) + (1 − α)·cosθ/π: cosθ = z inverts the
    distribution α z + (1 − α) z² of the cosine (in the form that does not cancel near 0), the
    azimuth uniform. Returns directions (n·k, 3), texel-major, and their density per steradian
    (n·k,)."""
    n = len(normals)
    u1, u2 = rng.random((2, n, k))
    root = alpha + np.sqrt(alpha * alpha + 4.0 * (1.0 - alpha) * u1)
    z = np.divide(2.0 * u1, root, out=np.zeros_like(u1), where=root > 0.0)
    r, phi = np.sqrt(np.maximum(1.0 - z * z, 0.0)), 2.0 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)  # (n, k, 3) in (t, b, n)
    dirs = np.einsum("tij,tsj->tsi", sh.tangent_frames(np.asarray(normals, np.float64)), local)
    pdf = alpha / (2.0 * np.pi) + (1.0 - alpha) * z / np.pi
    return dirs.reshape(n * k, 3), pdf.reshape(n * k)
