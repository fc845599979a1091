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

from ...errors import BakeError
from ...scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from . import choice, tree  # noqa: F401  (lights.choice, lights.tree: the package's other modules)
from .emitters import EmissiveTriangles, _emission_groups
from .lamps import Area, Point, Spot, Sun
from .light import Light
from .world import Environment

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
