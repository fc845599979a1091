"""The tracer on its own (no Blender): furnace, exact delta lights, determinism, threads,
progress, cancel, buried texels."""

import contextlib

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, hhd, rays, sh, tracer, unwrap
from hhd_lightmapper.core.colour import LUMINANCE
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit import meshes


def floor_points(extra_v=None, extra_f=None):
    v, f = meshes.plane(2.0)
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", v, f)], unwrap.UnwrapSettings(resolution=256))
    surface = bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), res.objects[0].uv.astype(float), np.zeros(2, int), np.full((2, 3), 0.5)
    )
    tris = v[f] if extra_v is None else np.concatenate([v[f], extra_v[extra_f]])
    return bakepoints.build(surface, 256, 256, occluders=rays.RayScene(tris)), tris


def test_furnace_gives_exact_irradiance_and_the_masked_hemisphere_sh():
    points, tris = floor_points()
    scene = BakeScene(tris, np.full((len(tris), 3), 0.5), world=np.array([1.0, 1.0, 1.0]))
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=32))
    np.testing.assert_allclose(hhd.irradz(result.sh, points.normal), 1.0, rtol=1e-12)
    local = sh.to_local(result.sh, sh.tangent_frames(points.normal))
    expected = np.zeros(9)
    expected[0], expected[2] = np.sqrt(np.pi), np.sqrt(3 * np.pi) / 2  # masked constant hemisphere
    mean = local.mean(axis=0)[:, 0]
    se = np.sqrt((result.sh_error[:, :, 0] ** 2).sum(axis=0)) / len(points.texel)
    assert (np.abs(mean - expected) <= 5 * se + 1e-12).all(), (mean, se)


def test_unshadowed_sun_is_noise_free_and_exact():
    points, tris = floor_points()
    sun = SunLight(np.array([0.6, 0.0, 0.8]), np.array([3.0, 2.0, 1.0]))
    result = tracer.bake(
        points, BakeScene(tris, np.full((len(tris), 3), 0.5), lights=[sun]), tracer.BakeSettings(samples=16, bounces=0)
    )
    np.testing.assert_allclose(
        hhd.irradz(result.sh, points.normal), np.tile([3.0, 2.0, 1.0], (len(points.texel), 1)) * 0.8 / np.pi, rtol=1e-9
    )
    np.testing.assert_allclose(
        result.sh,
        np.tile(sh.evaluate(sun.direction[None])[0][:, None] * sun.irradiance, (len(points.texel), 1, 1)),
        atol=1e-12,
    )


def test_same_seed_same_result_whatever_the_thread_count():
    wall_v, wall_f = meshes.cube(1.0, centre=(0.0, 0.0, 0.5))
    points, tris = floor_points(wall_v * [0.2, 1.0, 1.0], wall_f)
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.6),
        lights=[SunLight(np.array([0.5, 0.1, 0.86]), np.ones(3))],
        world=np.array([0.2, 0.3, 0.5]),
    )
    settings = dict(samples=32, bounces=2, seed=5, chunk_texels=4096)
    a = tracer.bake(points, scene, tracer.BakeSettings(threads=1, **settings))
    b = tracer.bake(points, scene, tracer.BakeSettings(threads=2, **settings))
    np.testing.assert_array_equal(a.sh, b.sh)
    c = tracer.bake(points, scene, tracer.BakeSettings(threads=2, **{**settings, "seed": 6}))
    assert not np.array_equal(a.sh, c.sh)
    assert a.rays > len(points.texel) * 32


def test_progress_is_reported_and_cancel_stops_within_a_chunk():
    points, tris = floor_points()
    scene = BakeScene(tris, np.full((len(tris), 3), 0.5), world=np.ones(3))
    seen = []
    tracer.bake(
        points, scene, tracer.BakeSettings(samples=32, chunk_texels=8192), progress=lambda f, msg: seen.append((f, msg))
    )
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert "pass 2 of 2" in seen[-1][1] and "rays/s" in seen[-1][1]
    calls = []
    with pytest.raises(tracer.BakeCancelled):
        tracer.bake(
            points,
            scene,
            tracer.BakeSettings(samples=64, chunk_texels=8192),
            cancel=lambda: calls.append(1) or len(calls) > 2,
        )
    assert len(calls) == 3


def test_buried_texels_bake_black_and_odd_pass_sizes_are_refused():
    v, f = meshes.cube(1.0)
    v = v * [0.03, 2.0, 1.2] + [0.0, 0.0, 0.4]
    points, tris = floor_points(v, f)
    assert points.buried.any()
    result = tracer.bake(
        points, BakeScene(tris, np.full((len(tris), 3), 0.5), world=np.ones(3)), tracer.BakeSettings(samples=16)
    )
    assert (result.sh[points.buried] == 0).all()
    clear = np.abs(points.position[:, 0]) > 0.015 + 3 * points.texel_size  # away from the wall
    assert (hhd.irradz(result.sh, points.normal)[clear] > 0).all()
    with pytest.raises(BakeError, match="multiple of 4"):
        tracer.bake(points, BakeScene(tris, np.full((len(tris), 3), 0.5)), tracer.BakeSettings(pass_samples=15))


def sky_environment(rotation=np.eye(3)):
    """A sky gradient with a bright 1-pixel sun (the hard case for bilinear vs sampling)."""
    from hhd_lightmapper.core.environment import EnvironmentMap

    h, w = 32, 64
    z = np.cos(np.pi * (1.0 - (np.arange(h) + 0.5) / h))
    img = np.tile(((0.2 + 0.8 * z.clip(0))[:, None, None] * np.array([0.3, 0.5, 1.0])), (1, w, 1))
    img[int(h * 0.8), int(w * 0.3)] = [2000.0, 1600.0, 1200.0]
    return EnvironmentMap(img, rotation)


def sphere_quadrature(env, s=8):
    """World directions and solid-angle weights of a fine grid over the environment image."""
    h, w = env.pixels.shape[:2]
    u, v = np.meshgrid((np.arange(w * s) + 0.5) / (w * s), (np.arange(h * s) + 0.5) / (h * s))
    phi, theta = np.pi - 2 * np.pi * u, np.pi - np.pi * v
    b = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    weight = ((2 * np.pi / (w * s)) * (np.pi / (h * s)) * np.sin(theta)).ravel()
    return b @ env.inverse.T, weight


def test_environment_sampling_density_is_normalised_and_consistent():
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    env = sky_environment(rotation)
    dirs, weight = sphere_quadrature(env)
    assert abs((env.pdf(dirs) * weight).sum() - 1.0) < 1e-3
    sampled, pdf = env.sample(np.random.default_rng(0), 100_000)
    np.testing.assert_allclose(pdf, env.pdf(sampled), rtol=1e-12)
    assert np.allclose(np.linalg.norm(sampled, axis=1), 1.0)
    # the sun pixel's 3×3 neighbourhood (where bilinear filtering spreads it) holds most of the
    # light and gets most of the samples
    uv = env.uv(sampled) * [64, 32]
    near_sun = (np.abs(uv[:, 0] - (int(64 * 0.3) + 0.5)) < 1.5) & (np.abs(uv[:, 1] - (int(32 * 0.8) + 0.5)) < 1.5)
    assert near_sun.mean() > 0.5


@pytest.mark.statistical
def test_hdri_world_bake_matches_quadrature_of_the_environment():
    """A plane under an HDRI sky with a tiny bright sun: MIS of environment and hemisphere
    sampling is unbiased (mean SH within 4 standard errors of a fine quadrature of the image)
    and far less noisy per texel than hemisphere sampling alone would be."""
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    env = sky_environment(rotation)
    points, tris = floor_points()
    result = tracer.bake(
        points,
        BakeScene(tris, np.full((len(tris), 3), 0.5), environment=env),
        tracer.BakeSettings(samples=32, bounces=1),
    )
    dirs, weight = sphere_quadrature(env)
    up = dirs[:, 2] > 0
    reference = sh.project(dirs[up], env.radiance(dirs[up]), weight[up]).reshape(9, 3)
    mean = result.sh.mean(axis=0)
    se = np.sqrt((result.sh_error**2).sum(axis=0)) / len(points.texel)
    assert (np.abs(mean - reference) <= 4 * se + 1e-9).all(), (mean - reference) / se
    iz = hhd.irradz(result.sh, points.normal)
    assert (iz.std(axis=0) / iz.mean(axis=0)).max() < 0.5  # per-texel noise at 32 spp


@pytest.mark.statistical
def test_emissive_triangles_are_light_sampled_without_bias():
    """A small emissive quad above the floor: the MIS bake's SH match a fine quadrature over the
    quad (per texel, within 4 standard errors), and are far less noisy than when the quad is
    found by hemisphere sampling alone."""
    lamp_v = np.array([[0.8, 0.8, 0.6], [1.2, 0.8, 0.6], [1.2, 1.2, 0.6], [0.8, 1.2, 0.6]])
    lamp_f = np.array([[0, 1, 2], [0, 2, 3]])
    points, tris = floor_points(lamp_v, lamp_f)
    emission = np.zeros((len(tris), 3))
    emission[-2:] = [40.0, 30.0, 20.0]
    scene = BakeScene(tris, np.full((len(tris), 3), 0.5), emission=emission)
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=64, pass_samples=8, bounces=0))
    pick = np.random.default_rng(0).choice(len(points.texel), 300, replace=False)
    s = 48
    a, b = np.meshgrid((np.arange(s) + 0.5) / s, (np.arange(s) + 0.5) / s)
    quad = np.stack([0.8 + 0.4 * a.ravel(), 0.8 + 0.4 * b.ravel(), np.full(s * s, 0.6)], 1)
    to = quad[None] - points.position[pick][:, None]
    dist = np.linalg.norm(to, axis=2)
    dirs = to / dist[..., None]
    weight = (0.16 / (s * s)) * np.abs(dirs[..., 2]) / dist**2  # dω = cos dA / d²
    y = sh.evaluate(dirs.reshape(-1, 3)).reshape(len(pick), s * s, 9)
    reference = np.einsum("pqk,pq->pk", y, weight)[..., None] * emission[-1]
    diff = (result.sh[pick] - reference).sum(axis=0)  # summed over texels
    se = np.sqrt((result.sh_error[pick] ** 2).sum(axis=0))
    assert (np.abs(diff) <= 4 * se + 1e-9).all(), diff / se
    relative_noise = result.sh_error[pick, 0] / np.maximum(reference[:, 0], 1e-12)
    assert np.median(relative_noise) < 0.05, np.median(relative_noise)


def shaded_floor(lit_by: str, res: int = 32):
    """A 2 m floor (res² texels) and a 30 cm box 25 cm above it, lit by a constant sky
    (`lit_by` "directions": the rays find the light) or by a 1 m emissive quad 1 m up (else:
    the light samples find it). (bake points, BakeScene)."""
    v, f = meshes.plane(2.0)
    floor = v[f]
    surface = bakepoints.SurfaceTriangles(
        floor, np.tile([0, 0, 1.0], (2, 3, 1)), floor[..., :2] / 2.0 + 0.5, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    box_v, box_f = meshes.cube(0.3, centre=(0.2, 0.1, 0.4))
    lamp = np.array(
        [[[-0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [0.5, -0.5, 1.0]], [[-0.5, -0.5, 1.0], [-0.5, 0.5, 1.0], [0.5, 0.5, 1.0]]]
    )
    tris = np.concatenate([floor, box_v[box_f], lamp])
    albedo = np.full((len(tris), 3), 0.5)
    if lit_by == "directions":
        scene = BakeScene(tris, albedo, world=np.array([1.0, 1.0, 1.0]))
    else:
        emission = np.zeros((len(tris), 3))
        emission[-2:] = 5.0
        scene = BakeScene(tris, albedo, emission=emission)
    return bakepoints.build(surface, res, res, occluders=rays.RayScene(tris)), scene


def floor_noise(points, scene, samples: int = 64) -> tuple[float, float]:
    """I_z's noise over the unburied texels (a texel's in one bake: two seeds' difference / √2)
    and its mean over both bakes, at `samples` per texel in passes of 16, direct light only."""
    keep = ~points.buried
    a, b = (
        hhd.irradz(
            tracer.bake(points, scene, tracer.BakeSettings(samples=samples, bounces=0, seed=s)).sh, points.normal
        )[keep]
        @ LUMINANCE
        for s in (3, 4)
    )
    return float(np.sqrt(np.mean((a - b) ** 2) / 2)), float(np.mean(a + b) / 2)


@pytest.mark.statistical
@pytest.mark.parametrize("part", ["directions", "lights"])
def test_a_texels_own_sequences_lower_its_noise_against_numbers_drawn_pass_by_pass(part):
    """A texel's hemisphere directions (the floor under a sky, shaded by a box) and its light
    samples (under an emissive quad: the box's penumbra) come from its own sequences, stratified
    across its passes. At 64 samples in 4 passes, I_z's noise over the floor is well below that
    of the same bake with that part's numbers drawn pass by pass (scenekit/estimator_reference.py),
    and both bakes agree on the mean."""
    from scenekit import estimator_reference

    points, scene = shaded_floor(part)
    noise, mean = {}, {}
    for reference in (False, True):
        with estimator_reference.used(part) if reference else contextlib.nullcontext():
            noise[reference], mean[reference] = floor_noise(points, scene)
    assert noise[False] < 0.7 * noise[True], noise
    texels = int((~points.buried).sum())
    assert abs(mean[False] - mean[True]) < 4 * np.hypot(noise[False], noise[True]) / np.sqrt(2 * texels), (mean, noise)


@pytest.mark.statistical
def test_a_texels_directions_lower_its_noise_faster_than_independent_passes_would():
    """The floor under a sky shaded by a box: 4 passes of 16 directions of one texel's own
    sequence cover its hemisphere as one 64-point net, so I_z's noise falls from 16 to 64
    samples clearly faster than the 1/√4 of independent passes, whether each pass is stratified
    within itself or not."""
    points, scene = shaded_floor("directions")
    assert floor_noise(points, scene, 64)[0] < 0.45 * floor_noise(points, scene, 16)[0]


@pytest.mark.statistical
@pytest.mark.parametrize("power, reference", [(0.5, 0.5), (0.5, 1.0), (1.0, 1.0)])
def test_roulette_keeps_a_glowing_closed_box_unbiased(monkeypatch, power, reference):
    """Inside a closed box whose every face emits radiance 1 and reflects 0.6, the radiance
    arriving from any direction after at most 3 reflections is 1 + 0.6 + 0.6² + 0.6³, whatever
    ends paths early: survival √(throughput / ½) (now), √throughput (Cycles') or the throughput
    (before 2026-12-03). The throughput after two reflections, 0.36, is below every reference."""
    from hhd_lightmapper.core.tracer import paths

    monkeypatch.setattr(paths, "RR_SURVIVAL_POWER", power)
    monkeypatch.setattr(paths, "RR_REFERENCE", reference)
    box_v, box_f = meshes.cube(3.0, centre=(1.0, 1.0, 1.0))  # around the floor (0..2, 0..2, 0)
    points, tris = floor_points(box_v, box_f)
    scene = BakeScene(tris, np.full((len(tris), 3), 0.6), emission=np.ones((len(tris), 3)))
    settings = tracer.BakeSettings(samples=16, bounces=3, seed=3)
    result = tracer.bake(points, scene, settings)
    iz = luminance_iz(result, points)
    expected = 1.0 + 0.6 + 0.6**2 + 0.6**3
    assert abs(iz.mean() - expected) < 4 * iz.std() / np.sqrt(len(iz)), (iz.mean(), expected)
    monkeypatch.setattr(paths, "RR_START", 1000)  # no roulette: every path to the last bounce
    assert result.rays < tracer.bake(points, scene, settings).rays  # the roulette did end paths


def occluded_floor_scene():
    """A floor half shadowed by a wall under a soft sun and a sky: texels differ in noise
    (open sky converges fast, the penumbra and the wall's foot slowly)."""
    wall_v, wall_f = meshes.cube(1.0, centre=(0.0, 0.0, 0.5))
    points, tris = floor_points(wall_v * [0.2, 1.2, 1.0], wall_f)
    sun = SunLight(np.array([0.6, 0.0, 0.8]), np.array([3.0, 2.8, 2.5]), angle=np.radians(10.0))
    return points, BakeScene(tris, np.full((len(tris), 3), 0.6), lights=[sun], world=np.array([0.3, 0.4, 0.6]))


def luminance_iz(result, points):
    return hhd.irradz(result.sh, points.normal) @ hhd.LUMINANCE


@pytest.mark.statistical
def test_noise_target_stops_converged_texels_and_meets_the_target():
    points, scene = occluded_floor_scene()
    open_ = ~points.buried
    reference = luminance_iz(tracer.bake(points, scene, tracer.BakeSettings(samples=1024, bounces=1, seed=1)), points)
    target = 0.03
    adaptive = tracer.bake(points, scene, tracer.BakeSettings(samples=1024, bounces=1, noise_target=target))
    taken = adaptive.texel_samples[open_]
    assert taken.min() >= tracer.MIN_ADAPTIVE_PASSES * 16
    assert taken.min() < taken.max()  # easy texels stopped before the hard ones
    assert adaptive.mean_samples < 0.5 * 1024
    # the error it reaches: relative RMS over the texels ≈ the target (the reference has noise too)
    iz = luminance_iz(adaptive, points)[open_]
    floor = tracer.NOISE_FLOOR * reference[open_].mean()
    relative = (iz - reference[open_]) / np.maximum(reference[open_], floor)
    assert np.sqrt(np.mean(relative**2)) < 1.5 * target, np.sqrt(np.mean(relative**2))
    # fixed counts with the same mean sample count are noisier where it matters: the slow texels
    slow = taken >= np.percentile(taken, 90)
    fixed = tracer.bake(points, scene, tracer.BakeSettings(samples=int(adaptive.mean_samples // 16 * 16), bounces=1))
    fixed_rel = (luminance_iz(fixed, points)[open_] - reference[open_]) / np.maximum(reference[open_], floor)
    assert np.sqrt(np.mean(relative[slow] ** 2)) < np.sqrt(np.mean(fixed_rel[slow] ** 2))


@pytest.mark.slow
def test_noise_target_is_deterministic_whatever_the_thread_count():
    points, scene = occluded_floor_scene()
    settings = dict(samples=256, bounces=1, noise_target=0.05, chunk_texels=4096)
    a = tracer.bake(points, scene, tracer.BakeSettings(threads=1, **settings))
    b = tracer.bake(points, scene, tracer.BakeSettings(threads=2, **settings))
    np.testing.assert_array_equal(a.sh, b.sh)
    np.testing.assert_array_equal(a.texel_samples, b.texel_samples)


def test_noise_target_on_black_and_constant_texels_stops_at_the_minimum():
    points, tris = floor_points()
    black = tracer.bake(
        points, BakeScene(tris, np.full((len(tris), 3), 0.5)), tracer.BakeSettings(samples=512, noise_target=0.01)
    )
    assert black.stopped_by == "noise_target" and black.samples == tracer.MIN_ADAPTIVE_PASSES * 16
    assert np.all(black.sh == 0.0)
    furnace = tracer.bake(
        points,
        BakeScene(tris, np.full((len(tris), 3), 0.5), world=np.full(3, 1e30)),
        tracer.BakeSettings(samples=512, noise_target=0.01),
    )
    assert furnace.stopped_by == "noise_target" and np.isfinite(furnace.sh).all()


@pytest.mark.slow
def test_time_budget_stops_after_the_first_pass_with_an_estimate_everywhere():
    points, scene = occluded_floor_scene()
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=1 << 20, bounces=1, time_budget=0.5))
    assert result.stopped_by == "time_budget"
    assert result.texel_samples.min() >= 16 and result.samples < 1 << 20
    assert result.seconds < 60  # far from the 65536 passes it was allowed
    assert np.isfinite(result.sh).all()
    fixed = tracer.bake(points, scene, tracer.BakeSettings(samples=64, bounces=1))
    assert luminance_iz(result, points).mean() == pytest.approx(luminance_iz(fixed, points).mean(), rel=0.02)


def test_negative_noise_target_or_budget_is_refused():
    points, scene = occluded_floor_scene()
    for bad in (dict(noise_target=-0.1), dict(time_budget=-1.0), dict(noise_target=float("nan"))):
        with pytest.raises(BakeError, match="noise target"):
            tracer.bake(points, scene, tracer.BakeSettings(samples=16, **bad))


def test_bake_point_stage_checks_for_cancel_between_chunks():
    from hhd_lightmapper.core.errors import BakeCancelled

    v, f = meshes.plane(2.0)
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", v, f)], unwrap.UnwrapSettings(resolution=1024))
    surface = bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), res.objects[0].uv.astype(float), np.zeros(2, int), np.full((2, 3), 0.5)
    )
    calls = []
    points = bakepoints.build(surface, 1024, 1024, occluders=rays.RayScene(v[f]), check=lambda: calls.append(1))
    assert len(calls) >= len(points.texel) // (1 << 16)  # at least once per chunk of the buried test

    def cancel_on_third():
        calls.append(1)
        if len(calls) > 2:
            raise BakeCancelled("bake cancelled")

    calls.clear()
    with pytest.raises(BakeCancelled):
        bakepoints.build(surface, 1024, 1024, occluders=rays.RayScene(v[f]), check=cancel_on_third)
    assert len(calls) == 3


def test_running_statistics_match_the_passes_mean_and_standard_error():
    """The accumulator (float64 sum, Welford's float32 squared deviations) against numpy over the
    stored passes: texels with different pass counts (a noise target's fancy-indexed chunks), a
    texel whose passes agree exactly (error 0, as an unshadowed sun), and values of 1e6 ± 1
    (where a float32 sum of squares minus the squared mean would lose everything)."""
    rng = np.random.default_rng(3)
    n = 6
    acc = tracer.Statistics(n, np.tile([0.0, 0.0, 1.0], (n, 1)))
    passes = {t: [] for t in range(n)}
    for p in range(7):
        idx = np.arange(n) if p < 3 else np.array([0, 2, 3, 5])  # later passes skip texels 1, 4
        est = 1e6 + rng.normal(size=(len(idx), 9, 3))
        est[idx == 3] = 2.5  # texel 3: every pass agrees
        acc.add(idx, est)
        for row, t in enumerate(idx):
            passes[t].append(est[row])
    mean, error = acc.result()
    for t, values in passes.items():
        values = np.array(values)
        k = len(values)
        assert acc.passes[t] == k
        np.testing.assert_allclose(mean[t], values.mean(axis=0), rtol=1e-14)
        np.testing.assert_allclose(error[t], values.std(axis=0, ddof=1) / np.sqrt(k), rtol=1e-5, atol=1e-30)
    assert (error[3] == 0.0).all()
