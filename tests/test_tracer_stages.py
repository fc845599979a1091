"""The tracer's stages as plain data (no Blender): bake points and traced atlases pickle exactly,
work units run bit-identically in other processes, every light type behind one interface, welded
corner ids, the SH basis defined once."""

import dataclasses
import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, rays, sh, tracer
from hhd_lightmapper.core.bakepoints.data import weld
from hhd_lightmapper.core.environment import EnvironmentMap
from hhd_lightmapper.core.scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from hhd_lightmapper.core.tracer import hemisphere_kernels, lights
from scenekit import meshes


def sky():
    h, w = 16, 32
    z = np.cos(np.pi * (1.0 - (np.arange(h) + 0.5) / h))
    img = np.tile(((0.2 + 0.8 * z.clip(0))[:, None, None] * np.array([0.3, 0.5, 1.0])), (1, w, 1))
    img[int(h * 0.8), int(w * 0.3)] = [200.0, 160.0, 120.0]
    return EnvironmentMap(img)


def every_light_scene(res=48, emission_group=None):
    """A 2 m floor (the receiver, UVs = its xy) with an open tray resting on it (its bottom covers
    the floor: near-cover texels) and an emissive box, under a sun, point, spot and area light
    and an HDRI world. Returns (points, scene, ray scene)."""
    v, f = meshes.plane(2.0)
    floor = v[f]
    tray_v, tray_f = meshes.cube(0.6, centre=(1.0, 1.0, 0.3))
    tray = tray_v[tray_f[[0, 1] + list(range(4, 12))]]  # no lid
    lamp_v, lamp_f = meshes.cube(0.2, centre=(0.4, 1.6, 0.8))
    tris = np.concatenate([floor, tray, lamp_v[lamp_f]])
    emission = np.zeros((len(tris), 3))
    emission[-12:] = [20.0, 12.0, 6.0]
    surface = bakepoints.SurfaceTriangles(
        floor, np.tile([0, 0, 1.0], (2, 3, 1)), floor[..., :2] / 2.0, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.6),
        emission=emission,
        environment=sky(),
        emission_group=emission_group,
        lights=[
            SunLight(
                np.array([0.6, 0.2, 0.77]) / np.linalg.norm([0.6, 0.2, 0.77]), np.array([3.0, 2.5, 2.0]), angle=0.1
            ),
            PointLight(np.array([1.6, 0.3, 0.9]), np.array([40.0, 30.0, 20.0]), radius=0.05),
            SpotLight(
                np.array([0.5, 0.5, 1.5]),
                np.array([80.0, 80.0, 80.0]),
                0.02,
                direction=np.array([0.0, 0.0, -1.0]),
                size=1.0,
            ),
            AreaLight(
                np.array([1.5, 1.5, 1.2]),
                np.array([0.2, 0.0, 0.0]),
                np.array([0.0, 0.2, 0.0]),
                np.array([0.0, 0.0, -1.0]),
                np.array([30.0, 30.0, 30.0]),
            ),
        ],
    )
    ray_scene = rays.RayScene(tris)
    return bakepoints.build(surface, res, res, occluders=ray_scene), scene, ray_scene


def assert_same_data(a, b):
    """Every field of two dataclasses equal: arrays exactly (values, dtype, shape), nested dataclasses too."""
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(x):
            assert_same_data(x, y)
        elif isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


def test_bake_points_are_plain_data_that_pickle_exactly():
    points, scene, _ = every_light_scene()
    assert points.near_cover.any() and points.buried.any()
    plain = (np.ndarray, int, float, bakepoints.SurfaceMesh)
    assert all(isinstance(getattr(points, f.name), plain) for f in dataclasses.fields(points))
    assert_same_data(points, pickle.loads(pickle.dumps(points)))
    atlas = tracer.bake(points, scene, tracer.BakeSettings(samples=4, pass_samples=4, bounces=1))
    again = pickle.loads(pickle.dumps(atlas))
    assert_same_data(atlas, again)
    np.testing.assert_array_equal(again.valid, ~points.buried)


def test_a_pickled_estimator_rebuilds_its_embree_scenes_and_traces_the_same_unit():
    points, scene, ray_scene = every_light_scene()
    for shared in (ray_scene, None):
        estimator = tracer.texel_estimator(points, scene, tracer.BakeSettings(pass_samples=8, bounces=2), shared)
        clone = pickle.loads(pickle.dumps(estimator))
        assert clone is not estimator and clone.scene._rays is None and clone._covers is None
        unit = tracer.WorkUnit(3, 1, 0, np.flatnonzero(points.near_cover)[:200])
        a, b = estimator.trace(unit), clone.trace(unit)
        np.testing.assert_array_equal(a.estimate, b.estimate)
        assert a.rays == b.rays
        assert clone.covers is not None and clone.scene.rays is not ray_scene


def test_a_process_pool_bakes_bit_identical_sh_to_the_thread_pool():
    """Work units on a 2-process pool (spawn: nothing inherited) give the thread pool's SH, its
    standard error, sample counts and ray count, with and without the caller's Embree scene
    (the cover probe is then rebuilt in the workers from either)."""
    points, scene, ray_scene = every_light_scene()
    runs = [
        (tracer.BakeSettings(samples=8, pass_samples=4, bounces=2, seed=11, chunk_texels=512, threads=2), ray_scene),
        (
            tracer.BakeSettings(
                samples=24, pass_samples=4, bounces=1, seed=12, chunk_texels=700, threads=2, noise_target=0.2
            ),
            None,
        ),
    ]
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        for settings, shared in runs:
            threaded = tracer.bake(points, scene, settings, ray_scene=shared)
            spawned = tracer.bake(points, scene, settings, ray_scene=shared, executor=pool)
            np.testing.assert_array_equal(spawned.sh, threaded.sh)
            np.testing.assert_array_equal(spawned.sh_error, threaded.sh_error)
            np.testing.assert_array_equal(spawned.texel_samples, threaded.texel_samples)
            assert (spawned.rays, spawned.stopped_by) == (threaded.rays, threaded.stopped_by)
    assert threaded.texel_samples.min() < threaded.texel_samples.max()  # the noise target stopped some


def test_every_light_type_samples_itself_in_scene_order_then_hdri_then_emitters():
    points, scene, _ = every_light_scene()
    built = lights.build(scene)
    assert [type(light) for light in built] == [
        lights.lamps.Sun,
        lights.lamps.Point,
        lights.lamps.Spot,
        lights.lamps.Area,
        lights.world.Environment,
        lights.emitters.EmissiveTriangles,
    ]
    assert [light.reachable for light in built] == [False] * 4 + [True] * 2
    assert [light.at_infinity for light in built] == [True, False, False, False, True, False]
    assert all(light.power > 0 and light.group == "" for light in built)
    x = points.origins()[:50]
    rng = np.random.default_rng(0)
    for light in built:
        dirs, value, dist = light.sample(rng, x, lambda w: np.full(len(w), 1.0 / (2 * np.pi)))
        assert dirs.shape == value.shape == (50, 3) and dist.shape == (50,)
        np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
        if not light.reachable:  # rays never reach it: nothing to weigh against
            assert not light.pdf(dirs).any() and not light.evaluate(dirs, dist, None, np.ones(50)).any()


def test_emission_groups_make_one_emitter_light_each():
    group = np.full(len(every_light_scene()[1].triangles), "", dtype=object)
    group[-12:-6], group[-6:] = "lamp_a", "lamp_b"
    points, scene, _ = every_light_scene(emission_group=group)
    emitters = [light for light in lights.build(scene) if isinstance(light, lights.emitters.EmissiveTriangles)]
    assert [e.group for e in emitters] == ["lamp_a", "lamp_b"]
    assert [len(e) for e in emitters] == [6, 6]
    whole = lights.emitters.EmissiveTriangles(scene.triangles, scene.emission)
    assert sum(e.power for e in emitters) == pytest.approx(whole.power)
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=4, pass_samples=4, bounces=0))
    assert np.isfinite(result.sh).all()


def test_welded_corner_ids_join_equal_positions_only():
    v, f = meshes.cube(1.0)
    tris = v[f]
    ids = weld(tris)
    assert ids.shape == (12, 3) and len(np.unique(ids)) == 8
    for a in range(12):  # same id exactly where the position is the same
        for b in range(12):
            same = (tris[a][:, None] == tris[b][None]).all(axis=2)
            np.testing.assert_array_equal(ids[a][:, None] == ids[b][None], same)
    flipped = tris.copy()
    flipped[flipped == 0.0] = -0.0
    np.testing.assert_array_equal(
        weld(flipped)[:, :, None] == weld(flipped)[:, None, :], ids[:, :, None] == ids[:, None, :]
    )
    vertex = every_light_scene()[0].mesh.vertex  # the floor: two triangles, one diagonal
    assert len(np.unique(vertex)) == 4 and vertex[0, 0] == vertex[1, 0] and vertex[0, 2] == vertex[1, 1]


def test_the_kernels_sh_basis_is_sh_basis_compiled():
    hemisphere_kernels.get()
    dirs = np.random.default_rng(2).normal(size=(100, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    compiled = np.array([hemisphere_kernels.sh_basis(*d) for d in dirs])
    np.testing.assert_array_equal(compiled, sh.evaluate(dirs))
    np.testing.assert_array_equal(np.array([sh.basis(*d) for d in dirs]), sh.evaluate(dirs))
