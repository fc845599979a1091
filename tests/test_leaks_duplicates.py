"""Duplicated geometry at a bounce: a wall that has a coincident twin (the same quad again, facing
either way: a wall and its reveal, a slab and the lintel against it, as the classroom's window
heads and staircase2's landing have) reflects light like the wall alone. Cycles' bake loses all
of that bounce light (its path vertex on the wall starts its rays on the surface and they hit the
twin at distance 0: on a floor facing such a wall, 0.880 without the twin, 0.637 with it, the sun
alone); the leak audit takes that light out of its re-measure before judging a texel against
Cycles (bench/leaks.py, `light_off_duplicates`), and finds it with `Duplicated`."""

import sys
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, colour, hhd, tracer
from hhd_lightmapper.core.scene import BakeScene, SunLight

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import leaks  # noqa: E402

RES = 32
STRENGTH = 4.0


def quad(a, b, c, d):
    """Two triangles (2, 3, 3) of the quad a b c d (counter-clockwise seen from its front)."""
    a, b, c, d = (np.asarray(p, float) for p in (a, b, c, d))
    return np.array([[a, b, c], [a, c, d]])


FLOOR = quad((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0))
WALL = quad((0.3, -1, 0), (0.3, -1, 1), (0.3, 1, 1), (0.3, 1, 0))  # faces -x, towards the floor's lit part
TWINS = {"alone": None, "opposite": WALL[:, ::-1], "same": WALL.copy()}


def floor_bake(twin):
    """Luminance I_z (P,) of the floor's texels, and their points, under a sun from -x (30° up)
    lighting the floor and the wall's front, one bounce."""
    tris = np.concatenate([FLOOR, WALL] + ([] if twin is None else [twin]))
    surface = bakepoints.SurfaceTriangles(
        positions=FLOOR,
        normals=np.tile([0.0, 0.0, 1.0], (2, 3, 1)),
        uv=(FLOOR[..., :2] + 1.0) / 2.0 * 0.9 + 0.05,
        object_index=np.zeros(2, int),
        albedo=np.full((2, 3), 0.8),
    )
    sun = SunLight(np.array([-np.sqrt(0.75), 0.0, 0.5]), np.full(3, STRENGTH))
    scene = BakeScene(tris, np.full((len(tris), 3), 0.8), lights=[sun])
    settings = tracer.BakeSettings(samples=64, pass_samples=16, bounces=1, seed=5)
    traced = bake.trace_surface(surface, RES, RES, scene, settings)
    return hhd.irradz(traced.sh, traced.points.normal) @ colour.LUMINANCE, traced.points


@pytest.mark.parametrize("side", ["opposite", "same"])
def test_a_wall_with_a_coincident_twin_bounces_light_as_the_wall_alone(side):
    """The floor in front of the wall receives the wall's bounce light with the twin as without
    it (same seed, same samples: equal to float rounding), well above the sun alone."""
    alone, points = floor_bake(None)
    twinned, _ = floor_bake(TWINS[side])
    x = points.position[:, 0]
    near = (x > -0.4) & (x < 0.2) & (np.abs(points.position[:, 1]) < 0.8) & (points.coverage >= 1.0 - 1e-9)
    assert near.sum() > 50
    sun_alone = STRENGTH * 0.5 / np.pi
    assert alone[near].mean() > 1.2 * sun_alone  # the wall's bounce light is there
    np.testing.assert_allclose(twinned[near], alone[near], rtol=1e-4)


def test_duplicated_finds_points_on_coincident_faces_of_either_facing():
    """`Duplicated.on`: a point on the wall is on duplicated geometry where a coincident twin
    (either facing) covers it, not where the twin does not reach, nor on the floor."""
    half = quad((0.3, -1, 0), (0.3, -1, 1), (0.3, 0, 1), (0.3, 0, 0))[:, ::-1]  # covers y < 0, faces +x
    tris = np.concatenate([FLOOR, WALL, half])
    dup = leaks.Duplicated(tris, 1e-4)
    q = np.array([[0.3, -0.5, 0.5], [0.3, 0.5, 0.5], [0.2, -0.5, 0.0], [0.3, -0.5, 0.5]])
    prim = np.array([2, 3, 0, 4])  # the wall (twice), the floor, the half twin itself
    assert dup.on(q, prim).tolist() == [True, False, False, True]
    assert not dup.on(q[:1] + [0.01, 0.0, 0.0], prim[:1]).any()  # off the plane by more than tol
