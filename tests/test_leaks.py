"""Light leaks, on the fixtures of scenekit/leak_fixtures.py baked by the core alone (no Blender):
a wall through a floor, a box resting on a floor, a thin wall between a sunlit and a closed
dark room, a table top thinner than its texels. Each is lit by one sun of zero angle and no
world, so every judged texel's answer is exact (0 in shadow or in the dark room, S·cosθ/π
fully lit) and the checks need no statistical tolerance: `leak_fixtures.judge` allows 1e-3 of
the fully lit value (float rounding), while one misplaced sample of 16 is 6e-2."""

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, encoding, rays
from scenekit import bakepoint_reference
from scenekit import leak_fixtures as lf

FIXTURES = lf.fixtures()


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_no_texel_of_a_fixture_leaks_light_or_darkens_next_to_geometry(name):
    """Every texel with an exact answer has it: none lit that should be dark (light leaking
    under a wall or from the far side of one), none darkened that should be fully lit (samples
    starting inside the wall or under the box). Buried texels are judged as the files hold
    them: filled from their own chart."""
    fixture = FIXTURES[name]
    points, iz, truth, full = lf.core_bake(fixture, resolution=128, samples=16)
    result = lf.judge(iz, truth, full)
    assert result["judged"] > 2000 and result["zero"] > 500, result
    assert result["light"] == 0 and result["dark"] == 0, result


def test_the_dark_rooms_floor_is_exactly_black_at_every_bounce():
    """The closed room beside the sunlit one, across a wall a third of a texel thick: every
    texel whose centre lies in it is exactly 0 after 2 bounces, those straddling the wall
    included; the wall's own texels take one side's value, and the sunlit room is lit."""
    fixture = FIXTURES["thin_wall_rooms"]
    points, iz, truth, full = lf.core_bake(fixture, resolution=256, samples=16, bounces=2)
    dark = truth == 0
    straddling = dark & points.crossed
    assert straddling.sum() > 50
    assert np.all(iz[dark] == 0.0)
    lit_room = lf.texel_centres(points)[:, 0] > 0.1
    assert np.median(iz[lit_room]) > 0.3 * full.max()


def test_before_settling_the_fixtures_leak():
    """The same audit with the bake points as they were (not settled:
    scenekit/bakepoint_reference.py): the dark room receives light through the wall's texels,
    and the floor next to the wall and the box darkens; what the fixes are measured against
    (bench/results/leaks.md)."""
    rooms = lf.judge(*lf.core_bake(FIXTURES["thin_wall_rooms"], resolution=256, samples=16, settled=False)[1:])
    box = lf.judge(*lf.core_bake(FIXTURES["box_on_floor"], resolution=128, samples=16, settled=False)[1:])
    assert rooms["light_zero"] > 0 and box["dark"] > 0, (rooms, box)


def test_a_bake_point_inside_a_wall_moves_out_and_one_in_an_outward_facing_room_stays():
    """`settle` moves a bake point standing inside a wall through the floor out past the
    wall's nearer face; a floor whose room is a box with outward normals (every wall shows the
    room its back) keeps its bake points where they are: a lone back face is not a solid."""
    fixture = lf.Fixture("room", [lf.floor(2.0), lf.Part("Room", (-0.9, -0.9, -0.1), (0.9, 0.9, 1.0))])
    surface = lf.surface_of(fixture, 64)
    scene = rays.RayScene(fixture.triangles())
    points = bakepoints.build(surface, 64, 64, occluders=rays.RayScene(fixture.triangles()))
    inside_room = np.max(np.abs(lf.texel_centres(points)[:, :2]), axis=1) < 0.9 - points.texel_size
    unsettled = bakepoint_reference.unsettled(surface, 64, 64, scene)
    np.testing.assert_array_equal(points.position[inside_room], unsettled.position[inside_room])
    wall = lf.fixtures()["wall_through_floor"]
    points = bakepoints.build(lf.surface_of(wall, 128), 128, 128, occluders=rays.RayScene(wall.triangles()))
    centre_hidden = wall.hidden(lf.texel_centres(points) + 1e-6 * points.face_normal)
    now_hidden = wall.hidden(points.position + 1e-6 * points.face_normal)
    rim = centre_hidden & points.crossed
    assert rim.sum() > 20 and not now_hidden[rim].any()


def test_buried_texels_fill_from_their_own_chart_not_black():
    """Invalid (buried) texels take the value of the nearest valid texel reachable through their
    own chart, never one of another chart nor black; a chart with no valid texel stays black."""
    h, w = 12, 20
    coverage = np.zeros((h, w), np.float32)
    coverage[2:10, 2:8] = 1.0  # chart A
    coverage[2:10, 10:18] = 1.0  # chart B, 2 texels away
    coverage[2:10, 7] = -1.0  # A's last column buried: B's texels are nearer than most of A's
    coverage[4:6, 3:5] = -1.0  # a buried patch inside A
    sh = np.zeros((h, w, 9, 3), np.float32)
    sh[:, :10, 0, 0] = 1.0  # A's value
    sh[:, 10:, 0, 0] = 5.0  # B's value
    sh[coverage < 0] = 0.0
    data = encoding.TexelData(sh=sh, normal=np.zeros((h, w, 3), np.float32), coverage=coverage)
    out = data.fill().apply(sh[..., 0, 0].copy())
    assert (out[coverage < 0] == 1.0).all()
    assert (out[coverage > 0] == sh[..., 0, 0][coverage > 0]).all()
    coverage[2:10, 2:8] = -1.0  # all of A buried: nothing to fill from
    data = encoding.TexelData(sh=sh, normal=data.normal, coverage=coverage)
    fill = data.fill()
    assert (fill.apply(sh[..., 0, 0].copy(), keep_black=True)[2:10, 2:8] == 0).all() and len(fill.invalid) == 48


def test_the_back_of_a_surface_passes_light_on():
    """Surfaces are two-sided, as in Cycles (`core.tracer.paths`): under a one-sided roof facing
    up (its underside a back face), the floor in its shadow sees only the roof's back and the
    black sky, and the roof's underside passes on the sunlit floor's light. (Until commit
    fc8bedd a switch ended paths there instead, which left that floor exactly 0.)"""
    fixture = lf.Fixture("roof", [lf.floor(2.0), lf.Part("Roof", (-0.5, -0.5, 0.5), (0.5, 0.5, 0.5), quad=True)])
    _, two_sided, truth, _ = lf.core_bake(fixture, resolution=64, samples=16, bounces=2)
    shadow = truth == 0
    assert shadow.sum() > 100
    assert (two_sided[shadow] > 0).mean() > 0.5  # 16 paths each: some find no light


def test_hidden_samples_take_a_visible_sample_of_their_own_texel():
    """`hemisphere_kernels.replace_hidden`: visible samples keep their origin, hidden ones take a visible
    sample of the same texel, drawn uniformly (each visible one about equally often), and a
    texel with none visible gets -1 (the tracer then uses its bake point)."""
    from hhd_lightmapper.core.tracer import hemisphere_kernels

    k = 8
    hidden = np.zeros((3000, k), bool)
    hidden[:, :5] = True  # 5 hidden, 3 visible in every texel
    hidden[-1] = True  # the last texel: all hidden
    source = hemisphere_kernels.get().replace_hidden(hidden.reshape(-1), k, 7).reshape(-1, k)
    own = np.arange(hidden.size).reshape(-1, k)
    assert (source[:, 5:][:-1] == own[:, 5:][:-1]).all()
    picked = source[:-1, :5] - own[:-1, :1]  # index within the texel
    assert np.isin(picked, [5, 6, 7]).all()
    counts = np.bincount(picked.ravel(), minlength=k)[5:]
    assert np.all(np.abs(counts / counts.sum() - 1 / 3) < 0.02), counts
    assert (source[-1] == -1).all()
