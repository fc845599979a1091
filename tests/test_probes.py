"""Probe volumes in core (no Blender): EEVEE's probe positions, the full-sphere estimator against
closed forms, validity and filling, trilinear sampling, files."""

import numpy as np
import pytest

from hhd_lightmapper.core import probes, sh, tracer
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.files import exr
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit import meshes

FAR = np.array([[[100.0, 100.0, 100.0], [100.1, 100.0, 100.0], [100.0, 100.1, 100.0]]])  # a speck


def grid(res=(3, 2, 2), scale=(1.0, 1.0, 1.0), centre=(0.0, 0.0, 0.0)):
    m = np.diag([*scale, 1.0])
    m[:3, 3] = centre
    return probes.ProbeGrid("Volume", m, res)


def test_positions_are_eevees_cell_centres_x_fastest():
    g = grid((2, 1, 3), scale=(2.0, 1.0, 3.0), centre=(1.0, 0.0, 0.0))
    p = g.positions()
    np.testing.assert_allclose(p[:2], [[0.0, 0.0, -2.0], [2.0, 0.0, -2.0]])
    np.testing.assert_allclose(p[:, 2], [-2, -2, 0, 0, 2, 2])
    np.testing.assert_allclose(g.grid_coordinates(p), [[i % 2, 0, i // 2] for i in range(6)], atol=1e-12)
    with pytest.raises(BakeError, match="resolution"):
        probes.ProbeGrid("V", np.eye(4), (0, 1, 1))
    with pytest.raises(BakeError, match="zero scale"):
        probes.ProbeGrid("V", np.diag([1.0, 0.0, 1.0, 1.0]), (1, 1, 1))


def test_constant_world_gives_the_constant_sphere_sh_and_a_sun_its_exact_direction():
    world = np.array([0.2, 0.5, 1.0])
    sun = SunLight(np.array([0.6, 0.0, 0.8]), np.array([3.0, 2.0, 1.0]))
    scene = BakeScene(FAR, np.full((1, 3), 0.5), world=world, lights=[sun])
    baked = probes.bake(grid(), scene, tracer.BakeSettings(samples=32, bounces=1))
    assert baked.valid.all() and baked.sh.shape == (12, 9, 3)
    want = np.zeros((9, 3))
    want[0] = 2.0 * np.sqrt(np.pi) * world  # ∫ L Y00 over the sphere
    want += sh.evaluate(sun.direction[None])[0][:, None] * sun.irradiance  # the delta sun: s·Y(l)
    # the speck far away hides a negligible share of the sky; stratified directions
    np.testing.assert_allclose(baked.sh, np.broadcast_to(want, baked.sh.shape), atol=2e-3)


def test_probes_inside_a_closed_box_are_invalid_and_take_their_neighbours_light():
    v, f = meshes.cube(1.0, centre=(0.0, 0.0, 0.0))
    floor_v, floor_f = meshes.plane(20.0)
    tris = np.concatenate([v[f], (floor_v - [10.0, 10.0, 2.0])[floor_f]])
    scene = BakeScene(tris, np.full((len(tris), 3), 0.5), world=np.ones(3))
    g = grid((5, 1, 1), scale=(2.5, 0.2, 0.2))  # x = -2, -1, 0, 1, 2: the middle one in the box
    baked = probes.bake(g, scene, tracer.BakeSettings(samples=16, bounces=1))
    np.testing.assert_array_equal(baked.valid, [True, True, False, True, True])
    assert baked.back_faces[2] == 1.0 and baked.back_faces[[0, 4]].max() < 0.1
    np.testing.assert_allclose(baked.sh[2], 0.5 * (baked.sh[1] + baked.sh[3]))


def test_fill_reaches_across_rings_and_isolated_grids():
    values = np.arange(8.0).reshape(2, 2, 2)
    valid = np.zeros((2, 2, 2), bool)
    valid[0, 0, 0] = True
    filled = probes.fill_invalid(values, valid)
    assert np.all(filled == 0.0)
    assert np.all(probes.fill_invalid(values, np.zeros_like(valid)) == values)  # nothing to fill from


def test_sampling_is_trilinear_between_probes_and_clamped_outside():
    g = grid((2, 2, 2))
    p = g.positions()
    values = np.zeros((8, 9, 3))
    values[:, 0, 0] = p[:, 0] * 2.0 + p[:, 1] - p[:, 2]  # linear in position: reproduced inside
    pts = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    got = probes.sample(g, values, pts)[:, 0, 0]
    np.testing.assert_allclose(got[:2], pts[:2, 0] * 2.0 + pts[:2, 1] - pts[:2, 2], atol=1e-12)
    assert got[2] == pytest.approx(0.5 * 2.0)  # clamped to the outermost probes (x = 0.5)


def test_files_round_trip(tmp_path):
    scene = BakeScene(FAR, np.full((1, 3), 0.5), world=np.array([0.3, 0.3, 0.3]))
    baked = probes.bake(grid(), scene, tracer.BakeSettings(samples=8, bounces=0))
    with exr.Staging() as staging:
        doc = probes.write(staging, tmp_path, [baked])
        staging.commit()
    assert doc["volumes"][0]["file"] == "Volume_probes.exr"
    g, got, valid = probes.read(tmp_path, "Volume")
    np.testing.assert_allclose(got, baked.sh.astype(np.float32))
    np.testing.assert_array_equal(valid, baked.valid)
    np.testing.assert_allclose(g.to_world, baked.grid.to_world)
