"""The texel estimator: one pass's radiance SH over the hemisphere of each texel's n_v. No bpy.

Estimator. For each texel, directions ω over the hemisphere of n_v are drawn from the mixture
p(ω) = α/(2π) + (1 − α)·cosθ/π with α = UNIFORM_SHARE = ½, by inverting its distribution in
cosθ (`hemisphere_kernels.texel_hemisphere_rays`). Every SH coefficient then has finite variance (pure
cosine sampling gives r_0 infinite variance from the 1/cosθ weight at the horizon) while I_z
keeps most of the cosine-sampling benefit (bench/estimator.py: α ¼ lowers I_z's per-sample
variance by 5–13% and raises bands 0 and 1's by ~20%). The samples come in two independent
halves, each from the texel's own scrambled (0,2)-sequence, stratified across all of the
texel's passes (so 16 passes of 16 samples cover the hemisphere as one 256-sample net would);
so are the samples' origins and their paths' first bounce (its light samples and its next
direction: `paths.TexelSamples`), each from a sequence of its own whose order is shuffled
(`sampling.sobol_pair`), so no two pair the same strata pass after pass. bench/estimator.py
measures what each step saves.
The radiance L arriving along ω is `paths.Paths.radiance` from the sample's origin, and
Σ (L(ω) − β) Y(ω) / (K p(ω)) + β·∫Y estimates the radiance SH over the hemisphere, with a
constant β per half of the samples taken from the other half (`hemisphere_kernels.project_halves`):
unbiased, exact for constant radiance, every sample used by every coefficient.

Every sample's origin is jittered over the texel's footprint (`BakePoints.sample_origins`, the
first tries from the texel's own (0,2)-sequence across its passes too: the
texel's FOOTPRINT square over its triangle and the others overlapping it, `BakePoints.others`), so a texel is an area average as Cycles bakes it;
where geometry crosses the footprint (a wall standing on the surface: `BakePoints.crossed`), only
the part the bake point sees is averaged (samples hidden from it are replaced by visible ones),
so light from the far side of the wall does not leak in; samples starting on a part of the
texel a coplanar face covers receive nothing (core.bakepoints.covers).
Lights are added by next-event estimation at the bake point too: one shadow ray per light per
sample (its random numbers from the texel's own stratified sequence across all its passes,
`lights.light.TexelStream`; emitters chosen by what they bring to the texel, `lights.emitters.EmissiveTriangles`),
projected to SH along the light's direction (`hemisphere_kernels.accumulate_grouped`; a delta
light has an exact direction: an unshadowed sun adds exactly s·Y(l), no noise), MIS-weighted
against the mixture pdf for the lights rays can reach. Light from below n_v's horizon is not
part of the hemisphere's SH.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..bakepoints import BakePoints
from ..bakepoints import covers as _covers
from ..bakepoints import data as _bakepoint_data
from ..bakepoints.covers import CoverProbe
from . import hemisphere_kernels, lights, shipping
from .paths import Paths, TexelSamples, TraceScene, seed
from .scheduler import UnitResult, WorkUnit

#: α, the uniform share of the hemisphere mixture α/(2π) + (1 − α)·cosθ/π the directions are
#: drawn from.
UNIFORM_SHARE = 0.5


class TexelEstimator(shipping.Shipped):
    """Traces work units of texels of `points` in `scene`, `pass_samples` samples per texel each.
    footprint: the texel footprint origins cover (`bakepoints.data.FOOTPRINT` when built). Picklable
    (`shipping.Shipped`): the cover probe is rebuilt where it is unpickled."""

    _live = ("_covers",)

    def __init__(self, points: BakePoints, scene: TraceScene, pass_samples: int):
        self.points = points
        self.scene = scene
        self.pass_samples = pass_samples
        self.footprint = _bakepoint_data.FOOTPRINT
        self._covers = self._cover_probe()

    @property
    def covers(self) -> CoverProbe | None:
        """The cover probe for the texels flagged near_cover, or None when none is."""
        probe = shipping.lazy(self, "_covers", self._cover_probe)
        return None if probe is False else probe

    def _cover_probe(self) -> CoverProbe | Literal[False]:
        """Built over the triangles traced: the shared Embree scene's (the probe the bake points
        flagged texels with, `covers.shared_probe`), or a probe of its own over the tracer's
        scene (the same corners); False when no texel is flagged."""
        points = self.points
        if not _probed(points).any():
            return False
        if self.scene.shared_rays:
            return _covers.shared_probe(self.scene.rays, points.offset, points.mesh.positions)
        rays = self.scene.rays
        return CoverProbe(rays.local_triangles, points.offset, points.mesh.positions, origin=rays.origin)

    def trace(self, unit: WorkUnit) -> UnitResult:
        """Radiance SH estimate `(len(unit.texels), 9, C)` from one pass's samples of the unit's
        texels (C: 3 per light set, `TraceScene.channels`), with its own generator seeded by
        (seed, pass, chunk)."""
        rng = np.random.default_rng([unit.seed, unit.pass_index, unit.chunk])
        paths = Paths(self.scene)
        k = self.pass_samples
        idx = unit.texels
        # the texels' own sequences are keyed by their place in the atlas, not by their bake point:
        # a bake of some receivers (core.incremental) draws what a full bake draws for those texels
        ids = np.ascontiguousarray(self.points.texel[idx], np.int64)
        normals = self.points.normal[idx]
        dirs, pdf = self._directions(unit, ids, normals)  # (n·k, 3), (n·k,)
        texel = np.repeat(np.arange(len(idx)), k)
        origins = self._origins(rng, unit)
        uncovered = self._uncovered(paths, idx, texel, origins)
        crossed = self.points.crossed
        if crossed is not None:  # settled bake points: hidden samples are replaced
            origins = self._visible(paths, rng, idx, origins, k, crossed[idx], uncovered)
            uncovered = None
        normal = np.repeat(self.points.normal[idx], k, axis=0)  # the light samples' too (`_direct_sh`)
        radiance = paths.radiance(rng, origins, dirs, pdf, uncovered, normal, self._first_bounce(unit, ids))  # (n·k, C)
        estimate = hemisphere_kernels.get().project_halves(dirs, radiance, pdf, normals, k)
        estimate = estimate + self._direct_sh(paths, rng, idx, origins, k, uncovered, self._light_stream(unit, ids))
        return UnitResult(estimate, paths.traced)

    # Where a pass's numbers come from: each texel's own sequences, stratified across its passes
    # (`unit.pass_index · k` is the pass's first sample). scenekit/estimator_reference.py draws
    # them pass by pass instead, what bench/estimator.py measures this against.
    def _directions(self, unit: WorkUnit, ids: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hemisphere directions `(n·k, 3)` of the unit's texels (atlas ids `ids` (n,), unit
        normals (n, 3)) and their density per steradian `(n·k,)`: the mixture of UNIFORM_SHARE
        from the texels' own (0,2)-sequences (`hemisphere_kernels.texel_hemisphere_rays`)."""
        k = self.pass_samples
        return hemisphere_kernels.get().texel_hemisphere_rays(
            normals, k, ids, unit.pass_index * k, unit.seed, UNIFORM_SHARE
        )

    def _origins(self, rng: np.random.Generator, unit: WorkUnit) -> np.ndarray:
        """Sample origins `(n·k, 3)` over the unit's texels' footprints (`BakePoints.sample_origins`),
        their first tries from the texels' own (0,2)-sequences."""
        k = self.pass_samples
        return self.points.sample_origins(rng, unit.texels, k, self.footprint, unit.pass_index * k, unit.seed)

    def _first_bounce(self, unit: WorkUnit, ids: np.ndarray) -> TexelSamples:
        """Where the paths' first bounce (its light samples, its new direction) takes its numbers."""
        return TexelSamples(ids, self.pass_samples, unit.pass_index * self.pass_samples, unit.seed)

    def _light_stream(self, unit: WorkUnit, ids: np.ndarray) -> lights.light.Strata:
        """Where the light samples at the bake point take their numbers (`_direct_sh`)."""
        return lights.light.TexelStream(ids, self.pass_samples, unit.pass_index * self.pass_samples, unit.seed)

    def _visible(self, paths: Paths, rng, idx, origins, k, crossed, uncovered=None) -> np.ndarray:
        """`origins` (n·k, 3) with those hidden from their texel's bake point (a wall or a box
        side between them, in the texels `crossed` (n,) bool: `BakePoints.crossed`) or under a
        coplanar face (not `uncovered`)
        replaced by visible origins of the same texel (`hemisphere_kernels.replace_hidden`), or by the bake
        point when none is: the texel averages the part of its footprint one can see on the
        bake point's side."""
        hidden = np.zeros(len(origins), bool) if uncovered is None else ~uncovered
        rows = np.flatnonzero(np.repeat(crossed, k))
        if len(rows):
            anchor = self.points.origins(idx[rows // k])
            ray = origins[rows] - anchor
            length = np.linalg.norm(ray, axis=1)
            direction = ray / np.maximum(length, 1e-300)[:, None]
            paths.count(len(rows))
            hidden[rows] |= self.scene.rays.occluded(anchor, direction, length) & (length > 0.0)
        if not hidden.any():
            return origins
        source = hemisphere_kernels.get().replace_hidden(hidden, k, seed(rng))
        out = origins[np.maximum(source, 0)]
        none = np.flatnonzero(source < 0)
        out[none] = self.points.origins(idx[none // k])
        return out

    def _uncovered(self, paths: Paths, idx, texel, origins) -> np.ndarray | None:
        """(n·k,) bool, False for samples starting on a part of the texel a coplanar face covers
        (core.bakepoints.covers: no light reaches it, as in Cycles), probed for the texels `_probed`
        (flagged near_cover, or sampling other triangles too); None when no texel of the unit is."""
        covers = self.covers
        if covers is None:
            return None
        rows = np.flatnonzero(_probed(self.points, idx)[texel])
        if len(rows) == 0:
            return None
        paths.count(len(rows))
        uncovered = np.ones(len(origins), bool)
        uncovered[rows] = ~covers.covered(origins[rows], self.points.face_normal[idx[texel[rows]]])
        return uncovered

    def _direct_sh(self, paths: Paths, rng, idx, origins, k, uncovered, strata: lights.light.Strata) -> np.ndarray:
        """Next-event estimation at the bake point: one shadow ray per light sampled
        (`Paths.light_samples`: one of the point, spot and area lights) from each of the
        pass's k origins (those `uncovered`, if not None), projected to SH (len(idx), 9, C), each
        light into its set's columns; light arriving from below n_v's horizon is left out.
        Penumbrae average over the footprint. `strata`: where the light samples take their
        numbers (`_light_stream`)."""
        out = np.zeros((len(idx), 9, self.scene.channels))
        normal = np.repeat(self.points.normal[idx], k, axis=0)

        def mixture_pdf(w):
            return _mixture_pdf(np.einsum("ri,ri->r", w, normal))

        samples = paths.light_samples(rng, origins, mixture_pdf, strata, normals=normal)
        for (dirs, value, dist), rows, c in samples:
            allowed = rows if uncovered is None else (uncovered if rows is None else uncovered & rows)
            weight, traced = paths.shadow(origins, dirs, dist, normal, 1.0 / k, cosine=False, allowed=allowed)
            if not traced:
                continue
            hemisphere_kernels.get().accumulate_grouped(dirs, value, weight, k, out[:, :, c : c + 3])
        return out


def _probed(points: BakePoints, idx=slice(None)) -> np.ndarray:
    """(n,) bool: texels `idx` whose samples are probed for covers: those flagged near_cover,
    and those whose samples also cover other triangles (`BakePoints.others`), which the flag's
    probes (inside the texel's own triangle) do not reach."""
    flagged = points.near_cover[idx]
    if points.others is None:
        return flagged
    return flagged | (points.others[idx] >= 0).any(axis=1)


def _mixture_pdf(cos):
    """Density per steradian of the hemisphere directions (`TexelEstimator.trace`) at cosθ."""
    return np.where(cos > 0.0, UNIFORM_SHARE / (2.0 * np.pi) + (1.0 - UNIFORM_SHARE) * cos / np.pi, 0.0)
