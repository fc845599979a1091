"""Every source of light the tracer samples, behind one interface (`Light`). No bpy.

`build(scene)` turns a BakeScene's light data (core.scene: plain dataclasses in Cycles' units)
into sampling objects, one class per light type, in the order the tracer samples them at every
path vertex: the scene's lights in scene order, then the HDRI world, then the emissive triangles
(one light per light group). That order fixes how each vertex draws its random numbers, so it
is part of what makes a seed reproduce a bake bit for bit.

Two kinds, told apart by `Light.reachable`:
  * lights rays never hit (sun, point, spot and area lights: not geometry) are added by
    next-event estimation only; their `sample` gives radiance × the solid angle it stands for;
  * lights the sampled rays also reach (the HDRI, by rays leaving the scene: `at_infinity`; the
    emissive triangles, by hitting them) are light-sampled too, and the two strategies are
    combined with the power heuristic (MIS): `sample` gives radiance × MIS weight / pdf,
    `evaluate` the MIS-weighted radiance a ray that reached the light brings.
Weights sum to one per direction, so every SH coefficient stays unbiased.

The point, spot and area lights (`Light.chosen`) are not each sampled at every shading point:
the point picks one of them by its expected contribution (`Choice`: intensity, the cosine
bounds at both ends, over distance²) and divides its sample by that probability. A point
samples none where none can light it (behind every one-sided lamp, all below its horizon).

Emissive triangles are grouped into a light tree: at most CLUSTERS spatial clusters (median
splits of their centroids along the longest axis), each cluster of several triangles split again
into at most FANOUT, down to single triangles (`light_tree`; up to MAX_LEAVES leaves). At each
shading point x the tree is descended from the top: among a node's children one is picked with
probability ∝ its power over max(distance², radius²) to x (mixed with POWER_SHARE of power
alone; a leaf of one triangle with x inside its bounding sphere: ∝ its luminance × the solid
angle it subtends, NEAR_RADII; below a node x lies DESCEND_RADII of its radius or more from, ∝
power alone, which costs no weights), then a triangle of the leaf ∝ its power (area × emitted
luminance; emission is two-sided, so both sides count alike), then a uniform point on the
triangle or, where the triangle subtends a solid angle within SOLID_ANGLE_RANGE, a uniform
direction in that solid angle (Arvo 1995: no 1/d² spikes beside a lamp): a lamp across the room
no longer takes as many samples as the one beside the texel. Sampling and densities are compiled
(`light_kernels.sample_emitters`, `light_kernels.emitter_pdf`). The density therefore depends on x: `pdf`
and `evaluate` take the rays' origins. Array conventions: x (R, 3) shading points, directions (R, 3)
unit, world space; densities per steradian.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .. import sampling
from .. import sh as _sh
from ..colour import LUMINANCE
from ..environment import EnvironmentMap
from ..errors import BakeError
from ..scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from . import light_kernels as _kernels

#: A light sample at R points: directions (R, 3), value (R, 3) (radiance × solid angle, or
#: radiance × MIS weight / pdf), distances (R,) to the sampled point (inf: a direction).
Sample = tuple[np.ndarray, np.ndarray, np.ndarray]
#: Density per steradian (R,) of the strategy that samples rays at the shading points, at
#: directions (R, 3): the other strategy an MIS weight is taken against.
RayPdf = Callable[[np.ndarray], np.ndarray]


class Light(ABC):
    """One source of light. group: the light group it belongs to ("": the default set);
    column: the first of the 3 radiance columns of its light set (`paths.TraceScene` sets it);
    reachable: rays can also reach it (MIS with `pdf` and `evaluate`), else next-event
    estimation only; at_infinity: reached by rays leaving the scene, not by hitting triangles."""

    group: str = ""
    column: int = 0
    reachable: bool = False
    at_infinity: bool = False
    #: one of the lights a shading point picks from (`Choice`), rather than sampled at every point
    chosen: bool = False

    @abstractmethod
    def sample(
        self,
        rng: np.random.Generator,
        x: np.ndarray,
        ray_pdf: RayPdf,
        strata: Strata = 1,
        normals: np.ndarray | None = None,
    ) -> Sample:
        """One sample per shading point x (R, 3), drawn from `rng` (see `Sample`); a reachable
        light weights it against `ray_pdf`, the others ignore it. strata: x comes in groups of
        that many points of one texel, whose random numbers are stratified together
        (`uniforms`); normals (R, 3): the points' normals, for lights that favour what lies above
        the horizon (`pdf` and `evaluate` must then get the same)."""

    def pdf(
        self,
        d: np.ndarray,
        t: np.ndarray | None = None,
        prim: np.ndarray | None = None,
        origins: np.ndarray | None = None,
        normals: np.ndarray | None = None,
    ) -> np.ndarray:
        """Density per steradian (R,) with which `sample` at `origins` (R, 3) with `normals` picks
        the point a ray along d (R, 3) reached (at distance t (R,) on triangle prim (R,), where
        that applies); 0 for a light rays never reach."""
        return np.zeros(len(d))

    def evaluate(
        self,
        d: np.ndarray,
        t: np.ndarray | None,
        prim: np.ndarray | None,
        pdf: np.ndarray,
        origins: np.ndarray | None = None,
        normals: np.ndarray | None = None,
    ) -> np.ndarray:
        """Radiance (R, 3) that rays from `origins` (R, 3) (with `normals`) along d (R, 3), sampled with density
        `pdf` (R,), bring from this light (ending at distance t on triangle prim, where that
        applies), MIS-weighted against `sample`; 0 for a light rays never reach."""
        return np.zeros((len(d), 3))

    def reached(self, prim: np.ndarray) -> np.ndarray:
        """The rows (int64) of the rays ending on triangles prim (R,) (−1: a miss) that reached
        this light by hitting it: none, but for emitting triangles."""
        return np.zeros(0, np.int64)

    def choice_row(self) -> list[float]:
        """A `chosen` light's row of `Choice.table` (`light_kernels.choose_lights`)."""
        raise NotImplementedError(f"{type(self).__name__} is not one of the lights a point chooses from")

    @property
    @abstractmethod
    def power(self) -> float:
        """Luminance of the light's emitted power: W for lights at a finite distance; for lights
        at infinity ∫ L dω over their directions, W/m² (a sun: its irradiance at normal incidence)."""


class Sun(Light):
    """A distant light: a direction (delta, angle 0) or a uniform cone of angular diameter
    `angle`; value: its irradiance at normal incidence (an unshadowed delta sun adds exactly
    s·Y(l) to the SH: no noise)."""

    at_infinity = True

    def __init__(self, light: SunLight):
        self.direction, self.irradiance, self.angle = light.direction, light.irradiance, light.angle
        self.is_delta, self.group = light.is_delta, light.group

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        r = len(x)
        axis = np.broadcast_to(self.direction, (r, 3))
        dirs = axis if self.is_delta else _cone_directions(rng, axis, np.cos(0.5 * self.angle), strata)
        return dirs, np.broadcast_to(self.irradiance, (r, 3)), np.full(r, np.inf)

    @property
    def power(self) -> float:
        return float(np.asarray(self.irradiance) @ LUMINANCE)


class Point(Light):
    """A point light of power P (W, RGB): a true point (radius 0, exact direction) or, with a
    radius r, radiance P/(4π² r²) over the cone it subtends, sampled uniformly: a disk facing the
    shaded point with soft falloff (Blender's default), else a sphere (Cycles' point_light_sample)."""

    chosen = True

    def __init__(self, light: PointLight):
        self.position, self.rgb_power, self.radius = light.position, light.power, light.radius
        self.soft_falloff, self.is_delta, self.group = light.soft_falloff, light.is_delta, light.group

    def choice_row(self) -> list[float]:
        """Its row of `Choice.table`: its sphere, P/4π as the intensity, lit all round."""
        r = float(self.radius)
        return [*map(float, self.position), r * r, r, self.power / (4.0 * np.pi), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.pi]

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        to = self.position - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        axis = to / dist[:, None]
        if self.is_delta:
            return axis, self.rgb_power[None, :] / (4.0 * np.pi * dist**2)[:, None], dist
        if self.soft_falloff:  # a disk of radius r facing the point
            cos_a = dist / np.sqrt(dist**2 + self.radius**2)
        else:  # a sphere of radius r
            cos_a = np.sqrt(1.0 - np.minimum(self.radius / dist, 1.0) ** 2)
        # radiance P/(4π² r²) over the cone the light subtends, solid angle 2π(1 - cos α)
        value = self.rgb_power[None, :] / (4.0 * np.pi**2 * self.radius**2) * (2.0 * np.pi * (1.0 - cos_a))[:, None]
        return _cone_directions(rng, axis, cos_a, strata), value, np.maximum(dist - self.radius, 0.0)

    @property
    def power(self) -> float:
        return float(np.asarray(self.rgb_power) @ LUMINANCE)


class Spot(Point):
    """A point light limited to a cone (core.scene.SpotLight): Cycles' smoothstep attenuation of
    the angle between the spot's axis and the direction from the light to the shaded point."""

    def __init__(self, light: SpotLight):
        super().__init__(light)
        self.axis, self.size, self.blend = light.direction, light.size, light.blend

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        dirs, value, dist = super().sample(rng, x, ray_pdf, strata)
        return dirs, value * self.attenuation(-dirs)[:, None], dist

    def choice_row(self) -> list[float]:
        """The point light's row, with its cone: its axis and half-angle (dark outside)."""
        return super().choice_row()[:9] + [*map(float, self.axis), 0.5 * float(self.size)]

    def attenuation(self, light_to_point: np.ndarray) -> np.ndarray:
        """(R,) in [0, 1] for unit directions (R, 3) from the light towards the shaded points."""
        cos_half = np.cos(0.5 * self.size)
        x = light_to_point @ self.axis - cos_half
        if self.blend <= 0.0:
            return (x > 0.0).astype(np.float64)
        f = np.clip(x / ((1.0 - cos_half) * self.blend), 0.0, 1.0)
        return f * f * (3.0 - 2.0 * f)


class Area(Light):
    """A one-sided Lambertian rectangle, square, disk or ellipse (core.scene.AreaLight) of
    radiance P / (π A). Sampled by a uniform direction in the solid angle of its rectangle
    (`sample_spherical_rectangles`; compiled: `light_kernels.sample_area_light`, whose numpy spec is
    `sample_numpy`): no 1/d² spikes beside the lamp. A disk or ellipse is counted
    where that direction meets it (its bounding rectangle's solid angle × inside: unbiased, and
    bounded by 2π × the radiance); where the rectangle subtends less than SOLID_ANGLE_RANGE's
    least, by a uniform point on its surface (the two agree there)."""

    chosen = True

    def __init__(self, light: AreaLight):
        self.position, self.axis_u, self.axis_v = light.position, light.axis_u, light.axis_v
        self.normal, self.rgb_power, self.shape = light.normal, light.power, light.shape
        self.area, self.group = light.area, light.group

    def choice_row(self) -> list[float]:
        """Its row of `Choice.table`: the sphere through its corners, the intensity of a
        Lambertian emitter of its power along its normal (P/π), one-sided along the normal."""
        r2 = float(self.axis_u @ self.axis_u + self.axis_v @ self.axis_v)
        return [
            *map(float, self.position),
            r2,
            r2**0.5,
            self.power / np.pi,
            *map(float, self.normal),
            0.0,
            0.0,
            0.0,
            np.pi,
        ]

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        u1, u2 = uniforms(rng, len(x), strata, 2), uniforms(rng, len(x), strata, 3)
        dirs, solid_angle, dist = _kernels.get().sample_area_light(
            _rows(x),
            np.ascontiguousarray(u1, np.float64),
            np.ascontiguousarray(u2, np.float64),
            self._rect,
            self._light,
            self.shape in ("DISK", "ELLIPSE"),
            SOLID_ANGLE_RANGE[0],
        )
        radiance = self.rgb_power / (np.pi * self.area)
        return dirs, radiance[None, :] * solid_angle[:, None], dist

    def sample_numpy(self, rng, x, strata=1) -> Sample:
        """`sample` in numpy: the spec of the compiled `light_kernels.sample_area_light`, the tests
        compare them."""
        u1, u2 = uniforms(rng, len(x), strata, 2), uniforms(rng, len(x), strata, 3)
        corner = self.position - self.axis_u - self.axis_v
        p, solid_angle = sample_spherical_rectangles(x, corner, 2.0 * self.axis_u, 2.0 * self.axis_v, u1, u2)
        by_direction = (solid_angle >= SOLID_ANGLE_RANGE[0]) & np.isfinite(p).all(axis=1)
        p = np.where(by_direction[:, None], p, self._surface_points(u1, u2))
        to = p - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        dirs = to / dist[:, None]
        cos_l = np.maximum(-(dirs @ self.normal), 0.0)
        if self.shape in ("DISK", "ELLIPSE"):
            solid_angle = solid_angle * self._inside(p)
        # radiance × the solid angle the sample stands for (of the area element: A cos_l / d²)
        weight = np.where(by_direction, np.where(cos_l > 0.0, solid_angle, 0.0), self.area * cos_l / dist**2)
        radiance = self.rgb_power / (np.pi * self.area)
        return dirs, radiance[None, :] * weight[:, None], dist

    @property
    def _rect(self) -> np.ndarray:
        """(4, 3) for the kernel: the rectangle's corner, unit edges, (edge lengths, 0)."""
        eu, ev = 2.0 * self.axis_u, 2.0 * self.axis_v
        lu, lv = float(np.linalg.norm(eu)), float(np.linalg.norm(ev))
        return np.array([self.position - self.axis_u - self.axis_v, eu / lu, ev / lv, [lu, lv, 0.0]], np.float64)

    @property
    def _light(self) -> np.ndarray:
        """(4, 3) for the kernel: centre, axis_u, axis_v, unit normal."""
        return np.array([self.position, self.axis_u, self.axis_v, self.normal], np.float64)

    def sample_points(self, rng: np.random.Generator, n: int, strata: Strata = 1) -> np.ndarray:
        """n points (n, 3) uniform over the light's surface (`strata`: `uniforms`)."""
        return self._surface_points(uniforms(rng, n, strata, 2), uniforms(rng, n, strata, 3))

    def _surface_points(self, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
        """Points (n, 3) on the light's surface, uniform for uniform numbers u1, u2 (n,)."""
        if self.shape in ("DISK", "ELLIPSE"):
            r, phi = np.sqrt(u1), 2.0 * np.pi * u2
            a, b = r * np.cos(phi), r * np.sin(phi)
        else:
            a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
        return self.position + a[:, None] * self.axis_u + b[:, None] * self.axis_v

    def _inside(self, p: np.ndarray) -> np.ndarray:
        """(n,) 1.0 where points p (n, 3) of the light's plane lie in its disk or ellipse, else 0."""
        rel = p - self.position
        a = rel @ self.axis_u / (self.axis_u @ self.axis_u)
        b = rel @ self.axis_v / (self.axis_v @ self.axis_v)
        return (a * a + b * b <= 1.0).astype(np.float64)

    @property
    def power(self) -> float:
        return float(np.asarray(self.rgb_power) @ LUMINANCE)


class Environment(Light):
    """An HDRI world (`environment.EnvironmentMap`): importance-sampled, and reached by every
    ray that leaves the scene."""

    reachable = True
    at_infinity = True

    def __init__(self, environment: EnvironmentMap, group: str = ""):
        self.map, self.group = environment, group

    def sample(self, rng, x, ray_pdf: RayPdf, strata=1, normals=None) -> Sample:
        dirs, p_env = self.map.sample(rng, len(x))
        p_other = ray_pdf(dirs)
        return (
            dirs,
            self.map.radiance(dirs) * (p_env / (p_env * p_env + p_other * p_other))[:, None],
            np.full(len(x), np.inf),
        )

    def pdf(self, d, t=None, prim=None, origins=None, normals=None) -> np.ndarray:
        return self.map.pdf(d)

    def evaluate(self, d, t, prim, pdf, origins=None, normals=None) -> np.ndarray:
        p_env = self.map.pdf(d)
        return self.map.radiance(d) * (pdf * pdf / (pdf * pdf + p_env * p_env))[:, None]

    @property
    def power(self) -> float:
        h, w = self.map.pixels.shape[:2]
        theta = np.pi * (1.0 - (np.arange(h) + 0.5) / h)
        solid_angle = (2.0 * np.pi / w) * (np.pi / h) * np.sin(theta)
        return float(((self.map.pixels @ LUMINANCE) * solid_angle[:, None]).sum())


#: Most spatial clusters the emitting triangles of one light group are split into.
CLUSTERS = 32
#: Split clusters of more than one emitting triangle again into at most FANOUT clusters each, down
#: to single triangles (or MAX_LEAVES leaves): a light tree, descended at each shading point by
#: the same weights one level at a time, so a scene with thousands of emitters picks the one
#: beside the point, not a cluster's triangle by power alone. False: the top clusters alone.
LIGHT_TREE = True
FANOUT = 8
MAX_LEAVES = 4096
#: Below a node a shading point lies this many of its bounding radii or more from, the tree is
#: descended by power alone (no weights to evaluate): its leaves' weights differ little there.
DESCEND_RADII = 4.0
#: Share of the cluster choice made by power alone, whatever the distance: the distance bound
#: knows nothing of occlusion, so a bright emitter behind a wall keeps some samples.
POWER_SHARE = 0.1
#: A cluster of one triangle is weighed by the solid angle the triangle subtends (times its
#: luminance) instead of power over distance² at points within this many of its bounding radii:
#: power over distance² sees the two triangles of a lamp's quad alike from a point beside one of
#: them, though that one subtends nearly all the quad. 1: inside the bounding sphere, where
#: distance² says least (README, "Speed vs accuracy"); 0: never.
NEAR_RADII = 1.0


class EmissiveTriangles(Light):
    """The emitting triangles of one light group. triangles (T, 3, 3) world space (all of the
    scene's: primitive ids index them; kept for the emitting ones only, the others' rows zero);
    emission (T, 3) radiance, zero for triangles that do not emit or belong to another group.
    Empty (`len` 0) when nothing emits. Sampling: the module docstring (a cluster, a triangle ∝
    power, then a uniform point on it or a uniform direction in its solid angle)."""

    reachable = True

    def __init__(self, triangles: np.ndarray, emission: np.ndarray, group: str = ""):
        self.group = group
        self.emission = np.asarray(emission, np.float64)
        # per triangle (T rows: primitive ids index them), filled for those with emission only:
        # nothing reads the others', and a scene has far more triangles than emitters
        n = len(self.emission)
        lit = np.flatnonzero(self.emission @ LUMINANCE > 0.0)
        self.triangles = np.zeros((n, 3, 3))
        self.triangles[lit] = np.asarray(triangles)[lit]
        corners = self.triangles[lit]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.area = np.zeros(n)
        self.area[lit] = 0.5 * np.linalg.norm(cross, axis=1)
        power = np.zeros(n)
        power[lit] = self.area[lit] * (self.emission[lit] @ LUMINANCE)
        self.index = np.flatnonzero(power > 0.0)
        self.normal = np.zeros((n, 3))
        self.normal[lit] = cross / np.maximum(2.0 * self.area[lit], 1e-300)[:, None]
        # (T + 1,): does triangle t emit; the last entry, False, is what prim −1 (a miss) reads
        self.emits = np.zeros(len(self.triangles) + 1, bool)
        self.emits[self.index] = True
        # each emitter's bounding sphere (T, 4): centroid, farthest corner (light_kernels._surely_small)
        self.bound = np.zeros((len(self.triangles), 4))
        corners = self.triangles[self.index]
        centroid = corners.mean(axis=1)
        self.bound[self.index, :3] = centroid
        self.bound[self.index, 3] = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1) * (1 + 1e-12)
        self._cluster(power)

    def _cluster(self, power: np.ndarray) -> None:
        """The light tree over the emitters `index` (`light_tree`) and per node (N columns, in
        breadth-first order: a node's children are consecutive) its power `cluster_power` (N,),
        bounding-box centre `centre` (N, 3) and squared radius `radius2` (N,), the tree's links
        `child_first`, `child_count` (N + 1,: the last entry is the root, above the top clusters)
        and `parent` (N,: N for a top cluster); per triangle (T,) its leaf `cluster_of` and its
        probability within it `within`; the emitters sorted by leaf `order` and `key` (E,):
        leaf + cumulative share within it, each leaf's rows `first` .. `last`."""
        t = len(self.triangles)
        self.cluster_of = np.zeros(t, np.int64)
        self.within = np.zeros(t)
        if not len(self.index):
            self.cluster_power = np.zeros(0)
            self.centre, self.radius2 = np.zeros((0, 3)), np.zeros(0)
            self.order, self.key = self.index, np.zeros(0)
            self.first = self.last = self.lone = np.zeros(0, np.int64)
            self.child_first = self.child_count = np.zeros(1, np.int64)
            self.parent = np.zeros(0, np.int64)
            self.luminance = np.zeros(0)
            return
        corners = self.triangles[self.index]
        leaf, self.child_first, self.child_count, self.parent = light_tree(
            corners.mean(axis=1), CLUSTERS, FANOUT if LIGHT_TREE else 0, MAX_LEAVES
        )
        k = len(self.parent)
        self.cluster_of[self.index] = leaf
        power_of_leaf = np.bincount(leaf, power[self.index], minlength=k)
        self.within[self.index] = power[self.index] / power_of_leaf[leaf]
        lo = np.full((k, 3), np.inf)
        hi = np.full((k, 3), -np.inf)
        np.minimum.at(lo, leaf, corners.min(axis=1))
        np.maximum.at(hi, leaf, corners.max(axis=1))
        self.cluster_power = power_of_leaf
        for node in range(k - 1, -1, -1):  # children before parents (breadth-first order reversed)
            a, m = self.child_first[node], self.child_count[node]
            if m:
                lo[node], hi[node] = lo[a : a + m].min(axis=0), hi[a : a + m].max(axis=0)
                self.cluster_power[node] = self.cluster_power[a : a + m].sum()
        self.centre = 0.5 * (lo + hi)
        self.radius2 = np.maximum(0.25 * np.square(hi - lo).sum(axis=1), 1e-12)
        self.order = self.index[np.argsort(leaf, kind="stable")]
        sorted_leaf = self.cluster_of[self.order]
        share = self.within[self.order]
        cum = np.cumsum(share)
        count = np.bincount(sorted_leaf, minlength=k)
        first = np.searchsorted(sorted_leaf, np.arange(k))  # each leaf's first row in order
        last = first + count - 1
        is_leaf = count > 0
        self.key = sorted_leaf + (cum - (cum - share)[first[sorted_leaf]])
        self.key[last[is_leaf]] = np.flatnonzero(is_leaf) + 1.0  # each leaf's segment ends exactly at c + 1
        self.first, self.last = first, np.where(is_leaf, last, first)
        # a leaf of one triangle: its id and emitted luminance (`cluster_probability`)
        self.lone = np.where(count == 1, self.order[np.minimum(first, len(sorted_leaf) - 1)], -1)
        self.luminance = np.where(self.lone >= 0, self.cluster_power / np.maximum(self.area[self.lone], 1e-300), 0.0)

    def __len__(self) -> int:
        return len(self.index)

    def cluster_probability(self, x: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(R, N): the probability of picking each node of the light tree (a leaf, or any leaf
        below an inner node) at the points x (R, 3); the leaves' sum to 1 per row. Among the
        children of a node, each is picked ∝ its weight: its power over max(distance², radius²)
        to its bounding box's centre, times (given the points' `normals` (R, 3)) the largest
        cosine of a direction into the box's bounding sphere (0 below the horizon), mixed with
        POWER_SHARE ∝ power alone (power alone where every child is below the horizon); a leaf
        of one triangle seen from within NEAR_RADII of its radius weighs its luminance × the
        triangle's solid angle instead of power over distance² (where that is finite). numpy:
        the spec of the compiled choice (`light_kernels.sample_emitters`, `light_kernels.emitter_pdf`), the
        tests compare them."""
        phi = self.cluster_power
        if len(phi) == 1:
            return np.ones((len(x), 1))
        w = self._weights(x, normals)
        prob = np.zeros_like(w)
        root = len(phi)
        # below a node x lies DESCEND_RADII of its radius or more from: by power alone
        far = np.square(self.centre[None] - x[:, None, :]).sum(axis=2) >= DESCEND_RADII**2 * self.radius2
        far_above = np.zeros((len(x), root + 1), bool)
        for c in [root, *range(root)]:  # breadth first: a node's probability before its children's
            a, m = self.child_first[c], self.child_count[c]
            if m == 0:
                continue
            above = 1.0 if c == root else prob[:, c : c + 1]
            part, power = w[:, a : a + m], phi[a : a + m]
            total = part.sum(axis=1, keepdims=True)
            power_only = np.broadcast_to(power / power.sum(), part.shape)
            mixed = (1.0 - POWER_SHARE) * part / np.where(total > 0.0, total, 1.0) + POWER_SHARE * power_only
            by_power = (total <= 0.0) | far_above[:, c : c + 1]
            prob[:, a : a + m] = above * np.where(by_power, power_only, mixed)
            far_above[:, a : a + m] = far_above[:, c : c + 1] | far[:, a : a + m]
        return prob

    def _weights(self, x: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
        """(R, N): every node's weight at the points x (`cluster_probability`)."""
        phi = self.cluster_power
        to = self.centre[None] - x[:, None, :]
        d2 = np.square(to).sum(axis=2)
        w = phi / np.maximum(d2, self.radius2)
        if normals is not None:
            d = np.sqrt(d2)
            cos_t = np.einsum("rki,ri->rk", to, normals) / np.maximum(d, 1e-300)
            sin_a = np.sqrt(np.minimum(self.radius2 / np.maximum(d2, 1e-300), 1.0))
            cos_a = np.sqrt(1.0 - sin_a * sin_a)
            edge = np.maximum(cos_t * cos_a + np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0)) * sin_a, 0.0)
            w *= np.where((d2 > self.radius2) & (cos_t < cos_a), edge, 1.0)
        for c in np.flatnonzero(self.lone >= 0):
            omega = spherical_triangles(x, np.broadcast_to(self.triangles[self.lone[c]], (len(x), 3, 3)))[-1]
            near = (d2[:, c] < NEAR_RADII**2 * self.radius2[c]) & np.isfinite(omega) & (w[:, c] > 0.0)
            by_angle = w[:, c] * (self.luminance[c] * omega * np.maximum(d2[:, c], self.radius2[c]) / phi[c])
            w[:, c] = np.where(near, by_angle, w[:, c])
        return w

    def sample(self, rng, x, ray_pdf: RayPdf, strata=1, normals=None) -> Sample:
        dirs, dist, emitted, p_light = self._sample_points(rng, x, strata, normals)
        p_other = ray_pdf(dirs)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(p_light > 0.0, p_light / (p_light * p_light + p_other * p_other), 0.0)
        return dirs, emitted * weight[:, None], dist

    def _sample_points(self, rng, x, strata=1, normals=None, u=None):
        """One point per shading point x (R, 3) (normals (R, 3) or None): directions (R, 3),
        distances (R,), emitted radiance (R, 3) and the pdf per steradian (R,) (0: no sample, a
        grazing or coincident point). Compiled (`light_kernels.sample_emitters`); its random numbers
        u (4, R): cluster, triangle, then two for the point or direction, from `uniforms`
        (strata) unless given."""
        r = len(x)
        if u is None:
            u = np.stack([uniforms(rng, r, strata, dim) for dim in range(4)])
        tri = (self.triangles, self.normal, self.area, self.within)
        dirs, dist, pick, pdf = _kernels.get().sample_emitters(
            _rows(x), _rows(normals), u, *tri, self._emitters(), POWER_SHARE, SOLID_ANGLE_RANGE
        )
        return dirs, dist, self.emission[pick], pdf

    def _emitters(self) -> tuple:
        """The cluster arrays the kernels take (`light_kernels.sample_emitters`)."""
        radius2 = self.radius2
        rows = [self.centre.T, radius2, np.sqrt(radius2), self.cluster_power, self.lone, self.luminance]
        rows += [NEAR_RADII**2 * radius2, DESCEND_RADII**2 * radius2]
        clusters = np.ascontiguousarray(np.vstack(rows), np.float64)
        tree = (self.child_first, self.child_count, self.parent)
        return (clusters, self.key, self.order, self.first, self.last, self.bound, *tree)

    def pdf(self, d, t=None, prim=None, origins=None, normals=None) -> np.ndarray:
        """Density per steradian of sampling, from `origins` (R, 3) with `normals` (R, 3) or
        None, the point at distance t (float64) along d on triangle prim (an emitter or not: 0
        for non-emitters). Compiled (`light_kernels.emitter_pdf`)."""
        if origins is None:
            raise ValueError("the emitters' density depends on where the ray starts: pass origins")
        if not len(self.index):
            return np.zeros(len(d))
        tri = (self.triangles, self.normal, self.area, self.within, self.cluster_of)
        return _kernels.get().emitter_pdf(
            _rows(origins),
            _rows(normals),
            _rows(d),
            np.ascontiguousarray(t, np.float64),
            np.ascontiguousarray(prim, np.int64),
            *tri,
            self._emitters(),
            POWER_SHARE,
            SOLID_ANGLE_RANGE,
        )

    def reached(self, prim: np.ndarray) -> np.ndarray:
        """The rows (int64) of the rays, ending on triangles prim (R,) (−1: a miss), that reached
        one of these emitters: the only ones `evaluate` gives light."""
        return np.flatnonzero(self.emits[prim])

    def evaluate(self, d, t, prim, pdf, origins=None, normals=None) -> np.ndarray:
        p_light = self.pdf(d, t.astype(np.float64), prim, origins, normals)
        weight = pdf * pdf / np.maximum(pdf * pdf + p_light * p_light, 1e-300)
        return self.emission[prim] * weight[:, None]

    @property
    def power(self) -> float:
        """Both sides of a Lambertian emitter: 2π · Σ area × emitted luminance."""
        return float(2.0 * np.pi * (self.area * np.maximum(self.emission @ LUMINANCE, 0.0)).sum())


#: Solid angles (sr) within which an emitting triangle is sampled by a uniform direction in it
#: (`sample_spherical_triangles`) rather than a uniform point on it: below, the spherical
#: formulas lose precision and the two agree anyway; above, a triangle fills most of a
#: hemisphere (PBRT-v4's bounds).
SOLID_ANGLE_RANGE = (3e-4, 6.22)


def by_solid_angle(solid_angle: np.ndarray) -> np.ndarray:
    """(R,) bool: the triangles of these solid angles (R,) are sampled by direction."""
    return (solid_angle >= SOLID_ANGLE_RANGE[0]) & (solid_angle <= SOLID_ANGLE_RANGE[1])


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spherical_triangles(x: np.ndarray, tri: np.ndarray):
    """(numpy: the spec of the compiled `light_kernels._spherical`, the tests compare them.)
    The spherical triangles triangles tri (R, 3, 3) make seen from points x (R, 3): unit
    directions a, b, c (R, 3) to their corners, the cosine and sine of the angle at a (R,) and
    the solid angle (R,) in steradians (0 seen edge-on, NaN from a corner). With D = |a·(b×c)|:
    the solid angle is 2·atan2(D, 1 + a·b + b·c + c·a) (Van Oosterom & Strackee 1983) and the
    angle at a is atan2(D, b·c − (a·b)(c·a)) (the spherical laws of cosines and sines)."""
    a, b, c = (_unit(tri[:, i] - x) for i in range(3))
    ab, bc, ca = (np.einsum("ri,ri->r", p, q) for p, q in ((a, b), (b, c), (c, a)))
    det = np.abs(np.einsum("ri,ri->r", a, np.cross(b, c)))
    y = bc - ab * ca
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.sqrt(det * det + y * y)
        return a, b, c, y / h, det / h, 2.0 * np.arctan2(det, 1.0 + ab + bc + ca)


def sample_spherical_triangles(x: np.ndarray, tri: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Unit directions (R, 3) from x (R, 3) uniform in the solid angle of triangles tri (R, 3, 3)
    for uniform numbers u1, u2 (R,) (Arvo 1995, in PBRT-v4's SampleSphericalTriangle form).
    numpy: the spec of the compiled `light_kernels._spherical_direction`, the tests compare them."""
    a, b, c, cos_a, sin_a, area = spherical_triangles(x, tri)
    s, q = -np.sin(u1 * area), -np.cos(u1 * area)  # sine and cosine of π + the sub-triangle's area
    sin_phi = s * cos_a - q * sin_a
    cos_phi = q * cos_a + s * sin_a
    k1 = cos_phi + cos_a
    k2 = sin_phi - sin_a * np.einsum("ri,ri->r", a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_bp = np.clip((k2 + (k2 * cos_phi - k1 * sin_phi) * cos_a) / ((k2 * sin_phi + k1 * cos_phi) * sin_a), -1, 1)
    sin_bp = np.sqrt(np.maximum(1.0 - cos_bp * cos_bp, 0.0))
    cp = cos_bp[:, None] * a + sin_bp[:, None] * _unit(c - np.einsum("ri,ri->r", c, a)[:, None] * a)
    cos_t = 1.0 - u2 * (1.0 - np.einsum("ri,ri->r", cp, b))
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    return _unit(cos_t[:, None] * b + sin_t[:, None] * _unit(cp - np.einsum("ri,ri->r", cp, b)[:, None] * b))


def sample_spherical_rectangles(
    x: np.ndarray, corner: np.ndarray, ex: np.ndarray, ey: np.ndarray, u1: np.ndarray, u2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points (R, 3) on the rectangle corner + s·ex + t·ey (corner, ex, ey (3,); ex ⟂ ey; s, t in
    [0, 1]) whose directions from x (R, 3) are uniform in the solid angle it subtends there, for
    uniform numbers u1, u2 (R,), and that solid angle (R,) in steradians (0 from its plane; NaN
    where it cannot be found). Ureña, Fajardo & King 2013, in PBRT-v4's SampleSphericalRectangle
    form: in a frame with z away from the rectangle, the solid angle is the sum of the angles
    between the planes through x and its edges, less 2π; u1 picks the x of the point by the
    solid angle left of it, u2 its y, uniformly in the sine of the elevation."""
    exl, eyl = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
    ax, ay = ex / exl, ey / eyl
    az = np.cross(ax, ay)
    d = corner - x
    x0, y0, z = d @ ax, d @ ay, d @ az
    h = np.abs(z)  # the local z axis points away from the rectangle: z0 = −h
    x1, y1 = x0 + exl, y0 + eyl
    zz = z * z
    # corner angles g_i = arg(c_i + i·s_i) (between the planes through x and two edges), summed
    # by multiplying: the solid angle Σg − 2π takes one arctan, and au needs only cos and sin of
    # g2 + g3 (au = u1·solid angle − g2 − g3 ≡ Ureña's u1·S + 2π − g2 − g3)
    c0, s0 = x1 * y0, h * np.sqrt(x1 * x1 + y0 * y0 + zz)
    c1, s1 = -x1 * y1, h * np.sqrt(x1 * x1 + y1 * y1 + zz)
    c2, s2 = x0 * y1, h * np.sqrt(x0 * x0 + y1 * y1 + zz)
    c3, s3 = -x0 * y0, h * np.sqrt(x0 * x0 + y0 * y0 + zz)
    ca, sa = c0 * c1 - s0 * s1, c0 * s1 + s0 * c1
    cb, sb = c2 * c3 - s2 * s3, c2 * s3 + s2 * c3
    solid_angle = np.mod(np.arctan2(ca * sb + sa * cb, ca * cb - sa * sb), 2.0 * np.pi)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.sqrt(cb * cb + sb * sb)
        v = u1 * solid_angle
        cos_au = (np.cos(v) * cb + np.sin(v) * sb) * inv
        sin_au = (np.sin(v) * cb - np.cos(v) * sb) * inv
        b0, b1 = -y0 / np.sqrt(zz + y0 * y0), y1 / np.sqrt(zz + y1 * y1)
        fu = (cos_au * b0 - b1) / sin_au
        cu = np.clip(np.copysign(1.0 / np.sqrt(fu * fu + b0 * b0), fu), -1.0 + 1e-12, 1.0 - 1e-12)
        xu = np.clip(h * cu / np.sqrt(1.0 - cu * cu), x0, x1)
        dd = np.sqrt(xu * xu + zz)
        h0, h1 = y0 / np.sqrt(dd * dd + y0 * y0), y1 / np.sqrt(dd * dd + y1 * y1)
        hv = h0 + u2 * (h1 - h0)
        yv = np.where(hv * hv < 1.0 - 1e-12, hv * dd / np.sqrt(np.maximum(1.0 - hv * hv, 1e-300)), y1)
    points = x + xu[:, None] * ax + yv[:, None] * ay + z[:, None] * az
    return points, np.where(z == 0.0, 0.0, solid_angle)


def _rows(a: np.ndarray | None) -> np.ndarray:
    """`a` (R, 3) as contiguous float64 for the kernels; None as no rows (0, 3)."""
    return np.zeros((0, 3)) if a is None else np.ascontiguousarray(a, np.float64)


def cluster_splits(centroids: np.ndarray, most: int) -> np.ndarray:
    """(E,) cluster ids 0..K-1 (K ≤ `most`) of points `centroids` (E, 3): the cluster whose points'
    box has the longest diagonal is split at the middle of its longest axis (both halves keep
    points), until there are `most` clusters or every cluster's points coincide."""
    ids = np.zeros(len(centroids), np.int64)
    extent = [float(np.linalg.norm(np.ptp(centroids, axis=0)))] if len(centroids) else [0.0]
    while len(extent) < most:  # at most `most` splits, each over one cluster's points
        c = int(np.argmax(extent))
        if extent[c] <= 0.0:
            break
        members = np.flatnonzero(ids == c)
        pts = centroids[members]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        axis = int(np.argmax(hi - lo))
        upper = pts[:, axis] >= 0.5 * (lo[axis] + hi[axis])
        if upper.all():  # the middle rounds onto the lowest point: split off the lowest points
            upper = pts[:, axis] > lo[axis]
        ids[members[upper]] = len(extent)
        extent[c] = float(np.linalg.norm(np.ptp(pts[~upper], axis=0)))
        extent.append(float(np.linalg.norm(np.ptp(pts[upper], axis=0))))
    return ids


def light_tree(centroids: np.ndarray, top: int, fanout: int, most_leaves: int):
    """A tree of spatial clusters over points `centroids` (E, 3): at most `top` top clusters
    (`cluster_splits`), each cluster of more than one point split again into at most `fanout`
    (`cluster_splits` of its points), breadth first, until every leaf holds one point (or
    coincident points) or there are `most_leaves` leaves; fanout 0: the top clusters alone.
    Returns (leaf (E,) each point's leaf, child_first (N + 1,), child_count (N + 1,), parent
    (N,)) over N nodes numbered breadth first, so a node's children are consecutive (0 children:
    a leaf); entry N of the first two is the root above the top clusters, which parent N names."""
    ids = cluster_splits(centroids, top)
    k = int(ids.max()) + 1
    members = [np.flatnonzero(ids == c) for c in range(k)]
    child_first, child_count, parent = [0] * k, [0] * k, [-1] * k  # the root's entry is appended last
    leaves, c = k, 0
    while fanout and c < len(members) and leaves < most_leaves:
        m = members[c]
        sub = cluster_splits(centroids[m], min(fanout, most_leaves - leaves + 1)) if len(m) > 1 else ids[:0]
        n = int(sub.max()) + 1 if len(sub) else 1
        if n > 1:
            child_first[c], child_count[c] = len(members), n
            for j in range(n):
                members.append(m[sub == j])
                child_first.append(0)
                child_count.append(0)
                parent.append(c)
            leaves += n - 1
        c += 1
    nodes = len(members)
    leaf = np.zeros(len(centroids), np.int64)
    for c in range(nodes):
        if child_count[c] == 0:
            leaf[members[c]] = c
    parent_of = np.array([nodes if p < 0 else p for p in parent], np.int64)
    return leaf, np.array(child_first + [0], np.int64), np.array(child_count + [k], np.int64), parent_of


#: The sampling class of each light data type of core.scene.
KINDS = {SunLight: Sun, PointLight: Point, SpotLight: Spot, AreaLight: Area}


def build(scene: BakeScene) -> list[Light]:
    """The scene's lights in sampling order: `scene.lights` in order, the HDRI world, then one
    EmissiveTriangles per emission group (sorted by name) that emits anything."""
    out = [_light(light) for light in scene.lights]
    if scene.environment is not None:
        out.append(Environment(scene.environment, scene.environment.group))
    if scene.emission is not None:
        for group, emission in _emission_groups(scene.emission, scene.emission_group):
            emitters = EmissiveTriangles(scene.triangles, emission, group)
            if len(emitters):
                out.append(emitters)
    return out


def _light(light) -> Light:
    kind = next((KINDS[c] for c in type(light).__mro__ if c in KINDS), None)
    if kind is None:
        raise BakeError(f"unsupported light {type(light).__name__}")
    return kind(light)


def _emission_groups(emission: np.ndarray, groups: np.ndarray | None) -> list[tuple[str, np.ndarray]]:
    """(group, emission (T, 3) with the other groups' triangles zeroed) per group of the emitting
    triangles, sorted by name; `groups` (T,) str or None (all "")."""
    if groups is None:
        return [("", emission)]
    group = np.asarray(groups).astype(str)
    names = sorted(set(group[np.flatnonzero(emission.any(axis=1))].tolist()))
    if len(names) <= 1:
        return [(names[0] if names else "", emission)]
    return [(name, np.where((group == name)[:, None], emission, 0.0)) for name in names]


#: Whether a shading point picks one of the point, spot and area lights (`Choice`); False
#: samples every one of them at every point, as until 2026-12-05 (bench/light_sampling.py).
CHOOSE = True
#: Share of a shading point's choice among point, spot and area lights made by intensity alone
#: (`Choice`), as POWER_SHARE is the emitter clusters': the bound knows nothing of occlusion.
CHOICE_SHARE = POWER_SHARE
#: The dimension of `uniforms` the choice draws its number from (the lights' own use 0–3).
CHOICE_DIM = 4


class Choice:
    """Which one of the scene's point, spot and area lights (`Light.chosen`: lights rays never
    reach, at a place) a shading point samples, instead of every one of them: light l with
    probability ∝ its largest radiant intensity × a bound on the cosine at the light (0 behind
    a one-sided area light's plane) × the horizon bound at the point, over max(d², r²), mixed
    with CHOICE_SHARE of intensity alone among the lights that can light the point
    (`light_kernels.choose_lights`). Its sample is divided by that probability: unbiased. A light that
    cannot light a point (behind a one-sided lamp, outside a spot's cone, or wholly below the
    point's horizon) is never picked there, and a point no light can light samples none (no
    shadow ray)."""

    def __init__(self, lights: list[Light]):
        self.lights = lights
        self.table = np.array([light.choice_row() for light in lights], np.float64).reshape(-1, 13)

    def pick(self, rng, x: np.ndarray, normals: np.ndarray | None, strata: Strata) -> tuple[np.ndarray, np.ndarray]:
        """(choice (R,) int64: an index into `lights` or −1 for none, probability (R,)) at the
        points x (R, 3) with `normals` (R, 3) or None; the numbers from `uniforms` (strata)."""
        u = np.ascontiguousarray(uniforms(rng, len(x), strata, CHOICE_DIM), np.float64)
        return _kernels.get().choose_lights(_rows(x), _rows(normals), u, self.table, CHOICE_SHARE)


@dataclass
class Subset:
    """The numbers of some rows (R',) of n points, each as `strata` gives it for all n: a light
    sampled only at the points that chose it (`Choice`) draws what it would have drawn there.
    `drawn` (dimension → (n,) numbers) is shared by the lights of one choice, whose rows are
    disjoint: each dimension is drawn once for all of them."""

    strata: Strata
    n: int
    rows: np.ndarray
    rng: np.random.Generator
    drawn: dict[int, np.ndarray] = field(default_factory=dict)

    def uniforms(self, dim: int) -> np.ndarray:
        if dim not in self.drawn:
            self.drawn[dim] = uniforms(self.rng, self.n, self.strata, dim)
        return self.drawn[dim][self.rows]


@dataclass(frozen=True)
class TexelStream:
    """Where a pass's light samples come from when they are grouped by texel: the texels (n,)
    (bake point ids), k samples each, the pass's first sample index (pass × k) and the bake's
    seed. `uniforms` then takes dimension `dim` of each texel's own sequence
    (`sampling.texel_sequence`), stratified across every pass of the texel, not only this one."""

    texels: np.ndarray
    k: int
    first: int
    seed: int

    def uniforms(self, dim: int) -> np.ndarray:
        texels = np.ascontiguousarray(self.texels, np.int64)
        return sampling.get().texel_sequence(texels, self.k, self.first, dim, self.seed)


@dataclass
class RowStream:
    """Where the light samples of some rows of a pass come from: rows (R,) of the pass's
    samples (row t·k + j: sample j of texel `texels[t]`, global ids (n,)), k samples per texel,
    the pass's first sample index (pass × k), the bake's seed and the first stream number.
    `uniforms(dim)` takes each row's number from its texel's own (0,2)-sequence for the pair of
    dimensions dim // 2 (`sampling.row_sequence`), stratified across every pass of the texel:
    the light sample at a path's first bounce, say, is stratified like the texel's own."""

    rows: np.ndarray
    texels: np.ndarray
    k: int
    first: int
    seed: int
    stream: int
    _pair: tuple[int, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def uniforms(self, dim: int) -> np.ndarray:
        stream = self.stream + dim // 2
        if self._pair is None or self._pair[0] != stream:  # dims 2j and 2j + 1 share one pair
            rows = np.ascontiguousarray(self.rows, np.int64)
            texels = np.ascontiguousarray(self.texels, np.int64)
            self._pair = (stream, sampling.get().row_sequence(rows, texels, self.k, self.first, self.seed, stream))
        return self._pair[1][dim % 2]


#: `Light.sample`'s strata: a group size (int), a TexelStream, a RowStream or a Subset of one.
Strata = int | TexelStream | RowStream | Subset


def uniforms(rng: np.random.Generator, n: int, strata: Strata = 1, dim: int = 0) -> np.ndarray:
    """(n,) uniform numbers in [0, 1) for dimension `dim` of a light's sampling. A TexelStream:
    its texels' own sequences (n must be its texels × k); a RowStream: its rows' (n rows). An int > 1 (and n a multiple of it):
    each group of `strata` consecutive numbers is stratified, one in each [j/strata,
    (j+1)/strata), in random order (a Latin hypercube when several dimensions are drawn so).
    Either way each number is still uniform, so estimates stay unbiased, while a texel's light
    samples cover the light evenly."""
    if isinstance(strata, (TexelStream, RowStream, Subset)):
        return strata.uniforms(dim)
    if strata <= 1 or n % strata:
        return rng.random(n)
    order = np.argsort(rng.random((n // strata, strata)), axis=1)
    return ((order + rng.random((n // strata, strata))) / strata).reshape(n)


def _cone_directions(rng, axis: np.ndarray, cos_max, strata: Strata = 1) -> np.ndarray:
    """Uniform directions in cones around `axis` (R, 3) with half-angle arccos(cos_max)
    (`strata`: `uniforms`)."""
    u1, u2 = uniforms(rng, len(axis), strata, 2), uniforms(rng, len(axis), strata, 3)
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return np.einsum("rij,rj->ri", _sh.tangent_frames(axis), local)
