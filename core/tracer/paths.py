"""Radiance along rays: the tracer's one radiance function, and next-event estimation at
points. No bpy.

`Paths.radiance` gives the radiance arriving at any origins from sampled directions (a texel's
hemisphere, a probe's sphere, a camera's pixels: it knows nothing of texels). It is a wavefront
over bounces on compacted live arrays: rays that escape take the world's radiance (the constant
world, or the HDRI weighted by MIS), hits take the emission of the triangle they reach (MIS
against emitter sampling), and every hit adds next-event estimation (`irradiance_at`: one
shadow ray per light and vertex, the point, spot and area lights being one light chosen per
vertex: `lights.choice.Choice`), then continues diffusely (two-sided,
cosine-distributed) with Russian roulette from RR_START bounces on (survival
√(throughput / ½), none ended above ½: RR_SURVIVAL_POWER, RR_REFERENCE), at most `bounces`
reflections. The per-sample work between two Embree queries runs in `path_kernels.advance_paths`.

A path that reaches the back of a triangle goes on as from its front: surfaces are two-sided, as
in Cycles, because real scenes show their back faces to the room (single-sided planes, rooms
whose normals face outwards: README, "Leaks"). Godot's and Unity's bakers end such a path
instead (it started inside a closed mesh or behind a wall's modelled side); here the bake points
keep their samples out of solids (`bakepoints.settle`).

Light sets (`core.light_sets`): with `TraceScene.sets` the radiance has 3 columns per set (RGB of
set 0, RGB of set 1, ...) and every contribution (next-event estimation, emitters and the world
reached by rays) goes to the columns of its light's set (`Light.column`), inside the same paths:
the random numbers drawn do not depend on the sets, so the columns of a bake with sets sum to
the radiance of the same bake without them.

`TraceScene` is what paths see of one bake (picklable: the Embree scene is rebuilt in a process
that receives it); a `Paths` traces in one thread for one work unit and counts its rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import sampling
from ..errors import BakeError
from ..rays import RayScene, ray_offset
from ..scene import BakeScene, light_set_names, light_set_of
from . import lights as _lights
from . import path_kernels, shipping

RR_START = 2  # bounces before Russian roulette may end a path
#: A path survives the roulette with probability min((max(throughput) / RR_REFERENCE)^
#: RR_SURVIVAL_POWER, RR_MAX_SURVIVAL): the square root of Cycles' rule, measured against the
#: throughput's own (bright scenes' paths ended too early for the rays they saved), and a path
#: still carrying half its light or more is never ended (a weight window): under a sun and a
#: sky the default 0.8 albedo keeps the throughput at 0.64 after two hits, and ending those
#: paths cost more noise than their rays were worth (bench/roulette.py; README, "Speed vs
#: accuracy"). The paths end at `bounces` whatever the roulette does, so survival may reach 1.
RR_SURVIVAL_POWER = 0.5
RR_REFERENCE = 0.5
RR_MAX_SURVIVAL = 1.0
_BLACK = np.zeros((1, 3))  # the sky of a scene without a world (path_kernels.advance_paths)
_NO_ROWS = np.zeros((0, 3))  # no per-row albedo: the kernel takes the triangles' own
_NO_NUMBERS = np.zeros((2, 0))  # no given numbers: advance_paths draws its own
#: `Paths.light_samples`' entries: (sample, the rows that sampled it or None for all, column)
LightSample = tuple[_lights.light.Sample, np.ndarray | None, int]


class TraceScene:
    """The scene paths are traced in: scene (BakeScene), lights (`lights.build`, in sampling
    order), offset (scene units: ray origins leave surfaces by at least `min_offset` and by the
    scene's own `rays.ray_offset`), bounces (diffuse reflections after the first hit).
    light_sets: keep each light set's radiance apart (`sets`: the set names, () when the scene
    uses no light groups or light_sets is False; `channels` = 3 per set, at least 3).
    ray_scene: the Embree scene of `scene.triangles` if the caller has built it (then shared:
    `shared_rays`), else built here. It is not pickled; a process receiving this object builds
    its own on first use (`shipping.ray_scene`: once per process and triangle content)."""

    def __init__(
        self,
        scene: BakeScene,
        bounces: int,
        min_offset: float = 0.0,
        ray_scene: RayScene | None = None,
        light_sets: bool = True,
    ):
        if len(scene.triangles) == 0:
            raise BakeError("the bake scene has no geometry")
        self.scene = scene
        self.bounces = bounces
        self.shared_rays = ray_scene is not None
        self._rays: RayScene | None = ray_scene if ray_scene is not None else RayScene(scene.triangles)
        self.offset = max(min_offset, ray_offset(scene.triangles, self._rays.origin))
        self.lights = _lights.build(scene)
        groups = [light.group for light in self.lights] + ([scene.world_group] if scene.world is not None else [])
        self.sets = light_set_names(groups) if light_sets else ()
        self.channels = 3 * max(len(self.sets), 1)
        for light in self.lights:
            light.column = self.column(light.group)
        self.world_column = self.column(scene.world_group) if scene.world is not None else 0
        chosen = [light for light in self.lights if light.chosen]
        self.choice = _lights.choice.Choice(chosen) if chosen else None
        self.surface_lights = [light for light in self.lights if light.reachable and not light.at_infinity]
        self.sky_lights = [light for light in self.lights if light.reachable and light.at_infinity]

    def column(self, group: str) -> int:
        """The first of the 3 radiance columns of the light set of light group `group`."""
        return 3 * self.sets.index(light_set_of(group)) if self.sets else 0

    def per_column(self, rgb: np.ndarray) -> np.ndarray:
        """RGB rows (R, 3) repeated for every set's columns (R, channels): a path's throughput."""
        return rgb if self.channels == 3 else np.tile(rgb, (1, self.channels // 3))

    @property
    def rays(self) -> RayScene:
        return shipping.lazy(self, "_rays", lambda: shipping.ray_scene(self.scene.triangles))

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_rays"}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._rays = None


class Paths:
    """Path tracing in a TraceScene for one work unit (one thread at a time); `traced` counts
    the rays it traced."""

    def __init__(self, scene: TraceScene):
        self.scene = scene
        self.traced = 0
        self._rays = scene.rays
        self.kernels = path_kernels.get()

    def count(self, n: int) -> None:
        """Count n rays traced elsewhere for this unit (e.g. cover probes)."""
        self.traced += int(n)

    def intersect(self, o, d, tmax=None, barycentrics=False):
        self.count(len(o))
        return self._rays.intersect(o, d, tmax, barycentrics)

    def radiance(
        self,
        rng: np.random.Generator,
        origins: np.ndarray,
        dirs: np.ndarray,
        pdf: np.ndarray,
        start: np.ndarray | None = None,
        normals: np.ndarray | None = None,
        texels: TexelSamples | None = None,
    ) -> np.ndarray:
        """Radiance (R, C) arriving at `origins` from directions `dirs` (R, 3) sampled with density
        `pdf` (R,) per steradian (what the MIS weights of reachable lights are taken against):
        wavefront over bounces, the arrays compacted to the live paths. `start` (R,) bool, if
        given: only those paths are traced (the others receive nothing). `normals` (R, 3), if
        given: the origins' normals, as the light samples taken there got them (the emitters'
        density depends on them: `lights.emitters.EmissiveTriangles`). C = `TraceScene.channels`
        (3 per light set). `texels`, if given: whose samples the rows are; the paths' first
        bounce (its light samples and its new direction) then takes its numbers from each
        texel's own sequences, stratified across its passes. Each live path gathers
        into its own row of `acc` (compacted with it), written out once when the path ends:
        cheaper than scattering into the (R, 3) result every bounce."""
        ts = self.scene
        scene = ts.scene
        radiance = np.zeros((len(origins), ts.channels))
        if start is None:
            live, o, d, nrm = np.arange(len(origins)), origins, dirs, normals
        else:
            live = np.flatnonzero(start)
            o, d, pdf = take_rows(origins, live), take_rows(dirs, live), pdf[live]
            nrm = None if normals is None else take_rows(normals, live)
        acc = np.zeros((len(live), ts.channels))
        throughput = np.ones((len(live), 3))
        for bounce in range(ts.bounces + 1):
            t, prim, ng, bu, bv = self.intersect(o, d, barycentrics=True)
            for light in ts.surface_lights:
                hit, c = light.reached(prim), light.column  # (the others bring nothing)
                acc[hit, c : c + 3] += throughput[hit] * light.evaluate(
                    d[hit], t[hit], prim[hit], pdf[hit], o[hit], None if nrm is None else nrm[hit]
                )
            sky = self._sky(prim, d, pdf)
            if bounce == ts.bounces:
                hit, miss = prim >= 0, prim < 0
                radiance[live[hit]] = acc[hit]
                tp = ts.per_column(throughput[miss])
                radiance[live[miss]] = acc[miss] + tp * (sky[miss] if len(sky) > 1 else sky)
                return radiance
            row_albedo = _NO_ROWS
            if scene.textures:
                row_albedo = np.zeros((len(prim), 3))
                hit = np.flatnonzero(prim >= 0)
                row_albedo[hit] = scene.albedo_at(prim[hit], bu[hit], bv[hit])
            # misses end (written to radiance); every hit adds its light, then the roulette's
            # victims end and the survivors continue with a cosine-distributed direction
            # (BRDF·cos/pdf = albedo, applied to the throughput), reweighted by 1/p
            first = texels if bounce == 0 else None  # its numbers from the texels' sequences
            u_dir = first.directions(live) if first is not None else _NO_NUMBERS
            live, acc, throughput, o, n, d, pdf, weight, s = self.kernels.advance_paths(
                live,
                acc,
                throughput,
                o,
                d,
                t,
                prim,
                ng,
                scene.albedo,
                row_albedo,
                sky,
                radiance,
                ts.offset,
                bounce + 1 >= RR_START,
                RR_MAX_SURVIVAL,
                RR_SURVIVAL_POWER,
                RR_REFERENCE,
                seed(rng),
                u_dir,
            )
            if len(live) == 0:
                return radiance
            strata = first.lights(live) if first is not None else 1
            acc += ts.per_column(throughput) * self.irradiance_at(rng, o, n, strata)
            radiance[live[s:]] = acc[s:]
            live, acc, o, nrm, d, pdf = live[:s], acc[:s], o[:s], n[:s], d[:s], pdf[:s]
            throughput = throughput[:s] * weight[:, None]
            if s == 0:
                return radiance
        return radiance

    def _sky(self, prim, d, pdf) -> np.ndarray:
        """Radiance brought by the rays that missed (prim < 0): (R, C) with a row per ray (the
        lights at infinity, weighted by MIS), or (1, C) for all (the constant world, or black)."""
        ts = self.scene
        if not ts.sky_lights:
            sky = np.zeros((1, ts.channels))
            if ts.scene.world is not None:
                sky[0, ts.world_column : ts.world_column + 3] = ts.scene.world
            return sky
        sky = np.zeros((len(prim), ts.channels))
        miss = np.flatnonzero(prim < 0)
        for light in ts.sky_lights:
            c = light.column
            sky[miss, c : c + 3] += light.evaluate(d[miss], None, None, pdf[miss])
        return sky

    def light_samples(
        self,
        rng: np.random.Generator,
        x: np.ndarray,
        ray_pdf,
        strata: _lights.light.Strata = 1,
        normals: np.ndarray | None = None,
    ) -> list[LightSample]:
        """Light samples at the points x (R, 3), each entry (sample, rows, column): a `lights.light.Sample`
        over all R points, the rows (R,) bool that sampled a light (None: all) and the first of
        the 3 radiance columns it adds to. One entry per light that is not chosen, in sampling
        order (that of `TraceScene.lights`), then one per light set of the point, spot and area
        lights, which are one choice per point (`lights.choice.Choice`): each sampled only at the points
        that chose it, its value divided by the choice's probability, 0 elsewhere.
        `ray_pdf(dirs)`: the density of the strategy sampling rays at x (MIS); strata: x comes
        in groups of that many points of one texel (`lights.light.uniforms`); normals (R, 3): x's
        normals (rays leaving x must be evaluated with the same)."""
        ts = self.scene
        choice = ts.choice
        out: list[LightSample] = [
            (light.sample(rng, x, ray_pdf, strata, normals), None, light.column)
            for light in ts.lights
            if choice is None or light not in choice.lights
        ]
        return out if choice is None else out + self._chosen_samples(rng, x, ray_pdf, strata, normals)

    def _chosen_samples(self, rng, x, ray_pdf, strata, normals) -> list[LightSample]:
        """`light_samples`' entries of the chosen lights: one sample per point over all of them."""
        choice = self.scene.choice
        assert choice is not None
        picked, probability = choice.pick(rng, x, normals, strata)
        r = len(x)
        dirs, value, dist = np.zeros((r, 3)), np.zeros((r, 3)), np.ones(r)
        dirs[:, 2] = 1.0  # (unit, carrying nothing)
        order = np.argsort(picked, kind="stable")  # each light's rows in a run, ascending
        ends = np.cumsum(np.bincount(picked + 1, minlength=len(choice.lights) + 1))  # −1 first
        drawn: dict[int, np.ndarray] = {}  # the lights' numbers, each dimension drawn once
        for j, light in enumerate(choice.lights):
            rows = order[ends[j] : ends[j + 1]]
            if len(rows):
                sub = _lights.light.Subset(strata, r, rows, rng, drawn)
                d, v, t = light.sample(
                    rng, take_rows(x, rows), ray_pdf, sub, None if normals is None else take_rows(normals, rows)
                )
                dirs[rows], dist[rows] = d, t
                value[rows] = v / probability[rows, None]
        columns = np.array([light.column for light in choice.lights])
        column_of = np.where(picked >= 0, columns[np.maximum(picked, 0)], -1)
        return [((dirs, value, dist), column_of == c, int(c)) for c in np.unique(columns)]

    def irradiance_at(
        self, rng: np.random.Generator, x: np.ndarray, n: np.ndarray, strata: _lights.light.Strata = 1
    ) -> np.ndarray:
        """Next-event estimate of the irradiance (R, C) (docs/conventions.md units, E/π·π = outgoing radiance
        per unit albedo; C: 3 per light set) at surface points x (R, 3) with unit normals n (R, 3)
        from every light (one of the point, spot and area lights: `light_samples`), one shadow
        ray per light sampled and point; MIS against cosine sampling at x. strata: where the
        light samples' numbers come from (`lights.light.uniforms`)."""
        total = np.zeros((len(x), self.scene.channels))
        cosine_pdf = lambda w: np.maximum(np.einsum("ri,ri->r", w, n), 0.0) / np.pi
        for (dirs, value, dist), rows, c in self.light_samples(rng, x, cosine_pdf, strata, normals=n):
            weight, traced = self.shadow(x, dirs, dist, n, allowed=rows)  # cosθ where seen, else 0
            if traced:  # (none: every sample below the horizon)
                total[:, c : c + 3] += weight[:, None] * value
        return total * (1.0 / np.pi)

    def shadow(self, x, dirs, dist, n, scale=1.0, cosine=True, allowed=None) -> tuple[np.ndarray, int]:
        """Light samples at points x (R, 3) with normals n along dirs (R, 3) at distances dist
        (R,) (inf: a direction) through one shadow ray each, those above the horizon (and
        `allowed`): weights (R,), scale·cosθ (`cosine`) or scale where the light is seen, else
        0, and how many rays that traced (`rays.RayScene.shadow`; counted)."""
        weight, traced = self._rays.shadow(x, dirs, dist, n, self.scene.offset, scale, cosine, allowed)
        self.count(traced)
        return weight, traced

    def unoccluded(self, o: np.ndarray, d: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """(R,) 1.0 where nothing lies between o and the light at distance dist (inf: a direction)."""
        tmax = np.where(np.isfinite(dist), dist * (1.0 - 1e-4) - self.scene.offset, np.float32(3e38))
        self.count(len(o))
        return 1.0 - self._rays.occluded(o, d, np.maximum(tmax, 0.0))


@dataclass(frozen=True)
class TexelSamples:
    """Whose samples a batch of rays is: texels (n,) (global ids), k rays each (row t·k + j is
    sample j of texel t), the pass's first sample index (pass × k) and the bake's seed. The
    paths' first bounce takes its numbers from the texels' own (0,2)-sequences
    (`sampling.row_sequence`; streams FIRST_BOUNCE_STREAM on, apart from the texel's other
    sequences), so a texel's first bounces are stratified across its passes as its own
    directions are."""

    texels: np.ndarray
    k: int
    first: int
    seed: int

    def directions(self, rows: np.ndarray) -> np.ndarray:
        """(2, R): the numbers of the new directions leaving the first hits of rows (R,)."""
        return sampling.get().row_sequence(
            np.ascontiguousarray(rows, np.int64), self.texels, self.k, self.first, self.seed, FIRST_BOUNCE_STREAM
        )

    def lights(self, rows: np.ndarray) -> _lights.light.RowStream:
        """Where the light samples at the first hits of rows (R,) take their numbers."""
        return _lights.light.RowStream(rows, self.texels, self.k, self.first, self.seed, FIRST_BOUNCE_STREAM + 2)


#: The first `sampling.row_sequence` stream of a path's first bounce (its direction; its light
#: samples take the next ones), apart from `kernels`' direction and origin streams.
FIRST_BOUNCE_STREAM = 128


def seed(rng: np.random.Generator) -> int:
    """A 64-bit seed for a compiled kernel's own random stream, drawn from the unit's generator."""
    return int(rng.integers(1 << 63))


def take_rows(a: np.ndarray, i: np.ndarray) -> np.ndarray:
    """a[i] along the first axis; np.take is faster than fancy indexing for 2-D rows."""
    return a[i] if a.ndim == 1 else np.take(a, i, axis=0)
