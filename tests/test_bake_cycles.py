"""Our bake's I_z against Cycles' Diffuse bake (Direct + Indirect, Color off), light by light.

Tolerance (see cycles_compare.assert_agree): both estimators are run twice with different
seeds; the spread gives each one's per-texel noise, from which the expected residual RMS and
the standard error of the mean difference follow. A 1% allowance covers what is not noise."""

import math

import numpy as np
import pytest

import cycles_compare as cc
from hhd_lightmapper import blender_compat
from hhd_lightmapper.core import bakepoints
from hhd_lightmapper.core.bakepoints import data as bakepoint_data
from scenekit import blender as kit

pytestmark = [pytest.mark.bpy, pytest.mark.cycles, pytest.mark.slow]
#: Texels per metre of the receivers (the 2 m floor: 128 texels across). Each comparison's bias
#: tolerance is ≥ 10× four standard errors of the mean at this density, so 4× the texels (at
#: 128/m) would buy it nothing; per-texel agreement does not depend on the texel count.
DENSITY = 64.0
#: The density of the closed rooms traced with three bounces (cost ∝ texels): a quarter of the
#: texels, for which the criterion above still holds (it does not for every scene at 32/m, e.g.
#: the disk and ellipse area lights, so the others keep DENSITY).
COARSE_DENSITY = 32.0


@pytest.fixture(autouse=True)
def cycles_footprint(monkeypatch):
    """Our bake averages each texel over the same footprint as the running Blender's Cycles."""
    monkeypatch.setattr(bakepoint_data, "FOOTPRINT", cc.cycles_footprint())
    return cc.cycles_footprint()


@pytest.fixture
def floor(extension):
    kit.clear_scene()
    f = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor", (0.8, 0.8, 0.8)))
    kit.box("Blocker", (0.2, 0.1, 0.35), (0.4, 0.4, 0.3), kit.material("Blocker", (0.6, 0.5, 0.4)))
    kit.unwrap([f], DENSITY)
    return f


def test_sun(floor):
    kit.light('SUN', rotation=(math.radians(30), math.radians(10), 0), energy=3.0, angle=0.0)
    r = cc.compare([floor], samples=32, bounces=1)
    assert r["mean"] > 0.3
    cc.assert_agree(r)


def test_hard_shadow_edge_texels_average_the_same_footprint_as_cycles(floor, monkeypatch, cycles_footprint):
    """Texels a sharp shadow edge crosses: their value is the lit fraction of the area each
    renderer averages, so they agree only if the footprints agree (Cycles': the whole texel from
    Blender 5.2.1, the central ½ × ½ before). Our footprint must match Cycles' within the edge
    texels' noise plus 1% of lit, and clearly better than the other footprint does.
    Texels whose footprint straddles two triangles are left out: there Cycles mirrors its jitter
    back into the texel's triangle (`bake_clamp_mirror_repeat` in its bake kernel) and we average
    the footprint over every triangle on it (`bakepoints.FOOTPRINT_TRIANGLES`), so where a shadow
    edge also crosses them the two differ by design (measured when we still clipped to the
    texel's triangle: 2 of 161 edge texels, on the quad's diagonal, residual 0.40 of a lit 0.81;
    the other 159: 0.013 against a noise of 0.0095)."""
    kit.light('SUN', rotation=(math.radians(30), math.radians(10), 0), energy=3.0, angle=0.0)
    r = cc.compare([floor], samples=64, bounces=0)
    value = r["cycles"].mean(1)
    lit = np.percentile(value, 90)
    edge = (value > 0.05 * lit) & (value < 0.95 * lit)
    straddling = footprint_straddles_triangles(r["points"], r["keep"])
    assert edge.sum() > 50 and (edge & straddling).sum() <= 0.05 * edge.sum()
    edge &= ~straddling
    residual = np.sqrt(np.mean((r["ours"][edge] - r["cycles"][edge]) ** 2))
    noise = np.sqrt(np.mean(r["texel_noise"][edge]))
    assert residual <= 1.5 * noise + 0.01 * lit, (residual, noise, lit, edge.sum())
    monkeypatch.setattr(bakepoint_data, "FOOTPRINT", 1.5 - cycles_footprint)  # 0.5 <-> 1.0
    points, other, _ = cc.ours([floor], 64, 0, seed=1)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    other_residual = np.sqrt(np.mean((other[keep][edge] - r["cycles"][edge]) ** 2))
    assert residual < 0.5 * other_residual, (residual, other_residual)


def footprint_straddles_triangles(points, keep):
    """(kept texels,) bool: the footprint's corners are not all inside the texel's triangle."""
    corners = 0.5 + bakepoint_data.FOOTPRINT * (np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) - 0.5)
    texel = points.texel[keep]
    origin = np.stack([texel % points.width, texel // points.width], 1).astype(float)
    tri_uv = points.mesh.texel_uv[points.triangle[keep]]
    bary = bakepoints._barycentric_grouped(origin[:, None, :] + corners[None], tri_uv)
    return (bary < -1e-9).any(axis=(1, 2))


def test_sun_with_angle(floor):
    kit.light('SUN', rotation=(math.radians(35), 0, 0), energy=3.0, angle=math.radians(12))
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


def test_point(floor):
    kit.light('POINT', location=(-0.3, -0.2, 1.2), energy=300.0, shadow_soft_size=0.0)
    cc.assert_agree(cc.compare([floor], samples=32, bounces=1))


@pytest.mark.parametrize("soft_falloff", [True, False])
def test_point_with_radius(floor, soft_falloff):
    lamp = kit.light('POINT', location=(-0.3, -0.2, 1.2), energy=300.0, shadow_soft_size=0.25)
    lamp.data.use_soft_falloff = soft_falloff  # disk facing the point (default) or sphere
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


@pytest.mark.parametrize("radius", [0.0, 0.2])
def test_spot(floor, radius):
    kit.light(
        'SPOT',
        location=(0.3, -0.4, 1.5),
        rotation=(math.radians(15), 0, 0),
        energy=500.0,
        shadow_soft_size=radius,
        spot_size=math.radians(70),
        spot_blend=0.4,
    )
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
def test_area(floor, shape):
    kit.light(
        'AREA',
        location=(-0.2, 0.1, 1.0),
        rotation=(math.radians(20), 0, 0),
        energy=150.0,
        shape=shape,
        size=0.6,
        size_y=0.3,
    )
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


def test_constant_world(floor):
    kit.world((0.4, 0.6, 1.0))
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


@pytest.mark.parametrize("rotation", [None, (0.0, 0.3, 1.2)])
def test_hdri_world(floor, rotation):
    """Environment Texture world (sky + a small bright sun), importance-sampled with MIS; with a
    Mapping node rotating it the sun's shadow must move exactly as in Cycles."""
    kit.hdri_world(kit.sky_pixels(), strength=1.5, rotation=rotation)
    r = cc.compare([floor], samples=64, bounces=1)
    assert r["mean"] > 0.3
    cc.assert_agree(r)


def test_emissive_mesh(floor):
    kit.plane(
        "Lamp",
        (0, 0, 1.0),
        0.8,
        kit.material("Lamp", (0.0, 0.0, 0.0), emission=(1.0, 0.9, 0.7, 8.0)),
        rotation=(math.pi, 0, 0),
    )
    cc.assert_agree(cc.compare([floor], samples=128, bounces=1))


def test_cornell_box_interreflection(extension):
    """A closed room with a red and a green wall, lit by a ceiling lamp (emissive) and a point
    light: three diffuse bounces in both renderers."""
    kit.clear_scene()
    white, red, green = (
        kit.material(n, c)
        for n, c in (("White", (0.75, 0.75, 0.75)), ("Red", (0.7, 0.1, 0.08)), ("Green", (0.1, 0.6, 0.12)))
    )
    floor = kit.plane("Floor", (0, 0, 0), 2.0, white)
    kit.plane("Ceiling", (0, 0, 2.0), 2.0, white, rotation=(math.pi, 0, 0))
    kit.plane("Back", (0, 1.0, 1.0), 2.0, white, rotation=(math.pi / 2, 0, 0))
    kit.plane("Front", (0, -1.0, 1.0), 2.0, white, rotation=(-math.pi / 2, 0, 0))
    kit.plane("Left", (-1.0, 0, 1.0), 2.0, red, rotation=(0, math.pi / 2, 0))
    kit.plane("Right", (1.0, 0, 1.0), 2.0, green, rotation=(0, -math.pi / 2, 0))
    kit.plane(
        "Lamp", (0, 0, 1.98), 0.6, kit.material("Lamp", (0, 0, 0), emission=(1, 1, 1, 6.0)), rotation=(math.pi, 0, 0)
    )
    kit.light('POINT', location=(0.4, -0.3, 1.5), energy=60.0, shadow_soft_size=0.0)
    kit.unwrap([floor], COARSE_DENSITY)
    r = cc.compare([floor], samples=128, bounces=3, cycles_samples=128)
    assert r["mean"] > 0.5
    red_side = r["points"].position[r["keep"], 0] < -0.6
    assert (r["ours"][red_side, 0] > r["ours"][red_side, 1]).mean() > 0.9  # colour bleeding
    cc.assert_agree(r, allowance=0.02)


def test_box_pushed_into_the_floor_leaves_no_light_under_it(extension):
    """The leak fixture of the unwrap/raster issue, baked: a box sunk into a sunlit floor."""
    kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4.0, kit.material("Floor"))
    kit.box("Sunk", (0.0, 0.0, 0.2), (1.0, 1.0, 1.0), kit.material("Box"))
    kit.light('SUN', rotation=(math.radians(40), 0, 0), energy=3.0)
    kit.world((0.3, 0.4, 0.6))
    kit.unwrap([floor], DENSITY)
    points, iz, _ = cc.ours([floor], samples=32, bounces=2, seed=3)
    x, y = np.abs(points.position[:, 0]), np.abs(points.position[:, 1])
    under = np.maximum(x, y) < 0.5 - 0.5 * points.texel_size  # any part of the texel under the box
    outside = np.maximum(x, y) > 0.5 + 2 * points.texel_size
    assert under.sum() > 100
    assert iz[under].max() == 0.0
    assert iz[outside].min() > 0.0


def test_floor_under_a_coplanar_face_stays_dark_as_in_cycles(extension):
    """An open-topped box standing on the floor: its bottom face lies in the floor's plane,
    facing down. Cycles' rays start on the floor and hit that face at distance 0, so the floor
    under it is dark; ours start an offset above the floor, inside the box, and without the
    cover probe (core.bakepoints.covers) see the sky through the open top (measured without it: I_z up to
    1.38 under the box, where Cycles is dark). The texels under the box are invalid (no one
    sees them: the files fill them from the visible floor) and bake black; the rest of the floor
    must agree with Cycles within the noise rule, except along the box's edge, where ours
    averages the visible part of a texel and Cycles the whole texel, its covered part dark
    (README, "Leaks"): there ours is never darker than Cycles beyond the noise."""
    import bmesh

    kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor", (0.8, 0.8, 0.8)))
    tray = kit.box("Tray", (0.0, 0.0, 0.2), (1.0, 1.0, 0.4), kit.material("Tray", (0.6, 0.5, 0.4)))
    bm = bmesh.new()
    bm.from_mesh(tray.data)
    bmesh.ops.delete(bm, geom=[f for f in bm.faces if f.normal.z > 0.9], context='FACES_ONLY')
    bm.to_mesh(tray.data)
    bm.free()
    kit.light('SUN', rotation=(math.radians(20), math.radians(10), 0), energy=3.0)
    kit.world((0.3, 0.4, 0.6))
    kit.unwrap([floor])  # at the scene Resolution, as the geometry checks below assume
    r = cc.compare([floor], samples=32, bounces=1)
    points = r["points"]
    centre = points.texel_points(np.arange(len(points.texel)), np.array([[0.5, 0.5]]))[:, 0]
    inner = np.maximum(np.abs(centre[:, 0]), np.abs(centre[:, 1]))
    under = inner < 0.5 - points.texel_size
    assert under.sum() > 1000 and points.buried[under].all()
    _, iz, _ = cc.ours([floor], 16, 1, seed=3)
    assert iz[under].max() == 0.0
    edge = (np.abs(inner - 0.5) < points.texel_size)[r["keep"]]
    assert edge.sum() > 200
    on_edge = cc.restricted(r, edge)
    assert on_edge["bias"] > -4 * on_edge["se_mean"], on_edge["bias"]
    cc.assert_agree(cc.restricted(r, ~edge))


def test_texture_albedo_reaches_bake_points_and_bounce_light(extension):
    """A wall textured red | blue (sRGB byte image through its own UV map) lit by the sun bleeds
    its colours onto the floor as in Cycles; the wall's bake points carry the decoded texture."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data
    from hhd_lightmapper.core import bakepoints, textures

    kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor", (0.8, 0.8, 0.8)))
    wall = kit.plane(
        "Wall",
        (0, 1.0, 0.6),
        2.0,
        kit.textured_material("Wall", (0.9, 0.1, 0.1), (0.1, 0.2, 0.9), "UVMap"),
        rotation=(math.pi / 2, 0, 0),
    )
    kit.light('SUN', rotation=(math.radians(50), 0, 0), energy=4.0)  # towards +y: lights the wall's floor side
    kit.unwrap([floor, wall], DENSITY)
    r = cc.compare([floor], samples=64, bounces=1)
    near_wall = r["points"].position[r["keep"], 1] > 0.6
    left, right = (
        near_wall & (r["points"].position[r["keep"], 0] < -0.3),
        near_wall & (r["points"].position[r["keep"], 0] > 0.3),
    )
    assert r["ours"][left, 0].mean() > r["ours"][right, 0].mean()  # red bleeds on the left
    assert r["ours"][right, 2].mean() > r["ours"][left, 2].mean()  # blue on the right
    cc.assert_agree(r)
    surface = mesh_data.read_surface([wall], kit.LAYER, bpy.context.evaluated_depsgraph_get())
    points = bakepoints.build(surface, wall.hhd.atlas_width, wall.hhd.atlas_height)
    stored = lambda c: np.round(np.array(c) * 255) / 255  # a byte image holds 8-bit sRGB
    red, blue = textures.srgb_to_linear(stored([0.9, 0.1, 0.1])), textures.srgb_to_linear(stored([0.1, 0.2, 0.9]))
    x = points.position[:, 0]
    np.testing.assert_allclose(points.albedo[x < -0.2].mean(axis=0), red, atol=1e-6)
    np.testing.assert_allclose(points.albedo[x > 0.2].mean(axis=0), blue, atol=1e-6)


def test_emission_shader_emitter_reflects_nothing(extension):
    """A closed white room whose whole ceiling is an Emission shader: Cycles reflects no light
    off it, so neither may we (baking it with a grey viewport colour adds ~30% at 3 bounces)."""
    kit.clear_scene()
    white = kit.material("White", (0.8, 0.8, 0.8))
    floor = kit.plane("Floor", (0, 0, 0), 2.0, white)
    for name, centre, rotation in (
        ("Back", (0, 1.0, 1.0), (math.pi / 2, 0, 0)),
        ("Front", (0, -1.0, 1.0), (-math.pi / 2, 0, 0)),
        ("Left", (-1.0, 0, 1.0), (0, math.pi / 2, 0)),
        ("Right", (1.0, 0, 1.0), (0, -math.pi / 2, 0)),
    ):
        kit.plane(name, centre, 2.0, white, rotation=rotation)
    lamp = bpy_emission_material("Ceiling Lamp", (1.0, 0.95, 0.9), 2.0)
    kit.plane("Ceiling", (0, 0, 2.0), 2.0, lamp, rotation=(math.pi, 0, 0))
    kit.unwrap([floor], COARSE_DENSITY)
    r = cc.compare([floor], samples=64, bounces=3, cycles_samples=64)
    assert r["mean"] > 0.5
    cc.assert_agree(r, allowance=0.02)


def bpy_emission_material(name, colour, strength):
    import bpy

    mat = bpy.data.materials.new(name)
    blender_compat.ensure_node_tree(mat)
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (*colour, 1.0)
    emission.inputs["Strength"].default_value = strength
    mat.node_tree.links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    return mat
