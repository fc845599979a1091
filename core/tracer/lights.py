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

Emissive triangles are picked with probability ∝ their power (area × emitted luminance;
emission is two-sided, so both sides count alike), then a uniform point on the triangle. Array
conventions: x (R, 3) shading points, directions (R, 3) unit, world space; densities per steradian.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

from .. import sh as _sh
from ..colour import LUMINANCE
from ..environment import EnvironmentMap
from ..errors import BakeError
from ..scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight

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

    @abstractmethod
    def sample(self, rng: np.random.Generator, x: np.ndarray, ray_pdf: RayPdf) -> Sample:
        """One sample per shading point x (R, 3), drawn from `rng` (see `Sample`); a reachable
        light weights it against `ray_pdf`, the others ignore it."""

    def pdf(self, d: np.ndarray, t: np.ndarray | None = None, prim: np.ndarray | None = None) -> np.ndarray:
        """Density per steradian (R,) with which `sample` picks the point a ray along d (R, 3)
        reached (at distance t (R,) on triangle prim (R,), where that applies); 0 for a light
        rays never reach."""
        return np.zeros(len(d))

    def evaluate(self, d: np.ndarray, t: np.ndarray | None, prim: np.ndarray | None, pdf: np.ndarray) -> np.ndarray:
        """Radiance (R, 3) that rays along d (R, 3), sampled with density `pdf` (R,), bring from
        this light (ending at distance t on triangle prim, where that applies), MIS-weighted
        against `sample`; 0 for a light rays never reach."""
        return np.zeros((len(d), 3))

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

    def sample(self, rng, x, ray_pdf=None) -> Sample:
        r = len(x)
        axis = np.broadcast_to(self.direction, (r, 3))
        dirs = axis if self.is_delta else _cone_directions(rng, axis, np.cos(0.5 * self.angle))
        return dirs, np.broadcast_to(self.irradiance, (r, 3)), np.full(r, np.inf)

    @property
    def power(self) -> float:
        return float(np.asarray(self.irradiance) @ LUMINANCE)


class Point(Light):
    """A point light of power P (W, RGB): a true point (radius 0, exact direction) or, with a
    radius r, radiance P/(4π² r²) over the cone it subtends, sampled uniformly: a disk facing the
    shaded point with soft falloff (Blender's default), else a sphere (Cycles' point_light_sample)."""

    def __init__(self, light: PointLight):
        self.position, self.rgb_power, self.radius = light.position, light.power, light.radius
        self.soft_falloff, self.is_delta, self.group = light.soft_falloff, light.is_delta, light.group

    def sample(self, rng, x, ray_pdf=None) -> Sample:
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
        return _cone_directions(rng, axis, cos_a), value, np.maximum(dist - self.radius, 0.0)

    @property
    def power(self) -> float:
        return float(np.asarray(self.rgb_power) @ LUMINANCE)


class Spot(Point):
    """A point light limited to a cone (core.scene.SpotLight): Cycles' smoothstep attenuation of
    the angle between the spot's axis and the direction from the light to the shaded point."""

    def __init__(self, light: SpotLight):
        super().__init__(light)
        self.axis, self.size, self.blend = light.direction, light.size, light.blend

    def sample(self, rng, x, ray_pdf=None) -> Sample:
        dirs, value, dist = super().sample(rng, x)
        return dirs, value * self.attenuation(-dirs)[:, None], dist

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
    radiance P / (π A), sampled by a uniform point on its surface."""

    def __init__(self, light: AreaLight):
        self.position, self.axis_u, self.axis_v = light.position, light.axis_u, light.axis_v
        self.normal, self.rgb_power, self.shape = light.normal, light.power, light.shape
        self.area, self.group = light.area, light.group

    def sample(self, rng, x, ray_pdf=None) -> Sample:
        p = self.sample_points(rng, len(x))
        to = p - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        dirs = to / dist[:, None]
        cos_l = np.maximum(-(dirs @ self.normal), 0.0)
        radiance = self.rgb_power / (np.pi * self.area)
        # radiance × (solid angle of the sampled area element = A cos_l / d²)
        return dirs, radiance[None, :] * (self.area * cos_l / dist**2)[:, None], dist

    def sample_points(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n points (n, 3) uniform over the light's surface."""
        if self.shape in ("DISK", "ELLIPSE"):
            r, phi = np.sqrt(rng.random(n)), 2.0 * np.pi * rng.random(n)
            a, b = r * np.cos(phi), r * np.sin(phi)
        else:
            a, b = 2.0 * rng.random(n) - 1.0, 2.0 * rng.random(n) - 1.0
        return self.position + a[:, None] * self.axis_u + b[:, None] * self.axis_v

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

    def sample(self, rng, x, ray_pdf: RayPdf) -> Sample:
        dirs, p_env = self.map.sample(rng, len(x))
        p_other = ray_pdf(dirs)
        return (
            dirs,
            self.map.radiance(dirs) * (p_env / (p_env * p_env + p_other * p_other))[:, None],
            np.full(len(x), np.inf),
        )

    def pdf(self, d, t=None, prim=None) -> np.ndarray:
        return self.map.pdf(d)

    def evaluate(self, d, t, prim, pdf) -> np.ndarray:
        p_env = self.map.pdf(d)
        return self.map.radiance(d) * (pdf * pdf / (pdf * pdf + p_env * p_env))[:, None]

    @property
    def power(self) -> float:
        h, w = self.map.pixels.shape[:2]
        theta = np.pi * (1.0 - (np.arange(h) + 0.5) / h)
        solid_angle = (2.0 * np.pi / w) * (np.pi / h) * np.sin(theta)
        return float(((self.map.pixels @ LUMINANCE) * solid_angle[:, None]).sum())


class EmissiveTriangles(Light):
    """The emitting triangles of one light group. triangles (T, 3, 3) world space (all of the
    scene's: primitive ids index them); emission (T, 3) radiance, zero for triangles that do not
    emit or belong to another group. Empty (`len` 0) when nothing emits."""

    reachable = True

    def __init__(self, triangles: np.ndarray, emission: np.ndarray, group: str = ""):
        self.group = group
        self.triangles = np.asarray(triangles, np.float64)
        self.emission = np.asarray(emission, np.float64)
        cross = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        self.area = 0.5 * np.linalg.norm(cross, axis=1)
        power = self.area * np.maximum(self.emission @ LUMINANCE, 0.0)
        self.index = np.nonzero(power > 0.0)[0]
        self.probability = np.zeros(len(self.triangles))
        if len(self.index):
            self.probability[self.index] = power[self.index] / power[self.index].sum()
        self.cdf = np.cumsum(self.probability[self.index])
        if len(self.cdf):
            self.cdf /= self.cdf[-1]
        self.normal = cross / np.maximum(2.0 * self.area, 1e-300)[:, None]

    def __len__(self) -> int:
        return len(self.index)

    def sample(self, rng, x, ray_pdf: RayPdf) -> Sample:
        dirs, dist, emitted, p_light = self._sample_points(rng, x)
        p_other = ray_pdf(dirs)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(p_light > 0.0, p_light / (p_light * p_light + p_other * p_other), 0.0)
        return dirs, emitted * weight[:, None], dist

    def _sample_points(self, rng, x):
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
        return dirs, dist, self.emission[pick], self.pdf(dirs, dist, pick)

    def pdf(self, d, t=None, prim=None) -> np.ndarray:
        """Density per steradian of sampling the point at distance t (float64) along d on
        triangle prim (an emitter or not: 0 for non-emitters)."""
        cos = np.abs(np.einsum("ri,ri->r", d, self.normal[prim]))
        with np.errstate(divide="ignore", invalid="ignore"):
            density = self.probability[prim] / self.area[prim] * t * t / cos
        return np.where((cos > 1e-12) & np.isfinite(density), density, 0.0)

    def evaluate(self, d, t, prim, pdf) -> np.ndarray:
        p_light = self.pdf(d, t.astype(np.float64), prim)
        weight = pdf * pdf / np.maximum(pdf * pdf + p_light * p_light, 1e-300)
        return self.emission[prim] * weight[:, None]

    @property
    def power(self) -> float:
        """Both sides of a Lambertian emitter: 2π · Σ area × emitted luminance."""
        return float(2.0 * np.pi * (self.area * np.maximum(self.emission @ LUMINANCE, 0.0)).sum())


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


def _cone_directions(rng, axis: np.ndarray, cos_max) -> np.ndarray:
    """Uniform directions in cones around `axis` (R, 3) with half-angle arccos(cos_max)."""
    u1, u2 = rng.random(len(axis)), rng.random(len(axis))
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return np.einsum("rij,rj->ri", _sh.tangent_frames(axis), local)
