"""The leak audit's fixtures as plain numpy (no bpy): boxes and floor quads, a sun, and the exact
answer each texel must have. bench/leaks.py builds them in Blender (to bake them with Cycles
too); tests/test_leaks.py bakes them with the core alone.

Every fixture is lit by one sun of zero angle (a delta light: an unshadowed texel gets exactly
S·cosθ/π, a shadowed one exactly 0, with no noise) and no world, so its truth is geometric:
`Fixture.expect` gives, per texel centre, 0 (in shadow or in the closed dark room), 1 (fully
lit: S·cosθ/π) or NaN (no exact answer: a shadow's own edge crosses the texel, or the texel
centre is hidden under geometry, so no one sees it). Lengths in metres, Z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .meshes import BOX_QUADS, box_corners

#: a texel this close to a shadow edge cast by the fixture's own geometry (in texel sizes)
#: has no exact value: its footprint is partly lit, legitimately
EDGE_MARGIN = 1.5
ALBEDO = 0.8


@dataclass
class Part:
    """An axis-aligned box (lo, hi) with outward faces, or, with `quad`, the upward-facing
    rectangle lo.xy–hi.xy at height lo.z. receiver: baked into the lightmap."""

    name: str
    lo: tuple
    hi: tuple
    receiver: bool = False
    quad: bool = False
    yaw: float = 0.0  # degrees about the vertical through `pivot` (not aligned with texels)
    pivot: tuple | None = None  # default: the box's centre

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V, 3), quads (F, 4)) with counter-clockwise (outward) winding."""
        if self.quad:  # the box's bottom face alone
            return np.array(box_corners(self.lo, self.hi)[:4], float), np.array([[0, 1, 2, 3]])
        return self._to_world(np.array(box_corners(self.lo, self.hi), float)), np.array(BOX_QUADS)

    def _to_world(self, v: np.ndarray, inverse: bool = False) -> np.ndarray:
        """Box-frame points to world space (the yaw about the box's centre), or back."""
        if self.yaw == 0.0:
            return v
        a = math.radians(-self.yaw if inverse else self.yaw)
        rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        c = 0.5 * (np.array(self.lo) + np.array(self.hi)) if self.pivot is None else np.array(self.pivot)
        return (v - c) @ rot.T + c

    def triangles(self) -> np.ndarray:
        """(T, 3, 3) world-space triangles."""
        v, f = self.mesh()
        return v[np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])]

    def inside(self, p: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(P,) bool: points strictly inside the box grown by `margin` (a quad: nothing)."""
        if self.quad:
            return np.zeros(len(p), bool)
        lo, hi = np.array(self.lo) - margin, np.array(self.hi) + margin
        q = self._to_world(p, inverse=True)
        return ((q > lo) & (q < hi)).all(axis=1)


@dataclass
class Fixture:
    """parts; the sun: elevation and azimuth (degrees, azimuth from +x towards +y), strength
    W/m²; dark: boxes (lo, hi) whose inside is closed to the sun at any bounce count (the dark
    room); bounces: the diffuse bounces to bake with (0: direct light only, every texel's answer
    is exact; more: only the dark room's is)."""

    name: str
    parts: list[Part]
    sun: tuple = (45.0, 0.0, 3.0)
    dark: list[Part] = field(default_factory=list)
    bounces: int = 0
    what: str = ""

    @property
    def sun_direction(self) -> np.ndarray:
        e, a = math.radians(self.sun[0]), math.radians(self.sun[1])
        return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])

    @property
    def receivers(self) -> list[Part]:
        return [p for p in self.parts if p.receiver]

    def triangles(self) -> np.ndarray:
        return np.concatenate([p.triangles() for p in self.parts])

    def full(self, normal: np.ndarray) -> np.ndarray:
        """(P,) the irradiance (docs/conventions.md#irradiance-units) of a fully lit texel of unit
        normal (P, 3)."""
        return self.sun[2] * np.maximum(normal @ self.sun_direction, 0.0) / math.pi

    def expect(self, centre: np.ndarray, normal: np.ndarray, texel: np.ndarray, shadowed) -> np.ndarray:
        """(P,) the exact answer per texel as a fraction of `full`: 0, 1 or NaN (no exact value).
        centre (P, 3): the texel centre on the surface; normal (P, 3) the face normal; texel (P,)
        world texel size; shadowed(points (N, 3)) -> (N,) bool, a shadow-ray query (the
        fixture's own triangles). A texel is exact when its centre and the points EDGE_MARGIN
        texels around it along the surface agree (all lit or all in shadow), ignoring points
        hidden inside a box: the wall a texel straddles is not a shadow edge. A texel whose
        centre is hidden is only read by bilinear filtering at the visible points around it:
        its answer is theirs (1 texel around) if they agree, else NaN (a wall thinner than a
        texel between a lit and a dark side: no value is right for both)."""
        lit = normal @ self.sun_direction > 1e-6
        hidden = self.hidden(centre + normal * 1e-6)
        out = self._around(centre, normal, texel * EDGE_MARGIN, lit, shadowed, with_centre=True)
        for room in self.dark:  # closed to the sun: 0 up to its walls
            out[room.inside(centre)] = 0.0
        if hidden.any():
            out[hidden] = self._around(centre[hidden], normal[hidden], texel[hidden], lit[hidden], shadowed)
        return out

    def _around(self, centre, normal, radius, lit, shadowed, with_centre=False) -> np.ndarray:
        """(P,) 0 / 1 where the visible points of a ring of `radius` around each centre (and the
        centre, `with_centre`) agree on the truth (in shadow or in a dark room: 0; lit: 1), else NaN."""
        ring = centre[:, None] + np.concatenate([_ring(normal, radius * f) for f in (1 / 3, 2 / 3, 1.0)], axis=1)
        probe = np.concatenate([centre[:, None], ring], axis=1) if with_centre else ring
        flat = (probe + normal[:, None] * 1e-6).reshape(-1, 3)
        n = len(centre)
        dark = np.zeros(len(flat), bool)
        for room in self.dark:
            dark |= room.inside(flat)
        dark = dark.reshape(n, -1)
        shadow = shadowed(flat).reshape(n, -1) | ~lit[:, None] | dark
        if self.bounces > 0:  # bounced light has no exact value: only the dark room's is known
            shadow = np.where(dark, True, np.nan)
        seen = ~self.hidden(flat).reshape(n, -1)
        lo = np.where(seen, shadow, np.inf).min(axis=1)
        hi = np.where(seen, shadow, -np.inf).max(axis=1)
        return np.where((lo == hi) & np.isfinite(lo), 1.0 - lo, np.nan)

    def hidden(self, p: np.ndarray) -> np.ndarray:
        """(P,) bool: points inside a box of the fixture (no one sees them)."""
        out = np.zeros(len(p), bool)
        for part in self.parts:
            out |= part.inside(p)
        return out


def _ring(normal: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(P, 8, 3) offsets of length `radius` (P,) in 8 directions square to each normal (P, 3)."""
    helper = np.where(np.abs(normal[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t = np.cross(normal, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normal, t)
    angle = np.arange(8) * (math.pi / 4)
    ring = np.cos(angle)[None, :, None] * t[:, None] + np.sin(angle)[None, :, None] * b[:, None]
    return ring * radius[:, None, None]


def floor(size=2.0, receiver=True) -> Part:
    h = size / 2
    return Part("Floor", (-h, -h, 0.0), (h, h, 0.0), receiver=receiver, quad=True)


def fixtures() -> dict[str, Fixture]:
    """The four fixtures of the audit, by name."""
    wall = Fixture(
        "wall_through_floor",
        [floor(), Part("Wall", (-0.03, -0.6, -0.4), (0.03, 0.6, 1.0), yaw=4.0)],
        sun=(45.0, 4.0, 3.0),  # square to the wall: no shadow slivers thinner than a texel along its ends
        what="a 6 cm wall standing through a 2 m floor, the sun on one side: the shadow side next to "
        "the wall must be 0, the sunlit side next to it fully lit",
    )
    box = Fixture(
        "box_on_floor",
        [floor(), Part("Box", (-0.3, -0.3, 0.0), (0.3, 0.3, 0.4), yaw=10.0)],
        sun=(45.0, 10.0, 3.0),
        what="a closed box resting on a 2 m floor (its bottom in the floor's plane): its shadow 0, "
        "the sunlit floor up to its sides fully lit",
    )
    t = 0.0025  # the divider: 5 mm, a third of a floor texel at 256²
    rooms = Fixture(
        "thin_wall_rooms",
        [
            Part("Floor", (-2.0, -1.0, 0.0), (2.0, 1.0, 0.0), receiver=True, quad=True),
            Part("Divider", (-t, -1.0, 0.0), (t, 1.0, 1.5), yaw=2.0),
            Part("WallWest", (-2.0, -1.0, 0.0), (-1.9, 1.0, 1.5)),
            Part("WallEast", (1.9, -1.0, 0.0), (2.0, 1.0, 1.5)),
            Part("WallSouth", (-2.0, -1.0, 0.0), (2.0, -0.9, 1.5)),
            Part("WallNorth", (-2.0, 0.9, 0.0), (2.0, 1.0, 1.5)),
            Part("Ceiling", (-2.0, -1.0, 1.5), (0.05, 1.0, 1.6)),
        ],
        sun=(70.0, 0.0, 3.0),
        dark=[
            Part("DarkRoom", (-3.0, -0.9, -1.0), (-t, 0.9, 1.5), yaw=2.0, pivot=(0.0, 0.0, 0.0))
        ],  # west of the divider
        bounces=2,
        what="a 5 mm wall between a sunlit open-topped room and a closed dark room on one 4 m "
        "floor: the dark room's floor must be exactly 0 at any bounce count",
    )
    slab = Fixture(
        "table_sliver",
        [floor(4.0, receiver=False), Part("TableTop", (-0.5, -0.3, 0.745), (0.5, 0.3, 0.75), receiver=True)],
        sun=(60.0, 30.0, 3.0),
        what="a 5 mm table top (thinner than its texels) above a floor: its underside and the "
        "edges facing away from the sun must be 0, the top fully lit",
    )
    return {f.name: f for f in (wall, box, rooms, slab)}


# ---- baking a fixture with the core alone, and judging texels -------------------------------
def scene_of(fixture: Fixture):
    """The fixture as a core BakeScene (every part grey, the sun, no world)."""
    from hhd_lightmapper.core.scene import BakeScene, SunLight

    tris = fixture.triangles()
    sun = SunLight(fixture.sun_direction, np.full(3, float(fixture.sun[2])))
    return BakeScene(tris, np.full((len(tris), 3), ALBEDO), lights=[sun])


def surface_of(fixture: Fixture, resolution: int):
    """The receivers as SurfaceTriangles in one atlas of `resolution`², unwrapped by core.unwrap."""
    from hhd_lightmapper.core import bakepoints, unwrap

    meshes, tris, normals, objects = [], [], [], []
    for k, part in enumerate(fixture.receivers):
        v, f = part.mesh()
        t = np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
        polygons = np.concatenate([np.arange(len(f)), np.arange(len(f))])
        meshes.append(unwrap.UnwrapMesh(part.name, v, t, polygons=polygons))
        face = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        face /= np.linalg.norm(face, axis=1, keepdims=True)
        tris.append(v[t])
        normals.append(np.repeat(face[:, None], 3, axis=1))
        objects.append(np.full(len(t), k))
    # unwrapped at 256² at least (the unwrap's smallest atlas); the UVs then serve any size
    res = unwrap.unwrap(meshes, unwrap.UnwrapSettings(resolution=max(resolution, 256), padding=4))
    uv = np.concatenate([o.uv for o in res.objects]).astype(float)
    tris = np.concatenate(tris)
    return bakepoints.SurfaceTriangles(
        tris, np.concatenate(normals), uv, np.concatenate(objects), np.full((len(tris), 3), ALBEDO)
    )


def texel_centres(points) -> np.ndarray:
    """(P, 3) the surface point at each texel's centre (clamped into its triangle): where the
    texel's exact answer is taken, whatever the bake did with its bake point."""
    return points.texel_points(np.arange(len(points.texel)), np.array([[0.5, 0.5]]))[:, 0] - (
        points.face_normal * points.offset
    )


def expected(fixture: Fixture, points) -> np.ndarray:
    """(P,) exact I_z per texel (NaN: none), units of docs/conventions.md#irradiance-units."""
    from hhd_lightmapper.core.rays import RayScene

    scene = RayScene(fixture.triangles())
    sun = fixture.sun_direction

    def shadowed(p):
        return scene.occluded(p + sun * 1e-5, np.broadcast_to(sun, p.shape), np.inf)

    fraction = fixture.expect(texel_centres(points), points.face_normal, points.texel_size, shadowed)
    return fraction * fixture.full(points.face_normal)


def judge(iz: np.ndarray, truth: np.ndarray, full: np.ndarray, noise: np.ndarray | float = 0.0, k=4.0) -> dict:
    """Counts of texels whose exact answer is known: `light` (leaking: I_z above the truth by
    more than 1e-3 of the fully lit value and k × `noise`, its standard error), `dark` (below
    it by as much: a dark halo), of `judged` texels with a truth, of which `zero` should be 0."""
    known = np.isfinite(truth)
    tol = np.maximum(1e-3 * np.max(full, initial=0.0), k * np.broadcast_to(noise, iz.shape))
    light = known & (iz > truth + tol)
    dark = known & (iz < truth - tol)
    return {
        "judged": int(known.sum()),
        "zero": int((known & (truth == 0)).sum()),
        "light": int(light.sum()),
        "dark": int(dark.sum()),
        "light_zero": int((light & (truth == 0)).sum()),
        "worst_light": float(np.max((iz - truth)[light] / np.max(full), initial=0.0)),
    }


def core_bake(fixture: Fixture, resolution=256, samples=16, bounces=None, seed=1, settled=True):
    """Bake the fixture's receivers with the core; (points, luminance I_z (P,), truth (P,), full (P,)).
    `settled` False: with the bake points as they were before the leak fixes
    (`bakepoint_reference.unsettled`)."""
    from hhd_lightmapper.core import bake, colour, hhd, tracer

    from .bakepoint_reference import trace_unsettled

    settings = tracer.BakeSettings.from_samples(
        samples,
        bounces=fixture.bounces if bounces is None else bounces,
        seed=seed,
    )
    trace = bake.trace_surface if settled else trace_unsettled
    traced = trace(surface_of(fixture, resolution), resolution, resolution, scene_of(fixture), settings)
    points = traced.points
    iz = filled(points, hhd.irradz(traced.sh, points.normal) @ colour.LUMINANCE)
    return points, iz, expected(fixture, points), fixture.full(points.face_normal)


def filled(points, values: np.ndarray) -> np.ndarray:
    """Per-texel `values` (P,) as the files hold them: buried texels filled as the encoder fills
    them (`TexelData.fill`), from their own chart."""
    from hhd_lightmapper.core import encoding

    data = encoding.TexelData.from_points(points, np.zeros((len(points.texel), 9, 3)))
    image = points.image(values, dtype=np.float32)
    return data.fill().apply(image).reshape(-1)[points.texel].astype(np.float64)
