"""One of the point, spot and area lights per shading point (core.tracer.lights.Choice): the
next-event estimate stays unbiased against closed forms with several lamps, a lamp that cannot
light a point is never picked there (no shadow ray), the probabilities the kernel returns are
the frequencies it picks with, and a scene with one such light bakes as before. No bpy."""

from __future__ import annotations

import numpy as np
import pytest

from hhd_lightmapper.core.scene import AreaLight, BakeScene, PointLight, SpotLight
from hhd_lightmapper.core.tracer import light_kernels, lights
from hhd_lightmapper.core.tracer.paths import Paths, TraceScene
from test_emitter_clusters import polygon_irradiance

X = np.array([0.0, 0.0, 0.0])
N = np.array([0.0, 0.0, 1.0])
#: Two 0.6 × 0.4 m lamps above X, one facing it, one facing away (it lights the ceiling),
#: and a third beside X, tilted towards it.
LAMPS = [
    AreaLight(
        np.array([0.2, 0.1, 1.0]),
        np.array([0.3, 0, 0]),
        np.array([0, 0.2, 0]),
        np.array([0, 0, -1.0]),
        np.array([50.0, 40.0, 30.0]),
    ),
    AreaLight(
        np.array([-0.5, 0.0, 1.5]),
        np.array([0.3, 0, 0]),
        np.array([0, 0.2, 0]),
        np.array([0, 0, 1.0]),
        np.array([90.0, 90.0, 90.0]),
    ),
    AreaLight(
        np.array([1.5, 0.0, 0.6]),
        np.array([0.0, 0.25, 0.0]),
        np.array([0.15, 0.0, 0.15]),
        np.array([-1.0, 0.0, -1.0]) / np.sqrt(2.0),
        np.array([20.0, 30.0, 40.0]),
    ),
]
POINT = PointLight(np.array([-1.0, 0.5, 2.0]), np.array([30.0, 20.0, 10.0]))


def far_triangle() -> np.ndarray:
    """One small triangle far below X: the scene needs geometry, nothing may shadow X."""
    return np.array([[[0.0, 0.0, -50.0], [0.1, 0.0, -50.0], [0.0, 0.1, -50.0]]])


def exact_irradiance(lamps, point=None) -> np.ndarray:
    """∫ L cosθ dω at X (normal N) from the lamps (Lambert's formula on their outlines; a lamp
    facing away gives 0) and a point light (P / 4πd² · cosθ)."""
    total = np.zeros(3)
    for lamp in lamps:
        light = lights.lamps.Area(lamp)
        if (X - lamp.position) @ lamp.normal <= 0.0:
            continue
        a, b = np.array([-1, 1, 1, -1.0]), np.array([-1, -1, 1, 1.0])
        outline = lamp.position + a[:, None] * lamp.axis_u + b[:, None] * lamp.axis_v
        total += polygon_irradiance(X, N, outline, lamp.power / (np.pi * light.area))
    if point is not None:
        to = point.position - X
        d = np.linalg.norm(to)
        total += point.power / (4.0 * np.pi * d * d) * (to @ N) / d
    return total


def trace_scene(light_list) -> TraceScene:
    tris = far_triangle()
    return TraceScene(BakeScene(tris, np.full((1, 3), 0.5), lights=light_list), bounces=0)


def test_one_lamp_per_point_is_unbiased_against_lamberts_formula():
    scene = trace_scene(LAMPS + [POINT])
    assert scene.choice is not None and len(scene.choice.lights) == 4
    paths, k = Paths(scene), 200_000
    x, n = np.tile(X, (k, 1)), np.tile(N, (k, 1))
    terms = paths.irradiance_at(np.random.default_rng(3), x, n) * np.pi  # ∫ L cosθ dω per sample
    exact = exact_irradiance(LAMPS, POINT)
    err = terms.std(axis=0) / np.sqrt(k)
    np.testing.assert_array_less(np.abs(terms.mean(axis=0) - exact), 5 * err)
    assert paths.traced <= k  # one shadow ray per point, not one per lamp


def test_a_lamp_that_cannot_light_a_point_is_never_picked_there():
    choice = lights.choice.Choice([lights.lamps.Area(lamp) for lamp in LAMPS])
    u = np.random.default_rng(0).random(50_000)
    x, n = np.tile(X, (len(u), 1)), np.tile(N, (len(u), 1))
    picked, probability = light_kernels.get().choose_lights(x, n, u, choice.table, lights.choice.CHOICE_SHARE)
    assert set(np.unique(picked)) == {0, 2}  # lamp 1 faces the ceiling, away from X
    # each pick's probability is how often it is picked
    for lamp in (0, 2):
        p = probability[picked == lamp]
        assert np.ptp(p) == 0.0
        assert (picked == lamp).mean() == pytest.approx(p[0], abs=0.01)
    assert probability[picked == 0][0] + probability[picked == 2][0] == pytest.approx(1.0)
    # below the lamp that faces the ceiling, looking up at its back: no lamp, no ray
    below = np.tile([-0.5, 0.0, 1.4], (len(u), 1))
    up = np.tile([0.0, 0.0, 1.0], (len(u), 1))
    picked, probability = light_kernels.get().choose_lights(below, up, u, choice.table[1:2], lights.choice.CHOICE_SHARE)
    assert (picked == -1).all() and not probability.any()


def test_behind_every_lamp_no_shadow_ray_is_traced():
    scene = trace_scene(LAMPS[:2])
    paths, k = Paths(scene), 1000
    x = np.tile([0.2, 0.1, 1.2], (k, 1))  # above lamp 0, below lamp 1: behind both
    n = np.tile([0.0, 0.0, -1.0], (k, 1))
    assert not paths.irradiance_at(np.random.default_rng(0), x, n).any()
    assert paths.traced == 0


def test_a_single_lamp_is_sampled_where_it_can_light_the_point_only():
    """With one lamp the choice only drops the points it cannot light; the others draw the
    numbers of their texel's sequences they drew before, so their samples are the lamp's own."""
    scene = trace_scene(LAMPS[:1])
    paths, k = Paths(scene), 4000
    x = np.concatenate([np.tile(X, (k, 1)), np.tile([0.2, 0.1, 1.3], (k, 1))])  # below, then behind
    n = np.tile(N, (2 * k, 1))
    stream = lights.light.TexelStream(np.arange(2), k, 0, 1)
    rng = np.random.default_rng(7)
    ((dirs, value, dist), allowed, column) = paths.light_samples(rng, x, None, stream, normals=n)[0]
    assert column == 0
    assert allowed[:k].all() and not allowed[k:].any() and not value[k:].any()
    own = lights.lamps.Area(LAMPS[0]).sample(rng, x[:k], None, lights.light.TexelStream(np.arange(1), k, 0, 1))
    for got, want in zip((dirs[:k], value[:k], dist[:k]), own):
        np.testing.assert_array_equal(got, want)


def test_spot_and_point_lights_without_normals_are_chosen_by_distance():
    """Probes pass no normals: the horizon factor is left out, the nearer of two equal point
    lights is picked more, and the far one keeps at least its share of intensity alone."""
    near = PointLight(np.array([0.0, 0.0, 1.0]), np.array([10.0, 10.0, 10.0]))
    far = SpotLight(
        np.array([0.0, 0.0, 10.0]), np.array([10.0, 10.0, 10.0]), direction=np.array([0, 0, -1.0]), size=1.0
    )
    choice = lights.choice.Choice([lights.lamps.Point(near), lights.lamps.Spot(far)])
    u = np.linspace(0.0, 1.0, 10_001)[:-1]
    picked, probability = light_kernels.get().choose_lights(
        np.zeros((len(u), 3)), np.zeros((0, 3)), u, choice.table, lights.choice.CHOICE_SHARE
    )
    share_far = (picked == 1).mean()
    assert lights.choice.CHOICE_SHARE / 2 <= share_far < 0.1
    assert probability[picked == 1][0] == pytest.approx(share_far, abs=1e-3)


def test_a_spot_is_never_picked_outside_its_cone_and_stays_unbiased_inside():
    """A spot (half-angle 0.3 rad, radius 0.1 m) 2 m above the floor and a point light: beside
    the spot, outside its cone widened by the angle its sphere subtends, only the point light is
    picked; at the cone's edge the estimate still matches each light sampled on its own."""
    spot = SpotLight(
        np.array([0.0, 0.0, 2.0]),
        np.array([40.0, 40.0, 40.0]),
        0.1,
        direction=np.array([0, 0, -1.0]),
        size=0.6,
        blend=0.2,
    )
    scene = trace_scene([spot, POINT])
    u = np.random.default_rng(1).random(20_000)
    assert scene.choice is not None
    outside = np.tile([2.0, 0.0, 0.0], (len(u), 1))  # 45° off the axis
    picked, _ = light_kernels.get().choose_lights(
        outside, np.tile(N, (len(u), 1)), u, scene.choice.table, lights.choice.CHOICE_SHARE
    )
    assert (picked == 1).all()
    edge = np.array([2.0 * np.tan(0.3), 0.0, 0.0])  # on the cone: half lit through the blend
    paths, k = Paths(scene), 200_000
    x, n = np.tile(edge, (k, 1)), np.tile(N, (k, 1))
    terms = paths.irradiance_at(np.random.default_rng(2), x, n)
    rng = np.random.default_rng(4)
    own = sum(
        (value * np.maximum(dirs @ N, 0.0)[:, None]).mean(axis=0) / np.pi
        for dirs, value, _ in (
            lights.lamps.Spot(spot).sample(rng, x, None),
            lights.lamps.Point(POINT).sample(rng, x, None),
        )
    )
    err = terms.std(axis=0) / np.sqrt(k)
    np.testing.assert_array_less(np.abs(terms.mean(axis=0) - own), 5 * err + 1e-3 * own)


def test_one_lamp_per_point_agrees_with_every_lamp_sampled_at_every_point():
    """The reference: every lamp sampled at every point, one shadow ray each (the sampling before
    `Choice`, bench/light_sampling.py's earlier rows), as the sum of each lamp alone in a scene of
    its own (independent numbers per lamp); the chosen lamp per point gives the same irradiance
    within the noise of both, with under half the shadow rays."""
    k = 100_000
    x, n = np.tile(X, (k, 1)), np.tile(N, (k, 1))
    chosen = Paths(trace_scene(LAMPS + [POINT]))
    picked = chosen.irradiance_at(np.random.default_rng(8), x, n)
    alone = [Paths(trace_scene([lamp])) for lamp in LAMPS + [POINT]]
    each = sum(paths.irradiance_at(np.random.default_rng(9 + j), x, n) for j, paths in enumerate(alone))
    assert chosen.traced < 2 * k <= sum(paths.traced for paths in alone)
    err = np.sqrt(picked.var(axis=0) / k + each.var(axis=0) / k)
    np.testing.assert_array_less(np.abs(picked.mean(axis=0) - each.mean(axis=0)), 5 * err)
