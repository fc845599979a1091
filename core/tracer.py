"""Path-traced L2 SH bake on Embree: per bake point, incident radiance over the hemisphere of
n_v projected to world-space radiance SH (N, 9, 3). No bpy.

Estimator. For each texel, directions ω over the hemisphere of n_v are drawn from the mixture
p(ω) = ½·1/(2π) + ½·cosθ/π (half the samples uniform, half cosine-weighted). Every SH
coefficient then has finite variance (pure cosine sampling gives r_0 infinite variance from the
1/cosθ weight at the horizon) while I_z keeps most of the cosine-sampling benefit. The radiance
L arriving along ω is the path traced from the texel: world radiance if the ray escapes,
emission plus reflected light at surfaces (diffuse, two-sided, next-event estimation to every
light at each vertex, Russian roulette from RR_START bounces on, at most `bounces` reflections),
and Σ (L(ω) − β) Y(ω) / (K p(ω)) + β·∫Y estimates the radiance SH over the hemisphere, with a
constant β per half of the samples taken from the other half (`kernels.project_hemisphere`):
unbiased, exact for constant radiance, every sample used by every coefficient.

Every sample's origin is jittered over the texel's footprint (`BakePoints.sample_origins`: the
central ½ × ½ of the texel within its triangle), so a texel is an area average as Cycles bakes
it. Lights (not geometry, never hit by rays) are added by next-event estimation only, so nothing
is counted twice: at the bake point one shadow ray per light per sample, projected to SH along
the light's direction (a delta light — sun without angle, point without radius — has an exact
direction: an unshadowed sun adds exactly s·Y(l), no noise). A constant world is reached by the sampled rays only. Emitting
triangles (picked ∝ power, `emitters.py`) and an HDRI world (`environment`) are both
light-sampled (one sample per path vertex, the bake point included) and reached by the sampled
rays; the two are combined with the power heuristic (MIS), against the mixture pdf at the bake
point and the cosine pdf at bounces.
Weights sum to one per direction, so every SH coefficient stays unbiased.

The per-sample work between Embree queries (camera rays over a texel, a hit turned into the next
bounce, the SH projection) runs in compiled kernels (`kernels`); this module drives them and
samples the lights. Work is split into fixed chunks of texels; each chunk of each pass draws
its random numbers from its own generator seeded by (seed, pass, chunk), which also seeds the
kernels it calls, so results do not depend on the thread count. Chunks run on a thread pool of
`settings.threads` workers (0: every core, `parallel.machine_threads`): the Embree queries
(`core.embree`) and the kernels release the GIL.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from . import hhd as _hhd
from . import kernels as _kernels
from . import parallel as _parallel
from . import sh as _sh
from .bakepoints import BakePoints
from .covers import CoverProbe
from .emitters import EmitterSampler
from .errors import BakeCancelled, BakeError
from .rays import RayScene, ray_offset
from .scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight

RR_START = 2            # bounces before Russian roulette may end a path
RR_MAX_SURVIVAL = 0.95
_BLACK = np.zeros((1, 3))        # the sky of a scene without a world (kernels.advance_paths)
_NO_ROWS = np.zeros((0, 3))      # no per-row albedo: the kernel takes the triangles' own


@dataclass
class BakeSettings:
    """samples: hemisphere samples per texel, rounded up to whole passes (the most a texel gets
    when a noise target or time budget stops it earlier); pass_samples: samples per texel per
    pass (the progressive step); bounces: diffuse reflections after the first hit (0 = direct
    light only); seed: makes the bake reproducible; threads: worker threads, 0 = every core this
    process may use (`parallel.resolve_threads`; the result does not depend on it); chunk_texels:
    texels per work item (bounds memory: ~1 KB per texel-sample). pass_samples is a multiple of
    4 (two independent halves of uniform + cosine samples, see `kernels.hemisphere_rays`).

    noise_target: 0 (off) or the relative standard error of I_z (luminance) at which a texel
    stops: after at least MIN_ADAPTIVE_PASSES passes a texel whose pass-to-pass standard error
    is below noise_target × max(its I_z, NOISE_FLOOR × the atlas mean I_z) gets no more passes.
    The floor keeps near-black texels from asking for relative precision nobody can see.
    time_budget: 0 (off) or seconds of tracing after which no new chunk starts; the first pass
    always completes, so every texel has an estimate."""
    samples: int = 256
    pass_samples: int = 16
    bounces: int = 3
    seed: int = 0
    threads: int = 0
    chunk_texels: int = 8192
    noise_target: float = 0.0
    time_budget: float = 0.0


#: Passes a texel takes before its pass-to-pass spread may stop it (the spread of few passes is
#: noisy itself: from 4 Gaussian passes it lies between 0.34× and 1.6× the true error 90% of the
#: time, from 2 passes between 0.06× and 2×).
MIN_ADAPTIVE_PASSES = 4
#: Fraction of the atlas mean I_z below which the noise target is absolute, not relative.
NOISE_FLOOR = 0.1


@dataclass
class BakeResult:
    """sh (P, 9, 3) world-space radiance SH; sh_error (P, 9, 3) standard error of the estimate,
    from the spread between passes (0 where every pass agrees, e.g. an unshadowed sun; not
    available, reported as 0, after a single pass); samples: the most samples a texel took;
    texel_samples (P,) samples each texel took (they differ under a noise target or time
    budget); passes: the most passes; rays traced; seconds of wall time; stopped_by: "samples",
    "noise_target" (every texel converged) or "time_budget"; threads: the worker threads used."""
    sh: np.ndarray
    sh_error: np.ndarray
    samples: int
    passes: int
    rays: int
    seconds: float
    texel_samples: np.ndarray | None = None
    stopped_by: str = "samples"
    threads: int = 1

    @property
    def mean_samples(self) -> float:
        return float(self.texel_samples.mean()) if self.texel_samples is not None and len(self.texel_samples) else 0.0


def bake(points: BakePoints, scene: BakeScene, settings: BakeSettings = BakeSettings(),
         progress: Callable[[float, str], None] | None = None,
         cancel: Callable[[], bool] | None = None, ray_scene: RayScene | None = None) -> BakeResult:
    """Trace every bake point; progressive passes of `pass_samples` each, each pass over the
    texels still converging (all of them unless `settings.noise_target` is set).
    `progress(fraction, message)` is called after every chunk; `cancel()` returning True stops
    within one chunk and raises BakeCancelled. `ray_scene`: the Embree scene of
    `scene.triangles`, if the caller has built it already."""
    if settings.pass_samples < 4 or settings.pass_samples % 4:
        raise BakeError(f"samples per pass must be a multiple of 4, got {settings.pass_samples}")
    if settings.noise_target < 0 or settings.time_budget < 0 or not np.isfinite(settings.noise_target):
        raise BakeError("the noise target and the time budget must be ≥ 0 (0 switches them off)")
    start = time.perf_counter()
    settings = replace(settings, threads=_parallel.resolve_threads(settings.threads))
    tracer = _Tracer(points, scene, settings, ray_scene)
    n = len(points.texel)
    max_passes = max(1, -(-settings.samples // settings.pass_samples))
    acc = _Accumulator(n, points.normal)
    active = np.arange(n)
    stopped_by = "samples"
    with ThreadPoolExecutor(max_workers=settings.threads) as pool:
        for p in range(max_passes):
            def on_chunk(done, of):
                elapsed = time.perf_counter() - start
                if progress:
                    progress(_fraction(p, done / of, max_passes, settings, elapsed),
                             _status(p, max_passes, len(active), n, tracer.rays, acc.texel_passes,
                                     settings.pass_samples, elapsed))
                return not (settings.time_budget and elapsed >= settings.time_budget and p > 0)
            if not _trace_pass(pool, tracer, acc, p, active, on_chunk, cancel):
                stopped_by = "time_budget"
                break
            if settings.noise_target and p + 1 >= MIN_ADAPTIVE_PASSES:
                active = active[~acc.converged(active, settings.noise_target)]
                if len(active) == 0:
                    stopped_by = "noise_target"
                    break
    sh, sh_error = acc.result()
    sh[points.buried] = 0.0
    return BakeResult(sh=sh, sh_error=sh_error, samples=int(acc.passes.max(initial=0)) * settings.pass_samples,
                      passes=int(acc.passes.max(initial=0)), rays=tracer.rays,
                      seconds=time.perf_counter() - start,
                      texel_samples=acc.passes * settings.pass_samples, stopped_by=stopped_by,
                      threads=settings.threads)


def _trace_pass(pool, tracer: "_Tracer", acc: "_Accumulator", p: int, active: np.ndarray, on_chunk, cancel) -> bool:
    """Pass p over the texels `active`, in chunks on the pool, added to `acc` in chunk order.
    Only a few chunks are queued ahead of the one being added (enough to keep every worker
    busy), so finished estimates never pile up: memory stays bounded whatever the atlas size.
    `on_chunk(done, of)` after each chunk returns False to end the pass early (returns False
    then); `cancel()` returning True raises BakeCancelled."""
    size = tracer.settings.chunk_texels
    chunks = [active[s:s + size] for s in range(0, len(active), size)]
    ahead = 2 * tracer.settings.threads
    queued: deque = deque()
    try:
        for c, idx in enumerate(chunks):
            while len(queued) < ahead and c + len(queued) < len(chunks):
                k = c + len(queued)
                queued.append(pool.submit(tracer.trace_pass, p, k, chunks[k]))
            if cancel is not None and cancel():
                raise BakeCancelled("bake cancelled")
            acc.add(idx, queued.popleft().result())
            if not on_chunk(c + 1, len(chunks)):
                return False
    finally:                    # cancelled, stopped early or failed: no chunk left queued
        _cancel_all(queued)
    return True


def _cancel_all(futures) -> None:
    """Drop the chunks not started; wait for the running ones so no worker outlives the bake."""
    for f in futures:
        f.cancel()
    for f in futures:
        if not f.cancelled():
            f.exception()


def _fraction(p, chunk_fraction, max_passes, settings, elapsed) -> float:
    fraction = (p + chunk_fraction) / max_passes
    if settings.time_budget:
        fraction = max(fraction, min(elapsed / settings.time_budget, 1.0))
    return fraction


def _status(p, max_passes, active, n, rays, texel_passes, pass_samples, elapsed) -> str:
    elapsed = max(elapsed, 1e-9)
    converging = f", {100 * active / max(n, 1):.0f}% of texels converging" if active < n else ""
    return (f"pass {p + 1} of {max_passes}{converging}, {rays / elapsed / 1e6:.2f} M rays/s, "
            f"{texel_passes * pass_samples / elapsed / 1e3:.0f} k texel-samples/s")


class _Accumulator:
    """Running statistics of the pass estimates per texel (each texel may have its own pass
    count): the SH sum (N, 9, 3) float64, the SH's sum of squared deviations from the running
    mean (Welford; float32 is enough, being a sum of squares, not a difference of two), and the
    sum and square sum of I_z's luminance for the noise target: 336 bytes per texel."""

    def __init__(self, n: int, normals: np.ndarray):
        self.normals = normals
        self.total = np.zeros((n, 9, 3))
        self.m2 = np.zeros((n, 9, 3), np.float32)
        self.iz = np.zeros(n)
        self.iz_sq = np.zeros(n)
        self.passes = np.zeros(n, dtype=np.int64)
        self.texel_passes = 0

    def add(self, idx: np.ndarray, estimate: np.ndarray) -> None:
        """Add one pass's estimate for the texels idx (unique: a chunk of `active`); compiled
        (`kernels.add_pass`): runs on the main thread beside the tracing workers, where numpy
        was several times slower (the README has the figures)."""
        self.texel_passes += len(idx)
        _kernels.get().add_pass(np.asarray(idx, dtype=np.int64), estimate, self.normals, _hhd.LUMINANCE,
                               _hhd.IRRADZ_FROM_R10, self.total, self.m2, self.iz, self.iz_sq, self.passes)

    def converged(self, idx: np.ndarray, target: float) -> np.ndarray:
        """Which of the texels idx have a standard error of I_z below the target (see BakeSettings)."""
        k = self.passes[idx].astype(np.float64)
        mean = self.iz[idx] / k
        var = np.maximum(self.iz_sq[idx] / k - mean * mean, 0.0) / np.maximum(k - 1.0, 1.0)
        sampled = self.passes > 0
        floor = NOISE_FLOOR * max(float((self.iz[sampled] / self.passes[sampled]).mean()), 0.0) if sampled.any() else 0.0
        ok = np.sqrt(var) <= target * np.maximum(mean, floor)
        return ok & np.isfinite(var)

    def result(self, chunk: int = 1 << 16):
        """(mean (N, 9, 3) float64, its standard error (N, 9, 3) float32), computed in place over
        the running statistics (the accumulator is spent afterwards), a chunk of texels at a time."""
        for s in range(0, len(self.passes), chunk):
            k = np.maximum(self.passes[s:s + chunk], 1).astype(np.float64)[:, None, None]
            self.total[s:s + chunk] /= k
            self.m2[s:s + chunk] /= k * np.maximum(k - 1.0, 1.0)     # variance of the mean
            np.sqrt(self.m2[s:s + chunk], out=self.m2[s:s + chunk])
        return self.total, self.m2


class _Tracer:
    def __init__(self, points: BakePoints, scene: BakeScene, settings: BakeSettings, ray_scene=None):
        if len(scene.triangles) == 0:
            raise BakeError("the bake scene has no geometry")
        self.points = points
        self.scene = scene
        self.settings = settings
        self.rays_scene = ray_scene if ray_scene is not None else RayScene(scene.triangles)
        self.offset = max(points.offset, ray_offset(scene.triangles))
        self.emitters = EmitterSampler(scene.triangles, scene.emission) if scene.emission is not None else None
        flagged = points.near_cover is not None and points.near_cover.any()
        self.covers = None
        if flagged:
            probe = points.cover_probe
            reuse = probe is not None and probe.probes(self.rays_scene.triangles, points.offset)
            self.covers = probe if reuse else CoverProbe(scene.triangles, points.offset, points.tri_positions)
        self.kernels = _kernels.get()
        self._lock = threading.Lock()
        self.rays = 0

    def _count(self, n):
        with self._lock:
            self.rays += int(n)

    def _intersect(self, o, d, tmax=None, barycentrics=False):
        self._count(len(o))
        return self.rays_scene.intersect(o, d, tmax, barycentrics)

    # ---- one pass over one chunk: the Monte Carlo part ------------------------------------
    def trace_pass(self, pass_index: int, chunk_index: int, idx: np.ndarray) -> np.ndarray:
        """Radiance SH estimate `(len(idx), 9, 3)` from this pass's samples of the texels idx."""
        rng = np.random.default_rng([self.settings.seed, pass_index, chunk_index])
        k = self.settings.pass_samples
        normals = self.points.normal[idx]
        dirs, pdf = self.kernels.hemisphere_rays(normals, k, _seed(rng))   # (n·k, 3), (n·k,)
        texel = np.repeat(np.arange(len(idx)), k)
        origins = self.points.sample_origins(rng, idx, k)
        uncovered = self._uncovered(idx, texel, origins)
        radiance = self._path_radiance(rng, origins, dirs, pdf, uncovered)   # (n·k, 3)
        estimate = self.kernels.project_hemisphere(dirs, radiance, pdf, normals, k)
        return estimate + self._direct_sh(rng, idx, origins, k, uncovered)

    def _uncovered(self, idx, texel, origins) -> np.ndarray | None:
        """(n·k,) bool, False for samples starting on a part of the texel a coplanar face covers
        (core.covers: no light reaches it, as in Cycles), probed for the texels flagged
        near_cover; None when no texel of the chunk is flagged."""
        if self.covers is None:
            return None
        rows = np.flatnonzero(self.points.near_cover[idx][texel])
        if len(rows) == 0:
            return None
        self._count(len(rows))
        uncovered = np.ones(len(origins), bool)
        uncovered[rows] = ~self.covers.covered(origins[rows], self.points.face_normal[idx[texel[rows]]])
        return uncovered

    def _path_radiance(self, rng, origins, dirs, pdf, start=None) -> np.ndarray:
        """Radiance arriving at `origins` from directions `dirs` (R, 3) sampled with density `pdf`
        (R,) per steradian: wavefront over bounces, the arrays compacted to the live paths.
        `start` (R,) bool, if given: only those paths are traced (the others receive nothing).
        Each live path gathers into its own row of `acc` (compacted with it), written out once
        when the path ends: cheaper than scattering into the (R, 3) result every bounce."""
        scene = self.scene
        radiance = np.zeros((len(origins), 3))
        if start is None:
            live, o, d = np.arange(len(origins)), origins, dirs
        else:
            live = np.flatnonzero(start)
            o, d, pdf = _rows(origins, live), _rows(dirs, live), pdf[live]
        acc = np.zeros((len(live), 3))
        throughput = np.ones((len(live), 3))
        for bounce in range(self.settings.bounces + 1):
            t, prim, ng, bu, bv = self._intersect(o, d, barycentrics=True)
            if self.emitters:
                hit = np.flatnonzero(prim >= 0)
                acc[hit] += throughput[hit] * self._emitted(prim[hit], d[hit], t[hit], pdf[hit])
            sky = self._sky(prim, d, pdf)
            if bounce == self.settings.bounces:
                hit, miss = prim >= 0, prim < 0
                radiance[live[hit]] = acc[hit]
                radiance[live[miss]] = acc[miss] + throughput[miss] * (sky[miss] if len(sky) > 1 else sky)
                return radiance
            row_albedo = _NO_ROWS
            if scene.textures:
                row_albedo = np.zeros((len(prim), 3))
                hit = np.flatnonzero(prim >= 0)
                row_albedo[hit] = scene.albedo_at(prim[hit], bu[hit], bv[hit])
            # misses end (written to radiance); every hit adds its light, then the roulette's
            # victims end and the survivors continue with a cosine-distributed direction
            # (BRDF·cos/pdf = albedo, applied to the throughput), reweighted by 1/p
            live, acc, throughput, o, n, d, pdf, weight, s = self.kernels.advance_paths(
                live, acc, throughput, o, d, t, prim, ng, scene.albedo, row_albedo, sky, radiance,
                self.offset, bounce + 1 >= RR_START, RR_MAX_SURVIVAL, _seed(rng))
            if len(live) == 0:
                return radiance
            acc += throughput * self._irradiance_at(rng, o, n)
            radiance[live[s:]] = acc[s:]
            live, acc, o, d, pdf = live[:s], acc[:s], o[:s], d[:s], pdf[:s]
            throughput = throughput[:s] * weight[:, None]
            if s == 0:
                return radiance
        return radiance

    def _sky(self, prim, d, pdf) -> np.ndarray:
        """Radiance brought by the rays that missed (prim < 0): (R, 3) with a row per ray (an
        HDRI, weighted by MIS), or (1, 3) for all (the constant world, or black)."""
        scene = self.scene
        if scene.environment is None:
            return _BLACK if scene.world is None else scene.world[None, :]
        sky = np.zeros((len(prim), 3))
        miss = np.flatnonzero(prim < 0)
        sky[miss] = self._escaped(d[miss], pdf[miss])
        return sky

    def _emitted(self, prim, d, t, pdf) -> np.ndarray:
        """Emitted radiance (R, 3) seen by rays hitting triangles prim along d at distance t,
        sampled with density pdf: MIS-weighted (power heuristic) against emitter sampling."""
        p_light = self.emitters.pdf(prim, d, t.astype(np.float64))
        weight = pdf * pdf / np.maximum(pdf * pdf + p_light * p_light, 1e-300)
        return self.scene.emission[prim] * weight[:, None]

    def _escaped(self, d, pdf) -> np.ndarray:
        """Radiance (R, 3) of rays leaving the scene along d, sampled with density pdf: the
        constant world, or the HDRI weighted against its own light sampling (power heuristic)."""
        scene = self.scene
        if scene.environment is not None:
            p_env = scene.environment.pdf(d)
            return scene.environment.radiance(d) * (pdf * pdf / (pdf * pdf + p_env * p_env))[:, None]
        if scene.world is not None:
            return np.broadcast_to(scene.world, (len(d), 3))
        return np.zeros((len(d), 3))

    def _mis_light_samples(self, rng, x, other_pdf):
        """One sample per point x (R, 3) of each light that rays can also reach (the HDRI, the
        emissive triangles): yields (directions (R, 3), radiance × MIS weight / pdf (R, 3),
        distances (R,)), the weight (power heuristic) against the strategy of density
        `other_pdf(dirs)`."""
        env = self.scene.environment
        if env is not None:
            dirs, p_env = env.sample(rng, len(x))
            p_other = other_pdf(dirs)
            yield dirs, env.radiance(dirs) * (p_env / (p_env * p_env + p_other * p_other))[:, None], np.full(len(x), np.inf)
        if self.emitters:
            dirs, dist, emitted, p_light = self.emitters.sample(rng, x)
            p_other = other_pdf(dirs)
            with np.errstate(divide="ignore", invalid="ignore"):
                weight = np.where(p_light > 0.0, p_light / (p_light * p_light + p_other * p_other), 0.0)
            yield dirs, emitted * weight[:, None], dist

    # ---- lights ------------------------------------------------------------------------------
    def _irradiance_at(self, rng, x, n) -> np.ndarray:
        """Irradiance (DESIGN units, E/π·π = outgoing radiance per unit albedo) at surface points
        x with normals n from all lights, one shadow ray per light and point."""
        total = np.zeros((len(x), 3))
        cosine_pdf = lambda w: np.maximum(np.einsum("ri,ri->r", w, n), 0.0) / np.pi
        samples = [self._sample_light(rng, light, x) for light in self.scene.lights]
        for dirs, value, dist in samples + list(self._mis_light_samples(rng, x, cosine_pdf)):
            cos = np.einsum("ri,ri->r", dirs, n)
            facing = np.flatnonzero(cos > 0.0)
            if len(facing) == len(x):
                weight = self._unoccluded(x, dirs, dist) * cos
            elif len(facing):
                weight = np.zeros(len(x))
                weight[facing] = self._unoccluded(_rows(x, facing), _rows(dirs, facing), dist[facing]) * cos[facing]
            else:
                continue
            total += weight[:, None] * value
        return total * (1.0 / np.pi)

    def _sample_light(self, rng, light, x):
        """Directions (R, 3) to one sample point of the light, its radiance·solid angle per
        sample (R, 3) — the 'irradiance at normal incidence' it represents — and distances."""
        r = len(x)
        if isinstance(light, SunLight):
            axis = np.broadcast_to(light.direction, (r, 3))
            dirs = axis if light.is_delta else _cone_directions(rng, axis, np.cos(0.5 * light.angle))
            return dirs, np.broadcast_to(light.irradiance, (r, 3)), np.full(r, np.inf)
        if isinstance(light, PointLight):
            dirs, value, dist = self._sample_point(rng, light, x)
            if isinstance(light, SpotLight):
                value = value * light.attenuation(-dirs)[:, None]
            return dirs, value, dist
        if isinstance(light, AreaLight):
            p = light.sample_points(rng, r)
            to = p - x
            dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
            dirs = to / dist[:, None]
            cos_l = np.maximum(-(dirs @ light.normal), 0.0)
            radiance = light.power / (np.pi * light.area)
            # radiance × (solid angle of the sampled area element = A cos_l / d²)
            return dirs, radiance[None, :] * (light.area * cos_l / dist ** 2)[:, None], dist
        raise BakeError(f"unsupported light {type(light).__name__}")

    @staticmethod
    def _sample_point(rng, light: PointLight, x):
        """_sample_light for a point light (also the base of a spot light)."""
        to = light.position - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        axis = to / dist[:, None]
        if light.is_delta:
            return axis, light.power[None, :] / (4.0 * np.pi * dist ** 2)[:, None], dist
        if light.soft_falloff:     # a disk of radius r facing the point
            cos_a = dist / np.sqrt(dist ** 2 + light.radius ** 2)
        else:                      # a sphere of radius r
            cos_a = np.sqrt(1.0 - np.minimum(light.radius / dist, 1.0) ** 2)
        # radiance P/(4π² r²) over the cone the light subtends, solid angle 2π(1 - cos α)
        value = light.power[None, :] / (4.0 * np.pi ** 2 * light.radius ** 2) * (2.0 * np.pi * (1.0 - cos_a))[:, None]
        return _cone_directions(rng, axis, cos_a), value, np.maximum(dist - light.radius, 0.0)

    def _unoccluded(self, o, d, dist) -> np.ndarray:
        """1.0 where nothing lies between o and the light at distance dist (inf: a direction)."""
        tmax = np.where(np.isfinite(dist), dist * (1.0 - 1e-4) - self.offset, np.float32(3e38))
        self._count(len(o))
        return 1.0 - self.rays_scene.occluded(o, d, np.maximum(tmax, 0.0))

    def _direct_sh(self, rng, idx, origins, k, uncovered=None) -> np.ndarray:
        """Next-event estimation at the bake point: one shadow ray per light from each of the
        pass's k origins (those `uncovered`, if given); light arriving from below n_v's horizon
        is not part of the hemisphere's SH. For a delta light the direction is exact, so an
        unshadowed sun adds exactly s·Y(l) (no noise); penumbrae average over the footprint."""
        out = np.zeros((len(idx), 9, 3))
        normal = np.repeat(self.points.normal[idx], k, axis=0)

        def mixture_pdf(w):
            return _mixture_pdf(np.einsum("ri,ri->r", w, normal))
        samples = [self._sample_light(rng, light, origins) for light in self.scene.lights]
        for dirs, value, dist in samples + list(self._mis_light_samples(rng, origins, mixture_pdf)):
            above = np.einsum("ri,ri->r", dirs, normal) > 0.0
            if uncovered is not None:
                above &= uncovered
            rows = np.flatnonzero(above)
            if len(rows) == 0:
                continue
            weight = np.zeros(len(origins))
            weight[rows] = self._unoccluded(_rows(origins, rows), _rows(dirs, rows), dist[rows]) * (1.0 / k)
            self.kernels.accumulate_grouped(dirs, value, weight, k, out)
        return out


def _mixture_pdf(cos):
    """Density per steradian of `kernels.hemisphere_rays` (half uniform, half cosine) at cosθ."""
    return np.where(cos > 0.0, 0.5 / (2.0 * np.pi) + 0.5 * cos / np.pi, 0.0)


def _seed(rng: np.random.Generator) -> int:
    """A 64-bit seed for a compiled kernel's own random stream, drawn from the chunk's generator."""
    return int(rng.integers(1 << 63))


def _rows(a: np.ndarray, i: np.ndarray) -> np.ndarray:
    """a[i] along the first axis; np.take is ~4× faster than fancy indexing for 2-D rows."""
    return a[i] if a.ndim == 1 else np.take(a, i, axis=0)


def _cone_directions(rng, axis: np.ndarray, cos_max) -> np.ndarray:
    """Uniform directions in cones around `axis` (R, 3) with half-angle arccos(cos_max)."""
    u1, u2 = rng.random(len(axis)), rng.random(len(axis))
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return np.einsum("rij,rj->ri", _sh.tangent_frames(axis), local)
