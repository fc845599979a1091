"""BakeScene: everything the tracer needs, as plain numpy (the only thing read from bpy). No bpy.

Units follow Blender/Cycles (checked against Cycles' Diffuse bake in tests/test_bake_cycles.py):
  * radiance: W/(m²·sr) as Cycles emission and world strength (strength × colour);
  * sun: `irradiance` = strength × colour, W/m² on a surface facing it; our irradiance unit
    (docs/conventions.md#irradiance-units, E = (1/π)∫L cos) is then S cosθ / π;
  * point light: `power` = power × colour, W; a surface at distance d facing it gets
    E = P / (4π² d²) in our unit, i.e. its radiance SH is P/(4π d²) · Y(l). With a radius r it
    has radiance P / (4π² r²) over the cone it subtends: with Blender's default "soft falloff"
    a disk of radius r facing the shaded point (cos α = d/√(d² + r²)), without it a sphere
    (cos α = √(1 - r²/d²)) — as Cycles' point_light_sample does.

Lights are plain data here; how each type is sampled lives in one place, `core.tracer.lights`.
`group` (every light, and `BakeScene.emission_group` per emissive triangle) names the light group
a light belongs to ("": the default set); a bake's light sets are its emitters' groups
(`light_set_names`; their files and blending: `core.light_sets`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .environment import EnvironmentMap

#: The light set of the emitters in no light group.
DEFAULT_LIGHT_SET = "Default"


def light_set_of(group: str) -> str:
    """The light set of an emitter of light group `group` ("" = none: DEFAULT_LIGHT_SET)."""
    return group or DEFAULT_LIGHT_SET


def light_set_names(groups: Sequence[str]) -> tuple[str, ...]:
    """The light sets of a bake whose emitting lights have these light `groups` (one entry per
    emitter, "" = no group): () when no emitter is in a group (an ordinary bake, no set files),
    else the sets in use sorted by name (DEFAULT_LIGHT_SET among them if some emitter has none)."""
    if not any(groups):
        return ()
    return tuple(sorted({light_set_of(g) for g in groups}))


@dataclass
class SunLight:
    """direction (3,) unit, towards the sun; irradiance (3,) W/m²; angle: angular diameter, rad."""

    direction: np.ndarray
    irradiance: np.ndarray
    angle: float = 0.0
    group: str = field(default="", kw_only=True)

    @property
    def is_delta(self) -> bool:
        return self.angle <= 0.0


@dataclass
class PointLight:
    """position (3,) m; power (3,) W; radius m (0: a true point, noise-free); soft_falloff:
    Blender's use_soft_falloff (disk facing the shaded point) rather than a sphere."""

    position: np.ndarray
    power: np.ndarray
    radius: float = 0.0
    soft_falloff: bool = True
    group: str = field(default="", kw_only=True)

    @property
    def is_delta(self) -> bool:
        return self.radius <= 0.0


@dataclass
class SpotLight(PointLight):
    """A point light (same units and radius models) limited to a cone: direction (3,) unit, the
    way it points; size: full cone angle, rad; blend in [0, 1]. Cycles' attenuation:
    smoothstep((cos φ - cos(size/2)) / ((1 - cos(size/2)) · blend)), φ the angle between the
    spot axis and the direction from the light to the shaded point (a hard edge for blend 0)."""

    direction: np.ndarray = None  # type: ignore[assignment]  # required: a default only because PointLight's fields have them
    size: float = np.pi / 4
    blend: float = 0.15


@dataclass
class AreaLight:
    """A one-sided Lambertian emitter: position (3,) centre; axis_u, axis_v (3,) half-extent
    vectors of the light's plane (length = half size); normal (3,) unit, the side it emits to;
    power (3,) W; shape 'SQUARE' | 'RECTANGLE' | 'DISK' | 'ELLIPSE'. Radiance P / (π A)."""

    position: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray
    power: np.ndarray
    shape: str = "SQUARE"
    group: str = field(default="", kw_only=True)
    is_delta = False

    @property
    def area(self) -> float:
        full = 4.0 * np.linalg.norm(self.axis_u) * np.linalg.norm(self.axis_v)
        return full * (np.pi / 4.0 if self.shape in ("DISK", "ELLIPSE") else 1.0)


@dataclass
class BakeScene:
    """triangles (T, 3, 3) world space, all geometry that casts shadows or reflects light;
    albedo (T, 3) linear RGB in [0, 1] (used where a triangle has no texture); optional texture
    albedo: texture_index (T,) int (-1: none), texture_uv (T, 3, 2), textures [textures.Texture];
    emission (T, 3) radiance, emitted on both sides; emission_group (T,) str, optional: the light
    group of each triangle's emission (None: all ""); lights: SunLight / PointLight / SpotLight / AreaLight; world:
    background radiance (3,) or None (black); world_group: the light group of the constant
    world (an environment carries its own `group`); environment: an HDRI world
    (`environment.EnvironmentMap`, importance-sampled with MIS) in place of `world`; notes: what
    the extraction approximated."""

    triangles: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray | None = None
    lights: list = field(default_factory=list)
    world: np.ndarray | None = None
    texture_index: np.ndarray | None = None
    texture_uv: np.ndarray | None = None
    textures: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    environment: EnvironmentMap | None = None
    emission_group: np.ndarray | None = None
    world_group: str = ""

    def albedo_at(self, prim: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Albedo (R, 3) at hit points given by triangle and barycentrics (u, v)."""
        out = self.albedo[prim]
        if self.texture_index is None or not self.textures:
            return out
        tex, texture_uv = self.texture_index[prim], self.texture_uv
        assert texture_uv is not None, "texture_index without texture_uv"
        for k, image in enumerate(self.textures):
            rows = np.nonzero(tex == k)[0]
            if len(rows):
                uv = texture_uv[prim[rows]]
                w = np.stack([1.0 - u[rows] - v[rows], u[rows], v[rows]], axis=1)
                out[rows] = image.sample(np.einsum("rk,rki->ri", w, uv))
        return out

    def __post_init__(self):
        self.triangles = np.asarray(self.triangles, dtype=np.float64)
        self.albedo = np.clip(np.asarray(self.albedo, dtype=np.float64), 0.0, 1.0)
        if self.emission is not None:
            self.emission = np.asarray(self.emission, dtype=np.float64)
            if not self.emission.any():
                self.emission = None  # model only what the scene has
        if self.world is not None:
            self.world = np.asarray(self.world, dtype=np.float64)
            if not self.world.any():
                self.world = None
        if self.environment is not None and self.environment.is_black:
            self.environment = None
        if self.environment is not None and self.world is not None:
            raise ValueError("a BakeScene has either a constant world or an environment map, not both")
