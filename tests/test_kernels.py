"""The tracer's compiled kernels against numpy references written from their definitions."""

from types import SimpleNamespace

import numpy as np
import pytest

import quadrature as quad
from hhd_lightmapper.core import sampling, sh
from hhd_lightmapper.core.bakepoints import kernels as bakepoint_kernels
from hhd_lightmapper.core.tracer import hemisphere_kernels, path_kernels, statistics_kernels

SETS = (sampling, hemisphere_kernels, path_kernels, statistics_kernels, bakepoint_kernels)
K = SimpleNamespace(**{name: f for module in SETS for name, f in vars(module.get()).items()})


@pytest.fixture
def rng():
    return np.random.default_rng(5)


def unit(rng, n):
    return quad.random_dirs(rng, n)


def sh_reference(dirs, values, weights, k):
    """Σ_s w v Y per group of k, with sh.evaluate."""
    y = sh.evaluate(dirs).reshape(-1, k, 9)
    v = (values * weights[:, None]).reshape(-1, k, 3)
    return np.einsum("tsm,tsc->tmc", y, v)


def test_grouped_accumulation_matches_the_sh_basis_with_broadcast_rows_and_zero_weights(rng):
    dirs, values, weights = unit(rng, 12 * 8), rng.random((12 * 8, 3)), rng.random(12 * 8)
    weights[::3] = 0.0
    out = np.zeros((12, 9, 3))
    K.accumulate_grouped(dirs, values, weights, 8, out)
    np.testing.assert_allclose(out, sh_reference(dirs, values, weights, 8), atol=1e-12)
    K.accumulate_grouped(dirs, values, weights, 8, out)  # adds in place
    np.testing.assert_allclose(out, 2 * sh_reference(dirs, values, weights, 8), atol=1e-12)
    sun, irradiance = np.broadcast_to(unit(rng, 1), (96, 3)), np.broadcast_to([1.0, 2.0, 3.0], (96, 3))
    out = np.zeros((12, 9, 3))
    K.accumulate_grouped(sun, irradiance, weights, 8, out)
    np.testing.assert_allclose(out, sh_reference(np.array(sun), np.array(irradiance), weights, 8), atol=1e-12)


def texel_rays(normals, k, passes, texels=None, seed=11, alpha=0.5):
    """`hemisphere_kernels.texel_hemisphere_rays` over `passes` passes of k, concatenated per texel:
    directions (n, passes·k, 3) in pass order, and the pdf (n, passes·k)."""
    texels = np.arange(len(normals)) if texels is None else texels
    out = [K.texel_hemisphere_rays(normals, k, texels, p * k, seed, alpha) for p in range(passes)]
    dirs = np.concatenate([d.reshape(len(normals), k, 3) for d, _ in out], axis=1)
    pdf = np.concatenate([f.reshape(len(normals), k) for _, f in out], axis=1)
    return dirs, pdf


def half_numbers(normals, dirs, k, passes, alpha=0.5):
    """The (u1, u2) each texel's samples were drawn from, per half: (2, n, passes·k/2) each
    (u1: the mixture's CDF in cosθ, α z + (1 − α) z²; u2: the azimuth / 2π)."""
    local = np.einsum("tji,tsj->tsi", sh.tangent_frames(normals), dirs)
    z, phi = local[..., 2], np.mod(np.arctan2(local[..., 1], local[..., 0]), 2 * np.pi) / (2 * np.pi)
    u1 = alpha * z + (1.0 - alpha) * z * z
    half = np.tile(np.repeat(np.arange(2), k // 2), passes)
    return np.stack([u1[:, half == h] for h in range(2)]), np.stack([phi[:, half == h] for h in range(2)])


@pytest.mark.parametrize("alpha", [0.5, 0.25])
def test_texel_hemisphere_rays_have_the_mixture_density_and_are_stratified_across_passes(alpha):
    """Across 4 passes of 16 each half's 32 numbers lie one per 1/32 stratum of u1 and of u2,
    and one per cell of the 4 × 8 and 8 × 4 grids (a (0,5,2)-net), for every texel; within
    one pass too (8 numbers: one per eighth). The cosines follow the mixture: E[cosθ] =
    α/2 + 2(1 − α)/3."""
    normals = unit(np.random.default_rng(4), 200)
    dirs, pdf = texel_rays(normals, 16, 4, alpha=alpha)
    cos = np.einsum("tsi,ti->ts", dirs, normals)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=2), 1.0, atol=1e-12)
    assert cos.min() >= 0.0
    np.testing.assert_allclose(pdf, alpha / (2 * np.pi) + (1 - alpha) * cos / np.pi, atol=1e-12)
    assert abs(cos.mean() - (alpha / 2 + 2 * (1 - alpha) / 3)) < 0.01
    u1, u2 = half_numbers(normals, dirs, 16, 4, alpha)
    every = np.tile(np.arange(32), (2, 200, 1))
    np.testing.assert_array_equal(np.sort(np.floor(u1 * 32 + 1e-9), axis=2), every)
    np.testing.assert_array_equal(np.sort(np.floor(u2 * 32), axis=2), every)
    for rows, cols in ((4, 8), (8, 4)):
        cells = np.floor(u1 * rows + 1e-9) * cols + np.floor(u2 * cols)
        np.testing.assert_array_equal(np.sort(cells, axis=2), every)
    first_pass = np.sort(np.floor(u1[:, :, :8] * 8 + 1e-9), axis=2)
    np.testing.assert_array_equal(first_pass, np.tile(np.arange(8), (2, 200, 1)))


def test_texel_hemisphere_rays_are_uniform_and_independent_between_halves_texels_and_seeds():
    """Each number is uniform (its scramble is random per (seed, texel, half)): over many texels
    the first sample of each half is uniform in u1 and u2, and the halves (the control
    variate's) are uncorrelated; a texel's sequence depends on its id and the seed only."""
    n = 20000
    normals = unit(np.random.default_rng(6), n)
    dirs, _ = texel_rays(normals, 4, 1)
    u1, u2 = half_numbers(normals, dirs, 4, 1)
    for u in (u1[:, :, 0], u2[:, :, 0]):
        counts = np.stack([np.bincount(np.floor(row * 10).astype(int), minlength=10) for row in u])
        assert np.abs(counts - n / 10).max() < 5 * np.sqrt(n / 10)  # 5 σ
    assert abs(np.corrcoef(u1[0, :, 0], u1[1, :, 0])[0, 1]) < 0.04
    same, _ = texel_rays(normals[:50], 16, 2, texels=np.arange(50))
    shifted, _ = texel_rays(normals[:50], 16, 2, texels=np.arange(50) + 1)
    reseeded, _ = texel_rays(normals[:50], 16, 2, seed=12)
    np.testing.assert_array_equal(same, texel_rays(normals[:50], 16, 2)[0])
    assert not np.isclose(same, shifted).all(axis=2).any()
    assert not np.isclose(same, reseeded).all(axis=2).any()


def test_mixture_cosine_solves_the_cdf_to_rounding_from_1e_300_to_1():
    """cosθ = z with α z + (1 − α) z² = u, to a relative 1e-14 of u even where u ≪ α² (the
    textbook root (−α + √(α² + 4(1 − α)u)) / (2(1 − α)) cancels to 0 there)."""
    mixture_cos = sampling.mixture_cos  # the compiled helper (`get()` rebinds it)
    for alpha in (0.0, 1e-9, 0.25, 0.5, 1.0):
        assert mixture_cos(0.0, alpha) == 0.0
        assert abs(mixture_cos(1.0, alpha) - 1.0) < 1e-15
        for u in np.logspace(-300, 0, 61):
            z = mixture_cos(u, alpha)
            assert 0.0 < z <= 1.0
            assert abs(alpha * z + (1.0 - alpha) * z * z - u) <= 1e-14 * u


def project_halves_reference(dirs, radiance, pdf, normals, k):
    """The control-variate estimator of hemisphere_kernels.project_halves, from its docstring."""
    half = k // 2
    r = radiance.reshape(-1, k, 3)
    beta_a, beta_b = r[:, half:].mean(axis=1), r[:, :half].mean(axis=1)
    adjusted = np.concatenate([r[:, :half] - beta_a[:, None], r[:, half:] - beta_b[:, None]], axis=1)
    estimate = sh_reference(dirs, adjusted.reshape(-1, 3), 1.0 / (pdf * k), k)
    hemisphere = np.zeros((len(normals), 9))
    hemisphere[:, 0] = 2 * np.pi * sh.Y00
    hemisphere[:, 1:4] = sh.C1 * np.pi * normals[:, [1, 2, 0]] * [-1, 1, -1]
    return estimate + hemisphere[:, :, None] * (0.5 * (beta_a + beta_b))[:, None, :]


def test_projection_of_halves_matches_its_estimator_and_the_furnace(rng):
    normals = unit(rng, 40)
    dirs, pdf = K.texel_hemisphere_rays(normals, 16, np.arange(40), 16, 5, 0.25)
    radiance = rng.random((len(dirs), 3)) * 5.0
    np.testing.assert_allclose(
        K.project_halves(dirs, radiance, pdf, normals, 16),
        project_halves_reference(dirs, radiance, pdf, normals, 16),
        atol=1e-10,
    )
    got = K.project_halves(dirs, np.full((len(dirs), 3), 2.5), pdf, normals, 16)
    qd, w = quad.hemisphere(n_z=200, n_phi=400)
    for t, n in enumerate(normals[:6]):
        world = qd @ sh.tangent_frames(n[None])[0].T
        np.testing.assert_allclose(got[t], 2.5 * (w @ sh.evaluate(world))[:, None] * np.ones(3), atol=1e-4)


def test_row_sequences_are_stratified_across_passes_whichever_rows_are_asked():
    """4 passes of 16 samples of 30 texels: each texel's 64 pairs lie one per 1/64 stratum of
    either number and one per cell of the 8 × 8 grid; asking for a subset of a pass's rows
    (the paths that hit something) gives those rows' numbers unchanged; another stream: others."""
    n, k, passes = 30, 16, 4
    texels = np.arange(n, dtype=np.int64) * 3 + 1
    rows = np.arange(n * k, dtype=np.int64)
    u = np.stack([K.row_sequence(rows, texels, k, p * k, 9, 128).reshape(2, n, k) for p in range(passes)], axis=2)
    u = u.reshape(2, n, k * passes)
    every = np.tile(np.arange(k * passes), (n, 1))
    for dim in range(2):
        np.testing.assert_array_equal(np.sort(np.floor(u[dim] * k * passes), axis=1), every)
    np.testing.assert_array_equal(np.sort(np.floor(u[0] * 8) * 8 + np.floor(u[1] * 8), axis=1), every)
    some = rows[np.random.default_rng(2).random(len(rows)) < 0.4]
    np.testing.assert_array_equal(
        K.row_sequence(some, texels, k, 16, 9, 128), K.row_sequence(rows, texels, k, 16, 9, 128)[:, some]
    )
    assert (
        not np.isclose(K.row_sequence(rows, texels, k, 0, 9, 129), K.row_sequence(rows, texels, k, 0, 9, 128))
        .all(axis=0)
        .any()
    )


def test_kernels_depend_on_the_seed_only():
    hidden = np.random.default_rng(3).random(50 * 8) < 0.5
    a, b, c = (K.replace_hidden(hidden, 8, seed) for seed in (1, 1, 2))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def hits(rng, r=4000):
    """Rays from random points towards a plane z = 0 hit from either side, half of them missing."""
    o = rng.normal(size=(r, 3))
    o[:, 2] = np.where(rng.random(r) < 0.5, 1.0, -1.0) * (0.5 + rng.random(r))
    d = unit(rng, r)
    d[:, 2] = -np.sign(o[:, 2]) * np.abs(d[:, 2])
    t = (-o[:, 2] / d[:, 2]).astype(np.float32)
    prim = np.where(rng.random(r) < 0.5, 0, -1).astype(np.int32)
    ng = np.tile(np.array([0.0, 0.0, 3.0], np.float32), (r, 1))  # not unit, CCW up
    return o, d, t, prim, ng


def advance(
    rng, roulette=False, throughput=None, row_albedo=np.zeros((0, 3)), sky=np.array([[0.2, 0.3, 0.4]]), reference=1.0
):
    o, d, t, prim, ng = hits(rng)
    r = len(o)
    live = np.arange(r) * 2
    acc = rng.random((r, 3))
    tp = np.full((r, 3), 0.5) if throughput is None else throughput
    radiance = np.full((2 * r, 3), -1.0)
    tri_albedo = np.array([[0.8, 0.6, 0.4]])
    out = K.advance_paths(
        live, acc, tp, o, d, t, prim, ng, tri_albedo, row_albedo, sky, radiance, 1e-3, roulette, 0.95, 0.5, reference, 7
    )
    return (o, d, t, prim, live, acc, tp, radiance), out


def test_advance_ends_misses_with_the_sky_and_continues_hits_from_the_facing_side(rng):
    (o, d, t, prim, live, acc, tp, radiance), out = advance(rng)
    new_live, new_acc, new_tp, x, n, nd, pdf, weight, s = out
    rows = new_live // 2  # live = 2 × input row
    miss = prim < 0
    np.testing.assert_allclose(radiance[live[miss]], acc[miss] + tp[miss] * [0.2, 0.3, 0.4])
    np.testing.assert_array_equal(rows, np.flatnonzero(~miss))  # no roulette: every hit survives
    assert s == len(rows) and (weight == 1.0).all()
    np.testing.assert_array_equal(new_acc, acc[rows])
    np.testing.assert_allclose(new_tp, tp[rows] * [0.8, 0.6, 0.4])
    assert (radiance[live[rows]] == -1.0).all()  # continuing paths not written
    facing = -np.sign(d[rows, 2])  # the side the ray came from
    np.testing.assert_allclose(n, np.stack([0 * facing, 0 * facing, facing], 1))
    np.testing.assert_allclose(x, o[rows] + d[rows] * t[rows, None].astype(np.float64) + n * 1e-3, atol=1e-6)
    cos = np.einsum("ri,ri->r", nd, n)
    assert cos.min() >= 0.0
    np.testing.assert_allclose(pdf, cos / np.pi, atol=1e-12)
    assert abs(cos.mean() - 2 / 3) < 0.02  # cosine-distributed


@pytest.mark.parametrize("reference", [1.0, 0.5, 0.25])
def test_advance_roulette_keeps_victims_for_their_light_and_reweights_survivors(rng, reference):
    """Per-row sky and albedo; survival p = min(√(max(throughput × albedo) / reference), 0.95)
    = √0.3, √0.6 or 0.95 (power ½, references 1, ½, ¼): survivors first with weight 1/p,
    victims after them (the caller adds their vertex's light, then ends them)."""
    r = 4000
    tp = np.full((r, 3), 0.3)
    albedo = np.tile([0.5, 1.0, 0.25], (r, 1))
    sky = rng.random((r, 3))
    (o, d, t, prim, live, acc, _, radiance), out = advance(rng, True, tp, albedo, sky, reference)
    new_live, new_acc, new_tp, x, n, nd, pdf, weight, s = out
    miss = prim < 0
    np.testing.assert_allclose(radiance[live[miss]], acc[miss] + 0.3 * sky[miss])
    hit = np.flatnonzero(~miss)
    np.testing.assert_array_equal(np.sort(new_live // 2), hit)  # every hit, once
    assert (radiance[new_live] == -1.0).all()  # none written yet
    survive = min(np.sqrt(0.3 / reference), 0.95)
    assert abs(s / len(hit) - survive) < 4 * np.sqrt(survive * (1 - survive) / len(hit))
    np.testing.assert_allclose(weight, 1 / survive)
    np.testing.assert_allclose(new_tp, np.tile([0.15, 0.3, 0.075], (len(hit), 1)))
    np.testing.assert_allclose(np.einsum("ri,ri->r", nd[:s], n[:s]), np.pi * pdf[:s], atol=1e-12)


def test_origins_cover_the_footprint_evenly_and_stay_inside_the_triangle(rng):
    """Inside a big triangle every first try is accepted: a texel's k origins then hit each of
    the k columns of its footprint once (a shifted Hammersley set). A triangle covering part
    of the footprint gets origins inside it only, uniform over the overlap."""
    n, k = 200, 16
    corner = rng.integers(0, 50, (n, 2)).astype(float)
    big = np.array([[-100.0, -100.0], [300.0, -100.0], [-100.0, 300.0]])
    tri_pos = np.concatenate([np.tile(big, (n, 1, 1)), np.zeros((n, 3, 1))], axis=2)  # world = texel space
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    one = np.ones(n, np.int64)  # the texel's own triangle alone
    out = K.footprint_origins(
        corner, np.tile(big, (n, 1, 1, 1)), tri_pos[:, None], one, np.zeros((n, 3)), up, 0.0, k, 0.5, 10, 3, NONE, 0, 0
    )
    local = out[:, :2].reshape(n, k, 2) - corner[:, None, :]
    assert local.min() >= 0.25 and local.max() <= 0.75
    np.testing.assert_array_equal(
        np.sort(np.floor((local[..., 0] - 0.25) * 2 * k), axis=1), np.tile(np.arange(k), (n, 1))
    )
    # half the footprint: the triangle x + y ≤ 1 through the texel's centre (corner at 0)
    half = np.array([[-5.0, 6.0], [6.0, -5.0], [-5.0, -5.0]])
    tri = np.tile(half, (n, 1, 1))
    tri_pos = np.concatenate([tri, np.zeros((n, 3, 1))], axis=2)
    out = K.footprint_origins(
        np.zeros((n, 2)), tri[:, None], tri_pos[:, None], one, np.zeros((n, 3)), up, 0.0, k, 0.5, 10, 4, NONE, 0, 0
    )
    assert (out[:, 0] + out[:, 1] <= 1.0 + 1e-12).all() and out[:, :2].min() >= 0.0
    assert (out[:, :2].min(axis=1) >= 0.25).mean() > 0.99  # 10 misses in a row (2⁻¹⁰): whole texel
    assert abs(out[:, 0].mean() - (0.25 + 0.5 / 3)) < 0.01  # centroid of the lower-left half


NONE = np.zeros(0, np.int64)  # footprint_origins without texel ids: per-pass stratification


def test_origins_by_texel_are_stratified_across_passes_and_depend_on_texel_and_seed(rng):
    """With texel ids, 4 passes of 16 first tries of a texel form a (0,6,2)-net's projections:
    its 64 origins hit each of the 64 columns and rows of its footprint once, and each cell of
    the 8 × 8 grid; within one pass each of 16 columns. Another texel id or seed: other origins."""
    n, k, passes = 100, 16, 4
    corner = rng.integers(0, 50, (n, 2)).astype(float)
    big = np.array([[-100.0, -100.0], [300.0, -100.0], [-100.0, 300.0]])
    tri_pos = np.concatenate([np.tile(big, (n, 1, 1)), np.zeros((n, 3, 1))], axis=2)
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    one = np.ones(n, np.int64)
    ids = np.arange(n, dtype=np.int64) * 7

    def origins(p, ids=ids, key=5):
        args = (corner, np.tile(big, (n, 1, 1, 1)), tri_pos[:, None], one, np.zeros((n, 3)), up, 0.0, k, 0.5, 10)
        return K.footprint_origins(*args, 3 + p, ids, p * k, key)[:, :2].reshape(n, k, 2) - corner[:, None]

    local = (np.concatenate([origins(p) for p in range(passes)], axis=1) - 0.25) * 2  # [0, 1)²
    every = np.tile(np.arange(k * passes), (n, 1))
    for axis in (0, 1):
        np.testing.assert_array_equal(np.sort(np.floor(local[..., axis] * k * passes), axis=1), every)
    cells = np.floor(local[..., 0] * 8) * 8 + np.floor(local[..., 1] * 8)
    np.testing.assert_array_equal(np.sort(cells, axis=1), every)
    one_pass = np.sort(np.floor(local[:, :k, 0] * k), axis=1)
    np.testing.assert_array_equal(one_pass, np.tile(np.arange(k), (n, 1)))
    assert not np.isclose(origins(0), origins(0, ids + 1)).all(axis=2).any()
    assert not np.isclose(origins(0), origins(0, key=6)).all(axis=2).any()


def test_add_pass_keeps_the_running_mean_variance_and_iz_of_each_texel(rng):
    """Per-texel passes in any order and subset: total = Σ x, m2 = Σ (x - mean)² (two-pass
    numpy), iz = Σ I_z luminance (hhd.irradz), passes counted."""
    from hhd_lightmapper.core import hhd

    n = 7
    normals = unit(rng, n)
    total, m2 = np.zeros((n, 9, 3)), np.zeros((n, 9, 3), np.float32)
    iz, iz_sq, passes = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)
    seen = [[] for _ in range(n)]
    for subset in ([0, 1, 2, 3, 4, 5, 6], [1, 3, 5], [0, 1, 2, 3, 4, 5, 6], [3], [2, 3, 6]):
        idx = np.array(subset)
        est = 1e3 * rng.normal(size=(len(idx), 9, 3)) + 5e3  # large mean: Welford's point
        K.add_pass(idx, est, normals, hhd.LUMINANCE, total, m2, iz, iz_sq, passes)
        for j, t in enumerate(idx):
            seen[t].append(est[j])
    for t in range(n):
        x = np.array(seen[t])
        assert passes[t] == len(x)
        np.testing.assert_allclose(total[t], x.sum(axis=0), rtol=1e-12)
        np.testing.assert_allclose(m2[t], ((x - x.mean(axis=0)) ** 2).sum(axis=0), rtol=1e-4, atol=1e-3)
        lum = hhd.irradz(x, np.repeat(normals[t : t + 1], len(x), axis=0)) @ hhd.LUMINANCE
        np.testing.assert_allclose([iz[t], iz_sq[t]], [lum.sum(), (lum**2).sum()], rtol=1e-12)
